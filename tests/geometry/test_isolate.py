"""The isolated worker: results and exceptions come back, crashes and hangs cost one call only."""

from __future__ import annotations

import pytest
from tests.geometry.makers import add, allocate, crash_process, hang, raise_value_error

from photoshape_flow.geometry.isolate import IsolatedWorker, WorkerCrashedError, WorkerTimeoutError


def test_results_exceptions_crash_and_timeout_in_one_worker() -> None:
    with IsolatedWorker(timeout_s=60) as worker:
        assert worker.call(add, 2, 3) == 5
        with pytest.raises(ValueError, match="boom"):
            worker.call(raise_value_error, "boom")
        assert worker.call(add, 1, 1) == 2  # the child survived the exception
        with pytest.raises(WorkerCrashedError, match="SIGSEGV"):
            worker.call(crash_process)
        assert worker.call(add, 4, 4) == 8  # a fresh child after the crash
        with pytest.raises(WorkerTimeoutError, match="timed out"):
            worker.call(hang, timeout_s=1.0)
        assert worker.call(add, 5, 5) == 10


def test_the_memory_budget_stops_a_bomb_in_the_child_only() -> None:
    with IsolatedWorker(timeout_s=60, memory_bytes=1024**3) as worker:
        assert worker.call(allocate, 64 * 1024**2) == 8 * 1024**2
        with pytest.raises(MemoryError):
            worker.call(allocate, 3 * 1024**3)  # would pass without the budget (the test host has the memory)
        assert worker.call(add, 1, 2) == 3


def test_a_function_the_child_cannot_import_fails_that_call_only() -> None:
    """The child imports a function's module as it unpickles the call: a module only the parent has
    (here one built in memory) comes back as the import error, and the child serves the next call."""
    import sys
    import types

    module = types.ModuleType("photoshape_parent_only")
    exec("def double(x):\n    return 2 * x\n", module.__dict__)
    sys.modules[module.__name__] = module
    try:
        with IsolatedWorker(timeout_s=60) as worker:
            with pytest.raises(ModuleNotFoundError, match="photoshape_parent_only"):
                worker.call(module.double, 2)
            assert worker.call(add, 2, 2) == 4
    finally:
        del sys.modules[module.__name__]
