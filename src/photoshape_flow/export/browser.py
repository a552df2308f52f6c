"""Check static pages the way a person would see them, in headless Chromium (export/node/check_pages.mjs).

Chromium is the system one (Debian's /usr/bin/chromium) driven by the pinned playwright-core, so
nothing downloads a browser. The report lists, per page, console and page errors, failed requests,
requests that tried to leave the machine (aborted), every image with its natural size and every link.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from photoshape_flow.export.node_tools import chromium_executable, require_package, run_script_with_config


def check_pages(
    pages: Sequence[str | Path],
    *,
    screenshot: str | Path | None = None,
    evaluate: Sequence[str] = (),
    viewport: tuple[int, int] = (1280, 900),
    timeout: float = 180.0,
    screenshot_selector: str | None = None,
) -> dict[str, Any]:
    """Load each page; `evaluate` expressions run on the first page (results in ``evaluated``; an
    expression's promise is awaited), then the first page is screenshotted to `screenshot`: the full
    page, or the first element matching `screenshot_selector`. Raises `NodeToolsMissing`."""
    require_package("playwright-core")
    config = {
        "executable": chromium_executable(),
        "pages": [str(Path(p).resolve()) for p in pages],
        "screenshot": str(Path(screenshot).resolve()) if screenshot else None,
        "viewport": list(viewport),
        "evaluate": list(evaluate),
        "screenshot_selector": screenshot_selector,
    }
    return run_script_with_config("check_pages.mjs", config, timeout=timeout)


def problems(report: dict[str, Any]) -> list[str]:
    """Everything wrong in a `check_pages` report, one line each (empty when all is well)."""
    out: list[str] = []
    for page in report.get("pages", []):
        name = Path(page["page"]).name
        out += [f"{name}: console error: {e}" for e in page.get("console_errors", [])]
        out += [f"{name}: page error: {e}" for e in page.get("page_errors", [])]
        out += [f"{name}: failed request: {e}" for e in page.get("failed_requests", [])]
        out += [f"{name}: external request: {e}" for e in page.get("external_requests", [])]
        out += [f"{name}: image did not load: {i['src']}" for i in page.get("images", []) if not i["natural_width"]]
        if not page.get("ok", True):
            out.append(f"{name}: page did not load")
    return out
