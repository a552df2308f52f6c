"""The demo's ground truth (groundtruth.json) as typed dataclasses, for the demo's own tools.

The file is the general ground-truth format (docs/evaluation.md, `evaluation.groundtruth`),
which `photoshape eval` reads like any other; the demo adds top-level blocks and per-entry fields
that only its benches and experiments use (paths relative to the demo folder):

    {"format": "photoshape-groundtruth", "version": 2, "size": "small", "seed": 0,
     "generator": "photoshape_flow demo <GENERATOR_VERSION>",
     "shapes": {source_id: {"kind", "in_collection", "path", "segmentation": "semantic|over|under",
                            "similar_to": source_id | null,
                            "parts": [{"index", "name", "roles": [...]}, ...]}},
     "materials": {name: {"substance", "path"}},
     "envmaps": [name, ...],                  # the collection (envmaps/<name>.hdr)
     "heldout_envmaps": [name, ...],          # used for exemplars only (groundtruth/envmaps/)
     "exemplars": [{"source": "demo-<size>", "source_id": stem,            # the format's fields
                    "shape": {"source": "demo-<size>", "source_id": ...}, "in_collection",
                    "camera": {"azimuth", "elevation", "distance", "fov"},
                    "parts": {name: {"material", "substance"}},
                    "mask": {"path", "kind": "part", "values": {"1": name, ...}},
                    "lighting": {"envmap": "groundtruth/envmaps/<name>.hdr", "rotation", "scale"},
                    "image", "size", "similar_to", "visible_parts",      # the demo's own
                    "envmap": {"name", "rotation", "scale"}, "degradation": {...}, "spec_hash": str}, ...]}

The evaluators take the typed `GroundTruth` or, in tests and scripts, a plain mapping from an
exemplar's stem to a dict with the same field names; `exemplar_records`, `record_for_source`,
`record_field` and `record_mask` read both alike, so every evaluator matches exemplars to records
and reads their fields the same way.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from photoshape_flow.evaluation.groundtruth import (
    FORMAT,
    VERSION,
    PartTruth,
    parse_groundtruth_data,
    read_part_mask,
    source_keys,
)
from photoshape_flow.render.camera import Camera

GROUNDTRUTH_FORMAT, GROUNDTRUTH_VERSION = FORMAT, VERSION


@dataclass(frozen=True)
class CameraTruth:
    azimuth: float
    elevation: float
    distance: float
    fov: float

    def to_camera(self) -> Camera:
        return Camera(self.azimuth, self.elevation, self.distance, self.fov)


@dataclass(frozen=True)
class ShapePartTruth:
    index: int
    name: str
    roles: tuple[str, ...]


@dataclass(frozen=True)
class ShapeTruth:
    source_id: str
    kind: str
    in_collection: bool
    path: Path
    segmentation: str
    similar_to: str | None
    parts: tuple[ShapePartTruth, ...]


@dataclass(frozen=True)
class MaterialTruth:
    name: str
    substance: str
    path: Path


@dataclass(frozen=True)
class ExemplarTruth:
    stem: str
    image: Path
    mask: Path
    size: int
    shape: str
    in_collection: bool
    similar_to: str | None
    camera: CameraTruth
    part_names: dict[int, str]
    parts: dict[str, PartTruth]
    visible_parts: tuple[str, ...]
    envmap: dict[str, Any] = field(default_factory=dict)
    degradation: dict[str, Any] = field(default_factory=dict)

    def load_mask(self) -> np.ndarray:
        """The part-index mask (H, W) in the exemplar's native frame; 0 = background."""
        return read_part_mask(self.mask)

    def substance_mask(self, substances: tuple[str, ...]) -> np.ndarray:
        """(H, W) labels: 0 background, 1 + substances.index(s) for parts of substance s."""
        mask = self.load_mask()
        lut = np.zeros(int(max(self.part_names, default=0)) + 1, np.uint8)
        for index, name in self.part_names.items():
            part = self.parts.get(name)
            if part is not None:
                lut[index] = 1 + substances.index(part.substance)
        return lut[np.clip(mask, 0, len(lut) - 1)]


@dataclass(frozen=True)
class GroundTruth:
    root: Path
    size: str
    seed: int
    generator: str
    shapes: dict[str, ShapeTruth]
    materials: dict[str, MaterialTruth]
    envmaps: tuple[str, ...]
    heldout_envmaps: tuple[str, ...]
    exemplars: dict[str, ExemplarTruth]


