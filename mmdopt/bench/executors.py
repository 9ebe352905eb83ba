"""Executors for sweeps: run independent tasks sequentially, on a local process pool, or on Ray.

Every runner (synthetic, reduced set, frontier, ngsim, highway, ...) cuts its sweep into tasks
(module-level functions of one picklable argument) that each write their own result file into the
sweep folder as soon as they finish, so a sweep is resumable whichever executor ran it: a task whose
file exists is skipped before submission (:func:`check_manifest` refuses a folder made with
other settings).

``executor="local"`` (default): ``jobs`` spawned worker processes (``concurrent.futures``), each
with one XLA thread (the workers, not XLA, use the cores); each worker compiles once and reuses its
jit caches for all its tasks.  ``executor="ray"``: the tasks as Ray remote functions
(``pip install mmdopt[ray]``), on a local Ray instance with ``jobs`` CPUs or on an existing
cluster at ``address`` (e.g. ``"ray://head:10001"`` or ``"auto"``).
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing as mp
import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from .results import write_json

__all__ = ["EXECUTORS", "run_tasks", "check_manifest"]

#: executor names accepted by :func:`run_tasks` and the CLI's ``--executor``
EXECUTORS = ("local", "ray")

_ONE_XLA_THREAD = "--xla_cpu_multi_thread_eigen=false"
#: the environment of every worker process (local pool and local Ray): one XLA / BLAS / OpenMP
#: thread each, so that both executors compute bit-identical numbers (Ray sets
#: OMP_NUM_THREADS=1 in its workers; multi-threaded BLAS sums in another order)
_WORKER_ENV = {
    "XLA_FLAGS": _ONE_XLA_THREAD,
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}


def check_manifest(out: str | Path, manifest: dict[str, Any], name: str = "run.json") -> None:
    """Write ``out/name`` on the first run; on a resumed run raise ``ValueError`` if the folder
    was made with other settings (the keys that differ are named)."""
    path = Path(out) / name
    if path.exists():
        try:
            old = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise ValueError(f"{path} is not valid JSON ({e}); delete it to start afresh") from None
        if not isinstance(old, dict):
            raise ValueError(f"{path} does not hold a JSON object; delete it to start afresh")
        diff = [k for k in manifest if old.get(k) != manifest[k]]
        if diff:
            raise ValueError(
                f"{out} holds results made with different settings ({', '.join(diff)}); "
                "use another --out folder (or delete it) to start a fresh sweep"
            )
    else:
        write_json(path, manifest)


def run_tasks(
    fn: Callable[[Any], Any],
    tasks: Sequence[Any],
    *,
    jobs: int = 1,
    executor: str = "local",
    address: str | None = None,
    progress: bool = True,
    desc: str = "tasks",
    unit: str = "task",
    first_note: str | None = None,
) -> list[Any]:
    """Run ``fn(task)`` for every task; returns the results in completion order.

    ``first_note`` (e.g. ``"compiling Algorithm 1 (first scene, ~30 s)…"``) is shown beside the
    progress bar until the first task finishes, so a first task that JIT-compiles does not look
    like a stuck bar.

    ``fn`` must be a module-level function (picklable); results should be small (the tasks write
    their own files).  Raises ``ValueError`` for an unknown executor or ``jobs < 1``.
    """
    from tqdm.auto import tqdm

    if executor not in EXECUTORS:
        raise ValueError(f"executor must be one of {EXECUTORS}, got {executor!r}")
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ValueError(f"jobs must be an integer >= 1, got {jobs!r}")
    tasks = list(tasks)
    bar = tqdm(total=len(tasks), desc=desc, unit=unit, disable=not progress or not tasks)
    if first_note and not bar.disable:
        bar.set_postfix_str(first_note)
    try:
        if executor == "ray":
            return list(_run_ray(fn, tasks, jobs, address, bar))
        if jobs <= 1 or len(tasks) <= 1:
            out = []
            for t in tasks:
                out.append(fn(t))
                _tick(bar)
            return out
        return list(_run_pool(fn, tasks, jobs, bar))
    finally:
        bar.close()


def _tick(bar) -> None:
    """One task done: advance the bar and clear the first-task note."""
    if getattr(bar, "postfix", None):  # a disabled bar has no postfix
        bar.set_postfix_str("", refresh=False)
    bar.update(1)


def _run_pool(fn, tasks, jobs, bar) -> Iterable[Any]:
    saved = {k: os.environ.get(k) for k in _WORKER_ENV}
    for k, v in _WORKER_ENV.items():
        old = saved[k]
        os.environ[k] = (old + " " + v) if (k == "XLA_FLAGS" and old) else v
    try:
        ctx = mp.get_context("spawn")
        with cf.ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=ctx) as ex:
            futs = [ex.submit(fn, t) for t in tasks]
            for f in cf.as_completed(futs):
                yield f.result()
                _tick(bar)
    finally:
        for k, old in saved.items():
            if old is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = old


def _code_root() -> str:
    """The folder holding the ``mmdopt``, ``frenet`` and ``solvers`` packages this process runs."""
    return str(Path(__file__).resolve().parents[2])


def _worker_env() -> dict[str, str]:
    """Environment of local Ray workers: :data:`_WORKER_ENV` (as the local pool's workers, so
    both executors compute the same numbers) and this process's code first on the path (an
    installed ``mmdopt`` elsewhere, e.g. an editable install of another checkout, must not win)."""
    path = [_code_root()] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    env = {**_WORKER_ENV, "PYTHONPATH": os.pathsep.join(path)}
    if os.environ.get("XLA_FLAGS"):
        env["XLA_FLAGS"] = os.environ["XLA_FLAGS"] + " " + _ONE_XLA_THREAD
    return env


def _run_ray(fn, tasks, jobs, address, bar) -> Iterable[Any]:
    try:
        import ray
    except ImportError:
        raise ValueError("executor 'ray' needs Ray: pip install 'mmdopt[ray]'") from None
    started = False
    if not ray.is_initialized():
        kw: dict[str, Any] = dict(ignore_reinit_error=True, log_to_driver=False)
        if address is None:
            kw.update(num_cpus=jobs, include_dashboard=False)
            kw["runtime_env"] = {"env_vars": _worker_env()}
        else:
            kw["address"] = address
        ray.init(**kw)
        started = True
    try:
        remote = ray.remote(num_cpus=1)(fn)
        pending = [remote.remote(t) for t in tasks]
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                yield ray.get(ref)
                _tick(bar)
    finally:
        if started and address is None:
            ray.shutdown()
