"""The substances stage's part labels again, with a given BatchNorm prior, in a copy of a data root.

    sqlite3 A/photoshape.db ".backup B/photoshape.db"; cp -al A/blobs B/blobs
    PHOTOSHAPE_DATA_ROOT=B python -m experiments.bn_adaptation.relabel --prior none
    PHOTOSHAPE_DATA_ROOT=B python -m experiments.bn_adaptation.compare --a sqlite:///A/photoshape.db \\
        --b sqlite:///B/photoshape.db --groundtruth <groundtruth.json> --source <ingest source>

The stage chooses its substance network's prior on validation renders (D52); this relabels every
aligned part with the newest substance network under another prior, exactly as the stage labels
them (`assign_part_substances`), so the choice's effect on the labels is one paired comparison
(row `substances` of `compare.py`), a couple of minutes at the medium profile. Writes only the
copy's `part_substance` rows; run it on a copy, never on the data root it came from.
"""

from __future__ import annotations

import argparse

from experiments.common import newest_substance_network
from photoshape_flow.classify.substance_configs import read_side_of
from photoshape_flow.config import get_settings
from photoshape_flow.db.session import session_scope
from photoshape_flow.networks.classifiers import load_substance_network
from photoshape_flow.recognition.substances import assign_part_substances
from photoshape_flow.store import BlobStore


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--prior", required=True, help="'none', or the training set's weight N (16, 4, 1)")
    args = parser.parse_args(argv)
    prior = None if args.prior.lower() == "none" else float(args.prior)
    settings = get_settings()
    store = BlobStore(settings.blob_root)
    with session_scope(settings.resolved_database_url) as session:
        row = newest_substance_network(session)
        network, side, network_id = load_substance_network(row, store, "cpu"), read_side_of(row.config), row.id
    print(assign_part_substances(settings, network_id, network, side, bn_prior=prior, store=store))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
