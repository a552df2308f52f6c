"""Where does `fit` lose? Its selection re-run with the ground truth's lighting and part mask.

    python -m experiments.fit_attribution.run --profile small
    python -m experiments.fit_attribution.run --profile small --groundtruth WORLD/groundtruth.json \\
        --envmap-dir ../shared/data/envmaps          # where `lighting.envmap` names, not paths, are found

For every pair whose shape is the exemplar's true one, the fit selection (no refinement) runs four
times, each on the same parts and candidates' source (the stored classifier ranking, the fitted
weights of the classifier's calibration):

    fit        the stage as it runs: the exemplar's estimated lighting, the CRF part map
    gt-light   the truth's envmap, rotation and scale instead of the estimate (exposure re-solved)
    gt-envmap  the truth's envmap file, its rotation and exposure searched as the stage searches its own
    gt-mask    the photo's part regions from the truth's part mask instead of the CRF map
    gt-both    both
    gt-camera  the candidates rendered at the truth's camera, not the pair's (the pose error removed)
    gt-camera-light  that and the truth's light; gt-all: camera, light and part mask (-distance: no prior)
    gt-both-distance  both, ranked by the rendered comparison alone (no ranking prior): what the
               distance itself knows
    fit-distance      the stage's light and part map, ranked without the prior: what the prior adds

and the table gives material top-1 (also per true substance) and substance accuracy per scored part (a part scored as
`photoshape eval` scores it, against the CRF map) with 95% bootstrap intervals over exemplars, the
classifier's rank-1 on the same parts, and how often the true material is among the candidates at
all (the ceiling any distance can reach). Gains of gt-light / gt-mask over fit attribute misses to
lighting / alignment; what gt-both still misses belongs to the distance and the candidates.
Read-only: nothing is written to the database. Output:
`<data root>/experiments/fit_attribution/results.json`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from experiments.common import results_dir
from photoshape_flow.align.partmap import resize_labels
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.evaluation.bootstrap import difference_interval, mean_interval
from photoshape_flow.evaluation.groundtruth import TruthEntry, read_groundtruth_file
from photoshape_flow.fit.appearance import erode
from photoshape_flow.fit.scene import FitScene, estimate_lighting
from photoshape_flow.fit.select import rank_candidates
from photoshape_flow.fitting.calibration import ensure_calibration
from photoshape_flow.fitting.context import FitContext, PairData, load_pair
from photoshape_flow.fitting.fit import candidates_of, exemplar_lighting, select_materials
from photoshape_flow.networks.classifier_rows import resolve_classifier
from photoshape_flow.profiles import resolve_profile
from photoshape_flow.recognition.inference import ALIGNMENT_METHOD
from photoshape_flow.render import Camera
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.scoring.truths import pair_truths, truth_labels
from photoshape_flow.store import BlobStore

CONDITIONS = ("fit", "fit-distance", "gt-light", "gt-envmap", "gt-mask", "gt-both", "gt-both-distance",
              "gt-camera", "gt-camera-light", "gt-all", "gt-all-distance")
Observations = dict[str, dict[str, dict[int, list[float]]]]  # condition -> figure -> exemplar -> values


def truth_part_map(truth: TruthEntry, exemplar: m.Exemplar, index_of: dict[str, int], size: int) -> np.ndarray | None:
    """The truth's part mask as the pair's part indices (-1 elsewhere) in the fit frame; None without a part mask.

    `truth_labels` crops it to the stored exemplar frame, its labels numbering the parts sorted by name."""
    if truth.mask is None or truth.mask.kind != "part":
        return None
    labels, _, _ = truth_labels(truth, exemplar)
    names = sorted({p.name for p in truth.pixel_truths().values()})
    lut = np.array([-1] + [index_of.get(n, -1) for n in names], np.int32)
    return resize_labels(lut[labels], size).astype(np.int32)


def truth_envmap(truth: TruthEntry, envmap_dir: Path | None) -> Any:
    """The truth's lighting as an envmap spec (None: no lighting, or its file cannot be found)."""
    from photoshape_flow.render import EnvmapSpec

    light = truth.lighting
    if light is None:
        return None
    tried = [light.path] if light.path is not None else []
    if envmap_dir is not None:  # a name, or a file the ground truth's folder does not hold
        name = Path(light.envmap).name
        tried += [envmap_dir / name, envmap_dir / f"{name}.hdr"]
    path = next((p for p in tried if p.is_file()), None)
    return None if path is None else EnvmapSpec(path, scale=light.scale, rotation=light.rotation)


