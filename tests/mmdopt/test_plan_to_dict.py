"""Plan.to_dict(): a plan as plain JSON-able data."""

from __future__ import annotations

import json

import numpy as np
import pytest

import frenet
import mmdopt


def _plan(**kw):
    cfg = mmdopt.MMDOptConfig().replace(n_cem=40, n_elite=10, iterations=2, n_brake=5)
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, cfg.trajectory.horizon, cfg.trajectory.num_steps)
    n = 30
    x = 50.0 + rng.uniform(4.0, 6.0, (n, 1)) * t
    y = np.where(np.arange(n)[:, None] < 5, -3.0 + 0.2 * t.clip(0, 15), -3.0)
    obs = np.stack([x, np.broadcast_to(y, x.shape)], -1)[None]
    road = mmdopt.Road(y_lb=-0.3, y_ub=0.3)
    ego = frenet.EgoState(s=0.0, d=0.0, vs=10.0)
    return mmdopt.plan(ego, road, obs, config=cfg, **kw)


@pytest.mark.slow
def test_to_dict_is_json_and_round_trips_the_trajectory_and_reduced_set():
    p = _plan()
    d = p.to_dict()
    back = json.loads(json.dumps(d, allow_nan=False))  # strict JSON: no NaN, no arrays
    np.testing.assert_allclose(back["x"], p.x)
    np.testing.assert_allclose(back["speed"], p.speed)
    assert back["status"] == p.status and back["method"] == "mmd"
    assert back["feasible"] is bool(p.feasible)
    rs = back["reduced_set"]
    assert rs["indices"] == np.asarray(p.reduced_set.indices).tolist()
    np.testing.assert_allclose(np.sum(rs["weights"], axis=1), 1.0, atol=1e-6)
    assert "state" not in back and "diagnostics" in back
    assert "diagnostics" not in p.to_dict(diagnostics=False)


def test_to_dict_of_a_braking_fallback_has_no_nan():
    # initial speed above v_max: a braking plan with a NaN cost
    cfg = mmdopt.MMDOptConfig().replace(n_cem=40, n_elite=10, iterations=2, n_brake=5)
    obs = np.zeros((1, 20, cfg.trajectory.num_steps, 2)) + np.array([300.0, 0.0])
    p = mmdopt.plan(
        frenet.EgoState(s=0.0, d=0.0, vs=40.0), mmdopt.Road(v_max=30.0), obs, config=cfg
    )
    assert p.fallback
    d = json.loads(json.dumps(p.to_dict(), allow_nan=False))
    assert d["cost"] is None and d["fallback"] is True
