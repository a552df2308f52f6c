"""Is the classifier's renders-to-photos gap the training renders' sampling noise?

Training renders are path traced at the classifier's resolution with few samples (medium: 128 px,
32 spp), so they carry per-pixel Monte Carlo noise; a product photo (and a demo exemplar: 320 px,
48 spp, downsampled to 128 for the classifier, ~10x the samples per output pixel) does not. A
network trained on noisy images can read the noise as part of the texture. This bench re-renders
validation training renders *from their own rows* (same shape, camera, materials, UV transforms,
envmap, seed) at higher quality and runs the material head on the exact material regions of each
version, so the only difference is the sampling:

  - as stored:         the rendering row's image (e.g. 128 px, 32 spp),
  - clean, same size:  re-rendered at the same size with `--spp-clean` samples,
  - photo-like:        re-rendered at `--photo-size` px with `--photo-spp` (the demo exemplars'
                       settings by default) and shrunk by the classifier's own area filter,
with `--conditions` also
  - photo-like + degradation: the same, imaged as the demo images an exemplar (exposure, white
                       balance, blur, sensor noise, JPEG: `demo.exemplars.degrade`),
  - framed like a photo: the stored quality, the camera moved so the shape fills 80-94% of the frame,
  - one material per substance: the stored quality, parts of a substance sharing its first part's
                       material (as products often are; its regions are unions of parts, so this
                       row is not paired with the others),
and with `--heldout-envmaps DIR` (the demo's `groundtruth/envmaps`, the studios only exemplars are lit by)
  - held-out studio:   the stored quality, lit by one of those envmaps instead (same scale and rotation),
  - with `--conditions` also photo-like + degradation under such a studio (everything an exemplar has
                       but its shape's material arrangement).

Only validation renders (held-out shapes and envmaps) are used, never exemplars, so whatever this
shows may be acted on without tuning on the test set. Prints a table and writes
bench/results/render_quality_gap.json.

    PHOTOSHAPE_DATA_ROOT=... python bench/render_quality_gap.py [--count 120] [--classifier ID]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import sqlalchemy as sa

from photoshape_flow.classify.dataset import load_label_map, load_rgb
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.pipeline.training import load_material_classifier
from photoshape_flow.pipeline.training_renders import _Inputs
from photoshape_flow.store import BlobStore
from photoshape_flow.synth.example import render_training_example
from photoshape_flow.synth.spec import RenderSpec

DEGRADED = "photo-like + photo degradation + JPEG"


def regions(ids: np.ndarray, known: set[int]) -> list[tuple[int, np.ndarray]]:
    """Material regions of a label map large enough for the classifier (0.5% of the image, as in training)."""
    minimum = int(np.ceil(0.005 * ids.size))
    values, counts = np.unique(ids, return_counts=True)
    return [(int(v), ids == v) for v, c in zip(values, counts, strict=True)
            if v != 0 and c >= minimum and int(v) in known]


def score(clf, rgb: np.ndarray, found: list[tuple[int, np.ndarray]]) -> list[tuple[int, int]]:
    probs, _ = clf.predict(rgb, [mask for _, mask in found])
    ranked = clf.top_k(probs, None, k=5, weight_by_substance=False)
    return [(int(r[0].material_id == mid), int(mid in [x.material_id for x in r])) for r, (mid, _) in
            zip(ranked, found, strict=True)]


def framed(spec: RenderSpec, mesh) -> RenderSpec:
    """The spec with its camera moved so the shape fills 80-94% of the frame, as a product photo does."""
    from photoshape_flow.demo.exemplars import framing_distance

    rng = np.random.default_rng(spec.seed % 2**32)
    cam = spec.camera
    vertices = np.concatenate([p.vertices for p in mesh.parts])
    distance = framing_distance(vertices, cam.azimuth, cam.elevation, cam.fov, float(rng.uniform(0.8, 0.94)))
    return dataclasses.replace(spec, camera=dataclasses.replace(cam, distance=distance))


def shared(spec: RenderSpec) -> RenderSpec:
    """The spec with every part of a substance given that substance's first material, as products often are."""
    first: dict[str, int] = {}
    parts = []
    for part in spec.parts:
        material = first.setdefault(part.substance, part.material_id)
        parts.append(dataclasses.replace(part, material_id=material))
    return dataclasses.replace(spec, parts=parts)


