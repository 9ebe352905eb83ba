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
cluster at ``address`` (``"auto"``, ``"HOST:PORT"`` or ``"ray://HOST:PORT"``, e.g.
``"ray://head:10001"``); the workers of either get the one-thread environment of the local pool
(:data:`_WORKER_ENV`, through Ray's ``runtime_env``), so a cluster computes the same rows.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import json
import multiprocessing as mp
import os
import signal
import socket
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ._optional import progress_bar

__all__ = [
    "EXECUTORS",
    "ADDRESS_FORMS",
    "Interrupted",
    "parse_ray_address",
    "check_ray_address",
    "run_tasks",
    "check_manifest",
    "stop_on_signals",
    "worker_layout",
]

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


def check_manifest(
    out: str | Path,
    manifest: dict[str, Any],
    name: str = "run.json",
    aliases: dict[str, Sequence[Any]] | None = None,
) -> None:
    """Write ``out/name`` on the first run; on a resumed run raise ``ValueError`` if the folder
    was made with other settings (the keys that differ are named).  ``aliases`` lists, per key,
    older recorded values that mean the same as the current one (accepted).  A ``run.json`` that
    is not a JSON object (truncated, empty, another shape) is a ``ValueError`` naming the file."""
    path = Path(out) / name
    if path.exists():
        try:
            old = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise ValueError(
                f"{path} is corrupt (not valid JSON: {e}); delete it (or the folder) to start "
                "afresh"
            ) from None
        except OSError as e:
            raise ValueError(f"{path} cannot be read ({e})") from None
        if not isinstance(old, dict):
            raise ValueError(
                f"{path} is corrupt (holds a JSON {type(old).__name__}, not an object); delete "
                "it (or the folder) to start afresh"
            )
        aliases = aliases or {}
        diff = [
            k
            for k in manifest
            if old.get(k) != manifest[k] and old.get(k, MISSING) not in aliases.get(k, ())
        ]
        if diff:
            raise ValueError(
                f"{out} holds results made with different settings ({', '.join(diff)}); "
                "use another --out folder (or delete it) to start a fresh sweep"
            )
    else:
        from .results import write_json  # numpy: not needed to build the CLI's parser

        write_json(path, manifest)


#: stands for an absent key in ``check_manifest(aliases=...)``
MISSING = object()


class Interrupted(KeyboardInterrupt):
    """Raised in the main thread when SIGINT or SIGTERM arrives inside :func:`stop_on_signals`;
    ``signum`` is the signal and ``exit_status`` the shell convention ``128 + signum``."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = int(signum)
        self.name = signal.Signals(signum).name
        self.exit_status = 128 + self.signum


_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: while :func:`stop_on_signals` is active: the handler it installed (reinstalled after ray.init)
_ACTIVE_HANDLER: list[Callable] = []


def _handler(signum, frame):  # noqa: ARG001
    # the first signal stops the run; later ones are ignored while the workers are shut down
    for s in _STOP_SIGNALS:
        signal.signal(s, signal.SIG_IGN)
    raise Interrupted(signum)


@contextlib.contextmanager
def stop_on_signals():
    """Turn SIGINT and SIGTERM into :class:`Interrupted` in the main thread for the duration.

    :func:`run_tasks` reacts to it by cancelling every queued task and killing its workers (no
    worker survives to write into the sweep folder); finished result files stay.  A no-op outside
    the main thread.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.getsignal(s) for s in _STOP_SIGNALS}
    for s in _STOP_SIGNALS:
        signal.signal(s, _handler)
    _ACTIVE_HANDLER.append(_handler)
    try:
        yield
    finally:
        _ACTIVE_HANDLER.pop()
        for s, h in old.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)


def _reinstall_handlers() -> None:
    """Put :func:`stop_on_signals`' handler back (a library, e.g. Ray, may have replaced it)."""
    if _ACTIVE_HANDLER and threading.current_thread() is threading.main_thread():
        for s in _STOP_SIGNALS:
            signal.signal(s, _ACTIVE_HANDLER[-1])


