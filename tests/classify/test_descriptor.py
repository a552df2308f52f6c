"""The shared photo/material descriptor (`classify.descriptor`), through the real ImageNet weights."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from photoshape_flow.classify import checkpoint as ckpt
from photoshape_flow.classify.configs import config_hash, get_config
from photoshape_flow.classify.dataset import RegionExample
from photoshape_flow.classify.descriptor import MaterialDescriptor, fit_prototypes
from photoshape_flow.classify.networks import build_network, grow_materials
from photoshape_flow.classify.part_net import NUM_SUBSTANCE_OUTPUTS
from photoshape_flow.profiles import ProfileError, resolve_profile


def _texture(kind: int, rng: np.random.Generator, size: int = 48) -> np.ndarray:
    """One grey part whose texture says its material: flat (0), stripes (1), checks (2), dots (3)."""
    yy, xx = np.mgrid[0:size, 0:size] + rng.integers(0, 8, 2)[:, None, None]
    period = rng.uniform(5, 7)
    pattern = {0: np.zeros((size, size)),
               1: np.sign(np.sin(xx * 2 * np.pi / period)),
               2: np.sign(np.sin(xx * 2 * np.pi / period) * np.sin(yy * 2 * np.pi / period)),
               3: ((xx % round(period) < 2) & (yy % round(period) < 2)) * 2.0 - 1.0}[kind]
    grey = 0.5 + 0.3 * pattern + rng.normal(0, 0.02, (size, size))
    return np.repeat(np.clip(grey, 0, 1)[..., None], 3, 2)


def _part(kind: int, rng: np.random.Generator) -> torch.Tensor:
    image, mask = np.ones((64, 64, 3)), np.zeros((64, 64, 1))
    image[8:56, 8:56], mask[8:56, 8:56] = _texture(kind, rng), 1
    return torch.from_numpy(np.concatenate([image, mask], 2)).permute(2, 0, 1).float()


class _Parts(torch.utils.data.Dataset):
    """Rendered parts as `fit_prototypes` reads them: (x, label, substance) with `examples`."""

    def __init__(self, kinds: list[int], labels: dict[int, int], seed: int):
        rng = np.random.default_rng(seed)
        self.x = [_part(k, rng) for k in kinds]
        self.examples = [RegionExample(i, labels[k], labels[k], 1, 0) for i, k in enumerate(kinds)]

    def __len__(self) -> int:
        return len(self.x)

    def __getitem__(self, i: int) -> tuple[torch.Tensor, int, int]:
        return self.x[i], self.examples[i].label, 1


@pytest.fixture(scope="module")
def network() -> MaterialDescriptor:
    torch.manual_seed(0)
    return MaterialDescriptor("efficientnet-lite0", num_materials=3, crop_size=64, dropout=0.0).eval()


def test_the_descriptor_keeps_the_networks_contract_and_reads_prototypes_once_set(network):
    x = torch.stack([_part(k, np.random.default_rng(k)) for k in (0, 1)])
    with torch.no_grad():
        logits, substances = network(x)
    assert logits.shape == (2, 4) and substances.shape == (2, NUM_SUBSTANCE_OUTPUTS)
    assert float(logits.abs().max()) <= 16.0 + 1e-4  # scaled cosines
    with torch.no_grad():
        d = network.describe(x)
    assert torch.allclose(d.norm(dim=1), torch.ones(2), atol=1e-5)
    # material 3's prototype is part 0's own descriptor: that part now reads material 3 at cosine 1
    network.set_prototypes(torch.cat([d, d[:1]]), torch.tensor([1, 2, 3]))
    with torch.no_grad():
        after = network(x)[0]
    assert after[0, 3] == pytest.approx(16.0, abs=1e-3) and after[1, 2] == pytest.approx(16.0, abs=1e-3)


def test_a_material_added_after_training_is_recognised_from_its_renders_without_a_retrain():
    """Materials 0-1 known; 'checks' and 'dots' added later: their renders alone make them readable."""
    torch.manual_seed(0)
    network = MaterialDescriptor("efficientnet-lite0", num_materials=2, crop_size=64, dropout=0.0).eval()
    known = _Parts([0, 1] * 6, {0: 1, 1: 2}, seed=1)
    fit_prototypes(network, known, per_material=6)
    grown = grow_materials(network, [11, 12], [11, 12, 13, 14], {11: "wood", 12: "wood", 13: "metal", 14: "metal"})
    assert grown.fc_material.rows == 5 and not bool(grown.has_prototypes)
    renders = _Parts([0, 1, 2, 3] * 6, {0: 1, 1: 2, 2: 3, 3: 4}, seed=2)
    assert fit_prototypes(grown, renders, per_material=6) == 24
    photos = _Parts([0, 1, 2, 3] * 5, {0: 1, 1: 2, 2: 3, 3: 4}, seed=3)  # other draws of the same materials
    x = torch.stack(photos.x)
    with torch.no_grad():
        predicted = grown(x)[0][:, 1:].argmax(1) + 1
    truth = torch.tensor([e.label for e in photos.examples])
    assert float((predicted == truth).float().mean()) >= 0.9
    added = truth >= 3
    assert float((predicted[added] == truth[added]).float().mean()) >= 0.9


def test_the_descriptor_round_trips_through_a_checkpoint_with_its_prototypes():
    config = get_config("tiny", arch="efficientnet-lite0", crop_size=48, head="descriptor")
    model = build_network(config, 3, seed=0)
    assert isinstance(model, MaterialDescriptor) and config.architecture == "efficientnet-lite0-desc48"
    model.eval()
    x = torch.stack([_part(k, np.random.default_rng(k)) for k in (0, 1, 2)])
    with torch.no_grad():
        model.set_prototypes(model.describe(x), torch.tensor([1, 2, 3]))
        expected = model(x)[0]
    data = ckpt.make_checkpoint(model, materials=[1, 2, 3], material_substances=["wood"] * 3, image_size=64,
                                config=config.to_dict(), epoch=1)
    rebuilt = ckpt.build_model(ckpt.load(ckpt.to_bytes(data))).eval()
    with torch.no_grad():
        assert torch.equal(rebuilt(x)[0], expected)


def test_the_head_field_keeps_the_two_head_networks_hashes_and_needs_a_backbone():
    # the hashes before the field existed: classifiers trained with them are reused, not retrained
    assert config_hash(get_config("backbone")) == "f5919bcd79db3e646589839d00e26974f8c7c43406194dd365c690eca4fb039e"
    assert config_hash(get_config("cpu")) == "4239563ae0b46f5e7dfebd4c0015c8bff5491542c90d74a3932fcfa8936bf87e"
    assert config_hash(get_config("backbone", head="descriptor")) != config_hash(get_config("backbone"))
    with pytest.raises(ValueError, match="pretrained backbone"):
        build_network(get_config("tiny", head="descriptor"), 2)
    with pytest.raises(ValueError, match="not one of"):
        get_config("backbone", head="linear")
    with pytest.raises(ProfileError, match="training: head 'descriptor' needs a pretrained backbone"):
        resolve_profile("small", ["training.head=descriptor"])
    resolved = resolve_profile("small", ["training.head=descriptor", "training.arch=efficientnet-lite0"])
    assert resolved.profile.training.architecture == "efficientnet-lite0-desc160"
    with pytest.raises(ProfileError, match="training.head: head: 'linear' is not one of heads, descriptor"):
        resolve_profile("small", ["training.head=linear"])
