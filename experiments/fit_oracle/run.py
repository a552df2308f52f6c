"""What limits fit's choice where everything can be made true? The calibration's cases with each nuisance removed.

    python -m experiments.fit_oracle.run --profile small
    python -m experiments.fit_oracle.run --profile small --conditions est,deg,mis,def --probe embedding

The fit calibration (`fitting.calibration`) turns validation renders (our renderer, library
materials, val shapes under val envmaps) into aligned "photos" and measures every candidate as the
stage does. Here each nuisance between such a photo and the render of its true material can be
switched off, one condition = four switches, comma-separated:

    lighting   est: the stage's estimate over the training envmaps | estx: that estimate lit by the true
               materials rather than the ranking's first (what the library of envmaps allows) |
               joint: the `--joint-top` best hypotheses of that search, each with every candidate
               rendered, the one whose selection costs least | true: the render's own envmap,
               rotation and scale (exposure still searched per candidate, `fit.scene.profiled_terms`) |
               truex: that and the one exposure that fits the true materials' render to the photo
    photo      deg: degraded like a demo exemplar (exposure, white balance, blur, noise, JPEG) | clean |
               deg:a+b: only those parts of that degradation (exposure, wb, background, blur, noise, jpeg)
    mask       mis: the part map misaligned as fine alignment errs | exact
    uv         def: candidates at their materials' own UV scale | uv: at the render's per-part UV transform

With `true,clean,exact,uv` the render of the true material repeats the photo up to sampling noise,
so whatever the statistics still miss there is the comparison's own limit. For each condition:
2-fold held-out log-loss and top-1 of the fitted cost (folds by render, `fit_calibration.held_out`),
the classifier prior alone, and the mean number of candidates. `--probe` adds one more term to the
cost, to measure a candidate term before it enters `fit.appearance`:

    embedding  1 - cos of the material classifier's pooled features of the photo's and the render's part
    layout     mean CIELAB difference per pixel after a blur of `--layout-sigma` (the shading's layout)
    shift      |log2| of how far a candidate's own exposure is from the lighting's (stops)

`--photo-size N` degrades each photo at N pixels (the render resampled; exemplars are degraded at
their own size, then framed) instead of at the render's size. `--wb-step S` profiles a white balance
with the exposure (red and blue gains 1 - S, 1, 1 + S at each exposure of the grid). `--dump` adds
each case (candidates, their substances, features, truth) to the results.

Read-only. Output: `<data root>/experiments/fit_oracle/results.json`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from experiments.common import results_dir
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.fit import calibrate as cal
from photoshape_flow.fit import lighting as lt
from photoshape_flow.fit import scene as sc
from photoshape_flow.fit.validation import frame, misalign, resampled, sample_misalignment
from photoshape_flow.fitting import calibration as fc
from photoshape_flow.fitting.context import FitContext, PairData
from photoshape_flow.fitting.fit import candidates_of, lighting_estimate
from photoshape_flow.hashing import item_seed
from photoshape_flow.networks.classifier_rows import resolve_classifier
from photoshape_flow.networks.validation_photos import as_photo
from photoshape_flow.profiles import resolve_profile
from photoshape_flow.render import Camera, EnvmapSpec, UVTransform
from photoshape_flow.render.specs import linear_to_srgb
from photoshape_flow.store import BlobStore
from photoshape_flow.synth.spec import RenderSpec

DEFAULT_CONDITIONS = ("est,deg,mis,def", "true,deg,mis,def", "est,clean,exact,def", "true,clean,exact,def",
                      "true,clean,exact,uv")


class UVFrame(sc.FrameRenderer):
    """The stage's frame renderer with the validation render's per-part UV transforms (`uv` condition)."""

    def __init__(self, plain: sc.FrameRenderer):
        super().__init__(plain.renderer, plain.size, plain.spp)
        self.uv: dict[int, Any] | None = None

    def render_rgba(self, mesh: Any, materials: Any, camera: Any, envmap: Any, uv_transforms: Any = None) -> np.ndarray:
        uvs = None if self.uv is None else [self.uv.get(p.index) for p in mesh.parts]
        return super().render_rgba(mesh, materials, camera, envmap, uv_transforms=uvs)


class Embedder:
    """The material classifier's pooled features of image regions (L2-normalised, mirrored view averaged)."""

    def __init__(self, classifier: Any):
        self.classifier = classifier

    @torch.inference_mode()
    def __call__(self, srgb: np.ndarray, masks: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
        keys = sorted(masks)
        if not keys:
            return {}
        x = self.classifier.inputs(srgb.astype(np.float32), [masks[k] for k in keys])
        f = self.classifier.model.features(torch.cat([x, x.flip(-1)]))
        f = torch.nn.functional.normalize(f[: len(keys)], dim=1) + torch.nn.functional.normalize(f[len(keys):], dim=1)
        f = torch.nn.functional.normalize(f, dim=1).numpy()
        return {k: f[i] for i, k in enumerate(keys)}


def probe_terms(probe: str, scene: sc.FitScene, renders: sc.CandidateRenders,
                exposure: float, erode_pixels: int, embed: Embedder | None,
                sigma: float) -> dict[tuple[int, int], float]:
    """(part, candidate) -> the probe term of that candidate's render."""
    out: dict[tuple[int, int], float] = {}
    if probe == "embedding":
        assert embed is not None
        photo = embed(lt.exposed_srgb(scene.photo_linear, 1.0), scene.masks)
    else:
        photo_lab = sc.to_lab(lt.exposed_srgb(sc.soften(scene.photo_linear, sigma), 1.0))
    for k, rgba in enumerate(renders.renders):
        shown = {i: mid for i, by in renders.where.items() for mid, at in by.items() if at == k}
        regions = {i: r for i in shown if (r := sc.erode(renders.ids == i, erode_pixels)).any()}
        alpha = rgba[..., 3:4]
        linear = rgba[..., :3] * alpha * exposure + (1.0 - alpha) * scene.background  # as `FitScene.exposed_lab`
        if probe == "embedding":
            srgb = lt.exposed_srgb(linear, 1.0)
            assert embed is not None
            feats = embed(srgb, regions)
            out.update({(i, shown[i]): 1.0 - float(photo[i] @ f) for i, f in feats.items() if i in photo})
        else:
            lab = sc.to_lab(lt.exposed_srgb(sc.soften(linear, sigma), 1.0))
            for i, region in regions.items():
                both = scene.masks[i] & region if (scene.masks[i] & region).sum() >= 12 else scene.masks[i]
                out[(i, shown[i])] = float(np.linalg.norm(lab[both] - photo_lab[both], axis=1).mean()) / 10.0
    return out


#: the degradation's parameters that each `deg:` name keeps, and their values when it is left out
DEGRADATION_PARTS = {"exposure": ("exposure",), "wb": ("white_balance",), "background": ("background",),
                     "blur": ("blur_sigma",), "noise": ("noise_sigma",), "jpeg": ("jpeg_quality",)}
NEUTRAL = {"exposure": 1.0, "white_balance": [1.0, 1.0, 1.0], "background": 1.0, "blur_sigma": 0.0, "noise_sigma": 0.0}


def partly_degraded(hdr: np.ndarray, ids: np.ndarray, seed: int, keep: set[str]) -> np.ndarray:
    """`validation_photos.as_photo` with only the `keep` parts of its degradation (the same draws)."""
    import cv2

    from photoshape_flow.demo.exemplars import degrade, encode_jpeg, sample_degradation

    unknown = keep - set(DEGRADATION_PARTS)
    if unknown:
        raise SystemExit(f"deg: unknown part {sorted(unknown)[0]!r}; choose from {', '.join(DEGRADATION_PARTS)}")
    params = sample_degradation(np.random.default_rng(seed))
    kept = {k for part in keep for k in DEGRADATION_PARTS[part]}
    params = {k: (v if k in kept or k not in NEUTRAL else NEUTRAL[k]) for k, v in params.items()}
    covered = (np.asarray(ids) > 0).astype(np.float32)
    image = degrade(np.asarray(hdr, np.float32)[..., :3] * covered[..., None], covered, params)
    if "jpeg_quality" not in kept:
        return image
    decoded = cv2.imdecode(np.frombuffer(encode_jpeg(image, params["jpeg_quality"]), np.uint8), cv2.IMREAD_COLOR)
    return np.ascontiguousarray(decoded[..., ::-1])


def white_balances(step: float) -> list[np.ndarray]:
    """Per-channel gains of unit luminance: red and blue each at 1 - step, 1, 1 + step."""
    luminance = np.array([0.2126, 0.7152, 0.0722])
    gains = [np.array([1.0 + a, 1.0, 1.0 + b]) for a in (-step, 0.0, step) for b in (-step, 0.0, step)]
    return [g / float(g @ luminance) for g in gains]


def clean_photo(hdr: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """The validation render as 8-bit sRGB on white, without the exemplar degradation."""
    covered = (ids > 0)[..., None]
    linear = np.where(covered, np.minimum(hdr[..., :3], 2.0), 1.0)
    return np.clip(np.round(linear_to_srgb(linear) * 255.0), 0, 255).astype(np.uint8)


class Oracle:
    """One data root's fit context, ranker and envmaps; `cases` builds one render's cases under a condition."""

    def __init__(self, settings: Settings, profile: str, overrides: list[str], probe: str | None, sigma: float):
        self.settings = settings
        self.cfg = resolve_profile(profile, overrides).profile.fit
        self.store = BlobStore(settings.blob_root)
        with session_scope(settings.resolved_database_url) as session:
            self.ctx = FitContext(session, self.store, resolve_classifier(session, None), self.cfg)
            self.envmaps = {e.id: e.blob for e in session.query(m.Envmap).all()}
        self.ranker = fc.RenderRanker(self.ctx, settings)
        self.frame = UVFrame(self.ctx.frame)
        self.ctx._frame = self.frame
        self.probe, self.sigma = probe, sigma
        self.records: list[dict[str, Any]] = []  # each case's candidates and features (`--dump`)
        self.photo_size = 0  # > 0: photos degraded at this size, not the render's (`--photo-size`)
        self.wb_step = 0.0  # > 0: the exposure profile also searches a white balance (`--wb-step`)
        self.joint_top = 3  # lighting hypotheses the `joint` condition renders the candidates under
        self.embed = Embedder(self.ranker.model) if probe == "embedding" else None

    def cases(self, row: m.Rendering, condition: str) -> list[cal.Case]:
        lighting, photo_kind, mask, uv = condition.split(",")
        spec = RenderSpec.from_dict(row.params)
        truth = spec.material_by_index()
        hdr, ids = self.store.load_image(row.blobs["hdr"]), self.store.load_image(row.blobs["part_ids"])
        ids = ids[..., 0] if ids.ndim == 3 else ids
        if self.photo_size:  # degrade at an exemplar's resolution, as exemplars are, then frame like them
            hdr, ids = resampled(hdr, ids, self.photo_size)
        rng = np.random.default_rng(item_seed(self.settings.seed, "fit-calibration", row.kind, row.key))
        seed = int(rng.integers(2**31 - 1))
        if photo_kind.startswith("deg:"):
            photo = partly_degraded(hdr, ids, seed, set(photo_kind[4:].split("+")))
        else:
            photo = as_photo(hdr, ids, seed) if photo_kind == "deg" else clean_photo(hdr, ids)
        rgb, labels, foreground = frame(photo, ids, self.cfg.size)
        error = sample_misalignment(rng, self.cfg.size)
        labels = misalign(labels, error) if mask == "mis" else labels
        with session_scope(self.settings.resolved_database_url) as session:
            mesh = self.ctx.mesh(session.get(m.Shape, row.shape_id))
        camera = Camera(spec.camera.azimuth, spec.camera.elevation, spec.camera.distance, spec.camera.fov)
        present = sorted(int(i) for i in np.unique(labels) if i > 0 and int(i) in truth)
        scene = sc.FitScene.from_photo(mesh, camera, rgb, labels, present, self.cfg.erode, blur=self.cfg.blur,
                                       foreground=foreground, features=self.ctx.features)
        rows = self.ranker.rank(rgb, {i: (labels == i) & foreground for i in scene.masks})
        if not rows:
            return []
        data = PairData(m.Pair(shape_id=row.shape_id), scene, rows, None)
        self.frame.uv = ({p.index: UVTransform(scale=p.uv.scale, rotation=p.uv.rotation, offset=tuple(p.uv.offset))
                          for p in spec.parts} if uv == "uv" else None)
        try:
            return self._measure(row, spec, truth, scene, data, lighting)
        finally:
            self.frame.uv = None

    def _joint_lighting(self, scene: sc.FitScene, data: PairData, candidates: dict) -> tuple[Any, float]:
        """(envmap, exposure) of the `joint_top` best lighting hypotheses (every training envmap and rotation lit
        by the ranking's first materials) whose profiled selection has the lowest joint cost."""
        from photoshape_flow.fit.select import rank_candidates

        ctx, cfg = self.ctx, self.cfg
        materials = [ctx.spec(data.rank1().get(p.index)) for p in scene.mesh.parts]
        hypotheses = [lt.Hypothesis(e, r) for e in sorted(ctx.envmaps) for r in lt.rotations(cfg.rotations)]
        scored = sc.score_lighting(ctx.frame, scene, materials, [(h, ctx.envmap_spec(h.envmap_id, h.rotation))
                                                                 for h in hypotheses], ctx.weights, cfg.erode)
        best: tuple[float, Any, float] | None = None
        for h, exposure, _ in sorted(scored, key=lambda item: item[2])[: self.joint_top]:
            envmap = ctx.envmap_spec(h.envmap_id, h.rotation)
            renders = sc.render_candidates(ctx.frame, scene, data.rank1(), candidates, ctx.spec, envmap)
            distances, _, joint = sc.select_profiled(renders, scene, candidates, exposure, ctx.weights,
                                                     ctx.prior_weight, cfg.exposure_stops, cfg.erode)
            total = sum(rank_candidates(candidates[i], distances[i], ctx.prior_weight)[0].cost for i in distances)
            if best is None or total < best[0]:
                best = (total, envmap, joint)
        assert best is not None
        return best[1], best[2]

    def _measure(self, row: m.Rendering, spec: RenderSpec, truth: dict[int, int], scene: sc.FitScene,
                 data: PairData, lighting: str) -> list[cal.Case]:
        ctx, cfg = self.ctx, self.cfg
        candidates = candidates_of(ctx, data)
        if not candidates:
            return []
        if lighting in ("true", "truex"):
            envmap = EnvmapSpec(self.store.resolve(self.envmaps[spec.envmap.envmap_id]), scale=spec.envmap.scale,
                                rotation=spec.envmap.rotation)
            lit = truth if lighting == "truex" else data.rank1()
            materials = [ctx.spec(lit.get(p.index)) for p in scene.mesh.parts]
            ((_, exposure, _),) = sc.score_lighting(ctx.frame, scene, materials, [(None, envmap)], ctx.weights,
                                                    cfg.erode)
        elif lighting == "joint":  # the best few lighting hypotheses, each judged by its selection's joint cost
            envmap, exposure = self._joint_lighting(scene, data, candidates)
        else:  # estx: the true materials light the search (what the library of envmaps can do)
            lit_data = data if lighting == "est" else dataclasses.replace(data, rows={
                i: [m.Assignment(material_id=truth[i])] for i in data.rows if i in truth})
            light = lighting_estimate(ctx, lit_data)
            envmap = ctx.light_envmap(light)
            exposure = float(light["exposure"])
        renders = sc.render_candidates(ctx.frame, scene, data.rank1(), candidates, ctx.spec, envmap)
        grid = (1.0,) if lighting == "truex" else sc.exposure_grid(cfg.exposure_stops)  # truex: kept as it is
        if self.wb_step:  # every exposure also at each white balance of a 3 x 3 grid (red and blue gains)
            grid = [f * gains for f in grid for gains in white_balances(self.wb_step)]
        measured, exposures, _ = sc.profiled_terms(renders, scene, candidates, exposure, ctx.weights,
                                                   ctx.prior_weight, grid, cfg.erode)
        shift = {(i, mid): abs(float(np.log2(np.mean(e) / exposure))) for i, by in exposures.items()
                 for mid, e in by.items()} if self.probe == "shift" else {}
        extra = (shift if self.probe == "shift" else
                 probe_terms(self.probe, scene, renders, exposure, cfg.erode, self.embed, self.sigma)
                 if self.probe else {})
        cases = []
        for index, options in sorted(candidates.items()):
            ids = [c.material_id for c in options]
            rows = {c.material_id: t if self.probe is None else np.append(t, extra.get((index, c.material_id), np.nan))
                    for c in options if (t := measured.get(index, {}).get(c.material_id)) is not None}
            if truth[index] not in ids or not rows:
                continue
            fill = np.nanmean(np.array(list(rows.values())), axis=0)  # unmeasured: the mean, as the stage fills it
            features = np.array([[*np.where(np.isnan(r := rows.get(c.material_id, fill)), fill, r), c.prior_cost]
                                 for c in options])
            cases.append(cal.Case(features, ids.index(truth[index]), group=f"{row.kind}/{row.key}"))
            self.records.append({"group": f"{row.kind}/{row.key}", "part": index, "candidates": ids,
                                 "substances": [ctx.material_substance.get(i, "") for i in ids],
                                 "truth": ids.index(truth[index]), "features": features.round(5).tolist(),
                                 "pixels": int(scene.masks[index].sum())})
        return cases


def summary(cases: list[cal.Case], cfg: Any, terms: tuple[str, ...]) -> dict[str, Any]:
    """Held-out figures of the fitted cost, and each term alone (in-sample temperature: for comparison only)."""
    alone = {}
    for j, name in enumerate(terms):
        w = np.zeros(len(terms))
        w[j] = 1.0
        s = cal.score(w / cal.fit_temperature(cases, w), cases)
        alone[name] = {"log_loss": round(s.log_loss, 4), "top1": round(s.top1, 4)}
    return {"held_out": fc.held_out(cases, cfg), "alone": alone,
            "mean_candidates": round(float(np.mean([c.features.shape[0] for c in cases])), 2)}


def with_terms(terms: tuple[str, ...], hand_set: Callable[[Any], np.ndarray]) -> None:
    """Make the calibration's fit and its hand-set centre take the probe's column (before `prior`)."""
    at = len(cal.TERMS) - 1  # the probe sits before `prior`
    cal.TERMS = terms
    if len(terms) > at + 1:
        fc.hand_set = lambda cfg: np.insert(hand_set(cfg), at, 0.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="small")
    parser.add_argument("--cases", type=int, default=None, help="validation renders (default: the profile's)")
    parser.add_argument("--conditions", default=";".join(DEFAULT_CONDITIONS), help="';'-separated conditions")
    parser.add_argument("--probe", choices=("embedding", "layout", "shift"), default=None)
    parser.add_argument("--layout-sigma", type=float, default=2.0)
    parser.add_argument("--set", action="append", default=[], help="profile override, e.g. fit.blur=1.0")
    parser.add_argument("--joint-top", type=int, default=3, help="hypotheses the `joint` lighting condition tries")
    parser.add_argument("--photo-size", type=int, default=0,
                        help="degrade the photo at this size (an exemplar's, e.g. 320) instead of the render's")
    parser.add_argument("--wb-step", type=float, default=0.0,
                        help="also profile a white balance: red and blue gains +-this (3 x 3 grid per exposure)")
    parser.add_argument("--dump", action="store_true", help="also write each case (candidates, features) per condition")
    args = parser.parse_args()
    settings = get_settings()
    oracle = Oracle(settings, args.profile, args.set, args.probe, args.layout_sigma)
    oracle.joint_top = args.joint_top
    oracle.wb_step = args.wb_step
    oracle.photo_size = args.photo_size
    terms = (*cal.TERMS[:-1], args.probe, "prior") if args.probe else cal.TERMS
    with_terms(terms, fc.hand_set)
    count = args.cases if args.cases is not None else oracle.cfg.calibration_cases
    with session_scope(settings.resolved_database_url) as session:
        renders = fc.validation_renders(session, count, settings.seed)
        session.expunge_all()
    results: dict[str, Any] = {"profile": args.profile, "overrides": args.set, "probe": args.probe,
                               "renders": len(renders), "blur": oracle.cfg.blur, "conditions": {}}
    for condition in args.conditions.split(";"):
        cases: list[cal.Case] = []
        for row in renders:
            try:
                cases += oracle.cases(row, condition)
            except (ValueError, OSError) as exc:
                print(f"{row.kind}/{row.key}: skipped ({exc})")
        results["conditions"][condition] = summary(cases, oracle.cfg, terms)
        if args.dump:
            results.setdefault("cases", {})[condition] = oracle.records
        oracle.records = []
        print(condition, json.dumps(results["conditions"][condition]), flush=True)
    out = results_dir(settings, "fit_oracle")
    out.mkdir(parents=True, exist_ok=True)
    name = "results.json" if not args.probe else f"results-{args.probe}.json"
    (out / name).write_text(json.dumps(results, indent=2))
    print(f"written {out / name}")


if __name__ == "__main__":
    main()
