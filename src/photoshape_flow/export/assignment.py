"""The `assignment.json` sidecar: which material went on which part, and every licence involved.

Users re-bind materials in their own tools from it (part -> material id/name, substance, score, the
UV transform), and filter or credit by licence: the shape's, the exemplar's, every material's and
the envmap's, as recorded at ingest (`license`, `attribution`, `source_url`). A missing licence is
written as null and counted in ``unknown_licenses`` rather than guessed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from photoshape_flow.export.text import one_line
from photoshape_flow.render.specs import UVTransform, uv_matrix

FORMAT = "photoshape_flow.assignment/1"


@dataclass
class Provenance:
    """Where an item came from and under which terms (the ProvenanceMixin columns)."""

    role: str  # shape | exemplar | material | envmap
    id: int | None
    name: str | None
    source: str | None = None
    license: str | None = None
    attribution: str | None = None
    source_url: str | None = None


@dataclass
class PartAssignment:
    """The material chosen for one part (rank 1 of a method), with its UV transform."""

    part_index: int
    part_name: str
    material_id: int | None
    material_name: str | None
    substance: str | None = None
    score: float | None = None
    unobserved: bool = False
    uv_density: float = 1.0
    material_scale: float | None = None
    uv_transform: Mapping[str, Any] | None = None  # {"scale", "rotation", "offset"}
    extra: dict[str, Any] = field(default_factory=dict)


def assignment_document(
    *,
    pair_id: int | None,
    method_key: str,
    shape: Provenance,
    exemplar: Provenance | None,
    parts: Sequence[PartAssignment],
    materials: Sequence[Provenance],
    envmap: Provenance | None = None,
    camera: Mapping[str, float] | None = None,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The sidecar as a JSON-ready dict (see the module docstring)."""
    part_rows = []
    for p in parts:
        jitter = None
        if p.uv_transform:
            t = p.uv_transform
            jitter = UVTransform(float(t.get("scale", 1.0)), float(t.get("rotation", 0.0)),
                                 tuple(float(x) for x in t.get("offset", (0.0, 0.0))))  # type: ignore[arg-type]
        matrix = uv_matrix(p.uv_density, p.material_scale, jitter)
        part_rows.append({
            "index": p.part_index,
            "name": p.part_name,
            "material": None if p.material_id is None and p.material_name is None
            else {"id": p.material_id, "name": p.material_name},
            "builtin": p.material_id is None,
            "substance": p.substance,
            "score": p.score,
            "unobserved": p.unobserved,
            "uv": {
                "density": p.uv_density,
                "material_scale": p.material_scale,
                "transform": jitter.to_dict() if jitter else None,
                "matrix": [[round(float(x), 9) for x in row] for row in matrix.tolist()],
                "note": "exported texcoords = matrix @ [u, v, 1] of the source UVs (OBJ convention, v up)",
            },
            **({"extra": p.extra} if p.extra else {}),
        })
    licences = [shape, *([exemplar] if exemplar else []), *_unique(materials), *([envmap] if envmap else [])]
    return {
        "format": FORMAT,
        "pair_id": pair_id,
        "method_key": method_key,
        "shape": asdict(shape),
        "exemplar": asdict(exemplar) if exemplar else None,
        "envmap": asdict(envmap) if envmap else None,
        "camera": dict(camera) if camera else None,
        "parts": part_rows,
        "licenses": [asdict(p) for p in licences],
        "license_summary": sorted({p.license for p in licences if p.license}),
        "unknown_licenses": sum(1 for p in licences if not p.license),
        **(dict(extra) if extra else {}),
    }


def _unique(items: Sequence[Provenance]) -> list[Provenance]:
    seen: set[tuple[str, int | None, str | None]] = set()
    out = []
    for item in items:
        key = (item.role, item.id, item.name)
        if key not in seen:
            seen.add(key)
            out.append(item)
    return out


def attribution_lines(document: Mapping[str, Any]) -> list[str]:
    """One human-readable line per licensed item (for glTF ``copyright``, OBJ/MTL headers, ATTRIBUTION.txt).

    Each is one line however the recorded text reads (`export.text.one_line`): a newline in an
    attribution must not become a line of its own in a line-based format.
    """
    lines = []
    for item in document.get("licenses", []):
        text = f"{item['role']} {item.get('name') or item.get('id')}: {item.get('license') or 'licence unknown'}"
        if item.get("attribution"):
            text += f", {item['attribution']}"
        if item.get("source_url"):
            text += f" <{item['source_url']}>"
        lines.append(one_line(text))
    return lines
