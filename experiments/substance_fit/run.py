"""Where does a substance network lose parts: fitting its own renders, new shapes and lights, photo
degradation, or the world?

    PHOTOSHAPE_DATA_ROOT=/work/w-base python -m experiments.substance_fit.run \\
        --groundtruth ../second-world/groundtruth.json --source second-world [--network ID]
    python -m experiments.substance_fit.run --compare A.json B.json
    ... run --with /work/other-root [--scales 1.0 0.8]   # an ensemble, several read scales

A substance network (the newest, or `--network`: the segmentation network or the part recogniser)
reads every part of four sets with the stage's own vote (`classify.substance_parts`), each part
against its true substance: the bootstrap renders it trained on, as it saw them (`train`); the
bootstrap renders held out by shape and envmap (`val`); the same held-out renders degraded and
framed like exemplars, their part maps misaligned (`val, photo-like`: `networks.validation_photos`);
and, with `--groundtruth`, the world's exemplars through their CRF maps, also split into the photos
showing collection materials and those showing only variants of them (`open_library`). The steps between the sets
attribute the loss: fitting, generalisation, degradation, the world. Per set: accuracy, small parts
(under `--small` of the map) and larger ones, recall per substance and the confusion matrix; reads
per photo are kept so that `--compare` pairs two networks over the same photos (B minus A, 95%
bootstrap interval over photos). `--with ROOT` (repeatable) adds the newest trained substance network
of another data root trained on the same renders (another seed, say): the members' probabilities are
averaged before the vote, an ensemble. `--scales` reads each photo at these multiples of the read
size and averages them too. Read-only; output `<data root>/experiments/substance_fit/network-ID.json`
(ID: the members' ids joined by `+`, then `@` and the scales when not 1).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa

from experiments.common import newest_substance_network, results_dir
from experiments.small_parts.run import read, vote, world_photos
from photoshape_flow.classify.substance_configs import read_side_of
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.evaluation.bootstrap import difference_interval
from photoshape_flow.hashing import item_seed
from photoshape_flow.networks.classifiers import load_substance_network
from photoshape_flow.networks.validation_photos import calibration_photo, exemplar_size
from photoshape_flow.recognition.substances import load_label_blob
from photoshape_flow.store import BlobStore
from photoshape_flow.synth.spec import RenderSpec
from photoshape_flow.vocab import SUBSTANCES

Read = tuple[str, str, str, float]  # photo, true substance, read substance, the part's share of its map
Photo = tuple[str, np.ndarray, np.ndarray, dict[int, str]]  # photo, RGB, part map, true substance per part


def summarise(reads: list[Read], small: float) -> dict[str, Any]:
    """Accuracy, small and larger parts, recall per true substance and the confusion (rows: truth)."""
    confusion = np.zeros((len(SUBSTANCES), len(SUBSTANCES)), np.int64)
    sizes: dict[str, list[bool]] = {"small": [], "larger": []}
    for _, truth, pick, share in reads:
        if truth in SUBSTANCES and pick in SUBSTANCES:
            confusion[SUBSTANCES.index(truth), SUBSTANCES.index(pick)] += 1
            sizes["small" if share < small else "larger"].append(truth == pick)
    totals = confusion.sum(1)
    return {
        "parts": int(confusion.sum()),
        "accuracy": float(np.trace(confusion) / max(1, confusion.sum())),
        **{f"{k}_parts": len(v) for k, v in sizes.items()},
        **{k: float(np.mean(v)) if v else None for k, v in sizes.items()},
        "recall": {s: float(confusion[i, i] / totals[i]) for i, s in enumerate(SUBSTANCES) if totals[i]},
        "confusion": confusion.tolist(),
    }


def by_photo(reads: list[Read]) -> dict[str, list[float]]:
    """Photo -> hit (1) or miss (0) per part: what `--compare` pairs."""
    out: dict[str, list[float]] = {}
    for photo, truth, pick, _ in reads:
        out.setdefault(photo, []).append(float(truth == pick))
    return out


def bootstrap_photos(session: Any, store: BlobStore, split: str, photo_like: bool, seed: int) -> Iterator[Photo]:
    """The bootstrap renders of one split, as trained (`beauty`) or degraded like exemplars."""
    substance = dict(session.execute(sa.select(m.Material.id, m.Material.substance)).all())
    side = exemplar_size(session) or 320
    rows = session.execute(sa.select(m.Rendering).where(
        m.Rendering.kind == "bootstrap", m.Rendering.split == split, m.Rendering.status == "ok",
        ~m.Rendering.exclude).order_by(m.Rendering.key)).scalars().all()
    for row in rows:
        truth = {i: substance[mid] for i, mid in RenderSpec.from_dict(row.params).material_by_index().items()
                 if mid in substance}
        ids = load_label_blob(store, row.blobs["part_ids"])
        ids = ids[..., 0] if ids.ndim == 3 else ids
        if not photo_like:
            yield row.key, store.load_image(row.blobs["beauty"])[..., :3], ids.astype(np.int64), truth
            continue
        rng = np.random.default_rng(item_seed(seed, "substance-fit", row.kind, row.key))
        rgb, labels, _ = calibration_photo(store.load_image(row.blobs["hdr"]), ids, side, side, rng)
        yield row.key, rgb, labels.astype(np.int64), truth


Member = tuple[Any, int]  # a substance network and its read size


def read_members(members: list[Member], scales: list[float], rgb: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """The mean of every member's probabilities at every scale of its read size, at the part map's size."""
    reads = [read(network, max(32, int(round(size * scale / 32)) * 32), rgb, labels)
             for network, size in members for scale in scales]
    return np.mean(reads, axis=0)


def read_parts(photos: Iterator[Photo], members: list[Member], scales: list[float]) -> list[Read]:
    """Every visible part's vote, one forward pass per photo, member and scale."""
    out: list[Read] = []
    for photo, rgb, labels, truth in photos:
        probs = read_members(members, scales, rgb, labels)
        for index, substance in truth.items():
            share = float((labels == index).sum() / max(1, (labels > 0).sum()))
            if share > 0.0:
                out.append((photo, substance, vote(labels, probs, index).substance, share))
    return out


