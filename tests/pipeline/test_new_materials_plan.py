"""The material-added planner (which stages a trigger runs vs the nightly), the changed-parts counts,
and publish's method: pure steps and one real stage function on a seeded database."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from photoshape_flow.fitting.changes import FitChanges, PartFit, fit_changes
from photoshape_flow.stages import REGISTRY, WorkUnit
from photoshape_flow.stages.new_materials import rerun_stages


def test_a_trigger_fits_first_and_leaves_retraining_to_the_nightly_run() -> None:
    assert rerun_stages(REGISTRY, "material", "triggered") == ["fit", "publish"]
    assert rerun_stages(REGISTRY, "material", "nightly") == [
        "substances", "training-renders", "training", "inference", "fit", "publish"]


def _stage(name: str, reads: tuple[str, ...], writes: tuple[str, ...], retraining: bool = False) -> SimpleNamespace:
    return SimpleNamespace(name=name, reads=reads, writes=writes, retraining=retraining)


def test_what_only_a_retraining_stage_changes_is_not_rerun_by_a_trigger() -> None:
    registry = [
        _stage("ingest", (), ("material",)),
        _stage("train", ("material",), ("model",), retraining=True),
        _stage("apply", ("model",), ("ranking",)),  # reads only what training writes
        _stage("fit", ("ranking", "material"), ("ranking",)),
        _stage("publish", ("ranking",), ("render",)),
        _stage("unrelated", ("shape",), ("pair",)),
    ]
    assert rerun_stages(registry, "material", "triggered") == ["fit", "publish"]
    assert rerun_stages(registry, "material", "nightly") == ["train", "apply", "fit", "publish"]
    assert rerun_stages(registry, "shape", "triggered") == ["unrelated"]


def test_fit_changes_counts_grown_changed_and_won_parts() -> None:
    old, new = 7, 42
    before = {
        (1, 10): PartFit(3, frozenset({3, old})),
        (1, 11): PartFit(3, frozenset({3, old})),
        (2, 10): PartFit(5, frozenset({5})),
        (2, 12): PartFit(6, frozenset({6})),  # unobserved: its copied ranking, unchanged
    }
    after = {
        (1, 10): PartFit(new, frozenset({3, old, new})),  # grew, changed, won by the new material
        (1, 11): PartFit(old, frozenset({3, old, new})),  # grew, changed to an older material
        (2, 10): PartFit(5, frozenset({5, new})),  # grew, kept its winner
        (2, 12): PartFit(6, frozenset({6})),
        (3, 10): PartFit(new, frozenset({new})),  # fitted for the first time
    }
    assert fit_changes(before, after, [new]) == FitChanges(parts=5, grown=4, changed=3, won_by_new=2)
    assert fit_changes(after, after, [new]) == FitChanges(parts=5, grown=0, changed=0, won_by_new=2)
    assert fit_changes({}, {}, [new]) == FitChanges()


def test_a_work_unit_keeps_only_the_affected_items_in_its_order() -> None:
    assert WorkUnit("pairs", (5, 1, 9, 3)).only([3, 9, 100]) == WorkUnit("pairs", (9, 3))
    assert WorkUnit("pairs", (5,)).only([]).ids == ()


def test_publish_method_is_a_validated_profile_field() -> None:
    from photoshape_flow.profiles import ProfileError, resolve_profile

    assert resolve_profile("tiny").profile.publish.method == "fit"  # D46
    assert resolve_profile("tiny", ["publish.method=classifier"]).profile.publish.method == "classifier"
    assert resolve_profile("tiny", ["publish.method=fit"]).profile.publish.method == "fit"
    with pytest.raises(ProfileError, match="publish.method"):
        resolve_profile("tiny", ["publish.method=colour"])


def test_publish_up_to_date_check_is_keyed_by_the_chosen_methods_assignment_set(db_url: str) -> None:
    from tests.db.seed import seed

    from photoshape_flow.db.session import session_scope
    from photoshape_flow.profiles import resolve_profile
    from photoshape_flow.publish.photoshapes import assignment_set_keys
    from photoshape_flow.publish.publish_stage import versions
    from photoshape_flow.stages import StageContext

    with session_scope(db_url) as session:
        ids = seed(session)
    pair, clf = ids["pair"], ids["classifier"]
    ctx = StageContext.create()
    unit = WorkUnit("pairs", (pair,))
    keyed = {method: versions(ctx, resolve_profile("tiny", [f"publish.method={method}"]).profile.publish, unit)
             for method in ("classifier", "fit")}
    with session_scope(db_url) as session:
        keys = assignment_set_keys(session, [(pair, f"classifier:{clf}"), (pair, f"fit:{clf}")])
    assert keyed["classifier"] == {pair: keys[(pair, f"classifier:{clf}")]}
    assert keyed["fit"] == {pair: keys[(pair, f"fit:{clf}")]} != keyed["classifier"]


def test_the_gallery_lists_the_candidates_of_the_chosen_method(db_url: str, settings_env) -> None:  # type: ignore[no-untyped-def]
    from tests.db.seed import seed

    from photoshape_flow.db.session import session_scope
    from photoshape_flow.profiles import resolve_profile
    from photoshape_flow.publish.publish_stage import finish
    from photoshape_flow.stages import StageContext

    with session_scope(db_url) as session:
        ids = seed(session)
    pair, clf = ids["pair"], ids["classifier"]
    for method in ("classifier", "fit"):
        report = finish(StageContext.create(), resolve_profile("tiny", [f"publish.method={method}"]).profile.publish)
        listed = (settings_env / "gallery" / "candidates.html").read_text()
        assert report.details["method"] == method
        assert f'href="pairs/{pair}-{method}-{clf}.html"' in listed
        other = "fit" if method == "classifier" else "classifier"
        assert f'href="pairs/{pair}-{other}-{clf}.html"' not in listed
