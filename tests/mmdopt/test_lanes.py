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


def test_lane_cost_is_zero_at_centres_free_early_and_grows_between_them():
    # settled at lane centres / changing lanes in the first half / held between two lanes
    dd = jnp.array([[4.0, 4.0, 8.0, 8.0], [0.0, 2.0, 4.0, 4.0], [2.0, 2.0, 2.0, 2.0]])
    c = np.asarray(alg.lane_cost(dd, jnp.asarray(LANES)))
    assert c[0] == 0.0 and c[1] == 0.0
    np.testing.assert_allclose(c[2], 4.0)


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
