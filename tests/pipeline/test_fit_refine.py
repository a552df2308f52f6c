"""Which pairs the fit refines: publish's pairs and each exemplar's best pair, nothing else."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import sqlalchemy as sa
from tests.pipeline.aligned import make_aligned_pairs

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.fitting.refine import is_refined
from photoshape_flow.profiles import FitConfig
from photoshape_flow.store import BlobStore


def test_only_used_pairs_are_refined(db_url: str, store: BlobStore) -> None:
    ids = make_aligned_pairs(db_url, store, n_pairs=2)  # ranks 1 and 2, each its exemplar's only pair
    with session_scope(db_url) as s:
        first, second = (s.get(m.Pair, i) for i in ids["pairs"])
        first.exemplar_rank = second.exemplar_rank = 1
        other = m.Shape(source="t", source_id="other")  # the first exemplar's second-best shape
        s.add(other)
        s.flush()
        other_part = m.Part(shape_id=other.id, index=1, name="seat")
        third = m.Pair(shape_id=other.id, exemplar_id=first.exemplar_id, rank=3, exemplar_rank=2,
                       distance=5.0, azimuth=0.0, elevation=0.2, fov=50.0, camera_distance=2.0)
        s.add_all([other_part, third])
        s.flush()
        s.add(m.Alignment(pair_id=third.id, method="flow-crf"))
        for pair, part in ((first, ids["seat"]), (second, ids["seat"]), (third, other_part.id)):
            s.add(m.Assignment(pair_id=pair.id, part_id=part, method="classifier", method_key="classifier:1",
                               rank=1, material_id=ids["red_leather"]))
        s.flush()
        assert {a.status for a in s.execute(sa.select(m.Alignment)).scalars()} == {"ok"}
        ctx = SimpleNamespace(cfg=FitConfig(refine=True, refine_max_rank=1), source_key="classifier:1")
        # the second pair is past publish's rank but its exemplar's best; the third is neither
        assert [is_refined(s, ctx, p) for p in (first, second, third)] == [True, True, False]
        ctx.cfg = replace(ctx.cfg, refine_max_rank=3)
        assert is_refined(s, ctx, third)
        ctx.cfg = replace(ctx.cfg, refine=False)
        assert not any(is_refined(s, ctx, p) for p in (first, second, third))
        ctx.cfg = FitConfig(refine_max_rank=1)  # the default refines nothing: it relit worse (D66)
        assert not any(is_refined(s, ctx, p) for p in (first, second, third))
