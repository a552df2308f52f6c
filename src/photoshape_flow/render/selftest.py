"""The renderer's self-test for ``photoshape doctor``: a real 16x16 part-ID render in a child process.

A child process because LLVM 15/16 abort the whole interpreter on the first Mitsuba kernel (see
`render.runtime`), which no ``try`` can catch. It lives apart from `render.runtime` because it needs
the `Renderer`, and the renderer's own modules import the runtime.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from photoshape_flow.geometry.mesh import PartMesh, ShapeMesh
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.factory import default_renderer
from photoshape_flow.render.runtime import LLVM_HINT, RendererUnavailableError, ensure_mitsuba, loaded_llvm


def self_test() -> None:
    """Render a 16x16 part-ID image of a quad; prints ``ok variant=... llvm=...`` (run by `check_llvm`)."""
    mi = ensure_mitsuba()
    quad = PartMesh(
        index=1,
        name="quad",
        vertices=np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], np.float32),
        faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
        normals=np.tile(np.array([[0, 0, 1]], np.float32), (4, 1)),
        uvs=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32),
    )
    ids = default_renderer().part_ids(ShapeMesh(parts=[quad]), Camera(0.0, 0.0, 2.0, 50.0), size=16)
    if ids[8, 8] != 1 or ids[0, 0] != 0:
        raise SystemExit(f"wrong part-ID render: centre {ids[8, 8]}, corner {ids[0, 0]}")
    sys.stdout.write(f"ok variant={mi.variant()} llvm={loaded_llvm() or 'n/a'}\n")


def check_llvm(timeout: float = 180.0) -> tuple[bool, str]:
    """Run `self_test` in a subprocess; (ok, one-line message) for ``photoshape doctor``."""
    code = f"from {__name__} import self_test; self_test()"
    try:
        proc = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, check=False
        )
    except subprocess.TimeoutExpired:
        return False, f"test render did not finish in {timeout:.0f} s (a single render thread deadlocks)"
    output = (proc.stdout + proc.stderr).strip().splitlines()
    if proc.returncode == 0 and output and output[-1].startswith("ok "):
        return True, output[-1][3:]
    tail = next((line for line in reversed(output) if line.strip()), "no output")
    tail = tail.replace(f"{RendererUnavailableError.__module__}.{RendererUnavailableError.__name__}: ", "")
    if proc.returncode < 0:
        return False, f"test render crashed with signal {-proc.returncode} ({tail}); {LLVM_HINT}"
    return False, f"test render failed (exit {proc.returncode}): {tail}"
