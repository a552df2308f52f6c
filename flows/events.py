"""Prefect's side of the pipeline's events: `PrefectEvents` implements `photoshape_flow.events.EventSink`.

The CLI and the flows build their stage context with it, so a material ingested by either path
emits `photoshape.material.added`, which triggers the debounced `new-materials` deployment.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.events import MATERIAL_EVENT, MATERIAL_SET_RESOURCE
from photoshape_flow.ingest.common import one_line
from photoshape_flow.stages import StageContext

logger = logging.getLogger(__name__)


def _prefect_api_url() -> str | None:
    """The API URL Prefect itself is configured with (None when it would use an ephemeral server)."""
    try:
        from prefect.settings import PREFECT_API_URL

        return PREFECT_API_URL.value() or None
    except Exception:
        return None


def _send_event(api_url: str, event: str, resource: dict[str, str], payload: dict[str, Any],
                timeout_s: float = 15.0) -> None:
    """Deliver one event to the Prefect API at `api_url` and wait for it (bounded by `timeout_s`).

    Used when Prefect itself is not configured for that API (e.g. the CLI with only
    PHOTOSHAPE_PREFECT_API_URL set): `prefect.events.emit_event` would then start an ephemeral
    server instead. Runs in its own thread and event loop, so it works inside running loops too.
    """
    import asyncio
    import threading

    from prefect.events import Event
    from prefect.events.clients import PrefectEventsClient

    async def send() -> None:
        async with PrefectEventsClient(api_url=api_url, reconnection_attempts=1) as client:
            await client.emit(Event(event=event, resource=resource, payload=payload))

    errors: list[BaseException] = []

    def run() -> None:
        try:
            asyncio.run(asyncio.wait_for(send(), timeout_s))
        except BaseException as exc:  # reported to the caller below
            errors.append(exc)

    thread = threading.Thread(target=run, name="photoshape-event", daemon=True)
    thread.start()
    thread.join(timeout_s + 5.0)
    if thread.is_alive():
        raise TimeoutError(f"no answer from {api_url} within {timeout_s:g} s")
    if errors:
        raise errors[0]


class PrefectEvents:
    """Sends stage events to the Prefect API of the settings (nothing when none is configured)."""

    def __init__(self, settings: Settings):
        self.settings = settings

    def materials_added(self, material_ids: Sequence[int]) -> bool:
        """Emit one `photoshape.material.added` Prefect event for a committed batch of new materials.

        Only when a Prefect API is configured (`settings.effective_prefect_api_url`). When Prefect is
        configured for that same API (flows, deployments) the event goes through
        `prefect.events.emit_event`; otherwise it is sent directly to the configured URL. A failure is
        logged, never raised: ingest must not fail because the orchestrator is down. Returns whether
        the event was handed over.
        """
        api_url = self.settings.effective_prefect_api_url
        if not material_ids or not api_url:
            return False
        resource = {"prefect.resource.id": MATERIAL_SET_RESOURCE}
        payload = {"count": len(material_ids), "material_ids": list(material_ids)}
        try:
            if _prefect_api_url() == api_url:
                from prefect.events import emit_event

                if emit_event(event=MATERIAL_EVENT, resource=resource, payload=payload) is None:
                    raise RuntimeError("Prefect did not accept the event (events disabled?)")
            else:
                _send_event(api_url, MATERIAL_EVENT, resource, payload)
        except Exception as exc:  # events are best effort
            logger.warning("could not emit %s event to %s: %s", MATERIAL_EVENT, api_url, one_line(exc))
            return False
        logger.info("emitted %s (%d materials)", MATERIAL_EVENT, len(material_ids))
        return True


def stage_context(settings: Settings | None = None, progress: Any = None) -> Any:
    """The stage context of the CLI and of the flows: the settings, events sent to Prefect, and the
    caller's progress sink (the CLI's bars or lines, a flow's progress artifacts; none by default)."""
    settings = settings or get_settings()
    extra = {} if progress is None else {"progress": progress}
    return StageContext.create(settings, events=PrefectEvents(settings), **extra)
