"""The assignment-set key changes exactly when what a PhotoShape shows changes."""

from __future__ import annotations

import sqlalchemy as sa
from tests.db.seed import seed

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.publish.photoshapes import assignment_set_keys


def test_key_follows_the_rank1_rows(db_url: str) -> None:
    with session_scope(db_url) as session:
        ids = seed(session)
        pair, key = ids["pair"], f"classifier:{ids['classifier']}"
        wanted = [(pair, key), (pair, "color-match"), (pair + 99, key)]
        first = assignment_set_keys(session, wanted)
        assert set(first) == {(pair, key), (pair, "color-match")}  # no rows, no key
        assert first[(pair, key)] != first[(pair, "color-match")]
        assert assignment_set_keys(session, wanted) == first  # stable
        rank2 = session.execute(sa.select(m.Assignment).where(m.Assignment.rank == 2)).scalar_one()
        rank2.score = 0.01  # below rank 1: nothing shown changes
        session.flush()
        assert assignment_set_keys(session, wanted) == first
        seat = session.execute(sa.select(m.Assignment).where(m.Assignment.rank == 1, m.Assignment.unobserved)
                               ).scalar_one()
        seat.params = {"uv": {"scale": 2.0, "rotation": 0.0, "offset": [0, 0]}}
        session.flush()
        after = assignment_set_keys(session, wanted)
        assert after[(pair, key)] != first[(pair, key)]
        assert after[(pair, "color-match")] == first[(pair, "color-match")]