def with_labels(ctx: FitContext, data: PairData, labels: np.ndarray, min_pixels: int = 12) -> PairData:
    """The pair's data with the photo's part regions taken from `labels` (same photo, frame and parts),
    eroded and size-filtered as `FitScene.from_photo` does with the CRF map."""
    scene = data.scene
    masks = {}
    for index, rows in data.rows.items():
        if rows and not rows[0].unobserved:
            region = erode(labels == index, ctx.cfg.erode)
            if int(region.sum()) >= min_pixels:
                masks[index] = region
    return PairData(data.pair, FitScene(scene.mesh, scene.camera, scene.photo_linear, scene.photo_lab, masks,
                                        scene.blur, scene.background, scene.features), data.rows, data.source_hash)


def with_camera(data: PairData, truth: TruthEntry) -> PairData | None:
    """The pair's data with the candidates rendered at the truth's camera instead of the pair's (the photo, its
    regions and the frame's crop rule unchanged): what the coarse pose costs the comparison."""
    if truth.camera is None or truth.camera.distance is None or truth.camera.fov is None:
        return None
    camera = Camera(truth.camera.azimuth, truth.camera.elevation, truth.camera.distance, truth.camera.fov)
    return PairData(data.pair, dataclasses.replace(data.scene, camera=camera), data.rows, data.source_hash)


def searched(ctx: FitContext, data: PairData, truth_env: Any) -> tuple[Any, float]:
    """The truth's envmap (its file and strength) at the rotation and exposure the stage's own search finds
    for it (`fit.rotations` azimuths, the ranking's first materials): separates "which light" from "how
    it is turned and exposed"."""
    from dataclasses import replace

    turned = {0: lambda rotation: replace(truth_env, rotation=rotation)}
    materials = [ctx.spec(data.rank1().get(p.index)) for p in data.scene.mesh.parts]
    best, scale, _, _ = estimate_lighting(ctx.frame, data.scene, materials, turned, ctx.cfg.rotations, ctx.weights,
                                          None, ctx.cfg.erode)
    return turned[0](best.rotation), scale


def winners(ctx: FitContext, data: PairData, light: dict[str, Any], envmap: Any,
            prior_weight: float | None = None) -> tuple[dict[int, int], dict]:
    """Each observed part's fit winner under the given lighting, and its candidates (`prior_weight`:
    the ranking prior's weight in the final order, default the calibration's)."""
    candidates = candidates_of(ctx, data)
    measured, _ = select_materials(ctx, data, candidates, light, envmap)
    weight = ctx.prior_weight if prior_weight is None else prior_weight
    return ({i: rank_candidates(c, measured.get(i, {}), weight)[0].candidate.material_id
             for i, c in candidates.items() if c}, candidates)


