"""Top-1, top-5 and substance per method by the part's size in the photo: where each method's misses sit.

    PHOTOSHAPE_DATA_ROOT=/work/w-base python -m experiments.fit_attribution.by_size \\
        --groundtruth ../second-world/groundtruth.json --source second-world

Every scored part (as `photoshape eval` scores it: the truth under the pair's CRF map) of every
non-excluded pair, binned by its share of the aligned part map (`--bins`), with each method's rank-1
against the true material and substance, and whether the truth is among its first five. Read-only, seconds; output
`<data root>/experiments/fit_attribution/by_size.json`.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np
import sqlalchemy as sa

from experiments.common import results_dir
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.evaluation.groundtruth import read_groundtruth_file
from photoshape_flow.recognition.inference import ALIGNMENT_METHOD
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.scoring.truths import pair_truths
from photoshape_flow.store import BlobStore


def size_bin(share: float, edges: list[float]) -> str:
    """The label of the bin of a part's share of the frame (`edges` ascending)."""
    for edge in edges:
        if share < edge:
            return f"<{edge:.1%}"
    return f">={edges[-1]:.1%}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--groundtruth", type=Path, required=True)
    parser.add_argument("--source", default=None)
    parser.add_argument("--bins", default="0.015,0.06", help="ascending edges of the part's share of the frame")
    args = parser.parse_args()
    edges = [float(x) for x in args.bins.split(",")]
    settings = get_settings()
    store = BlobStore(settings.blob_root)
    hits: dict[str, dict[str, list[tuple[bool, bool, bool]]]] = defaultdict(lambda: defaultdict(list))
    with session_scope(settings.resolved_database_url) as session:  # read-only
        truths = match_groundtruth(session, read_groundtruth_file(args.groundtruth), args.source).truths
        names = dict(session.execute(sa.select(m.Material.id, m.Material.name)).all())
        pairs = session.execute(sa.select(m.Pair, m.Alignment).join(m.Alignment, sa.and_(
            m.Alignment.pair_id == m.Pair.id, m.Alignment.method == ALIGNMENT_METHOD, m.Alignment.status == "ok"))
            .where(m.Pair.exemplar_id.in_(list(truths)), ~m.Pair.exclude)).all()
        for pair, alignment in pairs:
            scored = pair_truths(session, store, pair, session.get(m.Exemplar, pair.exemplar_id), alignment,
                                 truths[pair.exemplar_id])
            if not scored or not alignment.crf_blob:
                continue
            labels = store.load_image(alignment.crf_blob)
            labels = labels[..., 0] if labels.ndim == 3 else labels
            ranked: dict[tuple[str, int], list[m.Assignment]] = defaultdict(list)
            for row, index in session.execute(
                    sa.select(m.Assignment, m.Part.index).join(m.Part, m.Part.id == m.Assignment.part_id)
                    .where(m.Assignment.pair_id == pair.id, m.Assignment.rank <= 5)).all():
                if index in scored:
                    ranked[(row.method_key, index)].append(row)
            for (method, index), rows in ranked.items():
                rows.sort(key=lambda r: r.rank)
                material, substance = scored[index]
                hit = (names.get(rows[0].material_id) == material, rows[0].substance == substance,
                       any(names.get(r.material_id) == material for r in rows))
                label = size_bin(float((labels == index).mean()), edges)
                hits[method][label].append(hit)
                hits[method]["all"].append(hit)
        session.rollback()
    summary = {method: {label: {"parts": len(v), "top1": round(float(np.mean([h[0] for h in v])), 3),
                                "substance": round(float(np.mean([h[1] for h in v])), 3),
                                "top5": round(float(np.mean([h[2] for h in v])), 3)}
                        for label, v in sorted(by.items())} for method, by in sorted(hits.items())}
    print("method: per bin of the part's share, top-1 / top-5 / substance (parts)")
    for method, by in summary.items():
        print(f"{method:14s}", "  ".join(f"{label} {c['top1']:.3f} / {c['top5']:.3f} / {c['substance']:.3f} "
                                         f"(n={c['parts']})" for label, c in by.items()))
    out = results_dir(settings, "fit_attribution")
    out.mkdir(parents=True, exist_ok=True)
    (out / "by_size.json").write_text(json.dumps(summary, indent=2) + "\n")


if __name__ == "__main__":
    main()
