"""Fit by rendering (analysis by synthesis): choose each part's material by rendering it against the photo.

Pure pieces, no database or renderer: `appearance` (the misalignment-tolerant part statistics and
their distance), `lighting` (closed-form exposure and the choice among lighting hypotheses),
`candidates` (which materials each part tries, with their ranking prior) and `select` (the batched
render plan and the ranking of candidates by cost). `fitting.fit` wires them to the database and
the Mitsuba renderer; `fitting.fit_stage` is the stage.
"""