def score_pair(ctx: FitContext, session: Session, data: PairData, truth: TruthEntry, scored: dict[int, tuple],
               envmap_dir: Path | None, obs: Observations) -> None:
    """Every condition's winners on the pair's scored parts, added to `obs` under the exemplar."""
    exemplar = session.get(m.Exemplar, data.pair.exemplar_id)
    light, _ = exemplar_lighting(session, ctx, data)
    index_of = {p.name: p.index for p in session.execute(
        sa.select(m.Part).where(m.Part.shape_id == data.pair.shape_id)).scalars() if p.name}
    labels = truth_part_map(truth, exemplar, index_of, ctx.cfg.size)
    gt_data = with_labels(ctx, data, labels) if labels is not None else None
    gt_env = truth_envmap(truth, envmap_dir)
    # (data, envmap, starting exposure): the truth's light starts from exposure 1 (its scale is the
    # photo's); the truth's envmap at a searched rotation from the search's exposure; the rounds re-solve it
    runs: dict[str, tuple[PairData, Any, float]] = {"fit": (data, None, float(light.get("exposure", 1.0)))}
    runs["fit-distance"] = runs["fit"]
    distance_only = {"fit-distance", "gt-both-distance", "gt-all-distance"}
    if gt_env is not None:
        runs["gt-light"] = (data, gt_env, 1.0)
        runs["gt-envmap"] = (data, *searched(ctx, data, gt_env))
    if gt_data is not None:
        runs["gt-mask"] = (gt_data, None, float(light.get("exposure", 1.0)))
    if gt_env is not None and gt_data is not None:
        runs["gt-both"] = (gt_data, gt_env, 1.0)
        runs["gt-both-distance"] = runs["gt-both"]
    cam_data = with_camera(data, truth)
    if cam_data is not None:
        runs["gt-camera"] = (cam_data, None, float(light.get("exposure", 1.0)))
        if gt_env is not None:
            runs["gt-camera-light"] = (cam_data, gt_env, 1.0)
        if gt_env is not None and gt_data is not None:
            runs["gt-all"] = (with_camera(gt_data, truth), gt_env, 1.0)
            runs["gt-all-distance"] = runs["gt-all"]
    classifier_first = {i: rows[0].material_id for i, rows in data.rows.items() if rows}
    for name, (pair_data, envmap, exposure) in runs.items():
        chosen, candidates = winners(ctx, pair_data, {**light, "exposure": exposure}, envmap,
                                     0.0 if name in distance_only else None)
        for index, (material, substance) in scored.items():
            if index not in chosen:
                continue
            winner = chosen[index]
            figures = obs[name]
            figures["top1"][exemplar.id].append(float(ctx.material_rows[winner].name == material))
            figures[f"top1:{substance}"][exemplar.id].append(float(ctx.material_rows[winner].name == material))
            figures["substance"][exemplar.id].append(float(ctx.material_substance[winner] == substance))
            names = {ctx.material_rows[c.material_id].name for c in candidates.get(index, [])}
            figures["truth_in_candidates"][exemplar.id].append(float(material in names))
            if name == "fit":
                first = classifier_first.get(index)
                row = ctx.material_rows.get(first) if first is not None else None
                obs["classifier"]["top1"][exemplar.id].append(float(row is not None and row.name == material))
                obs["classifier"]["substance"][exemplar.id].append(
                    float(row is not None and row.substance == substance))


def measure(profile: str, overrides: list[str], groundtruth: Path, envmap_dir: Path | None,
            source: str | None) -> tuple[Observations, dict[str, Any]]:
    settings = get_settings()
    cfg = resolve_profile(profile, overrides).profile.fit
    store = BlobStore(settings.blob_root)
    engine = sa.create_engine(settings.resolved_database_url)
    obs: Observations = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    counts = defaultdict(int)
    with Session(engine) as session:  # never committed: the experiment writes nothing
        classifier = resolve_classifier(session)
        if classifier is None:
            raise SystemExit("no trained material classifier: run the pipeline through training first")
        ctx = FitContext(session, store, classifier, cfg)
        ctx.calibration = ensure_calibration(ctx, settings)
        truths = match_groundtruth(session, read_groundtruth_file(groundtruth), source).truths
        shapes = {(s.source, s.source_id): s.id for s in session.execute(sa.select(m.Shape)).scalars()}
        pairs = session.execute(
            sa.select(m.Pair, m.Alignment).join(m.Alignment, sa.and_(
                m.Alignment.pair_id == m.Pair.id, m.Alignment.method == ALIGNMENT_METHOD, m.Alignment.status == "ok"))
            .where(m.Pair.exemplar_id.in_(list(truths)), ~m.Pair.exclude).order_by(m.Pair.id)).all()
        for pair, alignment in pairs:
            truth = truths[pair.exemplar_id]
            if shapes.get((truth.shape_ref.source, truth.shape_ref.source_id)) != pair.shape_id:
                continue
            counts["own_shape_pairs"] += 1
            exemplar = session.get(m.Exemplar, pair.exemplar_id)
            scored = pair_truths(session, store, pair, exemplar, alignment, truth)
            try:
                data = load_pair(session, ctx, pair)
            except ValueError as exc:
                print(f"pair {pair.id}: skipped ({exc})")
                continue
            counts["lighting"] += truth_envmap(truth, envmap_dir) is not None
            counts["part_mask"] += truth.mask is not None and truth.mask.kind == "part"
            score_pair(ctx, session, data, truth, scored, envmap_dir, obs)
        session.rollback()
    return obs, dict(counts)


