"""One PhotoShape's downloads in one folder: the chosen formats (`export.formats`) and the sidecar.

Layout of `out_dir` (every format optional but the sidecar)::

    assignment.json         parts, materials, UV transforms, licences (export.assignment)
    ATTRIBUTION.txt         the same licences, one line each
    photoshape.glb          GLB (textures embedded: one file by definition)
    photoshape.gltf, .bin   glTF           } their texture images, each once, in textures/
    photoshape.obj, .mtl    OBJ            } named by content (<sha256 prefix>.png)
    textures/
    mitsuba/                scene.xml, meshes/*.ply, textures/*.exr (linear, content-named too)

Why one shared, content-addressed folder: the glTF and the OBJ convert the same materials to the
same PNGs (and a material on several parts, or equal constant maps, to the same bytes), so
per-format copies were over a third of an export's texture bytes. Both main files sit at the top,
so the references stay inside the folder (``textures/...``, no ``../``, which viewers and the glTF
validator refuse). The Mitsuba XML's EXRs hold other bytes than any PNG; it keeps its own folder.
`format_files` lists what one format needs, for a download of it alone.

Every file is written into a temporary sibling folder that replaces `out_dir` at the end, so a
reader never sees half an export and a crash leaves the previous export intact.
"""

from __future__ import annotations

import json
import re
import shutil
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from photoshape_flow.export.formats import DEFAULT_FORMATS, EXPORTERS, SIDECAR, SIDECAR_PATH, parse_formats
from photoshape_flow.export.pbr import ResolveRef
from photoshape_flow.export.writers import WRITERS, ExportInput
from photoshape_flow.faults import fault_point

# a relative file name with an extension the formats refer to (a number such as "0.5" is none)
FILE_REFERENCE = re.compile(r"[\w./-]+\.(?:bin|mtl|png|jpe?g|exr|ply|hdr|tga|tiff?)\b", re.IGNORECASE)


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

    The inputs are those of `export.writers.ExportInput`; each format's writer (`WRITERS`) writes its part.
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
            path = EXPORTERS[fmt].path
            WRITERS[fmt](stage / path, item)
            written[fmt] = out / path
            fault_point("export-writing")
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


def format_files(main: Path, fmt: str) -> list[tuple[Path, str]]:
    """(file, path inside a download) of everything format `fmt` needs, its main file being `main`.

    A single-file format is `main` alone; a format with its own folder is that folder. A format at
    the bundle's top (glTF, OBJ) is its main file and what it names, transitively (the .bin or .mtl,
    the shared textures). Download paths are ``<fmt>/`` + the path relative to the format's folder.
    """
    exporter = EXPORTERS.get(fmt)
    if fmt == SIDECAR or (exporter is not None and exporter.single_file):
        return [(main, main.name)] if main.is_file() else []
    base = main if main.is_dir() else main.parent
    if exporter is None or len(Path(exporter.path).parts) > 1:
        files = sorted(p for p in base.rglob("*") if p.is_file())
    else:
        files = _referenced(main, base)
    return [(p, f"{fmt}/{p.relative_to(base).as_posix()}") for p in files]


def _referenced(main: Path, base: Path) -> list[Path]:
    """`main` and the files under `base` that it names, and that those name (relative paths)."""
    found, todo = {main}, [main] if main.is_file() else []
    while todo:
        text = todo.pop().read_text(errors="replace")
        names = set(FILE_REFERENCE.findall(text))
        for name in names:
            path = base / name
            if ".." not in Path(name).parts and path.is_file() and path not in found:
                found.add(path)
                if path.suffix.lower() in (".mtl", ".gltf"):
                    todo.append(path)
    return sorted(found)
