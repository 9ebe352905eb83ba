"""Sweeps that stop and recover cleanly.

A small ``bench synthetic`` sweep (tiny planner config, small scenes, MMD-Opt alone: one
compiled program) is interrupted with SIGTERM
or SIGINT as soon as its first result file exists, with ``--jobs 2`` and ``--jobs 1``: the CLI
exits 143 / 130 with one line on stderr, no worker process survives, no partial file is left,
and resuming (with the other ``--jobs``) gives exactly the rows of an uninterrupted run.  A
folder with damaged task files names each one, moves it aside and recomputes it.
"""

from __future__ import annotations

import csv
import glob
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mmdopt.bench.synthetic import _row_problem, load_task_file

REPO = Path(__file__).resolve().parents[2]
CONFIG = {
    "n_samples": 60,
    "n_cem": 20,
    "n_elite": 10,
    "iterations": 2,
    "n_brake": 5,
    "reduced_set_size": 5,
    "reduced_set": {"population": 20, "n_elite": 5, "iterations": 5},
    "reselect": 0,  # one Algorithm 1 pass: one compiled program per process
}
SCENE_PARAMS = {"n_samples": 20, "n_validation": 50}
SCENES = 6
TIMING = ("plan_time_s", "wall_s", "predict_time_s")


def _cmd(out: Path, files: Path, jobs: int) -> list[str]:
    return [
        sys.executable, "-m", "mmdopt", "bench", "synthetic",
        "--scenes", str(SCENES), "--jobs", str(jobs), "--methods", "mmd",
        "--config", str(files / "cfg.json"), "--scene-params", str(files / "sp.json"),
        "--n-samples", "20", "--out", str(out), "--no-progress",
    ]  # fmt: skip


def _env():
    return dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1")


def _run(out, files, jobs):
    r = subprocess.run(
        _cmd(out, files, jobs), capture_output=True, text=True, cwd=REPO, env=_env(), timeout=900
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert "Traceback" not in r.stderr
    return r


def _rows(out: Path) -> list[dict]:
    with open(out / "results.csv", newline="") as f:
        return [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(f)]


def _descendants(pid: int) -> list[int]:
    kids = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            stat = Path(f"/proc/{d}/stat").read_text()
        except OSError:
            continue
        if int(stat[stat.rindex(")") + 2 :].split()[1]) == pid:
            kids.append(int(d))
    return kids + [g for k in kids for g in _descendants(k)]


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2] not in "ZX"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("sweep_files")
    (d / "cfg.json").write_text(json.dumps(CONFIG))
    (d / "sp.json").write_text(json.dumps(SCENE_PARAMS))
    return d


@pytest.fixture(scope="module")
def reference(files, tmp_path_factory):
    """An uninterrupted run (``--jobs 1``: one worker compiles; the rows do not depend on
    ``--jobs``, which the resumes below, with either, check again)."""
    out = tmp_path_factory.mktemp("reference") / "out"
    _run(out, files, 1)
    return out


