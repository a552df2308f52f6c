"""A static HTML gallery of PhotoShapes: browse, sort by quality, download, see licences and grades.

Pure function of `GalleryEntry` values (the pipeline gathers them from the database): `write_gallery`
copies the images and downloads into the output folder and writes plain HTML with inline CSS and JS,
so the site opens from disk or any static host and makes no request outside its own folder.

Layout::

    index.html              every PhotoShape, sortable by score, HOG distance, alignment IoU, grade
    pairs/<slug>.html       exemplar, built-in render, PhotoShape renders, parts, downloads, licences
    materials.html          the materials used, with substance, licence and how often they were chosen
    img/                    images, named by content hash
    downloads/<slug>/       single-file formats and assignment.json as they are, zips of the others
"""

from __future__ import annotations

import hashlib
import html
import shutil
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from photoshape_flow.export.formats import EXPORTERS, SIDECAR, SIDECAR_PATH

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
    renders: list[tuple[str, Path]] = field(default_factory=list)  # (view, image), exemplar view first
    hog_distance: float | None = None
    alignment_iou: float | None = None
    grade: str | None = None
    grade_note: str | None = None
    grader: str | None = None
    downloads: dict[str, Path] = field(default_factory=dict)  # format -> file (or folder: zipped)
    licenses: list[Mapping[str, Any]] = field(default_factory=list)  # role, name, license, attribution, url

    @property
    def slug(self) -> str:
        key = "".join(c if c.isalnum() or c in "-_" else "-" for c in self.method_key)
        return f"{self.pair_id}-{key}"

    @property
    def score(self) -> float | None:
        """Mean rank-1 confidence over the parts seen in the exemplar (all parts when none was)."""
        seen = [p.score for p in self.parts if p.score is not None and not p.unobserved]
        values = seen or [p.score for p in self.parts if p.score is not None]
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


CSS = """
*{box-sizing:border-box}body{font:14px/1.45 system-ui,sans-serif;margin:0;color:#222;background:#fafafa}
header{padding:14px 24px;background:#1f2a36;color:#fff}header a{color:#cde}h1{font-size:20px;margin:0}
main{padding:16px 24px}table{border-collapse:collapse;width:100%;background:#fff}
th,td{border-bottom:1px solid #e3e3e3;padding:6px 8px;text-align:left;vertical-align:middle}
th[data-key]{cursor:pointer;user-select:none;white-space:nowrap}th[data-key]:after{content:" \\2195";color:#999}
th.asc:after{content:" \\25B2";color:#222}th.desc:after{content:" \\25BC";color:#222}
td.num{text-align:right;font-variant-numeric:tabular-nums}img.thumb{width:96px;height:96px;object-fit:contain;
background:#fff;border:1px solid #ddd}.grade{padding:1px 6px;border-radius:8px;background:#ddd;font-size:12px}
.grade.good{background:#c8ecc9}.grade.acceptable{background:#e6f1c2}.grade.wrong{background:#f6cdcd}
.grid{display:flex;flex-wrap:wrap;gap:12px}figure{margin:0;background:#fff;border:1px solid #ddd;padding:6px}
figure img{width:200px;height:200px;object-fit:contain;display:block}figcaption{font-size:12px;color:#555}
.controls{margin:0 0 12px;display:flex;gap:12px;align-items:center}.muted{color:#777}section{margin:18px 0}
"""

