"""A static HTML gallery of PhotoShapes: browse, sort by quality, download, see licences and grades.

Pure function of `GalleryEntry` values (the pipeline gathers them from the database): `write_gallery`
copies the images and downloads into the output folder and writes plain HTML with inline CSS and JS,
so the site opens from disk or any static host and makes no request outside its own folder. The pages
come from the Jinja2 templates in ``export/templates/`` (`export.templating`: autoescaped, one line
per value, links only to http(s) URLs), since every name and licence shown is someone else's text.

Layout::

    index.html              the published PhotoShapes (those with a render), sortable by score, HOG
                            distance, alignment IoU, grade
    candidates.html         the candidates without a render yet, each with the command that renders it
    pairs/<slug>.html       3D view of the GLB, exemplar, built-in render, PhotoShape renders (click to
                            enlarge), parts, downloads with sizes, licences
    materials.html          the materials used, with substance, licence and how often they were chosen
    img/                    images, named by content hash
    models/<hash>.js        each GLB as a data: URL in a classic script, so the 3D view loads from disk
                            too (a file:// page may not fetch(), but may load a script)
    assets/                 the 3D viewer, @google/model-viewer (Apache-2.0; its UMD build, which a
                            file:// page can load, unlike a module script) with its LICENSE
    downloads/<slug>/       single-file formats and assignment.json as they are, zips of the others

The viewer is copied from ``export/node/node_modules`` (`npm ci`, pinned in package-lock.json); where
it is not installed the pages show the renders without the 3D view.
"""

from __future__ import annotations

import base64
import hashlib
import math
import shutil
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from photoshape_flow.export.bundle import format_files
from photoshape_flow.export.formats import EXPORTERS, SIDECAR, SIDECAR_PATH
from photoshape_flow.export.node_tools import NODE_DIR
from photoshape_flow.export.templating import render
from photoshape_flow.faults import fault_point

INDEX_PAGE, CANDIDATES_PAGE = "index.html", "candidates.html"
# the 3D viewer shipped with the site (`npm ci` installs it; pinned in export/node/package-lock.json)
VIEWER_PACKAGE = NODE_DIR / "node_modules" / "@google" / "model-viewer"
VIEWER_ASSET, VIEWER_LICENSE = "assets/model-viewer-umd.min.js", "assets/model-viewer.LICENSE.txt"

GRADE_ORDER: dict[str, int] = {
    "good": 0, "acceptable": 1, "not_sure": 2, "limitation": 3, "wrong_ambiguous": 4, "wrong_color": 5,
    "wrong_material": 6, "under_segmented": 7, "over_segmented": 8, "wrong_alignment": 9, "bad_shape": 10,
    "bad_exemplar": 11,
}
# format -> link text, in the order the pair page lists them; a multi-file format is offered as a zip
DOWNLOAD_LABELS: dict[str, str] = {
    **{name: f"{e.description} ({Path(e.path).suffix if e.single_file else '.zip'})" for name, e in EXPORTERS.items()},
    SIDECAR: SIDECAR_PATH,
}


@dataclass
class GalleryPart:
    index: int
    name: str
    material_id: int | None
    material_name: str | None
    substance: str | None
    score: float | None
    unobserved: bool = False
    posterior: float | None = None  # the ranking's posterior (ours); None for the baselines
    refinement: Mapping[str, Any] | None = None  # `fit.refine`'s parameters and loss, where refined

    @property
    def refinement_text(self) -> str:
        """The refinement in a few words (tint, roughness, UV; loss before -> after), or ""."""
        r = self.refinement
        if not r:
            return ""
        tint = " ".join(f"{float(t):.2f}" for t in r.get("tint", ()))
        return (f"tint {tint}, roughness x{float(r.get('roughness_scale', 1)):.2f}, "
                f"UV x{float(r.get('uv_scale', 1)):.2f} @ {math.degrees(float(r.get('uv_rotation', 0))):.0f} deg, "
                f"loss {float(r.get('loss_before', 0)):.4f} -> {float(r.get('loss_after', 0)):.4f}")

    @property
    def confidence(self) -> float | None:
        """What the gallery shows as the part's confidence: the posterior, else the method's own score."""
        return self.posterior if self.posterior is not None else self.score


