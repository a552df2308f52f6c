"""Run untrusted work in a persistent child process with a timeout: a crash costs one item.

Some native importers segfault on real files (two Kator Legaz Sweet Home 3D chairs crash Blender's),
and a segfault cannot be caught in-process. `IsolatedWorker` keeps one spawned child (spawn, not
fork, so it is safe in threaded hosts such as Prefect workers), sends it a module-level function
and picklable arguments (pickle names the function, the child imports its module as it unpickles),
and waits with a timeout. A dead child raises `WorkerCrashedError`,
an overrun kills it and raises `WorkerTimeoutError`; either way the next call starts a fresh child.
Exceptions raised by the function come back as themselves (BadShapeError stays a rejection).

`memory_bytes` is the per-item memory budget: the child's data segment (heap and anonymous maps,
RLIMIT_DATA: what decoders and numpy allocate, not the shared libraries it maps) is capped, so a
bomb that slips past every size check gets a MemoryError (or dies) in the child, never swaps the
machine; either way it costs one item.
"""

from __future__ import annotations

import multiprocessing as mp
import signal
import time
import traceback
from collections.abc import Callable
from typing import Any


class WorkerCrashedError(RuntimeError):
    """The child process died (segfault, abort, out of memory) while working on an item."""


class WorkerTimeoutError(RuntimeError):
    """The child process ran past its time limit and was killed."""


def _child_main(conn: Any, memory_bytes: int | None = None) -> None:
    if memory_bytes is not None:
        import resource

        _soft, hard = resource.getrlimit(resource.RLIMIT_DATA)
        cap = memory_bytes if hard == resource.RLIM_INFINITY else min(memory_bytes, hard)
        resource.setrlimit(resource.RLIMIT_DATA, (cap, hard))
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        except Exception as exc:  # the function's module failed to import here: one item's error
            conn.send(("error", exc, traceback.format_exc(limit=5)))
            continue
        if message is None:
            return
        func, args, kwargs = message
        try:
            result = ("ok", func(*args, **kwargs))
        except BaseException as exc:  # everything goes back to the parent
            result = ("error", exc, traceback.format_exc(limit=5))
        try:
            conn.send(result)
        except Exception as exc:  # unpicklable exception or result
            conn.send(("error", RuntimeError(f"{type(exc).__name__}: {exc}"), ""))


def _describe_exit(code: int | None) -> str:
    if code is None:
        return "no exit code"
    if code < 0:
        try:
            return f"killed by signal {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


class IsolatedWorker:
    """One reusable child process; use as a context manager."""

    def __init__(self, timeout_s: float = 600.0, memory_bytes: int | None = None):
        self.timeout_s = timeout_s
        self.memory_bytes = memory_bytes
        self._ctx = mp.get_context("spawn")
        self._proc: Any = None
        self._conn: Any = None

    def _start(self) -> None:
        parent, child = self._ctx.Pipe()
        proc = self._ctx.Process(target=_child_main, args=(child, self.memory_bytes), daemon=True,
                                 name="photoshape-isolated")
        proc.start()
        child.close()
        self._proc, self._conn = proc, parent

    def _stop(self, kill: bool = False) -> None:
        proc, conn = self._proc, self._conn
        self._proc = self._conn = None
        if proc is None:
            return
        if not kill:
            try:
                conn.send(None)
            except (OSError, BrokenPipeError):
                pass
            proc.join(5)
        if proc.is_alive():
            proc.kill()
            proc.join(5)
        try:
            conn.close()
        except OSError:
            pass

    def call(self, func: Callable[..., Any], *args: Any, timeout_s: float | None = None, **kwargs: Any) -> Any:
        """func(*args, **kwargs) in the child; `func` must be a module-level function."""
        if self._proc is None or not self._proc.is_alive():
            self._stop(kill=True)
            self._start()
        limit = self.timeout_s if timeout_s is None else timeout_s
        try:
            self._conn.send((func, args, kwargs))
        except (OSError, BrokenPipeError) as exc:
            self._proc.join(5)
            code = self._proc.exitcode
            self._stop(kill=True)
            raise WorkerCrashedError(f"worker process crashed ({_describe_exit(code)})") from exc
        deadline = time.monotonic() + limit
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self._stop(kill=True)
                raise WorkerTimeoutError(f"timed out after {limit:g} s")
            if self._conn.poll(min(remaining, 0.5)):
                try:
                    status, *payload = self._conn.recv()
                except (EOFError, OSError) as exc:
                    self._proc.join(5)  # the pipe closes before the exit status is known
                    code = self._proc.exitcode
                    self._stop(kill=True)
                    raise WorkerCrashedError(f"worker process crashed ({_describe_exit(code)})") from exc
                if status == "ok":
                    return payload[0]
                raise payload[0]
            if not self._proc.is_alive():
                code = self._proc.exitcode
                self._stop(kill=True)
                raise WorkerCrashedError(f"worker process crashed ({_describe_exit(code)})")

    def close(self) -> None:
        self._stop()

    def __enter__(self) -> IsolatedWorker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

