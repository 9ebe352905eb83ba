"""Obstacle body headings: ``plan(..., obstacle_headings=...)`` and ``collision.headings``.

The planner reads an obstacle's heading from its predicted motion; a car at rest has none, so
its footprint circles lie along the path.  A car at rest turned across its lane reaches further
sideways than that: given its body heading, the plan must keep clear of its real footprint.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import frenet
import mmdopt
from mmdopt.collision import collision_free_count, headings

from .test_algorithm import EGO, SMALL, T

#: a car at rest 80 m ahead, its centre 4.2 m to the right of the ego's lane centre, turned 45°
#: towards the ego's lane: its nose circle is 2.4 m from the ego's path (inside the 3.5 m
#: lateral semi-axis), its centre 4.2 m (outside)
REST = np.array([80.0, -4.2])
TURN = math.pi / 4


def _rest_samples(n=40):
    return np.broadcast_to(REST, (1, n, T.shape[0], 2)).copy()  # (1, n, K, 2)


def test_headings_hold_the_initial_heading_until_the_body_moves():
    xy = np.zeros((2, 6, 2))
    xy[1, 3:, 0] = [1.0, 2.0, 3.0]  # at rest for three steps, then along +x
    np.testing.assert_allclose(headings(xy), 0.0)
    h = np.asarray(headings(xy, initial=np.array([0.7, -0.4])))
    np.testing.assert_allclose(h[0], 0.7)  # never moves: the body heading throughout
    np.testing.assert_allclose(h[1, :2], -0.4)  # before its first step of its own
    np.testing.assert_allclose(h[1, 2:], 0.0)  # then its motion


@pytest.mark.parametrize("risk", [None, 0.1])
def test_plan_clears_a_turned_car_at_rest_given_its_heading(risk):
    """``risk=None``: the config's time-linear margins; ``risk=0.1``: the risk dial (its
    re-selection pass and final check also read the headings)."""
    cfg = SMALL if risk is not None else SMALL.replace(margin_mode="linear")
    road = mmdopt.Road()
    obs = _rest_samples()
    heading = np.array([TURN])
    given = mmdopt.plan(EGO, road, obs, config=cfg, risk=risk, obstacle_headings=heading)
    blind = mmdopt.plan(EGO, road, obs, config=cfg, risk=risk)
    body = np.broadcast_to(heading, (1, obs.shape[1], T.shape[0]))
    a, b = cfg.safety.footprint.a, cfg.safety.footprint.b

    def met(p):
        xy = np.stack([p.s, p.d], -1)
        cnt = collision_free_count(xy, obs, a=a, b=b, obstacle_heading=body)
        return int(np.asarray(cnt.colliding).sum())

    assert given.status.startswith("ok"), given.status
    assert met(given) == 0  # clear of the turned body in every sample
    assert given.s[-1] < REST[0]  # it stops short (the lane bounds leave no way round)
    # read from its (absent) motion the car lies along the path, 4.2 m away: the plan drives on
    assert met(blind) == obs.shape[1]
    assert blind.s[-1] > REST[0]


def test_obstacle_headings_are_checked():
    road, obs = mmdopt.Road(), _rest_samples()
    for bad, match in (
        ([0.1, 0.2], r"shape \(1,\)"),
        ([float("nan")], "NaN or inf"),
        ("north", "numbers"),
    ):
        with pytest.raises(ValueError, match=match):
            mmdopt.plan(EGO, road, obs, config=SMALL, obstacle_headings=bad)
    with pytest.raises(ValueError, match="obstacle_heading must have shape"):
        collision_free_count(np.zeros((T.shape[0], 2)), obs, obstacle_heading=np.zeros(3))


def test_frenet_headings_are_relative_to_the_path():
    """On a path turned by θ, a Cartesian body heading θ + 45° is 45° in the Frenet frame: the
    same plan as on the straight road."""
    th = 0.3
    c, s_ = math.cos(th), math.sin(th)
    rot = np.array([[c, -s_], [s_, c]])
    straight = mmdopt.Road()
    turned = mmdopt.Road(path=frenet.ReferencePath.straight(1000.0, heading=th))
    obs = _rest_samples()
    cfg = SMALL.replace(margin_mode="linear")
    p0 = mmdopt.plan(EGO, straight, obs, config=cfg, obstacle_headings=[TURN])
    p1 = mmdopt.plan(EGO, turned, obs @ rot.T, config=cfg, obstacle_headings=[TURN + th])
    np.testing.assert_allclose(p1.s, p0.s, atol=1e-2)
    np.testing.assert_allclose(p1.d, p0.d, atol=1e-2)