def _worker_init() -> None:
    """Pool worker start-up: the parent decides when to stop (SIGINT ignored: a Ctrl-C reaches
    the whole process group), SIGTERM kills at once; then the signals blocked while the worker
    was spawned are let through."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)


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
    isolate: bool = False,
    first_note: str | None = None,
) -> list[Any]:
    """Run ``fn(task)`` for every task; returns the results in completion order.

    ``fn`` must be a module-level function (picklable); results should be small (the tasks write
    their own files).  ``isolate=True`` runs even ``jobs=1`` in one spawned worker process (one
    XLA thread, as every pool and Ray worker: the numbers do not depend on ``jobs``); with
    ``isolate=False`` and ``jobs=1`` the tasks run in this process (its XLA threading).

    ``first_note`` (e.g. ``"compiling Algorithm 1 (first scene, ~30 s)…"``) is shown beside the
    progress bar until the first task finishes, so a first task that JIT-compiles does not look
    like a stuck bar.

    Stopping: an exception in the caller's thread (KeyboardInterrupt, :class:`Interrupted` from
    :func:`stop_on_signals`, a task's error) cancels the queued tasks and terminates every
    worker before it propagates.  Raises ``ValueError`` for an unknown executor or ``jobs < 1``,
    and, naming ``--address``, for an ``address`` of another form than
    :func:`parse_ray_address`'s or where no Ray cluster can be reached.
    """
    if executor not in EXECUTORS:
        raise ValueError(f"executor must be one of {EXECUTORS}, got {executor!r}")
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ValueError(f"jobs must be an integer >= 1, got {jobs!r}")
    tasks = list(tasks)
    bar = progress_bar(total=len(tasks), desc=desc, unit=unit, progress=progress and bool(tasks))
    if first_note and not bar.disable:
        bar.set_postfix_str(first_note)
    try:
        if not tasks:
            return []
        if (jobs <= 1 or len(tasks) <= 1) and not isolate and executor != "ray":
            out = []
            for t in tasks:
                out.append(fn(t))
                _tick(bar)
            return out
        fn = WithMethods.wrap(fn)  # a worker knows the methods registered here
        if executor == "ray":
            return _run_ray(fn, tasks, jobs, address, bar)
        return _run_pool(fn, tasks, jobs, bar)
    finally:
        bar.close()


class WithMethods:
    """``fn`` that first registers, in the worker process it runs in, the planning methods the
    caller registered beyond the built-ins (:func:`mmdopt.methods.register`): a worker starts
    with the built-ins only.  Such a method's record must pickle (its ``risk_settings`` a
    module-level function)."""

    def __init__(self, fn: Callable[[Any], Any], methods: tuple) -> None:
        self.fn, self.methods = fn, methods

    @classmethod
    def wrap(cls, fn: Callable[[Any], Any]) -> Callable[[Any], Any]:
        import mmdopt.methods

        extra = tuple(
            r for r in mmdopt.methods.records() if r.name not in mmdopt.methods.PLAN_METHODS
        )
        return cls(fn, extra) if extra else fn

    def __call__(self, task: Any) -> Any:
        import mmdopt.methods

        for rec in self.methods:
            mmdopt.methods.register(rec, replace=True)
        return self.fn(task)


def _apply(fn: Callable[[Any], Any], task: Any) -> Any:
    """``fn(task)``: the remote function of a Ray run."""
    return fn(task)


def _tick(bar) -> None:
    """One task done: advance the bar and clear the first-task note."""
    if getattr(bar, "postfix", None):  # a disabled bar has no postfix
        bar.set_postfix_str("", refresh=False)
    bar.update(1)


def worker_layout(jobs: int, executor: str = "local", isolate: bool = False) -> str:
    """Where the tasks of :func:`run_tasks` compute, as recorded in a sweep's manifest: results
    computed ``"in-process"`` (this process's XLA threading) and in ``"workers"`` (one XLA
    thread each) may differ in the last bits, so a folder refuses a mix."""
    if executor == "local" and jobs <= 1 and not isolate:
        return "in-process"
    return "workers"


def _kill_pool(ex: cf.ProcessPoolExecutor) -> None:
    """Cancel the queued tasks and terminate every worker process of ``ex`` (then reap them)."""
    procs = list((getattr(ex, "_processes", None) or {}).values())
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()  # SIGTERM: default action in the workers, they die at once
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(5)
            if p.is_alive():
                p.kill()
                p.join(5)
    with contextlib.suppress(Exception):
        ex.shutdown(wait=False, cancel_futures=True)


def _run_pool(fn, tasks, jobs, bar) -> list[Any]:
    saved = {k: os.environ.get(k) for k in _WORKER_ENV}
    for k, v in _WORKER_ENV.items():
        old = saved[k]
        os.environ[k] = (old + " " + v) if (k == "XLA_FLAGS" and old) else v
    can_mask = threading.current_thread() is threading.main_thread()
    ex = None
    try:
        ctx = mp.get_context("spawn")
        ex = cf.ProcessPoolExecutor(
            max_workers=min(jobs, len(tasks)), mp_context=ctx, initializer=_worker_init
        )
        # workers are spawned during submit: with SIGINT/SIGTERM blocked, so that they inherit
        # the mask and cannot die of a signal half-started (they unblock in _worker_init);
        # a signal arriving meanwhile is delivered to this process right after
        old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS) if can_mask else None
        try:
            futs = [ex.submit(fn, t) for t in tasks]
        finally:
            if old_mask is not None:
                signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)
        out = []
        for f in cf.as_completed(futs):
            out.append(f.result())
            _tick(bar)
        ex.shutdown(wait=True)
        return out
    except BaseException:
        if ex is not None:
            _kill_pool(ex)
        raise
    finally:
        for k, old in saved.items():
            if old is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = old


def _code_root() -> str:
    """The folder holding the ``mmdopt``, ``frenet`` and ``solvers`` packages this process runs."""
    return str(Path(__file__).resolve().parents[2])


def _thread_env() -> dict[str, str]:
    """:data:`_WORKER_ENV` with this process's ``XLA_FLAGS`` kept in front: the environment the
    local pool's workers plan in (they inherit this process's flags), for Ray's workers."""
    env = dict(_WORKER_ENV)
    if os.environ.get("XLA_FLAGS"):
        env["XLA_FLAGS"] = os.environ["XLA_FLAGS"] + " " + _ONE_XLA_THREAD
    return env


