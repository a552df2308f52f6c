"""Networks of the pipeline: the material classifier (section 5.2) and the substance network (4.3).

Material classifier modules: `resnet` (ResNet-18/34 + mask channel, two heads), `loss` (uncertainty-
weighted multitask loss), `augment`, `dataset` (region examples from training renders), `configs`
(tiny / cpu / paper), `train` (resumable loop, Table 4 metrics), `checkpoint`, `infer`
(`load_classifier`, `MaterialClassifier`). Import them directly: this package stays free of torch at
import time so that light callers (CLI help, flows) do not pay for it.
"""
