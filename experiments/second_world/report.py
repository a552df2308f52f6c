"""Where the second world loses: the inference figures split by share, and the open-library colour error.

`photoshape eval --groundtruth DIR/groundtruth.json` gives every figure over the whole world. This
report splits the material figures by what makes an exemplar hard, so a miss can be attributed:

- shape in the collection vs held out (a retrieval that can only find a look-alike);
- library materials vs the open-library share (hue/roughness/scale variants never ingested; the truth
  names the variant's parent);

and, on the open-library share, the CIELAB Delta E (CIE76) between the mean albedo of each method's
rank-1 material and the mean albedo the photo really shows (`albedo_lab`, computed by the build with
the same `materials.mean_lab`). Every figure carries its 95% bootstrap interval over exemplars.

    PHOTOSHAPE_DATA_ROOT=/work/sw-run python -m experiments.second_world.report \\
        --groundtruth /work/second-world/groundtruth.json [--json out.json]

Read-only: it writes nothing to the database.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa

from experiments.second_world.materials import mean_lab
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.evaluation.bootstrap import mean_interval
from photoshape_flow.evaluation.groundtruth import read_groundtruth_file
from photoshape_flow.scoring.evaluate import inference_metrics, inference_observations
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.scoring.truths import pair_truths
from photoshape_flow.store import BlobStore

METRICS = ("material_top1", "material_top5", "substance_accuracy")


def shares(raw: dict[str, Any], truths: dict[int, Any]) -> dict[str, set[int]]:
    """Exemplar ids of each share, from the world's own keys (`open_library`, `in_collection`)."""
    by_stem = {e["source_id"]: e for e in raw["exemplars"]}
    out: dict[str, set[int]] = defaultdict(set)
    for eid, truth in truths.items():
        entry = by_stem.get(truth.stem, {})
        out["all"].add(eid)
        out["open library" if entry.get("open_library") else "library materials"].add(eid)
        out["shape in collection" if truth.in_collection else "shape held out"].add(eid)
    return dict(out)


def fmt(est: Any) -> str:
    if est is None or est.value is None:
        return "-"
    if est.low is None:
        return f"{est.value:.3f}"
    return f"{est.value:.3f} ({est.low:.2f}-{est.high:.2f})"


def share_tables(session: Any, store: BlobStore, truths: dict[int, Any], groups: dict[str, set[int]]) -> list[dict]:
    rows = []
    for share, ids in groups.items():
        subset = {k: v for k, v in truths.items() if k in ids}
        metrics = inference_metrics(inference_observations(session, store, subset, rerender_max_pairs=0,
                                                           relight_max_pairs=0))
        by = {(x.method, x.metric): x for x in metrics}
        for method in sorted({x.method for x in metrics}):
            row = {"share": share, "exemplars": len(ids), "method": method}
            for metric in METRICS:
                row[metric] = fmt(by.get((method, metric)))
                row[f"{metric}_n"] = by[(method, metric)].count if (method, metric) in by else 0
            rows.append(row)
    return rows


