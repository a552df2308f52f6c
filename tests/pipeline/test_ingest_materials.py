"""Material ingest: maps as PNG blobs, analytic materials, idempotence, replacement, the Prefect event."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import sqlalchemy as sa
from photoshape_flow.flows import events as prefect_events
from photoshape_flow.flows.events import PrefectEvents
from tests.geometry.makers import write_png

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.ingest.ingest import MATERIAL_EVENT, ingest_materials, render_material_previews


def make_folders(root: Path) -> Path:
    write_png(root / "wood_oak" / "oak_Color.png", np.full((8, 8, 3), (120, 80, 40), np.uint8))
    write_png(root / "wood_oak" / "oak_Roughness.png", np.full((8, 8), 150, np.uint8))
    write_png(root / "wood_oak" / "oak_NormalDX.png", np.full((8, 8, 3), (128, 100, 255), np.uint8))
    write_png(root / "metal_gold" / "albedo.png", np.full((8, 8, 3), 200, np.uint8))
    red = root / "red_plastic"
    red.mkdir(parents=True)
    (red / "material.json").write_text(json.dumps({
        "name": "red_plastic", "substance": "plastic", "kind": "analytic", "license": "CC0-1.0",
        "params": {"albedo": [0.8, 0.1, 0.1], "roughness": 0.3},
    }))
    return root


def _rows(url: str) -> dict[str, m.Material]:
    with session_scope(url) as session:
        return {r.name: r for r in session.execute(sa.select(m.Material)).scalars()}


def test_ingest_material_folders(db_url: str, store, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    summary = ingest_materials([make_folders(tmp_path / "mats")], license="CC0-1.0", previews=False)
    assert len(summary.added) == 3 and summary.new_material_ids == summary.added and not summary.rejected
    rows = _rows(db_url)
    oak = rows["wood_oak"]
    assert (oak.substance, oak.kind, oak.status, oak.default_scale) == ("wood", "svbrdf", "ok", 0.25)
    assert set(oak.maps) == {"albedo", "roughness", "normal"}
    assert all(ref.endswith(".png") for ref in oak.maps.values())
    assert (store.load_image(oak.maps["normal"])[..., 1] == 155).all()  # DirectX -> OpenGL
    assert oak.params == {"metallic": 0.0} and oak.license == "CC0-1.0" and oak.sha256
    gold = rows["metal_gold"]
    assert gold.params == {"metallic": 1.0, "roughness": 0.5}
    red = rows["red_plastic"]
    assert red.kind == "analytic" and red.maps == {} and red.params["albedo"] == [0.8, 0.1, 0.1]


def test_idempotent_and_replacement_bumps_params_hash(db_url: str, tmp_path: Path) -> None:
    root = make_folders(tmp_path / "mats")
    first = ingest_materials([root], previews=False)
    before = _rows(db_url)["wood_oak"]
    again = ingest_materials([root], previews=False)
    assert sorted(again.present) == sorted(first.added) and not again.new_material_ids
    write_png(root / "wood_oak" / "oak_Roughness.png", np.full((8, 8), 20, np.uint8))
    replaced = ingest_materials([root], previews=False)
    assert replaced.replaced == [before.id] and not replaced.new_material_ids
    after = _rows(db_url)["wood_oak"]
    assert after.params_hash != before.params_hash and after.maps["roughness"] != before.maps["roughness"]


def test_bad_material_folders(db_url: str, tmp_path: Path) -> None:
    root = tmp_path / "mats"
    write_png(root / "fabric_ok" / "albedo.png", np.zeros((4, 4, 3), np.uint8))
    write_png(root / "fabric_ok" / "mystery_map.png", np.zeros((4, 4, 3), np.uint8))
    (root / "broken").mkdir(parents=True)
    (root / "broken" / "material.json").write_text("{oops")
    (root / "cheese").mkdir()
    (root / "cheese" / "material.json").write_text('{"substance": "cheese"}')
    write_png(root / "wood_corrupt" / "albedo.png", np.zeros((4, 4, 3), np.uint8))
    (root / "wood_corrupt" / "albedo.png").write_bytes(b"\x89PNG\r\n\x1a\ntruncated")
    summary = ingest_materials([root, tmp_path / "missing"], previews=False)
    reasons = {Path(k).name: v for k, v in summary.rejected}
    assert summary.added and len(summary.added) == 1
    assert "invalid JSON" in reasons["broken"] and "unknown substance 'cheese'" in reasons["cheese"]
    assert "albedo.png" in reasons["wood_corrupt"] and "no such file" in reasons["missing"]
    assert any("mystery_map.png: unrecognised map name" in w for _, w in summary.warnings)
    rows = _rows(db_url)
    assert rows["broken"].status == "rejected" and not rows["broken"].enabled
    assert rows["wood_corrupt"].status == "rejected" and rows["wood_corrupt"].maps == {}


def test_material_event_once_per_batch_only_with_a_prefect_api(db_url: str, tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    from photoshape_flow.config import get_settings

    calls: list[tuple] = []
    monkeypatch.setattr(prefect_events, "_send_event", lambda *args, **kw: calls.append(args))
    monkeypatch.setattr(prefect_events, "_prefect_api_url", lambda: None)
    root = make_folders(tmp_path / "mats")
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    ingest_materials([root / "wood_oak"], previews=False, events=PrefectEvents(get_settings()))
    assert calls == []  # no API configured: no event

    monkeypatch.setenv("PHOTOSHAPE_PREFECT_API_URL", "http://127.0.0.1:9/api")
    get_settings.cache_clear()
    summary = ingest_materials([root], previews=False, events=PrefectEvents(get_settings()))
    assert len(calls) == 1
    url, event, resource, payload = calls[0]
    assert (url, event) == ("http://127.0.0.1:9/api", MATERIAL_EVENT)
    assert resource == {"prefect.resource.id": "photoshape.material-set"}
    assert payload["count"] == 2 == len(summary.new_material_ids)
    assert sorted(payload["material_ids"]) == sorted(summary.new_material_ids)
    ingest_materials([root], previews=False, events=PrefectEvents(get_settings()))  # nothing new: no event
    assert len(calls) == 1


def test_event_goes_through_emit_event_when_prefect_uses_the_same_api(db_url: str, tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    import prefect.events

    from photoshape_flow.config import get_settings

    sent: list[dict] = []
    monkeypatch.setattr(prefect.events, "emit_event", lambda **kw: sent.append(kw) or object())
    monkeypatch.setattr(prefect_events, "_prefect_api_url", lambda: "http://prefect:4200/api")
    monkeypatch.setenv("PHOTOSHAPE_PREFECT_API_URL", "http://prefect:4200/api")
    get_settings.cache_clear()
    ingest_materials([make_folders(tmp_path / "mats") / "wood_oak"], previews=False,
                     events=PrefectEvents(get_settings()))
    assert len(sent) == 1 and sent[0]["event"] == MATERIAL_EVENT and sent[0]["payload"]["count"] == 1


def test_unreachable_prefect_never_fails_ingest(db_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from photoshape_flow.config import get_settings

    monkeypatch.setattr(prefect_events, "_prefect_api_url", lambda: None)
    monkeypatch.setenv("PHOTOSHAPE_PREFECT_API_URL", "http://127.0.0.1:9/api")  # nothing listens there
    get_settings.cache_clear()
    events = PrefectEvents(get_settings())
    summary = ingest_materials([make_folders(tmp_path / "mats") / "wood_oak"], previews=False, events=events)
    assert len(summary.added) == 1
    assert events.materials_added(summary.added) is False


def test_previews_skip_cleanly_without_an_envmap(db_url: str, tmp_path: Path) -> None:
    summary = ingest_materials([make_folders(tmp_path / "mats") / "wood_oak"], previews=True)
    reason = summary.skipped[0][1]
    assert "envmap" in reason or "renderer" in reason
    assert render_material_previews([]).skipped == []


@pytest.mark.realdata
def test_real_material_folders(db_url: str, shared_data: Path) -> None:
    summary = ingest_materials([shared_data / "materials"], previews=False)
    assert len(summary.added) == 4 and not summary.rejected
    rows = _rows(db_url)
    assert rows["metal_scratched_gold_01"].substance == "metal"
    assert rows["metal_scratched_gold_01"].params["metallic"] == 1.0
    assert set(rows["wood_rosewood_veneer1"].maps) == {"albedo", "normal", "roughness"}


@pytest.mark.render
def test_previews_are_rendered_when_the_renderer_is_available(db_url: str, store, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from tests.imaging.test_hdr import sky, write_hdr

    from photoshape_flow.ingest.ingest import ingest_envmaps

    ingest_envmaps([write_hdr(tmp_path / "sky.hdr", sky())], isolate=False)
    summary = ingest_materials([make_folders(tmp_path / "mats") / "wood_oak"], previews=False)
    result = render_material_previews(summary.added, size=32, spp=4)
    assert result.added == summary.added and not result.skipped
    preview = store.load_image(_rows(db_url)["wood_oak"].preview_blob)
    assert preview.shape == (32, 32, 3)
    assert preview[16, 16].mean() < 250 and preview[0, 0].min() >= 250  # a sphere on white


@pytest.mark.render
def test_materials_ingested_before_any_envmap_get_previews_later(db_url: str, tmp_path: Path) -> None:
    from tests.imaging.test_hdr import sky, write_hdr

    from photoshape_flow.ingest.ingest import ingest_envmaps

    folders = make_folders(tmp_path / "mats")
    ingest_materials([folders / "wood_oak"], previews=True)  # no envmap yet: skipped
    assert _rows(db_url)["wood_oak"].preview_blob is None
    ingest_envmaps([write_hdr(tmp_path / "sky.hdr", sky())], isolate=False)  # catches up
    preview = _rows(db_url)["wood_oak"].preview_blob
    assert preview is not None
    again = ingest_materials([folders / "wood_oak"], previews=True)  # present with a preview: nothing redone
    assert again.present and _rows(db_url)["wood_oak"].preview_blob == preview


def test_ingest_materials_says_whether_it_announced_the_new_ones(db_url: str, tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """Through the real CLI: the new materials by name, and whether the material-added event went out
    (it is handed to the Prefect API at `_send_event`, the network boundary)."""
    from typer.testing import CliRunner

    from photoshape_flow.cli import app
    from photoshape_flow.config import get_settings

    root = make_folders(tmp_path / "mats")
    monkeypatch.setattr(prefect_events, "_prefect_api_url", lambda: None)
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    monkeypatch.delenv("PHOTOSHAPE_PREFECT_API_URL", raising=False)
    get_settings.cache_clear()
    quiet = CliRunner().invoke(app, ["ingest", "materials", str(root / "wood_oak"), "--no-previews"])
    assert quiet.exit_code == 0, quiet.output
    name = next(iter(_rows(db_url)))
    assert f"not announced: 1 new material ({name}); no Prefect API configured" in " ".join(quiet.output.split())

    calls: list[tuple] = []
    monkeypatch.setattr(prefect_events, "_send_event", lambda *args, **kw: calls.append(args))
    monkeypatch.setenv("PHOTOSHAPE_PREFECT_API_URL", "http://127.0.0.1:9/api")
    get_settings.cache_clear()
    sent = CliRunner().invoke(app, ["ingest", "materials", str(root), "--no-previews"])
    assert sent.exit_code == 0, sent.output
    new = sorted(set(_rows(db_url)) - {name})
    assert len(calls) == 1 and len(new) == 2
    assert (f"announced 2 new materials ({', '.join(new)}): event {MATERIAL_EVENT} sent to "
            "http://127.0.0.1:9/api") in " ".join(sent.output.split())
    again = CliRunner().invoke(app, ["ingest", "materials", str(root), "--no-previews"])
    assert again.exit_code == 0 and "announced" not in again.output  # nothing new: nothing to announce
    get_settings.cache_clear()
