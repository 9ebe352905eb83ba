"""The bound every plan states on its collision probability, and what a sample count supports."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import beta

from mmdopt.risk import (
    RISK_CONFIDENCE,
    clopper_pearson_upper,
    risk_bound,
    risk_floor,
    samples_for_risk,
)


def test_clopper_pearson_matches_the_beta_quantile_and_its_closed_form():
    for k, n in [(1, 10), (3, 100), (50, 1000)]:
        assert clopper_pearson_upper(k, n) == pytest.approx(beta.ppf(0.95, k + 1, n - k))
    assert clopper_pearson_upper(0, 100) == pytest.approx(1 - 0.05 ** (1 / 100), rel=1e-12)
    assert clopper_pearson_upper(7, 7) == 1.0


def test_the_bound_covers_the_true_probability_as_often_as_its_confidence_says():
    rng = np.random.default_rng(1)
    for p, n in [(0.02, 100), (0.002, 1000), (0.1, 50)]:
        k = rng.binomial(n, p, size=4000)
        covered = np.mean([clopper_pearson_upper(int(x), n) >= p for x in k])
        # Clopper–Pearson is conservative: at least the nominal 95 % (minus sampling noise)
        assert covered >= RISK_CONFIDENCE - 0.01, (p, n, covered)


def test_union_over_obstacles_splits_the_confidence():
    one = risk_bound([0], [100])
    two = risk_bound([0, 0], [100, 100])
    assert two == pytest.approx(2 * clopper_pearson_upper(0, 100, 1 - 0.05 / 2))
    assert one < two <= 1.0
    assert risk_bound([100, 0], [100, 100]) == 1.0


@settings(max_examples=200, deadline=None)
@given(
    hits=st.lists(st.lists(st.booleans(), min_size=30, max_size=30), min_size=2, max_size=4),
)
def test_the_joint_bound_is_never_looser_than_the_union_bound(hits):
    # a plan meeting these (O, n) futures: the joint count is between the largest obstacle's
    # count and their sum, and Clopper–Pearson on it at full confidence never exceeds the sum
    # of per-obstacle bounds at the Bonferroni-split confidence
    h = np.array(hits)
    O, n = h.shape
    joint = risk_bound([int(h.any(0).sum())], [n])
    union = risk_bound(h.sum(1).tolist(), [n] * O)
    assert joint <= union + 1e-12


def test_the_joint_bound_covers_the_probability_of_meeting_any_obstacle():
    # two independent obstacles met with probabilities p1, p2: sample i of each is one joint
    # draw, and the bound on the joint count covers 1 − (1 − p1)(1 − p2) at least 95 % of
    # the time, while needing no more samples than one obstacle would
    rng = np.random.default_rng(2)
    p1, p2, n = 0.004, 0.002, 1000
    p = 1 - (1 - p1) * (1 - p2)
    met = (rng.random((3000, n)) < p1) | (rng.random((3000, n)) < p2)
    covered = np.mean([risk_bound([int(k)], [n]) >= p for k in met.sum(1)])
    assert covered >= RISK_CONFIDENCE - 0.01, covered
    assert samples_for_risk(0.005, 1) < samples_for_risk(0.005, 2)


def test_floor_and_the_samples_a_request_needs():
    assert risk_floor([100]) == pytest.approx(0.0295, abs=1e-4)  # "100 samples support 3e-2"
    for eps, O in [(0.005, 1), (1e-3, 2), (1e-4, 1)]:
        n = samples_for_risk(eps, O)
        assert risk_floor([n] * O) <= eps < risk_floor([n - 1] * O)
    assert samples_for_risk(0.005) == 598


@pytest.mark.parametrize("eps, O, hits", [(0.02, 1, 1), (0.005, 1, 3), (1e-3, 3, 2), (0.1, 2, 5)])
def test_samples_that_leave_room_for_hits_are_the_fewest_that_do(eps, O, hits):
    n = samples_for_risk(eps, O, hits=hits)
    # a plan meeting `hits` samples of every obstacle keeps its bound at eps, one fewer sample
    # would not
    assert risk_bound([hits] * O, [n] * O) <= eps < risk_bound([hits] * O, [n - 1] * O)
    assert n > samples_for_risk(eps, O, hits=hits - 1)
    assert samples_for_risk(eps, O, hits=0) == samples_for_risk(eps, O)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: risk_bound([1, 2], [10]), "one per obstacle"),
        (lambda: risk_bound([11], [10]), "collisions"),
        (lambda: risk_bound([], []), "one per obstacle"),
        (lambda: clopper_pearson_upper(0, 10, confidence=1.0), "confidence"),
        (lambda: samples_for_risk(0.7), "eps"),
        (lambda: samples_for_risk("0.1"), "eps"),
        (lambda: samples_for_risk(0.01, obstacles=0), "obstacles"),
        (lambda: samples_for_risk(0.01, hits=-1), "hits"),
        (lambda: samples_for_risk(0.01, hits=1.5), "hits"),
    ],
)
def test_bad_inputs_name_the_argument(call, match):
    with pytest.raises(ValueError, match=match):
        call()


# ------------------------------------------------------------------------------ on the plan
def _scene(n, on_ego=0):
    """n futures of one car 60 m ahead at 10 m/s; ``on_ego`` of them sit on the ego's start for
    the whole horizon (no plan can avoid them)."""
    import mmdopt

    cfg = mmdopt.MMDOptConfig().replace(
        n_samples=60, n_cem=30, n_elite=10, iterations=3, n_brake=2, reduced_set_size=5
    )
    K, H = cfg.trajectory.num_steps, cfg.trajectory.horizon
    t = np.linspace(0.0, H, K)
    rng = np.random.default_rng(0)
    x = 60.0 + rng.normal(10.0, 0.5, (n, 1)) * t
    x[:on_ego] = 0.0
    return cfg, np.stack([x, np.zeros_like(x)], -1)[None]


def test_plan_states_its_bound_and_a_floor_it_cannot_confirm():
    import jax

    import mmdopt

    cfg, obs = _scene(40)
    import frenet

    ego = frenet.EgoState(vs=10.0)
    key = jax.random.PRNGKey(0)
    asked = mmdopt.plan(ego, mmdopt.Road(), obs, config=cfg, key=key, risk=1e-4)
    assert asked.status == mmdopt.PlanStatus.RISK_FLOOR
    assert "asked 0.0001, the 40 samples" in asked.message and "29956 samples" in asked.message
    assert asked.to_dict()["risk_bound"] == pytest.approx(risk_floor([40]))
    # a level the 40 samples can confirm, met by a plan clear of them: ok, with its bound
    ok = mmdopt.plan(ego, mmdopt.Road(), obs, config=cfg, key=key, risk=0.2)
    assert ok.status == "ok" and ok.risk_bound <= 0.2, ok.status_text
    # the time-linear margins ask for no risk level: the bound is stated, the status is ok
    lin = mmdopt.plan(ego, mmdopt.Road(), obs, config=cfg.replace(margin_mode="linear"), key=key)
    assert lin.status == "ok" and lin.risk_bound == pytest.approx(risk_floor([40]))


def test_a_plan_that_meets_more_samples_than_asked_says_so():
    import jax

    import frenet
    import mmdopt

    cfg, obs = _scene(40, on_ego=8)  # 8 of 40 futures sit on the ego: every plan meets them
    p = mmdopt.plan(
        frenet.EgoState(vs=10.0), mmdopt.Road(), obs, config=cfg, key=jax.random.PRNGKey(0),
        risk=0.2,
    )  # fmt: skip
    assert p.status == mmdopt.PlanStatus.RISK_EXCEEDED, p.status_text
    assert p.risk_bound > 0.2 and "meets 8 planning sample(s)" in p.message


def test_a_plan_that_meets_every_future_says_so_or_brakes_where_a_stop_is_clear():
    """A car stands 18 m ahead on a road too narrow to pass: no plan found is collision-free
    and the plan is returned flagged ``unsafe``.  With ``unsafe_brake`` the planner brakes at
    that deceleration to a stop short of it instead and says why (status ``fallback``, nothing
    measured on the replaced plan kept).  Where the futures sit on the ego's start, a stop
    meets them as well: the plan stays, flagged ``unsafe``."""
    import jax

    import frenet
    import mmdopt

    cfg, on_ego = _scene(40, on_ego=40)
    t = np.linspace(0.0, cfg.trajectory.horizon, cfg.trajectory.num_steps)
    x = 18.0 + np.random.default_rng(0).normal(0.0, 0.2, (40, 1)) + 0.0 * t
    ahead = np.stack([x, np.zeros_like(x)], -1)[None]
    kw = dict(key=jax.random.PRNGKey(0), risk=0.2)
    ego, road = frenet.EgoState(vs=10.0), mmdopt.Road(y_lb=-0.5, y_ub=0.5)
    brake = cfg.replace(unsafe_brake=6.0)
    p = mmdopt.plan(ego, road, ahead, config=cfg, **kw)
    assert p.status == mmdopt.PlanStatus.UNSAFE, p.status_text
    b = mmdopt.plan(ego, road, ahead, config=brake, **kw)
    assert b.status == mmdopt.PlanStatus.FALLBACK and "unsafe_brake" in b.message
    assert "collides with every planning sample" in b.message
    np.testing.assert_allclose(b.vs, np.maximum(10.0 - 6.0 * (b.t - b.t[0]), 0.0), atol=1e-5)
    assert b.progress == pytest.approx(10.0**2 / (2 * 6.0), rel=1e-5) and np.all(b.d == b.d[0])
    assert np.isnan(b.risk_bound) and not b.feasible
    assert b.diagnostics["unsafe_brake_met"] == (40, 0)  # joint futures: the plan's, the stop's
    stays = mmdopt.plan(ego, road, on_ego, config=brake, **kw)
    assert (
        stays.status == mmdopt.PlanStatus.UNSAFE and stays.diagnostics["unsafe_brake_met"][1] == 40
    )
    with pytest.raises(ValueError, match="unsafe_brake"):
        cfg.replace(unsafe_brake=-1.0)


@pytest.mark.slow
def test_several_obstacles_met_in_the_same_futures_count_once():
    # two cars whose futures 0..7 both sit on the ego's start: every plan meets those 8 joint
    # futures, 8 of each car's; the bound counts the 8 draws once (joint futures, the default)
    # and both cars' 8 with the union bound when the samples are declared separate draws
    import jax

    import frenet
    import mmdopt

    cfg, one = _scene(40, on_ego=8)
    two = one.copy()
    two[:, 8:] += np.array([15.0, 0.0])  # the second car's other futures 15 m further on
    obs = np.concatenate([one, two])
    kw = dict(key=jax.random.PRNGKey(0), risk=0.2)
    ego = frenet.EgoState(vs=10.0)
    p = mmdopt.plan(ego, mmdopt.Road(), obs, config=cfg, **kw)
    assert p.status == mmdopt.PlanStatus.RISK_EXCEEDED, p.status_text
    assert "meets 8 joint futures (8, 8 of 40 per obstacle)" in p.message
    assert p.risk_bound == pytest.approx(risk_bound([8], [40]))
    sep = mmdopt.plan(ego, mmdopt.Road(), obs, config=cfg.replace(joint_futures=False), **kw)
    assert sep.risk_bound == pytest.approx(risk_bound([8, 8], [40, 40]))
    assert sep.risk_bound > p.risk_bound
    with pytest.raises(ValueError, match="joint_futures"):
        mmdopt.SafetyConfig(joint_futures=1)
