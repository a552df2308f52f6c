"""Stage `ingest`: the four collections into rows and blobs, envmaps first so previews can render."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from photoshape_flow.ingest import common as ingest_common
from photoshape_flow.ingest import ingest
from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.report import StageReport
from photoshape_flow.profiles import IngestConfig

COLLECTIONS: tuple[str, ...] = ("envmaps", "materials", "shapes", "exemplars")  # previews need envmaps


@dataclass(frozen=True)
class IngestRequest:
    """What to ingest: folders or files per collection (default: the inbox), and their provenance."""

    roots: Mapping[str, Sequence[Path]] | None = None
    source: str | None = None
    license: str | None = None
    attribution: str | None = None


def inbox(ctx: StageContext) -> Path:
    """Where `photoshape run ingest` looks: <data_root>/inbox/{envmaps,materials,shapes,exemplars}."""
    return ctx.settings.data_root / "inbox"


def _per_collection(ctx: StageContext, collection: str) -> Any:
    """Ingest reports (file name, done, total): the stage's sink gets one task per collection instead."""
    return lambda _label, done, total: ctx.progress(f"ingest {collection}", done, total)


def _collection(ctx: StageContext, name: str, paths: list[Path], kwargs: dict[str, Any]) -> Any:
    """One collection's ingest; should it raise outside its items (an unreadable folder while walking
    it, a blob store that cannot be opened), that is one rejected line for the collection, and the
    other collections still go in: a poison file in the inbox never fails a run."""
    summary = ingest.IngestSummary(name)
    function = getattr(ingest, f"ingest_{name}")
    done = ingest_common.guard_item(summary, ", ".join(str(p) for p in paths),
                                    lambda: function(paths, store=ctx.store, **kwargs))
    return summary if done is None else done


def run(ctx: StageContext, cfg: IngestConfig, work: IngestRequest | None = None) -> StageReport:

    request = work or IngestRequest()
    roots = request.roots
    if roots is None:
        roots = {name: [inbox(ctx) / name] for name in COLLECTIONS if (inbox(ctx) / name).is_dir()}
    report = StageReport("ingest")
    for name in COLLECTIONS:
        paths = [Path(p) for p in roots.get(name, [])]
        if not paths:
            continue
        kwargs: dict[str, Any] = {"settings": ctx.settings, "progress": _per_collection(ctx, name)}
        if request.source is not None and name != "envmaps":
            kwargs["source"] = request.source
        for key in ("license", "attribution"):
            if getattr(request, key) is not None:
                kwargs[key] = getattr(request, key)
        if name == "exemplars":
            kwargs["size"] = cfg.exemplar_size
        if name == "materials":
            kwargs.update(previews=cfg.previews, preview_size=cfg.preview_size, events=ctx.events,
                          renderer=ctx.renderer)
        summary = _collection(ctx, name, paths, kwargs)
        report = report.merge(StageReport(
            "ingest", done=len(summary.added) + len(summary.replaced), skipped=len(summary.present),
            rejected=len(summary.rejected),
            details={name: {"added": len(summary.added), "present": len(summary.present),
                            "replaced": len(summary.replaced),
                            "rejected": [f"{path}: {reason}" for path, reason in summary.rejected],
                            **({"announced": summary.announced} if summary.announced is not None else {})}},
        ))
    return report
