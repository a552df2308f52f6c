"""What both experiments load once: the ranking's evidence as inference fits it.

`load_evidence` gives the colour likelihood (sigma fit on the validation renders), the calibrated
substance network (its part-level temperature) and the material colours that inference uses, so the
experiments score exactly what the pipeline ranks with. `results_dir` is where an experiment writes
its output: under the data root it measured, next to the networks the figures belong to.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.classify.color_prior import fit_color_sigma, material_lab_matrix, region_color_distances
from photoshape_flow.config import Settings
from photoshape_flow.db import models as m
from photoshape_flow.networks.calibrations import material_lab
from photoshape_flow.networks.classifiers import load_substance_network
from photoshape_flow.recognition.calibration import COLOR_SIGMA_RENDERS
from photoshape_flow.recognition.substance_temperature import substance_temperature
from photoshape_flow.recognition.training import training_data
from photoshape_flow.store import BlobStore


def results_dir(settings: Settings, experiment: str) -> Path:
    """<data root>/experiments/<experiment>: an experiment's output for the networks of that data root."""
    return Path(settings.data_root) / "experiments" / experiment


@dataclass
class Evidence:
    material_substance: dict[int, str]
    labs: np.ndarray  # (M, 3) CIELAB of the classifier's materials, in its order (NaN: no colour)
    sigma: float | None  # the colour likelihood's sigma, fit on the validation renders
    network_id: int  # the newest substance network behind the part substances
    temperature: float | None  # its part-level temperature
    network: Any  # the substance network itself (segmentation net, or the part recogniser's MaterialClassifier)
    net_size: int  # its input size


def load_evidence(session: Session, store: BlobStore, settings: Settings, materials_order: list[int]) -> Evidence:
    """The evidence inference would use, for a classifier whose materials are `materials_order`."""
    materials = session.execute(sa.select(m.Material)).scalars().all()
    mat_labs = {mat.id: lab for mat in materials if (lab := material_lab(mat, store)) is not None}
    data = training_data(session, store)
    sigma = fit_color_sigma(region_color_distances(data.val, mat_labs, limit=COLOR_SIGMA_RENDERS))
    networks = session.execute(sa.select(m.PartSubstance.classifier_id).distinct()).scalars().all()
    newest = max(n for n in networks if n is not None)
    net_row = session.get(m.Classifier, newest)
    return Evidence(
        material_substance={mat.id: mat.substance for mat in materials},
        labs=material_lab_matrix(materials_order, mat_labs), sigma=sigma, network_id=newest,
        temperature=substance_temperature(settings, newest),
        network=load_substance_network(net_row, store, "cpu"),
        net_size=int(net_row.config.get("size") or 128),
    )
