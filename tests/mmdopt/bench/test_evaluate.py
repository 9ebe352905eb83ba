"""Collision metric, kinematic check, summary statistics and the resumable sweep harness."""

import csv
import dataclasses
import json
from types import SimpleNamespace

import numpy as np
import pytest

import mmdopt
from mmdopt.bench import metric, synthetic
from mmdopt.bench.metric import collision_free, kinematic_violation
from mmdopt.bench.results import check_bars, summarize
from mmdopt.bench.scenes import SceneParams

K = 100
T = np.linspace(0.0, 15.0, K)


def _line(v=10.0, y=0.0):
    return np.stack([v * T, np.full(K, y)], axis=-1)


def _fake_plan(v=10.0, d=0.0, **kw):
    s = v * T
    z = np.zeros(K)
    base = dict(
        x=s,
        y=np.full(K, d),
        s=s,
        d=np.full(K, d),
        vs=np.full(K, v),
        vd=z,
        as_=z,
        ad=z,
        speed=np.full(K, v),
        feasible=True,
        fallback=False,
        status="ok",
        cost=1.0,
        mmd=0.0,
        residual=0.0,
        plan_time_s=0.01,
    )
    base.update(kw)
    return SimpleNamespace(**base)


def test_plan_far_from_every_sample_counts_all():
    rng = np.random.default_rng(0)
    val = _line(5.0)[None] + rng.normal(0, 1, (1000, K, 2))
    assert collision_free(_line(10.0, y=100.0), val) == 1000


def test_plan_through_every_sample_counts_zero():
    rng = np.random.default_rng(1)
    plan = _line(10.0)
    val = plan[None] + rng.uniform(-0.1, 0.1, (1000, K, 2))
    assert collision_free(plan, val[None]) == 0


def test_collision_is_strict_f_bar_positive():
    """An obstacle exactly on the ellipse boundary (f = 0) is not a collision; inside it is."""
    plan = _line(10.0)
    # semi-axes that are powers of two, so that f = 0 is exact in floating point (with 3.5 m,
    # XLA's Δy²·(1/b²) rounds either way)
    a = b = 4.0
    on = plan + np.array([0.0, b])  # centre circle at Δy = b, Δx = 0: f = 0 exactly
    inside = plan + np.array([0.0, b - 1e-9])
    assert collision_free(plan, on[None, None], a=a, b=b) == 1
    assert collision_free(plan, inside[None, None], a=a, b=b) == 0
    # the front/rear circles (±2.5 m along the heading) count too
    ahead = plan + np.array([2.5 + 4.5 - 1e-6, 0.0])  # rear circle just inside the ellipse
    assert collision_free(plan, ahead[None, None]) == 0
    assert collision_free(plan, (plan + np.array([7.0 + 1e-6, 0.0]))[None, None]) == 1


def test_collision_any_step_and_joint_over_obstacles():
    plan = _line(10.0)
    far = plan + np.array([0.0, 50.0])
    one_step = far.copy()
    one_step[57] = plan[57]  # a single touching step is a collision
    val = np.stack([far, one_step, far])
    assert collision_free(plan, val) == 2
    # two obstacles: joint draw n collides if it collides with either obstacle
    two = np.stack([val, np.stack([one_step, far, far])])
    assert collision_free(plan, two) == 1


def test_metric_rejects_bad_shapes():
    with pytest.raises(ValueError, match="plan_xy"):
        collision_free(np.zeros((K, 3)), np.zeros((1, 5, K, 2)))
    with pytest.raises(ValueError, match="NaN"):
        collision_free(np.full((K, 2), np.nan), np.zeros((1, 5, K, 2)))
    with pytest.raises(ValueError, match="validation_samples"):
        collision_free(_line(), np.zeros((1, 5, K - 1, 2)))


def test_kinematic_check_flags_violations():
    road = SimpleNamespace(y_lb=-0.3, y_ub=0.3, v_min=0.0, v_max=30.0)
    assert kinematic_violation(_fake_plan(), road) == 0.0
    assert kinematic_violation(_fake_plan(d=0.5), road) == pytest.approx(0.2)
    assert kinematic_violation(_fake_plan(v=31.0), road) == pytest.approx(1.0)
    assert kinematic_violation(_fake_plan(as_=np.full(K, 20.0)), road) == pytest.approx(2.0)
    assert kinematic_violation(_fake_plan(d=np.full(K, np.nan)), road) == np.inf
    assert metric.progress(_fake_plan(v=8.0)) == pytest.approx(120.0)


