"""A sweep and a frontier on an existing Ray cluster (``ray start``) give exactly the local
executor's rows.

A cluster's workers are started by ``ray start``, not by the driver: the one-thread environment of
the local pool reaches them through the driver's ``runtime_env`` (``executors._run_ray``)."""

from __future__ import annotations

import ast
import contextlib
import csv
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from mmdopt.bench import cli
from mmdopt.bench.scenes import SceneParams
from mmdopt.bench.synthetic import run_synthetic
from tests.mmdopt.bench.test_frontier import TINY
from tests.reliability.test_kill_resume import CONFIG as SWEEP_CONFIG

pytest.importorskip("ray", reason="the Ray executor needs Ray (pip install 'mmdopt[ray]')")

REPO = Path(__file__).resolve().parents[3]
#: columns that measure time, not results
TIMING = {"plan_time_s", "wall_s", "compile_s", "predict_time_s"}


def _free_ports(n: int) -> list[int]:
    socks = [socket.socket() for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


@contextlib.contextmanager
def ray_cluster(log: Path, cpus: int = 2):
    """A one-node cluster of ``ray start --head --block`` on free ports with its own temporary
    folder; yields its address ``127.0.0.1:PORT``.  Stopped by ending that ``ray start``
    process (it shuts down the processes it started) and then its process group: ``ray stop``
    would stop every Ray instance on the machine, other tests' included."""
    exe = Path(sys.executable).with_name("ray")
    if not exe.is_file():
        pytest.skip(f"no ray command next to {sys.executable}")
    gcs, client, agent = _free_ports(3)
    # short: Ray's socket paths under it must fit in 107 bytes
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")
    argv = [str(exe), "start", "--head", "--block", "--num-cpus", str(cpus), "--port", str(gcs),
            "--ray-client-server-port", str(client), "--dashboard-agent-listen-port", str(agent),
            "--include-dashboard=false", "--disable-usage-stats", "--temp-dir", temp]  # fmt: skip
    with open(log, "w") as f:
        proc = subprocess.Popen(argv, stdout=f, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while "block forever" not in log.read_text():
            if proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"ray start did not come up:\n{log.read_text()[-3000:]}")
            time.sleep(0.5)
        yield f"127.0.0.1:{gcs}"
    finally:
        proc.terminate()
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)  # anything of this cluster still running
        shutil.rmtree(temp, ignore_errors=True)


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path) as f:
        return [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(f)]


@pytest.mark.slow
def test_sweep_and_frontier_on_a_ray_cluster_equal_the_local_executor(tmp_path, capsys):
    """One ``ray start`` cluster (one start-up for both checks):

    - a 4-scene ``bench synthetic`` sweep with two Ray tasks at a time (``run_synthetic``,
      in-process driver) writes the local process pool's rows, row by row, and its folder
      resumes under the local executor with nothing recomputed;
    - 1 scene, 1 method, 1 risk of the tiny planner through the CLI in a subprocess, as a user
      runs it (``--executor ray --address 127.0.0.1:PORT``): the same ``frontier.csv`` rows.

    Timing columns apart.  The local runs go first: the cluster's workers then load their
    programs from the compilation cache."""
    sweep_cfg = cli.load_planner_config_from_dict(SWEEP_CONFIG)
    sweep = dict(scenes=4, seed=5, params=SceneParams(n_samples=20, n_validation=50),
                 methods=("mmd",), config=sweep_cfg, progress=False)  # fmt: skip
    run_synthetic(tmp_path / "sweep_local", executor="local", jobs=1, isolate=True, **sweep)
    small, tiny = tmp_path / "scene.json", tmp_path / "cfg.json"
    small.write_text(json.dumps({"n_validation": 200, "n_samples": 40}))
    tiny.write_text(json.dumps(TINY))  # test_frontier's planner: its programs are compiled once
    argv = ["bench", "frontier", "--scenes", "1", "--seed", "3", "--methods", "mmd",
            "--risks", "0.1", "--jobs", "1", "--n-samples", "40", "--scene-params", str(small),
            "--config", str(tiny), "--no-progress"]  # fmt: skip
    from mmdopt.bench.executors import _WORKER_ENV

    names, want = list(_WORKER_ENV), list(_WORKER_ENV.values())
    # first locally: the cluster's workers then load its programs from the compilation cache
    assert cli.main([*argv, "--out", str(tmp_path / "local")]) == 0
    capsys.readouterr()
    with ray_cluster(tmp_path / "ray_start.log") as address:
        # the cluster's workers plan with the local pool's one-thread environment
        code = (
            "import os; from mmdopt.bench.executors import run_tasks; "
            f"print(run_tasks(os.getenv, {names!r}, executor='ray', address={address!r}, "
            "progress=False))"
        )
        env = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             cwd=REPO, timeout=300)  # fmt: skip
        assert env.returncode == 0, env.stderr[-3000:]
        got = ast.literal_eval(env.stdout.strip().splitlines()[-1])
        assert sorted(x.split()[-1] for x in got) == sorted(v.split()[-1] for v in want)
        # the driver disconnects when the sweep ends; the cluster stays up for the CLI
        run_synthetic(tmp_path / "sweep_ray", executor="ray", address=address, jobs=2, **sweep)
        r = subprocess.run(
            [sys.executable, "-m", "mmdopt", *argv, "--out", str(tmp_path / "ray"),
             "--executor", "ray", "--address", address],
            capture_output=True, text=True, cwd=REPO, timeout=600,
        )  # fmt: skip
    a = _rows(tmp_path / "sweep_local" / "results.csv")
    b = _rows(tmp_path / "sweep_ray" / "results.csv")
    assert len(a) == len(b) == 4
    for x, y in zip(a, b, strict=True):
        assert x == y, {k: (x[k], y[k]) for k in x if x[k] != y.get(k)}
    # interchangeable caches: the Ray folder resumes under the local executor
    res = run_synthetic(tmp_path / "sweep_ray", executor="local", jobs=2, **sweep)
    assert res["computed"] == 0 and res["reused"] == 4
    assert json.loads((tmp_path / "sweep_ray" / "run.json").read_text())["seed"] == 5
    assert r.returncode == 0, r.stderr[-3000:]
    assert "1 plans computed" in r.stdout
    a, b = _rows(tmp_path / "local" / "frontier.csv"), _rows(tmp_path / "ray" / "frontier.csv")
    assert len(a) == len(b) == 1
    assert a == b, {k: (a[0][k], b[0].get(k)) for k in a[0] if a[0][k] != b[0].get(k)}
