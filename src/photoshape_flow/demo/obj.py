"""OBJ + MTL writing for demo furniture, shaped like real collection files.

One `usemtl` group per material part, `g` object groups inside it, positions / UVs / normals with
`f v/vt/vn` faces, and an MTL whose Kd is the part's built-in colour (plus Ns from roughness and the
PBR extension keys Pr / Pm), so the shapes go through the same ingest as downloaded models.
"""

from __future__ import annotations

import io

import numpy as np

from photoshape_flow.demo.furniture.model import Furniture


def _block(prefix: str, rows: np.ndarray, fmt: str) -> str:
    buf = io.StringIO()
    np.savetxt(buf, rows, fmt=f"{prefix} {fmt}")
    return buf.getvalue()


def obj_text(furniture: Furniture, mtl_name: str) -> str:
    """The OBJ file content (deterministic for equal input)."""
    out = [
        f"# photoshape_flow demo shape {furniture.source_id}: {furniture.kind}, "
        f"{furniture.segmentation} segmentation (procedurally generated, CC0-1.0)\n",
        f"mtllib {mtl_name}\n",
        f"o {furniture.source_id}\n",
    ]
    base = 1
    for part in furniture.parts:
        out.append(f"usemtl {part.name}\n")
        for comp in part.components:
            p = comp.piece
            out.append(f"g {comp.name}\n")
            out.append(_block("v", np.round(p.vertices, 6) + 0.0, "%.6f %.6f %.6f"))
            out.append(_block("vt", np.round(p.uvs, 6) + 0.0, "%.6f %.6f"))
            out.append(_block("vn", np.round(p.normals, 6) + 0.0, "%.6f %.6f %.6f"))
            f = p.faces + base
            out.append(_block("f", np.repeat(f, 3, axis=1), "%d/%d/%d %d/%d/%d %d/%d/%d"))
            base += len(p.vertices)
    return "".join(out)


def mtl_text(furniture: Furniture) -> str:
    """The MTL file content: one `newmtl` per part with its built-in colour."""
    out = [f"# materials of demo shape {furniture.source_id}\n"]
    for part in furniture.parts:
        m = part.builtin
        r, g, b = m["albedo"]
        rough = float(m["roughness"])
        ns = float(np.clip(2.0 / max(rough, 0.05) ** 4 - 2.0, 1.0, 1000.0))
        ks = 0.5 if m["metallic"] > 0.5 else 0.04
        out.append(
            f"newmtl {part.name}\nKa 0.000000 0.000000 0.000000\nKd {r:.6f} {g:.6f} {b:.6f}\n"
            f"Ks {ks:.6f} {ks:.6f} {ks:.6f}\nNs {ns:.6f}\nPr {rough:.6f}\nPm {float(m['metallic']):.6f}\n"
            f"d 1.000000\nillum 2\n\n"
        )
    return "".join(out)