def open_library_photos(session: Any, groundtruth: Path, source: str | None) -> set[str]:
    """The world's photos whose parts all show materials outside the collection (the world's
    `open_library` share: hue, roughness and tile variants), by the keys `world_photos` gives them."""
    stems = [e["source_id"] for e in json.loads(groundtruth.read_text())["exemplars"] if e.get("open_library")]
    query = sa.select(m.Exemplar.id).where(m.Exemplar.source_id.in_(stems))
    if source is not None:
        query = query.where(m.Exemplar.source == source)
    return {f"exemplar/{eid}" for eid in session.execute(query).scalars()}


def compare(first: Path, second: Path) -> None:
    """B minus A per set, paired over the photos both read."""
    a, b = (json.loads(path.read_text()) for path in (first, second))
    for name in a["sets"]:
        if name not in b["sets"]:
            continue
        reads_a, reads_b = a["sets"][name]["by_photo"], b["sets"][name]["by_photo"]
        photos = set(reads_a) & set(reads_b)
        diff = difference_interval({k: reads_b[k] for k in photos}, {k: reads_a[k] for k in photos})
        print(f"{name:18s} A {a['sets'][name]['accuracy']:.3f}  B {b['sets'][name]['accuracy']:.3f}  "
              f"B - A {diff.value:+.3f} ({diff.low:+.3f}, {diff.high:+.3f})")


def other_member(root: Path) -> tuple[Member, str]:
    """The newest trained substance network of another data root (its database and blobs), and its id."""
    settings = Settings(data_root=root, database_url=None, blob_root=None)
    with session_scope(settings.resolved_database_url) as session:
        row = newest_substance_network(session)
        network = load_substance_network(row, BlobStore(settings.blob_root), "cpu")
        return (network, read_side_of(row.config) or 128), f"{root.name}:{row.id}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--groundtruth", type=Path, default=None, help="an evaluation world (attribution only)")
    parser.add_argument("--source", default=None)
    parser.add_argument("--network", type=int, default=None, help="a substance classifier id (default: newest)")
    parser.add_argument("--small", type=float, default=0.015, help="a part under this share of its map is small")
    parser.add_argument("--compare", type=Path, nargs=2, default=None, metavar=("A", "B"))
    parser.add_argument("--with", dest="others", type=Path, action="append", default=[],
                        help="another data root whose newest substance network joins the ensemble")
    parser.add_argument("--scales", type=float, nargs="+", default=[1.0],
                        help="read at these multiples of the read size")
    parser.add_argument("--skip-train", action="store_true", help="leave out the training renders (the slowest set)")
    args = parser.parse_args()
    if args.compare:
        compare(*args.compare)
        return
    settings = get_settings()
    store = BlobStore(settings.blob_root)
    others = [other_member(root) for root in args.others]
    with session_scope(settings.resolved_database_url) as session:  # read-only
        row = newest_substance_network(session, args.network)
        members = [(load_substance_network(row, store, "cpu"), read_side_of(row.config) or 128)]
        members += [member for member, _ in others]
        label = "+".join([str(row.id), *(name for _, name in others)])
        if args.scales != [1.0]:
            label += "@" + ",".join(f"{s:g}" for s in args.scales)
        results: dict[str, Any] = {"network": label, "name": row.name, "small": args.small,
                                   "scales": args.scales, "sets": {}}
        sets = {"train": bootstrap_photos(session, store, "train", False, settings.seed),
                "val": bootstrap_photos(session, store, "val", False, settings.seed),
                "val, photo-like": bootstrap_photos(session, store, "val", True, settings.seed)}
        if args.skip_train:
            del sets["train"]
        if args.groundtruth is not None:
            sets["world"] = world_photos(session, store, args.groundtruth, args.source)
        splits: dict[str, list[Read]] = {}
        for name, photos in sets.items():
            splits[name] = read_parts(photos, members, args.scales)
        if args.groundtruth is not None:  # the world's two shares: materials in the collection, or variants
            shown = open_library_photos(session, args.groundtruth, args.source)
            for share, wanted in (("world, library", False), ("world, open library", True)):
                splits[share] = [r for r in splits["world"] if (r[0] in shown) == wanted]
        for name, reads in splits.items():
            results["sets"][name] = {**summarise(reads, args.small), "by_photo": by_photo(reads)}
            cell = results["sets"][name]
            recall = ", ".join(f"{k} {v:.2f}" for k, v in cell["recall"].items())
            print(f"{name:18s} {cell['parts']:5d} parts  {cell['accuracy']:.3f}  small {cell['small'] or 0:.3f}  "
                  f"larger {cell['larger'] or 0:.3f}  recall: {recall}", flush=True)
        session.rollback()
    out = results_dir(settings, "substance_fit")
    out.mkdir(parents=True, exist_ok=True)
    (out / f"network-{results['network']}.json").write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
