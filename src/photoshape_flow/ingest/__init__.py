"""Stage 1, ingest: the four collections (shapes, exemplars, materials, envmaps) into rows and blobs.

`ingest_stage` is the registry's entry; `ingest` the facade of one function per collection.
"""
