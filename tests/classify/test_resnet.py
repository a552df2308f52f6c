"""ResNet with mask channel: torchvision-compatible keys, pretrained loading, growing the material head."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from photoshape_flow.classify.resnet import MaterialResNet, build_model, grow_material_head
from photoshape_flow.vocab import SUBSTANCE_LABELS

# torchvision.models.resnet34().state_dict().keys(), written out by hand (218 keys).
TORCHVISION_RESNET34_KEYS = """
conv1.weight bn1.weight bn1.bias bn1.running_mean bn1.running_var bn1.num_batches_tracked
layer1.0.conv1.weight layer1.0.bn1.weight layer1.0.bn1.bias layer1.0.bn1.running_mean
layer1.0.bn1.running_var layer1.0.bn1.num_batches_tracked layer1.0.conv2.weight layer1.0.bn2.weight
layer1.0.bn2.bias layer1.0.bn2.running_mean layer1.0.bn2.running_var layer1.0.bn2.num_batches_tracked
layer1.1.conv1.weight layer1.1.bn1.weight layer1.1.bn1.bias layer1.1.bn1.running_mean
layer1.1.bn1.running_var layer1.1.bn1.num_batches_tracked layer1.1.conv2.weight layer1.1.bn2.weight
layer1.1.bn2.bias layer1.1.bn2.running_mean layer1.1.bn2.running_var layer1.1.bn2.num_batches_tracked
layer1.2.conv1.weight layer1.2.bn1.weight layer1.2.bn1.bias layer1.2.bn1.running_mean
layer1.2.bn1.running_var layer1.2.bn1.num_batches_tracked layer1.2.conv2.weight layer1.2.bn2.weight
layer1.2.bn2.bias layer1.2.bn2.running_mean layer1.2.bn2.running_var layer1.2.bn2.num_batches_tracked
layer2.0.conv1.weight layer2.0.bn1.weight layer2.0.bn1.bias layer2.0.bn1.running_mean
layer2.0.bn1.running_var layer2.0.bn1.num_batches_tracked layer2.0.conv2.weight layer2.0.bn2.weight
layer2.0.bn2.bias layer2.0.bn2.running_mean layer2.0.bn2.running_var layer2.0.bn2.num_batches_tracked
layer2.0.downsample.0.weight layer2.0.downsample.1.weight layer2.0.downsample.1.bias
layer2.0.downsample.1.running_mean layer2.0.downsample.1.running_var
layer2.0.downsample.1.num_batches_tracked layer2.1.conv1.weight layer2.1.bn1.weight layer2.1.bn1.bias
layer2.1.bn1.running_mean layer2.1.bn1.running_var layer2.1.bn1.num_batches_tracked layer2.1.conv2.weight
layer2.1.bn2.weight layer2.1.bn2.bias layer2.1.bn2.running_mean layer2.1.bn2.running_var
layer2.1.bn2.num_batches_tracked layer2.2.conv1.weight layer2.2.bn1.weight layer2.2.bn1.bias
layer2.2.bn1.running_mean layer2.2.bn1.running_var layer2.2.bn1.num_batches_tracked layer2.2.conv2.weight
layer2.2.bn2.weight layer2.2.bn2.bias layer2.2.bn2.running_mean layer2.2.bn2.running_var
layer2.2.bn2.num_batches_tracked layer2.3.conv1.weight layer2.3.bn1.weight layer2.3.bn1.bias
layer2.3.bn1.running_mean layer2.3.bn1.running_var layer2.3.bn1.num_batches_tracked layer2.3.conv2.weight
layer2.3.bn2.weight layer2.3.bn2.bias layer2.3.bn2.running_mean layer2.3.bn2.running_var
layer2.3.bn2.num_batches_tracked layer3.0.conv1.weight layer3.0.bn1.weight layer3.0.bn1.bias
layer3.0.bn1.running_mean layer3.0.bn1.running_var layer3.0.bn1.num_batches_tracked layer3.0.conv2.weight
layer3.0.bn2.weight layer3.0.bn2.bias layer3.0.bn2.running_mean layer3.0.bn2.running_var
layer3.0.bn2.num_batches_tracked layer3.0.downsample.0.weight layer3.0.downsample.1.weight
layer3.0.downsample.1.bias layer3.0.downsample.1.running_mean layer3.0.downsample.1.running_var
layer3.0.downsample.1.num_batches_tracked layer3.1.conv1.weight layer3.1.bn1.weight layer3.1.bn1.bias
layer3.1.bn1.running_mean layer3.1.bn1.running_var layer3.1.bn1.num_batches_tracked layer3.1.conv2.weight
layer3.1.bn2.weight layer3.1.bn2.bias layer3.1.bn2.running_mean layer3.1.bn2.running_var
layer3.1.bn2.num_batches_tracked layer3.2.conv1.weight layer3.2.bn1.weight layer3.2.bn1.bias
layer3.2.bn1.running_mean layer3.2.bn1.running_var layer3.2.bn1.num_batches_tracked layer3.2.conv2.weight
layer3.2.bn2.weight layer3.2.bn2.bias layer3.2.bn2.running_mean layer3.2.bn2.running_var
layer3.2.bn2.num_batches_tracked layer3.3.conv1.weight layer3.3.bn1.weight layer3.3.bn1.bias
layer3.3.bn1.running_mean layer3.3.bn1.running_var layer3.3.bn1.num_batches_tracked layer3.3.conv2.weight
layer3.3.bn2.weight layer3.3.bn2.bias layer3.3.bn2.running_mean layer3.3.bn2.running_var
layer3.3.bn2.num_batches_tracked layer3.4.conv1.weight layer3.4.bn1.weight layer3.4.bn1.bias
layer3.4.bn1.running_mean layer3.4.bn1.running_var layer3.4.bn1.num_batches_tracked layer3.4.conv2.weight
layer3.4.bn2.weight layer3.4.bn2.bias layer3.4.bn2.running_mean layer3.4.bn2.running_var
layer3.4.bn2.num_batches_tracked layer3.5.conv1.weight layer3.5.bn1.weight layer3.5.bn1.bias
layer3.5.bn1.running_mean layer3.5.bn1.running_var layer3.5.bn1.num_batches_tracked layer3.5.conv2.weight
layer3.5.bn2.weight layer3.5.bn2.bias layer3.5.bn2.running_mean layer3.5.bn2.running_var
layer3.5.bn2.num_batches_tracked layer4.0.conv1.weight layer4.0.bn1.weight layer4.0.bn1.bias
layer4.0.bn1.running_mean layer4.0.bn1.running_var layer4.0.bn1.num_batches_tracked layer4.0.conv2.weight
layer4.0.bn2.weight layer4.0.bn2.bias layer4.0.bn2.running_mean layer4.0.bn2.running_var
layer4.0.bn2.num_batches_tracked layer4.0.downsample.0.weight layer4.0.downsample.1.weight
layer4.0.downsample.1.bias layer4.0.downsample.1.running_mean layer4.0.downsample.1.running_var
layer4.0.downsample.1.num_batches_tracked layer4.1.conv1.weight layer4.1.bn1.weight layer4.1.bn1.bias
layer4.1.bn1.running_mean layer4.1.bn1.running_var layer4.1.bn1.num_batches_tracked layer4.1.conv2.weight
layer4.1.bn2.weight layer4.1.bn2.bias layer4.1.bn2.running_mean layer4.1.bn2.running_var
layer4.1.bn2.num_batches_tracked layer4.2.conv1.weight layer4.2.bn1.weight layer4.2.bn1.bias
layer4.2.bn1.running_mean layer4.2.bn1.running_var layer4.2.bn1.num_batches_tracked layer4.2.conv2.weight
layer4.2.bn2.weight layer4.2.bn2.bias layer4.2.bn2.running_mean layer4.2.bn2.running_var
layer4.2.bn2.num_batches_tracked fc.weight fc.bias
""".split()


def test_resnet34_keys_are_torchvision_keys_with_two_heads() -> None:
    assert len(TORCHVISION_RESNET34_KEYS) == 218
    model = MaterialResNet("resnet34", num_materials=7)
    keys = list(model.state_dict().keys())
    backbone = [k for k in keys if not k.startswith(("fc_material.", "fc_substance."))]
    expected = [k for k in TORCHVISION_RESNET34_KEYS if not k.startswith("fc.")]
    assert backbone == expected  # same names, same order
    assert set(keys) - set(backbone) == {"fc_material.weight", "fc_material.bias", "fc_substance.weight",
                                          "fc_substance.bias"}
    assert model.conv1.weight.shape == (64, 4, 7, 7)
    assert model.fc_material.out_features == 8  # 7 materials + background
    assert model.fc_substance.out_features == len(SUBSTANCE_LABELS)


def test_narrow_resnet18_forward_shapes() -> None:
    model = build_model("resnet18", 3, width=8, seed=0)
    mat, sub = model(torch.rand(2, 4, 32, 32))
    assert mat.shape == (2, 4) and sub.shape == (2, len(SUBSTANCE_LABELS))
    assert all(k.startswith(("conv1", "bn1", "layer", "fc_")) for k in model.state_dict())


def test_build_model_seed_is_reproducible_and_leaves_global_rng_alone() -> None:
    torch.manual_seed(123)
    before = torch.get_rng_state()
    a = build_model("resnet18", 2, width=8, seed=5)
    assert torch.equal(torch.get_rng_state(), before)
    b = build_model("resnet18", 2, width=8, seed=5)
    c = build_model("resnet18", 2, width=8, seed=6)
    assert torch.equal(a.conv1.weight, b.conv1.weight)
    assert not torch.equal(a.conv1.weight, c.conv1.weight)


def _torchvision_like_state(width: int = 8) -> dict[str, torch.Tensor]:
    """A state dict shaped like torchvision's resnet18 at `width` (3-channel conv1 and an fc)."""
    donor = MaterialResNet("resnet18", num_materials=1, width=width)
    state = {k: torch.randn_like(v.float()).to(v.dtype) if v.is_floating_point() else v
             for k, v in donor.state_dict().items() if not k.startswith("fc_")}
    state["conv1.weight"] = torch.randn(width, 3, 7, 7) * 0.1
    state["fc.weight"] = torch.randn(1000, width * 8)
    state["fc.bias"] = torch.randn(1000)
    return state


