"""How the CLI shows the stages' progress (`progress_sink.Progress`): rich bars or plain lines.

Each loop gets one line that says what it works on: `training-renders batch 3/20: training renders`
(the stage runner names the stage and the batch, `progress_sink.nested`). In a terminal that line is
a rich bar (count, elapsed, ETA) updated in place; a loop inside a batch disappears when it ends. When
stdout is not a terminal (a log file, CI, a pipe) bars would be noise, so the sink prints plain lines,
at most one every `every_seconds` while loops run and one at the end of each loop (a loop nested in
a batch prints its end only when it ran long enough to have printed before):
`publish pairs: 40/40 (100%), 0.8/s, took 0:50`.
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

LOG_EVERY_SECONDS = 10.0  # off a terminal: at most one running line this often (ends always print)


@dataclass
class _Loop:
    started: float
    done: int
    nested: bool
    printed: bool = False  # a running line was printed for it


class PlainProgress:
    """The non-terminal sink: one line at the end of each loop, and while loops run at most one line
    per `every_seconds` in all (for the loop that reported; none before it ran `every_seconds`). A
    nested loop (`nested(label)`: one batch of a stage) prints its end only when it printed while
    running, so a stage of many quick batches prints its batch loop, not each batch. The clock is
    injectable."""

    def __init__(self, write: Callable[[str], None], every_seconds: float = LOG_EVERY_SECONDS,
                 clock: Callable[[], float] = time.monotonic):
        self.write, self.clock, self.every_seconds = write, clock, every_seconds
        self.loops: dict[str, _Loop] = {}
        self.last_line = clock()

    def __call__(self, task: str, done: int, total: int) -> None:
        self.report(task, done, total, nested=False)

    def nested(self, label: str) -> ProgressSink:
        """The sink of loops inside `label` (a batch of a stage): `label: task`, quiet when quick."""
        return lambda task, done, total: self.report(f"{label}: {task}", done, total, nested=True)

    def report(self, task: str, done: int, total: int, nested: bool) -> None:
        now = self.clock()
        loop = self.loops.get(task)
        if loop is None or done < loop.done or (done == 0 and loop.done == 0):  # a new loop (or run again)
            self.loops[task] = _Loop(now, done, nested)
            return
        if done == loop.done:
            return  # nothing new (a repeated report, or the end printed already)
        loop.done = done
        if total > 0 and done >= total:
            if not loop.nested or loop.printed:
                self._print(progress_line(task, done, total, now - loop.started), now)
            return
        if now - self.last_line >= self.every_seconds and now - loop.started >= self.every_seconds:
            loop.printed = True
            self._print(progress_line(task, done, total, now - loop.started), now)

    def _print(self, line: str, now: float) -> None:
        self.last_line = now
        self.write(line)


class RichProgress:
    """The terminal sink: one rich bar per loop (count, elapsed, ETA), updated in place; a nested loop's
    bar is removed when it ends, the others when the block ends."""

    def __init__(self, bar: Progress):
        self.bar = bar
        self.tasks: dict[str, object] = {}

    def __call__(self, task: str, done: int, total: int) -> None:
        self.report(task, done, total, nested=False)

    def nested(self, label: str) -> ProgressSink:
        return lambda task, done, total: self.report(f"{label}: {task}", done, total, nested=True)

    def report(self, task: str, done: int, total: int, nested: bool) -> None:
        if task not in self.tasks:
            self.tasks[task] = self.bar.add_task(task, total=total or None)
        self.bar.update(self.tasks[task], completed=done, total=total or None)  # type: ignore[arg-type]
        if nested and total and done >= total:
            self.bar.remove_task(self.tasks.pop(task))  # type: ignore[arg-type]


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
