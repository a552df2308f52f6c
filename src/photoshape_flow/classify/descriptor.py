"""The shared photo/material descriptor: one unit vector per part, each material the mean of its renders'.

The part recogniser's encoder (`classify.part_net`: the isolated part's crop through ImageNet
EfficientNet-Lite, mask-pooled moments at several depths) is projected to a `dim`-d unit vector. A
material is described by the normalised mean descriptor of its parts in the collection's training
renders (many shapes, lights, views: the material side of MatCLIP's photo/material pairs, Birsak et al.
2025; class prototypes as in Snell et al. 2017), and a part's material logits are scaled cosines to
those descriptors. Why: a material added later is recognised from its renders through the trained
network, without a retrain, and on the second world's photos the descriptor transferred better than
the two linear heads (docs/decisions.md D61).

* **Training** (the pipeline's own loop, `classify.train`): the material head is a cosine head whose
  rows are learned proxies (row 0 the background); cross-entropy over its scaled cosines pulls each
  rendered part toward its material's proxy and away from the others (normalised softmax: an InfoNCE
  over materials with one positive). The substance head stays a linear head on the pooled features,
  as in the paper's two-output network, so the loss and every reader are unchanged.
* **Inference**: once `fit_prototypes` ran (at the end of training, and again for a grown material
  list), the material rows are the prototypes; the background keeps its proxy.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.data import DataLoader

from photoshape_flow.classify.dataset import RegionDataset
from photoshape_flow.classify.part_net import PartRecognizer

SCALE = 16.0  # cosine logits span +-16: a softmax that can be confident, yet bounded


class CosineHead(nn.Module):
    """Scaled cosine between unit descriptors and the rows of `weight` (row 0: background)."""

    def __init__(self, dim: int, rows: int, scale: float = SCALE):
        super().__init__()
        self.weight = nn.Parameter(torch.randn(rows, dim) * 0.1)
        self.scale = float(scale)

    @property
    def rows(self) -> int:
        return int(self.weight.shape[0])

    def forward(self, descriptors: torch.Tensor, material_rows: torch.Tensor | None = None) -> torch.Tensor:
        rows = self.weight if material_rows is None else torch.cat([self.weight[:1], material_rows], 0)
        return self.scale * descriptors @ F.normalize(rows, dim=1).T


class MaterialDescriptor(PartRecognizer):
    """The part recogniser with its material head replaced by a descriptor and a cosine head."""

    def __init__(self, *args: Any, dim: int = 128, **kwargs: Any):
        """`PartRecognizer`'s arguments, and the descriptor's dimension."""
        super().__init__(*args, **kwargs)
        self.dim = int(dim)
        self.project = nn.Sequential(nn.Linear(self.feature_dim, 512), nn.ReLU(), nn.Linear(512, self.dim))
        self.fc_material = CosineHead(self.dim, self.num_materials + 1)  # type: ignore[assignment]
        self.register_buffer("prototypes", torch.zeros(self.num_materials, self.dim))
        self.register_buffer("has_prototypes", torch.zeros((), dtype=torch.bool))

    def describe(self, x: torch.Tensor) -> torch.Tensor:
        """Unit descriptors (N, dim) of a (N, 4, H, W) RGB-in-[0, 1] + mask batch."""
        return F.normalize(self.project(self.features(x)), dim=1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        feats = self.dropout(self.features(x))
        descriptors = F.normalize(self.project(feats), dim=1)
        use_prototypes = bool(self.has_prototypes) and not self.training
        logits = self.fc_material(descriptors, self.prototypes if use_prototypes else None)
        return logits, self.fc_substance(feats)

    def set_prototypes(self, descriptors: torch.Tensor, labels: torch.Tensor) -> None:
        """Each material's row: the normalised mean of its `descriptors` (labels 1..M); a material
        without any keeps its trained proxy."""
        sums = torch.zeros(self.num_materials, self.dim, dtype=descriptors.dtype)
        sums.index_add_(0, labels.long() - 1, descriptors.detach().cpu())
        seen = torch.bincount(labels.long() - 1, minlength=self.num_materials) > 0
        proxies = F.normalize(self.fc_material.weight.detach()[1:].cpu(), dim=1)
        rows = torch.where(seen[:, None], F.normalize(sums, dim=1), proxies)
        self.prototypes = rows.to(self.prototypes.device)
        self.has_prototypes = torch.ones((), dtype=torch.bool, device=self.prototypes.device)

    def grow_materials(self, old_ids: Sequence[int], new_ids: Sequence[int],
                       substance_of: Mapping[int, str] | None = None) -> MaterialDescriptor:
        """Re-map the material rows from `old_ids` to `new_ids`: kept materials keep proxy and prototype,
        a new one starts at the normalised mean proxy of its substance (no prototype until
        `fit_prototypes` sees its renders). Modifies and returns the network."""
        old, new = [int(i) for i in old_ids], [int(i) for i in new_ids]
        if self.fc_material.rows != len(old) + 1:
            raise ValueError(f"material head has {self.fc_material.rows} rows, old list implies {len(old) + 1}")
        if len(set(new)) != len(new) or not new:
            raise ValueError("new material list must be non-empty and without duplicates")
        index = {mid: i for i, mid in enumerate(old)}
        weight = F.normalize(self.fc_material.weight.detach(), dim=1)
        substance = dict(substance_of or {})
        rows, protos = [weight[0]], []
        for mid in new:
            if mid in index:
                rows.append(weight[index[mid] + 1])
                protos.append(self.prototypes[index[mid]])
                continue
            same = [index[o] + 1 for o in old if mid in substance and substance.get(o) == substance[mid]]
            rows.append(F.normalize(weight[same or list(range(1, len(old) + 1)) or [0]].mean(0), dim=0))
            protos.append(rows[-1])
        with torch.no_grad():
            self.fc_material.weight = nn.Parameter(torch.stack(rows))
        self.prototypes = torch.stack(protos)
        self.has_prototypes = torch.zeros((), dtype=torch.bool, device=self.prototypes.device)
        self.num_materials = len(new)
        return self

    def head_parameters(self) -> list[nn.Parameter]:
        return [*self.project.parameters(), *super().head_parameters()]

    def spec(self) -> dict[str, object]:
        return {**super().spec(), "head": "descriptor", "dim": self.dim}


@torch.inference_mode()
def fit_prototypes(model: MaterialDescriptor, dataset: RegionDataset, per_material: int = 24, seed: int = 0,
                   batch_size: int = 64, device: torch.device | str = "cpu") -> int:
    """Set `model`'s prototypes from up to `per_material` rendered parts per material of `dataset`
    (examples labelled 1..M, read without augmentation); returns the parts read."""
    rng = np.random.default_rng(seed)
    chosen: list[int] = []
    by_label: dict[int, list[int]] = {}
    for i, example in enumerate(dataset.examples):
        if example.label > 0:
            by_label.setdefault(int(example.label), []).append(i)
    for label in sorted(by_label):
        picks = by_label[label]
        chosen.extend(sorted(picks[j] for j in rng.permutation(len(picks))[:per_material]))
    if not chosen:
        return 0
    was_training = model.training
    model.eval()
    descriptors, labels = [], []
    for x, label, _substance in DataLoader(torch.utils.data.Subset(dataset, chosen), batch_size=batch_size):
        descriptors.append(model.describe(x.to(device)).cpu())
        labels.append(label)
    model.set_prototypes(torch.cat(descriptors), torch.cat(labels))
    model.train(was_training)
    return len(chosen)
