"""Where shapes come from: plain OBJ/glTF/GLB files, the ShapeNetCore v2 layout, Sweet Home 3D catalogs.

`discover_shapes` turns the paths a user gives into `ShapeItem`s with their natural key
(source, source_id), name, category and licence, without reading any geometry; bad paths come back
as `RejectedInput` so a batch goes on. `materialize` then makes an item's files available on disk
(extracting only its own members from an archive) and returns the content hash of everything the
shape is made of (model, MTL, textures), the hash that makes re-ingest idempotent.

Natural keys:
- plain files: source "local" (or --source), source_id = the path relative to the folder given
  without extension (``a/chair`` for ``<folder>/a/chair.obj``), or the file stem for a file given
  by itself (`photoshape_flow.inputs.source_id_for`);
- ShapeNet: source "shapenet", source_id "<synset>/<model id>", category from the synset;
- Sweet Home 3D: source "sweethome3d", source_id "<catalog file stem>/<piece id>".
"""

from __future__ import annotations

import hashlib
import re
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import unquote

from photoshape_flow.geometry.archive import ArchiveLimits, SafeZip, normalise_member
from photoshape_flow.geometry.obj import referenced_files, resolve_inside
from photoshape_flow.geometry.raw import BadShapeError
from photoshape_flow.geometry.sh3f import model_files, read_catalog
from photoshape_flow.inputs import Fingerprints, fingerprint, walk_inputs
from photoshape_flow.sidecar import parse_document

MODEL_SUFFIXES = {".obj": "obj", ".gltf": "gltf", ".glb": "glb"}
CATALOG_SUFFIXES = {".sh3f"}
GLTF_MAX_JSON_BYTES = 64 * 1024 * 1024  # a .gltf's JSON (geometry lives in its buffers)

# ShapeNetCore v2 synset ids -> category names.
SHAPENET_SYNSETS: dict[str, str] = {
    "02691156": "airplane", "02747177": "trash_bin", "02773838": "bag", "02801938": "basket",
    "02808440": "bathtub", "02818832": "bed", "02828884": "bench", "02843684": "birdhouse",
    "02871439": "bookshelf", "02876657": "bottle", "02880940": "bowl", "02924116": "bus",
    "02933112": "cabinet", "02942699": "camera", "02946921": "can", "02954340": "cap",
    "02958343": "car", "02992529": "cellphone", "03001627": "chair", "03046257": "clock",
    "03085013": "keyboard", "03207941": "dishwasher", "03211117": "display", "03261776": "earphone",
    "03325088": "faucet", "03337140": "file_cabinet", "03467517": "guitar", "03513137": "helmet",
    "03593526": "jar", "03624134": "knife", "03636649": "lamp", "03642806": "laptop",
    "03691459": "loudspeaker", "03710193": "mailbox", "03759954": "microphone", "03761084": "microwave",
    "03790512": "motorbike", "03797390": "mug", "03928116": "piano", "03938244": "pillow",
    "03948459": "pistol", "03991062": "pot", "04004475": "printer", "04074963": "remote",
    "04090263": "rifle", "04099429": "rocket", "04225987": "skateboard", "04256520": "sofa",
    "04330267": "stove", "04379243": "table", "04401088": "telephone", "04460130": "tower",
    "04468005": "train", "04530566": "vessel", "04554684": "washer",
}
SYNSET_PATTERN = re.compile(r"^\d{8}$")


@dataclass
class ShapeItem:
    """One shape to ingest, before its geometry is read."""

    source: str
    source_id: str
    label: str  # for messages: a path, or "<catalog>.sh3f:<piece id>"
    fmt: str  # obj | gltf | glb
    name: str | None = None
    category: str | None = None
    file: Path | None = None  # model file on disk
    root: Path | None = None  # MTL/texture references must stay inside this folder
    archive: Path | None = None  # catalog the model lives in
    member: str | None = None  # model member inside `archive`
    size_bytes: int = 0
    license: str | None = None
    attribution: str | None = None
    source_url: str | None = None
    rotation: tuple[float, ...] | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    legacy_id: str | None = None  # the id of plain files before ids were relative paths (the stem)


@dataclass
class RejectedInput:
    """A path or catalog piece that cannot be ingested, with the reason (and its key if known)."""

    label: str
    reason: str
    source: str | None = None
    source_id: str | None = None
    name: str | None = None


def _categories(category: str | None) -> set[str] | None:
    if not category:
        return None
    return {c.strip().lower() for c in category.split(",") if c.strip()}


