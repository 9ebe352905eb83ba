"""The synthetic scenes' predictor path: plans draw n(ε) futures from the scene's own model, and
the risk dial's final check keeps or refuses the request honestly."""

from __future__ import annotations

import csv
import math

import jax
import numpy as np
import pytest
from scipy.stats import binom

import frenet
import mmdopt
from mmdopt.bench.frontier import run_frontier
from mmdopt.bench.scenes import SceneParams, make_scene
from mmdopt.risk import samples_for_risk

TINY = mmdopt.MMDOptConfig().replace(
    n_samples=60, n_cem=20, n_elite=8, iterations=3, n_brake=4, reduced_set_size=10
)


def _left_share(xy: np.ndarray) -> np.ndarray:
    """Whether each future ends nearer the left lane (3.5 m) than the ego lane (0 m)."""
    return xy[..., -1, 1] > 1.75


def test_scene_predictor_draws_from_the_scenes_distribution_independently():
    scene = make_scene(2, seed=11, params=SceneParams(n_samples=50, n_validation=400))
    fc = scene.forecast()
    n = 3000
    xy = fc.predictor.sample(fc.history, fc.context, n, jax.random.PRNGKey(5))
    assert xy.shape == (1, n, 100, 2) and np.all(np.isfinite(xy))
    # the intents' shares: within the 99.9 % binomial range of the scene's probabilities
    left = int(_left_share(xy[0]).sum())
    p_left = float(scene.intent_probs[1])
    lo, hi = binom.ppf([0.0005, 0.9995], n, p_left)
    assert lo <= left <= hi, (left, n * p_left)
    # the speed set-points reach the same spread of positions as the scene's own samples
    end = xy[0, :, -1, 0]
    ref = scene.validation[0, :, -1, 0]
    assert abs(np.median(end) - np.median(ref)) < 5.0
    # deterministic per key, different across keys, and none is a validation or planning future
    again = fc.predictor.sample(fc.history, fc.context, n, jax.random.PRNGKey(5))
    np.testing.assert_array_equal(xy, again)
    other = fc.predictor.sample(fc.history, fc.context, n, jax.random.PRNGKey(6))
    assert not np.allclose(xy[0, :50], other[0, :50])
    for fixed in (scene.validation[0], scene.obstacles[0]):
        d = np.abs(xy[0, :200, None, -1, 0] - fixed[None, :, -1, 0]).min()
        assert d > 1e-9
    with pytest.raises(ValueError, match="n must"):
        fc.predictor.sample(fc.history, fc.context, 0, jax.random.PRNGKey(5))


def test_forecast_frontier_rows_record_the_futures_the_risk_level_needs(tmp_path):
    params = SceneParams(n_samples=40, n_validation=300)
    res = run_frontier(
        tmp_path / "f", risks={"random": [0.02]}, methods=["random"], scenes=1, seed=4,
        params=params, config=TINY, progress=False, forecast=True,
    )  # fmt: skip
    (row,) = res["rows"]
    assert row["n_planning"] == row["n_samples"] == samples_for_risk(0.02, 1) == 149
    with open(tmp_path / "f" / "frontier.csv") as f:
        (csv_row,) = list(csv.DictReader(f))
    assert int(csv_row["n_planning"]) == 149
    assert res["points"][0]["n_planning"] == 149
    # an "ok" status is a kept promise on the futures the plan met
    if row["status"].startswith("ok"):
        assert row["risk_bound"] <= 0.02


def _ahead_and_beside(n: int, on_start: int) -> np.ndarray:
    """(1, n, K, 2) futures of one car: ``on_start`` of them begin on the ego's own position (no
    plan can avoid them), the others drive 60 m ahead in the left lane."""
    t = frenet.TimeGrid(TINY.trajectory.horizon, TINY.trajectory.num_steps).t
    rng = np.random.default_rng(0)
    v = 5.0 + rng.normal(0.0, 0.5, n)
    s = np.where(np.arange(n)[:, None] < on_start, -30.0 + 0.0 * t, 60.0 + v[:, None] * t)
    s[:on_start, 0] = 0.0  # on the ego at t = 0
    d = np.where(np.arange(n)[:, None] < on_start, 0.0, 3.5) + 0.0 * t
    return np.stack([s, d], -1)[None]


def test_final_check_keeps_a_reachable_risk_and_refuses_an_unreachable_one():
    ego = frenet.EgoState(vs=10.0)
    key = jax.random.PRNGKey(3)
    n = samples_for_risk(0.05, 1)
    # every future is avoidable: the plan's bound over all its samples is <= ε, status ok
    p = mmdopt.plan_frenet(ego, mmdopt.Road(), _ahead_and_beside(n, 0), config=TINY, key=key,
                           risk=0.05, method="mmd")  # fmt: skip
    assert p.status == "ok" and p.risk_bound <= 0.05, p.status_text
    assert p.diagnostics["final_check_bounds"][p.diagnostics["final_check_choice"]] <= 0.05
    # 5 futures start on the ego: no plan can avoid them, so no candidate's bound is <= ε;
    # the plan says so instead of a silent "ok"
    q = mmdopt.plan_frenet(ego, mmdopt.Road(), _ahead_and_beside(n, 5), config=TINY, key=key,
                           risk=0.05, method="mmd")  # fmt: skip
    assert q.status == "risk exceeded" and q.risk_bound > 0.05, q.status_text
    bounds = q.diagnostics["final_check_bounds"]
    assert math.isclose(q.risk_bound, float(np.min(bounds)))
