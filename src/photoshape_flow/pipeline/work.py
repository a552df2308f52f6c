"""Units of work of the stages that fan out, and the claimed processing of one unit.

Flows map a task over `plan_batches(...)`, and `photoshape run` loops over the same units in its own
process; both call `process(...)`, which claims the items in `work_claim` (so several workers or
Dask processes never do an item twice, and a killed worker's items are re-claimed at once on its
host, elsewhere once its lease expires), runs the stage on the items it won and marks them done.
An item's claim hash covers the stage config and, where the stage declares `versions`, the item's
own inputs, so one up-to-date check serves the CLI and the flows. Stage functions are idempotent on
their own: a claim is about not wasting work and not racing on the same rows, never about the
correctness of the stored results.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass, is_dataclass

from photoshape_flow.hashing import stable_hash


@dataclass(frozen=True)
class WorkUnit:
    """Items of one part of a stage (shapes, exemplars, pairs, or one inference method's pairs)."""

    part: str
    ids: tuple[int, ...]

    def only(self, ids: Iterable[int]) -> WorkUnit:
        """This unit with just those of its items that are in `ids` (a re-run of the affected items)."""
        wanted = set(ids)
        return WorkUnit(self.part, tuple(i for i in self.ids if i in wanted))

    def batches(self, size: int) -> list[WorkUnit]:
        size = max(size, 1)
        return [WorkUnit(self.part, self.ids[i : i + size]) for i in range(0, len(self.ids), size)]


def claim_hash(stage: str, part: str, config: object) -> str:
    """Claims are keyed by the stage's own config: a changed config re-opens its items."""
    payload = asdict(config) if is_dataclass(config) and not isinstance(config, type) else config
    return stable_hash({"stage": stage, "part": part, "config": payload})


def item_hash(base: str, version: str | None) -> str:
    """An item's claim hash: the stage's `claim_hash` plus its input version (None: the base alone)."""
    return base if version is None else stable_hash({"claim": base, "version": version})