def _matches(pattern: re.Pattern[str] | None, *texts: str | None) -> bool:
    if pattern is None:
        return True
    return any(t and pattern.search(t) for t in texts)


def compile_filter(name_filter: str | None) -> re.Pattern[str] | None:
    """A case-insensitive regular expression, or ValueError with a readable message."""
    if not name_filter:
        return None
    try:
        return re.compile(name_filter, re.IGNORECASE)
    except re.error as exc:
        raise ValueError(f"invalid --name-filter {name_filter!r}: {exc}") from exc


def _shapenet_key(path: Path) -> tuple[str, str] | None:
    """(synset, model id) when `path` is <synset>/<id>/models/model_normalized.obj."""
    if path.name != "model_normalized.obj" or path.parent.name != "models":
        return None
    model_dir = path.parent.parent
    synset = model_dir.parent.name
    if not SYNSET_PATTERN.match(synset):
        return None
    return synset, model_dir.name


def _catalog_items(
    path: Path, source: str | None, cats: set[str] | None, pattern: re.Pattern[str] | None,
    license: str | None, limits: ArchiveLimits,
) -> Iterator[ShapeItem | RejectedInput]:
    try:
        with SafeZip(path, limits) as archive:
            catalog = read_catalog(archive)
            sizes = {name.lower(): archive.find(name).file_size for name in archive.names()}  # type: ignore[union-attr]
    except Exception as exc:  # BadShapeError, OSError, and whatever a corrupt zip raises (one catalog, one line)
        # a catalog-level row (source_id: the catalog's stem), so the reject is queryable like others
        reason = (str(exc) if isinstance(exc, BadShapeError | OSError)
                  else f"unreadable catalog ({type(exc).__name__}: {exc})")
        yield RejectedInput(str(path), reason.splitlines()[0] if reason.strip() else type(exc).__name__,
                            source or "sweethome3d", path.stem, path.stem)
        return
    src = source or "sweethome3d"
    if not catalog.entries and not catalog.invalid:
        yield RejectedInput(str(path), "no furniture in the catalog (no model#N entries)", src, path.stem, path.stem)
        return
    for label, reason, piece_id in catalog.invalid:  # a piece whose id cannot key a row is a line only
        yield (RejectedInput(label, reason) if piece_id is None
               else RejectedInput(label, reason, src, f"{path.stem}/{piece_id}"))
    for entry in catalog.entries:
        if cats is not None and entry.category not in cats:
            continue
        if not _matches(pattern, entry.name, entry.id, entry.tags, entry.catalog_category):
            continue
        suffix = Path(entry.model).suffix.lower()
        label = f"{path.name}:{entry.id}"
        source_id = f"{path.stem}/{entry.id}"
        if suffix not in MODEL_SUFFIXES:
            yield RejectedInput(label, f"unsupported model format {suffix!r}", src, source_id, entry.name)
            continue
        creator = entry.creator or "unknown"
        yield ShapeItem(
            source=src,
            source_id=source_id,
            label=label,
            fmt=MODEL_SUFFIXES[suffix],
            name=entry.name,
            category=entry.category,
            archive=path,
            member=entry.model,
            size_bytes=sizes.get(entry.model.lower(), 0),
            license=license or catalog.license,
            attribution=f"{entry.name} by {creator}, {catalog.name} ({catalog.provider or 'Sweet Home 3D'})",
            rotation=entry.rotation,
            meta={
                "catalog": catalog.name,
                "catalog_id": catalog.id,
                "catalog_category": entry.catalog_category,
                "tags": entry.tags,
                "creator": entry.creator,
                "dimensions_cm": {k: entry.props.get(k) for k in ("width", "depth", "height")},
            },
        )


