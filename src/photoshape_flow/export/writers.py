"""The export writers: one function per format of `export.formats.EXPORTERS`, and what they take.

`export.bundle` calls `WRITERS[name](target, item)` with the format's main file as `target`; the
table of names, paths and descriptions (`export.formats`) loads none of this.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

from photoshape_flow.export.assignment import attribution_lines
from photoshape_flow.export.formats import SHARED_TEXTURES
from photoshape_flow.export.gltf import write_glb, write_gltf
from photoshape_flow.export.mitsuba_xml import write_mitsuba_xml
from photoshape_flow.export.obj import write_obj
from photoshape_flow.export.pbr import ResolveRef


@dataclass(frozen=True)
class ExportInput:
    """One PhotoShape as the writers take it.

    `materials[i]` / `uv_transforms[i]` belong to `shape.parts[i]` (None = built-in / no jitter).
    `camera` is the view a scene format renders, `envmap` its light (None: constant white), `size`,
    `spp` and `seed` its film and sampler (those of the render it accompanies, so it renders the same
    image); `max_texture_size` limits the textures of the interchange formats.
    """

    shape: Any
    materials: Sequence[Any] | None
    uv_transforms: Sequence[Any] | None
    document: Mapping[str, Any]  # assignment.json
    envmap: Any = None
    camera: Any = None
    resolve_ref: ResolveRef | None = None
    size: int = 512
    spp: int = 128
    max_texture_size: int | None = 2048
    seed: int = 0

    @cached_property
    def attribution(self) -> list[str]:
        """The licences, one line each (`export.assignment.attribution_lines`)."""
        return attribution_lines(self.document)

    @cached_property
    def metadata(self) -> dict[str, Any]:
        """The assignment and its licences as a format's own metadata (glTF ``asset.extras``)."""
        return {"photoshape": json.loads(json.dumps(self.document, default=str)),
                "copyright": "; ".join(self.attribution)}


def _gltf_options(item: ExportInput) -> dict[str, Any]:
    return {"metadata": item.metadata, "resolve_ref": item.resolve_ref, "max_texture_size": item.max_texture_size}


def write_gltf_format(target: Path, item: ExportInput) -> None:
    write_gltf(target, item.shape, item.materials, item.uv_transforms, **_gltf_options(item),
               texture_dir=SHARED_TEXTURES, content_names=True)


def write_glb_format(target: Path, item: ExportInput) -> None:
    """One file: its textures are embedded."""
    write_glb(target, item.shape, item.materials, item.uv_transforms, **_gltf_options(item))


def write_xml_format(target: Path, item: ExportInput) -> None:
    if item.camera is None:
        raise ValueError("the Mitsuba XML export needs a camera")
    # textures as the renderer loads them (its own size limit), so the scene renders the same
    write_mitsuba_xml(target, item.shape, item.materials, item.envmap, item.camera,
                      uv_transforms=item.uv_transforms, size=item.size, spp=item.spp, seed=item.seed,
                      resolve_ref=item.resolve_ref)


def write_obj_format(target: Path, item: ExportInput) -> None:
    write_obj(target, item.shape, item.materials, item.uv_transforms, resolve_ref=item.resolve_ref,
              max_texture_size=item.max_texture_size, header=item.attribution, texture_dir=SHARED_TEXTURES,
              content_names=True)


# one per name of `EXPORTERS` (tests/export/test_formats.py holds the two tables to the same names)
WRITERS: dict[str, Callable[[Path, ExportInput], None]] = {
    "glb": write_glb_format,
    "gltf": write_gltf_format,
    "xml": write_xml_format,
    "obj": write_obj_format,
}