SORT_JS = """
(function(){
  const table=document.getElementById('photoshapes'); if(!table) return;
  const body=table.tBodies[0]; const rows=()=>Array.from(body.rows);
  function value(row,key,type){const v=row.dataset[key];
    if(v===undefined||v==='') return null; return type==='num'?parseFloat(v):v.toLowerCase();}
  function sortBy(th,dir){const key=th.dataset.key,type=th.dataset.type;
    const sorted=rows().sort((a,b)=>{const x=value(a,key,type),y=value(b,key,type);
      if(x===null&&y===null) return 0; if(x===null) return 1; if(y===null) return -1;
      return (x<y?-1:x>y?1:0)*dir;});
    sorted.forEach(r=>body.appendChild(r));
    table.querySelectorAll('th').forEach(h=>h.classList.remove('asc','desc'));
    th.classList.add(dir>0?'asc':'desc'); th.dataset.dir=dir;}
  table.querySelectorAll('th[data-key]').forEach(th=>th.addEventListener('click',()=>{
    const dir=th.dataset.dir==='1'?-1:(th.dataset.dir==='-1'?1:parseInt(th.dataset.first||'1'));
    sortBy(th,dir);}));
  const filter=document.getElementById('grade-filter'), text=document.getElementById('text-filter');
  function apply(){const g=filter.value,t=text.value.toLowerCase();let shown=0;
    rows().forEach(r=>{const ok=(!g||r.dataset.grade===g)&&(!t||r.textContent.toLowerCase().includes(t));
      r.hidden=!ok; shown+=ok;}); document.getElementById('count').textContent=shown;}
  filter.addEventListener('change',apply); text.addEventListener('input',apply);
  const initial=table.querySelector('th[data-key="score"]'); if(initial) sortBy(initial,-1);
})();
"""


def _e(value: Any) -> str:
    return html.escape("" if value is None else str(value), quote=True)


def _num(value: float | None, digits: int = 3) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def _page(title: str, body: str, root: str = "", script: str = "") -> str:
    nav = f'<a href="{root}index.html">PhotoShapes</a> &middot; <a href="{root}materials.html">Materials</a>'
    return (
        f'<!doctype html>\n<html lang="en"><head><meta charset="utf-8"><title>{_e(title)}</title>'
        f'<meta name="viewport" content="width=device-width,initial-scale=1">'
        f'<link rel="icon" href="data:,"><style>{CSS}</style></head>'
        f"<body><header><h1>{_e(title)}</h1>{nav}</header><main>{body}</main>"
        + (f"<script>{script}</script>" if script else "")
        + "</body></html>\n"
    )


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


