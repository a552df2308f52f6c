"""Publish stage on a tiny database: renders, exports, resumability, failures, grades, gallery."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import sqlalchemy as sa
from tests.export.tiny import make_envmap, make_material_maps, make_tiny_shape

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope

METHOD = "fit"  # publish's default method (D46): the seeded rows are what publish shows unless told otherwise


def seed(url: str, store, tmp_path: Path) -> dict[str, int]:  # type: ignore[no-untyped-def]
    """One shape (2 parts), two exemplars, two SVBRDF materials, two envmaps, two pairs with assignments.

    Pair 'good' is complete; pair 'broken' assigns a material whose map blob is missing from the store.
    """
    rng = np.random.default_rng(0)
    mesh = make_tiny_shape()
    maps = make_material_maps(tmp_path / "maps")
    ids: dict[str, int] = {}
    with session_scope(url) as s:
        shape = m.Shape(source="test", source_id="tiny", name="tiny chair", mesh_blob=store.put_bytes(
            mesh.to_npz_bytes(), "npz"), num_parts=2, license="CC-BY-4.0", attribution="Shape Author",
            source_url="https://example.org/shape")
        s.add(shape)
        s.flush()
        parts = []
        for p in mesh.parts:
            row = m.Part(shape_id=shape.id, index=p.index, name=p.name, num_faces=len(p.faces),
                         uv_density=p.uv_density, builtin_material=p.builtin_material)
            s.add(row)
            s.flush()
            parts.append(row.id)
        materials = {}
        for name, substance, scale in (("oak_01", "wood", 0.25), ("steel_02", "metal", 0.5)):
            row = m.Material(name=name, substance=substance, default_scale=scale, license="CC0-1.0",
                             attribution=f"{name} author", params_hash=name,
                             maps={ch: store.put_file(path) for ch, path in maps[name].items()})
            s.add(row)
            s.flush()
            materials[name] = row.id
        broken = m.Material(name="missing_03", substance="wood", maps={"albedo": "0" * 64 + ".png"}, params_hash="x")
        s.add(broken)
        for name in ("outdoor_sky", "studio_soft"):
            s.add(m.Envmap(name=name, blob=store.put_image(make_envmap(), "exr"), width=32, height=16))
        classifier = m.Classifier(name="clf", kind="material", architecture="resnet34")
        s.add(classifier)
        s.flush()
        for key in ("good", "broken"):
            exemplar = m.Exemplar(source="test", source_id=f"photo_{key}", name=f"photo {key}",
                                  image_blob=store.put_image(rng.integers(0, 255, (32, 32, 3), np.uint8)),
                                  license="CC0-1.0", attribution="Photographer")
            s.add(exemplar)
            s.flush()
            pair = m.Pair(shape_id=shape.id, exemplar_id=exemplar.id, rank=1, distance=9.5, azimuth=0.4,
                          elevation=0.3, fov=50.0, camera_distance=2.2)
            s.add(pair)
            s.flush()
            ids[key] = pair.id
            first = materials["oak_01"] if key == "good" else broken.id
            for rank, (part_id, material_id, score) in enumerate(
                [(parts[0], first, 0.8), (parts[1], materials["steel_02"], 0.6),
                 (parts[0], materials["steel_02"], 0.1)]
            ):
                s.add(m.Assignment(pair_id=pair.id, part_id=part_id, method=METHOD,
                                   classifier_id=classifier.id, method_key=f"{METHOD}:{classifier.id}",
                                   rank=1 if rank < 2 else 2, material_id=material_id, score=score,
                                   substance="wood" if material_id != materials["steel_02"] else "metal",
                                   params={"uv": {"scale": 1.2, "rotation": 0.3, "offset": [0.1, 0.0]}}
                                   if rank == 0 else {}))
            s.add(m.Alignment(pair_id=pair.id, method="flow-crf", iou_crf=0.77))
        ids["classifier"] = classifier.id
    return ids


def _renderings(url: str) -> dict[tuple[str, str], m.Rendering]:
    with session_scope(url) as s:
        return {(r.kind, r.key): r for r in s.execute(sa.select(m.Rendering)).scalars()}


@pytest.mark.render
def test_publish_renders_exports_and_resumes(db_url, store, tmp_path):
    from photoshape_flow.config import get_settings
    from photoshape_flow.export.node_tools import ProgramMissing
    from photoshape_flow.export.validate import errors, validate_gltf
    from photoshape_flow.publish.downloads import export_manifest
    from photoshape_flow.publish.publish import run_publish

    ids = seed(db_url, store, tmp_path)
    mk = f"{METHOD}:{ids['classifier']}"
    summary = run_publish(views=2, size=16, spp=2, formats=("glb", "xml", "obj"))
    assert summary.candidates == 2 and summary.envmap == "studio_soft"
    assert summary.rendered == 4 and summary.exported == 1  # good pair: exemplar + 2 turntable + builtin
    assert summary.failed == 1 and "missing" in summary.errors[0]  # broken pair recorded, batch went on
    rows = _renderings(db_url)
    good = ids["good"]
    assert {k for k, r in rows.items() if r.status == "ok"} == {
        ("photoshape", f"{good}/{mk}/exemplar"), ("photoshape", f"{good}/{mk}/turntable-00"),
        ("photoshape", f"{good}/{mk}/turntable-01"), ("builtin", f"{good}/exemplar")}
    failed = rows[("photoshape", f"{ids['broken']}/{mk}/exemplar")]
    assert failed.status == "failed" and "missing" in failed.error
    row = rows[("photoshape", f"{good}/{mk}/exemplar")]
    assert row.pair_id == good and row.classifier_id == ids["classifier"] and row.params_hash
    image = store.load_image(row.blobs["srgb"])
    assert image.shape == (16, 16, 3) and (image < 250).any()  # the shape is in view on white
    builtin = store.load_image(rows[("builtin", f"{good}/exemplar")].blobs["srgb"])
    assert not np.array_equal(image, builtin)  # other materials, other pixels

    manifest = export_manifest(good, mk)
    assert manifest["status"] == "ok" and set(manifest["files"]) == {"glb", "xml", "obj", "assignment"}
    folder = get_settings().data_root / "exports" / mk.replace(":", "-") / str(good)
    sidecar = json.loads((folder / "assignment.json").read_text())
    assert [p["material"]["name"] for p in sidecar["parts"]] == ["oak_01", "steel_02"]  # rank 1 only
    assert sidecar["parts"][0]["uv"]["transform"]["scale"] == pytest.approx(1.2)
    assert sidecar["license_summary"] == ["CC-BY-4.0", "CC0-1.0"] and sidecar["unknown_licenses"] == 1
    try:
        assert errors(validate_gltf(folder / "photoshape.glb")) == []
    except ProgramMissing:  # no node here: the validator's own tests skip with the reason
        pass

    again = run_publish(views=2, size=16, spp=2, formats=("glb", "xml", "obj"))
    assert (again.rendered, again.skipped, again.exported, again.export_skipped) == (0, 4, 0, 1)
    assert again.failed == 1  # still broken, retried
    # three turntable views: view 1 moves (2 pi / 3 instead of pi) and view 2 is new; the rest is kept
    more = run_publish(views=3, size=16, spp=2, formats=("glb", "xml", "obj"))
    assert (more.rendered, more.skipped) == (2, 3)


def test_grade_rows_labels_and_sql(db_url, store, tmp_path):
    from typer.testing import CliRunner

    from photoshape_flow.cli import app
    from photoshape_flow.publish.grading import record_grade

    ids = seed(db_url, store, tmp_path)
    runner = CliRunner()
    result = runner.invoke(app, ["grade", str(ids["good"]), "good", "--note", "close match"])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["grade", str(ids["good"]), "wrong_color", "--grader", "bob"])
    assert result.exit_code == 0, result.output
    bad = runner.invoke(app, ["grade", str(ids["good"]), "great"])
    assert bad.exit_code == 1 and "valid grades: good, acceptable" in bad.output
    assert len([line for line in bad.output.strip().splitlines() if line.strip()]) <= 3
    missing = runner.invoke(app, ["grade", "999", "good"])
    assert missing.exit_code == 1 and "pair 999" in missing.output
    with session_scope(db_url) as s:
        record_grade(s, ids["good"], "acceptable", grader="user")  # same grader: replaced, not added
        rows = s.execute(sa.text(
            "SELECT DISTINCT g.grader, g.label, g.note FROM grade g "
            "JOIN photoshape_candidate c ON c.pair_id = g.pair_id ORDER BY g.grader")).all()
        with pytest.raises(ValueError, match="unknown grade"):
            record_grade(s, ids["good"], "meh")
    assert [tuple(r) for r in rows] == [("bob", "wrong_color", None), ("user", "acceptable", None)]


@pytest.mark.render
@pytest.mark.browser
def test_gallery_of_published_candidates(db_url, store, tmp_path):
    from typer.testing import CliRunner

    from photoshape_flow.cli import app
    from photoshape_flow.export.browser import check_pages, problems
    from photoshape_flow.export.node_tools import ProgramMissing
    from photoshape_flow.publish.grading import record_grade
    from photoshape_flow.publish.publish import run_publish

    ids = seed(db_url, store, tmp_path)
    run_publish(views=1, size=16, spp=2, formats=("glb", "obj"))
    with session_scope(db_url) as s:
        record_grade(s, ids["good"], "acceptable", note="seat a bit dark")
    result = CliRunner().invoke(app, ["gallery", str(tmp_path / "site")])
    assert result.exit_code == 0 and "1 published PhotoShape(s); 1 candidate(s) without a render" in result.output, \
        result.output
    index = tmp_path / "site" / "index.html"
    html = index.read_text()
    assert "tiny chair" in html and "acceptable" in html and "CC-BY-4.0" in html
    pages = sorted((tmp_path / "site" / "pairs").glob("*.html"))
    assert len(pages) == 2  # the broken candidate has its page too, without renders
    good_page = next(p for p in pages if p.name.startswith(f"{ids['good']}-"))
    text = good_page.read_text()
    assert "seat a bit dark" in text and "oak_01" in text and "80.0%" in text and "photoshape.glb" in text
    site = tmp_path / "site"
    assert "<model-viewer" in text and "../assets/model-viewer-umd.min.js" in text  # the 3D view, shipped
    try:
        report = check_pages([good_page, index, site / "candidates.html"], screenshot=tmp_path / "gallery-3d.png",
                             screenshot_selector="model-viewer", evaluate=[VIEWER_LOADED, ENLARGE, CLOSE])
    except ProgramMissing as exc:
        pytest.skip(str(exc))
    assert problems(report) == []  # no console error, no failed or external request (the viewer's too)
    # exemplar, built-in, exemplar view and one turntable view
    assert len(report["pages"][0]["images"]) == 4
    loaded, enlarged, closed = report["pages"][0]["evaluated"]
    assert loaded["loaded"] and loaded["visible"] and loaded["src"].startswith("data:model/gltf-binary"), loaded
    assert enlarged["open"] and enlarged["width"] > 500 and enlarged["src"] == enlarged["clicked"], enlarged
    assert closed is False
    assert (tmp_path / "gallery-3d.png").stat().st_size > 1000
    if os.environ.get("PHOTOSHAPE_DOCS_SCREENSHOT"):  # refresh docs/images/gallery-3d.png
        shutil.copyfile(tmp_path / "gallery-3d.png", os.environ["PHOTOSHAPE_DOCS_SCREENSHOT"])


# wait for the <model-viewer> element's `load` event (or its error), then for the model on screen
VIEWER_LOADED = """new Promise((resolve) => {
  const v = document.querySelector('model-viewer');
  const state = (why) => ({why, loaded: v.loaded, visible: v.modelIsVisible, src: String(v.src).slice(0, 40)});
  const poll = (t0) => (v.modelIsVisible || Date.now() - t0 > 30000)
    ? resolve(state('load')) : setTimeout(() => poll(t0), 100);
  v.addEventListener('error', (e) => resolve(state('error ' + (e.detail && e.detail.type))));
  if (v.loaded) poll(Date.now()); else v.addEventListener('load', () => poll(Date.now()));
  setTimeout(() => resolve(state('timeout')), 60000);
})"""
# click a render: the lightbox opens with that image, large
ENLARGE = """(() => {
  const img = document.querySelectorAll('img.zoom')[2]; img.click();
  const box = document.getElementById('lightbox'), big = box.querySelector('img');
  return {open: box.open, width: big.getBoundingClientRect().width, src: big.src, clicked: img.src};
})()"""
CLOSE = "(document.getElementById('lightbox').click(), document.getElementById('lightbox').open)"


def test_export_command_writes_downloads_and_reports_failures(db_url, store, tmp_path):
    from typer.testing import CliRunner

    from photoshape_flow.cli import app

    ids = seed(db_url, store, tmp_path)
    runner = CliRunner()
    out = tmp_path / "out"
    result = runner.invoke(app, ["export", str(ids["good"]), "--out", str(out), "--format", "glb,obj", "--json"])
    assert result.exit_code == 0, result.output
    folder = out / f"{ids['good']}-{METHOD}-{ids['classifier']}"
    assert (folder / "photoshape.glb").is_file() and (folder / "photoshape.obj").is_file()
    assert json.loads((folder / "assignment.json").read_text())["pair_id"] == ids["good"]
    # every candidate: the broken one is reported, the good one still written
    result = runner.invoke(app, ["export", "--out", str(tmp_path / "all"), "--format", "glb"])
    assert result.exit_code == 1 and "missing" in result.output
    assert "export pairs: 2/2 (100%)" in result.output  # progress (plain lines: the runner is no terminal)
    assert (tmp_path / "all" / folder.name / "photoshape.glb").is_file()
    bad = runner.invoke(app, ["export", "--out", str(out), "--format", "glb,fbx"])
    assert bad.exit_code == 1 and "unknown export format(s) fbx; valid: glb, gltf, xml, obj" in bad.output
    none = runner.invoke(app, ["export", "--out", str(out), "--method", "color-match"])
    assert none.exit_code == 1 and "no candidates" in none.output


def test_commands_default_to_the_collections_publish_method(db_url, store, tmp_path):
    """Without --method, export and gallery show what the collection's last run published (D46)."""
    from typer.testing import CliRunner

    from photoshape_flow.cli import app
    from photoshape_flow.pipeline.runs import published_method
    from photoshape_flow.profiles import resolve_profile

    seed(db_url, store, tmp_path)  # fit rows only
    runner = CliRunner()
    with session_scope(db_url) as s:
        assert published_method(s) == "fit"  # before any run: the default
        record = resolve_profile("tiny", ["publish.method=classifier"]).record()  # as every run records it
        s.add(m.PipelineRun(origin="cli", profile_name="tiny", overrides=record["overrides"],
                            profile=record["profile"], stages=["publish"], status="ok"))
    with session_scope(db_url) as s:
        assert published_method(s) == "classifier"
    result = runner.invoke(app, ["export", "--out", str(tmp_path / "out"), "--format", "glb"])
    assert result.exit_code == 1, result.output
    assert "no candidates for method 'classifier'" in result.output and "photoshape run inference" in result.output
    result = runner.invoke(app, ["gallery", str(tmp_path / "site")])
    assert result.exit_code == 0 and "gallery: 0 published PhotoShape(s); 0 candidate(s)" in result.output


