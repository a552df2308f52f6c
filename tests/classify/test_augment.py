"""Augmentations: image and mask stay aligned, draws are reproducible, the region survives the crop."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from photoshape_flow.classify.augment import (
    AugmentConfig,
    augment,
    gaussian_blur,
    photo_degradation,
    rotate_hue,
    sample_affine,
    warp,
)

GEOMETRY_ONLY = AugmentConfig(brightness=0.0, contrast=0.0, saturation=0.0, hue=0.0, rotation_deg=25.0)


def _pattern(size: int = 40) -> tuple[torch.Tensor, torch.Tensor]:
    """A mask with an asymmetric shape, and an image whose red channel is 1 - mask (outside = white)."""
    mask = torch.zeros(1, size, size)
    mask[0, 5:20, 8:30] = 1.0
    mask[0, 20:34, 8:14] = 1.0  # an L: flips and rotations are visible
    image = torch.ones(3, size, size)
    image[0] = 1.0 - mask[0]
    image[1] = torch.linspace(0, 1, size)[None, :].expand(size, size)
    return image, mask


def test_geometric_augmentation_keeps_image_and_mask_aligned() -> None:
    image, mask = _pattern()
    changed = 0
    for seed in range(12):
        out_img, out_mask = augment(image, mask, 32, GEOMETRY_ONLY, torch.Generator().manual_seed(seed))
        assert out_img.shape == (3, 32, 32) and out_mask.shape == (1, 32, 32)
        assert set(out_mask.unique().tolist()) <= {0.0, 1.0}
        # red = 1 - mask was warped with the same grid: the thresholded red channel is the mask
        from_image = (out_img[0] < 0.5).float()
        disagree = (from_image != out_mask).float().mean()
        assert float(disagree) <= 0.01, seed  # only exact-0.5 ties may differ
        resized = torch.nn.functional.interpolate(mask[None], size=(32, 32), mode="area")[0] >= 0.5
        changed += int(not torch.equal(out_mask.bool(), resized))
    assert changed >= 10  # the transforms actually do something


def test_warp_identity_and_flip() -> None:
    image, mask = _pattern(32)
    identity = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    out_img, out_mask = warp(image, mask, identity, 32)
    assert torch.allclose(out_img, image, atol=1e-5) and torch.equal(out_mask, mask)
    flip = torch.tensor([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    out_img, out_mask = warp(image, mask, flip, 32)
    assert torch.equal(out_mask, mask.flip(-1))
    assert torch.allclose(out_img, image.flip(-1), atol=1e-5)


def test_augmentation_is_reproducible_per_generator_seed() -> None:
    image, mask = _pattern()
    config = AugmentConfig()
    a = augment(image, mask, 24, config, torch.Generator().manual_seed(7))
    b = augment(image, mask, 24, config, torch.Generator().manual_seed(7))
    c = augment(image, mask, 24, config, torch.Generator().manual_seed(8))
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    assert not torch.equal(a[0], c[0])


def test_small_region_is_never_cropped_away() -> None:
    mask = torch.zeros(1, 64, 64)
    mask[0, 0:6, 58:64] = 1.0  # a corner region: most crops lose it
    image = torch.ones(3, 64, 64)
    config = AugmentConfig(crop_scale=(0.2, 0.3), min_mask_kept=0.5)
    for seed in range(20):
        _, out_mask = augment(image, mask, 32, config, torch.Generator().manual_seed(seed))
        assert float(out_mask.sum()) > 0


def test_colour_jitter_changes_colour_only_within_range() -> None:
    image, mask = _pattern()
    colour_only = AugmentConfig(rotation_deg=0.0, crop_scale=(1.0, 1.0), aspect_ratio=(1.0, 1.0), hflip=False)
    out_img, out_mask = augment(image, mask, 40, colour_only, torch.Generator().manual_seed(3))
    assert torch.equal(out_mask, mask)
    assert float(out_img.min()) >= 0.0 and float(out_img.max()) <= 1.0
    assert not torch.allclose(out_img, image, atol=1e-3)


def test_hue_rotation_keeps_gray_and_full_turn_is_identity() -> None:
    gray = torch.full((3, 4, 4), 0.4)
    assert torch.allclose(rotate_hue(gray, 1.0), gray, atol=1e-5)
    colour = torch.rand(3, 4, 4)
    assert torch.allclose(rotate_hue(colour, 2 * torch.pi), colour, atol=1e-5)


def test_sample_affine_respects_crop_bounds() -> None:
    config = AugmentConfig(rotation_deg=0.0, hflip=False)
    for seed in range(50):
        theta = sample_affine(config, torch.Generator().manual_seed(seed))
        half_w, half_h, cx, cy = float(theta[0, 0]), float(theta[1, 1]), float(theta[0, 2]), float(theta[1, 2])
        assert abs(cx) + half_w <= 1.0 + 1e-6 and abs(cy) + half_h <= 1.0 + 1e-6
        assert 0.5 - 1e-6 <= half_w * half_h <= 1.0 + 1e-6 or half_w == 1.0 or half_h == 1.0


def test_gaussian_blur_smooths_noise_and_keeps_flat_images() -> None:
    flat = torch.full((3, 16, 16), 0.4)
    assert torch.allclose(gaussian_blur(flat, 1.0), flat, atol=1e-6)  # normalised kernel, reflected borders
    noise = torch.rand(3, 32, 32, generator=torch.Generator().manual_seed(0))
    blurred = gaussian_blur(noise, 1.0)
    assert blurred.shape == noise.shape
    assert float(blurred.std()) < 0.5 * float(noise.std())
    assert float(blurred.mean()) == pytest.approx(float(noise.mean()), abs=0.01)
    assert gaussian_blur(noise, 0.0) is noise


def test_blur_option_blurs_the_image_not_the_mask() -> None:
    image, mask = _pattern()
    sharp_cfg = AugmentConfig(brightness=0.0, contrast=0.0, saturation=0.0, hue=0.0, rotation_deg=0.0,
                              crop_scale=(1.0, 1.0), aspect_ratio=(1.0, 1.0), hflip=False)
    blur_cfg = replace(sharp_cfg, blur=2.0)
    edge = lambda x: float((x[0, :, 1:] - x[0, :, :-1]).abs().max())  # noqa: E731
    edges = []
    for seed in range(8):  # sigma ~ U(0, 2): some draws barely blur, most do
        sharp_img, sharp_mask = augment(image, mask, 40, sharp_cfg, torch.Generator().manual_seed(seed))
        blur_img, blur_mask = augment(image, mask, 40, blur_cfg, torch.Generator().manual_seed(seed))
        assert torch.equal(sharp_mask, blur_mask)  # geometry unchanged: the mask stays binary and in place
        assert edge(sharp_img) == pytest.approx(1.0)
        edges.append(edge(blur_img))
    assert sum(e < 0.6 for e in edges) >= 4


def test_tone_curve_is_a_monotonic_gamma_that_keeps_black_and_white() -> None:
    ramp = torch.linspace(0.0, 1.0, 64).view(1, 1, 64).repeat(3, 8, 1)
    untouched = photo_degradation(ramp, AugmentConfig(), torch.Generator().manual_seed(0))
    assert torch.equal(untouched, ramp)  # off by default: no draw, no change
    exponents = []
    for seed in range(20):
        out = photo_degradation(ramp, AugmentConfig(tone=0.3), torch.Generator().manual_seed(seed))
        assert float(out[..., 0].max()) == 0.0 and torch.allclose(out[..., -1], torch.ones(3, 8))
        assert bool((out[..., 1:] >= out[..., :-1]).all())  # monotonic: the order of tones is kept
        mid = float(out[0, 0, 32])
        exponents.append(math.log(mid) / math.log(float(ramp[0, 0, 32])))
    assert min(exponents) < 0.9 and max(exponents) > 1.1  # both brighter and darker curves are drawn
