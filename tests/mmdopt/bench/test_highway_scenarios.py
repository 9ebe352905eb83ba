"""highway-env scenarios beyond the straight highway: the Frenet frame of a curved road
(``racetrack-v0``), predictions that follow curved lanes, the off-road record and the planner's
video overlay.

Skipped when highway-env is not installed (``pip install -e ".[highway]"``).
"""

from __future__ import annotations

import csv

import numpy as np
import pytest

from mmdopt.bench import highway as hw
from mmdopt.bench.highway import roads

pytestmark = pytest.mark.skipif(
    not hw.highway_available(),
    reason='highway-env/gymnasium not installed (pip install ".[highway]")',
)

TINY = {
    "cem": {"n_samples": 60, "n_cem": 30, "n_elite": 10, "iterations": 3, "n_brake": 5},
    "trajectory": {"num_steps": 26},
    "selection": {"reduced_set_size": 3},
}
RACETRACK = hw.HighwaySettings(
    env="racetrack-v0",
    env_config={"other_vehicles": 20},
    duration=2.0,
    n_samples=4,
    max_obstacles=3,
    predictor="cv",
)


def _racetrack(seed=1):
    return hw.HighwaySource(RACETRACK, seed, hw.highway_config(TINY), method="mmd")


def _lane_points(network, indices, margin=6.0):
    """Points of the lane centres ``indices``, away from the junctions between lanes."""
    pts = []
    for li in indices:
        lane = network.get_lane(li)
        for s in np.linspace(margin, lane.length - margin, 5):
            pts.append(lane.position(float(s), 0.0))
    return np.array(pts)


def test_racetrack_path_is_the_centre_line_of_the_ego_lane():
    src = _racetrack()
    try:
        net, path = src.env.road.network, src.path
        model = src.road_model
        assert model.chain is not None and model.chain.closed  # a loop
        pts = _lane_points(net, model.chain.indices)
        s, d = path.to_frenet(pts[:, 0], pts[:, 1])
        inside = (s > 0) & (s < path.length)
        assert inside.sum() >= 30  # most of the lap is in the window
        x, y = path.to_cartesian(s[inside], np.zeros(inside.sum()))
        # Frenet -> Cartesian at d = 0 is the env's lane centre, to the centimetre
        assert np.max(np.hypot(x - pts[inside, 0], y - pts[inside, 1])) < 0.01
        assert np.max(np.abs(d[inside])) < 0.01
        # the lane centres are the two lanes' centres (5 m wide lanes); the bounds reach 1 m
        # past them (half the car's width and 0.5 m inside the road's edge)
        assert sorted(np.round(model.lane_centres, 3)) in ([-5.0, 0.0], [0.0, 5.0])
        assert (src.road.y_lb, src.road.y_ub) == pytest.approx(
            (min(model.lane_centres) - 1.0, max(model.lane_centres) + 1.0)
        )
        assert src.road.v_max == 10.0  # racetrack-v0's speed limit caps the planner's
        # moving the window round the loop keeps the geometry: arc lengths shift by `shift`
        moved, shift = roads.reanchor(model, path.length - 10.0, back=40.0)
        assert shift > 100.0
        s_old = np.array([shift + 20.0, path.length - 5.0])
        p = path.to_cartesian(s_old, np.full(2, 2.0))
        s2, d2 = moved.path.to_frenet(p[0], p[1])
        assert s2 == pytest.approx(s_old - shift, abs=0.05)
        assert d2 == pytest.approx([2.0, 2.0], abs=0.01)
        # and the new window runs on past the old one's end, round the loop
        assert moved.path.length == pytest.approx(path.length, abs=0.5)
    finally:
        src.close()


def test_racetrack_path_moves_to_the_lane_the_ego_drives_in():
    src = _racetrack()
    try:
        net, model = src.env.road.network, src.road_model
        other = min(model.lane_centres, key=lambda c: -abs(c))  # the other lane's offset
        assert abs(other) == pytest.approx(5.0, abs=1e-3)
        first = src.observe()
        assert not first.frame_changed and abs(first.ego.d) < 0.1
        # put the ego on the other lane's centre, 0.3 m off it, as after a lane change
        s0 = float(src.path.to_frenet(*src.ego.position)[0]) + 3.0
        src.ego.position = np.array(src.path.to_cartesian(s0, other + 0.3), dtype=float)
        src.ego.heading = float(src.path.heading(np.array([s0]))[0])
        before = src.distance()
        obs = src.observe()
        # the path is now that lane's centre line: the ego plans near d = 0, the old lane is
        # 5 m beside it, and the distance driven carries over
        assert obs.frame_changed and src.road_model is not model
        assert abs(obs.ego.d) < 0.5
        assert sorted(abs(c) for c in src.road_model.lane_centres) == pytest.approx(
            [0, 5], abs=1e-2
        )
        assert src.distance() == pytest.approx(before, abs=1e-6)
        x, y = src.path.to_cartesian(np.array([20.0, 60.0]), np.zeros(2))
        lane = net.get_closest_lane_index(np.array([x[0], y[0]]))
        lat = net.get_lane(lane).local_coordinates(np.array([x[0], y[0]]))[1]
        assert abs(lat) < 0.05
        assert not src.observe().frame_changed  # once
    finally:
        src.close()


