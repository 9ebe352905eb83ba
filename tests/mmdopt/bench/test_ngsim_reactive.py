"""CommonRoad's reactive planner as the ``reactive`` peer of ``bench ngsim``, on a shared
Lankershim Boulevard scene: it plans the task MMD-Opt plans (same start, path, bounds, futures),
its plan clears the futures it was given and passes CommonRoad's own checkers, and when every
trajectory is blocked it says so and brakes (skipped with a reason where ../shared/data or the
planner is absent)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip(
    "commonroad", reason="the ngsim benchmark needs commonroad-io (mmdopt[commonroad])"
)
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

FILE = "USA_Lanker-2_1_T-1.xml"


@pytest.fixture(scope="module")
def inputs(shared_data):
    from mmdopt.bench.ngsim.reactive import available
    from mmdopt.bench.ngsim.runner import NgsimParams, plan_inputs, select_tasks

    if available() is not None:
        pytest.skip(available())
    f = shared_data / "ngsim_urban" / FILE
    if not f.is_file():
        pytest.skip(f"Lankershim scenes not found in {f.parent}")
    p = NgsimParams(n_samples=20, n_validation=50, forecast=False)
    task = select_tasks([str(f)], p)[0]
    return task, p, plan_inputs(task, p, _cfg(), "cv")


def _cfg():
    from mmdopt.bench.ngsim.runner import ngsim_config

    return ngsim_config()


def _args(task, inp, futures=None):
    b = inp.task
    sc, v, k, obs = b["scene"], b["v"], b["k"], b["obs"]
    f = np.asarray(inp.planned)[: len(obs), :5] if futures is None else futures
    n = f.shape[0]
    obs = np.resize(obs, n)
    return (
        task["scenario"], b["road"], b["ego"],
        (sc.xy[v, k, 0], sc.xy[v, k, 1], sc.heading[v, k], sc.speed[v, k]),
        (sc.length[v], sc.width[v]), b["times"], f,
        np.stack([sc.length[obs], sc.width[obs]], -1), sc.heading[obs, k], 12.0,
    )  # fmt: skip


def test_the_peer_plans_the_task_clear_of_its_futures_and_feasible(inputs):
    from mmdopt.bench.ngsim import crcheck
    from mmdopt.bench.ngsim.metric import rect_corners, rects_overlap
    from mmdopt.bench.ngsim.reactive import plan_reactive

    task, _, inp = inputs
    b = inp.task
    sc, v, k = b["scene"], b["v"], b["k"]
    args = _args(task, inp)
    plan = plan_reactive(*args)
    assert plan.status_text == "ok" and plan.feasible and not plan.fallback
    assert plan.x.shape == plan.t.shape == b["times"].shape
    # it starts where the recorded car is (the planner's rear-axle state shifted back)
    assert np.hypot(plan.x[0] - sc.xy[v, k, 0], plan.y[0] - sc.xy[v, k, 1]) < 0.05
    assert plan.progress > 0 and np.all(np.isfinite(plan.d))
    # within the task's lateral bounds (the planner samples its end offsets there)
    assert np.all(plan.d <= b["road"].y_ub + 0.5) and np.all(plan.d >= b["road"].y_lb - 0.5)
    # its footprint clears every future it was given, at every step
    futures = args[6]
    ego = rect_corners(plan.x, plan.y, plan.heading, sc.length[v], sc.width[v])
    for i in range(futures.shape[0]):
        for j in range(futures.shape[1]):
            pts = futures[i, j]
            h = np.arctan2(*np.gradient(pts, axis=0).T[::-1])
            o = rect_corners(pts[:, 0], pts[:, 1], h, args[7][i, 0], args[7][i, 1])
            assert not np.any(rects_overlap(ego, o)), (i, j)
    # CommonRoad's own verdicts on it
    cr = crcheck.check_plan(plan, task["scenario"], task["ego_id"], k, sc.length[v], sc.width[v])
    assert cr["cr_road_compliant"] and cr["cr_feasible"]


def test_a_blocked_road_is_reported_and_the_peer_brakes(inputs):
    """Standing cars across the whole road 6 m ahead: no sample is collision-free; the plan is
    a braking fallback whose status says so, never a silent ``ok``."""
    from mmdopt.bench.ngsim.reactive import FALLBACK_DECEL, plan_reactive

    task, _, inp = inputs
    b = inp.task
    ego, path, K = b["ego"], b["road"].path, len(b["times"])
    d = np.arange(-6.0, 6.5, 1.5)
    x, y = (np.asarray(a) for a in path.to_cartesian(ego.s + 6.0 + 0 * d, d))
    wall = np.broadcast_to(np.stack([x, y], -1)[:, None, None, :], (len(d), 1, K, 2)).copy()
    plan = plan_reactive(*_args(task, inp, futures=wall))
    assert plan.fallback and not plan.feasible
    assert plan.status_text.startswith("fallback: ")
    # braking along the path: speed falls at FALLBACK_DECEL, never below 0
    dv = np.diff(plan.speed)
    assert np.all(dv <= 1e-9) and np.min(plan.speed) >= 0.0
    assert dv[0] == pytest.approx(-FALLBACK_DECEL * (b["times"][1] - b["times"][0]))


def test_bad_inputs_name_the_argument(inputs):
    from mmdopt.bench.ngsim.reactive import plan_reactive

    task, _, inp = inputs
    args = list(_args(task, inp))
    bad = list(args)
    bad[6] = args[6][..., :1]
    with pytest.raises(ValueError, match="futures"):
        plan_reactive(*bad)
    bad = list(args)
    bad[9] = float("nan")
    with pytest.raises(ValueError, match="v_des"):
        plan_reactive(*bad)


def test_run_task_scores_the_peer_like_a_method(inputs):
    """``run_task(..., ["reactive"])``: a results row with the at-fault verdict against the
    recorded futures, progress, plan time and CommonRoad's verdicts (no JAX program compiled)."""
    from mmdopt.bench.ngsim.runner import RESULT_COLUMNS, run_task

    task, p, _ = inputs
    (row,) = run_task(task, ["reactive"], "cv", p, _cfg())
    assert row["method"] == "reactive" and row["status"] == "ok"
    assert set(row) <= set(RESULT_COLUMNS)
    assert row["at_fault_collision"] is False and row["progress_m"] > 0
    assert row["plan_time_s"] > 0 and row["cr_feasible"] is True


