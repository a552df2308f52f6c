"""Named fault-injection points: where the kill-9 harness makes a run die, one env var, read here only.

`PHOTOSHAPE_FAULT=<point>[:<n>]` makes this process SIGKILL itself the n-th time (default: the
first) it reaches `fault_point("<point>")`, right after appending the point's name to the file
`PHOTOSHAPE_FAULT_MARK` (when set), so the harness can assert the run died exactly there.
`PHOTOSHAPE_FAULT_SIGNAL=INT` sends SIGINT instead: Ctrl-C at that point (a KeyboardInterrupt the run
may clean up after). Without the variable (every real run) a point is one comparison. The points sit
where a kill is most likely to leave something half-done: between a blob and its row, between a
claim and its first result, after a checkpoint, in the middle of an export or a gallery.
"""

from __future__ import annotations

import contextlib
import os
import signal

POINTS: dict[str, str] = {
    "ingest-blob-before-row": "a shape's mesh blob is stored, its rows are not",
    "claimed-before-result": "a unit's items are claimed (committed), nothing of them is done",
    "rendering-blobs-before-row": "a rendering's passes are stored, its row is not committed",
    "substance-checkpoint-saved": "the substance network saved an epoch's checkpoint",
    "training-checkpoint-saved": "the material classifier saved an epoch's checkpoint",
    "inference-pair-done": "a pair's ranked materials are committed, the next pair's are not",
    "export-writing": "an export bundle is half-written in its staging folder",
    "gallery-writing": "the gallery's pages are half-written",
}


def _parse(value: str | None) -> tuple[str, int] | None:
    if not value:
        return None
    name, _, count = value.partition(":")
    if name not in POINTS:
        raise ValueError(f"PHOTOSHAPE_FAULT={value!r}: unknown point (choose from {', '.join(POINTS)})")
    return name, int(count or 1)


_WANTED = _parse(os.environ.get("PHOTOSHAPE_FAULT"))
_hits: dict[str, int] = {}


def fault_point(name: str) -> None:
    """Die here (SIGKILL, no cleanup) if the harness asked for this point and hit count."""
    if _WANTED is None or _WANTED[0] != name:
        return
    _hits[name] = _hits.get(name, 0) + 1
    if _hits[name] < _WANTED[1]:
        return
    mark = os.environ.get("PHOTOSHAPE_FAULT_MARK")
    if mark:
        with open(mark, "a") as out:
            out.write(name + "\n")
            out.flush()
            os.fsync(out.fileno())
    interrupt = os.environ.get("PHOTOSHAPE_FAULT_SIGNAL", "KILL").upper() == "INT"
    if interrupt:
        # a process started in the background by a non-interactive shell inherits SIGINT ignored, and
        # Python then never installs its Ctrl-C handler: restore it so the harness's Ctrl-C lands
        with contextlib.suppress(ValueError):  # not the main thread: the disposition stays as it is
            signal.signal(signal.SIGINT, signal.default_int_handler)
    os.kill(os.getpid(), signal.SIGINT if interrupt else signal.SIGKILL)
