"""How the CLI shows the stages' progress (`progress_sink.Progress`): rich bars or plain lines.

In a terminal each long loop gets a rich bar with its count, elapsed time and ETA. When stdout is
not a terminal (a log file, CI, a pipe) bars would be noise, so each loop prints a plain line at
its start, after its first item, at each tenth (at most one a second), at least every
`every_seconds` seconds while items finish, and at its end:
`publish pairs: 12/40 (30%), 0.8/s, ETA 0:35`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from photoshape_flow.progress_sink import Progress as ProgressSink
from photoshape_flow.progress_sink import progress_line


@dataclass
class _Loop:
    started: float
    printed_at: float
    printed_done: int


class PlainProgress:
    """The non-terminal sink: per loop a line at its start, after its first item (the first ETA),
    each time it crosses a tenth (`every_items` items if set) but at most one per `min_seconds`,
    at least one per `every_seconds` while items finish, and at its end. The clock is injectable."""

    def __init__(self, write: Callable[[str], None], every_items: int = 0, every_seconds: float = 10.0,
                 min_seconds: float = 1.0, clock: Callable[[], float] = time.monotonic):
        self.write, self.every_items, self.clock = write, every_items, clock
        self.every_seconds, self.min_seconds = every_seconds, min_seconds
        self.loops: dict[str, _Loop] = {}

    def __call__(self, task: str, done: int, total: int) -> None:
        now = self.clock()
        loop = self.loops.get(task)
        if loop is None or done < loop.printed_done:  # a new loop (or the same task run again)
            self.loops[task] = _Loop(now, now, done)
            if total or done:  # an empty loop says nothing
                self.write(progress_line(task, done, total, 0.0))
            return
        if done == loop.printed_done:
            return  # nothing new (a repeated report, or the end printed already)
        step = self.every_items or max(total // 10, 1)
        since = now - loop.printed_at
        due = (
            (total > 0 and done >= total)
            or loop.printed_done == 0
            or (done // step > loop.printed_done // step and since >= self.min_seconds)
            or since >= self.every_seconds
        )
        if due:
            loop.printed_at, loop.printed_done = now, done
            self.write(progress_line(task, done, total, now - loop.started))


class RichProgress:
    """The terminal sink: one rich bar per loop (count, elapsed, ETA), removed when the block ends."""

    def __init__(self, bar: Progress):
        self.bar = bar
        self.tasks: dict[str, object] = {}

    def __call__(self, task: str, done: int, total: int) -> None:
        if task not in self.tasks:
            self.tasks[task] = self.bar.add_task(task, total=total or None)
        self.bar.update(self.tasks[task], completed=done, total=total or None)  # type: ignore[arg-type]


@contextmanager
def cli_progress(console: Console) -> Iterator[ProgressSink]:
    """The sink the CLI hands to stages: rich bars on a terminal, plain lines otherwise."""
    if not console.is_terminal:
        yield PlainProgress(lambda line: console.print(line, highlight=False, soft_wrap=True))
        return
    bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                   TextColumn("ETA"), TimeRemainingColumn(), console=console, transient=True)
    with bar:
        yield RichProgress(bar)
