"""Stages 4 to 7, recognition: the substance network (bootstrap renders, training, a substance per part),
the training renders, the material classifier (training and its calibrations) and inference.

The `*_stage` modules are the registry's entries; the science is `classify/` and `synth/`.
"""
