"""The synthetic-scene benchmark (paper Fig. 5): every method on every scene of a sweep.

:func:`run_synthetic` plans every scene with every method and writes one JSON file per
(scene, method) into ``OUT/scenes/`` as soon as it is done, so an interrupted sweep resumes where
it stopped (finished files are never recomputed); the rows are merged into ``OUT/results.csv`` and
summarised (:func:`~mmdopt.bench.results.summarize`) into ``OUT/summary.json``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

import mmdopt
from mmdopt.algorithm import PLANNER_BACKEND

from .executors import check_manifest, run_tasks
from .metric import _float, evaluate_plan
from .results import check_bars, summarize, write_json, write_results
from .scenes import Scene, SceneParams, make_scene, num_scenes

__all__ = ["plan_scene", "run_scene", "scene_config", "run_synthetic", "config_overrides"]


def scene_config(scene: Scene, config: mmdopt.MMDOptConfig | None = None) -> mmdopt.MMDOptConfig:
    """``config`` (default ``MMDOptConfig()``) with the scene's desired speed."""
    cfg = mmdopt.MMDOptConfig() if config is None else config
    return cfg.replace(v_des=scene.params.desired_speed)


def plan_scene(
    scene: Scene,
    method: str = "mmd",
    *,
    config: mmdopt.MMDOptConfig | None = None,
    backend: str = PLANNER_BACKEND,
    key: Any = None,
    reduced_set: Any = None,
) -> tuple[mmdopt.Plan, mmdopt.Road, float]:
    """Run Algorithm 1 (``mmdopt.plan``) on a scene with ``config`` as given; returns
    ``(plan, road, wall_s)``."""
    road = scene.road()
    cfg = mmdopt.MMDOptConfig() if config is None else config
    t0 = time.perf_counter()
    plan = mmdopt.plan(
        scene.ego(),
        road,
        scene.obstacles,
        method=method,
        config=cfg,
        backend=backend,
        key=scene.key() if key is None else key,
        reduced_set=reduced_set,
    )
    np.asarray(plan.x)  # block until computed
    return plan, road, time.perf_counter() - t0


def run_scene(
    scene: Scene, method: str = "mmd", *, config=None, backend: str = PLANNER_BACKEND
) -> tuple[dict[str, Any], mmdopt.Plan]:
    """Plan and evaluate one scene with one method: ``(row, plan)``."""
    cfg = scene_config(scene, config)
    plan, road, wall = plan_scene(scene, method, config=cfg, backend=backend)
    row = evaluate_plan(plan, scene, road)
    row.update(
        method=method,
        plan_time_s=_float(getattr(plan, "plan_time_s", wall)),
        wall_s=wall,
        backend=backend,
    )
    return row, plan


def config_overrides(config) -> dict[str, Any]:
    """A JSON-able description of a config (for the run manifest)."""
    if config is None:
        return {}
    if dataclasses.is_dataclass(config):
        return {k: repr(v) for k, v in dataclasses.asdict(config).items()}
    return {"repr": repr(config)}


def _row_path(out: Path, scene: int, method: str) -> Path:
    return out / "scenes" / f"scene_{scene:04d}__{method}.json"


def _scene_task(args) -> int:
    """Worker: generate scene ``index``, plan the missing methods, write one file per method."""
    index, seed, params_dict, methods, backend, out, config = args
    params = SceneParams.from_dict(params_dict)
    scene = make_scene(index, seed, params)
    done = 0
    for m in methods:
        path = _row_path(Path(out), index, m)
        if path.exists():
            continue
        row, plan = run_scene(scene, m, config=config, backend=backend)
        rec = dict(row)
        rec["plan_xy"] = np.stack([np.asarray(plan.x), np.asarray(plan.y)], -1).round(4)
        write_json(path, rec)
        done += 1
    return done


def _manifest(seed, params: SceneParams, backend, config) -> dict[str, Any]:
    return dict(
        seed=int(seed), params=params.to_dict(), backend=backend, config=config_overrides(config)
    )


def run_synthetic(
    out: str | Path,
    *,
    scenes: int | None = None,
    seed: int = 0,
    params: SceneParams | None = None,
    methods: Sequence[str] = ("mmd", "degroot", "random", "saa"),
    backend: str = PLANNER_BACKEND,
    jobs: int = 1,
    config=None,
    progress: bool = True,
    executor: str = "local",
    address: str | None = None,
) -> dict[str, Any]:
    """Plan and score a sweep of synthetic scenes; resumable and parallel.

    Writes ``out/scenes/scene_XXXX__METHOD.json`` (one per finished plan; existing ones are
    reused, never recomputed), ``out/results.csv`` (all rows,
    :data:`~mmdopt.bench.results.RESULT_COLUMNS`), ``out/summary.json`` and ``out/run.json``
    (the settings; resuming into a folder made with other settings raises ``ValueError``).

    Returns ``{"rows", "summary", "bars", "computed", "reused", "wall_s"}``.
    """
    params = SceneParams() if params is None else params
    n = num_scenes(params, scenes)
    methods = list(dict.fromkeys(methods))
    out = Path(out)
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    check_manifest(out, _manifest(seed, params, backend, config))

    todo, reused = [], 0
    for i in range(n):
        missing = [m for m in methods if not _row_path(out, i, m).exists()]
        reused += len(methods) - len(missing)
        if missing:
            todo.append((i, seed, params.to_dict(), missing, backend, str(out), config))

    t0 = time.perf_counter()
    done = run_tasks(
        _scene_task,
        todo,
        jobs=jobs,
        executor=executor,
        address=address,
        progress=progress,
        desc="scenes",
        unit="scene",
        first_note="compiling Algorithm 1 (first scene of each worker, ~30 s)…",
    )
    computed = int(sum(done))
    wall = time.perf_counter() - t0

    rows = []
    for i in range(n):
        for m in methods:
            rec = json.loads(_row_path(out, i, m).read_text())
            rec.pop("plan_xy", None)
            rows.append(rec)
    write_results(rows, out / "results.csv")
    summary = summarize(rows)
    bars = check_bars(summary)
    write_json(
        out / "summary.json",
        dict(
            summary=summary,
            bars=bars,
            scenes=n,
            methods=methods,
            seed=seed,
            backend=backend,
            params=params.to_dict(),
            computed=computed,
            reused=reused,
            wall_s=wall,
        ),
    )
    return dict(
        rows=rows, summary=summary, bars=bars, computed=computed, reused=reused, wall_s=wall
    )
