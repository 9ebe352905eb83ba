"""``mmdopt bench frontier``: knob grids, interpolation, the CSV contract and resuming."""

from __future__ import annotations

import csv
import json
import math

import pytest

from mmdopt.bench import cli
from mmdopt.bench.frontier import (
    DEFAULT_KNOBS,
    frontier_points,
    interpolate_progress,
    parse_knobs,
)

CONTRACT = ("method", "knob", "scene", "collision_free", "n_validation", "progress_m",
            "plan_time_s", "feasible")  # fmt: skip


def test_parse_knobs_defaults_overrides_and_errors():
    k = parse_knobs(None, ["mmd", "saa"])
    assert k == {"mmd": list(DEFAULT_KNOBS["mmd"]), "saa": list(DEFAULT_KNOBS["saa"])}
    k = parse_knobs("mmd=0.02,0.001; saa=0.05", ["mmd", "saa"])
    assert k == {"mmd": [0.001, 0.02], "saa": [0.05]}
    for bad, word in (("mmd=0.7", "risk|knob"), ("foo=0.1", "unknown"), ("mmd", "METHOD="),
                      ("degroot=0.1", "not among"), ("mmd=x", "knob|risk|number")):  # fmt: skip
        with pytest.raises(ValueError, match=word):
            parse_knobs(bad, ["mmd", "saa"])


def _row(m, k, scene, cf, prog):
    return dict(method=m, knob=k, scene=scene, collision_free=cf, n_validation=1000,
                progress_m=prog, plan_time_s=0.1, feasible=True)  # fmt: skip


def test_interpolated_progress_on_the_frontier():
    rows = [_row("a", 0.001, s, 999, 60.0) for s in range(2)]
    rows += [_row("a", 0.01, 0, 990, 80.0), _row("a", 0.01, 1, 994, 80.0)]  # mean 992
    rows += [_row("a", 0.1, s, 980, 100.0) for s in range(2)]
    pts = frontier_points(rows)
    assert [p["knob"] for p in pts] == [0.001, 0.01, 0.1]
    assert pts[1]["mean"] == 992.0 and pts[1]["q1"] == 991.0 and pts[1]["min"] == 990.0
    got = interpolate_progress(pts, "a", (990.0, 995.0, 999.0, 999.5))
    assert got["990"] == pytest.approx(80.0 + 20.0 * 2.0 / 12.0)  # between 980 and 992
    assert got["995"] == pytest.approx(60.0 + 20.0 * 4.0 / 7.0)  # between 992 and 999
    assert got["999"] == pytest.approx(60.0)
    assert math.isnan(got["999.5"])  # not reached by any knob


def test_frontier_cli_contract_and_resume(tmp_path, capsys):
    small = tmp_path / "scene.json"
    small.write_text(json.dumps({"n_validation": 200, "n_samples": 40}))
    tiny = tmp_path / "cfg.json"
    tiny.write_text(
        json.dumps({"n_samples": 60, "n_cem": 20, "n_elite": 8, "iterations": 3, "n_brake": 4})
    )
    out = tmp_path / "f"
    argv = ["bench", "frontier", "--scenes", "1", "--seed", "3", "--out", str(out),
            "--methods", "mmd", "--knobs", "mmd=0.002,0.1", "--jobs", "1",
            "--scene-params", str(small), "--config", str(tiny), "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    text = capsys.readouterr().out
    assert "2 plans computed, 0 reused" in text and "progress_m@995" in text
    with open(out / "frontier.csv") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
    assert reader.fieldnames[: len(CONTRACT)] == list(CONTRACT)
    assert sorted((r["method"], float(r["knob"])) for r in rows) == [("mmd", 0.002), ("mmd", 0.1)]
    assert all(0 <= int(r["collision_free"]) <= int(r["n_validation"]) == 200 for r in rows)
    assert (out / "frontier.png").stat().st_size > 0
    summary = json.loads((out / "frontier_summary.json").read_text())
    assert set(summary["interpolated"]) == {"mmd"}
    assert cli.main(argv) == 0
    assert "0 plans computed, 2 reused" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        cli.main(argv[:-2] + ["--knobs", "mmd=0.9", "--no-progress"])
    assert e.value.code == 2 and "--knobs" in capsys.readouterr().err
