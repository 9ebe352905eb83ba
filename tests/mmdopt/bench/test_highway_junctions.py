"""Junctions in highway-env (``intersection-v2``, ``roundabout-v1``): the ego's path along its
route, the routes other cars can take, the route predictor, the conflict areas of the shield's
crossing rule and the ``arrived`` record.

Skipped when highway-env is not installed (``pip install -e ".[highway]"``).
"""

from __future__ import annotations

import csv

import numpy as np
import pytest

from mmdopt.bench import highway as hw
from mmdopt.bench.highway import junction, roads
from mmdopt.bench.highway.predictors import RoutePredictor

from .test_highway_scenarios import TINY

pytestmark = pytest.mark.skipif(
    not hw.highway_available(),
    reason='highway-env/gymnasium not installed (pip install ".[highway]")',
)

JUNCTIONS = ("intersection-v2", "roundabout-v1")
LIMITS = dict(v_min=0.0, v_max=20.0, vy_max=3.0, ax_max=5.0, ay_max=3.0)


def _env(name, seed=0):
    from mmdopt.bench.highway.settings import require_highway

    gym = require_highway()
    env = gym.make(name).unwrapped
    env.reset(seed=seed)
    return env


@pytest.mark.parametrize("name", JUNCTIONS)
def test_the_ego_path_follows_its_route_exactly_and_smoothly(name):
    env = _env(name, seed=3)
    net, ego = env.road.network, env.vehicle
    route = roads.route_of(ego)
    assert route is not None and len(route) >= 3  # the configured destination
    model = roads.build_road(net, ego.lane_index, ego.position, limits=LIMITS, route=route)
    path = model.path
    # the path runs along the route, road after road
    assert [li[:2] for li in model.chain.indices[: len(route)]] == [r[:2] for r in route]
    # away from the joins, the route's lane centres are the path's d = 0 to well under a cm
    lanes = [net.get_lane(li) for li in model.chain.indices[: len(route)]]
    kinks = roads._kinks(lanes, False)
    pts = []
    for k, lane in enumerate(lanes):
        lo = kinks.get(k - 1, 0.0) + roads.BLEND
        hi = float(lane.length) - kinks.get(k, 0.0) - roads.BLEND
        pts += [lane.position(float(u), 0.0) for u in np.linspace(lo, hi, 40)]
    pts = np.array(pts)
    s, d = path.to_frenet(pts[:, 0], pts[:, 1])
    inside = (s > 1.0) & (s < path.length - 1.0)
    assert inside.sum() > 60
    assert np.max(np.abs(d[inside])) < 1e-3
    # Frenet <-> Cartesian round trip along the curves
    rng = np.random.default_rng(0)
    ss, dd = rng.uniform(1.0, path.length - 1.0, 500), rng.uniform(-2.0, 2.0, 500)
    x, y = path.to_cartesian(ss, dd)
    s2, d2 = path.to_frenet(x, y)
    assert np.max(np.abs(s2 - ss)) < 1e-6 and np.max(np.abs(d2 - dd)) < 1e-6
    # no kink a car could not follow (the roundabout's 47° entries are joined smoothly)
    kappa = np.abs(path.curvature(np.linspace(0.0, path.length, 5000)))
    assert kappa.max() < 0.2


def test_roundabout_entries_and_exits_are_kinks_the_chain_joins():
    env = _env("roundabout-v1")
    net, ego = env.road.network, env.vehicle
    idx, _ = roads.chain_indices(net, ego.lane_index, 300.0, route=roads.route_of(ego))
    kinks = roads._kinks([net.get_lane(i) for i in idx], False)
    assert len(kinks) == 2  # onto the ring and off it
    assert all(0 < cut <= roads.JOIN for cut in kinks.values())


def test_an_exit_lane_ends_the_chain_instead_of_turning_back():
    env = _env("intersection-v2")
    net = env.road.network
    idx, closed = roads.chain_indices(net, ("il1", "o1", 0), 500.0)
    assert idx == [("il1", "o1", 0)] and not closed


def test_an_entry_of_the_intersection_has_three_routes_to_three_exits():
    env = _env("intersection-v2")
    net = env.road.network
    routes = roads.routes_from(net, ("o2", "ir2", 0), 150.0)
    assert len(routes) == 3
    exits = {r[-1][1] for r in routes}
    assert exits == {"o0", "o1", "o3"}  # right, straight, left: never back to o2
    with pytest.raises(ValueError, match="reach"):
        roads.routes_from(net, ("o2", "ir2", 0), 0.0)


