"""Predictor protocol: shapes on the planner's grid, determinism by key, input checks, the
lane frame, and the shipped learned model (synthetic lanes: no data files needed)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from mmdopt.predict import (
    GAP_NONE,
    ConstantVelocity,
    LaneAware,
    PredictionContext,
    cartesian_to_lane,
    evaluate_predictor,
    kde_nll,
    lane_to_cartesian,
    make_predictor,
    min_ade_fde,
)
from mmdopt.predict.train import Window

TIMES = np.linspace(0.0, 5.0, 51)


def _curved_lane(x0: float, y0: float, kappa: float = 1e-3, P: int = 101) -> np.ndarray:
    s = np.linspace(-30.0, 170.0, P)
    th = kappa * s
    return np.stack([x0 + np.sin(th) / kappa, y0 + (1 - np.cos(th)) / kappa], -1)


def _make(O: int = 3, vx: float = 12.0, **overrides):
    """O cars in three lanes of a gently curved road, driving at vx along it."""
    lanes = [_curved_lane(0.0, 3.5 * (o % 3)) for o in range(O)]
    hist = np.empty((O, 10, 2))
    for o in range(O):
        s = vx * (np.arange(10) - 9) * 0.1 + 5.0 * o
        hist[o] = lane_to_cartesian(lanes[o], s, np.zeros(10))
    kw = dict(
        times=TIMES,
        dt_history=0.1,
        centerline=np.stack(lanes),
        lane_width=np.full(O, 3.5),
        has_left=np.array([o % 3 < 2 for o in range(O)]),
        has_right=np.array([o % 3 > 0 for o in range(O)]),
        gaps=np.full((O, 6), GAP_NONE),
        rel_speed=np.zeros((O, 6)),
    )
    kw.update(overrides)
    return hist, PredictionContext(**kw)


PREDICTORS = [ConstantVelocity(), LaneAware()]


@pytest.fixture(scope="module")
def learned():
    return make_predictor("learned")


@pytest.mark.parametrize("pred", PREDICTORS, ids=lambda p: p.name)
def test_samples_are_on_the_planner_grid_and_start_at_the_car(pred):
    hist, ctx = _make(O=3)
    s = pred.sample(hist, ctx, 7, jax.random.PRNGKey(0))
    assert s.shape == (3, 7, len(TIMES), 2)
    assert np.all(np.isfinite(s))
    np.testing.assert_allclose(s[:, :, 0], np.broadcast_to(hist[:, None, -1], (3, 7, 2)), atol=0.05)


@pytest.mark.parametrize("pred", PREDICTORS, ids=lambda p: p.name)
def test_same_key_same_samples_other_key_other_samples(pred):
    hist, ctx = _make(O=4)
    a = pred.sample(hist, ctx, 20, jax.random.PRNGKey(3))
    b = pred.sample(hist, ctx, 20, jax.random.PRNGKey(3))
    c = pred.sample(hist, ctx, 20, jax.random.PRNGKey(4))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_learned_loads_shipped_weights_samples_finite_and_deterministic(learned):
    hist, ctx = _make(O=5)
    a = learned.sample(hist, ctx, 50, jax.random.PRNGKey(0))
    b = learned.sample(hist, ctx, 50, jax.random.PRNGKey(0))
    assert a.shape == (5, 50, len(TIMES), 2) and np.all(np.isfinite(a))
    np.testing.assert_array_equal(a, b)
    # a car at 12 m/s travels roughly 60 m in 5 s, not 0 and not 200
    travelled = np.linalg.norm(a[:, :, -1] - a[:, :, 0], axis=-1)
    assert 30.0 < np.median(travelled) < 90.0
    assert learned.meta["info"]["n_train"] > 1000


def test_learned_spread_scales_the_sample_dispersion_and_is_validated(learned):
    """``Learned(spread=s)`` scales every component's σ: the same modes and means (same key), the
    spread of the travelled distance grows with s, and s = 1 is the default bit for bit."""
    hist, ctx = _make(O=3)
    key = jax.random.PRNGKey(2)
    base = learned.sample(hist, ctx, 400, key)
    np.testing.assert_array_equal(
        make_predictor("learned", spread=1.0).sample(hist, ctx, 400, key), base
    )

    # the same key draws the same modes and normals: the deviation from the mode's mean
    # trajectory (spread → 0) doubles at s = 2 (up to the curved lane's nonlinearity)
    mean = make_predictor("learned", spread=1e-9).sample(hist, ctx, 400, key)
    wide = make_predictor("learned", spread=2.0).sample(hist, ctx, 400, key)
    np.testing.assert_allclose(wide - mean, 2.0 * (base - mean), rtol=0.2, atol=0.1)
    assert np.abs(base - mean).max() > 1.0  # the components have a spread to scale
    for bad in (0.0, -1.0, float("nan"), float("inf"), True, "2"):
        with pytest.raises(ValueError, match="spread"):
            make_predictor("learned", spread=bad)


def test_learned_refuses_a_horizon_longer_than_it_was_trained_for(learned):
    hist, ctx = _make(O=2, times=np.linspace(0.0, 15.0, 100))
    with pytest.raises(ValueError, match="predicts only"):
        learned.sample(hist, ctx, 5, jax.random.PRNGKey(0))


def test_lane_aware_mode_weights_follow_lateral_motion_and_missing_lanes():
    hist, ctx = _make(O=3)
    w = LaneAware().mode_weights(hist, ctx)
    np.testing.assert_allclose(w.sum(1), 1.0)
    assert w[0, 2] == 0.0 and w[2, 1] == 0.0  # no lane right of lane 0 / left of lane 2
    assert np.all(w[:, 0] > 0.7)  # straight driving: keep lane dominates
    drift = hist.copy()
    drift[1] = lane_to_cartesian(
        ctx.centerline[1], 12.0 * (np.arange(10) - 9) * 0.1 + 5.0, 0.1 * np.arange(10)
    )  # moving left at 1 m/s
    w2 = LaneAware().mode_weights(drift, ctx)
    assert w2[1, 1] > 0.5 > w[1, 1]


def test_lane_change_samples_reach_the_next_lane():
    hist, ctx = _make(O=1, has_left=np.array([True]))
    s = LaneAware().sample(hist, ctx, 400, jax.random.PRNGKey(1))
    _, d = cartesian_to_lane(ctx.centerline[0], s[0, :, -1])
    assert np.any(d > 3.0) and np.any(np.abs(d) < 0.5)


def test_lane_frame_round_trip_on_a_curved_lane():
    poly = _curved_lane(10.0, -5.0, kappa=3e-3)
    rng = np.random.default_rng(0)
    s = rng.uniform(-40, 190, 500)
    d = rng.uniform(-5, 5, 500)
    s2, d2 = cartesian_to_lane(poly, lane_to_cartesian(poly, s, d))
    np.testing.assert_allclose(s2, s, atol=1e-3)
    np.testing.assert_allclose(d2, d, atol=1e-3)


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(hist=np.full((3, 10, 2), np.nan)), "NaN"),
        (dict(hist=np.zeros((3, 10))), "shape"),
        (dict(hist=np.zeros((2, 10, 2))), "obstacles"),
        (dict(n=0), "n must"),
        (dict(key=3), "key"),
    ],
)
def test_bad_inputs_raise_naming_the_argument(change, match):
    hist, ctx = _make(O=3)
    kw = dict(hist=hist, n=5, key=jax.random.PRNGKey(0))
    kw.update(change)
    with pytest.raises(ValueError, match=match):
        LaneAware().sample(kw["hist"], ctx, kw["n"], kw["key"])


def test_context_rejects_bad_arrays():
    with pytest.raises(ValueError, match="times"):
        _make(times=np.array([0.5, 1.0]))
    with pytest.raises(ValueError, match="gaps"):
        _make(gaps=np.zeros((3, 5)))
    with pytest.raises(ValueError, match="centerline"):
        _make(centerline=np.zeros((3, 5, 2)))
    with pytest.raises(ValueError, match="predictor must be"):
        make_predictor("oracle")


def test_metrics_prefer_the_predictor_that_contains_the_truth():
    hist, ctx = _make(O=2)
    truth = ConstantVelocity(0.0, 0.0).sample(hist, ctx, 1, jax.random.PRNGKey(0))[:, 0]
    good = ConstantVelocity(0.3, 0.05).sample(hist, ctx, 50, jax.random.PRNGKey(1))
    bad = good + np.array([0.0, 4.0])
    ade_g, fde_g = min_ade_fde(good, truth)
    ade_b, _ = min_ade_fde(bad, truth)
    assert np.all(ade_g < 0.5) and np.all(ade_b > 3.0) and np.all(fde_g >= 0)
    assert np.all(kde_nll(good, truth) < kde_nll(bad, truth))
    r = evaluate_predictor(ConstantVelocity(), [Window(hist, ctx, truth)], jax.random.PRNGKey(0))
    assert r["n_vehicles"] == 2 and r["min_ade"] < 0.5


def test_predict_does_not_import_the_benchmarks_or_commonroad():
    import subprocess
    import sys

    code = (
        "import sys, mmdopt.predict, mmdopt.predict.learned, mmdopt.predict.train; "
        "bad = [m for m in sys.modules if m.startswith(('mmdopt.bench', 'commonroad'))]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_neighbour_gaps_fill_the_six_slots_with_the_nearest_vehicle():
    from mmdopt.predict.base import GAP_NONE, neighbour_gaps

    # ahead in lane at 20 and 35 m, behind left at 8 m, one far ahead right (beyond GAP_NONE)
    ds = np.array([20.0, 35.0, -8.0, 150.0])
    d = np.array([0.3, -0.2, 3.6, -3.7])
    dv = np.array([1.0, 2.0, -3.0, 4.0])
    gaps, rel = neighbour_gaps(ds, d, dv, lane_width=3.7)
    np.testing.assert_array_equal(gaps, [20.0, GAP_NONE, GAP_NONE, 8.0, GAP_NONE, GAP_NONE])
    np.testing.assert_array_equal(rel, [1.0, 0.0, 0.0, -3.0, 0.0, 0.0])
