"""Synthetic training data (section 5.1): randomised render specs, substance priors, labelled examples.

- `spec`: `RenderSpec` and `sample_render_spec` (pair, jittered camera, materials by substance, envmap,
  UV jitter), seeded from each item's natural key, stable as the collection grows;
- `priors`: substance priors for parts without an observed substance (bootstrap round, unobserved parts);
- `example`: `render_training_example` (beauty + exact part / material / substance maps, saturation);
- `toy`: a tiny procedural chair and studio envmap for tests and smoke runs.

Pure science: no database, no Prefect; `example` loads Mitsuba only through the renderer it is given.
"""
