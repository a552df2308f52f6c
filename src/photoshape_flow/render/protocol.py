"""What the pipeline needs of a renderer, as a `typing.Protocol` (issue 43): the seam to Mitsuba.

`render.renderer.Renderer` is the implementation (built by `render.factory.default_renderer`);
tests and experiments pass fakes that render a few arrays. Importing this module loads neither
Mitsuba nor numpy.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol

if TYPE_CHECKING:
    import numpy as np

    from photoshape_flow.render.camera import Camera
    from photoshape_flow.render.renderer import BeautyResult, SweepResult
    from photoshape_flow.render.specs import EnvmapSpec, MaterialSpec, UVTransform


class RendererProtocol(Protocol):
    """Beauty renders, exact part-ID maps and viewpoint sweeps of a shape (see `Renderer`)."""

    def beauty(
        self,
        shape: Any,
        materials: Sequence[MaterialSpec | None] | None,
        camera: Camera,
        envmap: EnvmapSpec | None,
        *,
        size: int = ...,
        spp: int = ...,
        uv_transforms: Sequence[UVTransform | None] | None = ...,
        background: Literal["white", "transparent"] = ...,
        floor: bool = ...,
        seed: int = ...,
        record: bool = ...,
    ) -> BeautyResult: ...

    def part_ids(self, shape: Any, camera: Camera, size: int = ...) -> np.ndarray: ...

    def sweep(self, shape: Any, cameras: Sequence[Camera], size: int = ..., shaded: bool = ...) -> SweepResult: ...


class ResolvesRefs(Protocol):
    """A blob store as a renderer sees it: a blob ref to a local file."""

    def resolve(self, ref: str) -> Path: ...
