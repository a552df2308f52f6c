"""The events a pipeline stage announces, behind a small interface the orchestration layer implements.

Pipeline code never imports Prefect: a stage calls `ctx.events.materials_added(ids)` and whoever built
the context decides where that goes (`flows/events.py` sends a Prefect event that triggers the
`new-materials` deployment; tests record the calls; `NO_EVENTS` drops them).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

MATERIAL_EVENT = "photoshape.material.added"
MATERIAL_SET_RESOURCE = "photoshape.material-set"


class EventSink(Protocol):
    """Receives what a stage committed that other work may react to."""

    def materials_added(self, material_ids: Sequence[int]) -> bool:
        """A committed batch of new materials; returns whether the event was handed over."""
        ...


class NoEvents:
    """Drops every event (runs with no orchestrator to tell)."""

    def materials_added(self, material_ids: Sequence[int]) -> bool:
        return False


NO_EVENTS = NoEvents()