def _download(root: Path, slug: str, fmt: str, source: Path) -> str | None:
    """Copy a single-file download, or zip the folder of a multi-file format; returns the site path."""
    source = Path(source)
    folder = root / "downloads" / slug
    folder.mkdir(parents=True, exist_ok=True)
    if (fmt == SIDECAR or EXPORTERS[fmt].single_file) and source.is_file():
        shutil.copyfile(source, folder / source.name)
        return f"downloads/{slug}/{source.name}"
    base = source if source.is_dir() else source.parent
    if not base.is_dir():
        return None
    archive = folder / f"{fmt}.zip"
    with zipfile.ZipFile(archive, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for path in sorted(base.rglob("*")):
            if path.is_file():
                zf.write(path, f"{fmt}/{path.relative_to(base).as_posix()}")
    return f"downloads/{slug}/{archive.name}"


def _grade_badge(grade: str | None) -> str:
    if not grade:
        return '<span class="muted">ungraded</span>'
    css = "good" if grade == "good" else "acceptable" if grade == "acceptable" else (
        "wrong" if grade.startswith(("wrong", "under", "over")) else "")
    return f'<span class="grade {css}">{_e(grade)}</span>'


def write_gallery(
    out_dir: str | Path,
    entries: Sequence[GalleryEntry],
    materials: Sequence[GalleryMaterial] = (),
    *,
    title: str = "PhotoShapes",
) -> Path:
    """Write the site into `out_dir` (created; existing files are overwritten); returns index.html."""
    root = Path(out_dir)
    (root / "pairs").mkdir(parents=True, exist_ok=True)
    assets = _Assets(root)
    rows: list[str] = []
    usage: dict[int, int] = {}
    for entry in entries:
        for part in entry.parts:
            if part.material_id is not None:
                usage[part.material_id] = usage.get(part.material_id, 0) + 1
        thumb = assets.image(entry.renders[0][1]) if entry.renders else None
        exemplar = assets.image(entry.exemplar_image)
        _write_pair_page(root, entry, assets)
        grade_rank = GRADE_ORDER.get(entry.grade or "", 99)
        rows.append(
            f'<tr data-pair="{entry.pair_id}" data-score="{_num(entry.score, 6)}" '
            f'data-hog="{_num(entry.hog_distance, 6)}" data-iou="{_num(entry.alignment_iou, 6)}" '
            f'data-graderank="{grade_rank}" data-grade="{_e(entry.grade or "")}" data-shape="{_e(entry.shape_name)}">'
            f'<td><a href="pairs/{entry.slug}.html">'
            + (f'<img class="thumb" src="{thumb}" alt="PhotoShape {entry.pair_id}">' if thumb else "no render")
            + "</a></td><td>"
            + (f'<img class="thumb" src="{exemplar}" alt="exemplar {entry.pair_id}">' if exemplar else "")
            + f'</td><td><a href="pairs/{entry.slug}.html">{entry.pair_id}</a><br>'
            f'<span class="muted">{_e(entry.method_key)}</span></td>'
            f"<td>{_e(entry.shape_name)}<br><span class=\"muted\">{_e(entry.exemplar_name)}</span></td>"
            f'<td class="num">{_num(entry.score)}</td><td class="num">{_num(entry.hog_distance)}</td>'
            f'<td class="num">{_num(entry.alignment_iou)}</td><td>{_grade_badge(entry.grade)}</td>'
            f"<td>{_e(', '.join(entry.license_summary))}</td></tr>"
        )
    options = "".join(f'<option value="{_e(g)}">{_e(g)}</option>' for g in GRADE_ORDER)
    body = (
        '<div class="controls"><label>Grade <select id="grade-filter"><option value="">all</option>'
        f'{options}</select></label><label>Search <input id="text-filter" type="search"></label>'
        f'<span><span id="count">{len(rows)}</span> of {len(rows)} PhotoShapes</span></div>'
        '<table id="photoshapes"><thead><tr><th>PhotoShape</th><th>Exemplar</th>'
        '<th data-key="pair" data-type="num">Pair</th><th data-key="shape" data-type="text">Shape / exemplar</th>'
        '<th data-key="score" data-type="num" data-first="-1" title="mean rank-1 material confidence">Score</th>'
        '<th data-key="hog" data-type="num" title="coarse-alignment HOG distance (lower is closer)">HOG distance</th>'
        '<th data-key="iou" data-type="num" data-first="-1" title="fine-alignment IoU">Alignment IoU</th>'
        '<th data-key="graderank" data-type="num">Grade</th><th>Licences</th></tr></thead>'
        f"<tbody>{''.join(rows)}</tbody></table>"
        + ("" if rows else '<p class="muted">No PhotoShapes yet: run the publish stage first.</p>')
    )
    (root / "index.html").write_text(_page(title, body, script=SORT_JS))
    _write_materials_page(root, materials, usage, assets)
    return root / "index.html"


def _figure(src: str | None, caption: str) -> str:
    if src is None:
        return ""
    return f'<figure><img src="../{src}" alt="{_e(caption)}"><figcaption>{_e(caption)}</figcaption></figure>'


def _write_pair_page(root: Path, entry: GalleryEntry, assets: _Assets) -> None:
    figures = [
        _figure(assets.image(entry.exemplar_image), "exemplar photo"),
        _figure(assets.image(entry.builtin_image), "built-in materials"),
        *(_figure(assets.image(path), f"PhotoShape, {view} view") for view, path in entry.renders),
    ]
    parts = "".join(
        f"<tr><td>{p.index}</td><td>{_e(p.name)}</td><td>"
        + (f'<a href="../materials.html#m{p.material_id}">{_e(p.material_name)}</a>' if p.material_id is not None
           else '<span class="muted">built-in</span>')
        + f'</td><td>{_e(p.substance or "")}</td><td class="num">'
        + ("" if p.score is None else f"{100 * p.score:.1f}%")
        + f"</td><td>{'no (substance prior)' if p.unobserved else 'yes'}</td></tr>"
        for p in entry.parts
    )
    downloads = []
    for fmt, label in DOWNLOAD_LABELS.items():
        if fmt in entry.downloads:
            href = _download(root, entry.slug, fmt, entry.downloads[fmt])
            if href:
                downloads.append(f'<li><a href="../{href}" download>{_e(label)}</a></li>')
    licences = "".join(
        f"<tr><td>{_e(x.get('role'))}</td><td>{_e(x.get('name'))}</td><td>{_e(x.get('license') or 'unknown')}</td>"
        f"<td>{_e(x.get('attribution') or '')}</td><td>"
        + (f'<a href="{_e(x["source_url"])}" rel="noreferrer">source</a>' if x.get("source_url") else "")
        + "</td></tr>"
        for x in entry.licenses
    )
    grade = _grade_badge(entry.grade)
    if entry.grade_note:
        grade += f" &mdash; {_e(entry.grade_note)}"
    if entry.grader:
        grade += f' <span class="muted">({_e(entry.grader)})</span>'
    body = (
        f'<p><a href="../index.html">&larr; all PhotoShapes</a> &middot; shape <b>{_e(entry.shape_name)}</b>, '
        f"exemplar <b>{_e(entry.exemplar_name)}</b>, method <code>{_e(entry.method_key)}</code></p>"
        f'<section class="grid">{"".join(figures)}</section>'
        f"<section><h2>Quality</h2><p>score {_num(entry.score) or 'n/a'} &middot; HOG distance "
        f"{_num(entry.hog_distance) or 'n/a'} &middot; alignment IoU {_num(entry.alignment_iou) or 'n/a'}"
        f" &middot; grade {grade}</p><p class=\"muted\">Grade it: <code>photoshape grade {entry.pair_id} "
        f"LABEL --note ...</code></p></section>"
        "<section><h2>Parts</h2><table><thead><tr><th>#</th><th>Part</th><th>Material</th><th>Substance</th>"
        f"<th>Confidence</th><th>Seen in exemplar</th></tr></thead><tbody>{parts}</tbody></table></section>"
        "<section><h2>Downloads</h2>"
        + (f"<ul>{''.join(downloads)}</ul>" if downloads else '<p class="muted">not exported yet</p>')
        + "</section><section><h2>Licences</h2><table><thead><tr><th>Role</th><th>Item</th><th>Licence</th>"
        f"<th>Attribution</th><th></th></tr></thead><tbody>{licences}</tbody></table></section>"
    )
    title = f"PhotoShape {entry.pair_id}: {entry.shape_name}"
    (root / "pairs" / f"{entry.slug}.html").write_text(_page(title, body, root="../"))


def _write_materials_page(
    root: Path, materials: Sequence[GalleryMaterial], usage: Mapping[int, int], assets: _Assets
) -> None:
    rows = "".join(
        f'<tr id="m{m.id}"><td>'
        + (f'<img class="thumb" src="{src}" alt="{_e(m.name)}">' if (src := assets.image(m.preview)) else "")
        + f"</td><td>{_e(m.name)}</td><td>{_e(m.substance or '')}</td><td class=\"num\">{usage.get(m.id, 0)}</td>"
        f"<td>{_e(m.license or 'unknown')}</td><td>{_e(m.attribution or '')}</td><td>"
        + (f'<a href="{_e(m.source_url)}" rel="noreferrer">source</a>' if m.source_url else "")
        + "</td></tr>"
        for m in sorted(materials, key=lambda m: (-usage.get(m.id, 0), m.name))
    )
    body = (
        "<table><thead><tr><th>Preview</th><th>Material</th><th>Substance</th><th>Used by</th><th>Licence</th>"
        f"<th>Attribution</th><th></th></tr></thead><tbody>{rows}</tbody></table>"
    )
    (root / "materials.html").write_text(_page("Materials", body))