def test_cli_names_refused_files_records_the_split_and_the_predictors_training(
    shared_data, tmp_path, capsys
):
    """``bench ngsim --holdout`` on a 5.6 s scene and a 9.1 s one: the short one is refused with
    its reason (printed and in refused.json), the split is in run.json, and the scenes the
    learned predictor was trained on are named (trained_on.json, printed); a pattern that
    matches no file is exit 2 naming --holdout."""
    import json

    from mmdopt.bench.cli import main
    from mmdopt.bench.ngsim.reactive import available

    if available() is not None:
        pytest.skip(available())
    d = shared_data / "ngsim_urban"
    short, long_ = d / "USA_Lanker-1_2_T-1.xml", d / FILE
    if not (short.is_file() and long_.is_file()):
        pytest.skip(f"Lankershim scenes not found in {d}")
    out = tmp_path / "run"
    argv = ["bench", "ngsim", "--scenarios", str(short), str(long_), "--methods", "reactive"]
    held = [*argv, "--max-tasks", "1", "--out", str(out), "--holdout", "USA_Lanker-*"]
    assert main(held) == 0
    text = capsys.readouterr().out
    assert "refused USA_Lanker-1_2_T-1.xml: " in text and "too short" in text
    refused = json.loads((out / "refused.json").read_text())
    assert list(refused) == ["USA_Lanker-1_2_T-1.xml"]
    assert json.loads((out / "trained_on.json").read_text()) == [short.name, FILE]
    assert "trained on 2 of these scenes" in text
    split = json.loads((out / "run.json").read_text())["split"]
    assert split["heldout_files"] == [short.name, FILE] and split["train_files"] == []
    assert split["holdout"] == ["USA_Lanker-*"]
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main([*argv, "--out", str(tmp_path / "x"), "--holdout", "nothing*"])
    assert e.value.code == 2 and "--holdout" in capsys.readouterr().err


def test_junction_figure_is_written(shared_data, tmp_path):
    """The task figure (route, futures coloured by route, plans) of a turning Lankershim ego,
    with the peer's plan: a readable PNG."""
    import matplotlib.image as mpimg

    from mmdopt.bench.ngsim.plot import ngsim_scene_figure
    from mmdopt.bench.ngsim.reactive import available

    if available() is not None:
        pytest.skip(available())
    f = shared_data / "ngsim_urban" / "USA_Lanker-2_2_T-1.xml"
    if not f.is_file():
        pytest.skip(f"{f} not found")
    task = dict(scenario=str(f), ego_id=230, k=10, t0=1.0)
    out = ngsim_scene_figure(task, tmp_path / "junction.png", methods=("reactive",), n_draw=5)
    img = mpimg.imread(out)
    assert img.ndim == 3 and img.shape[0] > 500 and img.std() > 0.05
