"""A pair's fit steps: its candidates, its lighting and its candidates' measured distances.

The stage's loop (`fitting.fit`) runs them on exemplars, the fit's calibration
(`fitting.calibration`) on photo-like validation renders and the experiments on both, so they
live below all three (on the context and pair data of `fitting.context`).
"""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np

from photoshape_flow.fit.candidates import Candidate, RankedRow, part_candidates
from photoshape_flow.fit.scene import estimate_lighting, render_candidates, select_profiled
from photoshape_flow.fit.select import rank_candidates
from photoshape_flow.fitting.context import FitContext, PairData


def candidates_of(ctx: FitContext, data: PairData) -> dict[int, list[Candidate]]:
    """Each observed part's candidates (`fit.candidates`); a part with none keeps the ranking (absent here)."""
    out = {}
    for index, mask in sorted(data.scene.masks.items()):
        ranked = [RankedRow(int(r.material_id), r.substance or ctx.material_substance.get(r.material_id, ""), r.score)
                  for r in data.rows[index] if r.material_id is not None]
        part_lab = np.median(data.scene.photo_lab[mask].reshape(-1, 3), axis=0)
        candidates = part_candidates(ranked, ctx.cfg.top_k, ctx.material_substance, ctx.material_labs, part_lab,
                                     ctx.untrained, ctx.cfg.prior_floor)
        if candidates:
            out[index] = candidates
    return out


def lighting_estimate(ctx: FitContext, data: PairData) -> dict[str, Any]:
    """The best (envmap, rotation, exposure) for the pair's photo (`fit.scene.estimate_lighting`).

    Round 1 lights the ranking's first materials; each further round (`lighting_rounds`) selects the
    materials under the current estimate and lights those winners again, so a wrong first material
    does not fix the lighting for good.
    """
    # envmap id -> its spec at a rotation; no envmap at all: the constant white sky (id 0)
    envmaps = {e: partial(ctx.envmap_spec, e) for e in sorted(ctx.envmaps)} or {0: partial(ctx.envmap_spec, 0)}
    chosen = data.rank1()
    light: dict[str, Any] = {}
    for round_ in range(max(1, ctx.cfg.lighting_rounds)):
        if round_:
            candidates = candidates_of(ctx, data)
            measured, _ = select_materials(ctx, data, candidates, light)
            chosen = {**chosen, **{i: rank_candidates(c, measured[i], ctx.prior_weight)[0].candidate.material_id
                                   for i, c in candidates.items() if c}}
        materials = [ctx.spec(chosen.get(p.index)) for p in data.scene.mesh.parts]
        h, scale, loss, renders = estimate_lighting(ctx.frame, data.scene, materials, envmaps, ctx.cfg.rotations,
                                                    ctx.weights, ctx.cfg.lighting_envmaps, ctx.cfg.erode)
        light = {"envmap_id": h.envmap_id if h.envmap_id in ctx.envmaps else None, "rotation": round(h.rotation, 6),
                 "exposure": round(scale, 6), "loss": round(loss, 6), "hypotheses": renders, "rounds": round_ + 1}
    return light


def select_materials(ctx: FitContext, data: PairData, candidates: dict[int, list[Candidate]],
                     light: dict[str, Any], envmap: Any = None) -> tuple[dict[int, dict[int, float | None]], float]:
    """(part index -> {candidate material: distance}, the winners' exposure) under the exemplar's lighting
    (`fit.scene.select_profiled`: each candidate at the exposure that best explains the photo with it);
    `envmap` replaces the lighting's training envmap (the attribution experiment lights with the truth's)."""
    if not candidates:
        return {}, float(light.get("exposure", 1.0))
    if envmap is None:
        envmap = ctx.light_envmap(light)
    renders = render_candidates(ctx.frame, data.scene, data.rank1(), candidates, ctx.spec, envmap)
    distances, _, exposure = select_profiled(renders, data.scene, candidates, float(light.get("exposure", 1.0)),
                                             ctx.weights, ctx.prior_weight, ctx.cfg.exposure_stops, ctx.cfg.erode)
    return distances, exposure
