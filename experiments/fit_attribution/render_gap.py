"""How far our render of a part in its true material, under the truth's light, is from the world photo's part.

    PHOTOSHAPE_DATA_ROOT=/work/w-base python -m experiments.fit_attribution.render_gap \\
        --groundtruth ../second-world/groundtruth.json --envmap-dir ../shared/data/envmaps

For each own-shape pair: every part in its true library material, the truth's HDRI at its turn and
strength, the pair's camera, one exposure for the whole photo (`fit.lighting.exposure`), blended with
the photo's background and softened as fit compares (blur 1). Each part of the truth's part mask
inside the render's silhouette is compared by fit's own terms (`fit.appearance.terms`: colour,
contrast, gradient, each over its scale). Medians per true substance: the distance the true material
starts from, which every wrong candidate has to beat. Read-only. Output:
`<data root>/experiments/fit_attribution/render_gap.json`.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from experiments.common import results_dir
from experiments.fit_attribution.run import truth_part_map, with_camera
from experiments.fit_attribution.true_scenes import fit_context, true_scenes
from photoshape_flow.config import get_settings
from photoshape_flow.fit import lighting as lt
from photoshape_flow.fit.appearance import appearance, soften, terms, to_lab

MIN_PIXELS = 30


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--groundtruth", type=Path, required=True)
    parser.add_argument("--envmap-dir", type=Path, required=True, help="where lighting.envmap names are found")
    parser.add_argument("--source", default="second-world")
    parser.add_argument("--camera", choices=("pair", "truth"), default="pair",
                        help="render at the pair's camera (fit's) or at the truth's (the pose error removed)")
    args = parser.parse_args()
    settings = get_settings()
    gaps: dict[str, list[list[float]]] = defaultdict(list)
    with Session(sa.create_engine(settings.resolved_database_url)) as session:  # read-only
        ctx = fit_context(session, settings)
        blur = ctx.cfg.blur
        for scene in true_scenes(session, ctx, args.groundtruth, args.source, args.envmap_dir):
            truth, names, data = scene.truth, scene.names, scene.data
            labels = truth_part_map(truth, scene.exemplar, {name: index for index, name in names.items() if name},
                                    ctx.cfg.size)
            if labels is None:
                continue
            if args.camera == "truth":
                data = with_camera(data, truth)
                if data is None:
                    continue
            rgba = data.scene.render(ctx.frame, scene.materials, scene.light())
            alpha, photo = rgba[..., 3:4], data.scene.photo_linear
            masks = {i: mask for i in names if names[i] in truth.parts
                     and (mask := (labels == i) & (alpha[..., 0] > 0.95)).sum() >= MIN_PIXELS}
            rendered = {i: (rgba[..., :3][mask].mean(0), int(mask.sum())) for i, mask in masks.items()}
            seen = {i: (photo[mask].mean(0), int(mask.sum())) for i, mask in masks.items()}
            scale = lt.exposure(rendered, seen)
            shown = rgba[..., :3] * alpha * scale + (1.0 - alpha) * data.scene.background
            render_lab = to_lab(lt.exposed_srgb(soften(shown, blur), 1.0))
            photo_lab = to_lab(lt.exposed_srgb(soften(photo, blur), 1.0))
            for i, mask in masks.items():
                a, b = appearance(render_lab, mask), appearance(photo_lab, mask)
                if a is not None and b is not None:
                    gaps[truth.parts[names[i]].substance].append(
                        [*(float(v) for v in terms(a, b)[:3]), float(a.lab_mean[0] - b.lab_mean[0])])
        session.rollback()
    summary = {}
    print("true substance: parts, median colour / contrast / gradient term, median L* render - photo")
    for substance, rows in sorted(gaps.items()):
        x = np.array(rows)
        medians = np.median(x, axis=0)
        summary[substance] = {"parts": len(x), "colour": float(medians[0]), "contrast": float(medians[1]),
                              "gradient": float(medians[2]), "lightness": float(medians[3])}
        r = summary[substance]
        print(f"  {substance:8s} {r['parts']:3d}  {r['colour']:.2f} / {r['contrast']:.2f} / {r['gradient']:.2f}  "
              f"{r['lightness']:+.1f}")
    out = results_dir(settings, "fit_attribution")
    out.mkdir(parents=True, exist_ok=True)
    (out / f"render_gap_{args.camera}.json").write_text(json.dumps(summary, indent=2) + "\n")


if __name__ == "__main__":
    main()
