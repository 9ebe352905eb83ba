"""The RSS safety shield (mmdopt.safety): the safe-distance formula of Shalev-Shwartz et al.
(2017, Definition 1), the check of a plan and its continuation to a stop, and the checked braking
fallback.  Plain NumPy on a straight road: no planner runs here."""

from __future__ import annotations

import math

import numpy as np
import pytest

import frenet
from mmdopt import Plan, PlanStatus
from mmdopt.receding import RecedingConfig
from mmdopt.safety import (
    RSSConfig,
    braking_plan,
    check_plan,
    obstacle_states_from_cartesian,
    obstacle_states_from_samples,
    rss_safe_distance,
    shield,
)

PATH = frenet.ReferencePath.straight(2000.0, start=(-100.0, 0.0))
T = np.linspace(0.0, 5.0, 51)


def _plan(v0: float, accel: float = 0.0, d: float = 0.0) -> Plan:
    """A straight plan at lateral offset ``d`` from s = 100 m, speed ``v0 + accel·t`` (≥ 0)."""
    vs = np.maximum(v0 + accel * T, 0.0)
    s = 100.0 + np.concatenate([[0.0], np.cumsum(0.5 * (vs[1:] + vs[:-1]) * np.diff(T))])
    dd, zero = np.full_like(T, d), np.zeros_like(T)
    x, y, h, sp = PATH.trajectory_to_cartesian(s, dd, vs, zero)
    return Plan(
        x=x, y=y, heading=h, speed=sp, s=s, d=dd, vs=vs, vd=zero, as_=np.full_like(T, accel),
        ad=zero, t=T, cost=1.0, cost_trace=np.ones(3), residual=0.0, mmd=0.0, feasible=True,
        status=PlanStatus.OK, message="", method="mmd", projector="test", reduced_set=None,
        plan_time_s=0.0,
    )  # fmt: skip


# ---------------------------------------------------------------------------------- the formula
def test_safe_distance_matches_a_hand_computed_value():
    c = RSSConfig(response_time=1.0, a_max=2.0, b_min=4.0, b_max=8.0)
    # 20·1 + ½·2·1 + (20 + 2)²/(2·4) − 10²/(2·8) = 20 + 1 + 60.5 − 6.25
    assert rss_safe_distance(20.0, 10.0, c) == pytest.approx(75.25)
    # at a stop behind a stopped car only the response phase counts: ½ a ρ² + (ρ a)²/(2 b_min)
    assert rss_safe_distance(0.0, 0.0, c) == pytest.approx(1.0 + 0.5)


def test_safe_distance_grows_with_the_rear_speed_and_vanishes_behind_a_much_faster_car():
    c = RSSConfig()
    v = np.linspace(0.0, 40.0, 81)
    d = rss_safe_distance(v, 20.0, c)
    assert np.all(np.diff(d) >= 0) and d[-1] > d[0]
    assert np.all(np.diff(rss_safe_distance(25.0, v, c)) <= 0)  # and falls with the front's
    assert rss_safe_distance(10.0, 40.0, c) == 0.0  # clipped at 0, never negative


def test_bad_parameters_are_rejected():
    with pytest.raises(ValueError, match="b_min"):
        RSSConfig(b_min=0.0)
    with pytest.raises(ValueError, match="b_emergency"):
        RSSConfig(b_min=6.0, b_emergency=5.0)
    with pytest.raises(ValueError, match="v_rear"):
        rss_safe_distance(-1.0, 0.0)
    with pytest.raises(ValueError, match="executed"):
        check_plan(T, T, T, T, np.zeros((0, 3)), executed=9.0)
    with pytest.raises(ValueError, match="shield"):
        RecedingConfig(shield="rss")