@pytest.mark.render
def test_published_xml_renders_the_gallery_image(db_url, store, tmp_path):
    """The exported Mitsuba XML, reloaded, renders the published exemplar-view image: same framing
    (silhouette IoU), same materials, light and noise (mean absolute error at equal spp and seed)."""
    from photoshape_flow.publish.downloads import export_dir
    from photoshape_flow.publish.publish import run_publish
    from photoshape_flow.render.runtime import ensure_mitsuba
    from photoshape_flow.render.tonemap import composite

    ids = seed(db_url, store, tmp_path)
    mk, good = f"{METHOD}:{ids['classifier']}", ids["good"]
    run_publish(views=0, size=24, spp=4, formats=("xml",))
    row = _renderings(db_url)[("photoshape", f"{good}/{mk}/exemplar")]
    published, coverage = store.load_image(row.blobs["srgb"]), store.load_image(row.blobs["alpha"])
    mi = ensure_mitsuba()
    xml = export_dir(good, mk) / "mitsuba" / "scene.xml"
    image = np.asarray(mi.render(mi.load_file(str(xml))))  # Mitsuba's defaults: the XML's film, spp and seed
    _, srgb = composite(image[..., :3], image[..., 3], "white")
    ours, theirs = np.asarray(coverage) > 127, image[..., 3] > 0.5
    assert theirs.mean() > 0.1  # the shape is in view
    assert (ours & theirs).sum() / (ours | theirs).sum() >= 0.99
    assert np.abs(srgb.astype(np.float32) - published.astype(np.float32)).mean() <= 2.0
    assert 'value="24"' in xml.read_text() and row.params["camera"]["fov"] < 50.0  # framed, not the pair's fov
    # `photoshape export` on demand writes the same scene: the published render's framing, film and seed
    from typer.testing import CliRunner

    from photoshape_flow.cli import app

    result = CliRunner().invoke(app, ["export", str(good), "--out", str(tmp_path / "out"), "--format", "xml"])
    assert result.exit_code == 0, result.output
    again = tmp_path / "out" / f"{good}-{mk.replace(':', '-')}" / "mitsuba" / "scene.xml"
    assert again.read_text() == xml.read_text()


