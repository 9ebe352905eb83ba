"""Computation time (paper Table II): reduced-set selection, Algorithm 1 and the plan() call."""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

import mmdopt
from mmdopt.algorithm import PLANNER_BACKEND
from mmdopt.reduced_set import ReducedSetConfig, select_reduced_set

from . import plots
from ._optional import progress_bar
from .results import write_results
from .scenes import Scene, demo_scene, make_scene
from .synthetic import scene_config

__all__ = [
    "TIMING_COLUMNS",
    "OBSTACLE_TIMING_COLUMNS",
    "run_timing",
    "run_obstacle_timing",
    "traffic_scene",
    "time_reduced_set",
    "time_plan",
]


def _cpu() -> float:
    """CPU time (s) of this process, user + system."""
    t = os.times()
    return t.user + t.system


def _check_repeats(repeats: int) -> None:
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        raise ValueError(f"repeats must be an integer >= 1, got {repeats!r}")


def _time_calls(fn, key, repeats: int) -> tuple[float, float]:
    """``(first call, median of repeats)`` wall time (s) of ``fn(key)`` (a fresh key each call)."""
    t0 = time.perf_counter()
    np.asarray(fn(key))
    first = time.perf_counter() - t0
    ts = []
    for r in range(repeats):
        k = jax.random.fold_in(key, r + 1)
        t0 = time.perf_counter()
        np.asarray(fn(k))
        ts.append(time.perf_counter() - t0)
    return first, float(np.median(ts))


def time_reduced_set(
    samples: Any, m: int, *, repeats: int = 5, key: Any = None, config=None
) -> tuple[float, float]:
    """``(first call, median of repeats)`` wall time (s) of MMD reduced-set selection
    (paper eq. (red_set_opt_proposed)) of ``m`` of one obstacle's ``samples`` (n, K, 2); the
    first call includes the jit compile.  ``config``: a ``ReducedSetConfig`` (default: its
    defaults); ``key`` default ``PRNGKey(0)``, then ``fold_in(key, r)`` for repeat r."""
    _check_repeats(repeats)
    obs = jax.numpy.asarray(samples)
    if obs.ndim != 3 or obs.shape[-1] != 2:
        raise ValueError(f"samples must have shape (n, K, 2), got {obs.shape}")
    if isinstance(m, bool) or not isinstance(m, int | np.integer) or not 1 <= m <= obs.shape[0]:
        raise ValueError(f"m must be an integer in [1, {obs.shape[0]}], got {m!r}")
    rs_cfg = ReducedSetConfig() if config is None else config
    key = jax.random.PRNGKey(0) if key is None else key
    return _time_calls(lambda k: select_reduced_set(k, obs, m, "mmd", rs_cfg).weights, key, repeats)


def time_plan(
    scene: Scene,
    config: mmdopt.MMDOptConfig | None = None,
    *,
    method: str = "mmd",
    repeats: int = 5,
    backend: str = PLANNER_BACKEND,
) -> dict[str, Any]:
    """Time ``mmdopt.plan`` on ``scene``: a first call (with ``scene.key()``; jit compile
    included), then ``repeats`` calls with fresh keys (``fold_in(scene.key(), r)``).

    Returns wall times (s) ``plan_first_s`` and the median ``plan_s``, the process CPU times
    ``plan_first_cpu_s`` and ``plan_cpu_s`` (less sensitive to a loaded machine), Algorithm 1
    alone (the CEM loop, ``plan.diagnostics["cem_s"]``) ``algorithm1_first_s`` and the median
    ``algorithm1_s``, and the last ``plan``."""
    _check_repeats(repeats)
    key = scene.key()
    walls, cpus, cems = [], [], []
    for r in range(repeats + 1):
        k = key if r == 0 else jax.random.fold_in(key, r)
        c0, t0 = _cpu(), time.perf_counter()
        p = mmdopt.plan(
            scene.ego(), scene.road(), scene.obstacles, method=method, config=config,
            projector=backend, key=k,
        )  # fmt: skip
        np.asarray(p.x)
        walls.append(time.perf_counter() - t0)
        cpus.append(_cpu() - c0)
        cems.append(float(p.diagnostics["cem_s"]))
    return dict(
        plan_first_s=walls[0],
        plan_s=float(np.median(walls[1:])),
        plan_first_cpu_s=cpus[0],
        plan_cpu_s=float(np.median(cpus[1:])),
        algorithm1_first_s=cems[0],
        algorithm1_s=float(np.median(cems[1:])),
        plan=p,
    )