def discover_shapes(
    paths: Iterable[str | Path],
    *,
    source: str | None = None,
    category: str | None = None,
    name_filter: str | None = None,
    license: str | None = None,
    attribution: str | None = None,
    archive_limits: ArchiveLimits | None = None,
) -> list[ShapeItem | RejectedInput]:
    """Expand files, folders (recursively) and catalogs into items, in a deterministic order.

    `category`: for ShapeNet and catalogs, keep only items of these categories (comma-separated);
    plain files, whose source says nothing, are given it. `name_filter`: a regular expression on
    names, ids, tags or file stems.
    """
    cats = _categories(category)
    pattern = compile_filter(name_filter)
    limits = archive_limits or ArchiveLimits()
    out: list[ShapeItem | RejectedInput] = []
    for found in walk_inputs(paths, set(MODEL_SUFFIXES) | CATALOG_SUFFIXES):
        file = found.path
        if found.reason is not None:
            out.append(RejectedInput(str(file), found.reason))
            continue
        suffix = file.suffix.lower()
        if suffix in CATALOG_SUFFIXES:
            out.extend(_catalog_items(file, source, cats, pattern, license, limits))
            continue
        try:
            size = file.stat().st_size
        except OSError as exc:
            out.append(RejectedInput(str(file), f"unreadable ({exc.strerror or exc})"))
            continue
        key = _shapenet_key(file)
        if key is not None:
            synset, model_id = key
            item_category = SHAPENET_SYNSETS.get(synset, synset)
            if cats is not None and item_category not in cats and synset not in cats:
                continue
            if not _matches(pattern, f"{synset}/{model_id}", item_category):
                continue
            out.append(ShapeItem(
                source=source or "shapenet", source_id=f"{synset}/{model_id}", label=str(file), fmt="obj",
                name=model_id, category=item_category, file=file, root=file.parent.parent, size_bytes=size,
                license=license, attribution=attribution or "ShapeNetCore v2", meta={"synset": synset},
            ))
            continue
        root = found.root or file.parent
        rel = file.relative_to(root).as_posix()
        if not _matches(pattern, file.stem, rel):
            continue
        single = category if category and "," not in category else None
        out.append(ShapeItem(
            source=source or "local", source_id=found.source_id, label=str(file), fmt=MODEL_SUFFIXES[suffix],
            name=file.stem, category=single, file=file, root=root, size_bytes=size, license=license,
            attribution=attribution, meta={"relative_path": rel}, legacy_id=found.legacy_id,
        ))
    return out


def gltf_references(path: Path) -> list[Path]:
    """External buffers and images of a .gltf (data: URIs excluded), for content hashing."""
    try:
        doc = parse_document(path, max_bytes=GLTF_MAX_JSON_BYTES)
    except (OSError, ValueError):
        return []
    found: list[Path] = []
    for key in ("buffers", "images"):
        for entry in doc.get(key, []) if isinstance(doc, dict) else []:
            uri = entry.get("uri") if isinstance(entry, dict) else None
            if not isinstance(uri, str) or uri.startswith("data:"):
                continue
            ref = resolve_inside(path.parent, unquote(uri), path.parent)
            if ref is not None:
                found.append(ref)
    return found


def content_hash(entries: Iterable[tuple[str, bytes]]) -> str:
    """sha256 over (name, sha256(data)) of a shape's files, main file first, names relative."""
    digest = hashlib.sha256()
    for name, data in entries:
        digest.update(name.encode())
        digest.update(b"\0")
        digest.update(hashlib.sha256(data).digest())
    return digest.hexdigest()


def _file_hash(paths: list[Path], base: Path) -> str:
    def entries() -> Iterator[tuple[str, bytes]]:
        for p in paths:
            try:
                name = p.resolve().relative_to(base.resolve()).as_posix()
            except ValueError:
                name = p.name
            yield name, p.read_bytes()

    return content_hash(entries())


@dataclass
class Materialized:
    model: Path
    root: Path
    sha256: str
    files: list[str]
    fingerprints: Fingerprints = field(default_factory=dict)  # plain files: taken before hashing


@contextmanager
def materialize(item: ShapeItem, limits: ArchiveLimits | None = None) -> Iterator[Materialized]:
    """The item's files on disk (a temporary extraction for catalog pieces) and their content hash."""
    if item.archive is None:
        assert item.file is not None
        model = item.file
        root = item.root or model.parent
        if item.fmt == "obj":
            deps = referenced_files(model, root)
        elif item.fmt == "gltf":
            deps = gltf_references(model)
        else:
            deps = []
        paths = [model, *[d for d in deps if d != model]]
        before = fingerprint(paths)
        sha = _file_hash(paths, model.parent)
        yield Materialized(model=model, root=root, sha256=sha, files=[str(p) for p in paths], fingerprints=before)
        return

    assert item.member is not None
    with SafeZip(item.archive, limits) as archive, tempfile.TemporaryDirectory(prefix="photoshape-sh3f-") as tmp:
        members = model_files(archive, item.member)
        tmp_root = Path(tmp)
        entries: list[tuple[str, bytes]] = []
        for member in members:
            data = archive.read(member)
            entries.append((member, data))
            archive.extract(member, tmp_root, data=data)
        info = archive.find(item.member)
        assert info is not None

        model = tmp_root / normalise_member(info.filename)
        yield Materialized(model=model, root=tmp_root, sha256=content_hash(entries), files=members)
