"""Does fit's refinement (D35) make a PhotoShape relight closer to the truth, on validation renders?

    python -m experiments.refine_relight.run --profile small [--cases 48] [--winners fit,truth]
    python -m experiments.refine_relight.run --gaps --cases 6     # why: the true materials' photo/render gap

Each of the fit calibration's validation renders (`fitting.calibration.validation_renders`: val
shapes under val envmaps, the library's materials, each part's truth known) becomes a photo as the
calibration makes it (`fitting.calibration.render_photo_case` at the render's own size): degraded
like an exemplar, part map misaligned as fine alignment errs. The
stage's own steps then run on it: candidates, the lighting estimate over the training envmaps, the
selection (the classifier's calibrated weights, `fitting.calibration.ensure_calibration`) and the
refinement of the winners under that lighting (`fit.refine.refine_parts`, the stage's settings).
Winner sets (`--winners`):

    fit     the selection's winners, as the stage refines them
    truth   every part's true material: the ideal refinement is then the identity, so whatever it
            changes is error the estimated light and the photo put into the material

Each winner set is relit as `photoshape eval` relights a pair (`scoring.relighting_eval`): the
render's shape from three novel views (camera turned 90, 180, 270 degrees) under a held-out envmap,
silhouette RMSE (sRGB) against the same views with the true materials. Arms per winner set:
`unrefined`, `refined` (as stored), `no-tint` (the refinement without its tint), `uv-only`,
`tint-only` (only the tint) and `tint-norm` (the tints divided by their luminance-weighted geometric mean over
the pair's refined parts: one photo cannot tell the albedo's level from the exposure's). Per arm:
mean RMSE over renders and its difference from `unrefined` with a 95% bootstrap interval over renders.

Read-only. Output: `<data root>/experiments/refine_relight/results.json`.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from experiments.common import interval, results_dir
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.fit import scene as sc
from photoshape_flow.fit.refine import refine_parts
from photoshape_flow.fit.select import rank_candidates
from photoshape_flow.fitting import calibration as fc
from photoshape_flow.fitting.context import FitContext, PairData
from photoshape_flow.fitting.refine import refine_settings
from photoshape_flow.fitting.steps import candidates_of, lighting_estimate, select_materials
from photoshape_flow.networks.classifier_rows import resolve_classifier
from photoshape_flow.profiles import resolve_profile
from photoshape_flow.render import EnvmapSpec
from photoshape_flow.scoring.relighting_eval import Relighter, silhouette_rmse
from photoshape_flow.store import BlobStore
from photoshape_flow.synth.spec import RenderSpec

LUMA = np.array([0.2126, 0.7152, 0.0722])
Refinements = dict[int, dict[str, Any]]


def no_tint(refined: Refinements) -> Refinements:
    return {i: {**r, "tint": [1.0, 1.0, 1.0]} for i, r in refined.items()}


def tint_only(refined: Refinements) -> Refinements:
    return {i: {"tint": r["tint"]} for i, r in refined.items()}


def uv_only(refined: Refinements) -> Refinements:
    return {i: {**r, "tint": [1.0, 1.0, 1.0], "roughness_scale": 1.0} for i, r in refined.items()}


def tint_normalised(refined: Refinements) -> Refinements:
    """Tints divided by their common level: the geometric mean of their luminances over the refined parts."""
    if not refined:
        return {}
    level = math.exp(float(np.mean([math.log(max(float(LUMA @ np.asarray(r["tint"])), 1e-6))
                                    for r in refined.values()])))
    return {i: {**r, "tint": [float(t) / level for t in r["tint"]]} for i, r in refined.items()}


ARMS: dict[str, Callable[[Refinements], Refinements] | None] = {
    "unrefined": None, "refined": lambda r: r, "no-tint": no_tint, "uv-only": uv_only, "tint-only": tint_only,
    "tint-norm": tint_normalised,
}


class Experiment:
    """A data root's fit context; `measure` runs one validation render through fit, refinement and relighting."""

    def __init__(self, profile: str, overrides: list[str], size: int, spp: int, arms: list[str] | None = None):
        self.arms = ["unrefined", *[a for a in (arms or list(ARMS)) if a != "unrefined"]]
        self.settings = get_settings()
        self.cfg = resolve_profile(profile, overrides).profile.fit
        self.store = BlobStore(self.settings.blob_root)
        with session_scope(self.settings.resolved_database_url) as session:
            self.ctx = FitContext(session, self.store, resolve_classifier(session, None), self.cfg)
            self.relighter = Relighter(session, self.store, size, spp)
        # the stage's fitted weights (stored by the fit stage's calibration; fitted now when missing)
        self.ctx.calibration = fc.ensure_calibration(self.ctx, self.settings)
        self.ranker = fc.RenderRanker(self.ctx, self.settings)

    def photo_case(self, row: m.Rendering) -> tuple[RenderSpec, dict[int, int], PairData] | None:
        """The render as the calibration's photo (degraded at the render's own size), ranked."""
        spec, data = fc.render_photo_case(self.ctx, self.ranker, row, self.settings)
        return (spec, spec.material_by_index(), data) if data.rows else None

    def winners(self, data: PairData, truth: Mapping[int, int]) -> tuple[dict[str, dict[int, int]], dict, float]:
        """The fit's and the truth's winner per observed part, the lighting estimate and the winners' exposure."""
        light = lighting_estimate(self.ctx, data)
        candidates = candidates_of(self.ctx, data)
        measured, exposure = select_materials(self.ctx, data, candidates, light)
        fit = {i: rank_candidates(c, measured[i], self.ctx.prior_weight)[0].candidate.material_id
               for i, c in candidates.items() if c and i in measured}
        observed = {i: truth[i] for i in data.scene.masks if i in truth}
        return {"fit": {**data.rank1(), **fit}, "truth": dict(truth), "observed": observed}, light, exposure

    def refine(self, data: PairData, chosen: Mapping[int, int], parts: list[int], light: dict,
               exposure: float) -> Refinements:
        """The stage's refinement of `parts` with `chosen` materials under the estimated lighting."""
        ctx, cfg = self.ctx, self.cfg
        materials = [ctx.spec(chosen.get(p.index)) for p in data.scene.mesh.parts]
        frame_ = sc.FrameRenderer(ctx.frame.renderer, cfg.refine_size, cfg.refine_spp)
        uv_frame = sc.FrameRenderer(ctx.frame.renderer, cfg.size, cfg.refine_spp)
        result = refine_parts(frame_, data.scene, materials, parts, ctx.light_envmap(light), exposure,
                              refine_settings(cfg), uv_frame=uv_frame)
        return {i: r.refinement.to_dict() for i, r in result.items()}

    def measure(self, row: m.Rendering, winner_sets: list[str]) -> dict[str, Any] | None:
        case = self.photo_case(row)
        if case is None:
            return None
        spec, truth, data = case
        chosen, light, exposure = self.winners(data, truth)
        pair = m.Pair(shape_id=row.shape_id, azimuth=spec.camera.azimuth, elevation=spec.camera.elevation,
                      camera_distance=spec.camera.distance, fov=spec.camera.fov)
        parts = sorted(chosen["observed"])
        out: dict[str, Any] = {"render": f"{row.kind}/{row.key}", "parts": len(parts),
                               "fit_top1": float(np.mean([chosen["fit"].get(i) == truth[i] for i in parts]))
                               if parts else None}
        with session_scope(self.settings.resolved_database_url) as session:
            true_views = self.relighter.views(session, pair, truth)
            for name in winner_sets:
                materials = {**truth, **{i: chosen[name][i] for i in parts if i in chosen[name]}}
                refined = self.refine(data, materials, parts, light, exposure)
                out[f"{name}:tints"] = {str(i): r["tint"] for i, r in refined.items()}
                for arm in self.arms:
                    transform = ARMS[arm]
                    refinements = transform(refined) if transform else None
                    views = self.relighter.views(session, pair, materials, refinements)
                    values = [silhouette_rmse(p[0], t[0], t[1] | p[1]) for p, t in zip(views, true_views, strict=True)]
                    out[f"{name}:{arm}"] = float(np.nanmean(values))
        return out


