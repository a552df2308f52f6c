"""`experiments.small_parts.compare` pools trainings per photo and keeps small and larger parts apart."""

from __future__ import annotations

from experiments.small_parts.compare import mean, pooled

RULE = "network (whole photo)"


def _result(small: dict[str, list[float]], large: dict[str, list[float]]) -> dict:
    return {"world": {"by_photo": {"small": {RULE: small, "colour": {}}, "large": large}}}


def test_pooled_reads_join_per_photo_across_trainings() -> None:
    seed0 = _result({"p1": [1.0, 0.0]}, {"p1": [1.0], "p2": [0.0, 0.0]})
    seed1 = _result({"p1": [1.0, 1.0]}, {"p1": [0.0], "p2": [1.0, 1.0]})
    reads = pooled([seed0, seed1], "world", RULE)
    assert reads["small parts"] == {"p1": [1.0, 0.0, 1.0, 1.0]}
    assert reads["larger parts"] == {"p1": [1.0, 0.0], "p2": [0.0, 0.0, 1.0, 1.0]}
    assert sorted(reads["every part"]["p1"]) == [0.0, 0.0, 1.0, 1.0, 1.0, 1.0]
    assert mean(reads["small parts"], {"p1"}) == 0.75
    assert mean(reads["larger parts"], {"p1", "p2"}) == 0.5
