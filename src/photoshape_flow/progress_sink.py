"""The one progress interface of long loops: `progress(task, done, total)`.

Pipeline loops (publish's pairs, training renders' items, alignment's pairs and sweeps, inference's
pairs, training epochs) report through a callable of this shape, handed down from the stage
context. They never know who listens: the CLI draws rich bars in a terminal and plain count/rate/ETA
lines otherwise (`cli/progress.py`), a flow updates Prefect progress artifacts
(`flows/artifacts.py`), a test records the calls. `task` names the loop ("publish pairs"), `done`
counts finished items (0 announces the loop, so its clock starts), `total` is the loop's size.

The stage runner names what a loop works on: `labelled` puts the stage in front of a task that does
not start with it (`substances: bootstrap renders`), `nested` the batch of a stage that runs in
batches (`training-renders batch 3/20: training renders`); a sink with a `nested(label)` method (the
CLI's) is told such loops are inside another, so it can keep them quiet.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sized
from typing import TypeVar

T = TypeVar("T")

Progress = Callable[[str, int, int], None]
"""progress(task, done, total): called with done=0 before a loop and after each of its items."""


def no_progress(task: str, done: int, total: int) -> None:
    """The sink of runs nobody watches."""


def labelled(progress: Progress, stage: str) -> Progress:
    """`progress` with `stage` in front of every task that does not already start with it."""
    def report(task: str, done: int, total: int) -> None:
        progress(task if task.startswith(stage) else f"{stage}: {task}", done, total)

    return report


def nested(progress: Progress, label: str) -> Progress:
    """The sink of loops inside `label` (one batch of a stage): the sink's own `nested(label)` where it
    has one, else `progress` with `label: ` in front of every task."""
    inner = getattr(progress, "nested", None)
    if callable(inner):
        return inner(label)  # type: ignore[no-any-return]
    return lambda task, done, total: progress(f"{label}: {task}", done, total)


def counted(progress: Progress | None, task: str, items: Iterable[T], total: int | None = None) -> Iterator[T]:
    """Yield `items`, reporting (task, 0, total) first and (task, n, total) after the n-th item's body.

    The report after an item happens when the loop asks for the next one, so a `continue` in the body
    counts too; `total` defaults to len(items).
    """
    if progress is None:
        yield from items
        return
    size = total if total is not None else (len(items) if isinstance(items, Sized) else 0)
    progress(task, 0, size)
    for done, item in enumerate(items, start=1):
        yield item
        progress(task, done, size)


def clock_text(seconds: float) -> str:
    """H:MM:SS or M:SS, the way rich shows times."""
    whole = max(int(round(seconds)), 0)
    hours, rest = divmod(whole, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def progress_line(task: str, done: int, total: int, elapsed: float) -> str:
    """One plain progress line: count, share, rate and ETA (rate and ETA once an item is done)."""
    parts = [f"{task}: {done}/{total}" if total else f"{task}: {done}"]
    if total:
        parts[0] += f" ({100 * done // max(total, 1)}%)"
    if done and elapsed > 0:
        rate = done / elapsed
        parts.append(f"{rate:.2f}/s" if rate < 10 else f"{rate:.0f}/s")
        if total and done < total:
            parts.append(f"ETA {clock_text((total - done) / rate)}")
        elif total:
            parts.append(f"took {clock_text(elapsed)}")
    return ", ".join(parts)
