"""Where a PhotoShape's downloads live, and `photoshape export` (downloads written on demand).

The publish stage writes each candidate's exports into ``<data_root>/exports/<method_key>/<pair_id>/``
with a manifest ``<pair_id>.json`` (params_hash, status, error, files) beside the folder; the
gallery links what the manifest lists. `export_candidates` writes the same downloads into a folder
of the caller's choice.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.export.bundle import export_photoshape
from photoshape_flow.export.formats import DEFAULT_FORMATS, parse_formats
from photoshape_flow.profiles import DEFAULT_PUBLISH_METHOD
from photoshape_flow.progress_sink import Progress, counted
from photoshape_flow.publish.photoshapes import (
    EXEMPLAR_VIEW,
    candidate_method_keys,
    choose_envmap,
    exemplar_render,
    load_photoshape,
    render_key,
)
from photoshape_flow.store import default_store
from photoshape_flow.vocab import STATUS_FAILED, STATUS_OK

log = logging.getLogger(__name__)

DEFAULT_FILM = (512, 128)  # (size, spp) of a scene export without a published render to match


def safe_key(method_key: str) -> str:
    """A method key as a folder name (``classifier:3`` -> ``classifier-3``)."""
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in method_key)


def exports_root(settings: Settings | None = None) -> Path:
    return (settings or get_settings()).data_root / "exports"


def export_dir(pair_id: int, method_key: str, settings: Settings | None = None) -> Path:
    return exports_root(settings) / safe_key(method_key) / str(pair_id)


def export_manifest(pair_id: int, method_key: str, settings: Settings | None = None) -> dict[str, Any] | None:
    path = export_dir(pair_id, method_key, settings).with_suffix(".json")
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def published_film(session: Any, pair_id: int, method_key: str) -> tuple[int, int]:
    """(size, spp) of the PhotoShape's published exemplar-view render, else `DEFAULT_FILM`."""
    import sqlalchemy as sa

    params = session.execute(
        sa.select(m.Rendering.params).where(m.Rendering.kind == "photoshape", m.Rendering.status == STATUS_OK,
                                            m.Rendering.key == render_key(pair_id, method_key, EXEMPLAR_VIEW))
    ).scalar_one_or_none() or {}
    try:
        return int(params["size"]), int(params["spp"])
    except (KeyError, TypeError, ValueError):
        return DEFAULT_FILM


def export_candidates(
    out_dir: str | Path,
    pair_ids: Sequence[int] | None = None,
    method: str | None = None,
    formats: Sequence[str] = DEFAULT_FORMATS,
    settings: Settings | None = None,
    *,
    size: int | None = None,
    spp: int | None = None,
    progress: Progress | None = None,
) -> list[dict[str, Any]]:
    """Write each candidate's downloads into ``out_dir/<pair_id>-<method_key>/``; one result per item.

    Each result: ``{"pair_id", "method_key", "status", "error", "files": {format: path}}``; a failing
    candidate is reported and the others go on. `size` / `spp` of the scene formats: None takes the
    published exemplar-view render's, so the XML reproduces it (`DEFAULT_FILM` when unpublished).
    """
    settings = settings or get_settings()
    formats = parse_formats(list(formats))
    store = default_store(settings)
    url = settings.resolved_database_url
    with session_scope(url) as session:
        todo = candidate_method_keys(session, method, pair_ids)
        envmap = choose_envmap(session)
        envmap_id = envmap.id if envmap is not None else None
    missing = sorted(set(pair_ids or ()) - {p for p, _ in todo})
    results: list[dict[str, Any]] = [
        {"pair_id": p, "method_key": None, "status": STATUS_FAILED, "error": f"pair {p}: not a candidate for "
         f"{method or DEFAULT_PUBLISH_METHOD} (no rank-1 assignments, or excluded)", "files": {}} for p in missing
    ]
    for pair_id, method_key in counted(progress, "export pairs", todo):
        result: dict[str, Any] = {"pair_id": pair_id, "method_key": method_key, "files": {}}
        try:
            with session_scope(url) as session:
                env = session.get(m.Envmap, envmap_id) if envmap_id is not None else None
                item = load_photoshape(session, store, pair_id, method_key, env)
            target = Path(out_dir) / f"{pair_id}-{safe_key(method_key)}"
            camera, seed = exemplar_render(item, settings.seed)  # the framing and noise of the gallery's render
            with session_scope(url) as session:
                film = published_film(session, pair_id, method_key)
            written = export_photoshape(target, item.mesh, item.materials, item.uv_transforms, item.document,
                                        formats=formats, envmap=item.envmap, camera=camera, seed=seed,
                                        resolve_ref=store.resolve, size=size or film[0], spp=spp or film[1])
            result.update(status=STATUS_OK, error=None, files={k: str(v) for k, v in written.items()})
        except Exception as exc:
            result.update(status=STATUS_FAILED, error=f"pair {pair_id} ({method_key}): {type(exc).__name__}: {exc}")
            log.warning("export: %s", result["error"])
        results.append(result)
    return sorted(results, key=lambda r: r["pair_id"])
