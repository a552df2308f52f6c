"""Method keys: built and read by one type, the stored text unchanged."""

from __future__ import annotations

import pytest

from photoshape_flow.method_keys import MethodKey, classifier_id_of, is_method_name, method_of


@pytest.mark.parametrize("text", ["classifier:3", "fit:12", "color-match", "no-classifier", "builtin", "classifier"])
def test_a_stored_key_round_trips(text: str) -> None:
    assert str(MethodKey.parse(text)) == text


def test_builders_write_the_stored_strings() -> None:
    assert str(MethodKey.for_classifier(3)) == "classifier:3"
    assert str(MethodKey.fit_of(3)) == "fit:3"
    assert str(MethodKey("color-match")) == "color-match"
    assert MethodKey.parse("fit:7") == MethodKey("fit", 7) == MethodKey.fit_of(7)
    assert MethodKey.parse("builtin").classifier_id is None


@pytest.mark.parametrize("text", ["", ":3", "classifier:", "classifier:x", "classifier:-1", "classifier:03",
                                  "fit:3:4", "classifier: 3", "classifier:²"])
def test_an_invalid_key_is_a_clear_value_error(text: str) -> None:
    with pytest.raises(ValueError, match="not a method key"):
        MethodKey.parse(text)


def test_the_constructor_checks_its_parts() -> None:
    for method, classifier_id in (("fit:3", None), ("", 1), ("fit", -1), ("fit", True), ("fit", "3")):
        with pytest.raises(ValueError):
            MethodKey(method, classifier_id)  # type: ignore[arg-type]


def test_lenient_readers_never_raise() -> None:
    assert method_of("fit:3") == "fit" and method_of("color-match") == "color-match" and method_of("x:y") == "x"
    assert classifier_id_of("classifier:3") == 3
    assert classifier_id_of("classifier") is None and classifier_id_of("classifier:x") is None
    assert is_method_name("classifier") and not is_method_name("classifier:3")