TIMING_COLUMNS = (
    "reduced_set_size",
    "reduced_set_s",
    "algorithm1_s",
    "compile_s",
    "n_samples",
    "backend",
)


def _paper_algorithm() -> mmdopt.MMDOptConfig:
    """The paper's Algorithm 1: one CEM run with the time-linear margins (Table II's setting)."""
    return mmdopt.MMDOptConfig.paper()


def run_timing(
    out: str | Path,
    *,
    sizes: Sequence[int] = (10, 20, 30, 40, 50),
    samples: Sequence[int] = (50, 100, 200),
    repeats: int = 5,
    backend: str = PLANNER_BACKEND,
    config=None,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Median wall time of reduced-set selection, of Algorithm 1 (the CEM loop,
    ``plan.diagnostics["cem_s"]``) and of the whole ``mmdopt.plan`` call (``plan_s``) per
    reduced-set size ``m`` (at n = 100 samples) and per sample count n (at the smallest m), on
    the demo scene; ``compile_s`` is Algorithm 1's first-call extra time (jit compilation).
    Writes ``out/timing.csv`` (:data:`TIMING_COLUMNS` + first-call and plan times) and
    ``out/timing.png``.  ``config`` default: the paper's Algorithm 1 (one CEM run, time-linear
    margins: ``margin_mode="linear"``, ``reselect=0``), as the paper's Table II times it; the
    default planner's sample-driven margins and re-selection pass add to ``plan_s``
    (``benchmarks/plan_stages.py``).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    base = demo_scene()
    n_def = 100
    if not sizes:
        raise ValueError("sizes must hold at least one reduced-set size")
    if min(sizes) < 1 or any(m > n_def for m in sizes):
        raise ValueError(f"sizes must lie in [1, {n_def}] (the size sweep uses n = {n_def})")
    low = [int(n) for n in samples if n < min(sizes)]
    if low:
        raise ValueError(
            f"samples {low} below the smallest reduced-set size {min(sizes)}: the sample sweep "
            "runs at the smallest size, which needs n >= m"
        )
    pairs = [(int(m), n_def) for m in sizes] + [(min(sizes), int(n)) for n in samples]
    pairs = list(dict.fromkeys(pairs))
    cfg0 = scene_config(base, _paper_algorithm() if config is None else config)
    rows = []
    scenes: dict[int, Scene] = {}
    for m, n in progress_bar(pairs, desc="timing", progress=progress):
        if n not in scenes:
            scenes[n] = make_scene(base.index, base.seed, base.params.replace(n_samples=n))
        sc = scenes[n]
        rs_first, rs_med = time_reduced_set(sc.obstacles[0], int(m), repeats=repeats, key=sc.key())
        cfg = cfg0.replace(reduced_set_size=int(m))
        # Algorithm 1 = the CEM loop alone (plan.diagnostics["cem_s"]); the whole plan() call
        # (+ Frenet conversion, its own reduced-set selection, assembling the plan) is plan_s
        t = time_plan(sc, cfg, repeats=repeats, backend=backend)
        a_first, a_med = t["algorithm1_first_s"], t["algorithm1_s"]
        rows.append(
            dict(
                reduced_set_size=m,
                reduced_set_s=rs_med,
                algorithm1_s=a_med,
                compile_s=max(0.0, a_first - a_med),
                n_samples=n,
                backend=backend,
                reduced_set_first_s=rs_first,
                algorithm1_first_s=a_first,
                plan_s=t["plan_s"],
                plan_first_s=t["plan_first_s"],
                repeats=repeats,
            )
        )
    cols = list(TIMING_COLUMNS) + [
        "reduced_set_first_s",
        "algorithm1_first_s",
        "plan_s",
        "plan_first_s",
        "repeats",
    ]
    write_results(rows, out / "timing.csv", cols)
    plots.timing_figure(rows, out / "timing.png")
    return rows


