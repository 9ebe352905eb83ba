"""The Ray executor gives exactly the local executor's rows."""

from __future__ import annotations

import csv
import json

import pytest

from mmdopt.bench.cli import load_planner_config_from_dict
from mmdopt.bench.executors import run_tasks
from mmdopt.bench.scenes import SceneParams
from mmdopt.bench.synthetic import run_synthetic

ray = pytest.importorskip("ray", reason="the Ray executor needs Ray (pip install 'mmdopt[ray]')")

#: tiny planner and scenes: the test checks the executor, not the planner (one Algorithm 1
#: pass: no re-selection, which would compile a second program in every worker); the same as
#: tests/reliability/test_kill_resume.py's, so that the workers' programs compile once per run
#: (the persistent compilation cache of tests/conftest.py)
from tests.reliability.test_kill_resume import CONFIG as TINY  # noqa: E402

SCENE_PARAMS = {"n_samples": 20, "n_validation": 50}
#: columns that measure time, not results
TIMING = {"plan_time_s", "wall_s", "predict_time_s"}


def _rows(path):
    with open(path) as f:
        return [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(f)]


def _square(x):
    return x * x


def test_an_unknown_executor_is_refused_by_name():
    with pytest.raises(ValueError, match="executor"):
        run_tasks(_square, [1], executor="dask")


@pytest.mark.slow
def test_ray_sweep_equals_local_sweep(tmp_path):
    """A 4-scene sweep on a local Ray instance (2 CPUs) writes the same rows as the local process
    pool (same one-XLA-thread workers), row by row; and a Ray folder resumes locally.  The local
    pool has one worker (``isolate``): it compiles once, and the Ray workers that start after it
    load its programs from the compilation cache instead of compiling them side by side."""
    cfg = load_planner_config_from_dict(TINY)
    params = SceneParams(**SCENE_PARAMS)
    kw = dict(scenes=4, seed=5, params=params, methods=("mmd",), config=cfg, jobs=2)
    local = dict(kw, jobs=1, isolate=True)
    run_synthetic(tmp_path / "local", executor="local", progress=False, **local)
    run_synthetic(tmp_path / "ray", executor="ray", progress=False, **kw)
    a, b = _rows(tmp_path / "local" / "results.csv"), _rows(tmp_path / "ray" / "results.csv")
    assert len(a) == len(b) == 4
    for x, y in zip(a, b, strict=True):
        assert x == y, {k: (x[k], y[k]) for k in x if x[k] != y.get(k)}
    # interchangeable caches: the Ray folder resumes under the local executor, nothing recomputed
    res = run_synthetic(tmp_path / "ray", executor="local", progress=False, **kw)
    assert res["computed"] == 0 and res["reused"] == 4
    assert json.loads((tmp_path / "ray" / "run.json").read_text())["seed"] == 5
