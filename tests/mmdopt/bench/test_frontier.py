"""``mmdopt bench frontier``: risk grids, interpolation, the CSV contract and resuming."""

from __future__ import annotations

import csv
import json
import math

import pytest

from mmdopt.bench import cli
from mmdopt.bench.frontier import (
    DEFAULT_RISK_GRID,
    clopper_pearson_interval,
    frontier_axes,
    frontier_points,
    interpolate_progress,
    parse_risks,
    progress_at_level,
)

#: the tiny planner of the CLI tests (nested sections of ``MMDOptConfig``)
TINY = {"cem": {"n_samples": 60, "n_cem": 30, "n_elite": 10, "iterations": 3, "n_brake": 2},
        "selection": {"reduced_set_size": 5}}  # fmt: skip
CONTRACT = ("method", "risk", "scene", "collision_free", "n_validation", "progress_m",
            "plan_time_s", "feasible")  # fmt: skip


def test_parse_risks_defaults_overrides_and_errors():
    k = parse_risks(None, ["mmd", "saa"])
    assert k == {"mmd": list(DEFAULT_RISK_GRID), "saa": list(DEFAULT_RISK_GRID)}
    k = parse_risks("mmd=0.02,0.001; saa=0.05", ["mmd", "saa"])
    assert k == {"mmd": [0.001, 0.02], "saa": [0.05]}
    assert parse_risks("0.1,0.02,0.005", ["mmd", "saa"]) == {
        "mmd": [0.005, 0.02, 0.1],
        "saa": [0.005, 0.02, 0.1],
    }
    for bad, word in (("mmd=0.7", "risk"), ("foo=0.1", "unknown"), ("mmd", "METHOD="),
                      ("degroot=0.1", "not among"), ("mmd=x", "not a number"),
                      ("0.1;mmd=0.2", "METHOD=")):  # fmt: skip
        with pytest.raises(ValueError, match=word):
            parse_risks(bad, ["mmd", "saa"])


def _row(m, k, scene, cf, prog):
    return dict(method=m, risk=k, scene=scene, collision_free=cf, n_validation=1000,
                progress_m=prog, plan_time_s=0.1, feasible=True)  # fmt: skip


def test_interpolated_progress_on_the_frontier():
    rows = [_row("a", 0.001, s, 999, 60.0) for s in range(2)]
    rows += [_row("a", 0.01, 0, 990, 80.0), _row("a", 0.01, 1, 994, 80.0)]  # mean 992
    rows += [_row("a", 0.1, s, 980, 100.0) for s in range(2)]
    pts = frontier_points(rows)
    assert [p["risk"] for p in pts] == [0.001, 0.01, 0.1]
    assert pts[1]["mean"] == 992.0 and pts[1]["q1"] == 991.0 and pts[1]["min"] == 990.0
    got = interpolate_progress(pts, "a", (990.0, 995.0, 999.0, 999.5))
    assert got["990"] == pytest.approx(80.0 + 20.0 * 2.0 / 12.0)  # between 980 and 992
    assert got["995"] == pytest.approx(60.0 + 20.0 * 4.0 / 7.0)  # between 992 and 999
    assert got["999"] == pytest.approx(60.0)
    assert math.isnan(got["999.5"])  # not reached by any risk level
    # the measured points only: the most progress of a risk level that reaches the level
    at = progress_at_level(pts, "a", (990.0, 995.0, 999.0, 999.5))
    assert at["990"] == 80.0 and at["995"] == 60.0 and at["999"] == 60.0
    assert math.isnan(at["999.5"])


def test_progress_at_level_over_the_levels_that_kept_their_request():
    """A risk level counts in ``at_level_kept`` only where at least 95 % of its plans say ok:
    a method that reaches 999 with plans breaking their own bound is not credited there."""
    ok = "ok"
    rows = [dict(_row("a", 0.001, s, 999, 60.0), status=ok) for s in range(20)]
    # the looser level reaches 999 as well, with more progress, but one plan in 20 (5 %) and
    # then two in 20 (10 %) exceed their bound
    loose = [dict(_row("a", 0.01, s, 999, 80.0), status=ok) for s in range(20)]
    loose[0]["status"] = "risk exceeded: asked 0.01"
    pts = frontier_points(rows + loose)
    assert progress_at_level(pts, "a", (999.0,), min_ok_share=0.95)["999"] == 80.0
    loose[1]["status"] = "risk exceeded: asked 0.01"
    pts = frontier_points(rows + loose)
    assert progress_at_level(pts, "a", (999.0,))["999"] == 80.0
    assert progress_at_level(pts, "a", (999.0,), min_ok_share=0.95)["999"] == 60.0
    # rows without a status (the time-linear margins) never count as kept
    assert math.isnan(
        progress_at_level(
            frontier_points([_row("a", 0.001, 0, 999, 60.0)]), "a", (999.0,), min_ok_share=0.5
        )["999"]
    )
    with pytest.raises(ValueError, match="min_ok_share"):
        progress_at_level(pts, "a", (999.0,), min_ok_share=1.5)


