"""The synthetic-scene benchmark (paper Fig. 5): every method on every scene of a sweep.

:func:`run_synthetic` plans every scene with every method and writes one JSON file per
(scene, method) into ``OUT/scenes/`` as soon as it is done, so an interrupted sweep resumes where
it stopped (finished files are never recomputed); the rows are merged into ``OUT/results.csv`` and
summarised (:func:`~mmdopt.bench.results.summarize`) into ``OUT/summary.json``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

import mmdopt
from mmdopt.algorithm import PLANNER_BACKEND

from .executors import MISSING, check_manifest, run_tasks, worker_layout
from .metric import evaluate_plan
from .metric import float_or_nan as _float
from .results import (
    check_bars,
    remove_temp_files,
    summarize,
    write_json,
    write_results,
)
from .scenes import Scene, SceneParams, make_scene, num_scenes

__all__ = [
    "plan_scene",
    "run_scene",
    "forecast_cap",
    "scene_config",
    "run_synthetic",
    "config_overrides",
    "check_sweep_config",
    "load_task_file",
]


def scene_config(scene: Scene, config: mmdopt.MMDOptConfig | None = None) -> mmdopt.MMDOptConfig:
    """``config`` (default ``MMDOptConfig()``) with the scene's desired speed, and the scene
    family's collision ellipse where it has one (``SceneParams.footprint``)."""
    cfg = mmdopt.MMDOptConfig() if config is None else config
    cfg = cfg.replace(v_des=scene.params.desired_speed)
    if scene.params.footprint is not None:
        a, b = scene.params.footprint
        cfg = cfg.replace(footprint=dataclasses.replace(cfg.safety.footprint, a=a, b=b))
    return cfg


def plan_scene(
    scene: Scene,
    method: str = "mmd",
    *,
    config: mmdopt.MMDOptConfig | None = None,
    backend: str = PLANNER_BACKEND,
    key: Any = None,
    reduced_set: Any = None,
    obstacles: Any = None,
) -> tuple[mmdopt.Plan, mmdopt.Road, float]:
    """Run Algorithm 1 (``mmdopt.plan``) on a scene with ``config`` as given; returns
    ``(plan, road, wall_s)``.  ``obstacles``: the scene's fixed planning samples by default, or
    e.g. :meth:`Scene.forecast` (then the plan draws n(ε) futures)."""
    road = scene.road()
    cfg = mmdopt.MMDOptConfig() if config is None else config
    t0 = time.perf_counter()
    plan = mmdopt.plan(
        scene.ego(),
        road,
        scene.obstacles if obstacles is None else obstacles,
        method=method,
        config=cfg,
        projector=backend,
        key=scene.key() if key is None else key,
        reduced_set=reduced_set,
    )
    np.asarray(plan.x)  # block until computed
    return plan, road, time.perf_counter() - t0


#: the most futures per obstacle a plan through the scene's predictor draws (:meth:`Scene.forecast`)
MAX_FORECAST_SAMPLES = 5000
#: MMD-Opt's cap: its reduced set is chosen among at most 1000 futures, so only its margins,
#: nearest-futures pass, re-selection and final check grow with n (the other methods plan on
#: every future: their cost grows faster with n)
MMD_MAX_FORECAST_SAMPLES = 50_000


def forecast_cap(method: str) -> int:
    """The most futures per obstacle ``method`` draws from a scene's predictor."""
    return int(mmdopt.methods.get(method).max_futures)


