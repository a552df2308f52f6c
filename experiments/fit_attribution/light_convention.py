"""Does our renderer, under the truth's HDRI, reproduce a world photo's shading as the HDRI is given or mirrored?

    PHOTOSHAPE_DATA_ROOT=/work/w-base python -m experiments.fit_attribution.light_convention \\
        --groundtruth ../second-world/groundtruth.json --envmap-dir ../shared/data/envmaps --pairs 16

The `gt-light` condition of `run.py` trusts the world's lighting convention (`lighting.rotation` in the
project's frame, `experiments/second_world/scenes.project_rotation`). A horizontally mirrored HDRI is
no rotation of the given one: if the world's renderer read the lat-long mirrored, the "true light"
would be wrong, most of all for mirror-like metals. For each own-shape pair (the pair's camera and
part map, every part in its true library material) this renders the shape under the truth's HDRI at 24
turns, as given and mirrored, and at the truth's own turn, and scores each render by the correlation
of blurred log luminance with the photo inside both silhouettes (albedo is the same in both
hypotheses, so the shading decides). Read-only. Output: `<data root>/experiments/fit_attribution/
light_convention.json`.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from experiments.common import results_dir
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.evaluation.groundtruth import read_groundtruth_file
from photoshape_flow.fitting.context import FitContext, load_pair
from photoshape_flow.networks.classifier_rows import resolve_classifier
from photoshape_flow.profiles import resolve_profile
from photoshape_flow.render import EnvmapSpec
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.store import BlobStore

TURNS = 24


def mirrored(path: Path, folder: Path) -> Path:
    """The HDRI flipped left to right (azimuth phi -> -phi), written once under `folder`."""
    out = folder / path.name
    if not out.exists():
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise SystemExit(f"{path}: not a readable HDR image")
        cv2.imwrite(str(out), np.ascontiguousarray(image[:, ::-1]))
    return out


def shading_agreement(render: np.ndarray, photo: np.ndarray, foreground: np.ndarray) -> float:
    """Correlation of blurred log luminance of a render (RGBA, linear) and the photo inside both silhouettes."""
    inside = (render[..., 3] > 0.95) & foreground
    inside = cv2.erode(inside.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    if inside.sum() < 50:
        return float("nan")
    rendered = np.log(cv2.GaussianBlur(render[..., :3].mean(-1), (0, 0), 1.5) + 1e-3)[inside]
    seen = np.log(cv2.GaussianBlur(photo.mean(-1), (0, 0), 1.5) + 1e-3)[inside]
    return float(np.corrcoef(rendered, seen)[0, 1])


def agreement(ctx: FitContext, scene: Any, materials: list[Any], hdri: Path, scale: float, rotation: float) -> float:
    """`shading_agreement` of the scene's shape rendered under `hdri` at a turn with the scene's photo."""
    render = scene.render(ctx.frame, materials, EnvmapSpec(hdri, scale=scale, rotation=rotation))
    foreground = scene.photo_linear.mean(-1) < 0.9 * float(np.mean(scene.background))
    return shading_agreement(render, scene.photo_linear, foreground)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--groundtruth", type=Path, required=True)
    parser.add_argument("--envmap-dir", type=Path, required=True, help="where lighting.envmap names are found")
    parser.add_argument("--source", default="second-world")
    parser.add_argument("--pairs", type=int, default=16)
    args = parser.parse_args()
    settings = get_settings()
    out = results_dir(settings, "fit_attribution")
    flipped = out / "mirrored-envmaps"
    flipped.mkdir(parents=True, exist_ok=True)
    cfg = replace(resolve_profile("small", []).profile.fit, size=128, spp=32)
    rows: list[dict[str, Any]] = []
    with Session(sa.create_engine(settings.resolved_database_url)) as session:  # read-only
        ctx = FitContext(session, BlobStore(settings.blob_root), resolve_classifier(session), cfg)
        by_name = {mat.name: mat.id for mat in ctx.material_rows.values()}
        truths = match_groundtruth(session, read_groundtruth_file(args.groundtruth), args.source).truths
        shapes = {(s.source, s.source_id): s.id for s in session.execute(sa.select(m.Shape)).scalars()}
        pairs = session.execute(sa.select(m.Pair).where(m.Pair.exemplar_id.in_(list(truths)), ~m.Pair.exclude)
                                .order_by(m.Pair.id)).scalars().all()
        for pair in pairs:
            truth = truths[pair.exemplar_id]
            own = shapes.get((truth.shape_ref.source, truth.shape_ref.source_id)) == pair.shape_id
            if not own or truth.lighting is None or len(rows) >= args.pairs:
                continue
            try:
                data = load_pair(session, ctx, pair)
            except ValueError:
                continue
            names = dict(session.execute(sa.select(m.Part.index, m.Part.name)
                                         .where(m.Part.shape_id == pair.shape_id)).all())
            materials = [ctx.spec(by_name.get(truth.parts[names[p.index]].material))
                         if names.get(p.index) in truth.parts else None for p in data.scene.mesh.parts]
            path = args.envmap_dir / Path(truth.lighting.envmap).name
            row: dict[str, Any] = {"exemplar": session.get(m.Exemplar, pair.exemplar_id).source_id,
                                   "envmap": path.name, "truth_turn": round(math.degrees(truth.lighting.rotation))}
            for label, hdri in (("given", path), ("mirrored", mirrored(path, flipped))):
                scores = [agreement(ctx, data.scene, materials, hdri, truth.lighting.scale, 2 * math.pi * k / TURNS)
                          for k in range(TURNS)]
                best = int(np.nanargmax(scores))
                row[label] = {"agreement": round(scores[best], 3), "turn": round(360 * best / TURNS)}
            row["truth"] = round(agreement(ctx, data.scene, materials, path, truth.lighting.scale,
                                           truth.lighting.rotation), 3)
            rows.append(row)
            print(row, flush=True)
        session.rollback()
    given = np.array([r["given"]["agreement"] for r in rows])
    flip = np.array([r["mirrored"]["agreement"] for r in rows])
    at_truth = np.array([r["truth"] for r in rows])
    summary = {"pairs": len(rows), "given_best": float(np.nanmean(given)), "mirrored_best": float(np.nanmean(flip)),
               "truth_turn": float(np.nanmean(at_truth)), "mirrored_better": int((flip > given).sum())}
    print(summary)
    (out / "light_convention.json").write_text(json.dumps({"summary": summary, "pairs": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