def test_summary_statistics_and_ties_count_as_success():
    rows = []
    for s, (a, b) in enumerate([(990, 980), (970, 970), (950, 960), (1000, 900)]):
        rows.append(
            dict(
                scene=s,
                method="mmd",
                collision_free=a,
                n_validation=1000,
                progress_m=100.0,
                feasible=True,
                mean_speed=7.0,
                plan_time_s=0.1,
            )
        )
        rows.append(
            dict(
                scene=s,
                method="degroot",
                collision_free=b,
                n_validation=1000,
                progress_m=125.0,
                feasible=True,
                mean_speed=8.0,
                plan_time_s=0.2,
            )
        )
    summ = summarize(rows)
    cf = summ["methods"]["mmd"]["collision_free"]
    assert cf["mean"] == pytest.approx(977.5)
    assert cf["min"] == 950 and cf["q1"] == pytest.approx(np.percentile([990, 970, 950, 1000], 25))
    vs = summ["vs"]["degroot"]
    assert vs["share_ge"] == pytest.approx(0.75) and vs["share_gt"] == pytest.approx(0.5)
    assert vs["progress_ratio"] == pytest.approx(0.8)
    bars = check_bars(summ)
    assert bars["mean"]["ok"] and not bars["q1"]["ok"] and bars["progress_ratio_vs_degroot"]["ok"]


# --------------------------------------------------------------------------------- harness
# The sweep machinery (files, resume, manifest, CSV) is tested with a stand-in planner; the real
# Algorithm 1 runs through the same code in tests/mmdopt/test_cli.py.


@dataclasses.dataclass(frozen=True)
class _Cfg:
    v_des: float = 10.0

    def replace(self, **kw):
        return dataclasses.replace(self, **kw)


@pytest.fixture
def fake_planner(monkeypatch):
    calls = []

    def plan(
        ego, road, obstacles, *, method="mmd", config=None, backend="admm-fixed", key=None, **kw
    ):
        calls.append(method)
        return _fake_plan(v=6.0 if method == "mmd" else 9.0)

    monkeypatch.setattr(mmdopt, "plan", plan, raising=False)
    monkeypatch.setattr(mmdopt, "MMDOptConfig", _Cfg, raising=False)
    monkeypatch.setattr(mmdopt, "Road", lambda **kw: SimpleNamespace(**kw), raising=False)
    return calls


def test_sweep_writes_contract_columns_and_resumes(tmp_path, fake_planner):
    params = SceneParams(n_samples=20, n_validation=50)
    kw = dict(scenes=3, params=params, methods=["mmd", "degroot"], jobs=1, progress=False)
    res = synthetic.run_synthetic(tmp_path, **kw)
    assert res["computed"] == 6 and res["reused"] == 0 and len(fake_planner) == 6
    with open(tmp_path / "results.csv") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
    for col in (
        "scene",
        "method",
        "collision_free",
        "n_validation",
        "progress_m",
        "feasible",
        "plan_time_s",
    ):
        assert col in reader.fieldnames
    assert len(rows) == 6 and {r["n_validation"] for r in rows} == {"50"}
    assert float(rows[0]["progress_m"]) == pytest.approx(90.0)
    files = sorted((tmp_path / "scenes").glob("*.json"))
    assert len(files) == 6
    mtimes = {f: f.stat().st_mtime_ns for f in files}
    # rerun: nothing recomputed, files untouched
    res2 = synthetic.run_synthetic(tmp_path, **kw)
    assert res2["computed"] == 0 and res2["reused"] == 6 and len(fake_planner) == 6
    assert {f: f.stat().st_mtime_ns for f in files} == mtimes
    # a lost file is recomputed alone; a larger sweep adds only the new scenes
    files[0].unlink()
    res3 = synthetic.run_synthetic(tmp_path, **{**kw, "scenes": 4})
    assert res3["computed"] == 3 and len(fake_planner) == 9
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["summary"]["methods"]["mmd"]["scenes"] == 4


def test_sweep_refuses_to_mix_settings(tmp_path, fake_planner):
    params = SceneParams(n_samples=20, n_validation=50)
    synthetic.run_synthetic(tmp_path, scenes=1, params=params, methods=["mmd"], progress=False)
    with pytest.raises(ValueError, match="different settings.*seed"):
        synthetic.run_synthetic(
            tmp_path, scenes=1, seed=1, params=params, methods=["mmd"], progress=False
        )
    with pytest.raises(ValueError, match="different settings.*params"):
        synthetic.run_synthetic(
            tmp_path,
            scenes=1,
            params=params.replace(n_validation=60),
            methods=["mmd"],
            progress=False,
        )


# ``run_timing`` and ``run_obstacle_timing`` (their contract columns, Algorithm 1 inside plan(),
# one row per obstacle count, the figure) run through ``mmdopt bench timing`` in test_timing.py
