"""The real-traffic benchmark on the shared Lankershim Boulevard scenes (urban, signalised
intersections): tasks are found without any check on the scene name, and the ego's reference path
follows its recorded route through the junction with an exact Frenet <-> Cartesian map (skipped
with a reason where ../shared/data is absent)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip(
    "commonroad", reason="the ngsim benchmark needs commonroad-io (mmdopt[commonroad])"
)

FILE = "USA_Lanker-2_1_T-1.xml"
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@pytest.fixture(scope="module")
def urban_file(shared_data):
    f = shared_data / "ngsim_urban" / FILE
    if not f.is_file():
        pytest.skip(f"Lankershim scenes not found in {f.parent}")
    return str(f)


@pytest.fixture(scope="module")
def tasks(urban_file):
    from mmdopt.bench.ngsim.runner import select_tasks

    return select_tasks([urban_file])


def test_urban_scene_gives_tasks(urban_file, tasks):
    from mmdopt.bench.ngsim.scene import load_scenario

    sc = load_scenario(urban_file)
    assert sc.dt == pytest.approx(0.1)
    assert len(tasks) >= 1
    assert {t["scenario"] for t in tasks} == {urban_file}
    # every ego is a recorded car of the scene, planned at a time its history is recorded
    assert all(t["ego_id"] in set(sc.ids.tolist()) for t in tasks)


def test_route_path_follows_the_recorded_ego_exactly(urban_file, tasks):
    """Along each task's reference path, the recorded ego's next 5 s map to Frenet and back to
    within a millimetre, and stay within half a lane of the path (the path is its route)."""
    from mmdopt.bench.ngsim.scene import ego_road_geometry, load_scenario

    sc = load_scenario(urban_file)
    for t in tasks[:3]:
        v = int(np.flatnonzero(sc.ids == t["ego_id"])[0])
        path, _, _ = ego_road_geometry(sc, v, t["k"])
        xy = sc.xy[v, t["k"] : t["k"] + 51]
        xy = xy[np.all(np.isfinite(xy), -1)]
        s, d = (np.asarray(a) for a in path.to_frenet(xy[:, 0], xy[:, 1]))
        x2, y2 = (np.asarray(a) for a in path.to_cartesian(s, d))
        assert np.max(np.hypot(x2 - xy[:, 0], y2 - xy[:, 1])) < 1e-3
        lane_w = sc.lanes[int(sc.lane_of[v, t["k"]])].width
        assert np.max(np.abs(d)) < 0.5 * lane_w
        assert np.all(np.diff(s) > -1e-6)  # it drives forwards along the path


def test_a_turning_ego_plans_along_its_turn(shared_data):
    """Where the recorded ego turns through a junction (its heading over the next 5 s changes by
    more than 45°), its reference path turns with it: the path's heading where the car ends up
    is within 20° of the car's, and the car stays within a lane and a half of the path (the
    lanelet map of these scenes is itself up to ~6 m off the recorded turns)."""
    from mmdopt.bench.ngsim.runner import select_tasks
    from mmdopt.bench.ngsim.scene import ego_road_geometry, load_scenario

    # the scenes whose tasks include turns (2_2 ego 230, 2_9 ego 2807, 2_13 ego 2716)
    names = ("USA_Lanker-2_2_T-1.xml", "USA_Lanker-2_9_T-1.xml", "USA_Lanker-2_13_T-1.xml")
    files = [f for f in (shared_data / "ngsim_urban" / n for n in names) if f.is_file()]
    if len(files) < len(names):
        pytest.skip(f"Lankershim scenes not found in {shared_data / 'ngsim_urban'}")
    turns = 0
    for f in files:
        sc = load_scenario(str(f))
        for t in select_tasks([str(f)]):
            v, k = int(np.flatnonzero(sc.ids == t["ego_id"])[0]), t["k"]
            h = np.unwrap(sc.heading[v, k : k + 51])
            if abs(h[-1] - h[0]) < np.pi / 4:
                continue
            turns += 1
            path, _, _ = ego_road_geometry(sc, v, k)
            xy = sc.xy[v, k : k + 51]
            s, d = (np.asarray(a) for a in path.to_frenet(xy[:, 0], xy[:, 1]))
            dh = np.angle(np.exp(1j * (np.asarray(path.heading(s[-1])) - h[-1])))
            assert abs(dh) < np.radians(20), (f.name, t)
            assert np.max(np.abs(d)) < 1.5 * sc.lanes[int(sc.lane_of[v, k])].width + 1.0
            assert np.all(np.diff(s) > -0.05)  # the car moves forwards along its path
    assert turns >= 2


def test_route_path_is_smooth_enough_to_steer(urban_file, tasks):
    """The route's curvature changes no faster than a car steers: driving its centre line at
    8 m/s needs a steering rate within the KS model's 0.4 rad/s (the lanelets' polyline corners,
    unsmoothed, need more: :data:`~mmdopt.bench.ngsim.scene.ROUTE_SMOOTHING`)."""
    from mmdopt.bench.ngsim.scene import ego_road_geometry, load_scenario

    sc = load_scenario(urban_file)
    for t in tasks:
        v = int(np.flatnonzero(sc.ids == t["ego_id"])[0])
        path, _, _ = ego_road_geometry(sc, v, t["k"])
        se, _ = path.to_frenet(*sc.xy[v, t["k"]])
        s = float(se) + np.arange(0.0, 40.0, 0.8)  # 5 s at 8 m/s, one point per 0.1 s
        delta = np.arctan(2.578 * np.asarray(path.curvature(s)))  # BMW 320i wheelbase
        assert np.max(np.abs(np.diff(delta))) / 0.1 < 0.4, t


def test_the_desired_speed_respects_the_maps_speed_limit(urban_file, tasks):
    """Lankershim's lanelets carry speed-limit signs (25 and 30 mph, 8 mph on a few); a task's
    desired speed is capped at the one of the lanelets the ego reaches within 2 s, and only
    there (``speed_limits=False``: the traffic's speed alone)."""
    from mmdopt.bench.ngsim.runner import NgsimParams, build_task, ngsim_config, task_config
    from mmdopt.bench.ngsim.scene import load_scenario

    sc = load_scenario(urban_file)
    limits = [lane.speed_limit for lane in sc.lanes.values()]
    assert None not in limits
    assert {round(x, 2) for x in limits} <= {3.58, 11.18, 13.41}
    cfg = ngsim_config()
    for t in tasks:
        on, off = NgsimParams(), NgsimParams(speed_limits=False)
        b = build_task(t, on, cfg)
        assert b["v_limit"] is not None
        v_on = task_config(b, on, cfg).cost.v_des
        v_off = task_config(build_task(t, off, cfg), off, cfg).cost.v_des
        assert v_on == pytest.approx(min(v_off, b["v_limit"]))


def test_junction_cases_of_the_at_fault_rule(urban_file):
    """A side contact is the ego's fault when it changes lanes, and in a junction also when its
    centre is inside the junction or either car turns; the other classes keep their rule."""
    from mmdopt.bench.ngsim.metric import at_fault, inside_any, turning
    from mmdopt.bench.ngsim.scene import load_scenario

    assert not at_fault("lateral", 0.0, False)
    assert at_fault("lateral", 0.0, False, in_junction=True)
    assert at_fault("lateral", 0.0, False, turning=True)
    assert not at_fault("rear", 0.0, False, in_junction=True, turning=True)  # not a brake check
    assert at_fault("front", 0.0, False)
    # a car turning a right angle in 5 s turns; one drifting 3° in 1 s does not
    t = np.arange(51) * 0.1
    assert turning(t * (np.pi / 2) / 5.0, 0.1, 25)
    assert not turning(t * np.radians(3.0), 0.1, 25)
    # the junction polygons of a Lankershim scene hold their lanelets' centre points
    sc = load_scenario(urban_file)
    assert sc.n_intersections >= 1 and len(sc.junctions) >= 4
    for poly in sc.junctions[:4]:
        n = len(poly) // 2
        mid = 0.5 * (poly[n // 2] + poly[len(poly) - 1 - n // 2])
        assert inside_any(mid, [poly])
    assert not inside_any(np.array([1e6, 1e6]), sc.junctions)


def test_curve_speed_keeps_lateral_acceleration_and_steering_rate():
    """On a 20 m circle a car keeps 3 m/s² of lateral acceleration at √60 ≈ 7.7 m/s; where a
    straight runs into the circle the curvature's change caps the speed by the steering rate
    (wheelbase · v · |dκ/ds| ≤ δ̇); a straight road has no curve speed; bad bounds are named."""
    import frenet
    from mmdopt.bench.ngsim.scene import WHEELBASE, curve_speed

    ang = np.linspace(0.0, np.pi / 2, 200)
    circle = frenet.ReferencePath.from_waypoints(
        np.stack([20 * np.sin(ang), 20 * (1 - np.cos(ang))], -1), spacing=0.5
    )
    v = curve_speed(circle, 5.0, 15.0, lateral_accel=3.0, steer_rate=None)
    assert v == pytest.approx(np.sqrt(60.0), rel=0.03)
    line = frenet.ReferencePath.from_waypoints(np.stack([np.arange(0, 100.0), 0 * ang[:100]], -1))
    assert curve_speed(line, 0.0, 50.0, 3.0, 0.4) is None
    x = np.arange(0.0, 30.0, 0.5)
    arc = np.arange(0.0, 25.0, 0.5)
    arc_xy = np.stack([np.asarray(a) for a in circle.to_cartesian(arc, 0.0 * arc)], -1)
    joined = np.concatenate([np.stack([x - 30.0, 0 * x], -1)[:-1], arc_xy], axis=0)
    path = frenet.ReferencePath.from_waypoints(joined, spacing=0.5)
    v_steer = curve_speed(path, 10.0, 30.0, lateral_accel=None, steer_rate=0.4)
    s = np.arange(10.0, 40.5, 0.5)
    dk = np.max(np.abs(np.gradient(np.asarray(path.curvature(s)), 0.5)))
    assert v_steer == pytest.approx(0.4 / (WHEELBASE * dk), rel=1e-6)
    assert v_steer < np.sqrt(60.0)  # the transition binds before the circle itself
    with pytest.raises(ValueError, match="lateral_accel"):
        curve_speed(circle, 0.0, 10.0, lateral_accel=-1.0, steer_rate=None)
    with pytest.raises(ValueError, match="curve_accel"):
        from mmdopt.bench.ngsim.inputs import NgsimParams

        NgsimParams(curve_accel=0.0)
