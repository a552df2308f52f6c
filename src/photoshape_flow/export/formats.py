"""The export formats: `EXPORTERS`, the table of them by name (where each goes, what it holds).

Everything that names formats reads `EXPORTERS`: the download folder (`export.bundle`), the publish
stage and its defaults, `photoshape export` (its ``--format`` choices, default and validation) and
the gallery's download links. The writers stand apart, in `export.writers` (`WRITERS`, one function
per format, with numpy, PIL and the render specs behind them), so the CLI reads this table for its
``--help`` without loading them. Adding a format is one `ExportFormat` line here plus one writer
there. `assignment.json` is not a format: `export.bundle` writes it beside every export, under the
listing key `SIDECAR`.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

SIDECAR = "assignment"
SIDECAR_PATH = "assignment.json"
SHARED_TEXTURES = "textures"  # the glTF's and OBJ's texture files, beside them, named by content


@dataclass(frozen=True)
class ExportFormat:
    """One export format: its ``--format`` name, where it goes in an export folder, what it holds.

    The formats with texture files (glTF, OBJ) sit at the folder's top and write their textures
    into the one ``textures/`` folder there, named by content (`pbr.content_file_name`): identical
    textures are one file that both reference, without any ``../`` path (`export.bundle`).
    """

    name: str
    path: str  # the main file, relative to a PhotoShape's export folder
    description: str  # what a download of it holds, for people
    single_file: bool = False  # the main file is the whole format (else its folder is)
    default: bool = True  # written when no formats are chosen


# in the order help texts and the gallery list them
EXPORTERS: dict[str, ExportFormat] = {fmt.name: fmt for fmt in (
    ExportFormat("glb", "photoshape.glb", "glTF binary", single_file=True),
    ExportFormat("gltf", "photoshape.gltf", "glTF + textures", default=False),  # the GLB holds the same, in one file
    ExportFormat("xml", "mitsuba/scene.xml", "Mitsuba 3 scene"),
    ExportFormat("obj", "photoshape.obj", "OBJ + MTL + textures"),
)}
DEFAULT_FORMATS: tuple[str, ...] = tuple(name for name, fmt in EXPORTERS.items() if fmt.default)


def parse_formats(spec: str | Iterable[str]) -> tuple[str, ...]:
    """'glb,xml' -> ('glb', 'xml'); a one-line error naming the valid formats otherwise."""
    items = [s.strip().lower() for s in (spec.split(",") if isinstance(spec, str) else spec) if s.strip()]
    unknown = [s for s in items if s not in EXPORTERS]
    if unknown:
        raise ValueError(f"unknown export format(s) {', '.join(unknown)}; valid: {', '.join(EXPORTERS)}")
    return tuple(dict.fromkeys(items))
