"""The headline of an evaluation: ours against each baseline on the main metrics, then the shared
stages' main figures, as rows of plain strings.

`photoshape eval`, `photoshape demo` and the `evaluate` flow all print (or publish) these rows first
and the full metric table below, so a reader sees the comparison before the 80 figures behind it.
Pure functions over `Metric`s: no database, no terminal.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from photoshape_flow.method_keys import CLASSIFIER, classifier_id_of, method_of
from photoshape_flow.vocab import ASSIGNMENT_METHODS

# (metric, column title): short titles so the table fits an 80-column terminal; HEADLINE_TITLE says
# what they are (RMSE is the one where lower is better)
HEADLINE_METRICS: tuple[tuple[str, str], ...] = (
    ("material_top1", "top-1"),
    ("material_top5", "top-5"),
    ("substance_accuracy", "subst."),
    ("rerender_rmse", "RMSE"),
    ("rerender_ssim", "SSIM"),
    ("relight_rmse", "relit"),
)
HEADLINE_TITLE = ("ours, then each baseline: material top-1 / top-5 and substance accuracy per scored part "
                  "(\"vs ours\": top-1 minus ours', with its paired 95% bootstrap interval over exemplars), "
                  "re-render RMSE (lower is better) and SSIM per pair, relighting RMSE (\"relit\", lower is "
                  "better: held-out light, novel views, own shape); "
                  "how many were scored is in the full table; a method that refines its winners (fit) has a "
                  "second row, \"refined\", rendered with the refinements (its materials, so top-1/5 and "
                  "substance, are those of the selection)")
STAGES_TITLE = ("shared stages: recall and pose over exemplars of a collection shape (pose: those with a "
                "camera), part labels over pairs of the true shape with a part mask, substances over parts")
OURS = CLASSIFIER
REFINED = "_refined"  # suffix of a rendered figure made with the rank-1 rows' refinements (`scoring.rerender_eval`)
MISSING = "-"


def fmt(value: float | None, digits: int = 3) -> str:
    return MISSING if value is None else f"{value:.{digits}f}"


def _method_order(method_key: str) -> tuple[int, int, str]:
    """Ours first (the newest classifier first), then the baselines in the order tables list them."""
    base, classifier_id = method_of(method_key), classifier_id_of(method_key)
    rank = ASSIGNMENT_METHODS.index(base) if base in ASSIGNMENT_METHODS else len(ASSIGNMENT_METHODS)
    return rank, -classifier_id if classifier_id is not None else 0, method_key


def _method_label(method_key: str) -> str:
    if method_of(method_key) == OURS:
        classifier_id = classifier_id_of(method_key)
        return f"ours (classifier {classifier_id})" if classifier_id is not None else "ours"
    return method_key


def headline_rows(metrics: Sequence[Any]) -> list[dict[str, str]]:
    """One row per assignment method (ours first, then the baselines): the main inference metrics and
    how far top-1 lies from ours. Narrow on purpose (fits 80 columns); counts are in the full table."""
    values = {(x.method, x.metric): x for x in metrics if x.stage == "inference"}
    methods = sorted({method for method, _ in values}, key=_method_order)
    ours = next((k for k in methods if method_of(k) == OURS), None)
    reference = values.get((ours, "material_top1")) if ours else None
    rows = []
    for method in methods:
        row = {"method": _method_label(method)}
        for metric, title in HEADLINE_METRICS:
            found = values.get((method, metric))
            row[title] = fmt(found.value if found else None)
        top1 = values.get((method, "material_top1"))
        paired = values.get((method, "material_top1_vs_ours"))
        if method == ours or reference is None or reference.value is None or top1 is None or top1.value is None:
            row["vs ours"] = ""
        elif paired is not None and paired.value is not None and getattr(paired, "low", None) is not None:
            row["vs ours"] = f"{paired.value:+.3f} ({paired.low:+.2f}, {paired.high:+.2f})"
        else:
            row["vs ours"] = f"{top1.value - reference.value:+.3f}"
        rows.append(row)
        if any((method, f"{metric}{REFINED}") in values for metric, _ in HEADLINE_METRICS):
            refined = {"method": f"{row['method']} refined"}
            for metric, title in HEADLINE_METRICS:
                found = values.get((method, f"{metric}{REFINED}")) or values.get((method, metric))
                refined[title] = fmt(found.value if found else None)
            rows.append({**refined, "vs ours": row["vs ours"]})
    return rows


def _joined(values: dict[str, float | None], names: Sequence[str], sep: str, digits: int = 3) -> str:
    return sep.join(fmt(values.get(n), digits) for n in names)


def stage_rows(metrics: Sequence[Any]) -> list[dict[str, str]]:
    """The shared stages' main figures (retrieval, pose, part labels, substances), where measured; see
    STAGES_TITLE for what each is over."""
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
                     "over": over(coarse.get("n_in_collection"), "exemplars")})
    if coarse.get("median_azimuth_error_deg") is not None:
        rows.append({"figure": "median pose error az / el (deg)",
                     "value": _joined(coarse, ("median_azimuth_error_deg", "median_elevation_error_deg"), " / ",
                                      digits=1),
                     "over": over(coarse.get("n_pose"), "exemplars")})
    if fine.get("accuracy_crf") is not None:
        rows.append({"figure": "part labels coarse / flow / CRF",
                     "value": _joined(fine, ("accuracy_coarse", "accuracy_flow", "accuracy_crf"), " / "),
                     "over": over(fine.get("n_exact"), "pairs")})
    if subs.get("part_substance_accuracy") is not None:
        n = counts.get(("substances", "part_substance_accuracy"))
        rows.append({"figure": "substance network", "value": fmt(subs["part_substance_accuracy"]),
                     "over": over(n, "parts")})
    return rows


FIGURES_LEGEND = ("value: the figure; n: how many it is over (parts, pairs or exemplars); 95% interval: "
                  "bootstrap over exemplars (`<metric>_vs_ours`: paired, that method minus ours)")


def figures_text(metrics: Sequence[Any], title: str) -> str:
    """Every figure as plain text that reads at 80 columns: a heading per stage and method, then one
    line per metric (name, value, count, 95% interval), the headline's legend on top."""
    lines = [title, "", *_wrapped(f"headline: {HEADLINE_TITLE}"), "", *_wrapped(f"headline, {STAGES_TITLE}"), "",
             *_wrapped(FIGURES_LEGEND), ""]
    width = max([len(x.metric) for x in metrics] + [6])
    heading = None
    for x in metrics:
        if (x.stage, x.method) != heading:
            heading = (x.stage, x.method)
            lines += ["", f"{x.stage} / {x.method}", f"  {'metric':<{width}} {'value':>9} {'n':>6}  95% interval"]
        interval = "" if x.low is None or x.high is None else f"{x.low:.3f} to {x.high:.3f}"
        count = "" if x.count is None else str(x.count)
        lines.append(f"  {x.metric:<{width}} {fmt(x.value, 4):>9} {count:>6}  {interval}".rstrip())
    return "\n".join(lines) + "\n"


def _wrapped(text: str, width: int = 80) -> list[str]:
    import textwrap

    return textwrap.wrap(text, width)