def table(obs: Observations) -> dict[str, dict[str, Any]]:
    """Each condition's means with intervals, and each condition minus `fit` (paired)."""
    out: dict[str, dict[str, Any]] = {}
    for name in ("classifier", *CONDITIONS):
        if name not in obs:
            continue
        row: dict[str, Any] = {}
        for figure, values in sorted(obs[name].items()):
            est = mean_interval(values)
            row[figure] = {"value": est.value, "low": est.low, "high": est.high, "count": est.count}
            if name != "fit" and figure in obs["fit"]:
                diff = difference_interval(values, obs["fit"][figure])
                row[f"{figure}_vs_fit"] = {"value": diff.value, "low": diff.low, "high": diff.high}
        out[name] = row
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="small")
    parser.add_argument("--set", dest="overrides", action="append", default=[], help="profile override (repeatable)")
    parser.add_argument("--groundtruth", type=Path, default=None, help="default: the demo's under the data root")
    parser.add_argument("--envmap-dir", type=Path, default=None, help="where lighting.envmap names are found")
    parser.add_argument("--source", default=None, help="only the exemplars of this source")
    parser.add_argument("--tag", default="", help="write results-TAG.json (arms of one data root side by side)")
    args = parser.parse_args()
    settings = get_settings()
    groundtruth = args.groundtruth or sorted(Path(settings.data_root).glob("demo/*/groundtruth.json"))[-1]
    start = time.perf_counter()
    obs, counts = measure(args.profile, args.overrides, groundtruth, args.envmap_dir, args.source)
    results = {"groundtruth": str(groundtruth), "profile": args.profile, "overrides": args.overrides,
               "counts": counts, "seconds": round(time.perf_counter() - start, 1), "table": table(obs)}
    for name, row in results["table"].items():
        cells = []
        for figure in ("top1", "substance", "truth_in_candidates"):
            if figure in row and row[figure]["value"] is not None:
                cell = row[figure]
                span = "" if cell["low"] is None else f" ({cell['low']:.2f}-{cell['high']:.2f})"
                delta = row.get(f"{figure}_vs_fit")
                vs = "" if not delta or delta["value"] is None else f" [{delta['value']:+.3f}]"
                cells.append(f"{figure} {cell['value']:.3f}{span}{vs} n={cell['count']}")
        print(f"{name:16s}", " | ".join(cells))
        by_substance = [f"{figure.split(':', 1)[1]} {cell['value']:.2f} n={cell['count']}"
                        for figure, cell in row.items()
                        if figure.startswith("top1:") and not figure.endswith("_vs_fit") and cell["value"] is not None]
        if by_substance:
            print(f"{'':16s}  top-1 by true substance: " + ", ".join(by_substance))
    print(counts, f"{results['seconds']} s")
    out = results_dir(settings, "fit_attribution")
    out.mkdir(parents=True, exist_ok=True)
    (out / (f"results-{args.tag}.json" if args.tag else "results.json")).write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