def run_scene(
    scene: Scene,
    method: str = "mmd",
    *,
    config=None,
    backend: str = PLANNER_BACKEND,
    forecast: bool = False,
    max_samples: int | None = None,
) -> tuple[dict[str, Any], mmdopt.Plan]:
    """Plan and evaluate one scene with one method: ``(row, plan)``.

    ``forecast=False`` plans on the scene's fixed planning samples; ``True`` through the scene's
    predictor (:meth:`Scene.forecast`): the plan draws n(ε) futures (at most ``max_samples``,
    default :func:`forecast_cap`) with the scene's planner key, so methods that draw as many
    plan on the same futures at a given risk level.  ``n_planning`` (= ``n_samples``) and
    ``collision_free_planning`` of the row are those of the futures the plan met."""
    cfg = scene_config(scene, config)
    obstacles = None
    if forecast:
        cap = forecast_cap(method) if max_samples is None else int(max_samples)
        obstacles = scene.forecast(min_samples=scene.params.n_samples, max_samples=cap)
    plan, road, wall = plan_scene(scene, method, config=cfg, backend=backend, obstacles=obstacles)
    row = evaluate_plan(plan, scene, road)
    diag = getattr(plan, "diagnostics", {}) or {}
    n_plan = int(diag.get("n_planning_samples", row["n_samples"]))
    if forecast:
        row.update(
            n_samples=n_plan,
            collision_free_planning=int(np.min(diag["collision_free_planning"])),
        )
    row.update(
        method=method,
        n_planning=n_plan,
        plan_time_s=_float(getattr(plan, "plan_time_s", wall)),
        predict_time_s=_float(getattr(plan, "predict_time_s", 0.0)),
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
    index, seed, params_dict, methods, backend, out, config, forecast = args
    params = SceneParams.from_dict(params_dict)
    scene = make_scene(index, seed, params)
    done = 0
    for m in methods:
        path = _row_path(Path(out), index, m)
        if path.exists():
            continue
        row, plan = run_scene(scene, m, config=config, backend=backend, forecast=forecast)
        rec = dict(row)
        rec["plan_xy"] = np.stack([np.asarray(plan.x), np.asarray(plan.y)], -1).round(4)
        write_json(path, rec)
        done += 1
    return done


def sweep_manifest(
    seed, params: SceneParams, backend, config, layout: str = "in-process", forecast=False
):
    # the effective config (the default when none is given): the same settings, the same manifest
    cfg = mmdopt.MMDOptConfig() if config is None else config
    return dict(
        seed=int(seed),
        params=params.to_dict(),
        backend=backend,
        config=config_overrides(cfg),
        workers=layout,
        planning_samples=planning_samples(forecast),
    )


def planning_samples(forecast: bool) -> str:
    """The manifest's description of where a sweep's planning futures come from."""
    if not forecast:
        return "fixed"
    return f"forecast n(eps) <= {MAX_FORECAST_SAMPLES} (mmd <= {MMD_MAX_FORECAST_SAMPLES})"


def manifest_aliases(config, forecast: bool = False) -> dict[str, list[Any]]:
    """Older manifests had no ``workers`` key, nor ``planning_samples`` (they planned on the
    fixed samples).  (They recorded the default config as ``{}``: the time-linear margins, which
    are no longer the default, so such a folder is refused.)"""
    return {"workers": [MISSING], "planning_samples": [] if forecast else [MISSING]}


def check_sweep_config(
    params: SceneParams, config, methods: Sequence[str], backend: str, seed: int = 0
) -> None:
    """Everything about a sweep's planner settings that planning would otherwise find late:
    the config with the scene's desired speed, the obstacle samples against its horizon and
    reduced-set size for every method, the backend, the planning problem (built once).  Raises
    ``ValueError``; the runners call it before writing anything into the sweep folder."""
    from mmdopt import algorithm as alg
    from mmdopt.validate import check_obstacles

    if config is not None and not isinstance(config, mmdopt.MMDOptConfig):
        raise ValueError(f"config must be an mmdopt.MMDOptConfig, got {type(config).__name__}")
    scene = make_scene(0, seed, params)
    cfg = scene_config(scene, config)
    alg.check_backend(backend, {})
    if not isinstance(cfg, alg.MMDOptConfig):  # a stand-in planner's config: nothing to build
        return
    for m in methods:
        mmdopt.methods.get(m)
        check_obstacles(scene.obstacles, cfg, m, name="the scene's obstacle samples")
    road = scene.road()
    mmdopt.Planner(cfg).workspace(road.bounds())  # the projection is built (and checked)


#: keys every per-task record must hold, with their JSON types
_ROW_TYPES = dict(
    scene=(int,),
    method=(str,),
    collision_free=(int,),
    n_validation=(int,),
    progress_m=(int, float),
    feasible=(bool,),
    plan_time_s=(int, float),
)


def _row_problem(rec: Any, index: int, method: str) -> str | None:
    """Why ``rec`` is not the record of (``index``, ``method``), or ``None`` if it is."""
    if not isinstance(rec, dict):
        return f"holds a JSON {type(rec).__name__}, not an object"
    for k, types in _ROW_TYPES.items():
        if k not in rec:
            return f"has no {k!r}"
        v = rec[k]
        if isinstance(v, bool) and bool not in types:
            return f"{k!r} is {v!r}"
        if not isinstance(v, types):
            return f"{k!r} is {v!r}"
    if rec["scene"] != index or rec["method"] != method:
        return f"holds scene {rec['scene']!r}, method {rec['method']!r}"
    if not (0 <= rec["collision_free"] <= rec["n_validation"]):
        return f"collision_free {rec['collision_free']} outside [0, {rec['n_validation']}]"
    if not math.isfinite(rec["progress_m"]):
        return f"progress_m is {rec['progress_m']}"
    return None


def load_task_file(path: Path, check) -> Any:
    """Read one per-task JSON; return ``None`` if it is absent.  A damaged file (unreadable,
    truncated, empty, or ``check(record)`` returns a reason) is moved aside to
    ``NAME.corrupt`` (numbered if that exists), named in one warning line on stderr, and
    ``None`` is returned so the task is computed again."""
    if not path.exists():
        return None
    try:
        rec = json.loads(path.read_text())
        why = check(rec)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        why = f"is not valid JSON ({type(e).__name__}: {e})" if path.stat().st_size else "is empty"
    if why is None:
        return rec
    dest = path.with_name(path.name + ".corrupt")
    i = 1
    while dest.exists():
        dest = path.with_name(f"{path.name}.corrupt{i}")
        i += 1
    try:
        path.replace(dest)
        what = f"moved to {dest.name}"
    except OSError:
        path.unlink(missing_ok=True)
        what = "deleted"
    print(f"warning: {path} is corrupt ({why}); {what}, recomputing it", file=sys.stderr)
    return None


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
    isolate: bool = False,
    forecast: bool = False,
) -> dict[str, Any]:
    """Plan and score a sweep of synthetic scenes; resumable and parallel.  ``forecast`` as in
    :func:`run_scene` (``True``: every plan draws n(ε) futures from the scene's predictor).

    Writes ``out/scenes/scene_XXXX__METHOD.json`` (one per finished plan; existing ones are
    reused, never recomputed), ``out/results.csv`` (all rows,
    :data:`~mmdopt.bench.results.RESULT_COLUMNS`), ``out/summary.json`` and ``out/run.json``
    (the settings; resuming into a folder made with other settings raises ``ValueError``).
    The settings are checked (:func:`check_sweep_config`) before anything is written; a
    damaged per-task file is moved aside and recomputed (:func:`load_task_file`); ``isolate``
    as in :func:`~mmdopt.bench.executors.run_tasks` (the manifest records where results were
    computed, and a folder refuses a mix).

    Returns ``{"rows", "summary", "bars", "computed", "reused", "wall_s"}``.
    """
    params = SceneParams() if params is None else params
    n = num_scenes(params, scenes)
    methods = list(dict.fromkeys(methods))
    check_sweep_config(params, config, methods, backend, seed)
    out = Path(out)
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    layout = worker_layout(jobs, executor, isolate)
    check_manifest(
        out,
        sweep_manifest(seed, params, backend, config, layout, forecast),
        aliases=manifest_aliases(config, forecast),
    )
    remove_temp_files(out / "scenes")
    remove_temp_files(out)

    todo, reused = [], 0
    for i in range(n):
        missing = [
            m
            for m in methods
            if load_task_file(_row_path(out, i, m), lambda r, i=i, m=m: _row_problem(r, i, m))
            is None
        ]
        reused += len(methods) - len(missing)
        if missing:
            todo.append((i, seed, params.to_dict(), missing, backend, str(out), config, forecast))

    t0 = time.perf_counter()
    try:
        done = run_tasks(
            _scene_task,
            todo,
            jobs=jobs,
            executor=executor,
            address=address,
            progress=progress,
            desc="scenes",
            unit="scene",
            isolate=isolate,
            first_note="compiling Algorithm 1 (first scene of each worker, ~30 s)…",
        )
    finally:
        remove_temp_files(out / "scenes")  # left by workers killed mid-write
    computed = int(sum(done))
    wall = time.perf_counter() - t0

    rows = []
    for i in range(n):
        for m in methods:
            path = _row_path(out, i, m)
            rec = json.loads(path.read_text())
            why = _row_problem(rec, i, m)
            if why is not None:  # pragma: no cover - only if the folder changes under us
                raise ValueError(f"{path} {why}")
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
