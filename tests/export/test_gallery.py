"""The static gallery: every page loads in headless Chromium with all images and no errors, and sorts."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
from tests.export.tiny import write_png

from photoshape_flow.export.gallery import GalleryEntry, GalleryMaterial, GalleryPart, write_gallery


def _entries(tmp_path: Path) -> tuple[list[GalleryEntry], list[GalleryMaterial]]:
    rng = np.random.default_rng(1)
    img = tmp_path / "src"
    img.mkdir()
    export = tmp_path / "export"
    (export / "mitsuba" / "meshes").mkdir(parents=True)
    (export / "mitsuba" / "textures").mkdir()
    (export / "mitsuba" / "scene.xml").write_text("<scene/>")
    (export / "mitsuba" / "meshes" / "part_0001.ply").write_bytes(b"ply\n")
    write_png(export / "mitsuba" / "textures" / "oak.png", rng.integers(0, 255, (16, 16, 3), np.uint8))
    (export / "photoshape.glb").write_bytes(b"glTF")
    (export / "assignment.json").write_text("{}")
    entries = []
    for pair_id, score, hog, grade in ((1, 0.4, 9.0, "wrong_color"), (2, 0.9, 12.0, "good"), (3, 0.7, 8.5, None)):
        renders = [(view, write_png(img / f"{pair_id}-{view}.png", rng.integers(0, 255, (24, 24, 3), np.uint8)))
                   for view in ("exemplar", "turntable-00")]
        entries.append(GalleryEntry(
            pair_id=pair_id, method_key="classifier:1", shape_name=f"chair <{pair_id}>", exemplar_name="photo & co",
            parts=[GalleryPart(1, "seat", 10, "oak_01", "wood", score),
                   GalleryPart(2, "leg", None, None, "metal", None, unobserved=True)],
            exemplar_image=write_png(img / f"ex{pair_id}.png", rng.integers(0, 255, (32, 32, 3), np.uint8)),
            builtin_image=write_png(img / f"b{pair_id}.png", rng.integers(0, 255, (24, 24, 3), np.uint8)),
            renders=renders, hog_distance=hog, alignment_iou=0.5 + pair_id / 10, grade=grade,
            grade_note="too dark" if grade == "wrong_color" else None,
            downloads={"glb": export / "photoshape.glb", "xml": export / "mitsuba" / "scene.xml",
                       "assignment": export / "assignment.json"},
            licenses=[{"role": "shape", "name": "chair", "license": "CC-BY-4.0", "attribution": "someone",
                       "source_url": "https://example.org/chair"}],
        ))
    materials = [GalleryMaterial(10, "oak_01", "wood", preview=renders[0][1], license="CC0-1.0")]
    return entries, materials


def test_gallery_files_and_escaping(tmp_path):
    entries, materials = _entries(tmp_path)
    index = write_gallery(tmp_path / "site", entries, materials)
    text = index.read_text()
    assert "chair &lt;2&gt;" in text and "<2>" not in text  # names are escaped
    assert "http" not in text.replace("https://example.org", "")  # no CDN
    page = (tmp_path / "site" / "pairs" / "2-classifier-1.html").read_text()
    assert "90.0%" in page and "built-in" in page and "CC-BY-4.0" in page
    with zipfile.ZipFile(tmp_path / "site" / "downloads" / "2-classifier-1" / "xml.zip") as zf:
        assert sorted(zf.namelist()) == ["xml/meshes/part_0001.ply", "xml/scene.xml", "xml/textures/oak.png"]
        # text deflated; an image its codec already compressed stored as it is, byte for byte
        kinds = {info.filename: info.compress_type for info in zf.infolist()}
        assert kinds["xml/scene.xml"] == zipfile.ZIP_DEFLATED and kinds["xml/textures/oak.png"] == zipfile.ZIP_STORED
        texture = tmp_path / "export" / "mitsuba" / "textures" / "oak.png"
        assert zf.read("xml/textures/oak.png") == texture.read_bytes()


@pytest.mark.browser
def test_gallery_loads_in_chromium_and_sorts(tmp_path):
    from photoshape_flow.export.browser import check_pages, problems
    from photoshape_flow.export.node_tools import ProgramMissing

    entries, materials = _entries(tmp_path)
    index = write_gallery(tmp_path / "site", entries, materials)
    pages = [index, *sorted((tmp_path / "site" / "pairs").glob("*.html")), tmp_path / "site" / "materials.html"]
    order = "Array.from(document.querySelectorAll('#photoshapes tbody tr'), r => r.dataset.pair).join(',')"
    click = "document.querySelector('th[data-key=\"hog\"]').click()"
    filtered = "(document.getElementById('grade-filter').value='good', " \
               "document.getElementById('grade-filter').dispatchEvent(new Event('change')), " \
               "document.getElementById('count').textContent)"
    # the ungraded ones, from disk too; and no grade button on a page opened from disk (read-only)
    ungraded = "(document.getElementById('grade-filter').value='ungraded', " \
               "document.getElementById('grade-filter').dispatchEvent(new Event('change')), " \
               "Array.from(document.querySelectorAll('#photoshapes tbody tr:not([hidden])'), r => r.dataset.pair)" \
               ".join(',') + ' ' + document.querySelectorAll('button, #review').length)"
    try:
        report = check_pages(pages, screenshot=tmp_path / "gallery.png",
                             evaluate=[order, click, order, click, order, filtered, ungraded])
    except ProgramMissing as exc:
        pytest.skip(str(exc))
    assert problems(report) == []
    first = report["pages"][0]
    assert first["title"] == "PhotoShapes"
    assert len(first["images"]) == 6 and all(i["natural_width"] == 24 or i["natural_width"] == 32
                                             for i in first["images"])
    pair_images = sum(len(p["images"]) for p in report["pages"][1:4])
    assert pair_images == 3 * 4  # exemplar, built-in and two renders per pair page
    by_score, _, by_hog_asc, _, by_hog_desc, good_count, ungraded_rows = first["evaluated"]
    assert by_score == "2,3,1"  # initial order: best score first
    assert by_hog_asc == "3,1,2" and by_hog_desc == "2,1,3"
    assert good_count == "1"
    assert ungraded_rows == "3 0"  # pair 3 alone has no grade; no button
    assert (tmp_path / "gallery.png").stat().st_size > 1000


HOSTILE_URLS = ("javascript:alert(document.domain)", " JaVaScRiPt:alert(1)", "java\nscript:alert(1)",
                "data:text/html,<script>alert(1)</script>", "vbscript:msgbox(1)", "//evil.example/x", "file:///etc/passwd")


def test_gallery_links_only_web_urls_and_escapes_text(tmp_path):
    """Security: a hostile source_url is shown as text, never a link; names and texts are escaped."""
    entries, _ = _entries(tmp_path)
    entry = entries[0]
    entry.shape_name = 'chair"><script>alert("shape")</script>'
    entry.grade_note = "<img src=x onerror=alert(1)>"
    entry.grader = "me\u202egnp.exe"
    entry.licenses = [
        {"role": "material", "name": f"<b>m{i}</b>", "license": "CC0<i>", "attribution": "a\nb<script>",
         "source_url": url} for i, url in enumerate(HOSTILE_URLS)
    ] + [{"role": "shape", "name": "ok", "license": "CC0-1.0", "source_url": "https://example.org/ok?a=1&b=2"}]
    materials = [GalleryMaterial(10 + i, f"m{i}<svg onload=alert(1)>", "wood", license="CC0-1.0",
                                 attribution='x" onmouseover="alert(1)', source_url=url)
                 for i, url in enumerate(HOSTILE_URLS)]
    write_gallery(tmp_path / "site", entries, materials)
    site = tmp_path / "site"
    pages = {p.relative_to(site).as_posix(): p.read_text() for p in site.rglob("*.html")}
    for name, text in pages.items():
        lowered = text.lower()
        for scheme in ("javascript:", "data:text", "vbscript:", "file:", "//evil"):
            assert f'href="{scheme}' not in lowered and f"href=\" {scheme}" not in lowered, (name, scheme)
        assert "<script>alert" not in lowered and "<img src=x" not in lowered and "<svg" not in lowered, name
        assert "onmouseover=\"alert" not in lowered and "\u202e" not in text, name
    pair, materials_page = pages["pairs/1-classifier-1.html"], pages["materials.html"]
    assert pair.count("javascript:alert(document.domain)") == 1  # shown, as text
    assert '<a href="https://example.org/ok?a=1&amp;b=2" rel="noreferrer noopener">source</a>' in pair
    assert pair.count(">source</a>") == 1 and ">source</a>" not in materials_page  # the only http(s) URL
    assert "&lt;script&gt;alert(&#34;shape&#34;)&lt;/script&gt;" in pages["index.html"]
    assert "&lt;img src=x onerror=alert(1)&gt;" in pair and "me\\u202egnp.exe" in pair
    assert "m0&lt;svg onload=alert(1)&gt;" in materials_page and "x&#34; onmouseover=&#34;alert(1)" in materials_page


def test_a_part_shows_its_posterior_not_the_raw_score(tmp_path):
    """The raw score (a product of experts, 0.03) means nothing to a reader; the posterior (0.82) does."""
    part = GalleryPart(1, "seat", 10, "oak_01", "wood", 0.03, posterior=0.82)
    baseline = GalleryPart(2, "leg", 11, "steel", "metal", 0.4)  # baselines have no posterior: their score
    entry = GalleryEntry(pair_id=1, method_key="classifier:1", shape_name="c", exemplar_name="e",
                         parts=[part, baseline])
    assert part.confidence == 0.82 and baseline.confidence == 0.4 and entry.score == pytest.approx(0.61)
    write_gallery(tmp_path / "site", [entry], [])
    page = (tmp_path / "site" / "pairs" / "1-classifier-1.html").read_text()
    assert "82.0%" in page and "40.0%" in page and "3.0%" not in page


def _minimal_glb(path: Path) -> Path:
    """A whole GLB (header, one JSON chunk): enough for the gallery to ship it to the 3D view."""
    chunk = b'{"asset":{"version":"2.0"}}'
    chunk += b" " * (-len(chunk) % 4)
    body = len(chunk).to_bytes(4, "little") + b"JSON" + chunk
    path.write_bytes(b"glTF" + (2).to_bytes(4, "little") + (12 + len(body)).to_bytes(4, "little") + body)
    return path


def test_gallery_ships_the_3d_viewer_and_requests_nothing_outside(tmp_path):
    """The 3D view works offline: the viewer (model-viewer, Apache-2.0) and the GLB are in the site's folder,
    and no page or script of ours names an external URL (the only http(s) link is a licence's source)."""
    import re

    from photoshape_flow.export.gallery import VIEWER_ASSET, VIEWER_LICENSE, VIEWER_PACKAGE
    from photoshape_flow.export.node_tools import ProgramMissing, require_package

    try:
        require_package("@google/model-viewer")  # npm ci installs it (a set-up error where node is there)
    except ProgramMissing as exc:
        pytest.skip(str(exc))
    entries, materials = _entries(tmp_path)
    entries[1].downloads["glb"] = _minimal_glb(tmp_path / "export" / "real.glb")
    write_gallery(tmp_path / "site", entries, materials)
    site = tmp_path / "site"
    shipped = site / VIEWER_ASSET
    assert shipped.read_bytes() == (VIEWER_PACKAGE / "dist" / "model-viewer-umd.min.js").read_bytes()
    assert "Apache License" in (site / VIEWER_LICENSE).read_text()
    assert '"version": "4.4.0"' in (VIEWER_PACKAGE / "package.json").read_text()
    page = (site / "pairs" / "2-classifier-1.html").read_text()
    assert '<model-viewer id="viewer"' in page and f'<script src="../{VIEWER_ASSET}"></script>' in page
    model = re.search(r'<script src="\.\./(models/[0-9a-f]+\.js)"></script>', page)
    assert model and (site / model.group(1)).read_text().startswith(
        'window.photoshapeModel="data:model/gltf-binary;base64,Z2xURg')
    assert "<model-viewer" not in (site / "pairs" / "1-classifier-1.html").read_text()  # no whole GLB: no view
    assert re.search(r'<td class="num">\d+ B</td>', page)  # downloads with their sizes
    for path in site.rglob("*"):
        if path.suffix in (".html", ".js", ".css") and path != shipped:
            text = path.read_text().replace('href="https://example.org/chair"', "")
            assert not re.search(r"(https?:)?//[a-z0-9]", text, re.I), path  # nothing loads from elsewhere
            assert not re.search(r'(src|href)="(?!\.\./|[a-z]+/|[a-z0-9_-]+\.html|#|data:,")', text), path
