"""Sweet Home 3D furniture catalogs (.sh3f): the catalog listing and each model's files.

A catalog is a zip holding `PluginFurnitureCatalog.properties` (Java properties, ISO-8859-1 with
\\uXXXX escapes) whose numbered keys (`name#7`, `model#7`, `category#7`, `modelRotation#7`, ...)
describe each piece, and the OBJ + MTL + textures of every model. `catalog_entries` lists the pieces;
`model_files` finds the OBJ's MTL libraries and textures inside the zip (the dependency closure) so
only those are extracted, through `SafeZip`.

The properties are anyone's text, and `\\uXXXX` escapes can spell characters no database stores (a
lone surrogate, a NUL): a piece whose id, name or stored fields hold one, or whose id or name is
longer than its column, is listed as invalid with its reason (`piece_refusal`), and such a catalog
header refuses the catalog.
"""

from __future__ import annotations

import math
import posixpath
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from photoshape_flow.export.text import hidden_character
from photoshape_flow.geometry.archive import SafeZip, UnsafeArchiveError, join_member, normalise_member
from photoshape_flow.geometry.mtl import mtl_references
from photoshape_flow.geometry.obj import obj_references
from photoshape_flow.geometry.raw import BadShapeError
from photoshape_flow.sidecar import unstorable_character

CATALOG_FILE = "PluginFurnitureCatalog.properties"
MAX_KEY_CHARS = 255  # shape.source_id (<catalog stem>/<piece id>) and shape.name are String(255)
MAX_CATEGORY_CHARS = 64  # shape.category is String(64)
STORED_FIELDS = ("name", "creator", "tags", "category", "model", "width", "depth", "height")  # what reaches a row
HEADER_FIELDS = ("id", "name", "license", "provider")  # the catalog's, in every piece's row

# Keywords in a piece's name or tags -> our category (first match wins; checked in this order).
CATEGORY_KEYWORDS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("sofa", ("sofa", "couch", "loveseat", "settee", "futon", "canape")),
    ("stool", ("stool",)),
    ("bench", ("bench",)),
    ("chair", ("armchair", "chair", "recliner", "rocker")),
    ("table", ("table", "desk")),
    ("bed", ("bed",)),
    ("lamp", ("lamp", "light")),
    ("cabinet", ("cabinet", "cupboard", "dresser", "wardrobe", "shelf", "bookcase")),
)


def parse_properties(text: str) -> dict[str, str]:
    """Java .properties: comments, `=`/`:`/space separators, line continuations, \\u escapes."""
    result: dict[str, str] = {}
    logical: list[str] = []
    buffer = ""
    for raw in text.splitlines():
        line = raw.lstrip()
        if not buffer and (not line or line[0] in "#!"):
            continue
        trailing = len(line) - len(line.rstrip("\\"))
        if trailing % 2 == 1:
            buffer += line[:-1]
            continue
        logical.append(buffer + line)
        buffer = ""
    if buffer:
        logical.append(buffer)
    for line in logical:
        match = re.match(r"((?:\\.|[^=:\s\\])*)\s*[=:\s]?\s*(.*)$", line)
        if not match:
            continue
        key, value = _unescape(match.group(1)), _unescape(match.group(2))
        if key:
            result[key] = value
    return result


def _unescape(value: str) -> str:
    out: list[str] = []
    i = 0
    while i < len(value):
        ch = value[i]
        if ch == "\\" and i + 1 < len(value):
            nxt = value[i + 1]
            if nxt == "u" and re.match(r"[0-9a-fA-F]{4}", value[i + 2 : i + 6]):
                out.append(chr(int(value[i + 2 : i + 6], 16)))
                i += 6
                continue
            out.append({"t": "\t", "n": "\n", "r": "\r", "f": "\f"}.get(nxt, nxt))
            i += 2
            continue
        out.append(ch)
        i += 1
    return "".join(out)


def category_of(name: str, tags: str = "", catalog_category: str = "") -> str:
    """Our category for a catalog piece from its name and tags; the catalog's category otherwise."""
    words = set(re.findall(r"[a-z]+", f"{name} {tags}".lower()))
    text = f"{name} {tags}".lower()
    for category, keywords in CATEGORY_KEYWORDS:
        for keyword in keywords:
            if keyword in words or re.search(rf"\b{keyword}s?\b", text):
                return category
    slug = re.sub(r"[^a-z0-9]+", "-", catalog_category.lower())[:MAX_CATEGORY_CHARS].strip("-")
    return slug or "misc"


@dataclass
class CatalogEntry:
    index: int
    id: str
    name: str
    category: str  # ours (chair, sofa, stool, ...)
    catalog_category: str
    tags: str
    model: str  # normalised member name of the model file
    creator: str | None
    rotation: tuple[float, ...] | None
    props: dict[str, Any] = field(default_factory=dict)


@dataclass
class Catalog:
    path: Path
    id: str
    name: str
    license: str | None
    provider: str | None
    entries: list[CatalogEntry]
    invalid: list[tuple[str, str, str | None]]  # (label, reason, piece id; None when the id cannot key a row)


