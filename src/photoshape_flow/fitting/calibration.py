"""The fit stage's cost weights and temperature, fitted on validation renders and stored on the classifier.

Issue 26: "every weight and temperature is fitted on validation renders, never on exemplars or on
the evaluation worlds". A validation render (kinds `training`/`bootstrap`, split `val`: val shapes
under val envmaps, true material of every part known from its spec) becomes a calibration photo:

1. resampled to the side the collection's exemplars are stored at (the median crop, `exemplar_size`;
   `fit.calibration_at_exemplar_size`), degraded there as the demo degrades its exemplars
   (`demo.exemplars.degrade`: exposure, white balance, blur, noise; then a JPEG round trip), framed
   like an exemplar (`fit.validation.frame`), and its exact part map misaligned as fine alignment
   errs (`fit.validation.misalign`), all seeded by the render's key and the global seed; degraded at
   the render's own size instead, a photo is ~3x blurrier than an exemplar (D45);
2. ranked by the classifier as inference ranks a part (material head, stored colour likelihood,
   and, since the substance network is not re-run on renders, the classifier's own substance head,
   as `recognition.calibration.posterior_reliability` does): the prior of the candidates;
3. lit, given candidates, rendered and measured by the stage's own functions (`fitting.steps`:
   `lighting_estimate` over the training envmaps, not the render's own, `candidates_of`,
   `render_candidates`, `profiled_terms`) with the profile's hand-set weights, at the render's
   camera; each observed part whose true material is among its candidates is one `fit.calibrate.Case`.

The cases are measured at `fit.blur` (a blur chosen here decided nothing: D64); the model (every
weight fitted, the hand-set weights with only their temperature fitted, or the hand-set weights as
they are: `choices`) with the lowest cross-validated log-loss is kept and refitted on all the cases
(`fit.calibrate.fit`, centred on the hand-set weights, or `fit.calibrate.fit_temperature`) and stored
(`networks.calibrations.Calibration.fit`) with a key of everything they depend on (code, fit config,
checkpoint, the sampled renders, enabled materials, training envmaps, exemplar size, seed), like the D24
calibrations; `run_fit` computes them when the key changed and the stage then ranks with them. Two
workers that start `fit` at once may both compute them: the result is deterministic, so they write
the same record. Reported with them: 2-fold cross-validated log-loss and top-1 (folds by render) of
the hand-set cost, the hand-set cost with a fitted temperature, and the fitted cost.

The sample of validation renders, the exemplars' size and the photo (`validation_renders`,
`exemplar_size`, `calibration_photo`) are `networks.validation_photos`'s, shared with the BatchNorm
priors and the colour likelihood's sigma.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from photoshape_flow.config import Settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.devices import set_torch_threads
from photoshape_flow.fit import calibrate as cal
from photoshape_flow.fit.scene import FitScene, exposure_grid, profiled_terms, render_candidates
from photoshape_flow.fitting.context import PairData
from photoshape_flow.fitting.steps import candidates_of, lighting_estimate
from photoshape_flow.hashing import item_seed, stable_hash
from photoshape_flow.networks.calibrations import Calibration
from photoshape_flow.networks.classifiers import load_material_classifier
from photoshape_flow.networks.evidence import stored_evidence
from photoshape_flow.networks.validation_photos import calibration_photo, exemplar_size, validation_renders
from photoshape_flow.progress_sink import Progress, counted
from photoshape_flow.render import Camera
from photoshape_flow.synth.spec import RenderSpec

log = logging.getLogger(__name__)

CODE_VERSION = "fit-calibration-4"  # 2: photos degraded at the exemplars' size (D45); 3: model chosen (D48);
#                                     4: one blur, `fit.blur` (D64)
# what a calibration may keep (`choices`): every weight and the temperature fitted, the hand-set weights
# with their temperature fitted, or the hand-set weights as they are (temperature 1)
MODELS = ("fitted", "hand_set_temperature", "hand_set")


class RenderRanker:
    """The classifier's ranking of a photo's regions, as inference ranks an observed part (see the module doc)."""

    def __init__(self, ctx: Any, settings: Settings):
        set_torch_threads(settings.torch_threads)
        row, self.model = load_material_classifier(ctx.classifier.id, settings)
        self.top_k = ctx.cfg.top_k
        with session_scope(settings.resolved_database_url) as session:
            classifier = session.get(m.Classifier, row.id)
            assert classifier is not None
            self.evidence = stored_evidence(session, ctx.store, classifier, self.model,
                                            enabled=frozenset(ctx.material_substance))

    def rank(self, image: np.ndarray, masks: dict[int, np.ndarray]) -> dict[int, list[m.Assignment]]:
        """Part index -> transient (never added) assignment rows, best first, as `fitting.fit` reads them."""
        indices = sorted(masks)
        if not indices:
            return {}
        regions = [masks[i] for i in indices]
        mats, subs = self.model.predict(image, regions)
        ranked = self.evidence.rank_regions(image, regions, mats, subs, self.top_k)
        return {index: [m.Assignment(rank=r + 1, material_id=x.material_id, score=x.score, substance=x.substance,
                                     unobserved=False) for r, x in enumerate(part.materials)]
                for index, part in zip(indices, ranked, strict=True)}


def render_photo_case(ctx: Any, ranker: RenderRanker, row: m.Rendering, settings: Settings,
                      photo_size: int | None = None) -> tuple[RenderSpec, PairData]:
    """One validation render as the stage sees an exemplar: its spec and a transient pair (never added)
    whose scene is the render degraded, framed and misaligned (`calibration_photo`, seeded by the
    render's key) and whose rows are the classifier's ranking of each observed region (empty when
    none could be ranked). `photo_size`: the side the photo is degraded at (None: the render's own).
    """
    spec = RenderSpec.from_dict(row.params)
    truth = spec.material_by_index()
    hdr, ids = ctx.store.load_image(row.blobs["hdr"]), ctx.store.load_image(row.blobs["part_ids"])
    ids = ids[..., 0] if ids.ndim == 3 else ids
    rng = np.random.default_rng(item_seed(settings.seed, "fit-calibration", row.kind, row.key))
    rgb, labels, foreground = calibration_photo(hdr, ids, photo_size, ctx.cfg.size, rng)
    with session_scope(settings.resolved_database_url) as session:
        shape = session.get(m.Shape, row.shape_id)
        assert shape is not None
        mesh = ctx.mesh(shape)
    camera = Camera(spec.camera.azimuth, spec.camera.elevation, spec.camera.distance, spec.camera.fov)
    present = sorted(int(i) for i in np.unique(labels) if i > 0 and int(i) in truth)
    scene = FitScene.from_photo(mesh, camera, rgb, labels, present, ctx.cfg.erode, blur=ctx.cfg.blur,
                                foreground=foreground, features=ctx.features)
    rows = ranker.rank(rgb, {i: (labels == i) & foreground for i in scene.masks})
    return spec, PairData(m.Pair(shape_id=row.shape_id), scene, rows, None)


def render_cases(ctx: Any, ranker: RenderRanker, row: m.Rendering, settings: Settings,
                 photo_size: int | None = None) -> tuple[list[cal.Case], dict[str, int]]:
    """The calibration cases of one validation render, and counts (parts observed, true among candidates).

    `photo_size`: the side the photo is degraded at (None: the render's own).
    """
    spec, data = render_photo_case(ctx, ranker, row, settings, photo_size)
    truth, scene = spec.material_by_index(), data.scene
    counts = {"parts": len(scene.masks), "true_in_candidates": 0}
    if not data.rows:
        return [], counts
    light = lighting_estimate(ctx, data)
    candidates = candidates_of(ctx, data)
    if not candidates:
        return [], counts
    envmap = ctx.light_envmap(light)
    renders = render_candidates(ctx.frame, scene, data.rank1(), candidates, ctx.spec, envmap)
    measured, _, _ = profiled_terms(renders, scene, candidates, float(light["exposure"]), ctx.weights,
                                    ctx.prior_weight, exposure_grid(ctx.cfg.exposure_stops), ctx.cfg.erode)
    cases = []
    for index, options in sorted(candidates.items()):
        ids_ = [c.material_id for c in options]
        if truth[index] not in ids_:
            continue
        counts["true_in_candidates"] += 1
        found = [t for t in measured.get(index, {}).values() if t is not None]
        if not found:
            continue
        fill = np.mean(found, axis=0)  # an unmeasured candidate: the mean, as `rank_candidates` fills it
        features = np.array([[*(t if (t := measured[index].get(c.material_id)) is not None else fill), c.prior_cost]
                             for c in options])
        cases.append(cal.Case(features, ids_.index(truth[index]), group=f"{row.kind}/{row.key}"))
    return cases, counts


def hand_set(cfg: Any) -> np.ndarray:
    """The profile's weights in `fit.calibrate.TERMS` order (temperature 1)."""
    return np.array([cfg.color_weight, cfg.contrast_weight, cfg.gradient_weight, cfg.highlight_weight,
                     cfg.deep_weight, cfg.prior_weight], np.float64)


def held_out(cases: Sequence[cal.Case], cfg: Any) -> dict[str, Any]:
    """2-fold cross-validated figures (folds by render): hand-set, hand-set + fitted temperature, fitted."""
    first, second = cal.folds(cases)
    if not cal.usable(first) or not cal.usable(second):
        return {"cases": 0}
    base = hand_set(cfg)
    out: dict[str, list[cal.Score]] = {"hand_set": [], "hand_set_temperature": [], "fitted": []}
    for train, test in ((first, second), (second, first)):
        out["hand_set"].append(cal.score(base, test))
        out["hand_set_temperature"].append(cal.score(base / cal.fit_temperature(train, base), test))
        out["fitted"].append(cal.score(cal.fit(train, start=base, centre=base).theta, test))

    def pooled(scores: list[cal.Score]) -> dict[str, float]:
        n = sum(s.cases for s in scores)
        return {"log_loss": round(sum(s.log_loss * s.cases for s in scores) / n, 4),
                "top1": round(sum(s.top1 * s.cases for s in scores) / n, 4)}

    return {"cases": sum(s.cases for s in out["fitted"]), **{k: pooled(v) for k, v in out.items()}}


def calibration_key(ctx: Any, renders: Sequence[m.Rendering], seed: int, photo_size: int | None = None) -> str:
    """What a stored calibration depends on (a change of any re-fits it): not the refinement's settings.

    The classifier's BatchNorm prior and its colour evidence change how it ranks the cases
    (`RenderRanker`); each enters only when set, so older calibrations keep their keys.
    """
    record = Calibration.of(ctx.classifier)
    # the refinement runs after the selection: its settings do not change what is calibrated
    config = {k: v for k, v in dataclasses.asdict(ctx.cfg).items() if not k.startswith("refine")}
    return stable_hash({"code": CODE_VERSION, "fit_code": ctx.params["code"], "config": config,
                        "checkpoint": ctx.classifier.checkpoint_blob, "seed": seed, "photo_size": photo_size,
                        "renders": [[r.kind, r.key, r.params_hash] for r in renders],
                        "materials": sorted(ctx.material_substance), "envmaps": sorted(ctx.envmaps.items()),
                        **({} if record.bn_prior is None else {"bn_prior": record.bn_prior}), **record.colour_key})


def fit_calibration(ctx: Any, settings: Settings, renders: Sequence[m.Rendering],
                    progress: Progress | None = None, photo_size: int | None = None) -> dict[str, Any] | None:
    """The calibration record of `renders` (see the module docstring); None when no usable case came out.

    The model with the lowest cross-validated log-loss (in-sample when a fold is empty) is kept and its
    weights and temperature refitted on all the cases. `photo_size`: the side the photos are degraded
    at (None: each render's own).
    """
    started = time.perf_counter()
    ranker = RenderRanker(ctx, settings)
    cases: list[cal.Case] = []
    counts = {"renders": 0, "parts": 0, "true_in_candidates": 0, "failed": 0}
    for row in counted(progress, "fit calibration renders", renders):
        try:
            found, n = render_cases(ctx, ranker, row, settings, photo_size)
        except (ValueError, OSError) as exc:  # one unreadable or invisible render never stops the fit
            log.warning("fit calibration: %s/%s skipped: %s", row.kind, row.key, exc)
            counts["failed"] += 1
            continue
        cases += found
        counts["renders"] += 1
        counts["parts"] += n["parts"]
        counts["true_in_candidates"] += n["true_in_candidates"]
    usable = cal.usable(cases)
    if not usable:
        log.warning("fit calibration: no usable case in %d validation renders; hand-set weights", len(renders))
        return None
    base = hand_set(ctx.cfg)
    checked = held_out(usable, ctx.cfg)
    _, model = min(choices(checked, usable, base), key=lambda item: item[0])  # ties: the first of `MODELS`
    fitted = refit(model, usable, base)
    if not np.isfinite(fitted.temperature):
        log.warning("fit calibration: no term carries information on these cases; hand-set weights")
        return None
    record = {"weights": dict(zip(cal.TERMS, (round(w, 6) for w in fitted.weights), strict=True)),
              "temperature": round(fitted.temperature, 6), "blur": float(ctx.cfg.blur), "model": model,
              "photo_size": photo_size, "cases": len(usable), "held_out": checked, **counts,
              "seconds": round(time.perf_counter() - started, 2)}
    log.info("fit calibration (classifier %s): blur %s, %s weights %s, temperature %.3f on %d cases from %d renders "
             "(%.1f s); held out: %s", ctx.classifier.id, record["blur"], model, record["weights"], fitted.temperature,
             record["cases"], counts["renders"], record["seconds"], record["held_out"])
    return record


def choices(checked: dict[str, Any], usable: Sequence[cal.Case], base: np.ndarray) -> list[tuple[float, str]]:
    """(held-out log-loss, model) of each of `MODELS` on one blur's cases.

    Fitting five weights (or even a temperature) on a few dozen renders can over-fit: where the held-out
    figures favour a model with fewer fitted numbers, that model is kept (D48). Without two usable folds
    the in-sample log-loss of the fitted weights is all there is.
    """
    if not checked.get("cases"):
        return [(cal.score(cal.fit(usable, start=base, centre=base).theta, usable).log_loss, "fitted")]
    return [(float(checked[model]["log_loss"]), model) for model in MODELS]


def refit(model: str, cases: Sequence[cal.Case], base: np.ndarray) -> cal.Fit:
    """`model` (one of `MODELS`) fitted on all of `cases`, the hand-set weights `base` its start and centre."""
    if model == "fitted":
        return cal.fit(cases, start=base, centre=base)
    if model == "hand_set_temperature":
        return cal.Fit.from_theta(base / cal.fit_temperature(cases, base))
    return cal.Fit.from_theta(base)


def ensure_calibration(ctx: Any, settings: Settings, progress: Progress | None = None) -> dict[str, Any] | None:
    """The classifier's fitted weights for this config, fitted now when none are stored for it (None: hand-set)."""
    if ctx.cfg.calibration_cases <= 0:
        return None
    url = settings.resolved_database_url
    with session_scope(url) as session:
        renders = validation_renders(session, ctx.cfg.calibration_cases, settings.seed)
        photo_size = exemplar_size(session) if ctx.cfg.calibration_at_exemplar_size else None
        key = calibration_key(ctx, renders, settings.seed, photo_size)
        classifier = session.get(m.Classifier, ctx.classifier.id)
        found, stored = Calibration.of(classifier).fit_weights(key)
        session.expunge_all()
    if found:
        return None if stored is None else dict(stored)
    record = fit_calibration(ctx, settings, renders, progress, photo_size) if renders else None
    with session_scope(url) as session:
        classifier = session.get(m.Classifier, ctx.classifier.id)
        if classifier is not None:  # stored even when None: the hand-set fallback is not re-tried every run
            Calibration.store(classifier, fit={"key": key, "record": record})
    return record
