"""The headline of an evaluation: ours against each baseline on the main metrics, then the shared
stages' main figures, as rows of plain strings.

`photoshape eval`, `photoshape demo` and the `evaluate` flow all print (or publish) these rows first
and the full metric table below, so a reader sees the comparison before the 80 figures behind it.
Pure functions over `Metric`s: no database, no terminal.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from photoshape_flow.vocab import ASSIGNMENT_METHODS

# (metric, column title); RMSE is the one where lower is better
HEADLINE_METRICS: tuple[tuple[str, str], ...] = (
    ("material_top1", "material top-1"),
    ("material_top5", "material top-5"),
    ("substance_accuracy", "substance"),
    ("rerender_rmse", "re-render RMSE (lower)"),
    ("rerender_ssim", "re-render SSIM"),
)
OURS = "classifier"
MISSING = "-"


def fmt(value: float | None, digits: int = 3) -> str:
    return MISSING if value is None else f"{value:.{digits}f}"


def _method_order(method_key: str) -> tuple[int, int, str]:
    """Ours first (the newest classifier first), then the baselines in the order tables list them."""
    base, _, suffix = method_key.partition(":")
    rank = ASSIGNMENT_METHODS.index(base) if base in ASSIGNMENT_METHODS else len(ASSIGNMENT_METHODS)
    return rank, -int(suffix) if suffix.isdigit() else 0, method_key


def _method_label(method_key: str) -> str:
    base, _, suffix = method_key.partition(":")
    if base == OURS:
        return f"ours (classifier {suffix})" if suffix else "ours"
    return f"baseline: {method_key}"


def headline_rows(metrics: Sequence[Any]) -> list[dict[str, str]]:
    """One row per assignment method (ours first): the main inference metrics, how far top-1 lies from
    ours, and how many parts were scored."""
    values = {(x.method, x.metric): x for x in metrics if x.stage == "inference"}
    methods = sorted({method for method, _ in values}, key=_method_order)
    ours = next((k for k in methods if k.partition(":")[0] == OURS), None)
    reference = values.get((ours, "material_top1")) if ours else None
    rows = []
    for method in methods:
        row = {"method": _method_label(method)}
        for metric, title in HEADLINE_METRICS:
            found = values.get((method, metric))
            row[title] = fmt(found.value if found else None)
        top1 = values.get((method, "material_top1"))
        if method == ours or reference is None or reference.value is None or top1 is None or top1.value is None:
            row["top-1 vs ours"] = ""
        else:
            row["top-1 vs ours"] = f"{top1.value - reference.value:+.3f}"
        row["parts scored"] = str(top1.count) if top1 and top1.count is not None else MISSING
        rows.append(row)
    return rows


def _joined(values: dict[str, float | None], names: Sequence[str], sep: str, unit: str = "", digits: int = 3) -> str:
    return sep.join(MISSING if values.get(n) is None else f"{fmt(values[n], digits)}{unit}" for n in names)


def stage_rows(metrics: Sequence[Any]) -> list[dict[str, str]]:
    """The shared stages' main figures (retrieval, pose, part labels, substances), where measured."""
    by_stage: dict[str, dict[str, float | None]] = {}
    counts: dict[tuple[str, str], int | None] = {}
    for x in metrics:
        by_stage.setdefault(x.stage, {})[x.metric] = x.value
        counts[(x.stage, x.metric)] = x.count
    coarse, fine = by_stage.get("coarse-alignment", {}), by_stage.get("fine-alignment", {})
    subs = by_stage.get("substances", {})

    def over(value: float | None, what: str) -> str:
        return MISSING if value is None else f"{int(value)} {what}"

    rows = []
    if coarse.get("recall@1") is not None:
        rows.append({"figure": "shape recall@1 / @5", "value": _joined(coarse, ("recall@1", "recall@5"), " / "),
                     "over": over(coarse.get("n_in_collection"), "exemplars of a collection shape")})
    if coarse.get("median_azimuth_error_deg") is not None:
        rows.append({"figure": "median pose error, azimuth / elevation",
                     "value": _joined(coarse, ("median_azimuth_error_deg", "median_elevation_error_deg"), " / ",
                                      " deg", 1),
                     "over": over(coarse.get("n_pose"), "exemplars with a camera")})
    if fine.get("accuracy_crf") is not None:
        rows.append({"figure": "part-label accuracy, coarse -> flow -> CRF (ours)",
                     "value": _joined(fine, ("accuracy_coarse", "accuracy_flow", "accuracy_crf"), " -> "),
                     "over": over(fine.get("n_exact"), "pairs of the true shape")})
    if subs.get("part_substance_accuracy") is not None:
        n = counts.get(("substances", "part_substance_accuracy"))
        rows.append({"figure": "substance network, part accuracy", "value": fmt(subs["part_substance_accuracy"]),
                     "over": over(n, "parts")})
    return rows
