"""The RSS safety shield (mmdopt.safety): the safe-distance formula of Shalev-Shwartz et al.
(2017, Definition 1), the check of a plan and its continuation to a stop, and the checked braking
fallback.  Plain NumPy on a straight road: no planner runs here."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import frenet
from mmdopt import Plan, PlanStatus
from mmdopt.receding import Observation, RecedingConfig
from mmdopt.safety import (
    RSSConfig,
    braking_plan,
    check_crossings,
    check_lateral,
    check_plan,
    lane_braking_plan,
    obstacle_states_from_cartesian,
    obstacle_states_from_samples,
    rss_lateral_safe_distance,
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
    c = RSSConfig(b_gentle=6.0)  # no levels below b_min: the fallback brakes to a stop
    p = _plan(25.0, accel=2.0, d=0.3)
    lead = np.array([[150.0, 0.0, 15.0]])
    out, rec = shield(p, PATH, lead, c, executed=0.5)
    assert rec.intervened and rec.fallback_safe and "obstacle 0" in rec.reason
    assert out.status is PlanStatus.SHIELDED and out.state is None
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


def test_the_gentlest_braking_that_passes_is_used():
    """A car at rest 52 m ahead of an ego at 25 m/s: braking at 6 or 6.5 m/s² stops within
    6 m of it, 7 m/s² (44.6 m + 6 m) is the gentlest that keeps the gap; each level is checked
    along its own profile."""
    c = RSSConfig()
    out, rec = shield(_plan(25.0), PATH, np.array([[152.0, 0.0, 0.0]]), c, executed=0.5)
    assert rec.fallback_safe and rec.fallback_decel == pytest.approx(7.0)
    assert "no braking passes" not in out.message
    assert check_plan(out.t, out.s, out.d, out.vs, [[152.0, 0.0, 0.0]], c, executed=5.0).safe


def test_below_b_min_the_gentlest_braking_checked_as_a_plan_is_used():
    """A slower car 40 m ahead (the test above): the accelerating plan fails the check, but
    braking at 1 m/s² for the step that runs, then at b_min, keeps the gap.  The fallback keeps
    the plan's lateral path, brakes at the gentlest level that passes the check a plan passes,
    and after the step it runs, the braking at b_min from where it leaves the ego passes along
    its own profile with the leader at its worst (the induction of the guarantee)."""
    c = RSSConfig()
    lead = np.array([[150.0, 0.0, 15.0]])
    p = dataclasses.replace(_changing_lanes(25.0), d=np.full_like(T, 0.3), vd=np.zeros_like(T))
    out, rec = shield(p, PATH, lead, c, executed=0.5)
    assert rec.intervened and rec.fallback_safe and c.b_gentle <= rec.fallback_decel < c.b_min
    assert out.status is PlanStatus.SHIELDED and "along the plan's lateral path" in out.message
    assert check_plan(out.t, out.s, out.d, out.vs, lead, c, executed=0.5).safe
    gentler = rec.fallback_decel - 1.0  # the levels are 1 m/s² apart
    if gentler >= c.b_gentle:
        worse = braking_plan(p, PATH, gentler)
        assert not check_plan(worse.t, worse.s, worse.d, worse.vs, lead, c, executed=0.5).safe
    # the state the step leaves, and the leader braking at b_max meanwhile
    k = int(np.searchsorted(T, 0.5))
    then = dataclasses.replace(_plan(float(out.vs[k]), d=0.3), s=np.full_like(T, out.s[k]))
    lead_then = np.array([[150.0 + 15.0 * 0.5 - 0.5 * c.b_max * 0.25, 0.0, 15.0 - 0.5 * c.b_max]])
    stop = braking_plan(then, PATH, c.b_min)
    assert check_plan(stop.t, stop.s, stop.d, stop.vs, lead_then, c, executed=5.0).safe
    # mid lane change, the gentle fallback goes on moving sideways as the plan did
    mid = _changing_lanes(25.0)
    out2, rec2 = shield(mid, PATH, lead, c, executed=0.5)
    assert rec2.fallback_decel < c.b_min
    assert np.allclose(out2.d, mid.d) and out2.vd[0] == pytest.approx(1.5)
    with pytest.raises(ValueError, match="b_gentle"):
        RSSConfig(b_gentle=7.0)
    with pytest.raises(ValueError, match="b_gentle"):
        RSSConfig(b_gentle=0.0)


def _changing_lanes(v0: float = 20.0) -> Plan:
    """A plan halfway through a lane change from 0 to 4 m (at 2 m, moving sideways at 1.5 m/s)
    that accelerates at 2 m/s²."""
    p = _plan(v0, accel=2.0)
    d = np.minimum(2.0 + 1.5 * T, 4.0)
    vd = np.where(d < 4.0, 1.5, 0.0)
    return dataclasses.replace(p, d=d, vd=vd)


def test_a_plan_replaced_mid_lane_change_finishes_the_change_while_braking():
    """A slower car 40 m ahead in the lane the ego leaves: the plan (accelerating) fails the
    check; with lane centres the fallback brakes while it moves on to the lane centre the plan
    was heading to, within the lateral acceleration and a 17° heading, and passes the check
    along its own lateral path; without them it stops the ego between the two lanes."""
    c = RSSConfig(lateral_accel=3.0, b_gentle=6.0)
    lead = np.array([[140.0, 0.0, 10.0]])
    p = _changing_lanes()
    assert not check_plan(p.t, p.s, p.d, p.vs, lead, c, executed=0.5).safe
    out, rec = shield(p, PATH, lead, c, executed=0.5, lane_centres=(0.0, 4.0, 8.0))
    assert rec.intervened and rec.fallback_safe and rec.fallback_decel == c.b_min
    assert out.status is PlanStatus.SHIELDED and out.state is None
    assert out.d[0] == pytest.approx(2.0) and out.vd[0] == pytest.approx(1.5)
    assert out.d[-1] == pytest.approx(4.0, abs=1e-9) and np.all(out.d <= 4.0 + 1e-9)
    assert np.max(np.abs(out.ad)) <= 3.0 + 1e-9
    assert np.all(np.abs(out.vd) <= 0.3 * out.vs + 1e-9)
    assert "into the lane at 4 m" in out.message
    assert check_plan(out.t, out.s, out.d, out.vs, lead, c, executed=5.0).safe
    # without lane centres, or with lateral_accel 0 (the default): the offset is held
    held, _ = shield(p, PATH, lead, c, executed=0.5)
    assert np.allclose(held.d, 2.0)
    held, _ = shield(
        p, PATH, lead, RSSConfig(b_gentle=6.0), executed=0.5, lane_centres=(0.0, 4.0, 8.0)
    )
    assert np.allclose(held.d, 2.0)


def test_the_lane_fallback_checks_every_car_on_its_lateral_path():
    """A car at rest 30 m ahead in the lane the ego moves into (offset 5 m: outside the
    corridor at 2 m, inside the one at 4 m): no braking into that lane keeps the gap, and going
    back to 0 m would first carry the ego towards it (it moves sideways at 1.5 m/s), so the
    fallback holds the offset, which keeps the gap."""
    c = RSSConfig(lateral_accel=3.0)
    blocked = np.array([[130.0, 5.0, 0.0]])
    p = _changing_lanes()
    out, rec = shield(p, PATH, blocked, c, executed=0.5, lane_centres=(0.0, 4.0, 8.0))
    assert rec.intervened and rec.fallback_safe
    assert np.allclose(out.d, 2.0)
    assert check_plan(out.t, out.s, out.d, out.vs, blocked, c, executed=5.0).safe
    into = lane_braking_plan(p, PATH, c.b_emergency, 4.0, 3.0)
    assert not check_plan(into.t, into.s, into.d, into.vs, blocked, c, executed=5.0).safe


def test_a_lane_fallback_needs_speed_to_move_sideways():
    """At 2 m/s braking at 6 m/s², the car stops before it could cover 2 m sideways within a
    17° heading: no lane fallback; bad arguments are refused."""
    slow = dataclasses.replace(_changing_lanes(2.0), vd=np.zeros_like(T))
    assert lane_braking_plan(slow, PATH, 6.0, 4.0, 3.0) is None
    with pytest.raises(ValueError, match="lateral_accel"):
        lane_braking_plan(slow, PATH, 6.0, 4.0, 0.0)
    with pytest.raises(ValueError, match="centre"):
        lane_braking_plan(slow, PATH, 6.0, float("nan"), 3.0)
    with pytest.raises(ValueError, match="lateral_accel"):
        RSSConfig(lateral_accel=-1.0)
    for bad in ((0.0, float("nan")), ("a",)):
        with pytest.raises(ValueError, match="lane_centres"):
            shield(_changing_lanes(), PATH, np.zeros((0, 3)), executed=0.5, lane_centres=bad)


# ------------------------------------------------------------------------- obstacles' states
def test_obstacle_states_from_samples_and_from_cartesian_agree():
    # two samples of one car at (150, 0) driving at 20 m/s and 22 m/s along the road
    x = 50.0 + np.stack([20.0 * T, 22.0 * T])  # (n, K); the path starts at x = −100
    samples = np.stack([x, np.zeros_like(x)], axis=-1)[None]  # (1, n, K, 2)
    st = obstacle_states_from_samples(PATH, samples, T)
    assert st[0] == pytest.approx([150.0, 0.0, 20.0])  # the slower sample's speed
    cart = obstacle_states_from_cartesian(PATH, np.array([[50.0, 0.0, 20.0, 0.0]]))
    assert cart[0] == pytest.approx(st[0])


def test_the_shields_plan_has_its_own_status_and_no_stale_fields():
    """A shielded plan says so (``SHIELDED``, not the planner's ``FALLBACK``) and keeps nothing
    measured on the plan it replaced: its bound, MMD and cost were the replaced plan's."""
    import dataclasses

    c = RSSConfig(b_gentle=6.0)
    p = dataclasses.replace(_plan(25.0, accel=2.0, d=0.3), risk_bound=1e-3, mmd=0.5, feasible=True)
    out, rec = shield(p, PATH, np.array([[150.0, 0.0, 15.0]]), c, executed=0.5)
    assert rec.intervened and out.status is PlanStatus.SHIELDED and not out.fallback
    assert np.isnan(out.risk_bound) and np.isnan(out.mmd) and np.isnan(out.cost)
    assert not out.feasible and out.state is None
    assert out.diagnostics["replaced_status"] == str(p.status)
    assert out.status_text.startswith("shielded: ")


# ------------------------------------------------------------------- the lateral rule (Def. 4)
def test_lateral_safe_distance_at_rest_is_mu_plus_both_cars_response_and_braking():
    c = RSSConfig(lat_response_time=0.5, lat_a_max=1.0, lat_b_min=1.5, lat_mu=0.3)
    # each car, at rest, may accelerate at a towards the other for ρ (½ a ρ² = 0.125 m) and
    # then brakes from ρ a = 0.5 m/s (0.25 / 3 m): μ + 2 (0.125 + 0.08333…)
    assert rss_lateral_safe_distance(0.0, 0.0, c) == pytest.approx(0.3 + 2 * (0.125 + 0.25 / 3))
    # both moving towards each other: the paper's formula term by term
    v1, v2, rho, a, b = 1.0, -0.4, 0.5, 1.0, 1.5
    v1r, v2r = v1 + rho * a, v2 - rho * a
    paper = (
        0.3 + (v1 + v1r) / 2 * rho + v1r**2 / (2 * b) - ((v2 + v2r) / 2 * rho - v2r**2 / (2 * b))
    )
    assert rss_lateral_safe_distance(v1, v2, c) == pytest.approx(paper)


def test_lateral_safe_distance_grows_as_the_cars_close_and_is_mu_when_they_part():
    c = RSSConfig()
    v = np.linspace(-3.0, 3.0, 61)
    closing_left = rss_lateral_safe_distance(v, 0.0, c)  # the left car moving right faster
    assert np.all(np.diff(closing_left) >= 0) and closing_left[-1] > closing_left[30]
    closing_right = rss_lateral_safe_distance(0.0, -v, c)  # the right car moving left faster
    assert np.all(np.diff(closing_right) >= 0)
    # a car moving away fast: only the margin μ is left, never less
    assert rss_lateral_safe_distance(-5.0, 0.0, c) == pytest.approx(c.lat_mu)
    assert rss_lateral_safe_distance(0.0, 5.0, c) == pytest.approx(c.lat_mu)
    assert np.all(rss_lateral_safe_distance(v[:, None], v[None, :], c) >= c.lat_mu)


def test_lateral_safe_distance_is_symmetric_under_swapping_the_cars():
    # the right car seen as the left one, with the direction reversed
    c = RSSConfig(lat_a_max=0.7, lat_b_min=2.0)
    v1, v2 = np.meshgrid(np.linspace(-2.0, 2.0, 9), np.linspace(-2.0, 2.0, 9))
    assert np.allclose(rss_lateral_safe_distance(v1, v2, c), rss_lateral_safe_distance(-v2, -v1, c))


def test_lateral_parameters_and_inputs_are_checked():
    for bad in ({"lat_b_min": 0.0}, {"width": -1.0}, {"lat_mu": -0.1}, {"lat_a_max": math.inf}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            RSSConfig(**bad)
    with pytest.raises(ValueError, match="lateral"):
        RSSConfig(lateral=1)
    with pytest.raises(ValueError, match="v_left"):
        rss_lateral_safe_distance(float("nan"), 0.0)
    with pytest.raises(ValueError, match="v_right"):
        rss_lateral_safe_distance(0.0, [0.0, math.inf])
    p = _plan(20.0)
    with pytest.raises(ValueError, match="obstacles"):
        check_lateral(p.t, p.s, p.d, p.vd, np.zeros((1, 3)), executed=0.5)
    with pytest.raises(ValueError, match="executed"):
        check_lateral(p.t, p.s, p.d, p.vd, np.zeros((1, 4)), executed=-1.0)
    with pytest.raises(ValueError, match="t, s, d, vd"):
        check_lateral(p.t, p.s[:-1], p.d, p.vd, np.zeros((1, 4)), executed=0.5)
    with pytest.raises(ValueError, match="lateral_states"):
        shield(p, PATH, np.zeros((0, 3)), executed=0.5, lateral_states=np.zeros((2, 3)))


def _swerving(v0: float = 20.0) -> Plan:
    """A plan that moves left from the lane centre at 1 m/s, at constant speed."""
    p = _plan(v0)
    return dataclasses.replace(p, d=np.minimum(1.0 * T, 3.5), vd=np.where(T < 3.5, 1.0, 0.0))


BESIDE = np.array([[102.0, 3.5, 20.0, 0.0]])  # in the left lane, level with the ego, same speed


def test_a_plan_swerving_into_a_car_beside_fails_and_holding_the_lane_passes():
    c = RSSConfig(lateral=True)
    hold = _plan(20.0)
    ok = check_lateral(hold.t, hold.s, hold.d, hold.vd, BESIDE, c, executed=0.5)
    # 1.5 m between the sides; both at rest sideways need μ + 2 (½ a ρ² + (ρ a)²/(2 b))
    need = rss_lateral_safe_distance(0.0, 0.0, c)
    assert ok.safe and ok.n_checked == 1 and ok.margin == pytest.approx(1.5 - need)
    sw = _swerving()
    bad = check_lateral(sw.t, sw.s, sw.d, sw.vd, BESIDE, c, executed=0.5)
    assert not bad.safe and bad.obstacle == 0 and bad.n_checked == 1
    # the least slack is at the end of the step, the ego 0.5 m closer and moving at 1 m/s
    closing = rss_lateral_safe_distance(0.0, -1.0, c)  # the car is left: the ego's ḋ closes
    assert bad.time == pytest.approx(0.5) and bad.margin == pytest.approx(1.0 - closing)
    # the same car far ahead, or a car moving away sideways fast enough, is no concern
    far = BESIDE + np.array([60.0, 0.0, 0.0, 0.0])
    assert check_lateral(sw.t, sw.s, sw.d, sw.vd, far, c, executed=0.5).n_checked == 0
    away = BESIDE + np.array([0.0, 0.0, 0.0, 3.0])
    assert check_lateral(sw.t, sw.s, sw.d, sw.vd, away, c, executed=0.5).safe


def test_a_car_passing_the_ego_between_grid_times_is_beside_it():
    # 30 m/s faster, from 11.5 m behind: on the 0.1 s grid it is 2.5 m behind, then 0.5 m
    # ahead, never within contact = 0.4 m of the ego, but it passes the ego in the step
    c = RSSConfig(lateral=True, contact=0.4)
    p = _swerving()
    fast = np.array([[88.5, 3.5, 50.0, 0.0]])
    assert check_lateral(p.t, p.s, p.d, p.vd, fast, c, executed=0.5).n_checked == 1
    assert check_lateral(p.t, p.s, p.d, p.vd, fast, c, executed=0.3).n_checked == 0


def test_a_car_ahead_in_the_corridor_is_the_longitudinal_rules_not_the_lateral_one():
    c = RSSConfig(lateral=True)
    sw = _swerving()
    ahead = np.array([[104.0, 0.5, 20.0, 0.0], [140.0, 0.0, 15.0, 0.0]])
    chk = check_lateral(sw.t, sw.s, sw.d, sw.vd, ahead, c, executed=0.5)
    assert chk.safe and chk.n_checked == 0 and chk.margin == math.inf


def test_the_shield_replaces_a_swerve_into_a_car_beside_by_braking_in_lane():
    c = RSSConfig(lateral=True)
    sw = _swerving()
    out, rec = shield(sw, PATH, np.zeros((0, 3)), c, executed=0.5, lateral_states=BESIDE)
    assert rec.intervened and rec.rule == "lateral" and rec.fallback_safe
    assert "lateral" in rec.reason and "obstacle 0" in rec.reason and rec.plan_margin < 0
    # the gentle levels keep the swerve and fail: the fallback holds the offset, ḋ = 0
    assert out.status is PlanStatus.SHIELDED and rec.fallback_decel == c.b_min
    assert np.allclose(out.d, 0.0) and np.allclose(out.vd, 0.0)
    assert check_lateral(out.t, out.s, out.d, out.vd, BESIDE, c, executed=5.0).safe
    # the lateral rule is off by default, and without the states
    same, rec0 = shield(sw, PATH, np.zeros((0, 3)), executed=0.5, lateral_states=BESIDE)
    assert same is sw and not rec0.intervened and rec0.rule == ""
    same, _ = shield(sw, PATH, np.zeros((0, 3)), c, executed=0.5)
    assert same is sw


def test_lateral_obstacle_states_from_cartesian():
    st = np.array([[50.0, 3.5, 20.0, -1.0]])  # 150 m along, 3.5 m left, drifting right
    assert obstacle_states_from_cartesian(PATH, st).shape == (1, 3)
    assert obstacle_states_from_cartesian(PATH, st, lateral=True)[0] == pytest.approx(
        [150.0, 3.5, 20.0, -1.0]
    )
    # a road heading north: the left normal points west, so moving west is +ḋ
    north = frenet.ReferencePath.straight(500.0, heading=math.pi / 2)
    lat = obstacle_states_from_cartesian(north, np.array([[-2.0, 100.0, -0.5, 15.0]]), lateral=True)
    assert lat[0] == pytest.approx([100.0, 2.0, 15.0, 0.5])
    assert obstacle_states_from_cartesian(PATH, np.zeros((0, 4)), lateral=True).shape == (0, 4)
    with pytest.raises(ValueError, match="lateral"):
        obstacle_states_from_cartesian(PATH, st, lateral="yes")


# ---------------------------------------------------------------------- the crossing rule
# the ego at s = 100 m, 20 m/s: after 0.5 s at 20 m/s and braking at b_min = 6 it stops at
# 110 + 400/12 = 143.33 m at t = 0.5 + 20/6 = 3.83 s; braking at 8 m/s² now, at 125 m
CROSS = np.array([140.0, 150.0, 1.0])  # a conflict area 40 m ahead, reachable by t = 1 s


def test_a_car_that_can_reach_the_area_first_forbids_driving_through():
    c = RSSConfig()
    p = _plan(20.0)
    late = [140.0, 150.0, 10.0]  # arrives long after the ego could have stopped
    chk = check_crossings(p.t, p.s, p.vs, np.array([late, CROSS]), c, executed=0.5)
    assert not chk.safe and chk.obstacle == 1 and chk.n_checked == 1 and chk.time == 1.0
    assert chk.margin == pytest.approx(140.0 - c.margin - (110.0 + 400.0 / 12.0))
    assert check_crossings(p.t, p.s, p.vs, np.array([late]), c, executed=0.5).safe
    # a plan slowing at 4 m/s² passes: 0.5 s of it, then b_min, 109.5 + 18²/12 = 136.5 m;
    # at 1 m/s² it does not: 109.875 + 19.5²/12 = 141.56 m
    slow = _plan(20.0, accel=-4.0)
    chk = check_crossings(slow.t, slow.s, slow.vs, [CROSS], c, executed=0.5)
    assert chk.safe and chk.margin == pytest.approx(139.0 - 136.5)
    slow = _plan(20.0, accel=-1.0)
    assert not check_crossings(slow.t, slow.s, slow.vs, [CROSS], c, executed=0.5).safe
    stop = braking_plan(p, PATH, 5.0)  # 100 + 40 = 140 m > 139 m: not quite
    assert not check_crossings(stop.t, stop.s, stop.vs, [CROSS], c, executed=5.0).safe
    stop = braking_plan(p, PATH, 6.0)  # 133.3 m
    assert check_crossings(stop.t, stop.s, stop.vs, [CROSS], c, executed=5.0).safe


def test_the_shield_stops_the_ego_before_a_conflict_area_it_cannot_clear():
    c = RSSConfig(b_gentle=6.0)  # the fallback brakes to a stop from now
    p = _plan(20.0)
    out, rec = shield(p, PATH, np.zeros((0, 3)), c, executed=0.5, crossings=[CROSS])
    assert rec.intervened and rec.rule == "crossing" and "crossing 0" in rec.reason
    assert out.status is PlanStatus.SHIELDED and rec.fallback_safe
    assert out.vs[-1] == 0.0 and out.s[-1] <= CROSS[0] - c.margin
    # with the gentle levels, the gentlest braking whose continuation stops in time is used
    out, rec = shield(p, PATH, np.zeros((0, 3)), RSSConfig(), executed=0.5, crossings=[CROSS])
    assert rec.fallback_decel == pytest.approx(3.0) and out.status is PlanStatus.SHIELDED
    assert check_crossings(out.t, out.s, out.vs, [CROSS], executed=0.5).safe
    # 0.5 s at 3 m/s², then b_min: 109.625 + 18.5²/12 = 138.15 m, within 139 m
    k = int(np.searchsorted(T, 0.5))
    assert out.s[k] + out.vs[k] ** 2 / 12.0 <= CROSS[0] - 1.0


def test_a_committed_ego_and_areas_behind_it_are_not_checked():
    c = RSSConfig()
    p = _plan(20.0)
    # 15 m ahead: even 8 m/s² from now stops at 125 m, inside it: RSS says clear it
    near = [115.0, 125.0, 0.5]
    behind = [80.0, 95.0, 0.0]
    chk = check_crossings(p.t, p.s, p.vs, [near, behind], c, executed=0.5)
    assert chk.safe and chk.n_checked == 0 and chk.margin == math.inf
    same, rec = shield(p, PATH, np.zeros((0, 3)), c, executed=0.5, crossings=[near, behind])
    assert same is p and not rec.intervened
    # an ego that could still just stop at 8 m/s² (area from 127 m): the rule applies
    assert check_crossings(p.t, p.s, p.vs, [[127.0, 135.0, 0.5]], c, executed=0.5).n_checked == 1


def test_crossings_are_checked():
    p = _plan(20.0)
    for bad, word in (
        (np.zeros(3), "crossings"),
        (np.zeros((2, 2)), "crossings"),
        ([[150.0, 140.0, 1.0]], "s_out"),
        ([[140.0, 150.0, -1.0]], "t_arrive"),
        ([[140.0, math.nan, 1.0]], "crossings"),
    ):
        with pytest.raises(ValueError, match=word):
            check_crossings(p.t, p.s, p.vs, bad, executed=0.5)
        with pytest.raises(ValueError, match=word):
            shield(p, PATH, np.zeros((0, 3)), executed=0.5, crossings=bad)
    with pytest.raises(ValueError, match="t, s, vs"):
        check_crossings(p.t, p.s, p.vs[:3], [CROSS], executed=0.5)
    with pytest.raises(ValueError, match="config"):
        check_crossings(p.t, p.s, p.vs, [CROSS], "rss", executed=0.5)


def test_without_the_new_inputs_the_shield_is_the_longitudinal_one():
    c = RSSConfig()
    p = _plan(25.0, accel=2.0, d=0.3)
    lead = np.array([[150.0, 0.0, 15.0]])
    a, ra = shield(p, PATH, lead, c, executed=0.5)
    b, rb = shield(p, PATH, lead, c, executed=0.5, crossings=np.zeros((0, 3)))
    assert ra == rb and ra.rule == "longitudinal" and "longitudinal" in ra.reason
    assert np.array_equal(a.s, b.s) and np.array_equal(a.d, b.d) and a.message == b.message
    # positional records of before still build, with no rule
    assert dataclasses.replace(ra, rule="").rule == "" and len(dataclasses.fields(ra)) == 7


def test_the_receding_loop_passes_crossings_and_lateral_states_to_the_shield():
    from mmdopt import Road
    from mmdopt.receding import _shielded

    road = Road(path=PATH, y_lb=-0.3, y_ub=3.8, v_max=30.0)
    sw = _swerving()
    x, y = PATH.to_cartesian(np.array([102.0]), np.array([3.5]))
    states = np.array([[x[0], y[0], 20.0, 0.0]])
    obs = Observation(
        ego=frenet.EgoState(s=100.0, d=0.0, vs=20.0), road=road,
        obstacles=np.zeros((0, 2, len(T), 2)), obstacle_states=states,
    )  # fmt: skip
    rc = RecedingConfig(dt=0.5, shield=RSSConfig(lateral=True))
    _, rec = _shielded(sw, obs, rc, T)
    assert rec.intervened and rec.rule == "lateral"
    _, rec = _shielded(sw, obs, dataclasses.replace(rc, shield=RSSConfig()), T)
    assert not rec.intervened
    crossing = dataclasses.replace(obs, crossings=np.array([CROSS]))
    _, rec = _shielded(_plan(20.0), crossing, dataclasses.replace(rc, shield=RSSConfig()), T)
    assert rec.intervened and rec.rule == "crossing"


def test_the_ego_may_go_first_only_if_it_clears_the_area_ahead_of_the_car():
    c = RSSConfig()
    fast = _plan(20.0)  # s = 100 + 20 t: its centre passes s_out = 150 m at t = 2.5 s
    # the car can be there at 3.5 s: the plan clears the area a response time before it
    assert check_crossings(fast.t, fast.s, fast.vs, [[140.0, 150.0, 3.5]], c, executed=0.5).safe
    # at 2.8 s it cannot: within 40 m it can still stop, so it must
    chk = check_crossings(fast.t, fast.s, fast.vs, [[140.0, 150.0, 2.8]], c, executed=0.5)
    assert not chk.safe and chk.obstacle == 0
    # a slow plan that would creep into the area and stand there while a car may come is refused
    # however late that car, while the ego can still stop before the area
    creep = _plan(4.0)  # 4 m from the area at 4 m/s, never clear of it in the horizon
    far = [[104.0, 124.0, 30.0]]
    chk = check_crossings(creep.t, creep.s, creep.vs, far, c, executed=0.5)
    assert not chk.safe
    fb, rec = shield(creep, PATH, np.zeros((0, 3)), c, executed=0.5, crossings=np.array(far))
    assert rec.intervened and rec.rule == "crossing"
    assert fb.status == PlanStatus.SHIELDED
    # it slows so that braking after the next replan period stops short of the area
    assert check_crossings(fb.t, fb.s, fb.vs, far, c, executed=0.5).safe


def test_a_plan_its_planner_reports_unsafe_is_braked_even_when_the_rules_pass():
    c = RSSConfig()
    p = _plan(20.0)
    kept, rec = shield(p, PATH, np.zeros((0, 3)), c, executed=0.5)
    assert kept is p and not rec.intervened  # an empty road: every rule passes
    why = "the planner reports the plan unsafe (it meets every future of obstacle 0)"
    fb, rec = shield(p, PATH, np.zeros((0, 3)), c, executed=0.5, replace=why)
    assert rec.intervened and rec.rule == "unsafe" and rec.reason == why
    assert fb.status == PlanStatus.SHIELDED
    assert rec.fallback_decel == c.b_min  # no gentle braking along the unsafe plan's path
    assert np.all(np.diff(fb.vs) <= 1e-12) and fb.vs[-1] == 0.0
    with pytest.raises(ValueError, match="replace"):
        shield(p, PATH, np.zeros((0, 3)), c, executed=0.5, replace=True)


def test_the_receding_loop_brakes_on_a_plan_reported_unsafe():
    from mmdopt import Road
    from mmdopt.receding import _shielded

    road = Road(path=PATH, y_lb=-0.3, y_ub=3.8, v_max=30.0)
    obs = Observation(
        ego=frenet.EgoState(s=100.0, d=0.0, vs=20.0), road=road,
        obstacles=np.zeros((0, 2, len(T), 2)),
    )  # fmt: skip
    rc = RecedingConfig(dt=0.5, shield=RSSConfig())
    unsafe = dataclasses.replace(_plan(20.0), status=PlanStatus.UNSAFE, message="meets obstacle 0")
    out, rec = _shielded(unsafe, obs, rc, T)
    assert rec.intervened and rec.rule == "unsafe" and "meets obstacle 0" in rec.reason
    assert out.status == PlanStatus.SHIELDED
    _, rec = _shielded(_plan(20.0), obs, rc, T)
    assert not rec.intervened  # the same plan reported ok runs
