"""One PhotoShape's downloads in one folder: the chosen formats (`export.formats`) and the sidecar.

Layout of `out_dir` (every format optional but the sidecar)::

    assignment.json         parts, materials, UV transforms, licences (export.assignment)
    ATTRIBUTION.txt         the same licences, one line each
    <Exporter.path>         each chosen format's main file, the files it refers to beside it

Every file is written into a temporary sibling folder that replaces `out_dir` at the end, so a
reader never sees half an export and a crash leaves the previous export intact.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from photoshape_flow.export.formats import (
    DEFAULT_FORMATS,
    EXPORTERS,
    SIDECAR,
    SIDECAR_PATH,
    ExportInput,
    parse_formats,
)
from photoshape_flow.export.pbr import ResolveRef


def export_photoshape(
    out_dir: str | Path,
    shape: Any,
    materials: Sequence[Any] | None,
    uv_transforms: Sequence[Any] | None,
    document: Mapping[str, Any],
    *,
    formats: Iterable[str] = DEFAULT_FORMATS,
    envmap: Any = None,
    camera: Any = None,
    resolve_ref: ResolveRef | None = None,
    size: int = 512,
    spp: int = 128,
    max_texture_size: int | None = 2048,
    seed: int = 0,
) -> dict[str, Path]:
    """Write the requested formats plus `assignment.json`; returns format (or `SIDECAR`) -> main file path.

    The inputs are those of `export.formats.ExportInput`; each format's `Exporter` writes its part.
    """
    formats = parse_formats(list(formats))
    item = ExportInput(shape, materials, uv_transforms, document, envmap=envmap, camera=camera,
                       resolve_ref=resolve_ref, size=size, spp=spp, max_texture_size=max_texture_size,
                       seed=seed)
    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{out.name}-", dir=out.parent))
    stage.chmod(0o755)  # mkdtemp's 0700 would hide the export from a web server serving the gallery
    written: dict[str, Path] = {}
    try:
        for fmt in formats:
            exporter = EXPORTERS[fmt]
            exporter.write(stage / exporter.path, item)
            written[fmt] = out / exporter.path
        (stage / SIDECAR_PATH).write_text(json.dumps(document, indent=2, sort_keys=True, default=str))
        (stage / "ATTRIBUTION.txt").write_text("\n".join(item.attribution) + "\n")
        written[SIDECAR] = out / SIDECAR_PATH
        _replace_dir(stage, out)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    return written


def _replace_dir(stage: Path, out: Path) -> None:
    """Swap `stage` in as `out` (the old folder is moved aside first, then removed)."""
    old = None
    if out.exists():
        old = out.with_name(f".{out.name}-old-{stage.name[-8:]}")
        out.rename(old)
    stage.rename(out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
