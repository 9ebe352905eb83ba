"""Algorithm 1 (mmdopt.plan): behaviour on small scenes, determinism, backends, fallbacks, inputs.

One small configuration (200 samples, n_cem 40, n_e 15, N = 5) is shared by every test so that the
jitted solver compiles once per cost mode.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

import frenet
import mmdopt
from mmdopt.collision import collision_free_count

K = 100
T = np.linspace(0.0, 15.0, K)
SMALL = mmdopt.MMDOptConfig().replace(n_samples=200, n_cem=40, n_elite=15, iterations=5, n_brake=5)
EGO = frenet.EgoState(s=0.0, d=0.0, vs=10.0)


def _obstacle(x0=40.0, v=4.0, y=0.0, n=20, jitter=0.0, seed=0):
    """n samples of one obstacle driving along the ego lane at speed v (optionally jittered)."""
    rng = np.random.default_rng(seed)
    vs = v + jitter * rng.standard_normal(n)
    x = x0 + vs[:, None] * T[None]
    return np.stack([x, np.full_like(x, y)], axis=-1)[None]  # (1, n, K, 2)


@pytest.fixture(scope="module")
def road():
    return mmdopt.Road()


@pytest.fixture(scope="module")
def certain_plan(road):
    obs = _obstacle()  # a single-mode (certain) obstacle ahead, slower than the ego
    return obs, mmdopt.plan(EGO, road, obs, config=SMALL, key=jax.random.PRNGKey(0))


@pytest.mark.slow
def test_certain_obstacle_is_avoided_while_making_progress(certain_plan):
    obs, p = certain_plan
    assert p.feasible and not p.fallback
    counts = collision_free_count(p.xy, obs)
    assert int(counts.per_obstacle[0]) == obs.shape[1]  # clear of every sample
    # ... so its bound is the floor of its samples, above the default ε = 0.005: said so
    n = obs.shape[1]
    assert p.risk_bound == pytest.approx(mmdopt.risk.risk_floor([n]))
    assert p.status == "risk floor" and f"the {n} samples" in p.message, p.status_text
    # it follows the obstacle instead of stopping: the obstacle covers 60 m in 15 s
    assert p.progress > 40.0
    assert p.residual <= SMALL.projection.res_tol
    assert p.x.shape == p.y.shape == p.speed.shape == p.vs.shape == (K,)
    assert p.cost_trace.shape == (SMALL.cem.iterations,)


def test_plan_starts_at_the_ego_state(certain_plan):
    _, p = certain_plan
    assert abs(p.s[0] - EGO.s) < 1e-4 and abs(p.d[0] - EGO.d) < 1e-4
    assert abs(p.vs[0] - EGO.vs) < 1e-4
    assert np.allclose(p.x, p.s) and np.allclose(p.y, p.d)  # straight road: Frenet = Cartesian


def test_cost_trace_is_best_so_far_and_returned_plan_has_that_cost(certain_plan):
    _, p = certain_plan
    assert np.all(np.diff(p.cost_trace) <= 1e-9)
    assert p.cost == pytest.approx(p.cost_trace[-1])
    it_min = p.diagnostics["iteration_min_cost"]
    assert p.cost == pytest.approx(np.min(it_min))


def test_same_key_same_plan(road, certain_plan):
    obs, p = certain_plan
    q = mmdopt.plan(EGO, road, obs, config=SMALL, key=jax.random.PRNGKey(0))
    np.testing.assert_array_equal(p.x, q.x)
    assert p.cost == q.cost
    r = mmdopt.plan(EGO, road, obs, config=SMALL, key=jax.random.PRNGKey(1))
    assert not np.array_equal(p.x, r.x)


def test_frenet_entry_point_matches_on_a_straight_road(road, certain_plan):
    obs, p = certain_plan
    q = mmdopt.plan_frenet(EGO, road, obs, config=SMALL, key=jax.random.PRNGKey(0))
    np.testing.assert_allclose(p.x, q.x, atol=1e-6)


def test_backend_swap_gives_equal_cost(road):
    # One iteration with the same key: the same behavioural samples, so only the projection
    # differs.  ADMM runs 300 iterations here (the default 25 trades accuracy for speed).
    cfg = SMALL.replace(iterations=1, admm_iters=300)
    obs = _obstacle()
    pa = mmdopt.plan(EGO, road, obs, config=cfg, projector="admm-fixed", key=jax.random.PRNGKey(3))
    pc = mmdopt.plan(EGO, road, obs, config=cfg, projector="clarabel", key=jax.random.PRNGKey(3))
    # tolerance: 1 % of the cost + 0.05 (the cost is O(10) m²/s²; ADMM's projection is ~1e-3
    # from Clarabel's)
    assert pa.cost == pytest.approx(pc.cost, rel=0.01, abs=0.05)
    assert pa.feasible and pc.feasible
    assert (pa.projector, pc.projector) == ("admm-fixed", "clarabel")
    # ``backend=``, the projector's former name, still works (with a warning) and agrees
    with pytest.warns(DeprecationWarning, match="projector"):
        pb = mmdopt.plan(EGO, road, obs, config=cfg, backend="clarabel", key=jax.random.PRNGKey(3))
    np.testing.assert_array_equal(pb.x, pc.x)
    with pytest.raises(ValueError, match="disagree"):
        mmdopt.plan(EGO, road, obs, config=cfg, projector="osqp", backend="clarabel")


def test_initial_speed_above_vmax_gives_flagged_braking_fallback(road):
    ego = frenet.EgoState(vs=35.0)
    p = mmdopt.plan(ego, road, _obstacle(), config=SMALL)
    assert p.fallback and not p.feasible
    assert "initial speed" in p.message
    assert p.vs[-1] < 31.0  # brakes towards v_max


def test_no_feasible_sample_returns_least_violating_plan():
    # ḋ₀ = 1 m/s inside a ±0.3 m lane with |d̈| ≤ 0.05: nothing can stop in the lane
    road = mmdopt.Road(ay_max=0.05)
    ego = frenet.EgoState(vs=10.0, vd=1.0)
    p = mmdopt.plan(ego, road, _obstacle(), config=SMALL)
    assert p.fallback and not p.feasible
    assert "no sample met the constraints" in p.message
    assert np.all(np.isfinite(p.x))


@pytest.mark.parametrize(
    "obstacles, match",
    [
        (np.full((1, 20, K, 2), np.nan), "NaN"),
        (np.zeros((1, 20, 50, 2)), "time steps"),
        (np.zeros((1, 5, K, 2)), "reduced_set_size"),
        (np.zeros((20, K, 2)), "shape"),
        ([[[[0.0, 0.0]]], [[[0.0, 0.0], [1.0, 1.0]]]], "obstacles must be a numeric array"),
    ],
)
def test_bad_obstacles_raise(road, obstacles, match):
    with pytest.raises(ValueError, match=match):
        mmdopt.plan(EGO, road, obstacles, config=SMALL)


def test_an_empty_road_is_an_ok_plan_with_a_zero_bound(road):
    """No obstacle: nothing to collide with, so the plan is ``ok`` with ``risk_bound`` 0 at
    any requested risk level, and drives at the desired speed."""
    for obstacles in (np.zeros((0, 20, K, 2)), np.zeros((0, 0, K, 2))):
        p = mmdopt.plan(EGO, road, obstacles, config=SMALL, risk=1e-4)
        assert p.status == "ok" and p.risk_bound == 0.0, p.status_text
        assert p.diagnostics["empty_road"] and p.feasible
        assert abs(p.vs[-1] - SMALL.cost.v_des) < 1.0
    with pytest.raises(ValueError, match="empty"):
        mmdopt.plan(EGO, road, np.zeros((0, 20, K, 2)), config=SMALL, obstacle_headings=[])


def test_bad_arguments_raise(road):
    obs = _obstacle()
    with pytest.raises(ValueError, match="method"):
        mmdopt.plan(EGO, road, obs, method="nope", config=SMALL)
    with pytest.raises(ValueError, match="projector"):
        mmdopt.plan(EGO, road, obs, projector="nope", config=SMALL)
    with pytest.raises(ValueError, match="ego"):
        mmdopt.plan((0, 0, 10, 0, 0, 0), road, obs, config=SMALL)
    with pytest.raises(ValueError, match="key"):
        mmdopt.plan(EGO, road, obs, config=SMALL, key=3)
    with pytest.raises(ValueError, match="n_elite"):
        mmdopt.MMDOptConfig().replace(n_elite=200, n_cem=150)
    with pytest.raises(ValueError, match="y_lb"):
        mmdopt.Road(y_lb=1.0, y_ub=0.0)


def test_config_is_a_pytree_with_static_sizes():
    leaves = jax.tree_util.tree_leaves(SMALL)
    assert SMALL.cem.gamma in leaves and SMALL.cost.w_mmd in leaves
    assert all(not isinstance(v, str) for v in leaves)
    assert SMALL.replace(w_mmd=5.0).cost.w_mmd == 5.0


def test_slip_limit_is_validated_off_by_default_and_measures_sideways_motion_at_rest():
    """The kinematic slip limit (``slip_ratio``): a row that stops and then moves sideways
    exceeds it, a row that changes lane while driving does not, and the initial state's own
    slip is allowed (no plan can undo it at once)."""
    import jax.numpy as jnp

    from mmdopt import algorithm as alg

    assert not mmdopt.MMDOptConfig().safety.rules.kinematic
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="slip_ratio"):
            mmdopt.MMDOptConfig().replace(slip_ratio=bad)
    with pytest.raises(ValueError, match="slip_tol"):
        mmdopt.MMDOptConfig().replace(slip_ratio=0.5, slip_tol=0.0)
    cfg = mmdopt.MMDOptConfig().replace(horizon=5.0, num_steps=51, slip_ratio=0.5)
    assert cfg.safety.rules.kinematic
    prob = mmdopt.Planner(cfg).workspace(mmdopt.Road().bounds())
    t = prob.t()
    P = np.asarray(prob.P)

    def fit(x):  # Bernstein coefficients of a grid trajectory (least squares)
        return np.linalg.lstsq(P, x, rcond=None)[0]

    stop = np.minimum(t, 2.0) - 0.25 * np.minimum(t, 2.0) ** 2  # 1 m/s braking to rest at 2 s
    slide = np.clip(t - 2.5, 0.0, 2.0) ** 2 * 0.1  # then 0.4 m sideways at rest
    lane = 10.0 * t  # 10 m/s ...
    u = np.clip(t / 4, 0, 1)
    change = 3.5 * u**3 * (10 - 15 * u + 6 * u**2)  # ... changing lane in 4 s
    cx = jnp.asarray(np.stack([fit(stop), fit(lane), fit(stop)]))
    cy = jnp.asarray(np.stack([fit(slide), fit(change), fit(0 * t)]))
    rest = jnp.asarray([0.0, 0.0, 1.0, 0.0, -0.5, 0.0])
    r = np.asarray(alg.slip_residual(cfg, prob, rest, cx, cy))
    assert r[0] > 10 * cfg.projection.res_tol  # the slide at rest: far beyond the tolerance
    assert (
        r[1] <= cfg.projection.res_tol and r[2] <= cfg.projection.res_tol
    )  # a lane change at speed, a stop
    # a car that starts with 0.3 m/s of lateral slip at rest may keep it, not add to it
    slipping = jnp.asarray([0.0, 0.0, 0.0, 0.3, 0.0, 0.0])
    cy_keep = jnp.asarray(fit(0.3 * np.minimum(t, 0.5)))[None]
    assert (
        float(alg.slip_residual(cfg, prob, slipping, cx[2:], cy_keep)[0]) <= cfg.projection.res_tol
    )
    with pytest.raises(ValueError, match="cx and cy"):
        alg.slip_residual(cfg, prob, rest, cx, cy[:, :3])
    with pytest.raises(ValueError, match="ego_state"):
        alg.slip_residual(cfg, prob, rest[:4], cx, cy)
