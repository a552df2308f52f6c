"""One PhotoShape's downloads in one folder: GLB, glTF, Mitsuba XML, OBJ and the sidecar.

Layout of `out_dir` (every format optional but the sidecar)::

    assignment.json         parts, materials, UV transforms, licences (export.assignment)
    ATTRIBUTION.txt         the same licences, one line each
    photoshape.glb          self-contained binary glTF
    gltf/photoshape.gltf    JSON glTF + .bin + textures/
    mitsuba/scene.xml       Mitsuba 3 scene + meshes/*.ply + textures/*.exr
    obj/photoshape.obj      OBJ + MTL + textures/

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

from photoshape_flow.export.assignment import attribution_lines
from photoshape_flow.export.pbr import ResolveRef

FORMATS: tuple[str, ...] = ("glb", "gltf", "xml", "obj")
FORMAT_PATHS: dict[str, str] = {
    "glb": "photoshape.glb",
    "gltf": "gltf/photoshape.gltf",
    "xml": "mitsuba/scene.xml",
    "obj": "obj/photoshape.obj",
    "assignment": "assignment.json",
}


def parse_formats(spec: str | Iterable[str]) -> tuple[str, ...]:
    """'glb,xml' -> ('glb', 'xml'); a one-line error naming the valid formats otherwise."""
    items = [s.strip().lower() for s in (spec.split(",") if isinstance(spec, str) else spec) if s.strip()]
    unknown = [s for s in items if s not in FORMATS]
    if unknown:
        raise ValueError(f"unknown export format(s) {', '.join(unknown)}; valid: {', '.join(FORMATS)}")
    return tuple(dict.fromkeys(items))


def export_photoshape(
    out_dir: str | Path,
    shape: Any,
    materials: Sequence[Any] | None,
    uv_transforms: Sequence[Any] | None,
    document: Mapping[str, Any],
    *,
    formats: Iterable[str] = ("glb", "xml", "obj"),
    envmap: Any = None,
    camera: Any = None,
    resolve_ref: ResolveRef | None = None,
    size: int = 512,
    spp: int = 128,
    max_texture_size: int | None = 2048,
) -> dict[str, Path]:
    """Write the requested formats plus `assignment.json`; returns format -> main file path.

    `materials[i]` / `uv_transforms[i]` belong to `shape.parts[i]` (None = built-in / no jitter).
    The XML needs `camera` (the view it renders) and takes `envmap` (None: constant white light).
    `max_texture_size` limits the glTF/OBJ textures; the XML keeps the renderer's own limit.
    """
    formats = parse_formats(list(formats))
    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    lines = attribution_lines(document)
    meta = {"photoshape": json.loads(json.dumps(document, default=str)), "copyright": "; ".join(lines)}
    stage = Path(tempfile.mkdtemp(prefix=f".{out.name}-", dir=out.parent))
    stage.chmod(0o755)  # mkdtemp's 0700 would hide the export from a web server serving the gallery
    written: dict[str, Path] = {}
    try:
        for fmt in formats:
            target = stage / FORMAT_PATHS[fmt]
            if fmt == "glb":
                from photoshape_flow.export.gltf import write_glb

                write_glb(target, shape, materials, uv_transforms, metadata=meta, resolve_ref=resolve_ref,
                          max_texture_size=max_texture_size)
            elif fmt == "gltf":
                from photoshape_flow.export.gltf import write_gltf

                write_gltf(target, shape, materials, uv_transforms, metadata=meta, resolve_ref=resolve_ref,
                           max_texture_size=max_texture_size)
            elif fmt == "obj":
                from photoshape_flow.export.obj import write_obj

                write_obj(target, shape, materials, uv_transforms, resolve_ref=resolve_ref,
                          max_texture_size=max_texture_size, header=lines)
            elif fmt == "xml":
                from photoshape_flow.export.mitsuba_xml import write_mitsuba_xml

                if camera is None:
                    raise ValueError("the Mitsuba XML export needs a camera")
                # textures as the renderer loads them (its own size limit), so the scene renders the same
                write_mitsuba_xml(target, shape, materials, envmap, camera, uv_transforms=uv_transforms,
                                  size=size, spp=spp, resolve_ref=resolve_ref)
            written[fmt] = out / FORMAT_PATHS[fmt]
        (stage / FORMAT_PATHS["assignment"]).write_text(json.dumps(document, indent=2, sort_keys=True, default=str))
        (stage / "ATTRIBUTION.txt").write_text("\n".join(lines) + "\n")
        written["assignment"] = out / FORMAT_PATHS["assignment"]
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