def test_constant_velocity_futures_follow_the_curved_lanes():
    src = _racetrack(seed=4)
    try:
        net, targets = src.env.road.network, src._targets()
        assert targets
        pred = hw.ConstantVelocityPredictor(sigma_long=0.0, sigma_lat=0.0)
        out = pred(src.env.road, src.ego, targets, src.t_grid, 2, np.random.default_rng(0))
        assert out.shape == (len(targets), 2, len(src.t_grid), 2)
        # every predicted position is on the track, at the car's speed along its lane
        assert all(roads.on_road(net, p) for p in out.reshape(-1, 2))
        for o, v in enumerate(targets):
            step = np.linalg.norm(np.diff(out[o, 0], axis=0), axis=1).sum()
            assert step == pytest.approx(v.speed * src.t_grid[-1], rel=0.05)
        # a straight-line extrapolation would leave the track on these curves
        pos = np.array([v.position for v in targets])
        vel = np.array([v.velocity for v in targets])
        straight = pos[:, None] + vel[:, None] * src.t_grid[None, :, None]
        assert not all(roads.on_road(net, p) for p in straight.reshape(-1, 2))
    finally:
        src.close()


@pytest.mark.slow
def test_short_racetrack_episode_stays_on_the_road_and_its_video_shows_the_plan(tmp_path):
    import imageio.v2 as imageio

    from mmdopt.bench.highway import video

    rows = hw.run_highway(
        tmp_path / "run",
        episodes=1,
        seed=1,
        methods=["mmd"],
        settings=RACETRACK,
        config_overrides=TINY,
        progress=False,
    )
    (row,) = rows
    assert not row["crashed"] and row["off_road"] is False
    # distance along the curved path, not along x: about speed x duration
    assert row["distance_m"] == pytest.approx(row["mean_speed"] * 2.0, rel=0.2)
    with open(tmp_path / "run" / "episodes.csv") as f:
        header = next(csv.reader(f))
    # columns are only ever appended: the racetrack has no destination, its `arrived` is empty
    assert header[-4:] == ["off_road", "risk", "mean_risk_bound", "arrived"]
    with open(tmp_path / "run" / "episodes.csv") as f:
        assert next(csv.DictReader(f))["arrived"] == ""
    # the video: 2 s at 10 Hz, the plan and the samples drawn over highway-env's frames
    path = hw.write_video(tmp_path / "v.mp4", 0, 1, "mmd", RACETRACK, hw.highway_config(TINY))
    frames = [np.asarray(f)[..., :3].astype(int) for f in imageio.mimread(path)]
    assert len(frames) == 21
    raw = hw.HighwaySource(RACETRACK, 1, hw.highway_config(TINY), method="mmd", render=True)
    try:
        first = np.asarray(raw.frames[0]).astype(int)  # highway-env's own first frame
    finally:
        raw.close()
    assert first.shape == frames[0].shape
    changed = np.any(np.abs(frames[0] - first) > 40, axis=-1)
    assert changed.sum() > 500  # the labels, the plan and the predicted futures
    orange = np.all(np.abs(frames[0] - np.array(video.REDUCED_COLOUR)) < 40, axis=-1)
    assert orange.sum() > 20 and not np.any(
        np.all(np.abs(first - np.array(video.REDUCED_COLOUR)) < 40, axis=-1)
    )


def test_other_drivers_judge_the_ego_as_a_car_with_a_desired_speed():
    """highway-env's MOBIL asks what IDM acceleration a lane change would impose on the car
    behind, from that car's ``target_speed``: the ego has the planner's desired speed, so a
    moving ego is not taken for a car that would brake without limit (which kept every driver
    from ever merging in front of it)."""
    from highway_env.vehicle.behavior import IDMVehicle

    src = hw.HighwaySource(
        hw.HighwaySettings(env="merge-v0", duration=1.0, predictor="cv"),
        0,
        hw.highway_config(TINY),
        method="mmd",
    )
    try:
        assert src.ego.target_speed == hw.highway_config(TINY).cost.v_des
        # free road: IDM's acceleration of the ego at 20 m/s is its comfortable one, not -inf
        src.ego.speed = 20.0
        acc = IDMVehicle.acceleration(src.env.road.vehicles[1], ego_vehicle=src.ego)
        assert -1.0 < acc <= IDMVehicle.COMFORT_ACC_MAX
    finally:
        src.close()


def test_a_car_at_rest_reaches_the_planner_with_its_heading():
    """A car at rest turned across its lane (as after a crash): constant velocity keeps its
    samples at its centre (it may drive off along the road, never backwards or sideways), and
    the observation gives the planner its body heading, so every sample's footprint lies along
    its real axis; a moving car's samples start at its centre."""
    src = hw.HighwaySource(
        hw.HighwaySettings(env="highway-v0", duration=1.0, predictor="cv", forecast=False),
        3,
        hw.highway_config(TINY),
        method="mmd",
    )
    try:
        targets = src._targets()[:2]
        still, moving = targets
        still.speed, still.heading = 0.0, 1.0
        pred = hw.ConstantVelocityPredictor()
        out = pred(src.env.road, src.ego, targets, src.t_grid, 11, np.random.default_rng(0))
        np.testing.assert_allclose(out[0, :, 0], np.broadcast_to(still.position, (11, 2)))
        assert np.ptp(out[0, :, :, 1], axis=1).max() < 1e-9
        assert (np.diff(out[0, :, :, 0], axis=1) >= 0).all()
        np.testing.assert_allclose(out[1, :, 0], np.broadcast_to(moving.position, (11, 2)))
        obs = src.observe()
        heads = {id(v): h for v, h in zip(src._targets(), obs.obstacle_headings, strict=True)}
        assert heads[id(still)] == pytest.approx(1.0)
        assert obs.obstacle_headings.shape == (np.shape(obs.obstacles)[0],)
    finally:
        src.close()
