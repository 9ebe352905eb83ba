"""highway-env closed loop (mmdopt.bench.highway): adapter, predictors, one short episode, CLI.

Skipped when highway-env is not installed (``pip install -e ".[highway]"``).  Episodes are short
(1 s, δ = 0.5 s) with a tiny planner so the jitted planner compiles once per cost mode.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math

import numpy as np
import pytest

from mmdopt.bench import highway as hw
from mmdopt.receding import pad_obstacles

pytestmark = pytest.mark.skipif(
    not hw.highway_available(),
    reason='highway-env/gymnasium not installed (pip install ".[highway]")',
)

TINY = {
    "n_samples": 60,
    "n_cem": 30,
    "n_elite": 10,
    "iterations": 3,
    "n_brake": 5,
    "num_steps": 26,
    "reduced_set_size": 5,
}
# the drawn arrays (not a forecast) in each observation: the tests read the predictions
SETTINGS = hw.HighwaySettings(duration=1.0, dt=0.5, n_samples=6, max_obstacles=3, forecast=False)


def _source(seed=5, method="mmd", settings=SETTINGS):
    return hw.HighwaySource(settings, seed, hw.highway_config(TINY), method=method)


# --------------------------------------------------------------------------------------- adapter
def test_state_round_trip_sim_frenet_sim():
    src = _source()
    try:
        for v in src.env.road.vehicles[:10]:
            ego = hw.vehicle_to_frenet(src.path, v)
            x, y, h, sp = hw.frenet_to_pose(src.path, ego)
            assert (x, y) == pytest.approx(tuple(v.position), abs=1e-6)
            assert math.remainder(h - v.heading, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
            assert sp == pytest.approx(v.speed, abs=1e-9)
            # highway-v0's lanes run along +x from y = 0: Frenet d is the lateral position
            assert ego.d == pytest.approx(v.position[1], abs=1e-6)
    finally:
        src.close()


def test_planning_ellipse_covers_two_cars_touching():
    """The highway preset's planning ellipse (semi-axes plus the time-linear margins at t = 0),
    about a car's three circles, holds every ego position at which two highway-env cars touch
    (centres within a length along and a width across)."""
    from highway_env.vehicle.kinematics import Vehicle

    from mmdopt import OBSTACLE_FOOTPRINT

    cfg = hw.highway_config()
    a = cfg.safety.footprint.a + cfg.safety.margins.margin_long
    b = cfg.safety.footprint.b + cfg.safety.margins.margin_lat
    length, width = float(Vehicle.LENGTH), float(Vehicle.WIDTH)
    s, d = np.meshgrid(np.linspace(-length, length, 201), np.linspace(-width, width, 81))
    offsets = np.asarray(OBSTACLE_FOOTPRINT.offsets)[:, None, None]
    inside = ((s - offsets) ** 2 / a**2 + d**2 / b**2 < 1.0).any(axis=0)
    assert inside.all(), "a position in which the cars touch lies outside the planning ellipse"


def test_road_bounds_cover_every_lane_and_frequencies_are_explicit():
    src = _source()
    try:
        lanes = src.env.road.network.all_side_lanes(src.ego.lane_index)
        assert len(lanes) == 4
        assert (src.road.y_lb, src.road.y_ub) == (0.0, 12.0)  # centres of lanes 0 and 3
        assert src.env.config["simulation_frequency"] == 10
        assert src.env.config["policy_frequency"] == 2.0
        assert SETTINGS.frames_per_step == 5
    finally:
        src.close()


def _one_plan(src):
    import jax

    import mmdopt

    obs = src.observe()
    return mmdopt.plan(
        obs.ego,
        obs.road,
        pad_obstacles(obs.obstacles, 3, obs.ego, obs.road, src.t_grid),
        config=hw.highway_config(TINY),
        key=jax.random.PRNGKey(0),
    )


@pytest.mark.slow
def test_exact_ego_model_follows_the_plan_exactly():
    import jax

    import mmdopt

    src = _source(settings=dataclasses.replace(SETTINGS, ego_model="exact"))
    try:
        obs = src.observe()
        cfg = hw.highway_config(TINY)
        p = mmdopt.plan(
            obs.ego,
            obs.road,
            pad_obstacles(obs.obstacles, 3, obs.ego, obs.road, src.t_grid),
            config=cfg,
            key=jax.random.PRNGKey(0),
        )
        src.step(p, 0.5)
        at = {k: np.interp(0.5, p.t, getattr(p, k)) for k in ("x", "y", "speed")}
        assert tuple(src.ego.position) == pytest.approx((at["x"], at["y"]), abs=1e-9)
        assert src.ego.speed == pytest.approx(at["speed"], abs=1e-9)
        assert src.ego_state().s == pytest.approx(np.interp(0.5, p.t, p.s), abs=1e-9)
        assert src.env.time == pytest.approx(0.5)
    finally:
        src.close()


def test_bicycle_ego_drives_through_its_model_close_to_the_plan():
    src = _source()  # the default ego model: highway-env's kinematic bicycle
    try:
        assert src.ego.model == "bicycle"
        p = _one_plan(src)
        src.step(p, 0.5)
        at = {k: np.interp(0.5, p.t, getattr(p, k)) for k in ("x", "y", "speed")}
        # steered and accelerated by the tracking controller, not placed on the plan
        assert tuple(src.ego.position) != (at["x"], at["y"])
        assert np.hypot(src.ego.position[0] - at["x"], src.ego.position[1] - at["y"]) < 0.3
        assert src.ego.speed == pytest.approx(at["speed"], abs=0.3)
        assert abs(src.ego.action["steering"]) <= math.pi / 3  # highway-env's steering limit
        errs = src.ego.tracking_errors
        assert len(errs) == SETTINGS.frames_per_step and all(0 <= e < 0.3 for e in errs)
        k, _ = hw.plan_curvature(p)
        assert k < hw.bicycle_limits()  # the plan is within the bicycle's curvature limit
    finally:
        src.close()


@pytest.mark.parametrize(
    "other, kind",
    [((10.0, 0.0), "front"), ((-8.0, 0.5), "rear"), ((1.0, 2.5), "side"), ((-1.0, -2.0), "side")],
)
def test_crash_classes(other, kind):
    assert hw.classify_crash((0.0, 0.0, 0.0), other) == kind


# ------------------------------------------------------------------------------------ predictors
def _scene():
    src = _source(seed=11)
    for _ in range(4):
        src._advance()  # let traffic move (the ego keeps its speed without a plan)
    return src


def test_vectorised_rollout_matches_highway_env_own_rollout():
    src = _scene()
    try:
        targets = src._targets()
        assert targets
        kw = dict(randomise=False)
        a = hw.SimulatorPredictor(mode="vectorised", **kw)
        b = hw.SimulatorPredictor(mode="clone", **kw)
        pa = a(src.env.road, src.ego, targets, src.t_grid, 2, np.random.default_rng(0))
        pb = b(src.env.road, src.ego, targets, src.t_grid, 2, np.random.default_rng(0))
        assert pa.shape == pb.shape == (len(targets), 2, len(src.t_grid), 2)
        # same deterministic drivers: the NumPy replica follows highway-env's own IDM/MOBIL within
        # a metre over 5 s (the lateral response is a fitted first-order model)
        assert np.max(np.abs(pa - pb)) < 1.0
        assert a.last_time_s > 0 and b.last_time_s > 0
    finally:
        src.close()


def test_random_lane_changes_make_the_predictions_multimodal():
    src = _scene()
    try:
        targets = src._targets()
        pred = hw.SimulatorPredictor(lane_change_prob=1.0)
        s = pred(src.env.road, src.ego, targets, src.t_grid, 30, np.random.default_rng(1))
        assert np.all(np.isfinite(s))
        lanes = np.round(s[:, :, -1, 1] / 4.0)  # lane of each sample after 5 s
        # every target is predicted to end in at least two different lanes across samples
        assert all(len(np.unique(row)) >= 2 for row in lanes)
        # and the samples start where the cars are
        start = np.array([v.position for v in targets])
        assert np.allclose(s[:, :, 0, :], start[:, None, :], atol=1e-9)
    finally:
        src.close()


@pytest.mark.parametrize("mode", ["vectorised", "clone"])
def test_a_slower_car_ahead_is_not_predicted_to_make_way_for_a_fast_ego(mode):
    # highway-env's drivers have MOBIL politeness 0: a slower car does not leave its lane because
    # the ego closes in from behind, so no rollout may show it doing so (a rollout that did
    # promised the ego a gap that never opened, and the ego ran into the car)
    from highway_env.vehicle.behavior import IDMVehicle

    src = _source(seed=11)
    try:
        road, ego = src.env.road, src.ego
        lane = road.network.get_lane(ego.lane_index)
        y = float(lane.position(0.0, 0.0)[1])
        ego.position, ego.heading, ego.speed = np.array([100.0, y]), 0.0, 28.0
        lead = IDMVehicle(road, np.array([115.0, y]), 0.0, 18.0, target_speed=18.0)
        road.vehicles[:] = [ego, lead]
        t = np.linspace(0.0, 5.0, 51)
        ego.set_plan(t, 100.0 + 28.0 * t, np.full_like(t, y), 0 * t, np.full_like(t, 28.0))
        pred = hw.SimulatorPredictor(lane_change_prob=0.0, mode=mode)
        s = pred(road, ego, [lead], src.t_grid, 20, np.random.default_rng(0))
        assert np.all(np.abs(s[0, :, :, 1] - y) < 1.0)  # every sample stays in its lane
    finally:
        src.close()


def test_constant_velocity_predictor_extrapolates():
    src = _scene()
    try:
        targets = src._targets()
        cv = hw.ConstantVelocityPredictor(sigma_long=0.0, sigma_lat=0.0)
        s = cv(src.env.road, src.ego, targets, src.t_grid, 3, np.random.default_rng(0))
        v0 = targets[0]
        expect = v0.position + v0.velocity * src.t_grid[-1]
        assert s[0, 0, -1] == pytest.approx(expect, abs=1e-9)
    finally:
        src.close()


# ------------------------------------------------------------------------------------- episodes
def test_short_episode_writes_every_csv_column_and_resumes(tmp_path):
    rows = hw.run_highway(
        tmp_path,
        episodes=1,
        seed=3,
        methods=["mmd", "idm"],
        settings=SETTINGS,
        config_overrides=TINY,
        progress=False,
    )
    assert len(rows) == 2
    with open(tmp_path / "episodes.csv") as f:
        table = list(csv.DictReader(f))
    need = (
        "episode,seed,env,method,predictor,crashed,mean_speed,distance_m,duration_s,"
        "mean_plan_s,max_plan_s"
    ).split(",")
    assert all(c in table[0] for c in need)
    mmd = next(r for r in table if r["method"] == "mmd")
    assert mmd["env"] == "highway-v0" and mmd["predictor"] == "learned" and mmd["seed"] == "3"
    assert float(mmd["duration_s"]) == pytest.approx(1.0) or mmd["crashed"] == "True"
    assert float(mmd["mean_speed"]) > 0 and float(mmd["distance_m"]) > 0
    assert 0 < float(mmd["mean_plan_s"]) <= float(mmd["max_plan_s"])
    assert int(mmd["steps"]) == 2
    # appended after the original columns: the bicycle ego's mean tracking error, time between
    # lanes and shield interventions
    cols = list(table[0])
    i = cols.index("crash_kind")
    assert cols[i + 1 : i + 4] == ["tracking_error_m", "between_lanes_s", "interventions"]
    assert 0 <= float(mmd["tracking_error_m"]) < 0.5
    assert 0 <= float(mmd["between_lanes_s"]) <= 1.0 and int(mmd["interventions"]) >= 0
    idm = next(r for r in table if r["method"] == "idm")
    assert float(idm["distance_m"]) > 0
    # resumable: finished episodes are read back, not recomputed
    p = tmp_path / "episodes" / "episode_0000__mmd.json"
    before = p.stat().st_mtime_ns
    hw.run_highway(
        tmp_path,
        episodes=1,
        seed=3,
        methods=["mmd", "idm"],
        settings=SETTINGS,
        config_overrides=TINY,
        progress=False,
    )
    assert p.stat().st_mtime_ns == before
    rec = json.loads(p.read_text())
    assert len(rec["plan_times"]) == 2 and len(rec["predict_times"]) == 2
    # other settings in the same folder are refused
    with pytest.raises(ValueError, match="different settings"):
        hw.run_highway(tmp_path, episodes=1, seed=4, settings=SETTINGS, config_overrides=TINY)
    # and so is a folder whose planner preset was another (a folder of another version)
    man = json.loads((tmp_path / "run.json").read_text())
    assert man["planner"] == hw.highway_config(TINY).to_dict()
    man["planner"]["cost"]["v_des"] += 1.0
    (tmp_path / "run.json").write_text(json.dumps(man))
    with pytest.raises(ValueError, match="different settings.*planner"):
        hw.run_highway(
            tmp_path, episodes=1, seed=3, methods=["mmd", "idm"], settings=SETTINGS,
            config_overrides=TINY, progress=False,
        )  # fmt: skip


def test_risk_mode_episode_states_its_level_and_each_replans_bound(tmp_path, capsys):
    """``--risk EPS``: the preset in the risk mode (sample-driven margins, safety.risk = ε,
    recorded in run.json's config), futures drawn from the predictor's forecast at each replan,
    and episodes.csv's ``risk`` and ``mean_risk_bound``; a level outside (0, 0.5) is refused
    naming ``--risk``."""
    settings = hw.HighwaySettings(duration=1.0, dt=0.5, n_samples=6, max_obstacles=2)
    (row,) = hw.run_highway(
        tmp_path / "r", episodes=1, seed=3, methods=["mmd"], settings=settings,
        config_overrides=TINY, progress=False, risk=0.1,
    )  # fmt: skip
    assert row["risk"] == 0.1 and row["steps"] == 2
    assert 0.0 <= row["mean_risk_bound"] <= 1.0
    # no phantoms on the dial: each number of cars is a shape, and so is an empty road (0),
    # compiled before the timed loop
    assert hw.runner._WARMED[hw.config_for_method("mmd", hw.highway_config(
        hw.risk_overrides(TINY, 0.1)))] == {0, 1, 2}  # fmt: skip
    man = json.loads((tmp_path / "r" / "run.json").read_text())
    assert man["config"]["safety"] == {"risk": 0.1, "margins": {"margin_mode": "samples"}}
    assert man["planner"]["safety"]["margins"]["margin_mode"] == "samples"
    with open(tmp_path / "r" / "episodes.csv") as f:
        (csv_row,) = list(csv.DictReader(f))
    assert float(csv_row["risk"]) == 0.1 and csv_row["mean_risk_bound"] != ""
    # the preset's own mode: no level, no bound column value
    assert hw.risk_overrides(TINY, None) == TINY
    from mmdopt.bench import cli

    with pytest.raises(SystemExit) as e:
        cli.main(["bench", "highway", "--episodes", "1", "--risk", "0.7",
                  "--out", str(tmp_path / "x")])  # fmt: skip
    assert e.value.code == 2 and "--risk" in capsys.readouterr().err


def _strip_timings(rec):
    # wall-clock fields differ run to run; everything else must be identical
    drop = {"plan_times", "predict_times"}
    return {
        k: v
        for k, v in rec.items()
        if k not in drop and (k == "duration_s" or not k.endswith("_s"))
    }


def test_same_seed_same_episode():
    cfg = hw.highway_config(TINY)
    a = hw.run_episode(0, 21, "mmd", SETTINGS, cfg)
    b = hw.run_episode(0, 21, "mmd", SETTINGS, cfg)
    assert _strip_timings(a) == _strip_timings(b)
    # the planner draws from each replan's forecast (the default) exactly the futures the array
    # path gives it: the same episode
    assert hw.HighwaySettings().forecast
    e = hw.run_episode(0, 21, "mmd", dataclasses.replace(SETTINGS, forecast=True), cfg)
    assert _strip_timings(a) == _strip_timings(e)
    assert len(a["predict_times"]) == len(e["predict_times"]) == a["steps"]
    c = hw.run_episode(0, 21, "idm", SETTINGS, cfg)
    d = hw.run_episode(0, 21, "idm", SETTINGS, cfg)
    assert _strip_timings(c) == _strip_timings(d)


# ------------------------------------------------------------------------------------ validation
@pytest.mark.parametrize(
    "kw, match",
    [
        ({"duration": 0.0}, "duration"),
        ({"dt": 0.33}, "simulation_frequency"),
        ({"predictor": "oracle"}, "predictor"),
        ({"n_samples": 0}, "n_samples"),
        ({"forecast": 1}, "forecast"),
        ({"ahead": -1.0}, "ahead"),
    ],
)
def test_bad_settings_are_rejected(kw, match):
    with pytest.raises(ValueError, match=match):
        hw.HighwaySettings(**kw)


def test_bad_runner_arguments_are_rejected(tmp_path):
    with pytest.raises(ValueError, match="methods"):
        hw.run_highway(tmp_path, episodes=1, methods=["rl"], settings=SETTINGS)
    with pytest.raises(ValueError, match="episodes"):
        hw.run_highway(tmp_path, episodes=0, settings=SETTINGS)
    with pytest.raises(ValueError, match="executor"):
        hw.run_highway(tmp_path, episodes=1, executor="slurm", settings=SETTINGS)
    with pytest.raises(ValueError, match="jobs"):
        hw.run_highway(tmp_path / "j", episodes=1, jobs=0, settings=SETTINGS)
    with pytest.raises(ValueError, match="method"):
        hw.HighwaySource(SETTINGS, 0, hw.highway_config(TINY), method="rl")


def test_agents_are_drivers_plan_methods_and_predictors():
    """``--methods`` names agents: the planner with a plan method on the settings' predictor
    (mmd, degroot) or on its own noise-free constant-velocity mean (cv), or highway-env's IDM
    driver (idm); the table is read-only and gives the CLI's choices."""
    A = hw.AGENTS
    assert hw.METHODS == ("mmd", "degroot", "cv", "idm") == tuple(A)
    assert [(a.driver, a.plan_method, a.predictor) for a in A.values()] == [
        ("planner", "mmd", None),
        ("planner", "degroot", None),
        ("planner", "scenario_all", "cv-mean"),
        ("idm", None, None),
    ]
    with pytest.raises(TypeError):
        A["rl"] = A["mmd"]  # type: ignore[index]
    with pytest.raises(dataclasses.FrozenInstanceError):
        A["mmd"].plan_method = "saa"  # type: ignore[misc]
    with pytest.raises(ValueError, match="driver"):
        hw.Agent("x", "human", None)
    with pytest.raises(ValueError, match="plan_method"):
        hw.Agent("x", "idm", "mmd")
    # the cv agent observes one noise-free sample per car from its own predictor
    src = _source(seed=5, method="cv")
    try:
        assert src.agent is A["cv"] and src.own_predictor.sigma_lat == 0.0
        obs = src.observe()
        assert obs.obstacles.shape[1] == 1
    finally:
        src.close()


def test_cli_parser_and_bad_options(tmp_path, capsys):
    import argparse

    p = argparse.ArgumentParser()
    hw.add_highway_parser(p.add_subparsers(dest="experiment"))
    args = p.parse_args(
        ["highway", "--out", str(tmp_path), "--episodes", "2", "--methods", "mmd,idm"]
    )
    assert args.methods == ["mmd", "idm"] and args.episodes == 2 and args.func is hw.cmd_highway
    with pytest.raises(SystemExit):
        p.parse_args(["highway", "--out", str(tmp_path), "--methods", "mmd,rl"])
    assert "rl" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text('{"no_such_field": 1}')
    args = p.parse_args(["highway", "--out", str(tmp_path / "o"), "--config", str(bad)])
    assert hw.cmd_highway(args) == 2
    assert "no_such_field" in capsys.readouterr().err


def test_wired_into_the_package_cli(tmp_path):
    from mmdopt.bench.cli import build_parser

    a = build_parser().parse_args(["bench", "highway", "--out", str(tmp_path), "--seed", "4"])
    assert a.experiment == "highway" and a.seed == 4 and a.func is hw.cmd_highway


def test_merge_env_uses_its_main_road_and_the_exact_clone_rollouts():
    st = hw.HighwaySettings(
        env="merge-v0", duration=1.0, n_samples=4, max_obstacles=3, forecast=False
    )
    src = hw.HighwaySource(st, 1, hw.highway_config(TINY), method="mmd")
    try:
        assert (src.road.y_lb, src.road.y_ub) == (0.0, 4.0)  # the two main-road lanes
        assert not hw.straight_parallel(src.env.road.network)  # the ramp: clone mode
        obs = src.observe()
        assert obs.obstacles.shape[1:] == (4, len(src.t_grid), 2)
        assert np.all(np.isfinite(obs.obstacles)) and obs.info["predict_s"] > 0
    finally:
        src.close()


def test_video_of_one_episode(tmp_path):
    import imageio.v2 as imageio

    st = hw.HighwaySettings(duration=1.0, dt=0.5)
    path = hw.write_video(tmp_path / "v.mp4", 0, 2, "idm", st, hw.highway_config(TINY))
    frames = imageio.mimread(path)
    # the first frame plus one per simulator step (10 Hz for 1 s)
    assert len(frames) == 11 and frames[0].ndim == 3
    assert path.suffix in (".gif", ".mp4")


def test_a_measured_state_just_past_the_bounds_is_moved_onto_them_and_a_far_one_is_kept():
    """Tracking noise (10.05 m/s at a 10 m/s limit, a lateral offset 0.1 m past the outer lane
    centre) is moved onto the planner's bounds; a real excess is kept, so the planner reports
    it (a braking fallback) instead of starting from a silently moved state."""
    from mmdopt.bench.highway.adapter import MEASURED_SLACK, _settle

    assert _settle(10.05, 0.0, 10.0, MEASURED_SLACK["vs"]) == 10.0
    assert _settle(-0.1, 0.0, 12.0, MEASURED_SLACK["d"]) == 0.0
    assert _settle(12.1, 0.0, 12.0, MEASURED_SLACK["d"]) == 12.0
    assert _settle(5.0, 0.0, 12.0, MEASURED_SLACK["d"]) == 5.0
    assert _settle(13.0, 0.0, 10.0, MEASURED_SLACK["vs"]) == 13.0


def test_driving_on_past_the_end_of_the_road_is_not_a_departure():
    """merge-v0's road ends 460 m from the start: in line with its last lanes past that end the
    ego is still on the road; beside the lanes, or past the end of the acceleration lane (which
    ends before the road does), it is not."""
    import gymnasium as gym

    from mmdopt.bench.highway.roads import on_road

    env = gym.make("merge-v0").unwrapped
    env.reset(seed=1)
    net = env.road.network
    assert on_road(net, [100.0, 0.0]) and on_road(net, [300.0, 8.0])
    assert on_road(net, [700.0, 4.0])
    assert not on_road(net, [100.0, 9.0]) and not on_road(net, [330.0, 8.0])
    assert not on_road(net, [700.0, 9.0])
    env.close()
