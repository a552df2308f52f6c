"""A shared photo/material descriptor (MatCLIP-style) against the two-head part recogniser, on validation renders.

    PHOTOSHAPE_DATA_ROOT=/tmp/demo PHOTOSHAPE_DATABASE_URL=sqlite:////tmp/arms.db \\
        python -m experiments.material_descriptor.run --arm heads --arm descriptor --arm descriptor-seen --arm frozen

The descriptor is the part recogniser's encoder (`classify.part_net.PartRecognizer.features`: the
isolated part's crop through ImageNet EfficientNet-Lite0, mask-pooled moments of three blocks and the
head) with a projection to a unit vector. A material's descriptor is the mean descriptor of its parts
in the collection's training renders (shapes and lights of all kinds: the material side of MatCLIP's
pairs), so a material is recognised by the nearest descriptor, and a material added later needs
renders and one pass of the frozen network, not a retrain. Training pulls each rendered part toward
a learned proxy of its material (normalised softmax, scale 16), the same objective as an InfoNCE
over materials with one positive.

Arms, scored on the same photo-like validation renders (`recognition.bn_prior.photo_cases`: shapes and
envmaps no arm trained on, degraded like exemplars, part maps misaligned), never on exemplars:

* ``heads``: the two-head part recogniser (`--set training.arch=efficientnet-lite0`, D53) through the
  pipeline's own `run_training` (a new classifier row: run on a scratch copy of the database);
* ``descriptor``: the descriptor trained on every material;
* ``descriptor-seen``: trained without a quarter of the materials ("late": chosen by name hash, at least
  one material per substance kept), whose descriptors come from their renders only;
* ``frozen``: ImageNet features without training (standardised pooled moments), the floor.

Scores per region: material top-1 / top-5 over the enabled materials, the substance of the top
material and of the similarity mass per substance, each also over the late materials' regions, with 95%
bootstrap intervals over renders.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa
import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.data import DataLoader

from photoshape_flow.classify.configs import ClassifierConfig, get_config
from photoshape_flow.classify.dataset import RegionDataset, find_regions, frame_object
from photoshape_flow.classify.descriptor import SCALE, fit_prototypes
from photoshape_flow.classify.infer import MaterialClassifier
from photoshape_flow.classify.networks import grow_materials
from photoshape_flow.classify.part_net import PartRecognizer
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.devices import set_torch_threads
from photoshape_flow.evaluation.groundtruth import read_groundtruth_file, read_part_mask
from photoshape_flow.imaging.io import load_rgb
from photoshape_flow.networks.classifiers import load_material_classifier
from photoshape_flow.profiles import resolve_profile
from photoshape_flow.recognition.bn_prior import PhotoCase, photo_cases
from photoshape_flow.recognition.material_sets import MaterialSet, material_set
from photoshape_flow.recognition.training import run_training, training_data
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import SUBSTANCE_LABELS

from ..common import interval, region_hits, results_dir


def late_materials(materials: MaterialSet, fraction: float = 0.25) -> set[int]:
    """About `fraction` of the materials by a hash of their names, one material per substance always kept."""
    late: set[int] = set()
    for mid, name in zip(materials.ids, materials.names, strict=True):
        if int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "little") / 2**32 < fraction:
            late.add(mid)
    for substance in set(materials.substances):
        of = [mid for mid, s in zip(materials.ids, materials.substances, strict=True) if s == substance]
        if all(mid in late for mid in of):
            late.discard(of[0])
    return late


class FrozenFeatures(nn.Module):
    """The floor: ImageNet features untrained, standardised, scored by cosine to each material's mean.

    Same contract as the material networks (material logits with a background column, substance logits
    as the log of the softmax mass per substance), so `MaterialClassifier` reads it.
    """

    def __init__(self, arch: str, config: ClassifierConfig):
        super().__init__()
        self.encoder = PartRecognizer(arch, num_materials=1, crop_size=config.crop_size,
                                      context=config.crop_context, isolate=config.isolate_part)
        self.encoder.requires_grad_(False)
        dim = self.encoder.feature_dim
        self.register_buffer("mu", torch.zeros(dim))
        self.register_buffer("sd", torch.ones(dim))
        self.register_buffer("prototypes", torch.zeros(0, dim))
        self.register_buffer("substance_index", torch.zeros(0, dtype=torch.long))

    def embed(self, x: torch.Tensor) -> torch.Tensor:
        return F.normalize((self.encoder.features(x) - self.mu) / self.sd, dim=1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        logits = SCALE * self.embed(x) @ self.prototypes.T
        background = torch.full((len(x), 1), -1e4, dtype=logits.dtype)
        p = logits.softmax(1)
        mass = torch.zeros(len(x), len(SUBSTANCE_LABELS), dtype=p.dtype).index_add_(1, self.substance_index, p)
        return torch.cat([background, logits], 1), mass.clamp_min(1e-12).log()

    @torch.inference_mode()
    def fit(self, renders: RegionDataset, materials: MaterialSet, per_material: int, seed: int) -> None:
        """Standardise by, and average per material, up to `per_material` rendered parts each."""
        rng = np.random.default_rng(seed)
        chosen: list[int] = []
        for label in range(1, len(materials.ids) + 1):
            of = [i for i, e in enumerate(renders.examples) if e.label == label]
            chosen.extend(sorted(of[j] for j in rng.permutation(len(of))[:per_material]))
        batches = list(DataLoader(torch.utils.data.Subset(renders, chosen), batch_size=64))
        feats = torch.cat([self.encoder.features(x) for x, _, _ in batches])
        self.mu, self.sd = feats.mean(0), feats.std(0).clamp_min(1e-4)
        labels = torch.cat([label for _, label, _ in batches]) - 1
        emb = F.normalize((feats - self.mu) / self.sd, dim=1)
        self.prototypes = F.normalize(torch.zeros(len(materials.ids), emb.shape[1]).index_add_(0, labels, emb), dim=1)
        self.substance_index = torch.tensor([SUBSTANCE_LABELS.index(s) for s in materials.substances])


def trained_without(settings: Any, config: ClassifierConfig, late: set[int], name: str) -> int:
    """A classifier trained while the `late` materials are disabled (re-enabled afterwards, whatever happens)."""
    url = settings.resolved_database_url
    with session_scope(url) as session:
        session.execute(sa.update(m.Material).where(m.Material.id.in_(late)).values(enabled=False))
    try:
        return run_training(config, name=name, settings=settings)
    finally:
        with session_scope(url) as session:
            session.execute(sa.update(m.Material).where(m.Material.id.in_(late)).values(enabled=True))


def world_cases(groundtruth: Path, material_ids: dict[str, int]) -> list[PhotoCase]:
    """The evaluation world's photos with their true part masks (attribution only: never chosen on).

    Each photo is cut to the square around its object, as ingest stores an exemplar; a part is scored
    when its true material is in the collection and it covers at least 64 pixels.
    """
    truth_file = read_groundtruth_file(groundtruth)
    out = []
    for entry in truth_file.entries:
        if entry.mask is None or entry.mask.kind != "part":
            continue
        stem = Path(entry.exemplar.source_id).stem
        photo = next((p for p in sorted((groundtruth.parent / "exemplars").glob(f"{stem}.*"))), None)
        if photo is None:
            continue
        image, labels = frame_object(load_rgb(photo), read_part_mask(entry.mask.path))
        masks, truth = [], []
        for value, part in sorted(entry.mask.values.items()):
            material = entry.parts[part].material if part in entry.parts else None
            if material in material_ids and (labels == value).sum() >= 64:
                masks.append(labels == value)
                truth.append(material_ids[material])
        if masks:
            out.append(PhotoCase(entry.label, image, tuple(masks), tuple(truth)))
    return out


def score(model: Any, cases: list, materials: MaterialSet, late: set[int]) -> dict[str, Any]:
    """Per-region hits (top-1, top-5, substance of the top material and of the mass) with bootstrap intervals.

    Rows of "hits" (what compare.py reads): case, late material (0/1), top-1, top-5, substance of the top
    material, substance of the mass.
    """
    hits = region_hits(model, cases, materials.ids)
    late_flag = np.isin(hits[:, 1], sorted(late)).astype(float)
    data = np.column_stack([hits[:, 0], late_flag, hits[:, [2, 3, 4, 6]]])
    out: dict[str, Any] = {"regions": len(data), "late_regions": int(late_flag.sum()), "hits": data.tolist()}
    rng = np.random.default_rng(0)
    for subset, keep in (("all", np.ones(len(data), bool)), ("late", late_flag == 1)):
        sub = data[keep]
        for j, name in enumerate(("top1", "top5", "substance_top", "substance_mass"), start=2):
            out[f"{subset}.{name}"] = interval(sub[:, j], sub[:, 0].astype(int), rng)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arm", action="append", default=[],
                        choices=("scratch", "heads", "descriptor", "descriptor-seen", "frozen"))
    parser.add_argument("--profile", default="small", help="whose classifier the scratch arm trains")
    parser.add_argument("--renders", type=int, default=100, help="validation renders made photo-like")
    parser.add_argument("--epochs", type=int, default=4)
    parser.add_argument("--steps", type=int, default=30, help="batches per epoch")
    parser.add_argument("--per-material", type=int, default=24, help="rendered parts per material descriptor")
    parser.add_argument("--groundtruth", type=Path, default=None,
                        help="also score an evaluation world's photos through their true part masks")
    parser.add_argument("--out", default=None, help="default: <data root>/experiments/material_descriptor/arms.json")
    args = parser.parse_args()
    settings = get_settings()
    set_torch_threads(settings.torch_threads)
    torch.manual_seed(settings.seed)
    store = BlobStore(settings.blob_root)
    config = get_config("backbone", epochs=args.epochs, max_steps_per_epoch=args.steps)
    with session_scope(settings.resolved_database_url) as session:
        cases = photo_cases(session, store, settings, args.renders)
        materials = material_set(session)
        data = training_data(session, store)
        names = dict(session.execute(sa.select(m.Material.id, m.Material.name)).all())
    world = world_cases(args.groundtruth, {v: k for k, v in names.items()}) if args.groundtruth else []
    late = late_materials(materials)
    examples = find_regions(data.train, materials.ids, materials.substance_of)
    print(f"{len(cases)} validation renders, {len(data.train)} training renders, {len(examples)} rendered parts, "
          f"{len(materials.ids)} materials, late: {sorted(names[i] for i in late)}", flush=True)
    out = Path(args.out) if args.out else results_dir(settings, "material_descriptor") / "arms.json"
    results: dict[str, Any] = json.loads(out.read_text()) if out.exists() else {}  # arms added to a run's
    results["late"] = sorted(names[i] for i in late)
    for arm in args.arm:
        started = time.perf_counter()
        info: dict[str, Any] = {}
        renders = RegionDataset(data.train, examples, config.image_size, frame=config.frame_object)
        if arm == "frozen":
            net = FrozenFeatures(config.arch, config)
            net.fit(renders, materials, args.per_material, settings.seed)
            model = MaterialClassifier(net, materials.ids, materials.substances, config.image_size)
        elif arm == "descriptor-seen":  # trained without the late materials, which then get descriptors only
            chosen = config.replace(head="descriptor")
            classifier_id = trained_without(settings, chosen, late, f"exp-descriptor-seen-{chosen.architecture}")
            _row, seen_model = load_material_classifier(classifier_id, settings)
            net = grow_materials(seen_model.model, seen_model.materials, materials.ids, materials.substance_of)
            fit_prototypes(net, renders, seed=settings.seed)
            model = MaterialClassifier(net, materials.ids, materials.substances, config.image_size)
            info["classifier"] = classifier_id
        else:
            chosen = {"scratch": resolve_profile(args.profile).profile.training,
                      "heads": config, "descriptor": config.replace(head="descriptor")}[arm]
            classifier_id = run_training(chosen, name=f"exp-descriptor-{arm}-{chosen.architecture}", settings=settings)
            _row, model = load_material_classifier(classifier_id, settings)
            info["classifier"] = classifier_id
        seconds = round(time.perf_counter() - started, 1)
        key = arm if args.epochs == 4 else f"{arm}@{args.epochs}"  # another budget: another arm
        results[key] = {"seconds": seconds, "epochs": args.epochs, **info, **score(model, cases, materials, late)}
        if world:
            results[key]["world"] = score(model, world, materials, late)
        shown = {k: v for k, v in results[key].items() if k not in ("hits", "world")}
        if world:
            shown["world"] = {k: v for k, v in results[key]["world"].items() if k != "hits"}
        print(key, json.dumps(shown), flush=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
