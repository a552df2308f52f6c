"""Stage `training` (section 5.2): train, resume, or fine-tune the material classifier, then calibrate.

Calibration (`recognition.calibration`: the colour likelihood's sigma on the classifier's row, each
substance network's part temperature on its row) runs here, not in inference, because the substance
temperature needs the training round's validation renders and inference must only read.
"""

from __future__ import annotations

from photoshape_flow.classify.configs import ClassifierConfig
from photoshape_flow.db import models as m
from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.report import StageReport
from photoshape_flow.recognition.calibration import calibrate
from photoshape_flow.recognition.training import run_training

NAME = "training"


def run(ctx: StageContext, cfg: ClassifierConfig, work: None = None) -> StageReport:
    classifier_id = run_training(cfg, settings=ctx.settings, progress=ctx.progress, store=ctx.store)
    calibration = calibrate(ctx.settings, classifier_id, store=ctx.store)
    with ctx.session() as session:
        clf = session.get(m.Classifier, classifier_id)
        assert clf is not None
        details = {"classifier_id": classifier_id, "name": clf.name, "status": clf.status, "metrics": clf.metrics,
                   "calibration": calibration}
    return StageReport(NAME, done=1, details=details)
