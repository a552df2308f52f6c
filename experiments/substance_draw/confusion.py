"""Substance confusion of each method's first material on an evaluation world's scored parts.

    PHOTOSHAPE_DATA_ROOT=/work/world-a python -m experiments.substance_draw.confusion \\
        --groundtruth /work/second-world/groundtruth.json --source second-world [--url sqlite:////work/arm.db]

Rows: true substance; columns: the substance of the method's rank-1 material; the last column is
recall. Parts are matched and scored as `photoshape eval` scores them (`scoring.evaluate.pair_truths`).
Measurement only: nothing here is chosen on an evaluation world.
"""

from __future__ import annotations

import argparse
from collections import Counter, defaultdict
from pathlib import Path

import sqlalchemy as sa

from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.evaluation.groundtruth import read_groundtruth_file
from photoshape_flow.scoring.evaluate import pair_truths
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import SUBSTANCES


def confusions(url: str, groundtruth: Path, source: str) -> dict[str, Counter[tuple[str, str]]]:
    """Method key -> Counter of (true substance, rank-1 substance) over the scored parts."""
    store = BlobStore(get_settings().blob_root)
    out: dict[str, Counter[tuple[str, str]]] = defaultdict(Counter)
    with session_scope(url) as session:
        truths = match_groundtruth(session, read_groundtruth_file(groundtruth), source).truths
        rows = session.execute(
            sa.select(m.Assignment, m.Part.index).join(m.Part, m.Part.id == m.Assignment.part_id)
            .join(m.Pair, m.Pair.id == m.Assignment.pair_id)
            .where(m.Pair.exemplar_id.in_(list(truths)), ~m.Pair.exclude, m.Assignment.rank == 1)).all()
        by_pair: dict[int, dict[int, tuple[str, str]]] = {}
        for assignment, index in rows:
            if assignment.pair_id not in by_pair:
                pair = session.get(m.Pair, assignment.pair_id)
                alignment = session.execute(sa.select(m.Alignment).where(
                    m.Alignment.pair_id == pair.id, m.Alignment.method == "flow-crf",
                    m.Alignment.status == "ok")).scalar_one_or_none()
                by_pair[pair.id] = {} if alignment is None else pair_truths(
                    session, store, pair, session.get(m.Exemplar, pair.exemplar_id), alignment,
                    truths[pair.exemplar_id])
            truth = by_pair[assignment.pair_id].get(index)
            if truth is not None and assignment.substance is not None:
                out[assignment.method_key][(truth[1], assignment.substance)] += 1
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--groundtruth", type=Path, required=True)
    parser.add_argument("--source", required=True, help="the exemplars' source, e.g. second-world or demo-small")
    parser.add_argument("--url", default=None, help="database URL (default: the settings')")
    args = parser.parse_args()
    url = args.url or get_settings().resolved_database_url
    for key, counts in sorted(confusions(url, args.groundtruth, args.source).items()):
        total = sum(counts.values())
        right = sum(v for (t, p), v in counts.items() if t == p)
        print(f"\n{key}: {total} parts, substance {right / total:.3f}")
        print("true \\ first " + " ".join(f"{s:>8}" for s in SUBSTANCES) + "   recall")
        for t in SUBSTANCES:
            row = [counts[(t, p)] for p in SUBSTANCES]
            n = sum(row)
            recall = f"{row[SUBSTANCES.index(t)] / n:.2f}" if n else "-"
            print(f"{t:>12} " + " ".join(f"{v:>8}" for v in row) + f"   {recall} ({n})")


if __name__ == "__main__":
    main()
