"""Region examples from material-id maps, and the tensors the dataset yields."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from tests.classify.regiondata import TOY_MATERIALS, substance_of, write_renders

from photoshape_flow.classify.configs import AugmentConfig
from photoshape_flow.classify.dataset import RegionDataset, RenderItem, find_regions, frame_object, make_input
from photoshape_flow.vocab import SUBSTANCE_LABELS


def _write(tmp_path: Path, id_map: np.ndarray, name: str = "a") -> RenderItem:
    image = np.full((*id_map.shape, 3), 255, np.uint8)
    image[id_map > 0] = (90, 30, 10)
    cv2.imwrite(str(tmp_path / f"{name}.png"), image)
    cv2.imwrite(str(tmp_path / f"{name}_ids.png"), id_map.astype(np.uint16))
    return RenderItem(tmp_path / f"{name}.png", tmp_path / f"{name}_ids.png", name)


def test_find_regions_labels_thresholds_and_unknown_materials(tmp_path: Path) -> None:
    ids = np.zeros((20, 20), np.uint16)
    ids[0:10, :] = 7  # 200 px, fabric
    ids[10:12, 0:5] = 3  # 10 px, wood: below 5% of 400 px
    ids[15:20, 0:10] = 999  # a material not in the classifier's list
    item = _write(tmp_path, ids)
    materials = [3, 7, 8]
    examples = find_regions([item], materials, substance_of(), min_fraction=0.05)
    assert [(e.material_id, e.label, e.pixels) for e in examples] == [(7, 2, 200)]
    assert examples[0].substance == SUBSTANCE_LABELS.index("fabric")
    examples = find_regions([item], materials, substance_of(), min_fraction=0.01, background_every=1)
    wood, fabric = SUBSTANCE_LABELS.index("wood"), SUBSTANCE_LABELS.index("fabric")
    assert [(e.material_id, e.label, e.substance) for e in examples] == [(0, 0, 0), (3, 1, wood), (7, 2, fabric)]


def test_find_regions_skips_unreadable_maps(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    good = write_renders(tmp_path, 2, size=24)
    broken = RenderItem(tmp_path / "missing.png", tmp_path / "missing_ids.png", "missing")
    examples = find_regions([good[0], broken, good[1]], list(TOY_MATERIALS), substance_of())
    assert {e.item for e in examples} == {0, 2}
    assert "missing_ids.png" in caplog.text


def test_dataset_items_are_mask_aligned_tensors(tmp_path: Path) -> None:
    items = write_renders(tmp_path, 3, size=48)
    examples = find_regions(items, list(TOY_MATERIALS), substance_of())
    plain = RegionDataset(items, examples, size=32)
    x, label, substance = plain[0]
    assert x.shape == (4, 32, 32) and x.dtype == torch.float32
    assert 1 <= label <= len(TOY_MATERIALS) and substance >= 1
    mask = x[3] > 0.5
    assert mask.any() and (~mask).any()
    # the masked pixels are not white (the region is painted), the rest mostly is
    assert float(x[:3, mask].mean()) < 0.9
    augmented = RegionDataset(items, examples, size=32, augment_config=AugmentConfig(), seed=1)
    a1, a2 = augmented[0][0], augmented[0][0]
    assert torch.equal(a1, a2)  # same epoch, same example: same view
    augmented.set_epoch(1)
    assert not torch.equal(a1, augmented[0][0])


def test_make_input_resizes_image_and_mask(tmp_path: Path) -> None:
    image = np.zeros((64, 64, 3), np.uint8)
    mask = np.zeros((64, 64), bool)
    mask[:32] = True
    x = make_input(image, mask, 16)
    assert x.shape == (4, 16, 16)
    assert torch.equal(x[3, :8], torch.ones(8, 16)) and torch.equal(x[3, 8:], torch.zeros(8, 16))


def test_frame_object_crops_renders_to_the_exemplar_square(tmp_path: Path) -> None:
    """A render is cut to the square around its object, as an exemplar is: the object then fills it."""
    ids = np.zeros((40, 40), np.uint16)
    ids[10:30, 14:24] = 7  # a 20 x 10 object: its square is 20 x 20, centred on it
    item = _write(tmp_path, ids)
    image, framed = frame_object(cv2.imread(str(item.image))[..., ::-1], ids)
    assert framed.shape == (20, 20) and image.shape == (20, 20, 3)
    assert (framed > 0).any(axis=1).all()  # the object spans the full height
    assert (framed[:, :5] == 0).all() and (framed[:, 15:] == 0).all()
    assert (image[framed == 0] == 255).all()  # white beside the object, as in the render
    empty = np.zeros((8, 8), np.uint16)
    assert frame_object(np.zeros((8, 8, 3), np.uint8), empty)[1] is empty  # no object: unchanged

    examples = find_regions([item], [7], substance_of())
    plain = RegionDataset([item], examples, size=20)[0][0]
    framed_x = RegionDataset([item], examples, size=20, frame=True)[0][0]
    assert float(framed_x[3].mean()) == pytest.approx(0.5)  # 20 x 10 of the 20 x 20 square
    assert float(plain[3].mean()) == pytest.approx(200 / 1600, abs=0.02)