@dataclass
class GalleryEntry:
    """One PhotoShape candidate as the gallery shows it."""

    pair_id: int
    method_key: str
    shape_name: str
    exemplar_name: str
    parts: list[GalleryPart]
    exemplar_image: Path | None = None
    builtin_image: Path | None = None
    unrefined_image: Path | None = None  # the exemplar view with the winners before refinement (`fit.refine`)
    renders: list[tuple[str, Path]] = field(default_factory=list)  # (view, image), exemplar view first
    hog_distance: float | None = None
    alignment_iou: float | None = None
    grade: str | None = None
    grade_note: str | None = None
    grader: str | None = None
    downloads: dict[str, Path] = field(default_factory=dict)  # format -> file (or folder: zipped)
    licenses: list[Mapping[str, Any]] = field(default_factory=list)  # role, name, license, attribution, url
    assignment_set: str | None = None  # the assignment-set key the renders show (publish records it)

    @property
    def slug(self) -> str:
        key = "".join(c if c.isalnum() or c in "-_" else "-" for c in self.method_key)
        return f"{self.pair_id}-{key}"

    @property
    def published(self) -> bool:
        """Rendered: the gallery lists it on its index (the others wait on the candidates page)."""
        return bool(self.renders)

    @property
    def publish_command(self) -> str:
        """The command that renders and exports this candidate on demand."""
        return f"photoshape run publish --pair {self.pair_id}"

    @property
    def score(self) -> float | None:
        """Mean rank-1 confidence (posterior) over the parts seen in the exemplar (all parts when none was)."""
        seen = [p.confidence for p in self.parts if p.confidence is not None and not p.unobserved]
        values = seen or [p.confidence for p in self.parts if p.confidence is not None]
        return sum(values) / len(values) if values else None

    @property
    def license_summary(self) -> list[str]:
        """Distinct licences, plus "unknown" when any item has none recorded."""
        known = sorted({str(x["license"]) for x in self.licenses if x.get("license")})
        return known + (["unknown"] if any(not x.get("license") for x in self.licenses) else [])


@dataclass
class GalleryMaterial:
    id: int
    name: str
    substance: str | None
    preview: Path | None = None
    license: str | None = None
    attribution: str | None = None
    source_url: str | None = None


class _Assets:
    """Copies files into the site once each, named by content hash."""

    def __init__(self, root: Path):
        self.root = root
        self.copied: dict[Path, str] = {}

    def image(self, source: Path | None) -> str | None:
        if source is None or not Path(source).is_file():
            return None
        source = Path(source)
        if source not in self.copied:
            digest = hashlib.sha256(source.read_bytes()).hexdigest()[:20]
            rel = f"img/{digest}{source.suffix.lower() or '.png'}"
            target = self.root / rel
            if not target.exists():
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(source, target)
            self.copied[source] = rel
        return self.copied[source]


def human_size(size: int) -> str:
    """A file size as people read it: 812 B, 14.2 KB, 3.1 MB (powers of 1000)."""
    value = float(size)
    for unit in ("B", "KB", "MB", "GB"):
        if value < 1000 or unit == "GB":
            return f"{int(value)} {unit}" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1000
    raise AssertionError("unreachable")


def copy_viewer(root: Path) -> str | None:
    """Copy the 3D viewer and its licence into the site; its site path, or None where not installed."""
    source = VIEWER_PACKAGE / "dist" / "model-viewer-umd.min.js"
    if not source.is_file():
        return None
    for rel, path in ((VIEWER_ASSET, source), (VIEWER_LICENSE, VIEWER_PACKAGE / "LICENSE")):
        if path.is_file():
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, root / rel)
    return VIEWER_ASSET


def _model_script(root: Path, glb: Path | None) -> str | None:
    """`models/<hash>.js`: the GLB as a data: URL in a classic script (``window.photoshapeModel``)."""
    if glb is None or not Path(glb).is_file():
        return None
    data = Path(glb).read_bytes()
    if len(data) < 20 or data[:4] != b"glTF" or int.from_bytes(data[8:12], "little") != len(data):
        return None  # not a whole GLB (magic, then its length in the header)
    rel = f"models/{hashlib.sha256(data).hexdigest()[:20]}.js"
    target = root / rel
    if not target.exists():
        target.parent.mkdir(parents=True, exist_ok=True)
        encoded = base64.b64encode(data).decode("ascii")  # base64: nothing that can end the string
        target.write_text(f'window.photoshapeModel="data:model/gltf-binary;base64,{encoded}";\n', encoding="ascii")
    return rel


# members stored as they are: their own codecs already compressed them (deflate gains under 10%
# on EXR, nothing on PNG, JPEG or GLB textures, and took most of a gallery rewrite's time)
STORED_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".exr", ".glb", ".ktx2", ".webp"})


