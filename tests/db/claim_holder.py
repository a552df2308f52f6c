"""A separate worker process for the claim tests: claims keys, says which it won, holds them, exits.

    python tests/db/claim_holder.py URL STAGE KEY[,KEY...] HOLD_SECONDS [release]

It prints the keys it won on one line, sleeps HOLD_SECONDS (the test may kill it meanwhile), then
releases its claims when told to (a worker finishing cleanly) or just exits (a worker that died).
"""

from __future__ import annotations

import sys
import time

from sqlalchemy.orm import Session

from photoshape_flow.db import claims
from photoshape_flow.db.holder import set_worker_name
from photoshape_flow.db.session import make_engine

HELPER_NAME = "claim test helper"


def main(url: str, stage: str, keys: str, hold: str, *flags: str) -> None:
    set_worker_name(HELPER_NAME)
    engine = make_engine(url)
    with Session(engine) as session, session.begin():
        won = claims.claim(session, stage, keys.split(","), lease_seconds=900)
    print(",".join(won), flush=True)
    time.sleep(float(hold))
    if "release" in flags:
        with Session(engine) as session, session.begin():
            claims.release(session, stage, won)
    engine.dispose()


if __name__ == "__main__":
    main(*sys.argv[1:])