def _worker_env() -> dict[str, str]:
    """Environment of local Ray workers: :func:`_thread_env` (as the local pool's workers, so
    both executors compute the same numbers) and this process's code first on the path (an
    installed ``mmdopt`` elsewhere, e.g. an editable install of another checkout, must not win)."""
    path = [_code_root()] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    return {**_thread_env(), "PYTHONPATH": os.pathsep.join(path)}


#: the forms of a Ray cluster's address that :func:`parse_ray_address` takes
ADDRESS_FORMS = "auto, ray://HOST:PORT or HOST:PORT"


def parse_ray_address(address: str) -> tuple[str, int] | None:
    """``(host, port)`` of a Ray cluster's address ``"HOST:PORT"`` (its GCS, as ``ray start
    --head`` prints it) or ``"ray://HOST:PORT"`` (its client server); ``None`` for ``"auto"``
    (the cluster Ray finds on this machine).  Raises ``ValueError`` with the reason for any
    other form, e.g. a host without a port, which Ray would otherwise retry for half a minute."""
    a = address.strip()
    if not a:
        raise ValueError("is empty (omit it to start a local Ray instance)")
    if a == "auto":
        return None
    rest = a.removeprefix("ray://")
    host, sep, port = rest.rpartition(":")
    if host.startswith("[") and host.endswith("]"):  # [::1]:6379
        host = host[1:-1]
    if not (sep and host and port.isdigit() and 0 < int(port) < 65536) or any(
        c in host for c in "/@ \t"
    ):
        raise ValueError(f"expected {ADDRESS_FORMS} (e.g. 127.0.0.1:6379), got {address!r}")
    return host, int(port)


def check_ray_address(address: str, timeout: float = 3.0) -> None:
    """``address`` has one of the forms of :func:`parse_ray_address` and, unless ``"auto"``,
    something accepts a TCP connection at its host and port within ``timeout`` seconds; raises
    ``ValueError`` with the reason otherwise (no cluster, a wrong port, an unknown host), in
    seconds rather than after Ray's own retries."""
    hp = parse_ray_address(address)
    if hp is None:
        return
    try:
        with socket.create_connection(hp, timeout=timeout):
            pass
    except OSError as e:
        why = e.strerror or str(e) or type(e).__name__
        raise ValueError(
            f"no Ray cluster answers at {address!r} ({why}); start one with `ray start --head` "
            "or check the host and port"
        ) from None


def _run_ray(fn, tasks, jobs, address, bar) -> list[Any]:
    try:
        import ray
    except ImportError:
        raise ValueError("executor 'ray' needs Ray: pip install 'mmdopt[ray]'") from None
    started = False
    pending: list[Any] = []
    try:
        if not ray.is_initialized():
            kw: dict[str, Any] = dict(ignore_reinit_error=True, log_to_driver=False)
            if address is None:
                kw.update(num_cpus=jobs, include_dashboard=False)
                kw["runtime_env"] = {"env_vars": _worker_env()}
            else:
                try:
                    check_ray_address(address)
                except ValueError as e:
                    raise ValueError(f"--address: {e}") from None
                # a cluster's workers were started by `ray start`, not by this process: they
                # get the local pool's one-thread environment here (not this process's path:
                # the cluster's machines have their own install)
                kw.update(address=address, runtime_env={"env_vars": _thread_env()})
            try:
                ray.init(**kw)
            except (ConnectionError, TimeoutError) as e:
                where = "a local Ray instance" if address is None else f"--address {address!r}"
                raise ValueError(f"cannot connect to {where}: {e}") from None
            started = True
            _reinstall_handlers()  # ray.init installs its own SIGTERM handler
        remote = ray.remote(num_cpus=1)(_apply)  # a function: fn may be a WithMethods
        pending = [remote.remote(fn, t) for t in tasks]
        out = []
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                out.append(ray.get(ref))
                _tick(bar)
        return out
    except BaseException:
        for ref in pending:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        raise
    finally:
        if started:  # a local instance stops; a cluster stays up, this process disconnects
            with contextlib.suppress(Exception):
                ray.shutdown()
