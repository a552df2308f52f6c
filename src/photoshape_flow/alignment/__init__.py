"""Stages 2 and 3, alignment: shape-exemplar pairs (coarse: viewpoint sweeps, HOG, retrieval) and each
pair's part map on the photo (fine: projection, flow warp, dense CRF). The science is `align/`.

`coarse_alignment_stage` and `fine_alignment_stage` are the registry's entries.
"""