def photo_with_parts(renderer, mesh, spec: RenderSpec, material_specs, envmap_spec, size: int, spp: int):
    """(sRGB uint8, part-ID map, foreground) of `spec` imaged like a demo exemplar: rendered on
    transparent at photo size, then the demo's photo degradation (exposure, white balance, blur,
    noise) and JPEG."""
    import cv2

    from photoshape_flow.demo.exemplars import degrade, encode_jpeg, sample_degradation
    from photoshape_flow.synth.example import build_scene_inputs

    camera, materials, uv_transforms, envmap = build_scene_inputs(mesh, spec, material_specs, envmap_spec)
    result = renderer.beauty(mesh, materials, camera, envmap, size=size, spp=spp, uv_transforms=uv_transforms,
                             background="transparent", seed=int(spec.seed % (2**31 - 1)))
    params = sample_degradation(np.random.default_rng(spec.seed % 2**32))
    jpeg = encode_jpeg(degrade(result.hdr, result.alpha, params), params["jpeg_quality"])
    rgb = cv2.cvtColor(cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    part_ids = np.asarray(renderer.part_ids(mesh, camera, size=size))
    return rgb, part_ids, np.asarray(result.alpha) >= 0.5


def photo(renderer, mesh, spec: RenderSpec, material_specs, envmap_spec, size: int, spp: int):
    """(sRGB uint8, material-id map) of `spec` imaged like a demo exemplar (`photo_with_parts`)."""
    from photoshape_flow.synth.example import label_maps

    rgb, part_ids, _ = photo_with_parts(renderer, mesh, spec, material_specs, envmap_spec, size, spp)
    material_ids, _ = label_maps(part_ids, spec)
    return rgb, material_ids


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=120, help="validation renders to re-render")
    parser.add_argument("--classifier", type=int, default=None)
    parser.add_argument("--kind", default="training", help="rendering kind (round) to draw from")
    parser.add_argument("--spp-clean", type=int, default=256)
    parser.add_argument("--photo-size", type=int, default=320)
    parser.add_argument("--photo-spp", type=int, default=48)
    parser.add_argument("--conditions", action="store_true",
                        help="also: photo-like with the demo exemplars' photo degradation and JPEG; and, at the "
                             "stored quality, the camera framed like a product photo and one material per substance")
    parser.add_argument("--heldout-envmaps", type=Path, default=None,
                        help="a folder of envmaps (.hdr/.exr) to re-light each render with, at the stored quality")
    args = parser.parse_args()

    from photoshape_flow.render import Renderer

    settings = get_settings()
    store = BlobStore(settings.blob_root)
    row, clf = load_material_classifier(args.classifier, settings=settings)
    known = set(clf.materials)
    renderer = Renderer(resolve=store.resolve)
    inputs = _Inputs(store=store)
    heldout = sorted(p for ext in ("*.hdr", "*.exr") for p in args.heldout_envmaps.glob(ext)) \
        if args.heldout_envmaps else []
    results: dict[str, list[tuple[int, int]]] = {"as stored": [], "clean, same size": [], "photo-like": []}
    if args.conditions:
        results[DEGRADED] = []
    paired = list(results)
    seconds: dict[str, float] = {"clean, same size": 0.0, "photo-like": 0.0}
    stored_quality = (0, 0)
    with session_scope() as session:
        rows = session.execute(
            sa.select(m.Rendering).where(m.Rendering.kind == args.kind, m.Rendering.split == "val",
                                         m.Rendering.status == "ok").order_by(m.Rendering.key)
        ).scalars().all()
        step = max(1, len(rows) // max(1, args.count))
        picked = rows[::step][: args.count]
        for rendering in picked:
            params = dict(rendering.params)
            size, stored_spp = int(params.pop("size")), int(params.pop("spp"))
            spec = RenderSpec.from_dict(params)
            inputs.load(session, spec)
            stored_ids = load_label_map(store.path(rendering.blobs["material_ids"]))
            found = regions(stored_ids, known)
            if not found:
                continue
            stored_quality = (size, stored_spp)
            scored = {"as stored": score(clf, load_rgb(store.path(rendering.blobs["beauty"])), found)}
            for name, (r_size, r_spp) in {"clean, same size": (size, args.spp_clean),
                                          "photo-like": (args.photo_size, args.photo_spp)}.items():
                started = time.perf_counter()
                example = render_training_example(renderer, inputs.mesh(spec.shape_id), spec,
                                                  inputs.material_specs(spec),
                                                  inputs.envmap_spec(spec.envmap.envmap_id), r_size, r_spp)
                seconds[name] += time.perf_counter() - started
                # the same regions on this render's own label map (same camera, maybe finer pixels)
                mine = [(mid, example.material_ids == mid) for mid, _ in found]
                if all(mask.any() for _, mask in mine):
                    scored[name] = score(clf, example.srgb, mine)
            if args.conditions:
                started = time.perf_counter()
                rgb, ids = photo(renderer, inputs.mesh(spec.shape_id), spec, inputs.material_specs(spec),
                                 inputs.envmap_spec(spec.envmap.envmap_id), args.photo_size, args.photo_spp)
                seconds[DEGRADED] = seconds.get(DEGRADED, 0.0) + time.perf_counter() - started
                mine = [(mid, ids == mid) for mid, _ in found]
                if all(mask.any() for _, mask in mine):
                    scored[DEGRADED] = score(clf, rgb, mine)
            if set(scored) == set(paired):  # paired: every version scores the same regions
                for name, hits in scored.items():
                    results[name] += hits
            if args.conditions:
                mesh = inputs.mesh(spec.shape_id)
                for name, variant in {"framed like a photo": framed(spec, mesh),
                                      "one material per substance": shared(spec)}.items():
                    started = time.perf_counter()
                    example = render_training_example(renderer, mesh, variant, inputs.material_specs(variant),
                                                      inputs.envmap_spec(spec.envmap.envmap_id), size, stored_spp)
                    seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - started
                    own = regions(example.material_ids, known)
                    if own:
                        results.setdefault(name, []).extend(score(clf, example.srgb, own))
            if heldout:
                from photoshape_flow.render import EnvmapSpec

                # the studios in turn, indexed by the regions scored so far (how the figures in
                # docs/results.md were drawn; any spread over the few studios would do)
                lit = EnvmapSpec(path=heldout[len(results.get("held-out studio", [])) % len(heldout)])
                started = time.perf_counter()
                example = render_training_example(renderer, inputs.mesh(spec.shape_id), spec,
                                                  inputs.material_specs(spec), lit, size, stored_spp)
                seconds["held-out studio"] = seconds.get("held-out studio", 0.0) + time.perf_counter() - started
                own = regions(example.material_ids, known)
                if own:
                    results.setdefault("held-out studio", []).extend(score(clf, example.srgb, own))
                if args.conditions:  # both at once: imaged like an exemplar and lit by its studios
                    rgb, ids = photo(renderer, inputs.mesh(spec.shape_id), spec, inputs.material_specs(spec), lit,
                                     args.photo_size, args.photo_spp)
                    own = regions(ids, known)
                    if own:
                        results.setdefault(f"{DEGRADED}, held-out studio", []).extend(score(clf, rgb, own))
    summary = {
        "classifier": {"id": row.id, "name": row.name, "metrics": {k: (row.metrics or {}).get(k)
                                                                   for k in ("mtl@1", "mtl@5")}},
        "renders": len(picked),
        "stored_quality": {"size": stored_quality[0], "spp": stored_quality[1]} if picked else None,
        "settings": vars(args),
        "results": {name: {"regions": len(v), "top1": float(np.mean([h[0] for h in v])) if v else None,
                           "top5": float(np.mean([h[1] for h in v])) if v else None,
                           "render_seconds": seconds.get(name)} for name, v in results.items()},
    }
    print(f"classifier {row.name} (id {row.id}), {len(picked)} validation renders of kind {args.kind}, stored at "
          f"{stored_quality[0]} px / {stored_quality[1]} spp")
    print("| version | regions | top-1 | top-5 | render s |\n|---|---:|---:|---:|---:|")
    for name, r in summary["results"].items():
        secs = "" if r["render_seconds"] is None else f"{r['render_seconds']:.0f}"
        print(f"| {name} | {r['regions']} | {r['top1']:.3f} | {r['top5']:.3f} | {secs} |")
    out = Path(__file__).parent / "results" / "render_quality_gap.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(summary, indent=2, default=str))


if __name__ == "__main__":
    main()
