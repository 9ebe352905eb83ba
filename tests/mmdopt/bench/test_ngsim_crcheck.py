"""CommonRoad's own checkers on the real-traffic benchmark's plans (collision with the recorded
obstacles, road compliance, KS feasibility) and the solution files of ``bench ngsim --export``.

Skipped with a reason where the US-101 scenes (../shared/data) or the drivability checker (with a
commonroad-io it imports with) are absent."""

from __future__ import annotations

import csv
import types

import numpy as np
import pytest

pytest.importorskip(
    "commonroad", reason="the ngsim benchmark needs commonroad-io (mmdopt[commonroad])"
)

from mmdopt.bench.ngsim import crcheck  # noqa: E402

if crcheck.available() is not None:
    pytest.skip(crcheck.available(), allow_module_level=True)

FILE = "USA_US101-10_1_T-1.xml"
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@pytest.fixture(scope="module")
def ngsim_file(shared_data):
    f = shared_data / "ngsim_us101" / FILE
    if not f.is_file():
        pytest.skip(f"NGSIM scene not found at {f}")
    return f


def _tiny():
    import mmdopt

    return mmdopt.MMDOptConfig.ngsim().replace(
        n_samples=60, n_cem=30, n_elite=10, iterations=2, n_brake=2
    )


def _fake_plan(xy, heading, speed, times):
    """A plan-shaped object driving along given positions (no planner involved)."""
    K = len(times)
    return types.SimpleNamespace(
        x=xy[:, 0], y=xy[:, 1], heading=heading, speed=speed, t=times,
        d=np.zeros(K), as_=np.zeros(K), plan_time_s=0.0,
    )  # fmt: skip


def test_checker_and_our_metric_agree_on_recorded_and_colliding_footprints(ngsim_file):
    """The same footprint against the same recorded vehicles: the human's recorded drive and a
    drive on top of another car's recording get the same collision verdict from both."""
    from mmdopt.bench.ngsim.runner import NgsimParams, _score_recorded, build_task, select_tasks
    from mmdopt.bench.ngsim.scene import future_at

    cfg, p = _tiny(), NgsimParams(egos_per_time=1)
    task = select_tasks([ngsim_file], p, cfg)[0]
    b = build_task(task, p, cfg)
    sc, v, k, times = b["scene"], b["v"], b["k"], b["times"]
    steps = k + np.rint(times / sc.dt).astype(int)
    human = _fake_plan(
        future_at(sc, [v], k, times)[0], sc.heading[v, steps], sc.speed[v, steps], times
    )
    other = int(b["obs"][0])  # the nearest vehicle, recorded over the whole horizon?
    fut = future_at(sc, [other], k, times)[0]
    if not np.all(np.isfinite(fut)):
        pytest.skip("the nearest vehicle leaves the scene within the horizon")
    on_top = _fake_plan(fut, sc.heading[other, steps], sc.speed[other, steps], times)
    verdicts = {}
    for name, plan in (("human", human), ("on_top", on_top)):
        ours = _score_recorded(b, plan, p)
        cr = crcheck.check_plan(
            plan, task["scenario"], task["ego_id"], k, sc.length[v], sc.width[v]
        )
        assert set(cr) == set(crcheck.CR_COLUMNS)
        assert all(isinstance(x, bool) for x in cr.values())
        verdicts[name] = (ours["any_collision"], cr["cr_collision_free"])
    assert verdicts["on_top"] == (True, False), verdicts  # colliding for both
    assert verdicts["human"][1] == (not verdicts["human"][0]), verdicts
    assert crcheck.disagreements([]).startswith("CommonRoad checkers: no verdicts")


