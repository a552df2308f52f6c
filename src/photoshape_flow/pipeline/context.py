"""What a stage needs from its caller, in one object: settings, store, renderer, sessions, device, sinks.

The CLI and the flows each build one (`StageContext.create`) with their own progress and event
sinks, so a stage never asks where it runs: the CLI shows progress bars and sends events to the
configured Prefect API, a flow updates progress artifacts, a test records what was reported.
"""

from __future__ import annotations

from contextlib import AbstractContextManager
from dataclasses import dataclass
from functools import cached_property
from typing import Any

from sqlalchemy.orm import Session

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db.session import session_scope
from photoshape_flow.events import NO_EVENTS, EventSink
from photoshape_flow.progress_sink import Progress, no_progress
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.store import BlobStore, default_store

# progress(task, items done, items in all): the one interface long loops report to (progress_sink.py)
ProgressSink = Progress


@dataclass(frozen=True)
class StageContext:
    """Everything a stage reads besides its config; immutable, cheap to build, safe to share."""

    settings: Settings
    progress: ProgressSink = no_progress
    events: EventSink = NO_EVENTS
    # None: the stage's pipeline function builds one with `render.factory.default_renderer` when it
    # first renders (Mitsuba's start-up is expensive; most stages never render); tests inject a fake
    renderer: RendererProtocol | None = None

    @classmethod
    def create(cls, settings: Settings | None = None, **kwargs: Any) -> StageContext:
        return cls(settings=settings or get_settings(), **kwargs)

    @cached_property
    def store(self) -> BlobStore:
        return default_store(self.settings)

    @property
    def database_url(self) -> str:
        return self.settings.resolved_database_url

    def session(self) -> AbstractContextManager[Session]:
        """A transaction: committed when the block ends, rolled back on an exception."""
        return session_scope(self.database_url)

    @property
    def device(self) -> str:
        """The configured torch device name ("auto", "cpu", "cuda"); trainers resolve it."""
        return self.settings.device
