"""A contact sheet of PhotoShapes: one PNG that shows many results at a glance (README, reports).

Row per candidate: the exemplar photo, the shape with its built-in materials at the exemplar's view,
the PhotoShape at the exemplar's view, then `turntable` novel views. Pure function of `GalleryEntry`
values (the same ones the HTML gallery shows), so what the sheet shows is what the gallery shows.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from photoshape_flow.export.gallery import GalleryEntry

HEADERS = ("exemplar", "built-in", "PhotoShape", "novel views")
_WHITE = 255


def _tile(path: Path | None, size: int) -> np.ndarray:
    """`path` letterboxed onto a white `size` square (alpha composited over white); grey when missing."""
    tile = np.full((size, size, 3), _WHITE, np.uint8)
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path is not None else None
    if image is None:
        tile[:] = 235
        return tile
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    if image.shape[2] == 4:
        alpha = image[..., 3:4].astype(np.float32) / 255.0
        image = (image[..., :3] * alpha + _WHITE * (1.0 - alpha)).astype(np.uint8)
    h, w = image.shape[:2]
    scale = size / max(h, w)
    nh, nw = max(1, round(h * scale)), max(1, round(w * scale))
    interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC
    image = cv2.resize(image, (nw, nh), interpolation=interp)
    y, x = (size - nh) // 2, (size - nw) // 2
    tile[y:y + nh, x:x + nw] = image
    return tile


def _text(canvas: np.ndarray, text: str, x: int, y: int, scale: float = 0.45) -> None:
    cv2.putText(canvas, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (60, 60, 60), 1, cv2.LINE_AA)


def contact_sheet(entries: Sequence[GalleryEntry], out: str | Path, *, rows: int = 6, turntable: int = 3,
                  tile: int = 160, pad: int = 6) -> Path:
    """Write a PNG with up to `rows` candidates (highest score first); returns its path.

    Each row: exemplar | built-in | PhotoShape (exemplar view) | `turntable` novel views evenly picked
    from the candidate's turntable. Raises ValueError when no entry has a PhotoShape render.
    """
    shown = [e for e in entries if e.renders]
    if not shown:
        raise ValueError("no PhotoShape renders to show (run the publish stage first)")
    shown.sort(key=lambda e: (e.score is None, -(e.score or 0.0), e.pair_id))
    shown = shown[:rows]
    cols = 3 + turntable
    label_h = 18
    header_h = 24
    width = cols * tile + (cols + 1) * pad
    height = header_h + len(shown) * (tile + label_h + pad) + pad
    canvas = np.full((height, width, 3), _WHITE, np.uint8)
    for c, header in enumerate(HEADERS):
        _text(canvas, header, pad + c * (tile + pad) + 4, header_h - 8, 0.5)
    for r, entry in enumerate(shown):
        y = header_h + r * (tile + label_h + pad)
        views = dict(entry.renders)
        novel = [path for view, path in entry.renders if view != "exemplar"]
        if novel and turntable:
            picks = np.linspace(0, len(novel), turntable, endpoint=False).astype(int)
            novel = [novel[i] for i in picks]
        images = [entry.exemplar_image, entry.builtin_image, views.get("exemplar"), *novel[:turntable]]
        images += [None] * (cols - len(images))
        for c, path in enumerate(images):
            x = pad + c * (tile + pad)
            canvas[y:y + tile, x:x + tile] = _tile(path, tile)
        parts = ", ".join(p.material_name for p in entry.parts if p.material_name and not p.unobserved)
        caption = f"{entry.exemplar_name} -> {entry.shape_name}: {parts}"
        _text(canvas, caption[: (width - 2 * pad) // 7], pad + 2, y + tile + 13, 0.4)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp.png")
    if not cv2.imwrite(str(tmp), canvas):
        raise OSError(f"{out}: cannot write the contact sheet")
    tmp.replace(out)
    return out
