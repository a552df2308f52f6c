"""The relighting error's pure parts: the silhouette RMSE and the truth's library materials."""

from __future__ import annotations

import numpy as np
import pytest

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.evaluation.groundtruth import ItemRef, PartTruth, TruthEntry
from photoshape_flow.scoring.relighting_eval import held_out_envmap, silhouette_rmse, true_materials


def test_silhouette_rmse_counts_only_the_silhouette() -> None:
    a = np.zeros((4, 4, 3), np.uint8)
    b = np.zeros((4, 4, 3), np.uint8)
    b[0, 0] = 255  # outside the silhouette: ignored
    b[2, 2] = 51  # inside: 0.2 off on one of 4 pixels -> sqrt(0.04 / 4)
    alpha = np.zeros((4, 4), bool)
    alpha[2:, 2:] = True
    assert silhouette_rmse(a, b, alpha) == pytest.approx(0.1)
    assert np.isnan(silhouette_rmse(a, b, np.zeros((4, 4), bool)))


def truth(parts: dict[str, str]) -> TruthEntry:
    return TruthEntry("e", ItemRef("s", "e.png"), ItemRef("t", "chair"),
                      {name: PartTruth(name, mat, "wood") for name, mat in parts.items()})


def test_true_materials_need_every_part_in_the_library(db_url: str) -> None:
    with session_scope(db_url) as session:
        shape = m.Shape(source="t", source_id="chair")
        shape.parts = [m.Part(index=1, name="seat"), m.Part(index=2, name="legs")]
        oak = m.Material(name="oak", substance="wood")
        session.add_all([shape, oak, m.Envmap(name="studio", blob="ab" * 32, split="train"),
                         m.Envmap(name="held", blob="cd" * 32, split="val")])
        session.flush()
        assert true_materials(session, shape, truth({"seat": "oak", "legs": "oak"})) == {1: oak.id, 2: oak.id}
        assert true_materials(session, shape, truth({"seat": "oak"})) is None  # legs have no truth
        assert true_materials(session, shape, truth({"seat": "oak", "legs": "teak"})) is None  # not ingested
        assert held_out_envmap(session).name == "held"
