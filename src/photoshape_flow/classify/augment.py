"""Training augmentations of section 5.2, in plain torch, applied identically to image and mask.

"random rotations, random crops, random aspect ratio changes, random horizontal flips, and random
chromatic/brightness/contrast shifts". The geometric part (a random-resized crop of area fraction
``crop_scale`` and aspect ratio ``aspect_ratio``, a rotation about the crop centre, a horizontal flip)
is one affine map sampled once with ``grid_sample`` for the image and the mask together, so they stay
aligned by construction. Pixels from outside the source are white in the image (the renders and
exemplars sit on white) and 0 in the mask. A crop that keeps under ``min_mask_kept`` of the region is
redrawn (up to ``max_tries``) and finally falls back to the whole image, so an example never loses
the region it is labelled by. Colour shifts (brightness, contrast, saturation, hue) and an optional
Gaussian blur (``blur``: sigma drawn from U(0, blur) pixels of the prefiltered source, before the
warp; it smooths the
path tracer's per-pixel noise, which low-sample training renders show and photos do not) touch the
image only.

Everything is drawn from an explicit `torch.Generator`, seeded per example by the dataset, so an
epoch's augmentations are reproducible and a resumed training run sees the same images.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from photoshape_flow.classify.configs import AugmentConfig


def _uniform(generator: torch.Generator, low: float, high: float) -> float:
    return low + (high - low) * float(torch.rand((), generator=generator))


def sample_affine(config: AugmentConfig, generator: torch.Generator) -> torch.Tensor:
    """A (2, 3) `affine_grid` matrix: output normalised coords -> source normalised coords."""
    area = _uniform(generator, *config.crop_scale)
    log_lo, log_hi = math.log(config.aspect_ratio[0]), math.log(config.aspect_ratio[1])
    ratio = math.exp(_uniform(generator, log_lo, log_hi))
    half_w = min(1.0, math.sqrt(area * ratio))  # half extents in normalised [-1, 1] units
    half_h = min(1.0, math.sqrt(area / ratio))
    cx = _uniform(generator, -(1.0 - half_w), 1.0 - half_w)
    cy = _uniform(generator, -(1.0 - half_h), 1.0 - half_h)
    angle = math.radians(_uniform(generator, -config.rotation_deg, config.rotation_deg))
    flip = -1.0 if config.hflip and float(torch.rand((), generator=generator)) < 0.5 else 1.0
    cos, sin = math.cos(angle), math.sin(angle)
    # source = centre + R(angle) @ diag(flip * half_w, half_h) @ output
    return torch.tensor(
        [[cos * flip * half_w, -sin * half_h, cx], [sin * flip * half_w, cos * half_h, cy]], dtype=torch.float32
    )


def warp(
    image: torch.Tensor, mask: torch.Tensor, theta: torch.Tensor, size: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Resample image (3, H, W) and mask (1, H, W) through one affine map to (C, size, size).

    The image pads with white, the mask with 0; the mask is resampled bilinearly and thresholded at
    0.5, i.e. it is exactly the region whose interpolated coverage is at least half.
    """
    grid = F.affine_grid(theta.unsqueeze(0), [1, 1, size, size], align_corners=False)
    both = torch.cat([image - 1.0, mask], dim=0).unsqueeze(0)  # zero padding of (image - 1) = white
    out = F.grid_sample(both, grid, mode="bilinear", padding_mode="zeros", align_corners=False)[0]
    return out[:3] + 1.0, (out[3:] >= 0.5).to(image.dtype)


