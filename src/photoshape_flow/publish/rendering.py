"""One publish render: path traced on a white background and recorded as a `Rendering` row.

Shared by the PhotoShape renders (`publish.publish`) and the built-in-material renders of every
candidate (`publish.builtin_renders`), so both record a failure the same way: a ``failed`` row with
the one-line reason, counted, and the batch goes on.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from photoshape_flow.db.session import session_scope
from photoshape_flow.pipeline.renderings import record_rendering
from photoshape_flow.render.factory import default_renderer
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import STATUS_FAILED


@dataclass
class RenderCounts:
    """What a batch of publish renders did (a `PublishSummary` carries the same fields)."""

    rendered: int = 0
    skipped: int = 0
    failed: int = 0
    render_seconds: float = 0.0
    errors: list[str] = field(default_factory=list)


class LazyRenderer:
    """The renderer, built on first use: a batch whose renders are all up to date starts no Mitsuba."""

    def __init__(self, store: BlobStore, renderer: RendererProtocol | None = None) -> None:
        self._store, self._renderer = store, renderer

    def __call__(self) -> RendererProtocol:
        if self._renderer is None:
            self._renderer = default_renderer(self._store)
        return self._renderer


def render_and_record(url: str, store: BlobStore, renderer: Callable[[], RendererProtocol], counts: Any,
                      fail: Callable[[str], None], *, mesh: Any, materials: Sequence[Any], camera: Any,
                      envmap: Any, jitters: Sequence[Any] | None, size: int, spp: int, floor: bool, seed: int,
                      row: dict[str, Any]) -> None:
    """Render one view and upsert its row (`row`: kind, key, params, ids, params_hash); a failure is a
    ``failed`` row and one `fail` line. `counts` is a `RenderCounts` or a `PublishSummary`."""
    started = time.perf_counter()
    try:
        result = renderer().beauty(mesh, list(materials), camera, envmap, size=size, spp=spp,
                                   uv_transforms=jitters, background="white", floor=floor, seed=seed)
    except Exception as exc:
        counts.failed += 1
        message = f"{row['kind']} {row['key']}: {type(exc).__name__}: {exc}"
        fail(message)
        with session_scope(url) as session:
            record_rendering(session, store, images={}, status=STATUS_FAILED, error=message[:2000], **row)
        return
    seconds = time.perf_counter() - started
    counts.render_seconds += seconds
    alpha = (result.alpha.clip(0.0, 1.0) * 255.0 + 0.5).astype("uint8")
    with session_scope(url) as session:
        record_rendering(session, store, images={"srgb": result.srgb, "alpha": alpha}, seconds=seconds,
                         saturated_fraction=result.saturated_fraction, **row)
    counts.rendered += 1
