"""Ingest throughput: shapes/s and exemplars/s on real-size inputs, into a throwaway data root.

Inputs: generated 50k-triangle OBJs (curved, three material groups, no UVs, so xatlas runs), generated
1000x1000 JPEG product photos, plus ../shared/data (models, ABO photos) and the Sweet Home 3D seating
catalogs (Debian package sweethome3d-furniture) when present. Prints a table and writes
bench/results/ingest.json. Usage: .venv/bin/python bench/ingest.py [--shapes 3] [--photos 50] [--sh3d 30]
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
SH3D = Path("/usr/share/sweethome3d/furniture")


def write_curved_obj(path: Path, faces: int, seed: int) -> None:
    """A bumpy closed surface (sphere with noise) of about `faces` triangles in 3 usemtl bands."""
    rng = np.random.default_rng(seed)
    rings = int(np.sqrt(faces / 2))
    segments = faces // (2 * rings)
    theta = np.linspace(0.05, np.pi - 0.05, rings + 1)
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    radius = 1 + 0.05 * np.sin(7 * t) * np.cos(5 * p) + rng.normal(0, 0.002, t.shape)
    v = np.stack([radius * np.sin(t) * np.cos(p), radius * np.cos(t), radius * np.sin(t) * np.sin(p)], -1)
    idx = np.arange((rings + 1) * segments).reshape(rings + 1, segments)
    nxt = np.roll(idx, -1, axis=1)
    lines = [f"v {x:.5f} {y:.5f} {z:.5f}" for x, y, z in v.reshape(-1, 3)]
    for band, name in enumerate(("fabric", "wood", "metal")):
        lines.append(f"usemtl {name}")
        for r in range(band * rings // 3, (band + 1) * rings // 3):
            for a, b, c, d in zip(idx[r], nxt[r], idx[r + 1], nxt[r + 1], strict=True):
                lines.append(f"f {a + 1} {c + 1} {b + 1}")
                lines.append(f"f {b + 1} {c + 1} {d + 1}")
    path.write_text("\n".join(lines) + "\n")


def write_photo(path: Path, seed: int, side: int = 1000) -> None:
    from PIL import Image

    rng = np.random.default_rng(seed)
    image = np.clip(250 + rng.normal(0, 2, (side, side, 3)), 0, 255)
    x0, y0 = rng.integers(50, 300, 2)
    x1, y1 = x0 + rng.integers(300, 600), y0 + rng.integers(300, 600)
    image[y0:y1, x0:x1] = rng.integers(30, 160, 3) + rng.normal(0, 8, (y1 - y0, x1 - x0, 3))
    Image.fromarray(image.clip(0, 255).astype(np.uint8)).save(path, "JPEG", quality=90)


def timed(label: str, func, count_of) -> dict:  # type: ignore[no-untyped-def]
    start = time.perf_counter()
    summary = func()
    seconds = time.perf_counter() - start
    count = count_of(summary)
    row = {"case": label, "items": count, "rejected": len(summary.rejected), "seconds": round(seconds, 2),
           "items_per_s": round(count / seconds, 3) if seconds > 0 else None}
    print(f"{label:<44} {count:>6} {len(summary.rejected):>6} {seconds:>9.2f} {row['items_per_s']!s:>9}", flush=True)
    return row


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--shapes", type=int, default=3, help="generated 50k-face OBJs")
    parser.add_argument("--photos", type=int, default=50, help="generated 1000x1000 JPEGs")
    parser.add_argument("--sh3d", type=int, default=30, help="Sweet Home 3D seating models (0: skip)")
    args = parser.parse_args()

    from photoshape_flow.config import Settings
    from photoshape_flow.db import migrate
    from photoshape_flow.ingest.ingest import ingest_exemplars, ingest_shapes

    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="photoshape-bench-") as tmp:
        root = Path(tmp)
        settings = Settings(data_root=root / "data")
        migrate.upgrade(settings.resolved_database_url)
        gen_shapes = root / "shapes"
        gen_shapes.mkdir()
        for i in range(args.shapes):
            write_curved_obj(gen_shapes / f"bumpy_{i}.obj", 50_000, i)
        gen_photos = root / "photos"
        gen_photos.mkdir()
        for i in range(args.photos):
            write_photo(gen_photos / f"photo_{i:03d}.jpg", i)
        print(f"{'case':<44} {'items':>6} {'rej':>6} {'seconds':>9} {'items/s':>9}")
        added = lambda s: len(s.added) + len(s.replaced)  # noqa: E731
        rows.append(timed(f"shapes: generated 50k-face OBJ x{args.shapes}",
                          lambda: ingest_shapes([gen_shapes], settings=settings), added))
        rows.append(timed("shapes: same again (idempotent skip)",
                          lambda: ingest_shapes([gen_shapes], settings=settings), lambda s: len(s.present)))
        rows.append(timed(f"exemplars: generated 1000x1000 JPEG x{args.photos}",
                          lambda: ingest_exemplars([gen_photos], settings=settings), added))
        if SHARED.is_dir():
            rows.append(timed("shapes: shared/data/models (OBJ + glTF)",
                              lambda: ingest_shapes([SHARED / "models"], settings=settings), added))
            rows.append(timed("exemplars: shared/data/photos/abo (128 px)",
                              lambda: ingest_exemplars([SHARED / "photos" / "abo"], source="abo", settings=settings),
                              added))
        if args.sh3d and SH3D.is_dir():
            from photoshape_flow.geometry.sources import ShapeItem, discover_shapes

            seating = [i for i in discover_shapes(sorted(SH3D.glob("*.sh3f")), category="chair,sofa,stool,bench")
                       if isinstance(i, ShapeItem)][: args.sh3d]
            ids = "|".join(sorted({i.source_id.split("/", 1)[1].replace("#", "\\#") for i in seating}))
            rows.append(timed(f"shapes: Sweet Home 3D seating x{len(seating)}",
                              lambda: ingest_shapes(sorted(SH3D.glob("*.sh3f")), category="chair,sofa,stool,bench",
                                                    name_filter=f"^({ids})$", settings=settings), added))
    result = {"machine": {"python": platform.python_version(), "cpus": __import__("os").cpu_count()}, "rows": rows}
    out = REPO / "bench" / "results" / "ingest.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out.relative_to(REPO)}")


if __name__ == "__main__":
    main()
