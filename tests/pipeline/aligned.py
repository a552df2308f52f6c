"""Aligned pairs made directly in the database (no rendering): a red seat over brown legs, a hidden part."""

from __future__ import annotations

import numpy as np

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.store import BlobStore

RED, BLUE, BROWN = (200, 30, 30), (30, 40, 200), (120, 80, 40)


def solid(color: tuple[int, int, int], size: int = 16) -> np.ndarray:
    return np.broadcast_to(np.array(color, np.uint8), (size, size, 3)).copy()


def make_aligned_pairs(url: str, store: BlobStore, n_pairs: int = 1) -> dict[str, object]:
    """`n_pairs` pairs of one shape (seat, legs, hidden cushion) with exemplars, CRF maps and substances."""
    image = np.full((64, 64, 3), 255, np.uint8)
    part_map = np.zeros((64, 64), np.uint16)
    image[8:32, 8:56] = RED
    part_map[8:32, 8:56] = 1
    image[32:60, 16:48] = BROWN
    part_map[32:60, 16:48] = 2
    mask = (part_map > 0).astype(np.uint8) * 255
    with session_scope(url) as session:
        shape = m.Shape(source="t", source_id="s")
        session.add(shape)
        session.flush()
        parts = [m.Part(shape_id=shape.id, index=i, name=n, builtin_material={"albedo": [0.5, 0.5, 0.5]})
                 for i, n in ((1, "seat"), (2, "legs"), (3, "cushion_back"))]
        mats = [
            m.Material(name="red_leather", substance="leather", preview_blob=store.put_image(solid(RED))),
            m.Material(name="blue_leather", substance="leather", preview_blob=store.put_image(solid(BLUE))),
            m.Material(name="walnut", substance="wood", preview_blob=store.put_image(solid(BROWN))),
            m.Material(name="grey_fabric", substance="fabric", params={"albedo": [0.5, 0.5, 0.5]}),
        ]
        session.add_all(parts + mats)
        session.flush()
        pair_ids = []
        for k in range(n_pairs):
            exemplar = m.Exemplar(source="t", source_id=f"e{k}", image_blob=store.put_image(image),
                                  mask_blob=store.put_image(mask), size=64)
            session.add(exemplar)
            session.flush()
            pair = m.Pair(shape_id=shape.id, exemplar_id=exemplar.id, rank=k + 1, distance=1.0 + k, azimuth=0.0,
                          elevation=0.2, fov=50.0, camera_distance=2.0)
            session.add(pair)
            session.flush()
            session.add(m.Alignment(pair_id=pair.id, method="flow-crf", crf_blob=store.put_image(part_map)))
            session.add_all([
                m.PartSubstance(pair_id=pair.id, part_id=parts[0].id, substance="leather", confidence=0.9,
                                probs={"leather": 0.9, "fabric": 0.1}),
                m.PartSubstance(pair_id=pair.id, part_id=parts[1].id, substance="wood", confidence=0.8,
                                probs={"wood": 0.8, "metal": 0.2}),
                m.PartSubstance(pair_id=pair.id, part_id=parts[2].id, observed=False),
            ])
            pair_ids.append(pair.id)
        return {"pairs": pair_ids, "seat": parts[0].id, "legs": parts[1].id, "hidden": parts[2].id,
                **{mat.name: mat.id for mat in mats}}


def plant_true_pair(session, store: BlobStore, shape: m.Shape, exemplar_id: int, truth) -> m.Pair:  # type: ignore[no-untyped-def]
    """A pair of `shape` and an exemplar at the ground truth's camera, with the true part map as its
    CRF alignment: what perfect coarse and fine alignment would have written."""
    from photoshape_flow.scoring.truths import truth_labels

    camera = truth.camera
    pair = m.Pair(shape_id=shape.id, exemplar_id=exemplar_id, rank=1, exemplar_rank=1, distance=0.0,
                  azimuth=camera.azimuth, elevation=camera.elevation, fov=camera.fov, camera_distance=camera.distance)
    session.add(pair)
    session.flush()
    labels, _, _ = truth_labels(truth, session.get(m.Exemplar, exemplar_id))
    index = {p.name: p.index for p in shape.parts}
    to_shape = np.array([0] + [index[name] for name in sorted(truth.parts)], np.uint8)
    session.add(m.Alignment(pair_id=pair.id, method="flow-crf", crf_blob=store.put_image(to_shape[labels])))
    return pair


def plant_ranking(session, pair: m.Pair, part, classifier: m.Classifier, planted) -> None:  # type: ignore[no-untyped-def]
    """The classifier's rows for one part: `planted` materials ranked in that order (scores 0.5, 0.3, 0.2)."""
    for rank, (material, score) in enumerate(zip(planted, (0.5, 0.3, 0.2), strict=True), start=1):
        session.add(m.Assignment(pair_id=pair.id, part_id=part.id, method="classifier",
                                 method_key=f"classifier:{classifier.id}", classifier_id=classifier.id,
                                 rank=rank, material_id=material.id, score=score,
                                 substance=material.substance, params_hash="planted"))
