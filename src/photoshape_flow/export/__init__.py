"""Exports and the gallery: PhotoShapes in formats other tools open, with their licences.

Pure functions on a `ShapeMesh`, per-part `MaterialSpec` (None = built-in) and `UVTransform`; no
database. The UV transform of the renderer (texture-scale formula, then the jitter) is baked into
every format's texcoords (see `export.geometry`).

- `formats.EXPORTERS`: the table of formats (name, main file, description); everything that names
  formats reads it. `writers.WRITERS`: the one writer of each, loaded only when a format is written.
- `gltf.write_glb` / `gltf.write_gltf`: glTF 2.0, metallic-roughness (`export.pbr`), hand-written.
- `mitsuba_xml.write_mitsuba_xml`: Mitsuba 3 scene from the renderer's `build_scene`.
- `obj.write_obj`: OBJ + MTL (PBR extension) + textures.
- `assignment.assignment_document`: the `assignment.json` sidecar (parts, materials, licences).
- `bundle.export_photoshape`: all of the above into one folder, atomically.
- `gallery.write_gallery`: the static HTML gallery, from the Jinja2 templates in ``templates/``
  (`templating`: autoescaped, links only to http(s) URLs).
- `text.one_line`: the one escaping of metadata (names, licences, attributions, URLs) that every
  format and the gallery use, so hostile text stays inert (a newline never starts an OBJ line).
- `validate.validate_gltf` and `browser.check_pages`: the Khronos glTF validator and headless
  Chromium, through the pinned npm packages in `export/node/` (``npm ci --prefix .../export/node``).
"""
