"""Conditional-logit fit of the fit cost's weights and temperature on synthetic cases."""

from __future__ import annotations

import numpy as np
import pytest

from photoshape_flow.fit.calibrate import TERMS, Case, Fit, fit, fit_temperature, folds, score


def _cases(theta: np.ndarray, n: int, seed: int = 0, candidates: int = 6) -> list[Case]:
    """Cases whose true candidate is drawn from softmax(-X theta): the model the fit assumes."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        x = rng.gamma(2.0, 0.5, (candidates, len(TERMS)))
        logits = -x @ theta
        p = np.exp(logits - logits.max())
        out.append(Case(x, int(rng.choice(candidates, p=p / p.sum())), group=f"r{i // 3}"))
    return out


def test_recovers_known_weights_and_temperature() -> None:
    true = Fit((0.4, 0.2, 0.1, 0.1, 0.2, 0.0), 0.25)
    fitted = fit(_cases(true.theta, 3000), l2=0.0)
    assert np.allclose(fitted.weights, true.weights, atol=0.06), fitted
    assert fitted.temperature == pytest.approx(true.temperature, rel=0.15)


def test_a_term_without_information_gets_no_weight() -> None:
    theta = np.array([3.0, 0.0, 2.0, 1.0, 1.5, 1.0])  # contrast never decides the true candidate
    fitted = fit(_cases(theta, 2000, seed=1))
    assert fitted.weights[1] < 0.03 < min(fitted.weights[0], *fitted.weights[2:]), fitted


def test_fitted_beats_wrong_weights_on_held_out_cases_and_temperature_alone_helps() -> None:
    theta = np.array([4.0, 0.5, 0.0, 1.0, 1.0, 1.5])
    train, test = folds(_cases(theta, 1200, seed=2))
    assert train and test and not {c.group for c in train} & {c.group for c in test}
    wrong = np.array([0.0, 1.0, 1.0, 0.0, 0.0, 0.0])
    fitted = fit(train)
    assert score(fitted.theta, test).log_loss < score(wrong, test).log_loss
    t = fit_temperature(train, wrong)
    assert score(wrong / t, test).log_loss <= score(wrong, test).log_loss + 1e-9


def test_unusable_cases_are_refused() -> None:
    with pytest.raises(ValueError):
        fit([Case(np.ones((1, 6)), 0), Case(np.full((3, 6), np.nan), 0)])


def test_few_cases_stay_near_the_centre_many_cases_leave_it() -> None:
    theta = np.array([3.0, 0.0, 2.0, 1.0, 1.5, 1.0])
    centre = np.array([1.0, 0.5, 0.5, 0.5, 0.5, 0.3])
    few = fit(_cases(theta, 4, seed=3), centre=centre, start=centre, l2=50.0).theta
    many = fit(_cases(theta, 2000, seed=3), centre=centre, start=centre, l2=50.0).theta
    assert np.linalg.norm(few - centre) < np.linalg.norm(many - centre)
    assert np.linalg.norm(many - theta) < np.linalg.norm(centre - theta)


def test_the_calibration_keeps_the_model_with_the_lowest_held_out_loss() -> None:
    """Cases drawn from the hand-set weights themselves: with few of them the held-out figures keep the
    hand-set weights (fitting six numbers only adds noise); with many drawn from other weights, the fit (D48)."""
    from photoshape_flow.fitting.calibration import MODELS, choices, held_out, refit
    from photoshape_flow.profiles import FitConfig

    cfg = FitConfig()
    base = np.array([cfg.color_weight, cfg.contrast_weight, cfg.gradient_weight, cfg.highlight_weight,
                     cfg.deep_weight, cfg.prior_weight])
    for cases, want in ((_cases(base, 40, seed=4), {"hand_set", "hand_set_temperature"}),
                        (_cases(np.array([0.2, 2.0, 0.0, 1.0, 0.5, 0.1]), 1500, seed=5), {"fitted"})):
        ranked = sorted(choices(held_out(cases, cfg), cases, base))
        assert [m for _, m in sorted(ranked, key=lambda r: r[1])] == sorted(MODELS)
        assert ranked[0][1] in want, ranked
    kept = refit("hand_set", cases, base)
    assert np.allclose(kept.theta, base) and np.allclose(refit("fitted", cases, base).theta,
                                                         fit(cases, start=base, centre=base).theta)
    scaled = refit("hand_set_temperature", cases, base)
    assert np.allclose(np.asarray(scaled.weights), base / base.sum())
    assert scaled.temperature == pytest.approx(fit_temperature(cases, base) / base.sum())


def test_the_fit_calibrations_key_ignores_the_refinements_settings_and_follows_the_selections() -> None:
    from dataclasses import replace
    from types import SimpleNamespace

    from photoshape_flow.db import models as m
    from photoshape_flow.fitting.calibration import calibration_key
    from photoshape_flow.profiles import FitConfig

    def key(cfg: FitConfig) -> str:
        ctx = SimpleNamespace(params={"code": "fit-9"}, cfg=cfg, material_substance={1: "wood"},
                              envmaps={1: "studio"}, classifier=m.Classifier(checkpoint_blob="ab", metrics={}))
        return calibration_key(ctx, [], 0)

    plain = FitConfig()
    assert key(replace(plain, refine=True, refine_uv=True, refine_iterations=8)) == key(plain)
    assert key(replace(plain, top_k=3)) != key(plain)
