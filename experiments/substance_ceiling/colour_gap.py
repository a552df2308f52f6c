"""Why colour reads the exemplars better than the validation renders: imaging steps and reference colours.

A part's colour evidence is its median CIELAB against its material's colour. On the small demo that
distance was 10.8 (median) on the exemplars and 25.4 on the photo-like validation renders that chose
the ranking's weights (D62). This walks a sample of validation renders (the fit calibration's sample,
`networks.validation_photos.validation_renders`) from the stored training image to the photo the
calibrations see, adding one difference from an exemplar per step, and reads the exemplars through
their ground-truth masks and their aligned part maps. Each step reports the median distance, the
median part share and colour matching's top-1 (nearest material colour among the enabled ones)
under four references: the preview colours, the previews relit to each part's true light (von Kries
on the envmaps' mean colours: an oracle), the nearest over the training lights, and each material's
median colour in the training split's renders (D63). Nothing is fitted.

    PHOTOSHAPE_DATA_ROOT=... python -m experiments.substance_ceiling.colour_gap [--count 100]
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa
from skimage import color

from photoshape_flow.classify.assignment import median_lab
from photoshape_flow.classify.color_prior import rendered_material_labs
from photoshape_flow.classify.dataset import frame_object
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.demo import newest_groundtruth
from photoshape_flow.evaluation.groundtruth import GroundTruthFile, read_groundtruth_file
from photoshape_flow.fit.validation import frame, misalign, resampled, sample_misalignment
from photoshape_flow.hashing import item_seed
from photoshape_flow.imaging.hdr import read_hdr
from photoshape_flow.imaging.io import load_label_map, load_rgb
from photoshape_flow.networks.calibrations import material_labs
from photoshape_flow.networks.validation_photos import as_photo, calibration_photo, exemplar_size, validation_renders
from photoshape_flow.recognition.bn_prior import clean_photo
from photoshape_flow.recognition.calibration import COLOR_LAB_RENDERS
from photoshape_flow.recognition.training import training_data
from photoshape_flow.store import BlobStore
from photoshape_flow.synth.spec import RenderSpec

from ..common import results_dir
from .records import exemplar_pairs, exemplar_truths

MIN_FRACTION = 0.005  # the classifier's smallest training region, as a share of the image
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


@dataclass(frozen=True)
class Region:
    """One scored region: its median CIELAB, true material, share of the image and the light it was seen under."""

    lab: np.ndarray
    material: int
    share: float
    light: str


def envmap_tint(hdr: np.ndarray) -> np.ndarray:
    """An envmap's mean colour over the sphere (rows weighted by solid angle), scaled to unit luminance."""
    rgb = np.asarray(hdr, np.float64)[..., :3]
    weights = np.cos((np.arange(rgb.shape[0]) + 0.5) / rgb.shape[0] * np.pi - np.pi / 2)
    mean = (rgb * weights[:, None, None]).sum((0, 1)) / (weights.sum() * rgb.shape[1])
    return mean / float(mean @ LUMINANCE)


def relit(lab: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """A CIELAB colour seen under a light whose colour differs by linear-RGB `gains` (von Kries)."""
    srgb = np.clip(color.lab2rgb(np.asarray(lab, np.float64).reshape(1, 1, 3)), 0, 1)
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4) * gains
    linear = np.clip(linear, 0, 1)
    srgb = np.where(linear <= 0.0031308, linear * 12.92, 1.055 * linear ** (1 / 2.4) - 0.055)
    return color.rgb2lab(srgb).reshape(3)


def regions(rgb: np.ndarray, labels: np.ndarray, truth: dict[int, int | None], known: set[int], light: str,
            min_fraction: float = MIN_FRACTION) -> list[Region]:
    """Every labelled region of `rgb` of at least `min_fraction` whose true material has a colour."""
    out = []
    for value in np.unique(labels):
        mid = truth.get(int(value))
        mask = labels == value
        if value == 0 or mid not in known or mask.mean() < min_fraction:
            continue
        lab = median_lab(rgb, mask)
        if lab is not None:
            out.append(Region(np.asarray(lab, np.float64), int(mid), float(mask.mean()), light))
    return out