def _opt(value: Any) -> str | None:
    return None if value is None else str(value)


def parse_groundtruth(data: dict[str, Any], root: Path) -> GroundTruth:
    """GroundTruth from the decoded JSON; paths are resolved against `root`. The exemplars are read by
    the general format's parser (`evaluation.groundtruth`), so the demo's file is checked like
    any user's; a demo file with a bad entry is a bug, hence an error here."""
    general = parse_groundtruth_data(data, root)
    if general.problems:
        raise ValueError(f"{root}: demo ground truth has bad entries: {'; '.join(general.problems)}")
    shapes = {
        sid: ShapeTruth(
            source_id=sid,
            kind=str(s["kind"]),
            in_collection=bool(s["in_collection"]),
            path=root / s["path"],
            segmentation=str(s["segmentation"]),
            similar_to=_opt(s.get("similar_to")),
            parts=tuple(ShapePartTruth(int(p["index"]), str(p["name"]), tuple(p["roles"])) for p in s["parts"]),
        )
        for sid, s in data["shapes"].items()
    }
    materials = {
        name: MaterialTruth(name, str(m["substance"]), root / m["path"]) for name, m in data["materials"].items()
    }
    exemplars = {}
    for entry in general.entries:
        e, camera = entry.extra, entry.camera
        if camera is None or entry.mask is None or camera.distance is None or camera.fov is None:
            raise ValueError(f"{root}: demo ground truth {entry.label} lacks its camera or mask")
        exemplars[entry.stem] = ExemplarTruth(
            stem=entry.stem,
            image=root / e["image"],
            mask=entry.mask.path,
            size=int(e["size"]),
            shape=entry.shape,
            in_collection=bool(entry.in_collection),
            similar_to=_opt(e.get("similar_to")),
            camera=CameraTruth(camera.azimuth, camera.elevation, camera.distance, camera.fov),
            part_names=dict(sorted(entry.part_names.items())),
            parts=dict(entry.parts),
            visible_parts=tuple(e.get("visible_parts", ())),
            envmap=dict(e.get("envmap", {})),
            degradation=dict(e.get("degradation", {})),
        )
    return GroundTruth(
        root=root,
        size=str(data["size"]),
        seed=int(data["seed"]),
        generator=str(data["generator"]),
        shapes=shapes,
        materials=materials,
        envmaps=tuple(data.get("envmaps", ())),
        heldout_envmaps=tuple(data.get("heldout_envmaps", ())),
        exemplars=exemplars,
    )


def load_groundtruth(path: Path | str) -> GroundTruth:
    """Read <demo>/groundtruth.json (or the demo folder itself) into typed dataclasses."""
    path = Path(path)
    if path.is_dir():
        path = path / "groundtruth.json"
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read ground truth ({exc})") from exc
    return parse_groundtruth(data, path.parent)


def exemplar_records(groundtruth: Any) -> dict[str, Any]:
    """stem -> exemplar record: the ``exemplars`` of a `GroundTruth`, or a plain mapping itself."""
    return dict(getattr(groundtruth, "exemplars", groundtruth))


def record_for_source(records: Mapping[str, Any], source_id: str) -> Any | None:
    """The record of the exemplar ingested as `source_id` (see `source_keys`), or None."""
    for key in source_keys(source_id):
        if key in records:
            return records[key]
    return None


def record_field(record: Any, *names: str, default: Any = None) -> Any:
    """The first of `names` that a record (mapping or object) holds with a value other than None."""
    for name in names:
        value = record.get(name) if isinstance(record, Mapping) else getattr(record, name, None)
        if value is not None:
            return value
    return default


def record_mask(record: Any, root: Path | None) -> np.ndarray:
    """A record's native-frame part mask: `ExemplarTruth.load_mask`, or its ``mask`` path (relative
    paths against `root`, the ground truth's folder)."""
    loader = getattr(record, "load_mask", None)
    if callable(loader):
        return np.asarray(loader())
    path = Path(record_field(record, "mask"))
    if root is not None and not path.is_absolute():
        path = root / path
    return read_part_mask(path)


def newest_groundtruth(data_root: Path | str) -> Path | None:
    """The most recently written <data_root>/demo/*/groundtruth.json (None when there is no demo)."""
    candidates = sorted(Path(data_root).joinpath("demo").glob("*/groundtruth.json"), key=lambda p: p.stat().st_mtime)
    return candidates[-1] if candidates else None
