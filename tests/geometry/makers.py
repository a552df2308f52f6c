"""Tiny input files for ingest tests: OBJ+MTL with material groups, GLB, ShapeNet tree, .sh3f catalog.

Also module-level functions the isolated worker can import by name (crash / hang on purpose).
"""

from __future__ import annotations

import io
import os
import signal
import time
import zipfile
from pathlib import Path

import numpy as np

CUBE_QUADS = [  # a unit cube as 6 separate quads (24 vertices: every corner written three times)
    ((0, 0, 0), (0, 1, 0), (1, 1, 0), (1, 0, 0)),
    ((0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)),
    ((0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)),
    ((0, 1, 0), (0, 1, 1), (1, 1, 1), (1, 1, 0)),
    ((0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0)),
    ((1, 0, 0), (1, 1, 0), (1, 1, 1), (1, 0, 1)),
]


def box_lines(offset: tuple[float, float, float], size: tuple[float, float, float], start: int,
              with_uv: bool = False) -> tuple[list[str], int]:
    """OBJ lines of a box made of 6 separate quads; returns (lines, next vertex number)."""
    lines: list[str] = []
    index = start
    for quad in CUBE_QUADS:
        for corner in quad:
            x, y, z = (offset[k] + corner[k] * size[k] for k in range(3))
            lines.append(f"v {x:.6f} {y:.6f} {z:.6f}")
        if with_uv:
            lines += ["vt 0 0", "vt 0 1", "vt 1 1", "vt 1 0"]
            lines.append("f " + " ".join(f"{index + k}/{k - 4}" for k in range(4)))
        else:
            lines.append("f " + " ".join(str(index + k) for k in range(4)))
        index += 4
    return lines, index


def write_chair_obj(folder: Path, name: str = "chair", *, seat_kd: str = "0.8 0.2 0.1",
                    with_texture: bool = False) -> Path:
    """A 3-material chair: legs (2 boxes, reused `usemtl legs`), seat (textured), back; g groups."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = [f"mtllib {name}.mtl"]
    n = 1
    lines += ["g Legs", "usemtl legs"]
    part, n = box_lines((0.0, 0.0, 0.0), (0.1, 1.0, 0.1), n)
    lines += part
    lines += ["g Seat", "usemtl seat"]
    part, n = box_lines((0.0, 1.0, 0.0), (1.0, 0.1, 1.0), n, with_uv=with_texture)
    lines += part
    lines += ["g Legs", "usemtl legs"]
    part, n = box_lines((0.9, 0.0, 0.9), (0.1, 1.0, 0.1), n)
    lines += part
    lines += ["o Back", "usemtl back"]
    part, n = box_lines((0.0, 1.1, 0.9), (1.0, 1.0, 0.1), n)
    lines += part
    obj = folder / f"{name}.obj"
    obj.write_text("\n".join(lines) + "\n")
    mtl = ["newmtl legs", "Kd 0.1 0.1 0.1", "Ns 100", "newmtl seat", f"Kd {seat_kd}", "Ns 0"]
    if with_texture:
        mtl.append("map_Kd -s 1 1 1 tex/seat.png")
    mtl += ["newmtl back", "Kd 0.5 0.5 0.5", "Pr 0.3", "Pm 1"]
    if with_texture:
        write_png(folder / "tex" / "seat.png", np.full((8, 8, 3), (200, 50, 20), np.uint8))
    (folder / f"{name}.mtl").write_text("\n".join(mtl) + "\n")
    return obj


def write_png(path: Path, array: np.ndarray) -> Path:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path)
    return path


def write_glb(path: Path) -> Path:
    """A GLB with two materials (red box, blue box) written by trimesh."""
    import trimesh

    red = trimesh.creation.box(extents=(1.0, 0.2, 1.0))
    red.apply_translation((0, 0.5, 0))
    blue = trimesh.creation.box(extents=(0.2, 1.0, 0.2))
    red.visual = trimesh.visual.TextureVisuals(
        uv=np.random.default_rng(0).random((len(red.vertices), 2)),
        material=trimesh.visual.material.PBRMaterial(name="red", baseColorFactor=[255, 0, 0, 255],
                                                     roughnessFactor=0.4, metallicFactor=0.0))
    blue.visual = trimesh.visual.TextureVisuals(
        material=trimesh.visual.material.PBRMaterial(name="blue", baseColorFactor=[0, 0, 255, 255],
                                                     roughnessFactor=0.9, metallicFactor=1.0))
    scene = trimesh.Scene()
    scene.add_geometry(red, geom_name="seat")
    scene.add_geometry(blue, geom_name="leg")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(scene.export(file_type="glb"))
    return path


def write_shapenet_tree(root: Path, synset: str = "03001627", model_id: str = "abc123") -> Path:
    model_dir = root / synset / model_id / "models"
    obj = write_chair_obj(model_dir, "model_normalized")
    return obj


def properties_text(entries: list[dict[str, str]], header: dict[str, str] | None = None) -> str:
    lines = ["# test catalog"]
    for key, value in (header or {"id": "Test#Catalog", "name": "Test catalog", "license": "CC0"}).items():
        lines.append(f"{key}={value}")
    for i, entry in enumerate(entries, start=1):
        for key, value in entry.items():
            lines.append(f"{key}#{i}={value}")
    return "\n".join(lines) + "\n"


def write_sh3f(path: Path, entries: list[dict[str, str]], members: dict[str, bytes],
               extra: list[tuple[zipfile.ZipInfo, bytes]] | None = None) -> Path:
    """A .sh3f zip: PluginFurnitureCatalog.properties plus the given members."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("PluginFurnitureCatalog.properties", properties_text(entries).encode("latin-1"))
        for name, data in members.items():
            zf.writestr(name, data)
        for info, data in extra or []:
            zf.writestr(info, data)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(buffer.getvalue())
    return path


def chair_members(folder: str, name: str = "chair", tmp: Path | None = None) -> dict[str, bytes]:
    """The OBJ and MTL of `write_chair_obj` as archive members under `folder/`."""
    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        obj = write_chair_obj(Path(scratch), name)
        return {
            f"{folder}/{name}.obj": obj.read_bytes(),
            f"{folder}/{name}.mtl": obj.with_suffix(".mtl").read_bytes(),
        }


def crash_process(*_args: object, **_kwargs: object) -> None:
    """Kill the calling process with SIGSEGV (what a crashing native importer does)."""
    os.kill(os.getpid(), signal.SIGSEGV)


def hang(*_args: object, **_kwargs: object) -> None:
    time.sleep(3600)


def raise_value_error(message: str) -> None:
    raise ValueError(message)


def add(a: int, b: int) -> int:
    return a + b


def allocate(nbytes: int) -> int:
    """Touch `nbytes` of fresh memory in the caller's process (a bomb's decoder, for the isolated worker)."""
    return int(np.ones(nbytes // 8).sum())
