"""A small, consistent set of rows touching every table (used by schema tests)."""

from __future__ import annotations

import datetime as dt

from sqlalchemy.orm import Session

from photoshape_flow.db import models as m
from photoshape_flow.db.base import utcnow


def seed(session: Session, suffix: str = "") -> dict[str, int]:
    """Insert one item per table; returns ids by table name."""
    shape = m.Shape(source="test", source_id=f"chair{suffix}", name="chair", category="chair", num_parts=2)
    session.add(shape)
    session.flush()
    legs = m.Part(shape_id=shape.id, index=1, name="legs", area_world=0.2, area_uv=0.1, uv_density=0.5)
    seat = m.Part(shape_id=shape.id, index=2, name="seat", area_world=0.5, area_uv=0.5, uv_density=1.0)
    exemplar = m.Exemplar(source="test", source_id=f"photo{suffix}", size=256)
    oak = m.Material(name=f"oak{suffix}", substance="wood", default_scale=0.3, license="CC0-1.0")
    leather = m.Material(name=f"leather{suffix}", substance="leather")
    envmap = m.Envmap(name=f"studio{suffix}", split="train")
    vset = m.ViewpointSet(name=f"paper-456{suffix}", version=1, num_views=1, cameras=[[0.0, 0.3, 2.0, 50.0]])
    session.add_all([legs, seat, exemplar, oak, leather, envmap, vset])
    session.flush()
    pair = m.Pair(
        shape_id=shape.id, exemplar_id=exemplar.id, viewpoint_set_id=vset.id, rank=1, distance=3.5,
        azimuth=0.1, elevation=0.3, fov=50.0, camera_distance=2.0,
    )
    session.add(pair)
    session.add(m.ViewFeature(shape_id=shape.id, viewpoint_set_id=vset.id, descriptor="hog", dims=1352))
    session.add(m.ExemplarFeature(exemplar_id=exemplar.id, descriptor="hog", dims=1352))
    session.add(m.ExemplarMatch(
        exemplar_id=exemplar.id, viewpoint_set_id=vset.id, descriptor="hog", rank=1, shape_id=shape.id,
        view_index=0, distance=3.5, searched_at=utcnow(),
    ))
    session.flush()
    classifier = m.Classifier(name=f"r34{suffix}", kind="material", architecture="resnet34", materials=[0, oak.id])
    session.add(classifier)
    session.add(m.Alignment(pair_id=pair.id, method="flow-crf", iou_coarse=0.6, iou_crf=0.75))
    session.flush()
    session.add_all([
        m.PartSubstance(pair_id=pair.id, part_id=legs.id, substance="wood", confidence=0.8),
        m.PartSubstance(pair_id=pair.id, part_id=seat.id, observed=False),
        m.Assignment(pair_id=pair.id, part_id=legs.id, method="classifier", classifier_id=classifier.id,
                     method_key=f"classifier:{classifier.id}", rank=1, material_id=oak.id, score=0.3,
                     posterior=0.9),
        m.Assignment(pair_id=pair.id, part_id=legs.id, method="classifier", classifier_id=classifier.id,
                     method_key=f"classifier:{classifier.id}", rank=2, material_id=leather.id, score=0.02,
                     posterior=0.06),
        m.Assignment(pair_id=pair.id, part_id=seat.id, method="classifier", classifier_id=classifier.id,
                     method_key=f"classifier:{classifier.id}", rank=1, material_id=leather.id, score=0.2,
                     posterior=0.6, unobserved=True),
        m.Assignment(pair_id=pair.id, part_id=legs.id, method="color-match", method_key="color-match",
                     rank=1, material_id=leather.id, score=0.4),
        m.Assignment(pair_id=pair.id, part_id=legs.id, method="fit", classifier_id=classifier.id,
                     method_key=f"fit:{classifier.id}", rank=1, material_id=leather.id, score=0.7,
                     params={"fit": {"source": "ranking", "prior": 0.05, "distance": 0.4, "cost": 1.3}}),
        m.Rendering(kind="training", key=f"training/train/000001{suffix}", shape_id=shape.id, pair_id=pair.id,
                    envmap_id=envmap.id, split="train", params={"spp": 16}, blobs={}),
        m.Evaluation(run=f"run{suffix}", stage="inference", method="classifier", metric="material_top1", value=0.5),
        m.Grade(pair_id=pair.id, label="good"),
        m.WorkClaim(stage="fine-alignment", item_key=f"pair:{pair.id}", state="done"),
        m.WorkClaim(stage="coarse-alignment:shapes", item_key=f"{shape.id}{suffix}", state="claimed",
                    worker="worker-2:4242", holder_host="worker-2", holder_pid=4242, holder_started="1234",
                    holder_name="photoshape run", lease_expires_at=utcnow() + dt.timedelta(hours=1)),
        m.PipelineRun(origin="cli", profile_name="small", overrides={"training.epochs": "3"},
                      profile={"name": "small", "training": {"epochs": 3}}, stages=["training"],
                      reports={"training": {"done": 1}}, status="ok"),
    ])
    session.flush()
    return {"shape": shape.id, "pair": pair.id, "exemplar": exemplar.id, "classifier": classifier.id}
