"""The journal's receding-horizon runs: a synthetic scene family as a world the ego drives in."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import mmdopt
from mmdopt.bench import cli
from mmdopt.bench.loop import LOOP_COLUMNS, SceneLoop, run_episode
from mmdopt.bench.scenes import make_scene, preset

#: a small planner: the loop, not the planner, is under test
TINY = {"cem": {"n_samples": 40, "n_cem": 20, "n_elite": 8, "iterations": 2, "n_brake": 2},
        "selection": {"reduced_set_size": 5},
        "safety": {"risk_hits": 0, "reselect": 0}}  # fmt: skip


def _scene(name="cutin-high", obstacles=2, index=0):
    return make_scene(index, 3, preset(name).replace(num_obstacles=obstacles, n_samples=40))


def test_the_real_traffic_is_one_future_of_the_scene_and_predictions_start_from_it():
    sc = _scene()
    loop = SceneLoop(sc, duration_s=4.0)
    assert loop.truth.shape == (2, 100, 2)
    np.testing.assert_allclose(loop.truth[:, 0], np.stack([sc.layout.x0, sc.layout.y0], -1))
    # the real traffic ends in one of the two lanes, as every future of the family does
    assert np.all(np.min(np.abs(loop.truth[:, -1, 1, None] - [0.0, 3.5]), -1) < 0.05)
    loop.time = 3.0
    fc = loop.observe().obstacles
    xy = fc.predictor.sample(fc.history, fc.context, 200, __import__("jax").random.PRNGKey(0))
    assert xy.shape == (2, 200, 100, 2)
    # every prediction starts where the real traffic is at t = 3 s, moving as it moves
    now = np.stack([[np.interp(3.0, loop.t, loop.truth[o, :, i]) for i in (0, 1)] for o in (0, 1)])
    np.testing.assert_allclose(xy[:, :, 0], np.repeat(now[:, None], 200, 1), atol=1e-6)
    v_real = (np.interp(3.2, loop.t, loop.truth[0, :, 0]) - now[0, 0]) / 0.2
    v_pred = (xy[0, :, 1, 0] - xy[0, :, 0, 0]) / (loop.t[1] - loop.t[0])
    assert np.allclose(v_pred, v_real, atol=0.3)


def test_a_static_family_keeps_its_noise_around_the_nominal_start():
    sc = _scene("static-gaussian", 1)
    loop = SceneLoop(sc, duration_s=2.0)
    np.testing.assert_array_equal(loop.truth[0, 0], loop.truth[0, -1])  # it stands still
    loop.time = 1.5
    fc = loop.observe().obstacles
    xy = fc.predictor.sample(fc.history, fc.context, 4000, __import__("jax").random.PRNGKey(1))
    assert abs(np.mean(xy[0, :, 0, 0]) - sc.layout.x0[0]) < 0.1
    assert np.std(xy[0, :, 0, 0]) == pytest.approx(1.0, rel=0.1)


def test_an_episode_drives_reports_its_collisions_and_keeps_the_plan_times():
    cfg = mmdopt.MMDOptConfig.from_dict(TINY)
    row = run_episode(_scene(), "mmd", 0.05, config=cfg, dt=1.0, duration_s=3.0)
    assert set(row) == set(LOOP_COLUMNS)
    assert row["steps"] == 3 and row["obstacles"] == 2 and row["progress_m"] > 0
    assert row["crashed"] in (True, False) and 0 <= row["ok_share"] <= 1
    assert row["median_plan_s"] > 0 and row["compile_s"] >= 0
    # a car standing on the ego's path cannot be avoided: the episode reports the crash
    # (two obstacles, as above: the same compiled programs)
    sc = make_scene(0, 3, preset("static-gaussian").replace(
        num_obstacles=2, x0_choices=(6.0, 7.0), y0_choices=(0.0,), n_samples=40))  # fmt: skip
    crash = run_episode(sc, "mmd", 0.05, config=cfg, dt=1.0, duration_s=3.0)
    assert crash["crashed"] and crash["crash_time_s"] <= 2.0


def test_bench_receding_writes_its_table(tmp_path, capsys):
    (tmp_path / "tiny.json").write_text(json.dumps(TINY))
    rc = cli.main(["bench", "receding", "--preset", "cutin-low", "--obstacles", "2",
                   "--scenes", "2", "--methods", "mmd,cvar", "--risk", "0.05",
                   "--replan-dt", "1", "--duration", "2", "--config", str(tmp_path / "tiny.json"),
                   "--jobs", "1", "--no-progress", "--out", str(tmp_path / "r")])  # fmt: skip
    assert rc == 0
    out = capsys.readouterr().out
    assert "crashes" in out and "median_plan_s" in out
    with open(tmp_path / "r" / "receding.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4 and {r["method"] for r in rows} == {"mmd", "cvar"}
    assert all(r["preset"] == "cutin-low" and r["obstacles"] == "2" for r in rows)
    with pytest.raises(SystemExit) as e:
        cli.main(["bench", "receding", "--obstacles", "7", "--out", str(tmp_path / "x")])
    assert e.value.code == 2
