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


def test_top_k_weights_by_substance_and_never_ranks_background() -> None:
    classifier = load_classifier(_checkpoint(), device="cpu")
    wood, fabric = SUBSTANCE_LABELS.index("wood"), SUBSTANCE_LABELS.index("fabric")
    material = np.array([[0.7, 0.1, 0.15, 0.05]])  # background, 4 (wood), 9 (fabric), 12 (wood)
    substance = np.zeros((1, len(SUBSTANCE_LABELS)))
    substance[0, wood], substance[0, fabric] = 0.9, 0.1
    ranked = classifier.top_k(material, substance, k=3)[0]
    assert [r.material_id for r in ranked] == [4, 12, 9]
    assert ranked[0].score == pytest.approx(0.1 * 0.9) and ranked[0].probability == pytest.approx(0.1)
    plain = classifier.top_k(material, substance, k=2, weight_by_substance=False)[0]
    assert [r.material_id for r in plain] == [9, 4]
    assert all(r.material_id != 0 for r in classifier.top_k(material, None, k=10)[0])


def test_predict_averages_each_region_with_its_mirror_image() -> None:
    image, masks = _image_and_masks()
    plain = load_classifier(_checkpoint(), device="cpu")
    plain.flip = False
    mat, sub = plain.predict(image, masks)
    mirrored_mat, mirrored_sub = plain.predict(image[:, ::-1], [mask[:, ::-1] for mask in masks])
    both_mat, both_sub = load_classifier(_checkpoint(), device="cpu").predict(image, masks)
    assert np.allclose(both_mat, 0.5 * (mat + mirrored_mat), atol=1e-5)
    assert np.allclose(both_sub, 0.5 * (sub + mirrored_sub), atol=1e-5)


def test_top_k_multiplies_in_the_colour_likelihood() -> None:
    classifier = load_classifier(_checkpoint(), device="cpu")
    material = np.array([[0.1, 0.4, 0.35, 0.15]])  # background, 4, 9, 12
    colours = np.array([[0.2, 1.0, 0.5]])  # the part's colour is that of material 9
    ranked = classifier.top_k(material, None, k=3, weight_by_substance=False, color_weights=colours)[0]
    assert [r.material_id for r in ranked] == [9, 4, 12]
    assert ranked[0].score == pytest.approx(0.35) and ranked[1].score == pytest.approx(0.4 * 0.2)
    assert ranked[0].probability == pytest.approx(0.35)


def test_a_sharper_calibrated_substance_confidence_outweighs_the_material_head() -> None:
    from photoshape_flow.classify.assignment import substance_vector
    from photoshape_flow.classify.substance_calibration import temper

    classifier = load_classifier(_checkpoint(), device="cpu")
    material = np.array([[0.1, 0.3, 0.5, 0.1]])  # background, 4 (wood), 9 (fabric), 12 (wood)
    network = {"wood": 0.55, "fabric": 0.45}  # a mean of pixel opinions: right, but flat
    raw = classifier.top_k(material, substance_vector(network)[None], k=3)[0]
    assert raw[0].material_id == 9  # the head's fabric overrules the flat wood confidence
    calibrated = substance_vector(temper(network, 0.25))[None]  # validation parts say: trust it more
    sharp = classifier.top_k(material, calibrated, k=3)[0]
    assert sharp[0].material_id == 4 and sharp[0].substance == "wood"


def test_substance_first_takes_the_substance_with_most_mass_then_its_best_material() -> None:
    from photoshape_flow.classify.infer import substance_first_order

    classifier = load_classifier(_checkpoint(), device="cpu")
    # fabric's one material scores highest, but wood's two materials together hold more mass
    material = np.array([[0.1, 0.28, 0.34, 0.28]])  # background, 4 (wood), 9 (fabric), 12 (wood)
    by_score = classifier.top_k(material, None, k=3, weight_by_substance=False)[0]
    assert [r.material_id for r in by_score] == [9, 4, 12]
    decided = classifier.top_k(material, None, k=3, weight_by_substance=False, substance_first=True)[0]
    assert [r.material_id for r in decided] == [4, 9, 12]  # wood first; the rest still by score
    assert decided[0].substance == "wood" and decided[0].score == pytest.approx(0.28)
    assert [r.material_id for r in classifier.top_k(material, None, k=1, weight_by_substance=False,
                                                    substance_first=True)[0]] == [4]
    # when the best material's substance also holds the most mass, nothing moves
    assert list(substance_first_order(np.array([0.5, 0.3, 0.2]), SUBSTANCES)) == [0, 1, 2]
    assert substance_first_order(np.zeros(0), []).size == 0
    # a substance decided by other evidence is taken instead of the most mass, when it has any
    scores = np.array([0.28, 0.34, 0.28])
    labels = ["wood", "fabric", "wood"]
    assert list(substance_first_order(scores, labels, "fabric")) == [1, 0, 2]
    assert list(substance_first_order(scores, labels, "metal")) == [0, 1, 2]  # no such material: mass decides
    assert list(substance_first_order(np.array([0.6, 0.0, 0.4]), labels, "fabric")) == [0, 2, 1]
    assert [r.material_id for r in classifier.top_k(material, None, k=3, weight_by_substance=False,
                                                    substance_first=True, substances=["fabric"])[0]] == [9, 4, 12]
