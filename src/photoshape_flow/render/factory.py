"""The one place a `Renderer` is built (issue 43): stages take theirs from the stage context or
their caller, and code that renders only when it must calls `default_renderer` at that moment
(Mitsuba's start-up is expensive); `tests/test_resources.py` holds every other module to that.
"""

from __future__ import annotations

from photoshape_flow.render.protocol import ResolvesRefs
from photoshape_flow.render.renderer import Renderer


def default_renderer(store: ResolvesRefs | None = None) -> Renderer:
    """A Mitsuba `Renderer` reading built-in textures from `store` (default: the process's blob store)."""
    return Renderer(resolve=store.resolve if store is not None else None)
