"""Mitsuba/Dr.Jit start-up: the variant once per process, the thread count, and an LLVM check.

Why this is careful: Dr.Jit picks the newest ``libLLVM*.so`` it finds. LLVM 14 is rejected (the
backend is disabled and the first use fails), and LLVM 15/16 *abort the interpreter* on the first
Mitsuba kernel (``LLVM ERROR: Cannot select: fminimum``), which no ``try`` can catch. So
`ensure_mitsuba` refuses to render when the loaded libLLVM is older than 17 (and
`render.selftest.check_llvm` runs a real render in a subprocess for ``photoshape doctor``). Mitsuba
also deadlocks loading an ``envmap`` with a single worker thread, so the thread count is never below 2.

Every other render module imports this one, so it imports none of them.
"""

from __future__ import annotations

import re
import threading
from typing import Any

from photoshape_flow.config import get_settings

LLVM_HINT = (
    "install a newer LLVM: `apt-get install -y libllvm19` (Debian 12's default libllvm15 aborts on the "
    "first render; Dr.Jit picks the newest libLLVM it finds)"
)
MIN_LLVM_MAJOR = 17

_lock = threading.Lock()
_state: dict[str, Any] = {}


class RendererUnavailableError(RuntimeError):
    """Mitsuba cannot render in this process (missing module, LLVM missing or too old)."""


def loaded_llvm() -> str | None:
    """Path of the libLLVM this process has mapped, if any."""
    try:
        with open("/proc/self/maps") as handle:
            for line in handle:
                if "libLLVM" in line:
                    return line.split()[-1]
    except OSError:
        return None
    return None


def llvm_major(path: str | None) -> int | None:
    """Major version from a libLLVM file name (libLLVM-15.so.1, libLLVM.so.19.1)."""
    if not path:
        return None
    match = re.search(r"libLLVM[-.]?(?:so\.)?(\d+)", path.rsplit("/", 1)[-1])
    return int(match.group(1)) if match else None


def ensure_mitsuba(variant: str | None = None, threads: int | None = None) -> Any:
    """Import Mitsuba, set the variant (once per process) and the thread count; returns ``mi``.

    Raises `RendererUnavailableError` with a fix hint when LLVM is missing or too old.
    """
    settings = get_settings()
    variant = variant or settings.render_variant
    threads = max(2, threads or settings.effective_render_threads)
    with _lock:
        try:
            import drjit as dr
            import mitsuba as mi
        except ImportError as exc:  # pragma: no cover - the wheel is a hard dependency
            raise RendererUnavailableError(f"cannot import mitsuba/drjit: {exc}") from exc
        if mi.variant() != variant:  # first use, or another module (e.g. the blob store) set its own
            if variant.startswith("llvm") and not _state.get("llvm_checked"):
                _check_llvm_backend(dr)
                _state["llvm_checked"] = True
            try:
                mi.set_variant(variant)
            except Exception as exc:
                raise RendererUnavailableError(f"Mitsuba variant {variant!r} unavailable: {exc}") from exc
        if _state.get("threads") != threads:
            dr.set_thread_count(threads)
            _state["threads"] = threads
        return mi


def _check_llvm_backend(dr: Any) -> None:
    if not dr.has_backend(dr.JitBackend.LLVM):
        raise RendererUnavailableError(
            f"Dr.Jit's LLVM backend is unavailable (libLLVM missing or too old); {LLVM_HINT}"
        )
    try:  # initialise the backend so the library is mapped, without compiling a Mitsuba kernel
        import drjit.llvm as llvm

        dr.eval(llvm.Float(1.0, 2.0) + 1.0)
    except Exception as exc:
        raise RendererUnavailableError(f"Dr.Jit's LLVM backend failed to start: {exc}; {LLVM_HINT}") from exc
    path = loaded_llvm()
    major = llvm_major(path)
    if major is not None and major < MIN_LLVM_MAJOR:
        raise RendererUnavailableError(
            f"Dr.Jit loaded {path} (LLVM {major}); Mitsuba kernels abort with LLVM < {MIN_LLVM_MAJOR}; {LLVM_HINT}"
        )
