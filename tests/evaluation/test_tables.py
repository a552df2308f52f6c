"""`evaluation/tables.py`: the headline `photoshape eval`, `demo` and the evaluate flow show first."""

from __future__ import annotations

from photoshape_flow.evaluation.tables import headline_rows, stage_rows
from photoshape_flow.scoring.evaluate import Metric


def test_headline_puts_ours_first_then_the_baselines_with_the_gap_in_top1() -> None:
    """Ours is the newest classifier; baselines follow in vocab order whatever order the metrics came
    in; a missing figure is a dash, never an empty or JSON cell; the gap is to the newest classifier."""
    metrics = [
        Metric("inference", "builtin", "rerender_rmse", 0.25, 4),
        Metric("inference", "color-match", "material_top1", 0.5, 8),
        Metric("inference", "classifier:2", "material_top1", 0.75, 8),
        Metric("inference", "classifier:1", "material_top1", 0.625, 8),
        Metric("inference", "classifier:2", "rerender_ssim", None, 0),
        Metric("substances", "substance-network", "part_substance_accuracy", 0.9, 8),  # not a method row
    ]
    rows = headline_rows(metrics)
    assert [r["method"] for r in rows] == ["ours (classifier 2)", "ours (classifier 1)", "color-match", "builtin"]
    assert rows[0] == {"method": "ours (classifier 2)", "top-1": "0.750", "top-5": "-", "subst.": "-", "RMSE": "-",
                       "SSIM": "-", "relit": "-", "vs ours": ""}
    assert [r["vs ours"] for r in rows[1:]] == ["-0.125", "-0.250", ""]  # builtin has no top-1
    assert rows[3]["RMSE"] == "0.250"
    assert headline_rows(metrics[-1:]) == []


def test_a_refining_method_gets_a_refined_row_below_its_selection() -> None:
    """Before fit (ours), after selection (fit), after refinement (fit refined): the refined row takes the
    rendered figures from `<metric>_refined` and the rest (materials did not change) from the selection."""
    metrics = [
        Metric("inference", "classifier:2", "material_top1", 0.5, 8),
        Metric("inference", "fit:2", "material_top1", 0.625, 8),
        Metric("inference", "fit:2", "rerender_rmse", 0.25, 4),
        Metric("inference", "fit:2", "rerender_rmse_refined", 0.2, 4),
        Metric("inference", "fit:2", "relight_rmse", 0.1, 3),
    ]
    rows = headline_rows(metrics)
    assert [r["method"] for r in rows] == ["ours (classifier 2)", "fit:2", "fit:2 refined"]
    assert (rows[1]["RMSE"], rows[2]["RMSE"]) == ("0.250", "0.200")
    assert rows[2]["top-1"] == rows[1]["top-1"] == "0.625" and rows[2]["relit"] == "0.100"
    assert rows[2]["vs ours"] == rows[1]["vs ours"] == "+0.125"


def test_stage_rows_show_only_what_was_measured() -> None:
    metrics = [
        Metric("coarse-alignment", "hog", "recall@1", 0.8, None),
        Metric("coarse-alignment", "hog", "recall@5", 1.0, None),
        Metric("coarse-alignment", "hog", "n_in_collection", 5.0, None),
        Metric("coarse-alignment", "hog", "median_azimuth_error_deg", None, None),  # no camera given
        Metric("fine-alignment", "flow-crf", "accuracy_coarse", 0.5, None),
        Metric("fine-alignment", "flow-crf", "accuracy_crf", 0.9, None),
        Metric("fine-alignment", "flow-crf", "n_exact", 3.0, None),
        Metric("substances", "substance-network", "part_substance_accuracy", 0.75, 12),
    ]
    assert stage_rows(metrics) == [
        {"figure": "shape recall@1 / @5", "value": "0.800 / 1.000", "over": "5 exemplars"},
        {"figure": "part labels coarse / flow / CRF", "value": "0.500 / - / 0.900", "over": "3 pairs"},
        {"figure": "substance network", "value": "0.750", "over": "12 parts"},
    ]