def _rerank_with_a_new_classifier(url: str, pair_id: int) -> int:
    """A newer classifier's rank-1 rows for `pair_id` (other materials): returns its id."""
    with session_scope(url) as s:
        classifier = m.Classifier(name="clf-2", kind="material", architecture="resnet34")
        s.add(classifier)
        s.flush()
        old = s.execute(sa.select(m.Assignment).where(m.Assignment.pair_id == pair_id, m.Assignment.rank == 1)
                        .order_by(m.Assignment.part_id)).scalars().all()
        materials = [a.material_id for a in old][::-1]  # swapped: another PhotoShape of the same pair
        for a, material_id in zip(old, materials, strict=True):
            s.add(m.Assignment(pair_id=pair_id, part_id=a.part_id, method=METHOD, classifier_id=classifier.id,
                               method_key=f"{METHOD}:{classifier.id}", rank=1, material_id=material_id,
                               score=0.5, substance=a.substance))
        return classifier.id


def test_grade_belongs_to_the_photoshape_it_was_given_to(db_url, store, tmp_path):
    """A new classifier's PhotoShape of a graded pair shows ungraded; the old grade stays, with its key."""
    from typer.testing import CliRunner

    from photoshape_flow.cli import app
    from photoshape_flow.publish.photoshapes import assignment_set_keys

    ids = seed(db_url, store, tmp_path)
    good, old_key = ids["good"], f"{METHOD}:{ids['classifier']}"
    runner = CliRunner()
    result = runner.invoke(app, ["grade", str(good), "wrong_color", "--note", "seat too red"])
    assert result.exit_code == 0 and f"pair {good} ({old_key}): graded wrong_color" in result.output, result.output
    new_key = f"{METHOD}:{_rerank_with_a_new_classifier(db_url, good)}"

    result = runner.invoke(app, ["gallery", str(tmp_path / "site")])
    assert result.exit_code == 0 and "gallery candidates: 2/2 (100%)" in result.output, result.output
    page = (tmp_path / "site" / "pairs" / f"{good}-{new_key.replace(':', '-')}.html").read_text()
    assert "ungraded" in page and "seat too red" not in page and "wrong_color</span>" not in page
    with session_scope(db_url) as s:
        rows = s.execute(sa.select(m.Grade.pair_id, m.Grade.method_key, m.Grade.assignment_set, m.Grade.label)).all()
        shown = assignment_set_keys(s, [(good, old_key)])[(good, old_key)]
    assert [tuple(r) for r in rows] == [(good, old_key, shown, "wrong_color")]  # still there, with its key
    # the old PhotoShape still carries its grade; grading the new one adds a row instead of replacing it
    result = runner.invoke(app, ["gallery", str(tmp_path / "old"), "--method", old_key])
    assert "seat too red" in (tmp_path / "old" / "pairs" / f"{good}-{old_key.replace(':', '-')}.html").read_text()
    assert runner.invoke(app, ["grade", str(good), "good"]).exit_code == 0
    with session_scope(db_url) as s:
        labels = s.execute(sa.select(m.Grade.method_key, m.Grade.label).order_by(m.Grade.id)).all()
    assert [tuple(r) for r in labels] == [(old_key, "wrong_color"), (new_key, "good")]


