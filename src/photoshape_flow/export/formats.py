"""The export formats: one `Exporter` class per format, and `EXPORTERS`, the registry of them.

Everything that names formats reads `EXPORTERS`: the download folder (`export.bundle`), the publish
stage and its defaults, `photoshape export` (its ``--format`` choices, default and validation) and
the gallery's download links. Adding a format is one `Exporter` subclass here plus one line in
`EXPORTERS`.

This module imports no writer (nor numpy) until a format is written, so the CLI reads the registry
for its ``--help`` without slowing it down. `assignment.json` is not a format: `export.bundle`
writes it beside every export, under the listing key `SIDECAR`.
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

if TYPE_CHECKING:
    from photoshape_flow.export.pbr import ResolveRef

SIDECAR = "assignment"
SIDECAR_PATH = "assignment.json"
SHARED_TEXTURES = "textures"  # the glTF's and OBJ's texture files, beside them, named by content


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
        from photoshape_flow.export.assignment import attribution_lines

        return attribution_lines(self.document)

    @cached_property
    def metadata(self) -> dict[str, Any]:
        """The assignment and its licences as a format's own metadata (glTF ``asset.extras``)."""
        return {"photoshape": json.loads(json.dumps(self.document, default=str)),
                "copyright": "; ".join(self.attribution)}


class Exporter(ABC):
    """One export format: its ``--format`` name, where it goes in an export folder, how to write it.

    The formats with texture files (glTF, OBJ) sit at the folder's top and write their textures
    into the one ``textures/`` folder there, named by content (`pbr.content_file_name`): identical
    textures are one file that both reference, without any ``../`` path (`export.bundle`).
    """

    name: ClassVar[str]
    path: ClassVar[str]  # the main file, relative to a PhotoShape's export folder
    description: ClassVar[str]  # what a download of it holds, for people
    single_file: ClassVar[bool] = False  # the main file is the whole format (else its folder is)
    default: ClassVar[bool] = True  # written when no formats are chosen

    @abstractmethod
    def write(self, target: Path, item: ExportInput) -> None:
        """Write `item` with its main file at `target` (other files beside it)."""


class GltfExporter(Exporter):
    name = "gltf"
    path = "photoshape.gltf"
    description = "glTF + textures"
    default = False  # the GLB holds the same, in one file
    binary: ClassVar[bool] = False  # one .glb file instead of .gltf + .bin + textures

    def write(self, target: Path, item: ExportInput) -> None:
        from photoshape_flow.export.gltf import write_glb, write_gltf

        common = {"metadata": item.metadata, "resolve_ref": item.resolve_ref, "max_texture_size": item.max_texture_size}
        if self.binary:  # one file: its textures are embedded
            write_glb(target, item.shape, item.materials, item.uv_transforms, **common)
        else:
            write_gltf(target, item.shape, item.materials, item.uv_transforms, **common, texture_dir=SHARED_TEXTURES,
                       content_names=True)


class GlbExporter(GltfExporter):
    name = "glb"
    path = "photoshape.glb"
    description = "glTF binary"
    single_file = True
    default = True
    binary = True


class MitsubaXmlExporter(Exporter):
    name = "xml"
    path = "mitsuba/scene.xml"
    description = "Mitsuba 3 scene"

    def write(self, target: Path, item: ExportInput) -> None:
        from photoshape_flow.export.mitsuba_xml import write_mitsuba_xml

        if item.camera is None:
            raise ValueError("the Mitsuba XML export needs a camera")
        # textures as the renderer loads them (its own size limit), so the scene renders the same
        write_mitsuba_xml(target, item.shape, item.materials, item.envmap, item.camera,
                          uv_transforms=item.uv_transforms, size=item.size, spp=item.spp, seed=item.seed,
                          resolve_ref=item.resolve_ref)


class ObjExporter(Exporter):
    name = "obj"
    path = "photoshape.obj"
    description = "OBJ + MTL + textures"

    def write(self, target: Path, item: ExportInput) -> None:
        from photoshape_flow.export.obj import write_obj

        write_obj(target, item.shape, item.materials, item.uv_transforms, resolve_ref=item.resolve_ref,
                  max_texture_size=item.max_texture_size, header=item.attribution, texture_dir=SHARED_TEXTURES,
                  content_names=True)


# in the order help texts and the gallery list them
EXPORTERS: dict[str, Exporter] = {exporter.name: exporter for exporter in (
    GlbExporter(),
    GltfExporter(),
    MitsubaXmlExporter(),
    ObjExporter(),
)}
DEFAULT_FORMATS: tuple[str, ...] = tuple(name for name, exporter in EXPORTERS.items() if exporter.default)


def parse_formats(spec: str | Iterable[str]) -> tuple[str, ...]:
    """'glb,xml' -> ('glb', 'xml'); a one-line error naming the valid formats otherwise."""
    items = [s.strip().lower() for s in (spec.split(",") if isinstance(spec, str) else spec) if s.strip()]
    unknown = [s for s in items if s not in EXPORTERS]
    if unknown:
        raise ValueError(f"unknown export format(s) {', '.join(unknown)}; valid: {', '.join(EXPORTERS)}")
    return tuple(dict.fromkeys(items))
