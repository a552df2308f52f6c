"""Named configurations: the paper's settings, JSON round trip, hashes."""

from __future__ import annotations

import pytest

from photoshape_flow.classify.configs import ClassifierConfig, config_hash, get_config


def test_paper_config_is_section_5_2() -> None:
    paper = get_config("paper")
    assert (paper.arch, paper.image_size, paper.optimizer, paper.lr, paper.momentum) == (
        "resnet34", 224, "sgd", 1e-4, 0.9)
    assert paper.weight_decay == 1e-4 and paper.epochs == 100
    assert paper.loss_mode == "uncertainty"
    assert (paper.init_log_var_material, paper.init_log_var_substance) == (0.0, -1.0)


def test_round_trip_and_hash() -> None:
    for name in ("tiny", "cpu", "paper"):
        config = get_config(name)
        again = ClassifierConfig.from_dict(config.to_dict())
        assert again == config
        assert config_hash(again) == config_hash(config)
    cpu = get_config("cpu")
    assert config_hash(cpu.replace(lr=2e-3)) != config_hash(cpu)
    assert config_hash(cpu.replace(num_workers=3)) == config_hash(cpu)  # does not change the model
    assert get_config("cpu", pretrained="x.pth").pretrained == "x.pth"
    assert get_config("tiny").architecture == "resnet18-w8" and cpu.architecture == "resnet18"
    with pytest.raises(ValueError, match="unknown classifier config"):
        get_config("huge")


def test_recogniser_fields_leave_the_resnet_hashes_as_they_were() -> None:
    """Classifiers trained before the recogniser keep their params_hash (no retrain on upgrade)."""
    from photoshape_flow.classify.configs import AugmentConfig, config_hash, get_config

    resnet = get_config("cpu")
    assert config_hash(resnet.replace(crop_size=999, isolate_part=False)) == config_hash(resnet)
    assert config_hash(resnet.replace(augment=AugmentConfig(hue=0.02, saturation=0.15, jpeg_quality=70))) != \
        config_hash(resnet)
    backbone = get_config("backbone")
    assert config_hash(backbone.replace(crop_size=224)) != config_hash(backbone)
