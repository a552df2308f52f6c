"""The stored calibrations are one typed record that reads existing rows unchanged."""

from __future__ import annotations

from types import SimpleNamespace

from photoshape_flow.networks.calibrations import Calibration, fitted_labs

# a material classifier's and a substance network's metrics as rows written before the record hold them
MATERIAL_ROW = {
    "top1": 0.5, "history": [{"epoch": 1}],  # training's own metrics: not the record's
    "color_sigma": 12, "color_sigma_key": "k1",
    "bn_prior_choice": {"bn_prior": 4.0, "regions": 12, "renders": 5, "log_loss": {"None": 2.0}}, "bn_prior_key": "k2",
    "posterior_ece": 0.1, "posterior_reliability": {"ece": 0.1, "bins": []}, "posterior_key": "k3",
    "fit_calibration": {"key": "k4", "record": {"weights": {"lab": 1.0}, "temperature": 0.5}},
}
SUBSTANCE_ROW = {"part_temperature": 1.5, "part_temperature_parts": 30, "part_temperature_renders": 6,
                 "part_temperature_key": "k5", "part_accuracy": 0.8, "part_nll": 0.6, "part_nll_tempered": 0.5,
                 "sub@1": 0.7}


def test_existing_rows_read_unchanged_and_round_trip() -> None:
    material = Calibration.from_json(MATERIAL_ROW)
    assert material.color_sigma == 12.0 and isinstance(material.color_sigma, float)
    assert material.bn_prior == 4.0 and material.posterior_key == "k3"
    assert material.fit_weights("k4") == (True, {"weights": {"lab": 1.0}, "temperature": 0.5})
    assert material.fit_weights("other") == (False, None)
    substance = Calibration.from_json(SUBSTANCE_ROW)
    assert substance.part_temperature == 1.5 and substance.part_stats["part_temperature_parts"] == 30
    for record, row in ((material, MATERIAL_ROW), (substance, SUBSTANCE_ROW)):
        written = record.to_json()
        assert Calibration.from_json(written) == record
        assert written == {k: v for k, v in row.items() if k not in ("top1", "history", "sub@1")}
    assert Calibration.from_json(None) == Calibration() and Calibration().bn_prior is None


def test_store_writes_the_fields_given_and_keeps_the_rest() -> None:
    row = SimpleNamespace(metrics={"top1": 0.5, "color_sigma": 3.0})
    record = Calibration.store(row, posterior_reliability={"ece": 0.2}, posterior_key="k", fit=None)
    assert row.metrics == {"top1": 0.5, "color_sigma": 3.0, "posterior_ece": 0.2,
                           "posterior_reliability": {"ece": 0.2}, "posterior_key": "k", "fit_calibration": None}
    assert record == Calibration.of(row) and record.color_sigma == 3.0
    Calibration.store(row, color_sigma=None)  # "fitted, nothing came out" is stored too
    assert "color_sigma" in row.metrics and Calibration.of(row).color_sigma is None


def test_the_colour_key_names_fitted_colours_only() -> None:
    """Rows calibrated before material colours were fitted (D63) keep the keys of what ranks with them."""
    assert Calibration.from_json(MATERIAL_ROW).colour_key == {}
    fitted = Calibration.from_json({**MATERIAL_ROW, "color_labs": {"3": [50.0, 10.0, -4.0]}})
    assert fitted.colour_key == {"colour": "k1"}
    assert fitted_labs(fitted)[3].tolist() == [50.0, 10.0, -4.0] and fitted_labs(Calibration()) == {}
