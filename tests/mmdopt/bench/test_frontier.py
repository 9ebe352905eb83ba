"""``mmdopt bench frontier``: risk grids, interpolation, the CSV contract and resuming."""

from __future__ import annotations

import csv
import json
import math

import pytest

from mmdopt.bench import cli
from mmdopt.bench.frontier import (
    DEFAULT_RISKS,
    frontier_points,
    interpolate_progress,
    parse_risks,
)

CONTRACT = ("method", "risk", "scene", "collision_free", "n_validation", "progress_m",
            "plan_time_s", "feasible")  # fmt: skip


def test_parse_risks_defaults_overrides_and_errors():
    k = parse_risks(None, ["mmd", "saa"])
    assert k == {"mmd": list(DEFAULT_RISKS["mmd"]), "saa": list(DEFAULT_RISKS["saa"])}
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


def test_frontier_cli_contract_and_resume(tmp_path, capsys):
    small = tmp_path / "scene.json"
    small.write_text(json.dumps({"n_validation": 200, "n_samples": 40}))
    tiny = tmp_path / "cfg.json"
    tiny.write_text(
        json.dumps({"n_samples": 60, "n_cem": 20, "n_elite": 8, "iterations": 3, "n_brake": 4})
    )
    out = tmp_path / "f"
    argv = ["bench", "frontier", "--scenes", "1", "--seed", "3", "--out", str(out),
            "--methods", "mmd", "--risks", "mmd=0.002,0.1", "--jobs", "1",
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
