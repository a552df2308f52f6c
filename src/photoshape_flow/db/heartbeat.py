"""A heartbeat that renews this process's claim leases while it works, so a short lease is safe.

Leases exist so that a dead worker's items come back; they must not expire under a live worker
whose batch takes longer than the lease. `Heartbeat` is a context manager around a batch: a daemon
thread renews every claim this process holds every `lease / 3` seconds and stops when the block
ends (a killed process stops renewing, so its leases still run out). A failed renewal is logged
and retried on the next beat: it never stops the batch.
"""

from __future__ import annotations

import logging
import threading
from types import TracebackType

from photoshape_flow.db import claims
from photoshape_flow.db.session import session_scope

log = logging.getLogger(__name__)


class Heartbeat:
    """Renew this process's claims every `lease_seconds / 3` while the `with` block runs."""

    def __init__(self, database_url: str, lease_seconds: float) -> None:
        self.database_url = database_url
        self.lease_seconds = lease_seconds
        self.interval = max(lease_seconds / 3, 0.05)
        self.beats = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._worker = claims.worker_id()

    def __enter__(self) -> Heartbeat:
        self._thread = threading.Thread(target=self._run, name="photoshape-claim-heartbeat", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=30)

    def beat(self) -> int:
        """One renewal now; returns how many claims were renewed."""
        with session_scope(self.database_url) as session:
            renewed = claims.renew(session, self.lease_seconds, worker=self._worker)
        self.beats += 1
        return renewed

    def _run(self) -> None:
        while not self._stop.wait(self.interval):
            try:
                self.beat()
            except Exception as exc:  # the database is briefly away: the next beat tries again
                log.warning("claim heartbeat failed (%s); retrying in %.0f s", exc, self.interval)
