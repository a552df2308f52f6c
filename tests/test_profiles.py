"""Typed profiles: dotted overrides are validated against the field types and recorded as given."""

from __future__ import annotations

import dataclasses

import pytest

from photoshape_flow.classify.configs import get_config
from photoshape_flow.profiles import PROFILES, ProfileError, resolve_profile
from photoshape_flow.stages import REGISTRY


def test_every_profile_has_a_config_for_every_registered_stage() -> None:
    for profile in PROFILES.values():
        for stage in REGISTRY:
            assert dataclasses.is_dataclass(stage.config(profile)), (profile.name, stage.name)


def test_presets_are_the_classifier_configs_the_old_override_dicts_built() -> None:
    """The medium classifier must hash as before: the same named preset with the same fields changed."""
    medium = PROFILES["medium"].training
    assert medium == get_config("cpu", epochs=12, max_steps_per_epoch=80, image_size=128)
    assert PROFILES["small"].substances.network.epochs == 20 and PROFILES["tiny"].training.name == "tiny"


def test_overrides_coerce_to_the_field_types() -> None:
    resolved = resolve_profile("small", ["training.epochs=3", "publish.formats=glb,obj",
                                         "training.max_steps_per_epoch=none", "ingest.previews=false",
                                         "substances.network.lr=0.01", "training_renders.env_scale_range=0.5,2",
                                         "training.augment.tone=0.2"])
    p = resolved.profile
    assert (p.training.epochs, p.publish.formats, p.training.max_steps_per_epoch) == (3, ("glb", "obj"), None)
    assert p.ingest.previews is False and p.substances.network.lr == 0.01
    assert p.training_renders.env_scale_range == (0.5, 2.0) and p.training.augment.tone == 0.2
    assert PROFILES["small"].training.epochs == 4  # the table itself is untouched
    record = resolved.record()
    assert record["name"] == "small" and record["overrides"]["training.epochs"] == "3"
    assert record["profile"]["publish"]["formats"] == ["glb", "obj"]
    assert resolve_profile("small", record["overrides"]).profile == p  # a recorded run resolves again


@pytest.mark.parametrize(("override", "message"), [
    ("training.epoch=3", "no field 'epoch'"),
    ("training.epochs=three", "not a valid int"),
    ("training.epochs=2.5", "not a valid int"),
    ("ingest.previews=maybe", "not a boolean"),
    ("epochs", "section.field=value"),
    ("publish.formats.glb=1", "no fields to set"),
    ("name=other", "no field 'name'"),
    ("inference.methods=classifier,magic", "unknown method 'magic'"),
    ("training_renders.env_scale_range=2,1", "need 0 < low <= high"),
])
def test_bad_overrides_fail_with_one_line_naming_the_path(override: str, message: str) -> None:
    with pytest.raises(ProfileError, match=message):
        resolve_profile("tiny", [override])


def test_unknown_profile_names_the_choices() -> None:
    with pytest.raises(ProfileError, match="tiny, small, medium, default, paper"):
        resolve_profile("huge")


def test_profiles_and_the_cli_load_without_torch() -> None:
    """Profiles nest the training configs, yet `photoshape --help` must not pay torch's import (~1.4 s)."""
    import subprocess
    import sys

    code = ("import sys, photoshape_flow.profiles, photoshape_flow.cli;"
            "print('torch' in sys.modules, 'photoshape_flow.stages' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


def test_medium_and_default_read_parts_at_the_fine_pitch_small_keeps_its_renders() -> None:
    """D72: 256 px bootstrap renders, 128 px crops at their pitch, photos read at 256; small and tiny as they were."""
    for name in ("medium", "default"):
        substances = PROFILES[name].substances
        assert substances.size == substances.network.read_side == 256, name
        assert substances.network.size == 128 and substances.network.crop_scale == (0.1375, 0.25), name
    for name in ("tiny", "small"):
        assert PROFILES[name].substances.network.read_size == 0, name
