"""The rows of a sweep do not depend on ``--jobs``: the CLI plans every task in a worker process
with one XLA thread (``--jobs 1`` included), so a sweep resumed with other ``--jobs`` never mixes
rows that differ in the last bits (Ray's executor against the local one:
``test_executors_ray``)."""

from __future__ import annotations

import csv
import json

import pytest

from mmdopt.bench import cli

from . import test_frontier

#: the tiny planner, on 40 fixed planning samples, of test_frontier's CLI tests: the workers'
#: programs are compiled once per run for the three tests (the persistent compilation cache of
#: tests/conftest.py)
TINY = test_frontier.TINY
#: columns that measure time, not results
TIMING = {"plan_time_s", "wall_s", "compile_s", "predict_time_s"}


def _rows(path):
    with open(path) as f:
        return [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(f)]


@pytest.mark.slow
def test_frontier_rows_are_bit_identical_across_jobs_and_executors(tmp_path, capsys):
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps(TINY))
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({"n_samples": 40, "n_validation": 200}))
    base = ["bench", "frontier", "--scenes", "2", "--methods", "mmd", "--risks", "0.05",
            "--n-samples", "40", "--config", str(cfg), "--scene-params", str(scene),
            "--no-progress"]  # fmt: skip
    # Ray's rows equal the local executor's: test_executors_ray (a sweep on both)
    runs = {"jobs1": ["--jobs", "1"], "jobs2": ["--jobs", "2"]}
    rows = {}
    for name, extra in runs.items():
        assert cli.main([*base, *extra, "--out", str(tmp_path / name)]) == 0
        rows[name] = _rows(tmp_path / name / "frontier.csv")
        assert json.loads((tmp_path / name / "run.json").read_text())["workers"] == "workers"
    capsys.readouterr()
    assert len(rows["jobs1"]) == 2
    for name, r in rows.items():
        assert r == rows["jobs1"], name  # every column, as written (repr of the floats)
    # one folder, resumed with other --jobs: nothing recomputed, nothing refused
    assert cli.main([*base, "--jobs", "2", "--out", str(tmp_path / "jobs1")]) == 0
    assert "0 plans computed, 2 reused" in capsys.readouterr().out