def summary(rows: list[Region], references: Callable[[str], dict[int, np.ndarray] | list[dict[int, np.ndarray]]]
            ) -> dict[str, Any]:
    """Median distance to the true colour, median share and colour matching's top-1 under `references`.

    `references(light)` gives the material colours to match against for a region seen under `light`;
    a list of them is a set of candidate lights, and each material counts at its nearest.
    """
    if not rows:
        return {"regions": 0}
    distances, hits = [], []
    for r in rows:
        tables = references(r.light)
        tables = tables if isinstance(tables, list) else [tables]
        ids = np.array(sorted(tables[0]))
        d = np.min([np.linalg.norm(np.stack([t[i] for i in ids]) - r.lab[None], axis=1) for t in tables], axis=0)
        distances.append(float(d[ids == r.material][0]))
        hits.append(bool(ids[int(np.argmin(d))] == r.material))
    return {"regions": len(rows), "median_distance": round(float(np.median(distances)), 2),
            "median_share": round(float(np.median([r.share for r in rows])), 4),
            "colour_top1": round(float(np.mean(hits)), 3)}


def ladder(hdr: np.ndarray, ids: np.ndarray, size: int, seed: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(image, part ids) of one validation render at each imaging step, from the training image to the photo."""
    photo, misaligned, _ = calibration_photo(hdr, ids, size, size, np.random.default_rng(seed))
    rng = np.random.default_rng(seed)  # the same draws again, for the steps in between
    degrade_seed = int(rng.integers(2**31 - 1))
    error = sample_misalignment(rng, size)
    big_hdr, big_ids = resampled(hdr, ids, size)
    framed_clean, framed_ids, _ = frame(clean_photo(big_hdr, big_ids), big_ids, size)
    return {
        "1 render size, clean, exact parts": (clean_photo(hdr, ids), ids),
        "2 framed at the exemplar size, clean": (framed_clean, framed_ids),
        "3 framed, degraded like an exemplar": (photo, framed_ids),
        "4 framed, degraded, misaligned (fit calibration)": (photo, misaligned),
        "5 unframed, degraded, misaligned (BatchNorm prior, D62)": (as_photo(big_hdr, big_ids, degrade_seed),
                                                                    misalign(big_ids, error)),
    }


def validation_steps(session: Any, store: BlobStore, seed: int, count: int, known: set[int]
                     ) -> dict[str, list[Region]]:
    """Regions of a sample of validation renders at each imaging step."""
    size = exemplar_size(session) or 128
    steps: dict[str, list[Region]] = {}
    envmaps = {e.id: e.name for e in session.execute(sa.select(m.Envmap)).scalars()}
    for row in validation_renders(session, count, seed):
        spec = RenderSpec.from_dict(row.params)
        truth = spec.material_by_index()
        hdr, ids = store.load_image(row.blobs["hdr"]), store.load_image(row.blobs["part_ids"])
        ids = ids[..., 0] if ids.ndim == 3 else ids
        light = envmaps.get(spec.envmap.envmap_id, "?")
        for name, (rgb, labels) in ladder(hdr, ids, size, item_seed(seed, "colour-gap", row.kind, row.key)).items():
            steps.setdefault(name, []).extend(regions(rgb, labels, truth, known, light))
    return steps


def stored_training_images(session: Any, store: BlobStore, count: int, known: set[int], light_of: dict[str, str],
                           framing: Callable | None = None) -> list[Region]:
    """Regions of the stored validation training images (what the colour sigma is fit on), optionally framed."""
    out: list[Region] = []
    for item in training_data(session, store).val[:count]:
        ids, rgb = load_label_map(item.material_map), load_rgb(item.image)
        if framing is not None:
            rgb, ids = framing(rgb, ids)
        out += regions(rgb, ids, {int(v): int(v) for v in np.unique(ids)}, known, light_of.get(item.key, "?"))
    return out


def exemplar_steps(session: Any, store: BlobStore, known: set[int], gt: GroundTruthFile) -> dict[str, list[Region]]:
    """Exemplar regions through the ground-truth material masks and through the aligned part maps."""
    names = {mat.name: mat.id for mat in session.execute(sa.select(m.Material)).scalars()}
    lights = {eid: Path(entry.lighting.envmap).stem if entry.lighting else "?"
              for eid, entry in exemplar_truths(session, gt).items()}
    truth_masks: list[Region] = []
    aligned: list[Region] = []
    seen: set[int] = set()
    for ep in exemplar_pairs(session, store, gt):
        light = lights.get(ep.exemplar.id, "?")
        label_truth = {k + 1: names.get(name) for k, name in enumerate(ep.materials)}
        if ep.exemplar.id not in seen:  # one exemplar may be paired with several shapes
            seen.add(ep.exemplar.id)
            truth_masks += regions(ep.image, ep.labels, label_truth, known, light)
        part_truth = {}
        for part in ep.parts:
            mask = ep.part_map == part.index
            if mask.any():
                values, counts = np.unique(ep.labels[mask], return_counts=True)
                part_truth[part.index] = label_truth.get(int(values[np.argmax(counts)]))
        aligned += regions(ep.image, ep.part_map, part_truth, known, light)
    return {"exemplars, ground-truth masks": truth_masks, "exemplars, aligned part maps": aligned}


def light_tints(session: Any, store: BlobStore, gt_path: Path) -> tuple[dict[str, np.ndarray], str, list[str]]:
    """Tint of every light (ingested envmaps and the ground truth's), the preview light, the training lights."""
    rows = session.execute(sa.select(m.Envmap).where(m.Envmap.blob.is_not(None))
                           .order_by(m.Envmap.split, m.Envmap.name)).scalars().all()
    tints = {e.name: envmap_tint(store.load_image(e.blob)) for e in rows}
    for path in sorted((gt_path.parent / "groundtruth" / "envmaps").glob("*.hdr")):
        tints[path.stem] = envmap_tint(read_hdr(path))
    preview = rows[0].name  # `ingest.materials.render_material_previews` lights every preview with the first
    return tints, preview, [e.name for e in rows if e.split == "train"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=100, help="validation renders walked (default 100)")
    args = parser.parse_args()
    settings = get_settings()
    store = BlobStore(settings.blob_root)
    gt_path = newest_groundtruth(settings.data_root)
    with session_scope() as session:
        enabled = session.execute(sa.select(m.Material.id).where(m.Material.enabled)).scalars().all()
        labs = material_labs(session, store, enabled)
        known = set(labs)
        tints, preview, training_lights = light_tints(session, store, gt_path)
        rendered = rendered_material_labs(training_data(session, store).train, limit=COLOR_LAB_RENDERS)
        light_of = {f"{r.kind}/{r.key}": envmap for r, envmap in _render_lights(session)}
        steps = {"0 stored training images (the colour sigma's data)":
                     stored_training_images(session, store, 400, known, light_of),
                 "0b stored training images, framed":
                     stored_training_images(session, store, 400, known, light_of, framing=frame_object),
                 **validation_steps(session, store, settings.seed, args.count, known),
                 **exemplar_steps(session, store, known, read_groundtruth_file(gt_path))}

    def under(light: str) -> dict[int, np.ndarray]:
        gains = tints.get(light, tints[preview]) / tints[preview]
        return {i: relit(lab, gains) for i, lab in labs.items()}

    cache: dict[str, dict[int, np.ndarray]] = {}

    def cached(light: str) -> dict[int, np.ndarray]:
        if light not in cache:
            cache[light] = under(light)
        return cache[light]

    schemes: dict[str, Callable] = {
        f"preview colours (lit by {preview}, today)": lambda light: labs,
        "preview colours relit to the region's true light (oracle)": lambda light: cached(light),
        "nearest over the training lights": lambda light: [cached(t) for t in training_lights],
        "median colour in the training split's renders": lambda light: {**labs, **rendered},
    }
    result = {"lights": {k: np.round(v, 3).tolist() for k, v in tints.items()}, "preview": preview,
              "training_lights": training_lights,
              "schemes": {s: {k: summary(v, f) for k, v in steps.items()} for s, f in schemes.items()}}
    out = results_dir(settings, "substance_ceiling") / "colour_gap.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print("light tints (R, G, B at unit luminance):",
          ", ".join(f"{k} {np.round(v, 2).tolist()}" for k, v in tints.items()))
    for scheme, rows in result["schemes"].items():
        print(scheme)
        for name, s in rows.items():
            print(f"  {name:58s} " + "  ".join(f"{k} {v}" for k, v in s.items()))
    print(f"-> {out}")


def _render_lights(session: Any) -> list[tuple[Any, str]]:
    """(rendering row, its envmap's name) of every validation training render."""
    envmaps = {e.id: e.name for e in session.execute(sa.select(m.Envmap)).scalars()}
    rows = session.execute(sa.select(m.Rendering).where(m.Rendering.split == "val")).scalars().all()
    return [(r, envmaps.get(RenderSpec.from_dict(r.params).envmap.envmap_id, "?")) for r in rows if r.params]


if __name__ == "__main__":
    main()