# ------------------------------------------------------------------------------------ the check
def test_a_plan_closing_on_a_slower_leader_is_flagged_and_keeping_distance_is_not():
    c = RSSConfig()
    p = _plan(25.0)
    slow = np.array([[140.0, 0.0, 15.0]])  # 40 m ahead in the ego's lane, 10 m/s slower
    chk = check_plan(p.t, p.s, p.d, p.vs, slow, c, executed=0.5)
    assert not chk.safe and chk.margin < 0 and chk.obstacle == 0 and chk.n_checked == 1
    far = np.array([[200.0, 0.0, 25.0]])  # 100 m ahead at the same speed
    assert check_plan(p.t, p.s, p.d, p.vs, far, c, executed=0.5).safe
    beside = np.array([[110.0, 4.0, 10.0], [60.0, 0.0, 40.0]])  # next lane; behind the ego
    ok = check_plan(p.t, p.s, p.d, p.vs, beside, c, executed=0.5)
    assert ok.safe and ok.n_checked == 0 and ok.margin == math.inf


def test_the_check_is_the_rss_rule_when_the_plan_accelerates_at_a_max():
    # executing ρ seconds at +a_max and then braking at b_min is RSS's worst case: the plan
    # passes exactly when the bumper-to-bumper gap is at least d_min
    c = RSSConfig(response_time=0.5, a_max=3.0, b_min=5.0, b_max=7.0, margin=0.0)
    p = _plan(20.0, accel=3.0)
    need = rss_safe_distance(20.0, 15.0, c) + c.contact
    for extra, safe in ((0.3, True), (-0.3, False)):
        lead = np.array([[100.0 + need + extra, 0.0, 15.0]])
        assert check_plan(p.t, p.s, p.d, p.vs, lead, c, executed=0.5).safe is safe


# --------------------------------------------------------------------------------- the fallback
def test_an_unsafe_plan_is_replaced_by_a_braking_fallback_that_passes_the_check():
    c = RSSConfig()
    p = _plan(25.0, accel=2.0, d=0.3)
    lead = np.array([[150.0, 0.0, 15.0]])
    out, rec = shield(p, PATH, lead, c, executed=0.5)
    assert rec.intervened and rec.fallback_safe and "obstacle 0" in rec.reason
    assert out.status is PlanStatus.FALLBACK and out.state is None
    assert np.all(np.diff(out.vs) <= 1e-12) and out.vs[-1] == 0.0  # brakes to a stop
    assert np.allclose(out.d, 0.3) and out.as_[0] == pytest.approx(-rec.fallback_decel)
    assert c.b_min <= rec.fallback_decel <= c.b_emergency
    assert check_plan(out.t, out.s, out.d, out.vs, lead, c, executed=0.0).safe
    assert (out.x[0], out.y[0]) == pytest.approx((p.x[0], p.y[0]))  # starts where the ego is
    # a plan that keeps its distance runs unchanged
    same, rec2 = shield(p, PATH, np.array([[400.0, 0.0, 30.0]]), c, executed=0.5)
    assert same is p and not rec2.intervened and rec2.reason == ""


def test_when_no_braking_passes_the_hardest_is_used_and_said_so():
    c = RSSConfig()
    out, rec = shield(_plan(25.0), PATH, np.array([[110.0, 0.0, 0.0]]), c, executed=0.5)
    assert rec.intervened and not rec.fallback_safe
    assert rec.fallback_decel == c.b_emergency and "no braking passes" in out.message
    with pytest.raises(ValueError, match="decel"):
        braking_plan(_plan(25.0), PATH, 0.0)


# ------------------------------------------------------------------------- obstacles' states
def test_obstacle_states_from_samples_and_from_cartesian_agree():
    # two samples of one car at (150, 0) driving at 20 m/s and 22 m/s along the road
    x = 50.0 + np.stack([20.0 * T, 22.0 * T])  # (n, K); the path starts at x = −100
    samples = np.stack([x, np.zeros_like(x)], axis=-1)[None]  # (1, n, K, 2)
    st = obstacle_states_from_samples(PATH, samples, T)
    assert st[0] == pytest.approx([150.0, 0.0, 20.0])  # the slower sample's speed
    cart = obstacle_states_from_cartesian(PATH, np.array([[50.0, 0.0, 20.0, 0.0]]))
    assert cart[0] == pytest.approx(st[0])
