"""Lane discipline: ``Road.lane_centres``, ``TrajectoryConfig.lane_setpoints`` and
``CostConfig.w_lane`` (the planner keeps to lane centres except while changing lanes)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import frenet
import mmdopt
from mmdopt import algorithm as alg

# the highway preset (which keeps to lanes) with lane discipline off, at small sizes
CFG = mmdopt.MMDOptConfig.highway().replace(
    n_samples=120,
    n_cem=40,
    n_elite=12,
    iterations=6,
    n_brake=5,
    reduced_set_size=5,
    lane_setpoints=False,
    w_lane=0.0,
)
LANES = (0.0, 4.0, 8.0, 12.0)
PATH = frenet.ReferencePath.straight(2000.0, start=(-100.0, 0.0))


def _road(lanes=LANES):
    return mmdopt.Road(
        path=PATH, y_lb=0.0, y_ub=12.0, vy_max=3.0, ax_max=5.0, ay_max=3.0, lane_centres=lanes
    )


def _slow_leader(ego_d: float, n: int = 10) -> np.ndarray:
    """One 15 m/s car 30 m ahead in the ego's lane, n samples 0.1 m apart."""
    t = frenet.TimeGrid(CFG.trajectory.horizon, CFG.trajectory.num_steps).t
    obs = np.zeros((1, n, t.size, 2))
    obs[..., 0] = 100.0 + 30.0 + 15.0 * t + 0.1 * np.arange(n)[:, None]
    obs[..., 1] = ego_d
    return obs


def test_road_lane_centres_are_checked_and_sorted():
    assert _road((8.0, 0.0, 4.0)).lane_centres == (0.0, 4.0, 8.0)
    with pytest.raises(ValueError, match="lane_centres"):
        _road((0.0, float("nan")))
    with pytest.raises(ValueError, match="lane_centres"):
        _road(("a",))
    assert mmdopt.Road().lane_centres == ()


def test_lanes_only_enter_the_problem_when_asked():
    ego = frenet.EgoState(s=100.0, d=4.0, vs=25.0)
    road = _road()
    assert alg.Problem.create(CFG, ego, road.bounds(), road.lane_centres).lanes is None
    on = CFG.replace(lane_setpoints=True)
    lanes = alg.Problem.create(on, ego, road.bounds(), road.lane_centres).lanes
    np.testing.assert_array_equal(np.asarray(lanes), LANES)
    # a road without lanes: nothing to keep to
    assert alg.Problem.create(on, ego, road.bounds(), ()).lanes is None


def test_lane_inputs_move_lateral_setpoints_to_the_nearest_centre():
    cfg = CFG.replace(lane_setpoints=True)
    S = cfg.trajectory.num_segments
    d = jnp.array([[20.0] * S + [1.9, 2.1, 5.0, 13.0]])
    out = np.asarray(alg.lane_inputs(cfg, d, jnp.asarray(LANES)))
    np.testing.assert_array_equal(out[0, :S], 20.0)  # speeds untouched
    np.testing.assert_array_equal(out[0, S:], [0.0, 4.0, 4.0, 12.0])
    # off: unchanged
    assert alg.lane_inputs(CFG, d, jnp.asarray(LANES)) is d


