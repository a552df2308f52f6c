"""Training examples of the material classifier: one per (rendering, material region).

A synthetic training rendering (section 5.1) knows which material is at each pixel (its
``material_ids`` map: material DB id per pixel, 0 = background). Each material region covering at
least ``min_fraction`` of the image becomes one example: input = the RGB render + the binary mask of
that region, labels = the material's index in the classifier's material list (1-based; 0 is the
background class) and its substance's index in ``vocab.SUBSTANCE_LABELS`` (the substance comes from
the material's annotation, as in the paper). With ``background_every = n`` every n-th rendering also
gives one background example (mask = background pixels, both labels 0), so the background output of
the "C + 1" head is trained too. Regions of materials outside the list (disabled since) are skipped.

The datasets take plain file paths so they are testable without a database; the pipeline builds the
path lists from `Rendering` rows (`pipeline.training`).
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from photoshape_flow.classify.augment import augment, resize
from photoshape_flow.classify.configs import AugmentConfig
from photoshape_flow.imaging.io import load_label_map, load_rgb
from photoshape_flow.imaging.squares import crop_square, square_box
from photoshape_flow.vocab import SUBSTANCE_LABELS

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RenderItem:
    """One training rendering as files: the sRGB image and its material-id map (same size)."""

    image: Path
    material_map: Path
    key: str = ""


@dataclass(frozen=True)
class RegionExample:
    """One classifier example: a region of `items[item]` and its labels."""

    item: int
    material_id: int  # DB id; 0 = background example
    label: int  # index in the material head (0 = background)
    substance: int  # index in SUBSTANCE_LABELS (0 = background)
    pixels: int


def frame_object(image: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Crop a render and its label map to the square around the object (label > 0), white outside.

    Exemplars are stored as exactly this square (`imaging.exemplar`, margin 0), so a network trained
    on framed renders sees objects at the scale it meets at inference; unframed, the training renders'
    objects (camera distance U(1.3, 1.75)) span about 60% of the frame against 100% in an exemplar.
    An image without foreground is returned unchanged. `ids` may stack label maps (H, W, C): the
    first channel's foreground decides.
    """
    ids = np.asarray(ids)
    box = square_box((ids if ids.ndim == 2 else ids[..., 0]) > 0)
    if box is None:
        return image, ids
    x0, y0, side = box
    return crop_square(image, x0, y0, side, fill=255), crop_square(ids, x0, y0, side, fill=0)


def substance_label(substance: str) -> int:
    if substance not in SUBSTANCE_LABELS:
        raise ValueError(f"unknown substance {substance!r}; expected one of {SUBSTANCE_LABELS[1:]}")
    return SUBSTANCE_LABELS.index(substance)


def find_regions(
    items: Sequence[RenderItem],
    material_ids: Sequence[int],
    substance_of: Mapping[int, str],
    *,
    min_fraction: float = 0.005,
    background_every: int = 0,
) -> list[RegionExample]:
    """Every (rendering, material region) example of `items`, in a stable order.

    `material_ids` is the classifier's material list (output index i + 1 = material_ids[i]);
    `substance_of` maps a material id to its substance name. Unreadable items are logged and skipped.
    """
    label_of = {int(mid): i + 1 for i, mid in enumerate(material_ids)}
    substance_idx = {int(mid): substance_label(substance_of[int(mid)]) for mid in material_ids}
    examples: list[RegionExample] = []
    for index, item in enumerate(items):
        try:
            ids = load_label_map(Path(item.material_map))
        except (ValueError, OSError) as exc:
            log.warning("%s", exc)
            continue
        values, counts = np.unique(ids, return_counts=True)
        minimum = max(1, int(np.ceil(min_fraction * ids.size)))
        for value, count in zip(values.tolist(), counts.tolist(), strict=True):
            if value == 0:
                if background_every and index % background_every == 0 and count >= minimum:
                    examples.append(RegionExample(index, 0, 0, 0, int(count)))
                continue
            if value not in label_of or count < minimum:
                continue
            examples.append(RegionExample(index, int(value), label_of[value], substance_idx[value], int(count)))
    return examples


def example_seed(seed: int, epoch: int, index: int) -> int:
    """A 63-bit seed per (run seed, epoch, example), independent of batching and worker layout."""
    mixed = (int(seed) * 0x9E3779B97F4A7C15 + int(epoch) * 0xBF58476D1CE4E5B9 + int(index) * 0x94D049BB133111EB)
    return mixed & ((1 << 63) - 1)


class RegionDataset(Dataset):
    """Examples as tensors: x (4, size, size) = RGB in [0, 1] + mask, material label, substance label.

    With an `augment` config the views are random (seeded by `seed`, the epoch set through
    `set_epoch`, and the example index); without, images are plainly resized (validation).
    Decoded files are kept in a small per-process LRU cache.
    """

    def __init__(
        self,
        items: Sequence[RenderItem],
        examples: Sequence[RegionExample],
        size: int,
        augment_config: AugmentConfig | None = None,
        seed: int = 0,
        cache_items: int = 256,
        frame: bool = False,
    ):
        self.items = list(items)
        self.examples = list(examples)
        self.size = int(size)
        self.augment_config = augment_config
        self.seed = int(seed)
        self.epoch = 0
        self.cache_items = int(cache_items)
        self.frame = bool(frame)
        self._cache: OrderedDict[int, tuple[np.ndarray, np.ndarray]] = OrderedDict()

    def __len__(self) -> int:
        return len(self.examples)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def _load(self, item_index: int) -> tuple[np.ndarray, np.ndarray]:
        if item_index in self._cache:
            self._cache.move_to_end(item_index)
            return self._cache[item_index]
        item = self.items[item_index]
        image = load_rgb(Path(item.image))
        ids = load_label_map(Path(item.material_map))
        if image.shape[:2] != ids.shape:
            raise ValueError(f"{item.image}: image {image.shape[:2]} and material map {ids.shape} differ in size")
        if self.frame:
            image, ids = frame_object(image, ids)
        self._cache[item_index] = (image, ids)
        if len(self._cache) > self.cache_items:
            self._cache.popitem(last=False)
        return image, ids

    def __getitem__(self, index: int) -> tuple[torch.Tensor, int, int]:
        example = self.examples[index]
        image_u8, ids = self._load(example.item)
        image = torch.from_numpy(image_u8).permute(2, 0, 1).float().div_(255.0)
        mask = torch.from_numpy(ids == example.material_id).float().unsqueeze(0)
        if self.augment_config is not None:
            generator = torch.Generator().manual_seed(example_seed(self.seed, self.epoch, index))
            image, mask = augment(image, mask, self.size, self.augment_config, generator)
        else:
            image, mask = resize(image, mask, self.size)
        return torch.cat([image, mask], 0), example.label, example.substance

    def label_counts(self, num_classes: int) -> np.ndarray:
        counts = np.zeros(num_classes, dtype=np.int64)
        for example in self.examples:
            counts[example.label] += 1
        return counts


def make_input(image_rgb: np.ndarray, mask: np.ndarray, size: int) -> torch.Tensor:
    """The network input (4, size, size) for an RGB uint8 (or [0, 1] float) image and a boolean mask."""
    image = torch.from_numpy(np.ascontiguousarray(image_rgb)).permute(2, 0, 1).float()
    if image_rgb.dtype == np.uint8:
        image = image / 255.0
    mask_t = torch.from_numpy(np.ascontiguousarray(mask).astype(np.float32)).unsqueeze(0)
    image, mask_t = resize(image, mask_t, size)
    return torch.cat([image, mask_t], 0)
