"""Stage 9, publish: PhotoShape renders and exports of the best pairs, downloads, the gallery and its grades.

`publish_stage` is the registry's entry; the writers are `export/`.
"""