def test_lane_commit_holds_the_first_setpoint_only_between_lanes():
    cfg = CFG.replace(lane_setpoints=True, lane_commit=0.5)
    S = cfg.trajectory.num_segments
    d = jnp.array([[20.0] * S + [3.8, 0.2, 0.1, 4.2], [20.0] * S + [0.3, 0.0, 4.1, 3.9]])
    lanes = jnp.asarray(LANES)

    def at(ego_d):
        state = jnp.array([100.0, ego_d, 25.0, 0.0, 0.0, 0.0])
        return np.asarray(alg.lane_inputs(cfg, d, lanes, state))[:, S:]

    # in a lane (within 0.5 m of its centre): set-points as sampled, a lane change may wait
    np.testing.assert_array_equal(at(0.3), [[4.0, 0.0, 0.0, 4.0], [0.0, 0.0, 4.0, 4.0]])
    # between lanes: each candidate finishes the change (4 m) or gives it up (0 m) at once
    np.testing.assert_array_equal(at(1.7), [[4.0] * 4, [0.0] * 4])
    # off (the default) or without the ego state: as sampled
    np.testing.assert_array_equal(np.asarray(alg.lane_inputs(cfg, d, lanes))[:, S:], at(0.3))
    off = CFG.replace(lane_setpoints=True, lane_commit=0.0)
    state = jnp.array([100.0, 1.7, 25.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(np.asarray(alg.lane_inputs(off, d, lanes, state))[:, S:], at(0.3))
    with pytest.raises(ValueError, match="lane_commit"):
        CFG.replace(lane_commit=-0.1)


@pytest.mark.slow
def test_a_plan_begun_between_lanes_reaches_a_lane_centre_within_the_horizon():
    """With lane_commit, a plan from 1.8 m (a lane change under way, a slower car ahead in the
    lane it left) follows one lateral set-point throughout and is at that lane centre within
    0.3 m by the second half of its horizon."""
    ego = frenet.EgoState(s=100.0, d=1.8, vs=25.0, vd=1.0)
    cfg = CFG.replace(lane_setpoints=True, w_lane=6.0, lane_commit=0.5)
    S = cfg.trajectory.num_segments
    for k in range(3):
        p = mmdopt.plan(ego, _road(), _slow_leader(0.0), config=cfg, key=jax.random.PRNGKey(k))
        assert p.feasible
        sp = p.diagnostics["behavioural_input"][S:]
        assert len(set(sp.tolist())) == 1 and sp[0] in LANES, sp
        K = p.d.size
        assert np.all(np.abs(p.d[K // 2 :] - sp[0]) < 0.3), (p.d, sp)


def test_lane_cost_is_zero_at_centres_free_early_and_grows_between_them():
    # settled at lane centres / changing lanes in the first half / held between two lanes
    dd = jnp.array([[4.0, 4.0, 8.0, 8.0], [0.0, 2.0, 4.0, 4.0], [2.0, 2.0, 2.0, 2.0]])
    c = np.asarray(alg.lane_cost(dd, jnp.asarray(LANES)))
    assert c[0] == 0.0 and c[1] == 0.0
    np.testing.assert_allclose(c[2], 4.0)
    # from the start of the horizon: the lane change pays for its step between lanes
    c0 = np.asarray(alg.lane_cost(dd, jnp.asarray(LANES), 0.0))
    np.testing.assert_allclose(c0, [0.0, 1.0, 4.0])
    with pytest.raises(ValueError, match="lane_from"):
        CFG.replace(lane_from=1.0)
    with pytest.raises(ValueError, match="lane_from"):
        CFG.replace(lane_from=-0.1)


def test_a_plan_with_lane_setpoints_drives_to_lane_centres():
    """From between two lanes, behind a slower car: every lateral set-point the plan followed is
    a lane centre, and the plan ends within 1 m of its last one (without lane set-points, two of
    these three plans end more than 1 m from every lane centre); the plans are feasible."""
    ego = frenet.EgoState(s=100.0, d=5.5, vs=25.0)
    cfg = CFG.replace(lane_setpoints=True, w_lane=2.0)
    S = cfg.trajectory.num_segments
    for k in range(3):
        p = mmdopt.plan(ego, _road(), _slow_leader(5.5), config=cfg, key=jax.random.PRNGKey(k))
        assert p.feasible
        sp = p.diagnostics["behavioural_input"][S:]
        assert set(sp.tolist()) <= set(LANES), sp
        assert abs(p.d[-1] - sp[-1]) < 1.0, (p.d[-1], sp)


def test_a_larger_lateral_gain_changes_lanes_sooner():
    """The Frenet planner's lateral gain k_p: from lane 0 to set-point 4 m, the time spent more
    than 1 m from both lane centres is shorter with k_p = 4 than with the reference's 2."""
    road = _road()
    ego = frenet.EgoState(s=0.0, d=0.0, vs=22.0)
    d = np.array([[22.0] * 4 + [4.0] * 4])

    def band_time(gain):
        ws = alg.Workspace(CFG.replace(lateral_gain=gain), road.bounds())
        _, cy = ws.planner.closed_form(d, ego)
        dd = np.asarray(cy) @ ws.P.T
        assert abs(dd[0, -1] - 4.0) < 0.1  # both arrive
        return np.sum((dd[0] > 1.0) & (dd[0] < 3.0)) * (ws.t()[1] - ws.t()[0])

    assert band_time(4.0) < band_time(2.0) - 0.2
    with pytest.raises(ValueError, match="lateral_gain"):
        CFG.replace(lateral_gain=0.0)