@pytest.mark.render
def test_gallery_opens_on_published_photoshapes_and_publishes_on_demand(db_url, store, tmp_path):
    """index.html lists rendered PhotoShapes; the others wait on candidates.html, photo beside a built-in
    render, with the command that renders them, and `photoshape run publish --pair N` (whatever the
    pair's rank) does."""
    from typer.testing import CliRunner

    from photoshape_flow.cli import app

    ids = seed(db_url, store, tmp_path)
    good, mk = ids["good"], f"{METHOD}:{ids['classifier']}"
    with session_scope(db_url) as s:
        s.get(m.Pair, good).rank = 40  # beyond any profile's max_rank: only --pair publishes it
    runner = CliRunner()
    site = get_settings_data_root() / "gallery"
    small = ["--set", "publish.views=0", "--set", "publish.size=16", "--set", "publish.spp=2",
             "--set", "publish.formats=glb"]
    result = runner.invoke(app, ["run", "publish", *small])
    assert result.exit_code == 0, result.output
    index, candidates = (site / "index.html").read_text(), (site / "candidates.html").read_text()
    assert f'data-pair="{good}"' not in index and "No published PhotoShapes yet" in index
    assert f"photoshape run publish --pair {good}" in candidates
    # a waiting candidate still shows its shape beside the photo: a built-in render at thumbnail size
    waiting = _renderings(db_url)[("builtin", f"{good}/exemplar")]
    assert waiting.status == "ok" and waiting.params["size"] == 128
    assert f'alt="built-in materials {good}"' in candidates
    again = runner.invoke(app, ["run", "publish", *small])  # up to date: not rendered again
    assert again.exit_code == 0 and _renderings(db_url)[("builtin", f"{good}/exemplar")].updated_at == \
        waiting.updated_at

    result = runner.invoke(app, ["run", "publish", "--pair", str(good), "--pair", "999", *small])
    assert result.exit_code == 0, result.output
    assert "pair 999: not a PhotoShape candidate" in result.output and "pairs published" in result.output
    index, candidates = (site / "index.html").read_text(), (site / "candidates.html").read_text()
    assert f'data-pair="{good}"' in index and "img/" in index and "1 more candidate without a render" in index
    assert f"--pair {good}" not in candidates and f"--pair {ids['broken']}" in candidates
    assert _renderings(db_url)[("photoshape", f"{good}/{mk}/exemplar")].status == "ok"
    bad = runner.invoke(app, ["run", "coarse-alignment", "--pair", str(good)])
    assert bad.exit_code == 1 and "--pair applies to the publish stage only" in bad.output
    none = runner.invoke(app, ["run", "publish", "--pair", "999"])
    assert none.exit_code == 1 and "no pair to publish" in none.output