@pytest.mark.slow
@pytest.mark.parametrize(
    "jobs,sig,resume_jobs",
    [(2, signal.SIGTERM, 1), (1, signal.SIGINT, 2)],
    ids=["jobs2-SIGTERM-resume-jobs1", "jobs1-SIGINT-resume-jobs2"],
)
def test_signal_stops_cleanly_and_resume_equals_uninterrupted(
    files, reference, tmp_path, jobs, sig, resume_jobs
):
    out = tmp_path / "out"
    p = subprocess.Popen(
        _cmd(out, files, jobs),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        env=_env(),
    )
    t0 = time.monotonic()
    while not glob.glob(str(out / "scenes" / "*.json")):
        assert p.poll() is None, p.communicate()[1][-3000:]
        assert time.monotonic() - t0 < 600, "no result file after 600 s"
        time.sleep(0.05)
    kids = _descendants(p.pid)
    assert kids, "the sweep runs its tasks in worker processes"
    p.send_signal(sig)
    t_sig = time.monotonic()
    _, err = p.communicate(timeout=120)
    stop_s = time.monotonic() - t_sig
    assert p.returncode == 128 + sig, err[-3000:]
    lines = err.strip().splitlines()
    assert len(lines) == 1 and signal.Signals(sig).name in lines[0], err
    assert "Traceback" not in err
    assert stop_s < 60
    deadline = time.monotonic() + 10
    while any(_alive(k) for k in kids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [k for k in kids if _alive(k)], "worker processes survived the CLI"
    # no partial or temporary files; every finished file is complete
    left = sorted(os.listdir(out / "scenes"))
    assert left and all(f.endswith(".json") for f in left), left
    assert not [f for f in os.listdir(out) if ".tmp" in f]
    for f in left:
        json.loads((out / "scenes" / f).read_text())
    assert len(left) < SCENES  # it was interrupted, not finished
    # nothing is written after the CLI returned
    time.sleep(1.0)
    assert sorted(os.listdir(out / "scenes")) == left

    r = _run(out, files, resume_jobs)
    assert f"{len(left)} reused" in r.stdout
    assert _rows(out) == _rows(reference)


@pytest.mark.slow
def test_corrupt_task_files_are_named_moved_aside_and_recomputed(files, reference, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(reference, out)
    (out / "results.csv").unlink()
    sc = out / "scenes"
    damage = {
        "scene_0000__mmd.json": (sc / "scene_0000__mmd.json").read_text()[:40],  # truncated
        "scene_0001__mmd.json": "",  # empty
        "scene_0002__mmd.json": "{}",  # valid JSON, wrong shape
        "scene_0003__mmd.json": "[1, 2]",
        "scene_0004__mmd.json": (sc / "scene_0005__mmd.json").read_text(),  # other scene
    }
    for name, text in damage.items():
        (sc / name).write_text(text)
    r = _run(out, files, 1)
    warnings = [ln for ln in r.stderr.splitlines() if ln.startswith("warning:")]
    assert len(warnings) == len(damage), r.stderr
    for name in damage:
        assert sum(name in w for w in warnings) == 1
        assert (sc / (name + ".corrupt")).exists()
        assert (sc / name).exists()
    assert f"{len(damage)} plans computed" in r.stdout
    assert _rows(out) == _rows(reference)


# ---------------------------------------------------------------- fast: one task file at a time
GOOD = dict(
    scene=3, method="mmd", collision_free=40, n_validation=50, progress_m=90.0, feasible=True,
    plan_time_s=0.5,
)  # fmt: skip


@pytest.mark.parametrize(
    "text,reason",
    [
        ("", "is empty"),
        ('{"scene": 3, "meth', "not valid JSON"),
        ("\udcff", "not valid JSON"),
        ("{}", "has no 'scene'"),
        ("[]", "holds a JSON list"),
        ("null", "holds a JSON NoneType"),
        (json.dumps(dict(GOOD, scene=4)), "holds scene 4"),
        (json.dumps(dict(GOOD, method="saa")), "method 'saa'"),
        (json.dumps(dict(GOOD, collision_free="40")), "'collision_free' is '40'"),
        (json.dumps(dict(GOOD, collision_free=60)), "collision_free 60 outside"),
        (json.dumps(dict(GOOD, feasible=1)), "'feasible' is 1"),
        (json.dumps(dict(GOOD, scene=True)), "'scene' is True"),
        (json.dumps({k: v for k, v in GOOD.items() if k != "plan_time_s"}), "no 'plan_time_s'"),
    ],
    ids=lambda v: v[:20] if isinstance(v, str) else None,
)
def test_damaged_task_file_is_named_and_moved_aside(tmp_path, capsys, text, reason):
    path = tmp_path / "scene_0003__mmd.json"
    path.write_text(text, errors="surrogateescape")
    assert load_task_file(path, lambda r: _row_problem(r, 3, "mmd")) is None
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and reason in err, err
    assert not path.exists() and (tmp_path / "scene_0003__mmd.json.corrupt").exists()
    # a second damaged copy does not overwrite the first
    path.write_text("")
    load_task_file(path, lambda r: _row_problem(r, 3, "mmd"))
    assert (tmp_path / "scene_0003__mmd.json.corrupt1").exists()


def test_valid_task_file_is_kept(tmp_path, capsys):
    path = tmp_path / "scene_0003__mmd.json"
    path.write_text(json.dumps(dict(GOOD, plan_xy=[[0, 0]])))
    assert load_task_file(path, lambda r: _row_problem(r, 3, "mmd"))["collision_free"] == 40
    assert capsys.readouterr().err == "" and path.exists()
