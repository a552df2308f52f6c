"""What a trained network's row stores about reading its outputs: one typed record, `Calibration`.

The training stage fits them (`recognition.calibration`, `recognition.bn_prior`,
`recognition.substance_temperature`, `fitting.calibration`); inference, fit, `retrieve`
and the evaluation read them. They live in the row's `metrics` under the keys they always had (so
existing rows read unchanged and no migration is needed), each beside the key of what it was fitted
on: `Calibration.of(row)` reads them, `Calibration.store(row, field=value, ...)` writes fields (the
row's other metrics, such as the training history, are kept). Every reader and writer goes through
this record; no code outside it names those keys.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.classify.assignment import foreground_of_render, median_lab
from photoshape_flow.classify.color_prior import material_lab_matrix
from photoshape_flow.db import models as m
from photoshape_flow.store import BlobStore

# the fields stored under another key than their name
_KEYS = {"fit": "fit_calibration"}
# the substance network's part-temperature figures, kept beside the temperature (reports, not read back)
PART_STATS = ("part_temperature_parts", "part_temperature_renders", "part_accuracy", "part_nll", "part_nll_tempered")


@dataclass(frozen=True)
class Calibration:
    """A network's stored calibrations (None: not fitted); each `*_key` names what it was fitted on."""

    color_sigma: float | None = None  # the colour likelihood's sigma (CIELAB), a material classifier's
    color_sigma_key: str | None = None  # also the key of `color_labs`: both are fitted together
    color_labs: Mapping[str, Sequence[float]] | None = None  # material id -> CIELAB in the training renders
    part_temperature: float | None = None  # a substance network's part-level temperature
    part_temperature_key: str | None = None
    part_stats: Mapping[str, Any] = field(default_factory=dict)  # PART_STATS
    bn_prior_choice: Mapping[str, Any] | None = None  # {"bn_prior", "regions", "renders", "log_loss", "top1"}
    bn_prior_key: str | None = None
    posterior_reliability: Mapping[str, Any] | None = None  # bins and ECE of the ranking's posterior
    posterior_key: str | None = None
    fit: Mapping[str, Any] | None = None  # the fit's weights: {"key": ..., "record": {...} or None}

    @property
    def bn_prior(self) -> float | None:
        """The BatchNorm prior chosen for reading photos (None: not chosen, or no adaptation won)."""
        value = self.bn_prior_choice.get("bn_prior") if isinstance(self.bn_prior_choice, Mapping) else None
        return None if value is None else float(value)

    def fit_weights(self, key: str) -> tuple[bool, Mapping[str, Any] | None]:
        """(stored for `key`, the record): the fit's weights fitted on what `key` names (None: hand-set)."""
        if isinstance(self.fit, Mapping) and self.fit.get("key") == key:
            return True, self.fit.get("record")
        return False, None

    @property
    def colour_key(self) -> dict[str, str]:
        """What the colour evidence was fitted on, for the keys of what ranks with it; empty for a classifier
        calibrated before material colours were fitted, so its rows and calibrations keep their keys."""
        return {} if self.color_labs is None or self.color_sigma_key is None else {"colour": self.color_sigma_key}

    @classmethod
    def from_json(cls, metrics: Mapping[str, Any] | None) -> Calibration:
        """The record of a row's `metrics` (keys it does not know are left to their owners)."""
        metrics = metrics or {}
        values: dict[str, Any] = {}
        for f in fields(cls):
            key = _KEYS.get(f.name, f.name)
            if f.name == "part_stats":
                values[f.name] = {k: metrics[k] for k in PART_STATS if k in metrics}
            elif key in metrics:
                values[f.name] = metrics[key]
        for name in ("color_sigma", "part_temperature"):
            if values.get(name) is not None:
                values[name] = float(values[name])
        return cls(**values)

    def to_json(self) -> dict[str, Any]:
        """The `metrics` keys of the fields that are set, as `from_json` reads them back."""
        return _json({f.name: getattr(self, f.name) for f in fields(self)
                      if getattr(self, f.name) not in (None, {})})

    @classmethod
    def of(cls, row: m.Classifier | None) -> Calibration:
        return cls.from_json(row.metrics if row is not None else None)

    @classmethod
    def store(cls, row: m.Classifier, **changes: Any) -> Calibration:
        """Write `changes` (field names; None is written too: "fitted, nothing came out") onto the row."""
        record = replace(cls.of(row), **changes)
        row.metrics = {**(row.metrics or {}), **_json(changes)}
        return record


def _json(values: Mapping[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, value in values.items():
        if name == "part_stats":
            out.update(value)
            continue
        if name == "posterior_reliability" and value is not None:
            out["posterior_ece"] = value["ece"]
        out[_KEYS.get(name, name)] = value
    return out


def stored_temperature(session: Session, network_id: int) -> float | None:
    """A substance network's stored part-level temperature (None: not fitted, or too few parts)."""
    return Calibration.of(session.get(m.Classifier, network_id)).part_temperature


def material_labs(session: Session, store: BlobStore, materials: Sequence[int]) -> dict[int, np.ndarray]:
    """Median CIELAB colour of each of `materials` that has one (`material_lab`)."""
    rows = session.execute(sa.select(m.Material).where(m.Material.id.in_([int(x) for x in materials]))).scalars()
    return {mat.id: lab for mat in rows if (lab := material_lab(mat, store)) is not None}


def material_lab(material: m.Material, store: BlobStore) -> np.ndarray | None:
    """Median CIELAB colour of a material's render (its preview), else of its albedo."""
    if material.preview_blob and store.exists(material.preview_blob):
        image = store.load_image(material.preview_blob)
        alpha = image[..., 3] / 255.0 if image.ndim == 3 and image.shape[2] == 4 else None
        rgb = image[..., :3]
        if rgb.dtype != np.uint8:
            rgb = (np.clip(rgb.astype(np.float64) / np.iinfo(rgb.dtype).max, 0, 1) * 255).astype(np.uint8)
        return median_lab(rgb, foreground_of_render(rgb, alpha))
    albedo = (material.maps or {}).get("albedo")
    if albedo and store.exists(albedo):
        return median_lab(store.load_image(albedo)[..., :3])
    color = (material.params or {}).get("albedo")
    if color is not None:
        rgb = (np.clip(np.asarray(color, np.float64), 0, 1) * 255).astype(np.uint8).reshape(1, 1, 3)
        return median_lab(rgb)
    return None


def stored_color_prior(
    session: Session, store: BlobStore, materials: Sequence[int], classifier: m.Classifier
) -> tuple[np.ndarray, float] | None:
    """(material colours in `materials` order, the classifier's stored sigma); None when not calibrated.

    A material's colour is the one fitted with the sigma (`Calibration.color_labs`: its median colour
    in the training renders), else its preview's (a material added since, or a classifier calibrated
    before colours were fitted).
    """
    record = Calibration.of(classifier)
    if record.color_sigma is None:
        return None
    fitted = fitted_labs(record)
    wanted = {int(x) for x in materials}
    labs = {**material_labs(session, store, sorted(wanted - set(fitted))),  # previews only where none was fitted
            **{mid: lab for mid, lab in fitted.items() if mid in wanted}}
    return (material_lab_matrix(materials, labs), record.color_sigma) if labs else None


def fitted_labs(record: Calibration) -> dict[int, np.ndarray]:
    """The material colours stored with the colour sigma, by material id (empty when none are)."""
    return {int(k): np.asarray(v, np.float64) for k, v in (record.color_labs or {}).items()}
