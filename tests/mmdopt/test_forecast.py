"""Planning from a predictor: plan() draws as many futures as the risk level needs."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import frenet
import mmdopt
from mmdopt.config import MMD_RISK_HITS
from mmdopt.predict import GAP_NONE, ConstantVelocity, Forecast, PredictionContext
from mmdopt.risk import samples_for_risk

CFG = mmdopt.MMDOptConfig().replace(
    n_samples=60, n_cem=30, n_elite=10, iterations=3, n_brake=2, reduced_set_size=5
)


def _forecast(**kw) -> Forecast:
    """One car 40 m ahead at 6 m/s in the ego's lane, on the planner's grid."""
    t = frenet.TimeGrid(CFG.trajectory.horizon, CFG.trajectory.num_steps).t
    past = np.arange(-9, 1) * 0.1
    history = np.stack([40.0 + 6.0 * past, 0.0 * past], axis=-1)[None]
    lane = np.stack([np.linspace(-100.0, 400.0, 51), np.zeros(51)], axis=-1)[None]
    context = PredictionContext(
        times=t, dt_history=0.1, centerline=lane, lane_width=np.array([3.5]),
        has_left=np.array([False]), has_right=np.array([False]),
        gaps=np.full((1, 6), GAP_NONE), rel_speed=np.zeros((1, 6)),
    )  # fmt: skip
    return Forecast(ConstantVelocity(), history, context, **kw)


EGO = frenet.EgoState(vs=10.0)


@pytest.mark.slow
def test_plan_draws_the_futures_the_risk_level_needs_and_confirms_it():
    key = jax.random.PRNGKey(0)
    fc = _forecast(min_samples=10)
    p = mmdopt.plan(EGO, mmdopt.Road(), fc, config=CFG, key=key, risk=0.05)
    # MMD-Opt draws enough for a plan that meets MMD_RISK_HITS of them to keep its bound
    n = samples_for_risk(0.05, 1, hits=MMD_RISK_HITS)  # 1041 for 40 hits
    assert n > samples_for_risk(0.05, 1)  # 59: the fewest that can confirm ε at all
    assert p.diagnostics["forecast_samples"] == n == p.diagnostics["n_planning_samples"]
    assert p.status == "ok" and p.risk_bound <= 0.05, p.status_text
    # the same key gives the same futures and the same plan
    q = mmdopt.plan(EGO, mmdopt.Road(), fc, config=CFG, key=key, risk=0.05)
    np.testing.assert_array_equal(p.x, q.x)
    # at least min_samples (default 100) are drawn even when fewer would do
    r = mmdopt.plan(
        EGO, mmdopt.Road(), _forecast(), config=CFG.replace(risk_hits=2), key=key, risk=0.2
    )  # n(0.2) = 30 for 2 hits
    assert r.diagnostics["forecast_samples"] == 100
    # the baselines (and MMD-Opt with risk_hits=0) draw the fewest that can confirm ε
    s = mmdopt.plan(EGO, mmdopt.Road(), fc, config=CFG.replace(risk_hits=0), key=key, risk=0.05)
    assert s.diagnostics["forecast_samples"] == samples_for_risk(0.05, 1)


def test_a_cap_below_the_need_is_said_in_the_status():
    # a cap of 100 (the shape the test above compiled), above min_samples
    fc = _forecast(min_samples=10, max_samples=100)
    p = mmdopt.plan(EGO, mmdopt.Road(), fc, config=CFG, key=jax.random.PRNGKey(1), risk=1e-3)
    assert p.diagnostics["forecast_samples"] == 100
    # the hits-driven need, limited by the futures budget but never below n(ε) with no hit
    budget = CFG.schedule.futures_budget
    fewest = samples_for_risk(1e-3, 1)
    need = min(samples_for_risk(1e-3, 1, hits=MMD_RISK_HITS), max(fewest, budget))
    assert p.diagnostics["forecast_samples_needed"] == need > 100
    assert p.status == "risk floor" and f"{samples_for_risk(1e-3, 1)} samples" in p.message


def test_without_a_risk_level_it_draws_min_samples():
    cfg = CFG.replace(margin_mode="linear")
    p = mmdopt.plan(EGO, mmdopt.Road(), _forecast(min_samples=30), config=cfg)
    assert p.diagnostics["forecast_samples"] == 30


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: Forecast(object(), np.zeros((1, 3, 2)), _forecast().context), "predictor"),
        (lambda: _forecast(min_samples=0), "min_samples"),
        (lambda: _forecast(min_samples=50, max_samples=10), "max_samples"),
        (lambda: Forecast(ConstantVelocity(), np.zeros((2, 3, 2)), _forecast().context), "history"),
    ],
)
def test_bad_forecasts_name_the_field(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_a_context_off_the_planner_grid_is_refused():
    cfg = CFG.replace(horizon=10.0)
    with pytest.raises(ValueError, match="context.times"):
        mmdopt.plan(EGO, mmdopt.Road(), _forecast(), config=cfg)


class _SlowPredictor(ConstantVelocity):
    """A constant-velocity predictor that takes 0.3 s to draw (a learned model's forward pass)."""

    def sample(self, history, context, n, key):
        import time

        time.sleep(0.3)
        return super().sample(history, context, n, key)


def test_the_predictors_draw_is_timed_apart_from_the_plan():
    """``predict_time_s`` is the predictor's draw; ``plan_time_s`` leaves it out."""
    import dataclasses
    import time

    fc = dataclasses.replace(_forecast(), predictor=_SlowPredictor())
    cfg = CFG.replace(risk_hits=0)
    mmdopt.plan(EGO, mmdopt.Road(), fc, config=cfg, risk=0.05)  # compiled
    t0 = time.perf_counter()
    p = mmdopt.plan(EGO, mmdopt.Road(), fc, config=cfg, risk=0.05)
    wall = time.perf_counter() - t0
    assert p.predict_time_s >= 0.3
    assert p.plan_time_s + p.predict_time_s <= wall + 1e-6
    assert p.plan_time_s <= wall - 0.3
    fixed = mmdopt.plan(EGO, mmdopt.Road(), fc.predictor.sample(
        fc.history, fc.context, 60, jax.random.PRNGKey(0)), config=cfg)  # fmt: skip
    assert fixed.predict_time_s == 0.0