def get_settings_data_root() -> Path:
    from photoshape_flow.config import get_settings

    return get_settings().data_root


@pytest.mark.render
def test_publish_renders_and_exports_the_refined_look_with_a_before_after(db_url, store, tmp_path):
    """A refined rank-1 row: publish renders the refined materials, the unrefined ones once more for the
    gallery's before/after, and the exports carry the refinement (the XML renders the published image)."""
    from photoshape_flow.publish.downloads import export_dir
    from photoshape_flow.publish.gallery_site import write_gallery_site
    from photoshape_flow.publish.photoshapes import UNREFINED_VIEW, assignment_set_keys
    from photoshape_flow.publish.publish import run_publish
    from photoshape_flow.render.runtime import ensure_mitsuba
    from photoshape_flow.render.tonemap import composite

    ids = seed(db_url, store, tmp_path)
    mk, good = f"{METHOD}:{ids['classifier']}", ids["good"]
    with session_scope(db_url) as s:
        before_key = assignment_set_keys(s, [(good, mk)])[(good, mk)]
        row = s.execute(sa.select(m.Assignment).where(m.Assignment.pair_id == good, m.Assignment.rank == 1)
                        .order_by(m.Assignment.part_id)).scalars().first()
        row.refinement = {"tint": [1.5, 0.6, 0.4], "roughness_scale": 0.6, "uv_scale": 1.4, "uv_rotation": 0.785398,
                          "loss_before": 0.2, "loss_after": 0.05}
    with session_scope(db_url) as s:
        assert assignment_set_keys(s, [(good, mk)])[(good, mk)] != before_key  # another look, another set
    run_publish(views=0, size=24, spp=4, formats=("glb", "xml"), pair_ids=[good])
    renders = _renderings(db_url)
    after = renders[("photoshape", f"{good}/{mk}/exemplar")]
    before = renders[("photoshape", f"{good}/{mk}/{UNREFINED_VIEW}")]
    published = store.load_image(after.blobs["srgb"]).astype(np.float32)
    assert np.abs(published - store.load_image(before.blobs["srgb"]).astype(np.float32)).max() > 30
    folder = export_dir(good, mk)
    doc = json.loads((folder / "assignment.json").read_text())
    assert doc["parts"][0]["extra"]["refinement"]["uv_scale"] == 1.4
    glb = (folder / "photoshape.glb").read_bytes()
    assert b"KHR_texture_transform" in glb and b"extensionsUsed" in glb
    image = np.asarray(ensure_mitsuba().render(ensure_mitsuba().load_file(str(folder / "mitsuba" / "scene.xml"))))
    _, srgb = composite(image[..., :3], image[..., 3], "white")
    assert np.abs(srgb.astype(np.float32) - published).mean() <= 2.0
    site = write_gallery_site(tmp_path / "site")
    page = next((tmp_path / "site" / "pairs").glob(f"{good}-*.html")).read_text()
    assert site.published == 1 and "before refinement" in page and "after refinement" in page
    assert "tint 1.50 0.60 0.40" in page and UNREFINED_VIEW not in page  # not listed as a view of its own