def albedo_delta_e(session: Any, store: BlobStore, raw: dict[str, Any], truths: dict[int, Any],
                   ids: set[int]) -> list[dict]:
    """Per method: Delta E between the rank-1 material's mean albedo and the shown albedo, per part."""
    by_stem = {e["source_id"]: e for e in raw["exemplars"]}
    shown: dict[int, dict[str, np.ndarray]] = {}  # exemplar -> truth material (the parent) -> shown Lab
    for eid in ids:
        labs: dict[str, list[list[float]]] = defaultdict(list)
        for part in by_stem[truths[eid].stem]["parts"].values():
            if part.get("albedo_lab"):
                labs[part["material"]].append(part["albedo_lab"])
        shown[eid] = {k: np.mean(v, axis=0) for k, v in labs.items()}
    material_lab: dict[int, np.ndarray] = {}
    for mat in session.execute(sa.select(m.Material)).scalars():
        albedo = (mat.maps or {}).get("albedo")
        if albedo and store.exists(albedo):
            material_lab[mat.id] = np.asarray(mean_lab(store.load_image(albedo)[..., :3]))
    obs: dict[str, dict[int, list[float]]] = defaultdict(lambda: defaultdict(list))
    rows = session.execute(
        sa.select(m.Assignment, m.Part.index, m.Pair, m.Alignment, m.Exemplar)
        .join(m.Part, m.Part.id == m.Assignment.part_id)
        .join(m.Pair, m.Pair.id == m.Assignment.pair_id)
        .join(m.Exemplar, m.Exemplar.id == m.Pair.exemplar_id)
        .join(m.Alignment, sa.and_(m.Alignment.pair_id == m.Pair.id, m.Alignment.method == "flow-crf",
                                   m.Alignment.status == "ok"))
        .where(m.Pair.exemplar_id.in_(list(ids)), ~m.Pair.exclude, m.Assignment.rank == 1)
    ).all()
    cache: dict[int, dict[int, tuple[str, str]]] = {}
    for a, part_index, pair, alignment, exemplar in rows:
        if pair.id not in cache:
            cache[pair.id] = pair_truths(session, store, pair, exemplar, alignment, truths[exemplar.id])
        truth = cache[pair.id].get(part_index)
        if truth is None or a.material_id not in material_lab or truth[0] not in shown[exemplar.id]:
            continue
        delta = float(np.linalg.norm(material_lab[a.material_id] - shown[exemplar.id][truth[0]]))
        obs[a.method_key][exemplar.id].append(delta)
        if a.refinement and a.refinement.get("tint"):  # the same parts before and after refinement
            tinted = tinted_lab(session, store, a.material_id, a.refinement["tint"])
            if tinted is not None:
                obs[f"{a.method_key} refined parts, before"][exemplar.id].append(delta)
                after = float(np.linalg.norm(tinted - shown[exemplar.id][truth[0]]))
                obs[f"{a.method_key} refined parts, after"][exemplar.id].append(after)
    return [{"method": k, "albedo_delta_e": fmt(mean_interval(v)), "parts": mean_interval(v).count}
            for k, v in sorted(obs.items())]


def tinted_lab(session: Any, store: BlobStore, material_id: int, tint: list[float]) -> np.ndarray | None:
    """Mean-albedo CIELAB of a material whose base colour is multiplied (linearly) by a refinement's tint."""
    albedo = (session.get(m.Material, material_id).maps or {}).get("albedo")
    if not albedo or not store.exists(albedo):
        return None
    srgb = store.load_image(albedo)[..., :3].astype(np.float64) / 255.0
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4) * np.asarray(tint, np.float64)
    back = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.clip(linear, 0, None) ** (1 / 2.4) - 0.055)
    return np.asarray(mean_lab((np.clip(back, 0, 1) * 255.0).round().astype(np.uint8)))


def markdown(rows: list[dict], columns: list[str]) -> str:
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(str(r.get(c, "")) for c in columns) + " |" for r in rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--groundtruth", type=Path, required=True)
    parser.add_argument("--source", default="second-world")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    settings = get_settings()
    store = BlobStore(settings.blob_root)
    raw = json.loads(args.groundtruth.read_text())
    gt = read_groundtruth_file(args.groundtruth)
    with session_scope(settings.resolved_database_url) as session:
        truths = match_groundtruth(session, gt, args.source).truths
        if not truths:
            print(f"{args.groundtruth}: no entry matches an ingested exemplar of source {args.source!r}",
                  file=sys.stderr)
            return 2
        groups = shares(raw, truths)
        table = share_tables(session, store, truths, groups)
        delta = albedo_delta_e(session, store, raw, truths, groups.get("open library", set()))
    print("## Material figures by share (95% bootstrap intervals over exemplars)\n")
    print(markdown(table, ["share", "exemplars", "method", *METRICS, "material_top1_n"]))
    print("\n## Open-library share: mean-albedo Delta E (CIE76) of the rank-1 material to the shown albedo\n")
    print(markdown(delta, ["method", "albedo_delta_e", "parts"]))
    if args.json:
        args.json.write_text(json.dumps({"shares": table, "albedo_delta_e": delta}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