def piece_refusal(piece_id: str, fields: dict[str, str | None], stem: str) -> tuple[str, bool] | None:
    """Why a catalog piece cannot be stored, and whether its id can still key its rejected row; None if it can.

    The id becomes part of `source_id` and the name `shape.name`: both are names, so a hidden
    character refuses them (`hidden_character`), as do lengths past the columns. The other fields
    are free text, escaped wherever shown, but a NUL or lone surrogate cannot be stored at all.
    """
    hidden = unstorable_character(piece_id) or hidden_character(piece_id)
    if hidden is not None:
        return f"catalog id contains {hidden}", False
    if len(stem) + 1 + len(piece_id) > MAX_KEY_CHARS:
        return f"catalog id is {len(piece_id)} characters long (limit {MAX_KEY_CHARS - len(stem) - 1})", False
    name = fields.get("name") or ""
    hidden = unstorable_character(name) or hidden_character(name)
    if hidden is not None:
        return f"name contains {hidden}", True
    if len(name) > MAX_KEY_CHARS:
        return f"name is {len(name)} characters long (limit {MAX_KEY_CHARS})", True
    for key, value in fields.items():
        problem = unstorable_character(value or "")
        if problem is not None:
            return f"{key} contains {problem}", True
    return None


def read_catalog(archive: SafeZip) -> Catalog:
    """The pieces of a catalog, with their model members validated (no traversal)."""
    if archive.find(CATALOG_FILE) is None:
        raise BadShapeError(f"{archive.path.name}: no {CATALOG_FILE} (not a Sweet Home 3D furniture catalog)")
    props = parse_properties(archive.read(CATALOG_FILE).decode("latin-1"))
    for key in HEADER_FIELDS:
        problem = unstorable_character(props.get(key) or "")
        if problem is not None:
            raise BadShapeError(f"{archive.path.name}: catalog {key} contains {problem}")
    indices = sorted({int(k.split("#", 1)[1]) for k in props if re.match(r"^model#\d+$", k)})
    entries: list[CatalogEntry] = []
    invalid: list[tuple[str, str, str | None]] = []
    for i in indices:
        get = lambda key, i=i: props.get(f"{key}#{i}")  # noqa: E731
        piece_id = get("id") or f"piece-{i}"
        name = get("name") or piece_id
        label = f"{archive.path.name}:{piece_id}"
        refusal = piece_refusal(piece_id, {key: get(key) for key in STORED_FIELDS}, archive.path.stem)
        if refusal is not None:
            invalid.append((label, refusal[0], piece_id if refusal[1] else None))
            continue
        model = (get("model") or "").strip()
        try:
            if not model:
                raise BadShapeError("no model file")
            member = normalise_member(model.lstrip("/"))
        except BadShapeError as exc:
            invalid.append((label, str(exc), piece_id))
            continue
        rotation = None
        if raw_rotation := get("modelRotation"):
            try:
                values = tuple(float(x) for x in raw_rotation.split())
                rotation = values if len(values) == 9 else None
            except ValueError:
                rotation = None
            if rotation is not None and not all(math.isfinite(v) and abs(v) <= 1.001 for v in rotation):
                invalid.append((label, "modelRotation is no rotation matrix (non-finite or beyond ±1 values)",
                                piece_id))
                continue
        tags = get("tags") or ""
        catalog_category = get("category") or ""
        entries.append(
            CatalogEntry(
                index=i,
                id=piece_id,
                name=name,
                category=category_of(name, tags, catalog_category),
                catalog_category=catalog_category,
                tags=tags,
                model=member,
                creator=get("creator"),
                rotation=rotation,
                props={k.split("#", 1)[0]: v for k, v in props.items() if k.endswith(f"#{i}")},
            )
        )
    return Catalog(
        path=archive.path,
        id=props.get("id", archive.path.stem),
        name=props.get("name", archive.path.stem),
        license=props.get("license"),
        provider=props.get("provider"),
        entries=entries,
        invalid=invalid,
    )


def model_files(archive: SafeZip, model: str) -> list[str]:
    """The model member and the MTL libraries and textures it references (present members only)."""
    info = archive.find(model)
    if info is None:
        raise BadShapeError(f"model {model!r} is missing from the archive")
    files = [model]
    if not model.lower().endswith(".obj"):
        return files
    base = posixpath.dirname(model)
    text = archive.read(model).decode("utf-8", errors="replace")
    for lib in obj_references(text):
        mtl = join_member(base, lib)
        if archive.find(mtl) is None:
            continue
        files.append(mtl)
        mtl_text = archive.read(mtl).decode("utf-8", errors="replace")
        for tex in mtl_references(mtl_text):
            try:
                member: str | None = join_member(posixpath.dirname(mtl), tex)
            except UnsafeArchiveError:  # an absolute path from the author's machine: never followed, but the
                member = None           # file of that name next to the model is used, as the OBJ loader does
            if member is not None and archive.find(member) is not None:
                files.append(member)
            else:
                nearby = join_member(base, posixpath.basename(tex.replace("\\", "/")))
                if archive.find(nearby) is not None:
                    files.append(nearby)
    return list(dict.fromkeys(files))
