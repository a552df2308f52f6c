"""The world's shapes: real catalogue seating read by the project's own importer, exported as OBJ.

Sources: the Debian `sweethome3d-furniture` catalogs (.sh3f, seating categories only) and the
segmented models of `shared/data/models`. Each goes through exactly what `photoshape ingest shapes`
runs (`discover_shapes` -> `materialize` -> `prepare_shape`, with the catalog's model rotation), so
the parts Blender renders and the ground truth names are the parts the collection gets. The
collection's share is written as subset catalogs under the *same file names* (so `ingest shapes`
gives the same natural keys, `sweethome3d` / `<catalog stem>/<piece id>`) plus copies of the shared
models; the held-out pieces are absent from those files.
"""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
import zipfile
from pathlib import Path

import numpy as np

from experiments.second_world.plan import ShapeInfo
from photoshape_flow.export.obj import write_obj
from photoshape_flow.geometry.archive import SafeZip
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.geometry.prepare import prepare_shape
from photoshape_flow.geometry.preprocess import PreprocessOptions
from photoshape_flow.geometry.raw import BadShapeError
from photoshape_flow.geometry.sh3f import CATALOG_FILE, model_files, parse_properties
from photoshape_flow.geometry.sources import RejectedInput, ShapeItem, discover_shapes, materialize

CATALOG_DIR = Path("/usr/share/sweethome3d/furniture")
SEATING = "chair,sofa,stool,bench"
MAX_MODEL_BYTES = 700_000  # larger catalogue models cost seconds of preprocessing each on a shared CPU
MIN_PART_AREA_SHARE = 0.02  # a part counts towards "at least 2 parts" above this share of the surface
POINTS_FOR_FRAMING = 4000


def part_object(index: int) -> str:
    """The OBJ object (and Blender object) name of a part: ASCII, unique, independent of its name."""
    return f"part_{index:02d}"


