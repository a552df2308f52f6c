"""A tiny collection in the database for pipeline tests: toy chairs, analytic materials, envmaps, pairs."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from sqlalchemy.orm import Session

from photoshape_flow.db import models as m
from photoshape_flow.store import BlobStore
from photoshape_flow.synth.toy import studio_envmap, toy_chair

MATERIALS = (
    ("leather_brown", "leather", (0.30, 0.12, 0.05), 0.45),
    ("fabric_blue", "fabric", (0.15, 0.25, 0.65), 0.9),
    ("fabric_beige", "fabric", (0.70, 0.62, 0.50), 0.9),
    ("wood_oak", "wood", (0.55, 0.36, 0.16), 0.6),
    ("metal_steel", "metal", (0.75, 0.75, 0.78), 0.3),
    ("plastic_red", "plastic", (0.80, 0.10, 0.10), 0.35),
)


@dataclass
class Collection:
    shapes: dict[int, str] = field(default_factory=dict)  # id -> split
    envmaps: dict[int, str] = field(default_factory=dict)  # id -> split
    pairs: dict[int, int] = field(default_factory=dict)  # pair id -> shape id
    parts: dict[int, list[int]] = field(default_factory=dict)  # shape id -> part ids by index
    materials: dict[str, int] = field(default_factory=dict)  # name -> id


def seed_collection(
    session: Session,
    store: BlobStore,
    *,
    shape_splits: tuple[str, ...] = ("train", "train", "val"),
    envmap_splits: tuple[str, ...] = ("train", "val"),
    with_pairs: bool = True,
    envmap_gain: float = 1.0,
    exemplar_size: int = 48,
) -> Collection:
    out = Collection()
    for name, substance, albedo, roughness in MATERIALS:
        row = m.Material(
            name=name, substance=substance, kind="analytic", default_scale=0.25,
            params={"albedo": list(albedo), "roughness": roughness, "metallic": 1.0 if substance == "metal" else 0.0},
            params_hash=name,
        )
        session.add(row)
        session.flush()
        out.materials[name] = row.id
    for i, split in enumerate(envmap_splits):
        ref = store.put_image(studio_envmap(64, 32, sun=3.0 + i) * envmap_gain, "exr")
        row = m.Envmap(name=f"studio_{i}", blob=ref, width=64, height=32, split=split)
        session.add(row)
        session.flush()
        out.envmaps[row.id] = split
    for i, split in enumerate(shape_splits):
        mesh = toy_chair(seat_height=0.35 + 0.05 * i, back_height=0.45 + 0.05 * i)
        shape = m.Shape(
            source="toy", source_id=f"chair_{i}", name=f"chair {i}", category="chair", split=split,
            mesh_blob=store.put_bytes(mesh.to_npz_bytes(), "npz"), num_parts=len(mesh.parts),
            num_vertices=mesh.num_vertices, num_faces=mesh.num_faces,
        )
        session.add(shape)
        session.flush()
        out.shapes[shape.id] = split
        out.parts[shape.id] = []
        for p in mesh.parts:
            part = m.Part(
                shape_id=shape.id, index=p.index, name=p.name, num_faces=len(p.faces),
                area_world=p.area_world, area_uv=p.area_uv, uv_density=p.uv_density,
                builtin_material=p.builtin_material,
            )
            session.add(part)
            session.flush()
            out.parts[shape.id].append(part.id)
        if with_pairs:
            image = np.full((exemplar_size, exemplar_size, 3), 255, np.uint8)
            exemplar = m.Exemplar(
                source="toy", source_id=f"photo_{i}", image_blob=store.put_image(image), size=exemplar_size
            )
            session.add(exemplar)
            session.flush()
            pair = m.Pair(
                shape_id=shape.id, exemplar_id=exemplar.id, rank=1, distance=1.0,
                azimuth=0.4 * (i - 1), elevation=math.pi / 12, fov=50.0, camera_distance=1.6,
            )
            session.add(pair)
            session.flush()
            out.pairs[pair.id] = shape.id
    return out