@pytest.mark.slow  # one JIT compile of Algorithm 1 at a tiny size (~30-60 s on 2 cores)
def test_bench_ngsim_writes_checker_columns_and_exports_solutions(ngsim_file, tmp_path):
    from commonroad.common.solution import CommonRoadSolutionReader, VehicleModel

    from mmdopt.bench.ngsim import NgsimParams, run_ngsim
    from mmdopt.bench.ngsim.runner import RESULT_COLUMNS

    p = NgsimParams(egos_per_time=1, every=100.0, n_samples=20, n_validation=50)
    rows = run_ngsim(
        [ngsim_file], tmp_path / "r", methods=("mmd",), predictor="cv", config=_tiny(),
        params=p, max_tasks=1, export=tmp_path / "sol",
    )  # fmt: skip
    assert len(rows) == 1 and not str(rows[0]["status"]).startswith("error"), rows
    assert set(crcheck.CR_COLUMNS) <= set(RESULT_COLUMNS)
    with open(tmp_path / "r" / "results.csv") as f:
        table = list(csv.DictReader(f))
    for c in crcheck.CR_COLUMNS:
        assert table[0][c] in ("True", "False"), (c, table[0][c])
        assert isinstance(rows[0][c], bool)
    if rows[0]["any_collision"]:  # the same footprint: a plan we call colliding is not free
        assert not rows[0]["cr_collision_free"], crcheck.disagreements(rows)
    assert "CommonRoad checkers on 1 plans" in crcheck.disagreements(rows)
    files = sorted((tmp_path / "sol").glob("*.xml"))
    assert len(files) == 1
    sol = CommonRoadSolutionReader.open(str(files[0]))
    pps = sol.planning_problem_solutions[0]
    assert pps.vehicle_model == VehicleModel.KS and pps.planning_problem_id == rows[0]["ego_id"]
    traj = pps.trajectory
    assert traj.initial_time_step == round(rows[0]["t0"] / 0.1)
    assert len(traj.state_list) == 51  # 5 s on the scene's 0.1 s grid


def _arc_plan(v: float, radius: float, straight: float, seconds: float = 5.0):
    """The centre of a car driving ``straight`` m straight, then a circle of ``radius`` m (no
    transition), at ``v`` m/s; heading = its direction of motion, as a plan's."""
    t = np.arange(0.0, seconds + 1e-9, 0.1)
    s = v * t
    on = s > straight
    ang = np.where(on, (s - straight) / radius, 0.0)
    x = np.where(on, straight + radius * np.sin(ang), s)
    y = np.where(on, radius * (1.0 - np.cos(ang)), 0.0)
    return _fake_plan(np.stack([x, y], -1), ang, np.full_like(t, v), t)


def test_body_heading_is_the_tractrix_of_a_steady_turn():
    """On a circle the KS car's rear axle runs on the inner circle: the body heading trails the
    centre's direction of motion by the slip angle asin(l_r / R) and turns at v / R."""
    l_r, R, v = 1.42, 20.0, 8.0
    plan = _arc_plan(v, R, straight=0.0)
    psi, rate = crcheck.body_heading(plan.t, plan.heading, plan.speed, l_r)
    np.testing.assert_allclose(plan.heading - psi, np.arcsin(l_r / R), atol=1e-6)
    np.testing.assert_allclose(rate, v / R, rtol=1e-5)
    # the rear axle moves along the body heading
    rear = np.stack([plan.x - l_r * np.cos(psi), plan.y - l_r * np.sin(psi)], -1)
    chord = np.arctan2(*np.diff(rear, axis=0).T[::-1])
    np.testing.assert_allclose(chord, 0.5 * (psi[1:] + psi[:-1]), atol=1e-4)
    with pytest.raises(ValueError, match="l_r"):
        crcheck.body_heading(plan.t, plan.heading, plan.speed, 0.0)


def test_the_ks_check_accepts_a_steerable_turn_and_rejects_a_steering_jump():
    """A car steering into a 20 m circle at 6 m/s (the steady turn from the start) is
    reproducible by the KS model; a straight that turns into a 12 m circle without a
    transition at 12 m/s asks for a steering jump beyond the 0.4 rad/s limit."""
    from commonroad_dc.feasibility.feasibility_checker import trajectory_feasibility

    for plan, expected in ((_arc_plan(6.0, 20.0, 0.0), True), (_arc_plan(12.0, 12.0, 20.0), False)):
        traj = crcheck.plan_trajectory(plan, 0, 0.1)
        ok, _ = trajectory_feasibility(traj, crcheck._vehicle(), 0.1)
        assert bool(ok) is expected