@pytest.mark.render
def test_documented_published_query_is_the_gallerys_index_with_its_grades_and_scores(db_url, store, tmp_path):
    """docs/data-model.md's first example, on what the real publish stage wrote: exactly the PhotoShapes
    the gallery lists as published, by name, with the grade and Score the gallery shows; another
    method's PhotoShape of the same pair (the classifier's, unpublished) stays out."""
    from tests.db.test_data_model_doc import published_query

    from photoshape_flow.config import get_settings
    from photoshape_flow.publish.gallery_site import gallery_data
    from photoshape_flow.publish.grading import record_grade
    from photoshape_flow.publish.publish import run_publish
    from photoshape_flow.store import BlobStore

    ids = seed(db_url, store, tmp_path)
    run_publish(views=0, size=16, spp=2, formats=("glb",))
    with session_scope(db_url) as s:
        fit_rows = s.execute(sa.select(m.Assignment).where(m.Assignment.pair_id == ids["good"],
                                                           m.Assignment.rank == 1)).scalars().all()
        for row in fit_rows:  # the classifier's own ranking of the good pair: never published
            s.add(m.Assignment(pair_id=row.pair_id, part_id=row.part_id, method="classifier",
                               classifier_id=row.classifier_id, method_key=f"classifier:{row.classifier_id}",
                               rank=1, material_id=row.material_id, score=0.01, posterior=0.99))
        fit_rows[1].unobserved = True  # the Score counts the parts seen in the photo
        s.flush()
        record_grade(s, ids["good"], "wrong_color", grader="bob")
        record_grade(s, ids["good"], "good", grader="user")  # the newest grade wins
        rows = s.execute(sa.text(published_query())).all()
        entries, _ = gallery_data(s, BlobStore(get_settings().blob_root))
    published = [e for e in entries if e.published]
    assert [(r.pair_id, r.shape_name, r.exemplar_name, r.method_key, r.grade) for r in rows] == [
        (e.pair_id, e.shape_name, e.exemplar_name, e.method_key, e.grade) for e in published]
    assert [(r.pair_id, r.shape_name, r.exemplar_name, r.grade) for r in rows] == [
        (ids["good"], "tiny chair", "photo good", "good")]
    assert [r.score for r in rows] == [pytest.approx(e.score) for e in published] == [pytest.approx(0.8)]
    assert len(entries) == 2  # the broken pair is a candidate, not published
    from photoshape_flow.flows.artifacts import candidate_rows

    table = candidate_rows(method="fit")  # the flows' candidates artifact: names, score, published, grade
    assert [(r["shape_name"], r["exemplar_name"], r["published"], r["grade"], r["score"]) for r in table] == [
        ("tiny chair", "photo good", True, "good", 0.8), ("tiny chair", "photo broken", False, None, 0.7)]