def shape_key(source: str, source_id: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", f"{source}__{source_id}").strip("_")


def discover_seating(shared_models: Path) -> tuple[list[ShapeItem], list[str]]:
    """Seating pieces of the Debian catalogs and the shared models, with one line per rejected input."""
    catalogs = sorted(CATALOG_DIR.glob("*.sh3f"))
    found = discover_shapes(catalogs, category=SEATING) if catalogs else []
    found += discover_shapes([shared_models])
    items, problems = [], []
    for item in found:
        if isinstance(item, RejectedInput):
            problems.append(f"{item.label}: {item.reason}; skipped")
        elif item.size_bytes > MAX_MODEL_BYTES:
            problems.append(f"{item.label}: {item.size_bytes} bytes (world limit {MAX_MODEL_BYTES}); skipped")
        else:
            items.append(item)
    return items, problems


def significant_parts(mesh: ShapeMesh) -> int:
    areas = np.array([p.area_world for p in mesh.parts])
    return int((areas >= MIN_PART_AREA_SHARE * areas.sum()).sum()) if areas.sum() > 0 else 0


def export_mesh(mesh: ShapeMesh, path: Path) -> None:
    """The prepared mesh as OBJ with one object per part (`part_object`), built-in textures left out
    (Blender gets the planned materials; only the geometry and UVs matter)."""
    parts = [dataclasses.replace(p, name=part_object(p.index),
                                 builtin_material={k: v for k, v in p.builtin_material.items() if k != "texture"})
             for p in mesh.parts]
    write_obj(path, ShapeMesh(parts=parts, meta={}), header=("second_world: geometry only",))


def prepare_item(item: ShapeItem, meshes: Path) -> ShapeInfo:
    """Prepare one shape as ingest does (cached by key under `meshes`); BadShapeError when unusable."""
    key = shape_key(item.source, item.source_id)
    record_path, obj_path = meshes / f"{key}.json", meshes / f"{key}.obj"
    if not record_path.is_file() or not obj_path.is_file():
        options = PreprocessOptions(rotation=item.rotation) if item.rotation else PreprocessOptions()
        with materialize(item) as files:
            prepared = prepare_shape(str(files.model), item.fmt, str(files.root), options)
        mesh = prepared.mesh
        if len({p.name for p in mesh.parts}) != len(mesh.parts):
            raise BadShapeError("two parts share a name (the ground truth names parts)")
        points = np.concatenate([p.vertices for p in mesh.parts])
        pick = np.random.default_rng(0).permutation(len(points))[:POINTS_FOR_FRAMING]
        meshes.mkdir(parents=True, exist_ok=True)
        export_mesh(mesh, obj_path)
        record = {"source": item.source, "source_id": item.source_id, "category": item.category,
                  "parts": [{"name": p.name, "object": part_object(p.index), "uv_density": p.uv_density}
                            for p in mesh.parts],
                  "significant_parts": significant_parts(mesh), "points": points[np.sort(pick)].round(5).tolist()}
        record_path.write_text(json.dumps(record))
    record = json.loads(record_path.read_text())
    if record["significant_parts"] < 2:
        raise BadShapeError(f"{record['significant_parts']} part(s) above {MIN_PART_AREA_SHARE:.0%} of the surface")
    return ShapeInfo(source=item.source, source_id=item.source_id, key=key,
                     parts=tuple(p["name"] for p in record["parts"]), category=item.category or "chair",
                     points=np.asarray(record["points"], np.float64), from_catalog=item.archive is not None)


def part_records(meshes: Path, shape: ShapeInfo) -> list[dict]:
    """name, object and uv_density of each part of a prepared shape (from its cache record)."""
    return json.loads((meshes / f"{shape.key}.json").read_text())["parts"]


# -- the collection's shapes ------------------------------------------------------------------------


def _escape(text: str, key: bool = False) -> str:
    """Java .properties escaping (ASCII out): backslash, line breaks, non-ASCII as \\uXXXX."""
    out = []
    for i, ch in enumerate(text):
        if ch == "\\":
            out.append("\\\\")
        elif ch in "\n\r\t\f":
            out.append({"\n": "\\n", "\r": "\\r", "\t": "\\t", "\f": "\\f"}[ch])
        elif (key and ch in "=: #!") or (ch == " " and i == 0):
            out.append("\\" + ch)
        elif not 32 <= ord(ch) < 127:
            out.extend(f"\\u{b:04x}" for b in _utf16(ch))
        else:
            out.append(ch)
    return "".join(out)


def _utf16(ch: str) -> list[int]:
    data = ch.encode("utf-16-be")
    return [int.from_bytes(data[i:i + 2], "big") for i in range(0, len(data), 2)]


def write_subset_catalog(source: Path, dest: Path, keep_ids: set[str]) -> int:
    """A copy of catalog `source` holding only the pieces `keep_ids` (and their model files); returns
    how many pieces it holds. Same file name, so ingest gives the pieces their original keys."""
    with zipfile.ZipFile(source) as zin:
        props = parse_properties(zin.read(CATALOG_FILE).decode("latin-1"))
    indices = {k.split("#", 1)[1] for k, v in props.items() if k.startswith("id#") and v in keep_ids}
    kept = {k: v for k, v in props.items() if "#" not in k or k.split("#", 1)[1] in indices}
    members: list[str] = []
    with SafeZip(source) as archive:
        for k, v in kept.items():
            if k.startswith("model#"):
                members += model_files(archive, v.strip().lstrip("/"))
        data = {m: archive.read(m) for m in dict.fromkeys(members)}
    dest.parent.mkdir(parents=True, exist_ok=True)
    text = "\n".join(f"{_escape(k, key=True)}={_escape(v)}" for k, v in sorted(kept.items())) + "\n"
    with zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as zout:
        zout.writestr(CATALOG_FILE, text.encode("ascii"))
        for member, payload in data.items():
            zout.writestr(member, payload)
    return len(indices)


def write_collection_shapes(items: list[ShapeItem], collection: list[ShapeInfo], dest: Path,
                            shared_models: Path) -> None:
    """Subset catalogs for the ingested catalogue pieces, copies of the ingested shared models."""
    wanted = {(s.source, s.source_id) for s in collection}
    by_catalog: dict[Path, set[str]] = {}
    for item in items:
        if (item.source, item.source_id) not in wanted:
            continue
        if item.archive is not None:
            by_catalog.setdefault(item.archive, set()).add(item.source_id.split("/", 1)[1])
        else:
            assert item.file is not None
            for file in [item.file, *_companions(item)]:
                target = dest / file.relative_to(shared_models)  # same relative path: same source id
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(file, target)
    for catalog, ids in sorted(by_catalog.items()):
        write_subset_catalog(catalog, dest / "catalogs" / catalog.name, ids)


def _companions(item: ShapeItem) -> list[Path]:
    """The files a shared model needs next to it (glTF buffers and textures, OBJ MTL and maps)."""
    with materialize(item) as files:
        return [Path(f) for f in files.files if Path(f) != item.file]


def collection_keys(folder: Path) -> set[tuple[str, str]]:
    """The natural keys `photoshape ingest shapes <folder>` gives: the check that the files written
    for the collection hold exactly the planned shapes."""
    return {(i.source, i.source_id) for i in discover_shapes([folder], category=None)
            if isinstance(i, ShapeItem)}