# ---------------------------------------------------------------------------------- many obstacles
OBSTACLE_TIMING_COLUMNS = (
    "obstacles",
    "interacting",
    "reduced_set_s",
    "algorithm1_s",
    "plan_s",
    "plan_first_s",
    "per_obstacle_s",
    "backend",
)


def traffic_scene(n_obstacles: int, seed: int = 0) -> tuple[Scene, np.ndarray, int]:
    """The demo scene plus ``n_obstacles − 1`` other vehicles on a three-lane road (seeded): each a
    copy of the demo obstacle's samples moved to another lane (offsets −3.5, +3.5, +7 m) and
    20–200 m ahead or 30–90 m behind.  Returns ``(scene, obstacles (O, n, K, 2), interacting)``,
    ``interacting`` = the obstacles some sample of which comes within 10 m of the ego's lane
    centre line ahead of the ego within the horizon (a rough count of the ones that matter)."""
    if n_obstacles < 1:
        raise ValueError(f"n_obstacles must be >= 1, got {n_obstacles}")
    sc = demo_scene()
    base = sc.obstacles[0]
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 15]))
    out = [base]
    for _ in range(1, n_obstacles):
        dy = rng.choice([-3.5, 3.5, 7.0])
        dx = rng.uniform(20.0, 200.0) if rng.random() < 0.7 else -rng.uniform(30.0, 90.0)
        out.append(base + np.array([dx, dy]))
    obs = np.stack(out)
    t = sc.t
    ego_x = sc.params.ego_speed * t
    near = (np.abs(obs[..., 1]) < 3.0) & (np.abs(obs[..., 0] - ego_x) < 10.0)
    return sc, obs, int(np.sum(np.any(near, axis=(1, 2))))


def run_obstacle_timing(
    out: str | Path,
    *,
    counts: Sequence[int] = (1, 5, 10, 20),
    repeats: int = 5,
    backend: str = PLANNER_BACKEND,
    config=None,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Median time of reduced-set selection, Algorithm 1 and the whole ``plan()`` call against
    1, 5, 10, 20 obstacles (:func:`traffic_scene`); writes ``out/timing_obstacles.csv``.
    ``config`` default: the paper's Algorithm 1, as in :func:`run_timing`."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for O in progress_bar([int(c) for c in counts], desc="obstacles", progress=progress):
        sc, obs, inter = traffic_scene(O)
        cfg = scene_config(sc, _paper_algorithm() if config is None else config)
        rs_t, cem_t, plan_t = [], [], []
        for r in range(repeats + 1):
            p = mmdopt.plan(
                sc.ego(), sc.road(), obs, config=cfg, backend=backend,
                key=jax.random.fold_in(sc.key(), r),
            )  # fmt: skip
            rs_t.append(p.diagnostics["reduced_set_s"])
            cem_t.append(p.diagnostics["cem_s"])
            plan_t.append(p.plan_time_s)
        a1 = float(np.median(cem_t[1:]))
        rows.append(
            dict(
                obstacles=O,
                interacting=inter,
                reduced_set_s=float(np.median(rs_t[1:])),
                algorithm1_s=a1,
                plan_s=float(np.median(plan_t[1:])),
                plan_first_s=plan_t[0],
                per_obstacle_s=a1 / O,
                backend=backend,
            )
        )
    write_results(rows, out / "timing_obstacles.csv", OBSTACLE_TIMING_COLUMNS)
    return rows