def test_pretrained_rgb_filters_are_copied_and_mask_filters_gaussian(tmp_path: Path) -> None:
    state = _torchvision_like_state()
    path = tmp_path / "resnet18.pth"
    torch.save(state, path)
    model = build_model("resnet18", 4, width=8, pretrained=path, seed=0)
    assert torch.equal(model.conv1.weight[:, :3], state["conv1.weight"])
    assert torch.equal(model.layer3[1].conv2.weight, state["layer3.1.conv2.weight"])
    mask_filters = model.conv1.weight[:, 3].detach()
    assert 0.03 < float(mask_filters.std()) < 0.3  # drawn with the RGB filters' std (0.1)
    assert not torch.equal(mask_filters, torch.zeros_like(mask_filters))


def test_pretrained_wrong_architecture_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "bad.pth"
    torch.save(_torchvision_like_state(width=8), path)
    with pytest.raises(ValueError, match="conv1 mismatch"):
        build_model("resnet18", 2, width=16, pretrained=path)
    with pytest.raises(FileNotFoundError):
        build_model("resnet18", 2, width=8, pretrained=tmp_path / "missing.pth")


def test_grow_material_head_keeps_old_rows_by_id() -> None:
    model = build_model("resnet18", 3, width=8, seed=0)
    old_w = model.fc_material.weight.detach().clone()
    old_b = model.fc_material.bias.detach().clone()
    old_ids, new_ids = [10, 20, 30], [10, 15, 30, 40, 20]
    substances = {10: "wood", 20: "wood", 30: "metal", 15: "wood", 40: "fabric"}
    grow_material_head(model, old_ids, new_ids, substances, generator=torch.Generator().manual_seed(0))
    w, b = model.fc_material.weight.detach(), model.fc_material.bias.detach()
    assert w.shape == (6, 64) and model.num_materials == 5
    assert torch.equal(w[0], old_w[0]) and torch.equal(b[0], old_b[0])  # background
    for new_row, mid in enumerate(new_ids, start=1):
        if mid in old_ids:
            old_row = old_ids.index(mid) + 1
            assert torch.equal(w[new_row], old_w[old_row]) and torch.equal(b[new_row], old_b[old_row])
    # new wood material 15 starts near the mean of the old wood rows (10, 20)
    wood_mean = old_w[[1, 2]].mean(0)
    assert torch.allclose(w[2], wood_mean, atol=0.05)
    assert torch.isclose(b[2], old_b[[1, 2]].mean())
    mat, _ = model(torch.rand(2, 4, 32, 32))
    assert mat.shape == (2, 6)


def test_grow_material_head_rejects_wrong_old_list() -> None:
    model = build_model("resnet18", 3, width=8, seed=0)
    with pytest.raises(ValueError, match="outputs"):
        grow_material_head(model, [1, 2], [1, 2, 3])