def _download(root: Path, slug: str, fmt: str, source: Path) -> str | None:
    """Copy a single-file download, or zip what a multi-file format needs (`bundle.format_files`);
    returns the site path."""
    source = Path(source)
    folder = root / "downloads" / slug
    folder.mkdir(parents=True, exist_ok=True)
    if (fmt == SIDECAR or EXPORTERS[fmt].single_file) and source.is_file():
        shutil.copyfile(source, folder / source.name)
        return f"downloads/{slug}/{source.name}"
    files = format_files(source, fmt)
    if not files:
        return None
    archive = folder / f"{fmt}.zip"
    with zipfile.ZipFile(archive, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for path, name in files:
            stored = Path(path).suffix.lower() in STORED_SUFFIXES
            zf.write(path, name, compress_type=zipfile.ZIP_STORED if stored else zipfile.ZIP_DEFLATED)
    return f"downloads/{slug}/{archive.name}"


def write_gallery(
    out_dir: str | Path,
    entries: Sequence[GalleryEntry],
    materials: Sequence[GalleryMaterial] = (),
    *,
    title: str = "PhotoShapes",
) -> Path:
    """Write the site into `out_dir` (created; existing files are overwritten); returns index.html.

    The index lists the published PhotoShapes, so the gallery opens on renders rather than on rows
    of blanks (only each shape's best pairs are published); every other candidate is on
    candidates.html with the command that publishes it.
    """
    root = Path(out_dir)
    (root / "pairs").mkdir(parents=True, exist_ok=True)
    assets = _Assets(root)
    viewer = copy_viewer(root)
    rows: list[dict[str, Any]] = []
    usage: dict[int, int] = {}
    for entry in entries:
        for part in entry.parts:
            if part.material_id is not None:
                usage[part.material_id] = usage.get(part.material_id, 0) + 1
        _write_pair_page(root, entry, assets, viewer)
        rows.append({
            "entry": entry,
            "thumb": assets.image(entry.renders[0][1]) if entry.renders else None,
            "exemplar": assets.image(entry.exemplar_image),
            "builtin": assets.image(entry.builtin_image),
            "grade_rank": GRADE_ORDER.get(entry.grade or "", 99),
        })
    published = [row for row in rows if row["entry"].published]
    waiting = [row for row in rows if not row["entry"].published]
    pages = {INDEX_PAGE: ("gallery_index.html", title, published),
             CANDIDATES_PAGE: ("gallery_candidates.html", f"{title}: candidates without a render", waiting)}
    for name, (template, page_title, page_rows) in pages.items():
        page = render(template, title=page_title, root="", rows=page_rows, grades=list(GRADE_ORDER),
                      published=len(published), waiting=len(waiting))
        (root / name).write_text(page, encoding="utf-8")
    _write_materials_page(root, materials, usage, assets)
    return root / INDEX_PAGE


def _write_pair_page(root: Path, entry: GalleryEntry, assets: _Assets, viewer: str | None = None) -> None:
    images = [(entry.exemplar_image, "exemplar photo"), (entry.builtin_image, "built-in materials"),
              *((path, f"PhotoShape, {view} view") for view, path in entry.renders)]
    figures = [(src, caption) for path, caption in images if (src := assets.image(path)) is not None]
    downloads = [
        (href, label, human_size((root / href).stat().st_size)) for fmt, label in DOWNLOAD_LABELS.items()
        if fmt in entry.downloads and (href := _download(root, entry.slug, fmt, entry.downloads[fmt]))
    ]
    model = _model_script(root, entry.downloads.get("glb")) if viewer else None
    after = dict(entry.renders).get("exemplar")
    before_after = [(src, caption) for path, caption in (
        (entry.exemplar_image, "exemplar photo"), (entry.unrefined_image, "before refinement"),
        (after, "after refinement")) if (src := assets.image(path)) is not None] if entry.unrefined_image else []
    page = render("gallery_pair.html", title=f"PhotoShape {entry.pair_id}: {entry.shape_name}", root="../",
                  e=entry, figures=figures, downloads=downloads, before_after=before_after,
                  viewer=viewer if model else None, model=model)
    (root / "pairs" / f"{entry.slug}.html").write_text(page, encoding="utf-8")
    fault_point("gallery-writing")


def _write_materials_page(
    root: Path, materials: Sequence[GalleryMaterial], usage: Mapping[int, int], assets: _Assets
) -> None:
    rows = [{"material": m, "preview": assets.image(m.preview), "used": usage.get(m.id, 0)}
            for m in sorted(materials, key=lambda m: (-usage.get(m.id, 0), m.name))]
    (root / "materials.html").write_text(render("gallery_materials.html", title="Materials", root="", rows=rows),
                                          encoding="utf-8")