def test_route_predictor_splits_its_samples_evenly_over_the_routes_along_their_centre_lines():
    env = _env("intersection-v2", seed=3)
    cars = [v for v in env.road.vehicles if v is not env.vehicle]
    pred = RoutePredictor()
    t = np.linspace(0.0, 5.0, 26)
    out = pred(env.road, env.vehicle, cars, t, 12, np.random.default_rng(1))
    assert out.shape == (len(cars), 12, 26, 2)
    assert np.all(np.isfinite(out))
    for o, routes in enumerate(pred.last_routes):
        counts = np.bincount(pred.last_modes[o], minlength=len(routes))
        assert counts.max() - counts.min() <= 1  # uniform weights
        # the noise-free sample of each mode lies on its route's centre line (at the car's
        # lateral offset, which the predictor keeps)
        car = cars[o]
        lane = env.road.network.get_lane(car.lane_index)
        d0 = float(lane.local_coordinates(np.asarray(car.position, float))[1])
        for j, route in enumerate(routes):
            ch = pred.chain(env.road.network, route)
            xy = out[o, j]
            dist = np.min(np.linalg.norm(xy[:, None, :] - ch.xy[None, :, :], axis=-1), axis=1)
            assert np.max(dist) < abs(d0) + 0.35
    again = pred(env.road, env.vehicle, cars, t, 12, np.random.default_rng(1))
    np.testing.assert_array_equal(out, again)  # the same stream, the same futures
    with pytest.raises(ValueError, match="weights"):
        RoutePredictor(weights="learned")


def test_crossing_cars_get_conflict_areas_and_the_car_ahead_in_lane_none():
    env = _env("intersection-v2", seed=3)
    net, ego = env.road.network, env.vehicle
    model = roads.build_road(net, ego.lane_index, ego.position, limits=LIMITS,
                             route=roads.route_of(ego))  # fmt: skip
    pred = RoutePredictor()
    s_ego = float(model.path.to_frenet(*ego.position)[0])
    cars = [v for v in env.road.vehicles if v is not ego]
    c = junction.crossings(pred, env.road, model.path, s_ego, cars, ahead=80.0)
    assert c.shape[1] == 3 and c.shape[0] >= 1
    # the conflict areas lie in the junction ahead of the ego (it starts ~ 35 m before it)
    assert np.all(c[:, 0] > s_ego) and np.all(c[:, 1] > c[:, 0])
    assert np.all(c[:, 2] >= 0)
    # a car in the ego's own lane, ahead of it, is the longitudinal rule's
    ahead = type(cars[0]).make_on_lane(env.road, ego.lane_index, longitudinal=90.0, speed=5.0)
    assert junction.crossings(pred, env.road, model.path, s_ego, [ahead]).shape == (0, 3)


def test_earliest_arrival_accelerates_to_the_top_speed():
    t = junction.earliest_arrival(np.array([0.0, 2.0, 100.0]), 0.0, 10.0, 2.0)
    assert t[0] == 0.0
    assert t[1] == pytest.approx(np.sqrt(2.0))  # ½ a t² = 2 m
    assert t[2] == pytest.approx(5.0 + (100.0 - 25.0) / 10.0)  # 25 m to reach 10 m/s


def test_arrival_is_25_m_along_the_last_road_of_the_route():
    for name in JUNCTIONS:
        env = _env(name, seed=2)
        ego = env.vehicle
        route = roads.route_of(ego)
        last = env.road.network.get_lane((route[-1][0], route[-1][1], 0))
        assert not roads.arrived(env, ego, route)  # at the start
        for s, want in ((min(10.0, 0.3 * last.length), False), (last.length - 1.0, True)):
            ego.position = last.position(s, 0.0)
            ego.heading = last.heading_at(s)
            ego.on_state_update()
            assert roads.arrived(env, ego, route) is want, (name, s)
        assert not roads.arrived(env, ego, None)  # no destination, never arrived


