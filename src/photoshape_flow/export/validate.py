"""The Khronos glTF validator (npm gltf-validator, pinned) as a Python function."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from photoshape_flow.export.node_tools import require_package, run_script


def validate_gltf(path: str | Path, max_issues: int = 200) -> dict[str, Any]:
    """Validate a .gltf (with its external files) or .glb; returns the validator's report.

    ``report["issues"]["numErrors"]`` is the number of spec violations; ``report["issues"]["messages"]``
    lists them (code, message, severity 0 = error .. 3 = hint, JSON pointer). Raises
    `NodeToolsMissing` when node or the package is not installed.
    """
    require_package("gltf-validator")
    file = Path(path)
    if not file.is_file():
        raise FileNotFoundError(f"{file}: no such file")
    return run_script("validate.mjs", str(file.resolve()), str(max_issues))


def errors(report: dict[str, Any]) -> list[str]:
    """The report's errors as one-line strings (empty when the asset is valid)."""
    return [
        f"{m.get('code')}: {m.get('message')} at {m.get('pointer', '')}"
        for m in report.get("issues", {}).get("messages", [])
        if m.get("severity") == 0
    ]