def gaps(experiment: Experiment, renders: list[m.Rendering]) -> dict[str, list[float]]:
    """Mean log2 of photo / render per channel over the observed parts, true materials, four ways.

    Lighting `true` (the render's own envmap, the exposure that fits the true materials) or `est`
    (the stage's estimate and its winners' exposure); the render `raw` (unblended, what the
    refinement's loss reads) or `blended` (over the photo's background at the silhouette and
    softened like the photo, what the selection compares: `FitScene.exposed_linear`).
    """
    ctx = experiment.ctx
    with session_scope(experiment.settings.resolved_database_url) as session:
        envmaps = {e.id: e.blob for e in session.query(m.Envmap).all()}
    ratios: dict[str, list[np.ndarray]] = {}
    for row in renders:
        case = experiment.photo_case(row)
        if case is None:
            continue
        spec, truth, data = case
        _, light, exposure = experiment.winners(data, truth)
        materials = [ctx.spec(truth.get(p.index)) for p in data.scene.mesh.parts]
        true_env = EnvmapSpec(experiment.store.resolve(envmaps[spec.envmap.envmap_id]), scale=spec.envmap.scale,
                              rotation=spec.envmap.rotation)
        ((_, true_exposure, _),) = sc.score_lighting(ctx.frame, data.scene, materials, [(None, true_env)],
                                                     ctx.weights, experiment.cfg.erode)
        for light_name, envmap, gain in (("true", true_env, true_exposure),
                                         ("est", ctx.light_envmap(light), exposure)):
            rgba = data.scene.render(ctx.frame, materials, envmap)
            shown = {"raw": rgba[..., :3] * gain, "blended": data.scene.exposed_linear(rgba, gain)}
            for kind, image in shown.items():
                for mask in data.scene.masks.values():
                    photo, render = data.scene.photo_linear[mask].mean(0), image[mask].mean(0)
                    ratios.setdefault(f"{light_name}:{kind}", []).append(
                        np.log2(np.maximum(photo, 1e-4) / np.maximum(render, 1e-4)))
    return {k: [round(float(x), 3) for x in np.mean(v, axis=0)] for k, v in ratios.items()}