@pytest.mark.slow
def test_frontier_cli_contract_and_resume(tmp_path, capsys):
    small = tmp_path / "scene.json"
    small.write_text(json.dumps({"n_validation": 200, "n_samples": 40}))
    tiny = tmp_path / "cfg.json"
    # the option test's tiny planner: its worker programs are compiled once for both tests
    tiny.write_text(json.dumps(TINY))
    out = tmp_path / "f"
    argv = ["bench", "frontier", "--scenes", "1", "--seed", "3", "--out", str(out),
            "--methods", "mmd", "--risks", "mmd=0.002,0.1", "--jobs", "1", "--n-samples", "40",
            "--scene-params", str(small), "--config", str(tiny), "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    text = capsys.readouterr().out
    assert "2 plans computed, 0 reused" in text and "progress_m@995" in text
    with open(out / "frontier.csv") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
    assert reader.fieldnames[: len(CONTRACT)] == list(CONTRACT)
    assert sorted((r["method"], float(r["risk"])) for r in rows) == [("mmd", 0.002), ("mmd", 0.1)]
    assert all(0 <= int(r["collision_free"]) <= int(r["n_validation"]) == 200 for r in rows)
    assert (out / "frontier.png").stat().st_size > 0
    summary = json.loads((out / "frontier_summary.json").read_text())
    assert set(summary["interpolated"]) == {"mmd"}
    assert cli.main(argv) == 0
    assert "0 plans computed, 2 reused" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        cli.main(argv[:-2] + ["--risks", "mmd=0.9", "--no-progress"])
    assert e.value.code == 2 and "--risks" in capsys.readouterr().err

    # a folder written when the column was called "knob" resumes with it renamed
    for task in (out / "tasks").glob("*.json"):
        row = json.loads(task.read_text())
        task.write_text(json.dumps({("knob" if k == "risk" else k): v for k, v in row.items()}))
    # the old option name still works, with a one-line warning naming the new one
    old = [a if a != "--risks" else "--knobs" for a in argv]
    assert cli.main(old) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["mmdopt: --knobs is deprecated; use --risks (same values)"]
    with open(out / "frontier.csv") as f:
        reader = csv.DictReader(f)
        assert reader.fieldnames[: len(CONTRACT)] == list(CONTRACT)
        assert sorted(float(r["risk"]) for r in reader) == [0.002, 0.1]


def test_load_results_reads_an_older_frontier_csv_with_knob_as_risk(tmp_path):
    pytest.importorskip("pandas")
    from mmdopt.bench import load_results

    (tmp_path / "frontier.csv").write_text("method,knob,scene\nmmd,0.005,0\n")
    df = load_results(tmp_path)
    assert list(df.columns) == ["method", "risk", "scene"] and df["risk"][0] == 0.005


def test_clopper_pearson_interval_and_pooled_rate():
    lo, hi = clopper_pearson_interval(0, 1000)
    assert lo == 0.0 and hi == pytest.approx(1 - 0.025 ** (1 / 1000))
    lo, hi = clopper_pearson_interval(1000, 1000)
    assert hi == 1.0 and lo == pytest.approx(0.025 ** (1 / 1000))
    lo, hi = clopper_pearson_interval(7, 400)
    assert lo < 7 / 400 < hi
    for k, n, word in ((-1, 10, "k"), (11, 10, "k"), (0, 0, "n"), (1.5, 10, "k")):
        with pytest.raises(ValueError, match=word):
            clopper_pearson_interval(k, n)
    with pytest.raises(ValueError, match="confidence"):
        clopper_pearson_interval(1, 10, confidence=1.0)
    # pooled over scenes: 3 + 0 collisions of 2 x 200 futures
    rows = [dict(_row("a", 0.01, 0, 197, 50.0), n_validation=200, status="ok", risk_bound=0.02),
            dict(_row("a", 0.01, 1, 200, 50.0), n_validation=200, status="risk floor: too few",
                 risk_bound=0.04)]  # fmt: skip
    (p,) = frontier_points(rows)
    assert (p["collisions"], p["validation"], p["rate"]) == (3, 400, 3 / 400)
    assert p["rate_lo"] < p["rate"] < p["rate_hi"]
    assert (p["rate_lo"], p["rate_hi"]) == clopper_pearson_interval(3, 400)
    assert p["ok_share"] == 0.5 and p["risk_bound"] == pytest.approx(0.03)
    # rows of an older folder without status / risk_bound
    (q,) = frontier_points([_row("a", 0.01, 0, 1000, 50.0)])
    assert q["rate"] == 0.0 and math.isnan(q["ok_share"]) and math.isnan(q["risk_bound"])


def test_frontier_figure_has_a_log_frontier_and_a_calibration_panel():
    pytest.importorskip("matplotlib")
    rows = []
    for m, scale in (("mmd", 1.0), ("saa", 3.0)):
        for k in (0.001, 0.02, 0.1):
            for s in range(2):
                c = 0 if k == 0.001 else int(1000 * k * scale) + s
                rows.append(_row(m, k, s, 1000 - c, 40.0 + 100 * k + scale))
    fig = frontier_axes(frontier_points(rows), "test")
    try:
        front, cal, budget = fig.axes
        assert front.get_yscale() == "log" and front.get_xscale() == "linear"
        assert cal.get_xscale() == "log" and cal.get_yscale() == "log"
        assert "collisions per 1000" in front.get_ylabel() and "0 drawn at" in front.get_ylabel()
        # a zero (k = 0.001 plans meet no future) is drawn at the floor, above 0
        lo = min(min(line.get_ydata()) for line in front.lines)
        assert 0 < lo <= 0.01
        assert any(line.get_label() == "measured = requested" for line in cal.lines)
        # ε is named in the title, not at every point
        assert len(front.texts) == 0 and "0.001 … 0.1" in front.get_title()
        # matched compute: progress at 995 / 999 within a plan-time budget, log time axis
        assert budget.get_xscale() == "log" and "within a budget" in budget.get_title()
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


@pytest.mark.slow
def test_frontier_cli_sample_options_reach_the_scenes_and_the_manifest(tmp_path, capsys):
    tiny = tmp_path / "cfg.json"
    tiny.write_text(json.dumps(TINY))
    out = tmp_path / "f"
    argv = ["bench", "frontier", "--scenes", "2", "--seed", "1", "--out", str(out),
            "--methods", "mmd", "--risks", "0.05", "--jobs", "1", "--config", str(tiny),
            "--no-progress"]  # fmt: skip
    for opt in ("--n-validation", "--n-samples"):
        for bad in ("0", "-3", "x", "2.5"):
            with pytest.raises(SystemExit) as e:
                cli.main([*argv, opt, bad])
            assert e.value.code == 2 and f"argument {opt}" in capsys.readouterr().err
    assert not out.exists()

    # the options override --scene-params' keys
    small = tmp_path / "scene.json"
    small.write_text(json.dumps({"n_validation": 500, "n_samples": 80}))
    run = [*argv, "--scene-params", str(small), "--n-validation", "200", "--n-samples", "40"]
    assert cli.main(run) == 0
    text = capsys.readouterr().out
    assert "2 plans computed" in text and "rate_hi" in text and "ok_share" in text
    with open(out / "frontier.csv") as f:
        rows = list(csv.DictReader(f))
    assert [(int(r["n_validation"]), int(r["n_samples"])) for r in rows] == [(200, 40)] * 2
    assert all(r["status"] for r in rows) and all(r["risk_bound"] for r in rows)
    manifest = json.loads((out / "run.json").read_text())
    assert (manifest["n_validation"], manifest["n_samples"]) == (200, 40)

    # the summary's calibration: the interval contains the pooled rate
    (p,) = json.loads((out / "frontier_summary.json").read_text())["points"]
    k = sum(int(r["n_validation"]) - int(r["collision_free"]) for r in rows)
    assert (p["collisions"], p["validation"]) == (k, 400) and p["rate"] == k / 400
    assert p["rate_lo"] <= p["rate"] <= p["rate_hi"]
    oks = [r["status"].startswith("ok") for r in rows]
    assert p["ok_share"] == sum(oks) / 2
    assert p["risk_bound"] == pytest.approx(sum(float(r["risk_bound"]) for r in rows) / 2)

    # resuming with other values is refused (exit 2), naming the setting
    for opt, val, key in (("--n-validation", "300", "n_validation"),
                          ("--n-samples", "50", "n_samples")):  # fmt: skip
        i = run.index(opt)
        with pytest.raises(SystemExit) as e:
            cli.main([*run[: i + 1], val, *run[i + 2 :]])
        err = capsys.readouterr().err
        assert e.value.code == 2 and "different settings" in err and key in err
    assert cli.main(run) == 0
    assert "0 plans computed, 2 reused" in capsys.readouterr().out


def test_progress_within_a_budget_uses_only_the_risk_levels_that_fit_in_it():
    """Matched compute (``--budgets``): the most progress reaching a level among the risk
    levels whose median plan time is within the budget; NaN where none within it reaches it."""
    from mmdopt.bench.frontier import check_budget, progress_within_budget, summarise_frontier

    def rows(m, risk, cf, prog, t):
        return [dict(method=m, risk=risk, scene=s, collision_free=cf, n_validation=1000,
                     progress_m=prog, plan_time_s=t, feasible=True, status="ok",
                     risk_bound=risk) for s in range(2)]  # fmt: skip

    rs = rows("mmd", 0.001, 999, 80.0, 0.5) + rows("mmd", 0.02, 992, 95.0, 0.05)
    rs += rows("saa", 0.001, 999, 70.0, 0.2)
    summary = summarise_frontier(rs, ["mmd", "saa"], budgets=(0.1, 1.0))
    fast, slow = summary["at_budget"]["0.1"], summary["at_budget"]["1"]
    assert fast["mmd"]["990"] == 95.0 and math.isnan(fast["mmd"]["995"])
    assert slow["mmd"] == {"990": 95.0, "995": 80.0, "999": 80.0}
    assert math.isnan(fast["saa"]["990"]) and slow["saa"]["999"] == 70.0
    assert progress_within_budget(summary["points"], "mmd", 0.5)["999"] == 80.0
    with pytest.raises(ValueError, match="budget"):
        check_budget(0)
