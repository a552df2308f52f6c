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
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from experiments.common import results_dir
from experiments.fit_attribution.true_scenes import TrueScene, fit_context, true_scenes
from photoshape_flow.config import get_settings
from photoshape_flow.fitting.context import FitContext
from photoshape_flow.render import EnvmapSpec

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


def agreement(ctx: FitContext, scene: TrueScene, light: EnvmapSpec) -> float:
    """`shading_agreement` of the pair's shape in its true materials under `light` with its photo."""
    fit_scene = scene.data.scene
    render = fit_scene.render(ctx.frame, scene.materials, light)
    foreground = fit_scene.photo_linear.mean(-1) < 0.9 * float(np.mean(fit_scene.background))
    return shading_agreement(render, fit_scene.photo_linear, foreground)


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
    rows: list[dict[str, Any]] = []
    with Session(sa.create_engine(settings.resolved_database_url)) as session:  # read-only
        ctx = fit_context(session, settings)
        for scene in true_scenes(session, ctx, args.groundtruth, args.source, args.envmap_dir):
            if len(rows) >= args.pairs:
                break
            light = scene.truth.lighting
            assert light is not None
            row: dict[str, Any] = {"exemplar": scene.exemplar.source_id, "envmap": scene.hdri.name,
                                   "truth_turn": round(math.degrees(light.rotation))}
            for label, hdri in (("given", scene.hdri), ("mirrored", mirrored(scene.hdri, flipped))):
                scores = [agreement(ctx, scene, scene.light(2 * math.pi * k / TURNS, hdri)) for k in range(TURNS)]
                best = int(np.nanargmax(scores))
                row[label] = {"agreement": round(scores[best], 3), "turn": round(360 * best / TURNS)}
            row["truth"] = round(agreement(ctx, scene, scene.light()), 3)
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
