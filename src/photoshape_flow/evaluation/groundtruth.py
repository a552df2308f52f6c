"""The ground-truth file format (docs/evaluation.md) parsed into typed records, without a database.

One JSON object: ``{"format": "photoshape-groundtruth", "version": 2, "exemplars": [entry, ...]}``;
any other top-level key (the demo's ``shapes``, ``materials``, ``stamps`` ...) is kept out of the
evaluation. Or JSON Lines (``.jsonl``): that object without ``exemplars`` on the first line, one entry
per further line, for collections written (or appended to) one photo at a time. Each entry names an
ingested exemplar by source and source id, its true shape, optionally its camera, the true material
and substance per part name, and optionally a per-pixel mask (part indices or material indices, path
relative to the file).

A bad entry (wrong JSON types, no parts, a mask value naming an unlisted part, a duplicate) gives one
message naming it and is left out, so one typo never costs the whole evaluation; only a file that is
not this format at all is an error (`GroundTruthError`). Names are checked against the database by
`scoring.groundtruth_match`, which keeps this module pure.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from photoshape_flow.export.text import one_line
from photoshape_flow.sidecar import DocumentError, parse_text

FORMAT = "photoshape-groundtruth"
MAX_BYTES = 256 * 1024 * 1024  # a million entries are a few hundred megabytes; more is no ground truth
MAX_DEPTH = 16  # an entry nests five levels deep (exemplars, entry, parts, part, value)
VERSION = 2
MASK_KINDS: tuple[str, ...] = ("part", "material")


class GroundTruthError(ValueError):
    """The file as a whole cannot be read as ground truth (not JSON, another format or version)."""


class EntryError(ValueError):
    """One entry is malformed; the message says why (the caller prefixes the entry's name)."""


@dataclass(frozen=True)
class ItemRef:
    """An ingested row by (source, source id); ``source=None`` matches any source."""

    source: str | None
    source_id: str

    def __str__(self) -> str:
        return self.source_id if self.source is None else f"{self.source}/{self.source_id}"


@dataclass(frozen=True)
class CameraTruth:
    """Azimuth and elevation in radians (as the coarse alignment's viewpoints), fov in degrees."""

    azimuth: float
    elevation: float
    distance: float | None = None
    fov: float | None = None


@dataclass(frozen=True)
class LightingTruth:
    """The light the photo was taken under: an equirectangular envmap turned by `rotation` radians about
    +y and scaled by `scale`, as `render.EnvmapSpec` lights a scene. `envmap` is a file (.hdr/.exr,
    relative to the ground-truth file; `path`) or the name of an envmap (ingested, or found by the
    tool that uses it in a folder it is given)."""

    envmap: str
    rotation: float = 0.0
    scale: float = 1.0
    path: Path | None = None


@dataclass(frozen=True)
class PartTruth:
    name: str
    material: str
    substance: str


@dataclass(frozen=True)
class MaskTruth:
    """A per-pixel label image in the photo's native frame: value -> part name or material name."""

    path: Path
    kind: Literal["part", "material"]
    values: dict[int, str]


@dataclass(frozen=True)
class TruthEntry:
    """One exemplar's ground truth.

    The attribute names are those the stage evaluators read (``shape``, ``in_collection``,
    ``camera``, ``part_names``, ``load_mask``), so a resolved entry is what they score against;
    `shape` is the true shape's source id, `in_collection` None until resolved against the database.
    """

    label: str
    exemplar: ItemRef
    shape_ref: ItemRef
    parts: dict[str, PartTruth]
    camera: CameraTruth | None = None
    mask: MaskTruth | None = None
    lighting: LightingTruth | None = None
    in_collection: bool | None = None
    material_substances: dict[str, str] = field(default_factory=dict)  # material masks: name -> substance
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def stem(self) -> str:
        return self.exemplar.source_id

    @property
    def shape(self) -> str:
        return self.shape_ref.source_id

    @property
    def part_names(self) -> dict[int, str]:
        """Mask value -> part name (part masks only: a material mask says nothing about parts)."""
        return dict(self.mask.values) if self.mask is not None and self.mask.kind == "part" else {}

    def load_mask(self) -> np.ndarray:
        """The label mask (H, W) in the photo's native frame; 0 = background."""
        if self.mask is None:
            raise ValueError(f"{self.label}: no mask")
        return read_part_mask(self.mask.path)

    def pixel_truths(self) -> dict[int, PartTruth]:
        """Mask value -> the (name, material, substance) its pixels show; for a material mask the
        name is the material's, its substance the one resolved from the database."""
        if self.mask is None:
            return {}
        if self.mask.kind == "part":
            return {v: self.parts[name] for v, name in self.mask.values.items() if name in self.parts}
        return {v: PartTruth(name, name, self.material_substances[name])
                for v, name in self.mask.values.items() if name in self.material_substances}


@dataclass(frozen=True)
class GroundTruthFile:
    path: Path
    sha256: str
    version: int
    entries: tuple[TruthEntry, ...]
    problems: tuple[str, ...]
    extra: dict[str, Any] = field(default_factory=dict)  # top-level keys outside the format


def source_keys(source_id: str) -> tuple[str, str, str]:
    """The keys a ground truth may list an ingested exemplar under, most specific first: its
    source_id, the file name in it, and that name without its extension (the demo's stem)."""
    name = source_id.rsplit("/", 1)[-1]
    return source_id, name, name.rsplit(".", 1)[0]


def read_part_mask(path: Path) -> np.ndarray:
    """A label mask file as stored (8- or 16-bit PNG; values as written, 0 = background)."""
    import cv2

    mask = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if mask is None:
        raise FileNotFoundError(f"{path}: cannot read the mask")
    return mask


# --- field readers: each raises EntryError with the field's name -----------------------------------


def _text(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise EntryError(f"{where} must be a non-empty string, got {value!r}")
    return value.strip()


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(float(value)):
        raise EntryError(f"{where} must be a finite number, got {value!r}")
    return float(value)


def _object(value: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise EntryError(f"{where} must be an object, got {type(value).__name__}")
    return value


def _ref(value: Any, where: str) -> ItemRef:
    """``{"source": ..., "source_id": ...}`` (source may be omitted or null: any source)."""
    obj = _object(value, where)
    source = obj.get("source")
    return ItemRef(None if source is None else _text(source, f"{where}.source"),
                   _text(obj.get("source_id"), f"{where}.source_id"))


def _camera(value: Any) -> CameraTruth | None:
    if value is None:
        return None
    obj = _object(value, "camera")
    optional = {k: None if obj.get(k) is None else _number(obj[k], f"camera.{k}") for k in ("distance", "fov")}
    return CameraTruth(_number(obj.get("azimuth"), "camera.azimuth"),
                       _number(obj.get("elevation"), "camera.elevation"), **optional)


ENVMAP_SUFFIXES = (".hdr", ".exr")


def _lighting(value: Any, root: Path) -> LightingTruth | None:
    if value is None:
        return None
    obj = _object(value, "lighting")
    envmap = _text(obj.get("envmap"), "lighting.envmap")
    rotation = 0.0 if obj.get("rotation") is None else _number(obj["rotation"], "lighting.rotation")
    scale = 1.0 if obj.get("scale") is None else _number(obj["scale"], "lighting.scale")
    if scale <= 0:
        raise EntryError(f"lighting.scale must be positive, got {scale}")
    path = Path(envmap)
    if path.suffix.lower() in ENVMAP_SUFFIXES:
        return LightingTruth(envmap, rotation, scale, path if path.is_absolute() else root / path)
    return LightingTruth(envmap, rotation, scale)


def _parts(value: Any) -> dict[str, PartTruth]:
    obj = _object(value, "parts")
    if not obj:
        raise EntryError("parts is empty: give each part's material and substance")
    out = {}
    for name, part in obj.items():
        part = _object(part, f"parts.{name}")
        out[name] = PartTruth(name, _text(part.get("material"), f"parts.{name}.material"),
                              _text(part.get("substance"), f"parts.{name}.substance"))
    return out


def _mask(value: Any, root: Path, parts: Mapping[str, PartTruth]) -> MaskTruth | None:
    if value is None:
        return None
    obj = _object(value, "mask")
    kind = obj.get("kind", "part")
    if kind not in MASK_KINDS:
        raise EntryError(f"mask.kind must be one of {', '.join(MASK_KINDS)}, got {kind!r}")
    values: dict[int, str] = {}
    for key, name in _object(obj.get("values"), "mask.values").items():
        try:
            number = int(key)
        except ValueError:
            raise EntryError(f"mask.values key {key!r} is not a pixel value") from None
        if not 0 < number < 65536:
            raise EntryError(f"mask.values key {key!r} must lie in 1..65535 (0 is background)")
        values[number] = _text(name, f"mask.values.{key}")
    if not values:
        raise EntryError("mask.values is empty")
    if kind == "part":
        unlisted = sorted(set(values.values()) - set(parts))
        if unlisted:
            raise EntryError(f"mask values name parts missing from parts: {', '.join(unlisted)}")
    path = Path(_text(obj.get("path"), "mask.path"))
    return MaskTruth(path if path.is_absolute() else root / path, kind, values)


def parse_entry(data: Any, root: Path, label: str) -> TruthEntry:
    """One entry of ``exemplars``; raises EntryError on the first thing wrong with it."""
    obj = _object(data, "the entry")
    exemplar = ItemRef(None if obj.get("source") is None else _text(obj["source"], "source"),
                       _text(obj.get("source_id"), "source_id"))
    in_collection = obj.get("in_collection")
    if in_collection is not None and not isinstance(in_collection, bool):
        raise EntryError(f"in_collection must be true or false, got {in_collection!r}")
    parts = _parts(obj.get("parts"))
    known = {"source", "source_id", "shape", "in_collection", "camera", "parts", "mask", "lighting"}
    return TruthEntry(
        label=f"{label} ({exemplar})",
        exemplar=exemplar,
        shape_ref=_ref(obj.get("shape"), "shape"),
        parts=parts,
        camera=_camera(obj.get("camera")),
        mask=_mask(obj.get("mask"), root, parts),
        lighting=_lighting(obj.get("lighting"), root),
        in_collection=in_collection,
        extra={k: v for k, v in obj.items() if k not in known},
    )


def parse_groundtruth_data(data: Any, root: Path, *, path: Path | None = None, sha256: str = "",
                           labels: Sequence[str] | None = None, problems: Sequence[str] = ()) -> GroundTruthFile:
    """Typed entries and one message per entry left out; raises GroundTruthError for a foreign file.

    `labels` name the entries in messages (default ``exemplars[i]``; a JSON Lines file's line
    numbers); `problems` are those found before parsing (lines that are not JSON)."""
    where = path or root
    if not isinstance(data, Mapping):
        raise GroundTruthError(f"{where}: the ground truth must be a JSON object")
    if data.get("format") != FORMAT:
        hint = " (a pre-format demo file: run `photoshape demo` again)" if data.get("version") == 1 else ""
        raise GroundTruthError(f"{where}: \"format\" must be {FORMAT!r}, got {data.get('format')!r}{hint}")
    if data.get("version") != VERSION:
        raise GroundTruthError(f"{where}: version {data.get('version')!r} not supported (expected {VERSION})")
    raw = data.get("exemplars")
    if not isinstance(raw, list):
        raise GroundTruthError(f"{where}: \"exemplars\" must be a list of entries")
    entries: list[TruthEntry] = []
    problems = list(problems)
    seen: dict[ItemRef, str] = {}
    for i, item in enumerate(raw):
        label = labels[i] if labels is not None else f"exemplars[{i}]"
        try:
            entry = parse_entry(item, root, label)
        except EntryError as exc:
            named = item.get("source_id") if isinstance(item, Mapping) else None
            problems.append(f"{label}{f' ({named})' if isinstance(named, str) else ''}: {exc}; skipped")
            continue
        if entry.exemplar in seen:
            problems.append(f"{entry.label}: the same exemplar as {seen[entry.exemplar]}; skipped")
            continue
        seen[entry.exemplar] = entry.label
        entries.append(entry)
    extra = {k: v for k, v in data.items() if k not in ("format", "version", "exemplars")}
    return GroundTruthFile(path=Path(where), sha256=sha256, version=VERSION, entries=tuple(entries),
                           problems=tuple(one_line(problem) for problem in problems), extra=extra)


def _json_lines(text: str, where: Path) -> tuple[dict[str, Any], list[str], list[str]]:
    """A JSON Lines file as the object it stands for: the first non-empty line is the header
    (``format``, ``version``, any other top-level key), each further line one entry. Returns (data,
    the entries' labels "line N", one problem per line that is not JSON)."""
    lines = [(n, line) for n, line in enumerate(text.splitlines(), start=1) if line.strip()]
    if not lines:
        raise GroundTruthError(f"{where}: empty")
    try:
        header = parse_text(lines[0][1], "json", MAX_DEPTH, finite_only=False)
    except DocumentError as exc:
        raise GroundTruthError(f"{where}: line {lines[0][0]}, the header, is not JSON ({exc})") from exc
    if not isinstance(header, Mapping):
        raise GroundTruthError(f"{where}: line {lines[0][0]} must be the header object (format, version)")
    entries: list[Any] = []
    labels: list[str] = []
    problems: list[str] = []
    for n, line in lines[1:]:
        try:
            entries.append(parse_text(line, "json", MAX_DEPTH, finite_only=False))
        except DocumentError as exc:
            problems.append(f"line {n}: not JSON ({exc}); skipped")
            continue
        labels.append(f"line {n}")
    return {**header, "exemplars": entries}, labels, problems


def read_groundtruth_file(path: Path | str) -> GroundTruthFile:
    """Read and parse a ground-truth file (JSON, or JSON Lines when it ends in .jsonl); its sha256 tags
    the evaluation it feeds."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_BYTES:
            raise GroundTruthError(f"{path}: {size} bytes (limit {MAX_BYTES})")
        raw = path.read_bytes()
    except OSError as exc:
        raise GroundTruthError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    sha256 = hashlib.sha256(raw).hexdigest()
    try:
        text = raw.decode("utf-8")
        if path.suffix.lower() == ".jsonl":
            data, labels, problems = _json_lines(text, path)
            return parse_groundtruth_data(data, path.parent, path=path, sha256=sha256, labels=labels,
                                          problems=problems)
        data = parse_text(text, "json", MAX_DEPTH, finite_only=False)  # bounded depth and digits
    except (DocumentError, UnicodeDecodeError) as exc:
        raise GroundTruthError(f"{path}: not JSON ({exc})") from exc
    return parse_groundtruth_data(data, path.parent, path=path, sha256=sha256)
