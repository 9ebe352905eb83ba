"""What the ``mmdopt`` command prints: its version, tables whose headers say their
units, no internal acceptance targets in the summary."""

from __future__ import annotations

import re

import pytest

import mmdopt
from mmdopt.bench import cli
from mmdopt.bench.results import summarize


def test_version_flag_prints_the_package_version(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["--version"])
    assert e.value.code == 0
    out = capsys.readouterr().out.strip()
    assert re.fullmatch(r"mmdopt \d+\.\d+\.\d+\S*", out), out
    assert out.split()[1] == cli.version()


def test_version_falls_back_to_the_module_attribute(monkeypatch):
    import importlib.metadata as md

    def missing(name):
        raise md.PackageNotFoundError(name)

    monkeypatch.setattr(md, "version", missing)
    assert cli.version() == mmdopt.__version__


def _rows():
    return [
        dict(
            scene=i,
            method=m,
            collision_free=990 - 5 * (m == "degroot") + i,
            n_validation=1000,
            progress_m=100.0,
            feasible=True,
            mean_speed=8.0,
            plan_time_s=0.4,
        )
        for i in range(4)
        for m in ("mmd", "degroot")
    ]


def test_summary_headers_have_units_and_no_acceptance_targets(capsys):
    cli._print_summary(summarize(_rows()), 1000)
    out = capsys.readouterr().out
    header = out.splitlines()[0]
    for h in ("collision-free (of 1000): mean", "progress (m)", "plan time (s)"):
        assert h in header
    assert "bars" not in out and "target" not in out and ">=" not in out.split("\n", 2)[2]


def test_progress_bar_says_the_first_task_is_compiling(capsys):
    from mmdopt.bench.executors import run_tasks

    note = "compiling Algorithm 1 (first scene of each worker, ~30 s)…"
    assert run_tasks(abs, [-1, -2], first_note=note, progress=True) == [1, 2]
    assert note in capsys.readouterr().err
    assert run_tasks(abs, [-3], first_note=note, progress=False) == [3]  # no bar, no note