def summarise(records: list[dict[str, Any]], winner_sets: list[str], arms: list[str],
              seed: int = 0) -> dict[str, Any]:
    """Mean relit RMSE per arm and its paired difference from `unrefined` (95% interval over renders)."""
    rng = np.random.default_rng(seed)
    groups = np.arange(len(records))
    table: dict[str, Any] = {}
    for name in winner_sets:
        base = np.array([r[f"{name}:unrefined"] for r in records])
        for arm in arms:
            values = np.array([r[f"{name}:{arm}"] for r in records])
            diff = values - base
            table[f"{name}:{arm}"] = {"rmse": round(float(values.mean()), 4),
                                      "minus_unrefined": round(float(diff.mean()), 4),
                                      "interval": interval(diff, groups, rng)}
    return table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="small")
    parser.add_argument("--set", action="append", default=[], help="profile override, e.g. fit.refine_iterations=4")
    parser.add_argument("--cases", type=int, default=None, help="validation renders (default: the profile's)")
    parser.add_argument("--winners", default="fit,truth")
    parser.add_argument("--arms", default="", help=f"comma-separated, of {', '.join(ARMS)} (default: all)")
    parser.add_argument("--size", type=int, default=128, help="relit render size (the evaluation's)")
    parser.add_argument("--spp", type=int, default=32)
    parser.add_argument("--gaps", action="store_true",
                        help="only the true materials' photo/render gap per channel (`gaps`), then exit")
    args = parser.parse_args()
    experiment = Experiment(args.profile, args.set, args.size, args.spp, args.arms.split(",") if args.arms else None)
    winner_sets = args.winners.split(",")
    count = args.cases if args.cases is not None else experiment.cfg.calibration_cases
    settings = experiment.settings
    with session_scope(settings.resolved_database_url) as session:
        renders = fc.validation_renders(session, count, settings.seed)
        session.expunge_all()
    if args.gaps:
        print(json.dumps(gaps(experiment, renders)))
        return
    records = []
    for row in renders:
        try:
            record = experiment.measure(row, winner_sets)
        except (ValueError, OSError) as exc:
            print(f"{row.kind}/{row.key}: skipped ({exc})")
            continue
        if record is not None:
            records.append(record)
            print(json.dumps({k: v for k, v in record.items() if not k.endswith(":tints")}), flush=True)
    results = {"profile": args.profile, "overrides": args.set, "renders": len(records),
               "fit_top1": round(float(np.nanmean([r["fit_top1"] for r in records])), 4),
               "arms": summarise(records, winner_sets, experiment.arms), "records": records}
    print(json.dumps(results["arms"], indent=1))
    out = results_dir(settings, "refine_relight")
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=2))
    print(f"written {out / 'results.json'}")


if __name__ == "__main__":
    main()
