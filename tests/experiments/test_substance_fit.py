"""`experiments.substance_fit`: the confusion, the size split and the per-photo reads it pairs."""

from __future__ import annotations

from experiments.substance_fit.run import by_photo, summarise

from photoshape_flow.vocab import SUBSTANCES


def test_summary_counts_truth_by_read_and_splits_small_parts() -> None:
    reads = [("p1", "leather", "leather", 0.30), ("p1", "leather", "wood", 0.010),
             ("p2", "metal", "plastic", 0.005), ("p2", "wood", "wood", 0.20)]
    summary = summarise(reads, small=0.015)
    assert summary["parts"] == 4 and summary["accuracy"] == 0.5
    assert (summary["small_parts"], summary["small"]) == (2, 0.0)
    assert (summary["larger_parts"], summary["larger"]) == (2, 1.0)
    assert summary["recall"] == {"leather": 0.5, "wood": 1.0, "metal": 0.0}
    confusion = summary["confusion"]
    assert confusion[SUBSTANCES.index("leather")][SUBSTANCES.index("wood")] == 1
    assert confusion[SUBSTANCES.index("metal")][SUBSTANCES.index("plastic")] == 1
    assert sum(map(sum, confusion)) == 4


def test_reads_outside_the_vocabulary_are_not_scored_and_photos_keep_their_parts() -> None:
    reads = [("p1", "leather", "background", 0.3), ("p1", "fabric", "fabric", 0.3), ("p2", "wood", "metal", 0.3)]
    assert summarise(reads, small=0.015)["parts"] == 2
    assert by_photo(reads) == {"p1": [0.0, 1.0], "p2": [0.0]}


def test_an_ensemble_averages_every_member_at_every_scale_of_its_read_size(monkeypatch) -> None:
    import numpy as np
    from experiments.substance_fit import run

    seen: list[tuple[str, int]] = []

    def fake_read(network: str, size: int, rgb: np.ndarray, labels: np.ndarray) -> np.ndarray:
        seen.append((network, size))
        probs = np.zeros((6, *labels.shape), np.float32)
        probs[1 if network == "a" else 2] = 1.0
        return probs

    monkeypatch.setattr(run, "read", fake_read)
    labels = np.ones((4, 4), np.int64)
    probs = run.read_members([("a", 256), ("b", 128)], [1.0, 0.75], np.zeros((4, 4, 3), np.uint8), labels)
    assert seen == [("a", 256), ("a", 192), ("b", 128), ("b", 96)]  # scales rounded to the network's 32 px step
    assert np.allclose(probs[1], 0.5) and np.allclose(probs[2], 0.5) and np.allclose(probs.sum(0), 1.0)


def test_the_worlds_open_library_photos_are_found_by_the_keys_world_photos_gives(db_url: str, tmp_path) -> None:
    import json

    from experiments.substance_fit import run

    from photoshape_flow.db import models as m
    from photoshape_flow.db.session import session_scope

    truth = tmp_path / "groundtruth.json"
    truth.write_text(json.dumps({"exemplars": [{"source_id": "e0", "open_library": False},
                                               {"source_id": "e1", "open_library": True},
                                               {"source_id": "e4", "open_library": True}]}))
    with session_scope(db_url) as session:  # e4 is not ingested; another source's e1 is not the world's
        rows = [m.Exemplar(source=source, source_id=stem)
                for source, stem in (("world", "e0"), ("world", "e1"), ("other", "e1"))]
        session.add_all(rows)
        session.flush()
        assert run.open_library_photos(session, truth, "world") == {f"exemplar/{rows[1].id}"}
        assert run.open_library_photos(session, truth, None) == {f"exemplar/{rows[1].id}", f"exemplar/{rows[2].id}"}
