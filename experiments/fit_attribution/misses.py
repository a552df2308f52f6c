"""Where fit's misses fall on an evaluation world, from the rows a run left (no rendering, seconds).

    PHOTOSHAPE_DATA_ROOT=/work/w-base python -m experiments.fit_attribution.misses \\
        --groundtruth ../second-world/groundtruth.json --source second-world

Three tables, each part matched and scored as `photoshape eval` scores it (`scoring.truths.pair_truths`):

1. per true substance and method: top-1, top-5 (is the truth among the method's first five at all)
   and substance recall;
2. per true substance, fit's parts whose truth is among its candidates but not first: how often the
   winner has the smaller distance, how often the larger prior, and the winners' substances;
3. fit's stored lighting estimate per exemplar against the truth's (`lighting.envmap`, `rotation`):
   which envmap it chose (the truth's when the library holds that file) and the rotation error then.

Measurement only: nothing here is chosen on an evaluation world. Output:
`<data root>/experiments/fit_attribution/misses.json`.
"""

from __future__ import annotations

import argparse
import json
import math
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa

from experiments.common import ScoredPart, results_dir, scored_rankings
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.evaluation.groundtruth import read_groundtruth_file
from photoshape_flow.fitting.fit import LIGHTING_KEY
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.vocab import SUBSTANCES


def by_substance(scored: list[ScoredPart]) -> dict[str, dict[str, dict[str, float]]]:
    """Method key -> true substance -> parts, top-1, top-5, substance recall."""
    counts: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0, 0, 0, 0])
    for key, (material, substance), candidates in scored:
        c = counts[(key, substance)]
        c[0] += 1
        c[1] += candidates[0][1] == material
        c[2] += material in [x[1] for x in candidates[:5]]
        c[3] += candidates[0][2] == substance
    out: dict[str, dict[str, dict[str, float]]] = defaultdict(dict)
    for (key, substance), (n, top1, top5, recall) in sorted(counts.items()):
        out[key][substance] = {"parts": n, "top1": top1 / n, "top5": top5 / n, "recall": recall / n}
    return dict(out)


def fit_losses(scored: list[ScoredPart]) -> dict[str, dict[str, Any]]:
    """True substance -> fit's parts lost with the truth among its candidates: distance, prior, winners."""
    lost: dict[str, list[tuple[bool, bool, str | None]]] = defaultdict(list)
    for key, (material, substance), candidates in scored:
        if not key.startswith("fit"):
            continue
        truth = [c for c in candidates if c[1] == material]
        winner = candidates[0]
        if not truth or truth[0][0] == 1:
            continue
        t, w = truth[0][3], winner[3]
        if None in (t.get("distance"), w.get("distance"), t.get("prior"), w.get("prior")):
            continue
        lost[substance].append((w["distance"] < t["distance"], w["prior"] > t["prior"], winner[2]))
    return {s: {"parts": len(xs), "winner_nearer": float(np.mean([x[0] for x in xs])),
                "winner_likelier": float(np.mean([x[1] for x in xs])),
                "winners": dict(Counter(x[2] for x in xs).most_common())} for s, xs in sorted(lost.items())}


def lighting(url: str, groundtruth: Path, source: str) -> dict[str, Any]:
    """Fit's lighting estimate against the truth's: the chosen envmaps, and rotation errors when right."""
    chosen: Counter[str] = Counter()
    errors = []
    with session_scope(url) as session:
        truths = match_groundtruth(session, read_groundtruth_file(groundtruth), source).truths
        names = dict(session.execute(sa.select(m.Envmap.id, m.Envmap.name)).all())
        for exemplar_id, truth in truths.items():
            exemplar = session.get(m.Exemplar, exemplar_id)
            light = (exemplar.meta or {}).get(LIGHTING_KEY) if exemplar is not None else None
            if light is None or truth.lighting is None:
                continue
            name = names.get(light.get("envmap_id"), "none")
            right = Path(truth.lighting.envmap).stem == name
            chosen["the truth's" if right else name] += 1
            if right:
                turn = (float(light["rotation"]) - truth.lighting.rotation) % (2 * math.pi)
                errors.append(round(math.degrees(min(turn, 2 * math.pi - turn))))
    return {"chosen": dict(chosen.most_common()), "rotation_error_deg": sorted(errors)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--groundtruth", type=Path, required=True)
    parser.add_argument("--source", required=True, help="the exemplars' source, e.g. second-world")
    args = parser.parse_args()
    settings = get_settings()
    url = settings.resolved_database_url
    scored = scored_rankings(url, args.groundtruth, args.source)
    results = {"by_substance": by_substance(scored), "fit_losses": fit_losses(scored),
               "lighting": lighting(url, args.groundtruth, args.source)}
    for key, table in results["by_substance"].items():
        print(f"\n{key}: top-1 / top-5 / substance recall (parts)")
        for s in SUBSTANCES:
            if s in table:
                r = table[s]
                print(f"  {s:8s} {r['top1']:.2f} / {r['top5']:.2f} / {r['recall']:.2f} ({r['parts']})")
    print("\nfit, truth among the candidates but not first: winner nearer / likelier (parts), winners")
    for s, r in results["fit_losses"].items():
        print(f"  {s:8s} {r['winner_nearer']:.2f} / {r['winner_likelier']:.2f} ({r['parts']}) {r['winners']}")
    print(f"\nlighting chosen: {results['lighting']['chosen']}")
    print(f"rotation error when the truth's envmap was chosen (deg): {results['lighting']['rotation_error_deg']}")
    out = results_dir(settings, "fit_attribution")
    out.mkdir(parents=True, exist_ok=True)
    (out / "misses.json").write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
