"""Substance segmentation network: shapes, overfitting a tiny batch, resumable epochs, prediction."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from tests.classify.regiondata import SUBSTANCE_COLOURS, toy_substances

from photoshape_flow.classify.substance_configs import get_config, read_side_of
from photoshape_flow.classify.substance_net import NUM_CLASSES, SubstanceNet
from photoshape_flow.classify.substance_train import (
    SubstanceData,
    augment,
    checkpoint_from_bytes,
    checkpoint_to_bytes,
    confusion_matrix,
    load_model,
    metrics_from_confusion,
    part_weights,
    predict_substances,
    train_substance_net,
)


def test_network_output_shape_any_size() -> None:
    model = SubstanceNet(width=8).eval()
    with torch.no_grad():
        out = model(torch.rand(2, 3, 40, 56))
    assert out.shape == (2, NUM_CLASSES, 40, 56)


def test_overfits_a_tiny_batch() -> None:
    torch.set_num_threads(2)
    data = toy_substances(4)
    config = get_config("tiny", epochs=1, iters_per_epoch=60, lr=1e-2, jitter=0.0, crop_scale=(1.0, 1.0), flip=False)
    result = train_substance_net(data, None, config)
    metrics = result.checkpoint["metrics"]
    assert metrics["loss_last"] < 0.5 * metrics["loss_first"]
    assert metrics["split"] == "train"
    assert metrics["pixel_accuracy"] > 0.8


def test_resume_continues_from_the_last_epoch() -> None:
    data, val = toy_substances(4, seed=1), toy_substances(2, seed=2)
    config = replace(get_config("tiny"), epochs=3, iters_per_epoch=2)
    saved: list[bytes] = []

    class Interrupt(Exception):
        pass

    def stop_after_two(checkpoint: dict, metrics: dict) -> None:
        saved.append(checkpoint_to_bytes(checkpoint))
        if checkpoint["epoch"] == 2:
            raise Interrupt

    with pytest.raises(Interrupt):
        train_substance_net(data, val, config, on_epoch=stop_after_two)
    assert len(saved) == 2

    resumed = train_substance_net(data, val, config, checkpoint=checkpoint_from_bytes(saved[-1]))
    assert resumed.epochs_run == [3]
    assert [h["epoch"] for h in resumed.history] == [1, 2, 3]
    assert resumed.checkpoint["metrics"]["split"] == "val"

    # the resumed run equals an uninterrupted one (per-epoch seeded streams, schedule from the iteration)
    straight = train_substance_net(data, val, config)
    for name, tensor in straight.checkpoint["model"].items():
        torch.testing.assert_close(tensor, resumed.checkpoint["model"][name], rtol=1e-4, atol=1e-5)

    # finished checkpoints train nothing more
    again = train_substance_net(data, val, config, checkpoint=resumed.checkpoint)
    assert again.epochs_run == []


def test_predict_substances_returns_probabilities_at_image_size() -> None:
    data = toy_substances(2)
    result = train_substance_net(data, None, get_config("tiny", epochs=1, iters_per_epoch=1))
    model = load_model(checkpoint_from_bytes(checkpoint_to_bytes(result.checkpoint)))
    probs = predict_substances(model, data.images[0][:30, :30], size=32)
    assert probs.shape == (NUM_CLASSES, 30, 30)
    np.testing.assert_allclose(probs.sum(axis=0), 1.0, atol=1e-4)


def test_metrics_from_confusion() -> None:
    target = np.array([[0, 0, 1, 1]])
    pred = np.array([[0, 1, 1, 1]])
    metrics = metrics_from_confusion(confusion_matrix(pred, target))
    assert metrics["pixel_accuracy"] == pytest.approx(0.75)
    assert metrics["foreground_accuracy"] == pytest.approx(1.0)
    assert metrics["iou"]["background"] == pytest.approx(0.5)
    assert metrics["iou"]["leather"] == pytest.approx(2 / 3)
    assert metrics["iou"]["wood"] is None


def test_training_frames_renders_and_blur_is_seeded() -> None:
    """Renders are cut to the square around the object before training (as exemplars are)."""
    label = np.zeros((40, 40), np.uint8)
    label[5:15, 10:30] = 2  # a 10 x 20 object: its square is 20 x 20
    image = np.full((40, 40, 3), 255, np.uint8)
    image[label > 0] = SUBSTANCE_COLOURS[2]
    framed = SubstanceData([image], [label], ["k"]).framed()
    assert framed.labels[0].shape == (20, 20) and framed.images[0].shape == (20, 20, 3)
    assert (framed.labels[0] > 0).any(axis=0).all()  # the object spans the full width
    assert framed.keys == ["k"]

    config = replace(get_config("tiny"), blur=1.5)
    a = augment(image, label, config, np.random.default_rng(4))
    b = augment(image, label, config, np.random.default_rng(4))
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_predict_substances_averages_the_mirrored_view() -> None:
    torch.manual_seed(0)
    model = SubstanceNet(width=8).eval()
    image = toy_substances(1, size=32, seed=3).images[0]
    single = predict_substances(model, image, size=32, flip=False)
    mirrored = predict_substances(model, image[:, ::-1], size=32, flip=False)[..., ::-1]
    both = predict_substances(model, image, size=32)
    assert np.allclose(both, 0.5 * (single + mirrored), atol=1e-5)
    assert np.allclose(both.sum(axis=0), 1.0, atol=1e-5)


def test_part_weights_give_every_part_the_same_total_weight() -> None:
    parts = np.zeros((64, 64), np.uint16)
    parts[:32, :] = 1  # 2048 pixels
    parts[40:42, :4] = 2  # 8 pixels
    weights = part_weights(parts, 1.0)
    assert weights[parts == 1].sum() == pytest.approx(weights[parts == 2].sum(), rel=1e-5)
    assert weights[parts > 0].mean() == pytest.approx(1.0, rel=1e-5)
    assert (weights[parts == 0] == 1).all()
    half = part_weights(parts, 0.5)
    assert weights[parts == 2][0] > half[parts == 2][0] > 1 > half[parts == 1][0] > weights[parts == 1][0]
    assert (part_weights(parts, 0.0) == 1).all()
    sliver = parts.copy()
    sliver[63, 63] = 3  # one pixel weighs as 1/1024 of the image (4 pixels) would: twice the 8-pixel part
    assert part_weights(sliver, 1.0)[63, 63] == pytest.approx(2 * part_weights(sliver, 1.0)[40, 0], rel=1e-5)


def test_part_maps_follow_the_labels_through_framing_and_augmentation() -> None:
    data = toy_substances(3, size=40, seed=5)
    parts = [(label > 0).astype(np.uint16) * (1 + (label % 2)) for label in data.labels]
    with_parts = SubstanceData(data.images, data.labels, [], parts)
    framed = with_parts.framed()
    assert framed.parts is not None
    config = replace(get_config("tiny"), crop_scale=(0.3, 1.0))
    rng = np.random.default_rng(0)
    for image, stack in zip(framed.images, framed.label_stacks(), strict=True):
        _, out = augment(image, stack, config, rng)
        assert out.shape == (config.size, config.size, 2)
        assert ((out[..., 0] > 0) == (out[..., 1] > 0)).all()
    with pytest.raises(ValueError, match="part maps"):
        SubstanceData(data.images, data.labels, [], parts[:2])


def test_part_balanced_training_needs_part_maps_and_learns() -> None:
    torch.set_num_threads(2)
    data = toy_substances(4)
    config = get_config("tiny", epochs=1, iters_per_epoch=60, lr=1e-2, jitter=0.0, crop_scale=(1.0, 1.0), flip=False,
                        part_balance=1.0)
    with pytest.raises(ValueError, match="part maps"):
        train_substance_net(data, None, config)
    parts = [label.astype(np.uint16) for label in data.labels]  # each rectangle's label stands for its part
    result = train_substance_net(SubstanceData(data.images, data.labels, [], parts), None, config)
    metrics = result.checkpoint["metrics"]
    assert metrics["loss_last"] < 0.5 * metrics["loss_first"]
    assert metrics["pixel_accuracy"] > 0.8
    assert result.checkpoint["config"]["part_balance"] == 1.0
    assert "part_balance" not in replace(config, part_balance=0.0).to_dict()  # old rows keep their hashes


def test_a_network_trained_on_crops_reads_whole_images_at_its_read_size() -> None:
    """`read_size`: crops of `size` cut at the read scale train it; whole images are scored at that scale."""
    torch.set_num_threads(2)
    data = toy_substances(4, size=64)
    config = get_config("tiny", epochs=1, iters_per_epoch=80, lr=1e-2, jitter=0.0, flip=False,
                        read_size=64, crop_scale=(0.25, 0.25))
    image, label = augment(data.images[0], data.labels[0], config, np.random.default_rng(0))
    assert image.shape == (32, 32, 3) and label.shape == (32, 32)  # a quarter of the render, at its pitch
    result = train_substance_net(data, None, config)
    metrics = result.checkpoint["metrics"]
    assert metrics["pixels"] == 4 * 64 * 64  # whole images at the read side, not resized to 32
    assert metrics["pixel_accuracy"] > 0.8
    assert read_side_of(result.checkpoint["config"]) == 64 and config.read_side == 64
    assert read_side_of(replace(config, read_size=0).to_dict()) == 32
    assert "read_size" not in replace(config, read_size=0).to_dict()  # old rows keep their hashes
