"""The timing measurement shared by ``mmdopt bench timing`` and ``benchmarks/planner_timing.py``,
and the command itself: its tables, its figure and the time of Algorithm 1 inside ``plan()``."""

from __future__ import annotations

import csv

import pytest

from mmdopt.bench import cli, timing
from mmdopt.bench.scenes import demo_scene
from mmdopt.bench.timing import time_plan, time_reduced_set

from .test_figures import assert_readable


@pytest.mark.slow
def test_bench_timing_tables_figure_and_algorithm1_inside_plan(tmp_path, capsys, monkeypatch):
    """One small ``mmdopt bench timing`` run (one reduced-set size at 100 and 50 samples, and
    ``--obstacles 3``; the paper's Algorithm 1 compiles once per shape, so one run checks all):

    * ``time_plan`` (which the command calls per setting) reports first-call and median wall
      and CPU times, Algorithm 1 (the CEM alone) inside the whole ``plan()`` call;
    * ``timing.csv`` has the contract columns and Algorithm 1 inside ``plan()``;
    * ``timing.png`` is a readable figure (labels with units, legends);
    * ``--obstacles``: one row per obstacle count in ``timing_obstacles.csv``.
    """
    from matplotlib.figure import Figure

    timed, saved = [], {}
    orig_time_plan, orig_savefig = timing.time_plan, Figure.savefig

    def record_time_plan(*a, **k):
        timed.append(orig_time_plan(*a, **k))
        return timed[-1]

    def record_savefig(self, fname, *a, **k):
        saved[str(fname)] = self
        return orig_savefig(self, fname, *a, **k)

    monkeypatch.setattr(timing, "time_plan", record_time_plan)
    monkeypatch.setattr(Figure, "savefig", record_savefig)
    out = tmp_path / "t"
    argv = ["bench", "timing", "--out", str(out), "--sizes", "5", "--samples", "50",
            "--repeats", "1", "--obstacles", "3", "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    text = capsys.readouterr().out
    assert "timing.csv" in text and "timing_obstacles.csv" in text

    # time_plan: one call per (size, samples) setting
    assert len(timed) == 2
    for t in timed:
        assert 0 < t["algorithm1_s"] <= t["plan_s"]
        assert 0 < t["algorithm1_first_s"] <= t["plan_first_s"]
        assert t["plan_first_cpu_s"] > 0 and t["plan_cpu_s"] > 0
        assert t["plan"].x.ndim == 1

    # timing.csv: the contract columns, Algorithm 1 inside plan()
    with open(out / "timing.csv") as f:
        rows = list(csv.DictReader(f))
    assert set(timing.TIMING_COLUMNS) <= set(rows[0])
    assert [(int(r["reduced_set_size"]), int(r["n_samples"])) for r in rows] == [(5, 100), (5, 50)]
    for r in rows:
        assert r["backend"] == "admm-fixed"
        assert 0 < float(r["algorithm1_s"]) <= float(r["plan_s"])
        assert float(r["reduced_set_s"]) > 0 and float(r["compile_s"]) >= 0

    # timing.png: a readable figure
    png = out / "timing.png"
    assert png.is_file() and str(png) in saved, "timing.png was not written through savefig"
    assert_readable(saved[str(png)], "timing.png")

    # --obstacles 3: one row, with its columns; the demo car interacts
    with open(out / "timing_obstacles.csv") as f:
        obs = list(csv.DictReader(f))
    assert set(timing.OBSTACLE_TIMING_COLUMNS) <= set(obs[0])
    assert [int(r["obstacles"]) for r in obs] == [3]
    assert all(float(r["algorithm1_s"]) > 0 and int(r["interacting"]) >= 1 for r in obs)


def test_time_reduced_set_times_the_selection_and_checks_its_arguments():
    samples = demo_scene().obstacles[0]
    first, median = time_reduced_set(samples, 5, repeats=2)
    assert first > 0 and median > 0
    for kw, name in ((dict(m=0), "m"), (dict(m=5, repeats=0), "repeats")):
        with pytest.raises(ValueError, match=name):
            time_reduced_set(samples, **kw)
    with pytest.raises(ValueError, match="samples"):
        time_reduced_set(samples[0], 5)
    with pytest.raises(ValueError, match="repeats"):
        time_plan(demo_scene(), repeats=0)
