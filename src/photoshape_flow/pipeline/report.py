"""What every stage returns: one dataclass the CLI tables, the Prefect artifacts and the claims read."""

from __future__ import annotations

import datetime as dt
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol


@dataclass(frozen=True)
class Blocked:
    """Items left pending because another live worker holds them."""

    count: int = 0
    holders: tuple[str, ...] = ()
    until: dt.datetime | None = None


class _Hold(Protocol):  # db.claims.Hold, without importing the database layer here
    count: int
    until: dt.datetime | None

    def describe(self) -> str: ...


def blocked_by(holds: list[Any]) -> Blocked:
    """The `Blocked` of live claims another worker holds (`db.claims.live_holds`)."""
    typed: list[_Hold] = holds
    if not typed:
        return Blocked()
    return Blocked(sum(h.count for h in typed), tuple(dict.fromkeys(h.describe() for h in typed)),
                   max((h.until for h in typed if h.until is not None), default=None))


@dataclass
class StageReport:
    """Counts of one stage run (or one batch of it), its wall time, and stage-specific details.

    done: items computed now; skipped: already up to date; failed: crashed (recorded, retried next
    run); rejected: bad input (recorded, not retried until it changes); blocked: held elsewhere.
    """

    stage: str
    done: int = 0
    skipped: int = 0
    failed: int = 0
    rejected: int = 0
    blocked: Blocked = field(default_factory=Blocked)
    seconds: float = 0.0
    details: dict[str, Any] = field(default_factory=dict)

    def merge(self, other: StageReport) -> StageReport:
        """The sum of two reports of the same stage (batches of one run); details by `merge_details`."""
        until = max((u for u in (self.blocked.until, other.blocked.until) if u is not None), default=None)
        return StageReport(
            stage=self.stage,
            done=self.done + other.done,
            skipped=self.skipped + other.skipped,
            failed=self.failed + other.failed,
            rejected=self.rejected + other.rejected,
            blocked=Blocked(self.blocked.count + other.blocked.count,
                            tuple(dict.fromkeys(self.blocked.holders + other.blocked.holders)), until),
            seconds=self.seconds + other.seconds,
            details=merge_details(self.details, other.details),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly (Prefect task results, the `pipeline_run` row)."""
        return _plain(asdict(self))


SETTINGS = frozenset({"weights"})  # details that say how a batch ran (fit's cost weights), not what it did


def merge_details(a: dict[str, Any], b: dict[str, Any], key: str = "") -> dict[str, Any]:
    """Two batches' details as one run's: counts (ints) add, wall times (a ``seconds`` or ``*_seconds``
    number, or the numbers of a ``seconds`` dict) add, lists join, dicts merge key by key; anything else
    (a flag, a ratio, a `SETTINGS` dict such as the weights a batch used) is the later batch's. A run
    fanned out in batches then reports its totals, not its last batch's."""
    out = dict(a)
    for name, value in b.items():
        if name not in out or name in SETTINGS:
            out[name] = value
            continue
        mine = out[name]
        if isinstance(mine, dict) and isinstance(value, dict):
            out[name] = merge_details(mine, value, name)
        elif isinstance(mine, list) and isinstance(value, list):
            out[name] = mine + value
        elif _count(mine) and _count(value) and (_is_time(key, name) or _is_int(mine) and _is_int(value)):
            out[name] = mine + value
        else:
            out[name] = value
    return out


def _is_time(parent: str, name: str) -> bool:
    return parent == "seconds" or name == "seconds" or name.endswith("_seconds")


def _count(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _plain(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, dt.datetime):
        return obj.isoformat()
    if hasattr(obj, "__dataclass_fields__"):
        return _plain(asdict(obj))
    return obj