def resize(image: torch.Tensor, mask: torch.Tensor, size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Plain resize to (size, size) for validation and inference (area filter when shrinking)."""
    mode = "area" if image.shape[-1] > size or image.shape[-2] > size else "bilinear"
    kwargs = {} if mode == "area" else {"align_corners": False}
    out = F.interpolate(torch.cat([image, mask], 0).unsqueeze(0), size=(size, size), mode=mode, **kwargs)[0]
    return out[:3].clamp(0.0, 1.0), (out[3:] >= 0.5).to(image.dtype)


def prefilter(image: torch.Tensor, mask: torch.Tensor, size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Shrink a source far larger than the output (area filter) so bilinear warping does not alias."""
    limit = int(size * 1.5)
    height, width = image.shape[-2:]
    if max(height, width) <= limit:
        return image, mask
    scale = limit / max(height, width)
    target = (max(1, round(height * scale)), max(1, round(width * scale)))
    out = F.interpolate(torch.cat([image, mask], 0).unsqueeze(0), size=target, mode="area")[0]
    return out[:3], out[3:]


def gaussian_blur(image: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of a (C, H, W) image (reflected borders); sigma <= 0.05 returns it as is."""
    if sigma <= 0.05:
        return image
    radius = max(1, int(math.ceil(3.0 * sigma)))
    taps = torch.arange(-radius, radius + 1, dtype=image.dtype)
    kernel = torch.exp(-0.5 * (taps / sigma) ** 2)
    kernel = kernel / kernel.sum()
    channels = image.shape[0]
    x = image.unsqueeze(1)  # (C, 1, H, W): one depthwise pass per channel
    x = F.conv2d(F.pad(x, (radius, radius, 0, 0), mode="reflect"), kernel.view(1, 1, 1, -1))
    x = F.conv2d(F.pad(x, (0, 0, radius, radius), mode="reflect"), kernel.view(1, 1, -1, 1))
    return x.view(channels, *image.shape[1:])


def color_jitter(image: torch.Tensor, config: AugmentConfig, generator: torch.Generator) -> torch.Tensor:
    """Random brightness, contrast, saturation and hue shifts of a (3, H, W) image in [0, 1]."""
    weights = torch.tensor([0.299, 0.587, 0.114], dtype=image.dtype).view(3, 1, 1)
    if config.brightness:
        image = image * _uniform(generator, 1 - config.brightness, 1 + config.brightness)
    if config.contrast:
        mean = (image * weights).sum(0).mean()
        image = (image - mean) * _uniform(generator, 1 - config.contrast, 1 + config.contrast) + mean
    if config.saturation:
        gray = (image * weights).sum(0, keepdim=True)
        image = (image - gray) * _uniform(generator, 1 - config.saturation, 1 + config.saturation) + gray
    if config.hue:
        image = rotate_hue(image, _uniform(generator, -config.hue, config.hue) * 2 * math.pi)
    return image.clamp(0.0, 1.0)


_RGB_TO_YIQ = torch.tensor([[0.299, 0.587, 0.114], [0.596, -0.274, -0.322], [0.211, -0.523, 0.312]])


def rotate_hue(image: torch.Tensor, angle: float) -> torch.Tensor:
    """Rotate the chroma of a (3, H, W) RGB image by `angle` radians in YIQ space (luma kept)."""
    cos, sin = math.cos(angle), math.sin(angle)
    rotation = torch.tensor([[1.0, 0.0, 0.0], [0.0, cos, -sin], [0.0, sin, cos]])
    matrix = torch.linalg.inv(_RGB_TO_YIQ) @ rotation @ _RGB_TO_YIQ
    return torch.einsum("ij,jhw->ihw", matrix.to(image.dtype), image)


def augment(
    image: torch.Tensor,
    mask: torch.Tensor,
    size: int,
    config: AugmentConfig,
    generator: torch.Generator,
) -> tuple[torch.Tensor, torch.Tensor]:
    """One random training view: image (3, size, size) in [0, 1] and binary mask (1, size, size)."""
    if not config.enabled:
        return resize(image, mask, size)
    image, mask = prefilter(image, mask, size)
    if config.blur > 0:
        image = gaussian_blur(image, _uniform(generator, 0.0, config.blur))
    source_fraction = float(mask.mean())
    out_image = out_mask = None
    for _ in range(max(1, config.max_tries)):
        theta = sample_affine(config, generator)
        out_image, out_mask = warp(image, mask, theta, size)
        # mask pixels kept, in source-area units: output fraction * crop area / full area
        crop_area = abs(float(torch.det(theta[:, :2])))
        if source_fraction == 0 or float(out_mask.mean()) * crop_area >= config.min_mask_kept * source_fraction:
            break
    else:
        out_image, out_mask = resize(image, mask, size)
    assert out_image is not None and out_mask is not None
    if config.brightness or config.contrast or config.saturation or config.hue:
        out_image = color_jitter(out_image, config, generator)
    out_image = photo_degradation(out_image, config, generator)
    return out_image.clamp(0.0, 1.0), out_mask


def photo_degradation(image: torch.Tensor, config: AugmentConfig, generator: torch.Generator) -> torch.Tensor:
    """Tone curve, white balance, sensor noise and JPEG compression of a (3, H, W) image in [0, 1], each
    if enabled.

    The ranges follow what a product photo shows and a clean render does not (the demo's exemplar
    degradation, `demo.exemplars.sample_degradation`, is of the same kind; the ranges here are wider,
    as another camera's are).
    """
    if config.tone:
        image = image.clamp(0, 1) ** math.exp(float(torch.randn((), generator=generator)) * config.tone)
    if config.white_balance:
        gains = torch.exp(torch.randn(3, generator=generator, dtype=image.dtype) * config.white_balance)
        image = (image * (gains / (gains * torch.tensor([0.2126, 0.7152, 0.0722])).sum()).view(3, 1, 1)).clamp(0, 1)
    if config.noise:
        sigma = _uniform(generator, 0.0, config.noise) / 255.0
        image = (image + torch.randn(image.shape, generator=generator, dtype=image.dtype) * sigma).clamp(0, 1)
    if config.jpeg_quality:
        quality = int(_uniform(generator, config.jpeg_quality, 95.0))
        image = jpeg_roundtrip(image, quality)
    return image


def jpeg_roundtrip(image: torch.Tensor, quality: int) -> torch.Tensor:
    """A (3, H, W) image in [0, 1] encoded as JPEG at `quality` and decoded again."""
    rgb = (image.permute(1, 2, 0).numpy() * 255.0 + 0.5).astype(np.uint8)
    ok, buffer = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    decoded = cv2.imdecode(buffer, cv2.IMREAD_COLOR)[..., ::-1]
    return torch.from_numpy(np.ascontiguousarray(decoded)).permute(2, 0, 1).to(image.dtype) / 255.0
