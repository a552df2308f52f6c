"""Inference: checkpoint round trip, probabilities per mask, batching, substance-weighted ranking."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from photoshape_flow.classify import checkpoint as ckpt
from photoshape_flow.classify.infer import MaterialClassifier, load_classifier
from photoshape_flow.classify.resnet import build_model
from photoshape_flow.vocab import SUBSTANCE_LABELS

MATERIALS = [4, 9, 12]
SUBSTANCES = ["wood", "fabric", "wood"]


def _checkpoint() -> dict:
    model = build_model("resnet18", len(MATERIALS), width=8, seed=0)
    return ckpt.make_checkpoint(model, materials=MATERIALS, material_substances=SUBSTANCES, image_size=32,
                                config={"name": "tiny"}, epoch=1)


def _image_and_masks() -> tuple[np.ndarray, list[np.ndarray]]:
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, size=(40, 56, 3), dtype=np.uint8)  # not square
    masks = []
    for k in range(5):
        mask = np.zeros((40, 56), bool)
        mask[k * 6:k * 6 + 10, k * 8:k * 8 + 20] = True
        masks.append(mask)
    return image, masks


def test_checkpoint_round_trip_and_slim(tmp_path: Path) -> None:
    data = _checkpoint()
    blob = ckpt.to_bytes(ckpt.slim(data))
    loaded = ckpt.load(blob)
    assert loaded["materials"] == MATERIALS and "optimizer" not in loaded and "rng" not in loaded
    path = tmp_path / "c.pt"
    path.write_bytes(blob)
    classifier = load_classifier(path, device="cpu")
    assert isinstance(classifier, MaterialClassifier) and not classifier.model.training
    for key, value in ckpt.build_model(data).state_dict().items():
        assert torch.equal(value, classifier.model.state_dict()[key])
    with pytest.raises(ValueError, match="checkpoint"):
        ckpt.load(b"not a checkpoint")


def test_predict_shapes_probabilities_and_batching() -> None:
    image, masks = _image_and_masks()
    one = load_classifier(_checkpoint(), device="cpu", batch_size=1)
    many = load_classifier(_checkpoint(), device="cpu", batch_size=32)
    mat, sub = many.predict(image, masks)
    assert mat.shape == (5, len(MATERIALS) + 1) and sub.shape == (5, len(SUBSTANCE_LABELS))
    assert np.allclose(mat.sum(1), 1.0, atol=1e-5) and np.allclose(sub.sum(1), 1.0, atol=1e-5)
    mat1, sub1 = one.predict(image, masks)
    assert np.allclose(mat, mat1, atol=1e-5) and np.allclose(sub, sub1, atol=1e-5)
    assert not np.allclose(mat[0], mat[4])  # the mask changes the answer
    empty_mat, _ = many.predict(image, [])
    assert empty_mat.shape == (0, len(MATERIALS) + 1)
    with pytest.raises(ValueError, match="mask shape"):
        many.predict(image, [np.zeros((10, 10), bool)])
    crop_mat, _ = many.predict(image, masks, crop="mask")
    assert crop_mat.shape == mat.shape


def test_predict_averages_each_region_with_its_mirror_image() -> None:
    image, masks = _image_and_masks()
    plain = load_classifier(_checkpoint(), device="cpu")
    plain.flip = False
    mat, sub = plain.predict(image, masks)
    mirrored_mat, mirrored_sub = plain.predict(image[:, ::-1], [mask[:, ::-1] for mask in masks])
    both_mat, both_sub = load_classifier(_checkpoint(), device="cpu").predict(image, masks)
    assert np.allclose(both_mat, 0.5 * (mat + mirrored_mat), atol=1e-5)
    assert np.allclose(both_sub, 0.5 * (sub + mirrored_sub), atol=1e-5)
