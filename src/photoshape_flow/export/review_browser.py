"""A person's review session on a served gallery, in headless Chromium (export/node/review_flow.mjs).

The same system Chromium and pinned playwright-core as `export.browser`: open the index of
`photoshape gallery --serve`, open a PhotoShape, turn it in 3D, enlarge a render, grade it with a
key, reload, filter the index to the ungraded ones. The report says what the page showed at each
step (``steps``) and, as `export.browser.problems` reads it, every console error, page error,
failed request and request that tried to leave the server (aborted). With `screenshots`, each
step is also a PNG there (review-1-turned.png ... review-4-ungraded.png, as docs/operations.md
shows them; `scripts/review-screenshots.sh` makes them from the tiny demo).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from photoshape_flow.export.node_tools import chromium_executable, require_package, run_script_with_config
from photoshape_flow.export.review_server import GRADE_KEYS

SCREENSHOTS: tuple[str, ...] = ("review-1-turned.png", "review-2-enlarged.png", "review-3-graded.png",
                                "review-4-ungraded.png")


def review_flow(url: str, *, label: str = "good", pair: int | None = None, screenshots: str | Path | None = None,
                viewport: tuple[int, int] = (1280, 900), timeout: float = 300.0) -> dict[str, Any]:
    """Run the session on the served gallery at `url` (its index), grading `pair` (default: the
    index's first row) `label` with that grade's key. Raises `NodeToolsMissing`."""
    require_package("playwright-core")
    config = {
        "executable": chromium_executable(), "url": url, "pair": pair, "label": label, "key": GRADE_KEYS[label],
        "viewport": list(viewport), "screenshots": str(Path(screenshots).resolve()) if screenshots else None,
    }
    if screenshots:
        Path(screenshots).mkdir(parents=True, exist_ok=True)
    return run_script_with_config("review_flow.mjs", config, timeout=timeout)