def test_junction_episode_ends_on_arrival_and_records_it(tmp_path):
    settings = hw.HighwaySettings(
        env="roundabout-v1",
        duration=15.0,
        n_samples=6,
        max_obstacles=3,
        predictor="route",
    )
    rows = hw.run_highway(
        tmp_path, episodes=1, seed=7, methods=["mmd", "idm"], settings=settings,
        config_overrides=TINY, progress=False,
    )  # fmt: skip
    for r in rows:
        assert isinstance(r["arrived"], bool)
        if r["arrived"]:
            assert r["duration_s"] < 15.0  # the episode ends on arrival, as the env's does
        elif not r["crashed"]:
            assert r["duration_s"] == pytest.approx(15.0)
    with open(tmp_path / "episodes.csv") as f:
        got = list(csv.DictReader(f))
    assert {"arrived", "risk", "mean_risk_bound"} <= set(got[0])
    import json

    run = json.loads((tmp_path / "run.json").read_text())
    assert run["predictor"] == "route" and run["margin_mode"] == "linear"
    assert run["risk"] is None  # no ε asked: the preset's time-linear margins


def test_the_env_spawns_and_clears_its_traffic_between_steps():
    settings = hw.HighwaySettings(env="intersection-v2", duration=8.0, predictor="route")
    src = hw.HighwaySource(settings, 11, hw.highway_config({}), method="idm")
    try:
        first = {id(v) for v in src.env.road.vehicles}
        src.run_idm()
        now = {id(v) for v in src.env.road.vehicles}
        assert now - first  # intersection-v2 spawns cars at its entries, ~0.6 per second
        assert src._spawned == int(src.env.time)  # once per second of the env's own policy
        assert src.others_crashed() >= 0
    finally:
        src.close()


def test_at_a_junction_the_planner_sees_the_nearest_cars_from_every_side():
    settings = hw.HighwaySettings(env="roundabout-v1", duration=2.0, predictor="route")
    src = hw.HighwaySource(settings, 3, hw.highway_config({}), method="mmd")
    try:
        targets = src._targets()
        ego = np.asarray(src.ego.position, float)
        d = sorted(
            float(np.linalg.norm(np.asarray(v.position) - ego))
            for v in src.env.road.vehicles
            if v is not src.ego
        )
        got = sorted(float(np.linalg.norm(np.asarray(v.position) - ego)) for v in targets)
        want = [x for x in d if x <= settings.ahead][: settings.max_obstacles]
        assert got == pytest.approx(want)  # by distance, not by the Frenet frame of the path
    finally:
        src.close()


def test_the_video_colours_each_route_and_draws_the_ego_route():
    from mmdopt.bench.highway import video

    frame = np.full((60, 60, 3), 100, np.uint8)
    samples = np.zeros((1, 2, 3, 2))
    samples[0, 0, :, 0] = [5.0, 10.0, 15.0]
    samples[0, 0, :, 1] = 10.0
    samples[0, 1, :, 0] = 10.0
    samples[0, 1, :, 1] = [30.0, 40.0, 50.0]
    step = video.StepDrawing(
        time=0.0,
        plan_xy=np.array([[50.0, 50.0], [55.0, 55.0]]),
        samples=samples,
        reduced=None,
        status="ok",
        modes=np.array([[0, 1]]),
        route_xy=np.array([[2.0, 2.0], [2.0, 58.0]]),
    )
    out = video.overlay(frame, (np.zeros(2), 1.0), step, [])
    colours = {tuple(int(c) for c in px) for px in out.reshape(-1, 3)}
    assert video.MODE_COLOURS[0] in colours and video.MODE_COLOURS[1] in colours
    assert video.ROUTE_COLOUR in colours
    assert video.SAMPLE_COLOUR not in colours  # at a junction the samples are by route


def test_at_an_intersection_the_route_predictor_beats_constant_velocity_on_a_rollout():
    from mmdopt.bench.highway.predictors import ConstantVelocityPredictor
    from mmdopt.bench.highway.training import evaluate_live

    preds = {"cv": ConstantVelocityPredictor, "route": RoutePredictor}
    res = evaluate_live(preds, "intersection-v2", [0], duration=7.0)
    assert res["route"]["n_vehicles"] == res["cv"]["n_vehicles"] > 0
    # cars turn: a mode per route covers the turn that one straight extrapolation misses
    assert res["route"]["min_ade"] < 0.5 * res["cv"]["min_ade"]
    assert res["route"]["coverage"] > res["cv"]["coverage"]


def test_bench_highway_predicts_routes_at_a_junction_by_default():
    from mmdopt.bench.highway.settings import default_predictor

    assert default_predictor("intersection-v2") == "route"
    assert default_predictor("roundabout-v1") == "route"
    assert default_predictor("highway-v0") == "learned"  # the learned MDN's roads
