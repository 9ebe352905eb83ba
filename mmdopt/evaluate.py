"""The collision metric and the synthetic benchmark harness (paper §Benchmarks, SPEC §h).

**Metric.**  A plan is scored by the number of validation samples it avoids: a sample *collides*
if, at any time step, for any of its circles (default 3 at {0, ±2.5} m along its heading) the
ellipse function ``f = 1 − Δx²/a² − Δy²/b²`` (a = 4.5 m, b = 3.5 m, ego a point) is **strictly**
positive (``f̄ > 0``); ``collision_free = N − #colliding`` (:func:`collision_free`, built on
:func:`mmdopt.collision_free_count`).  Safety alone rewards standing still, so every result row
also carries the plan's **progress** (metres travelled along the road), its speed, and an
independent **kinematic check** (lane, speed and acceleration bounds, evaluated on the returned
trajectory, not trusted from the planner).

**Harness.**  :func:`run_synthetic` plans every scene of a sweep with every method and writes one
JSON file per (scene, method) into ``OUT/scenes/`` as soon as it is done, so an interrupted sweep
resumes where it stopped (finished files are never recomputed); the rows are merged into
``OUT/results.csv`` and summarised (:func:`summarize`) into ``OUT/summary.json``.  Scenes run in
parallel over ``jobs`` processes (``concurrent.futures`` with the *spawn* context; each worker
compiles Algorithm 1 once and reuses it for all its scenes).
"""

from __future__ import annotations

import concurrent.futures as cf
import csv
import dataclasses
import json
import math
import multiprocessing as mp
import os
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .scenarios import Scene, SceneParams, make_scene, num_scenes

__all__ = [
    "RESULT_COLUMNS",
    "METHODS",
    "BARS",
    "collision_free",
    "kinematic_violation",
    "progress",
    "evaluate_plan",
    "plan_scene",
    "run_scene",
    "run_synthetic",
    "read_results",
    "write_results",
    "summarize",
    "check_bars",
]

#: Columns of ``results.csv`` (the first seven are the outside contract).
RESULT_COLUMNS = (
    "scene",
    "method",
    "collision_free",
    "n_validation",
    "progress_m",
    "feasible",
    "plan_time_s",
    "collision_free_planning",
    "n_samples",
    "mean_speed",
    "final_speed",
    "kinematic_violation",
    "planner_feasible",
    "fallback",
    "status",
    "cost",
    "mmd",
    "residual",
    "wall_s",
    "x0",
    "y0",
    "p",
    "seed",
    "backend",
)

#: Planning methods of ``mmdopt.plan`` (the first is MMD-Opt, the rest baselines).
METHODS = ("mmd", "degroot", "random", "saa", "scenario_all")

#: The paper-protocol bars (issue 4): MMD-Opt on 100 scenes × 1000 validation samples.
BARS = dict(mean=972.0, q1=967.0, share_vs_degroot=0.80, progress_ratio_vs_degroot=0.80)

#: Tolerances of the independent kinematic check (m, m/s, m/s²).
KINEMATIC_TOL = 0.05


# ---------------------------------------------------------------------------------------------
# metric


def collision_free(
    plan_xy, validation, *, a: float = 4.5, b: float = 3.5, obstacle_footprint=None
) -> int:
    """Validation samples a plan avoids (strict ``f̄ > 0`` = collision; any circle, any step).

    Parameters
    ----------
    plan_xy : (K, 2) ego waypoints (m)
    validation : (O, N, K, 2) or (N, K, 2) obstacle samples; with several obstacles, sample n of
        every obstacle is one joint draw and counts as collision-free only if clear of all

    Returns
    -------
    int in ``[0, N]``
    """
    from .geometry import OBSTACLE_FOOTPRINT
    from .surrogate import collision_free_count

    fp = OBSTACLE_FOOTPRINT if obstacle_footprint is None else obstacle_footprint
    xy = np.asarray(plan_xy, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"plan_xy must have shape (K, 2), got {xy.shape}")
    if not np.all(np.isfinite(xy)):
        raise ValueError("plan_xy contains NaN or inf")
    counts = collision_free_count(xy, np.asarray(validation, dtype=np.float64), fp, a=a, b=b)
    return int(counts.joint)


def progress(plan) -> float:
    """Distance travelled along the road (m): ``s_{K−1} − s_0``."""
    s = np.asarray(plan.s, dtype=np.float64)
    return float(s[-1] - s[0])


def _bound(road, names: Sequence[str], default: float) -> float:
    for n in names:
        v = getattr(road, n, None)
        if v is not None:
            return float(v)
    return default


def kinematic_violation(plan, road=None, *, y_lb=None, y_ub=None) -> float:
    """Largest violation (m, m/s or m/s², ≥ 0) of the lane, speed and acceleration bounds.

    Checked on the returned Frenet trajectory: ``y_lb ≤ d ≤ y_ub``, ``v_min ≤ v_s ≤ v_max``,
    ``|a_s|, |a_d| ≤ a_max`` (bounds from ``road`` where it has them; defaults 0, 30 m/s,
    18 m/s² as the reference), and finiteness (non-finite plans score ``inf``).
    """
    d = np.asarray(plan.d, dtype=np.float64)
    vs = np.asarray(plan.vs, dtype=np.float64)
    arrs = [d, vs, np.asarray(plan.s, dtype=np.float64)]
    acc = [
        np.asarray(getattr(plan, n), dtype=np.float64) for n in ("as_", "ad") if hasattr(plan, n)
    ]
    if not all(np.all(np.isfinite(x)) for x in arrs + acc):
        return math.inf
    lo = _bound(road, ("y_lb",), -np.inf) if y_lb is None else float(y_lb)
    hi = _bound(road, ("y_ub",), np.inf) if y_ub is None else float(y_ub)
    v_min = _bound(road, ("v_min",), 0.0)
    v_max = _bound(road, ("v_max",), 30.0)
    a_max = _bound(road, ("a_max", "ax_max"), 18.0)
    viol = [
        np.max(lo - d),
        np.max(d - hi),
        np.max(v_min - vs),
        np.max(vs - v_max),
    ]
    viol += [np.max(np.abs(a)) - a_max for a in acc]
    return float(max(0.0, *viol))


def evaluate_plan(plan, scene: Scene, road=None) -> dict[str, Any]:
    """Metric row of one plan on one scene (without the ``method``/timing columns)."""
    xy = np.stack([np.asarray(plan.x), np.asarray(plan.y)], axis=-1)
    cf_val = collision_free(xy, scene.validation)
    cf_plan = collision_free(xy, scene.obstacles)
    viol = kinematic_violation(plan, road, y_lb=scene.params.ego_y_lb, y_ub=scene.params.ego_y_ub)
    speed = np.asarray(getattr(plan, "speed", np.hypot(plan.vs, plan.vd)), dtype=np.float64)
    planner_feasible = bool(getattr(plan, "feasible", True))
    return dict(
        scene=scene.index,
        collision_free=cf_val,
        n_validation=int(scene.validation.shape[1]),
        progress_m=progress(plan),
        feasible=bool(planner_feasible and viol <= KINEMATIC_TOL),
        collision_free_planning=cf_plan,
        n_samples=int(scene.obstacles.shape[1]),
        mean_speed=float(np.mean(speed)),
        final_speed=float(speed[-1]),
        kinematic_violation=viol,
        planner_feasible=planner_feasible,
        fallback=bool(getattr(plan, "fallback", False)),
        status=str(getattr(plan, "status", "")),
        cost=_float(getattr(plan, "cost", math.nan)),
        mmd=_float(getattr(plan, "mmd", math.nan)),
        residual=_float(getattr(plan, "residual", math.nan)),
        x0=scene.x0,
        y0=scene.y0,
        p=scene.p,
        seed=scene.seed,
    )


def _float(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


# ---------------------------------------------------------------------------------------------
# planning


def plan_scene(scene: Scene, method: str = "mmd", *, config=None, backend: str = "admm", key=None):
    """Run Algorithm 1 (``mmdopt.plan``) on a scene; returns ``(plan, road, wall_s)``."""
    import mmdopt

    road = scene.road()
    cfg = mmdopt.MMDOptConfig() if config is None else config
    kw = {}
    if _accepts(mmdopt.plan, "v_des") and not _has_field(cfg, "v_des"):
        kw["v_des"] = scene.params.desired_speed
    t0 = time.perf_counter()
    plan = mmdopt.plan(
        scene.ego(),
        road,
        scene.obstacles,
        method=method,
        config=cfg,
        backend=backend,
        key=scene.key() if key is None else key,
        **kw,
    )
    np.asarray(plan.x)  # block until computed
    return plan, road, time.perf_counter() - t0


def _accepts(fn, name: str) -> bool:
    import inspect

    try:
        return name in inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False


def _has_field(obj, name: str) -> bool:
    return dataclasses.is_dataclass(obj) and name in {f.name for f in dataclasses.fields(obj)}


def scene_config(scene: Scene, config=None):
    """``config`` (default ``MMDOptConfig()``) with the scene's desired speed, if it has one."""
    import mmdopt

    cfg = mmdopt.MMDOptConfig() if config is None else config
    for name in ("v_des", "desired_speed"):
        if _has_field(cfg, name):
            return cfg.replace(**{name: scene.params.desired_speed})
    return cfg


def run_scene(
    scene: Scene, method: str = "mmd", *, config=None, backend: str = "admm"
) -> tuple[dict[str, Any], Any]:
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


# ---------------------------------------------------------------------------------------------
# results files


def _row_path(out: Path, scene: int, method: str) -> Path:
    return out / "scenes" / f"scene_{scene:04d}__{method}.json"


def _write_json(path: Path, obj) -> None:
    tmp = path.with_suffix(path.suffix + f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(obj, indent=1, default=_json_default))
    os.replace(tmp, path)


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")


def write_results(rows: Iterable[dict[str, Any]], path: str | Path) -> None:
    """Write rows to CSV with :data:`RESULT_COLUMNS` first (extra keys appended, sorted)."""
    rows = list(rows)
    extra = sorted({k for r in rows for k in r} - set(RESULT_COLUMNS))
    cols = list(RESULT_COLUMNS) + extra
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, "") for k in cols})


def read_results(path: str | Path) -> list[dict[str, Any]]:
    """Read a ``results.csv`` back (numbers parsed, booleans as bool)."""
    out = []
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            out.append({k: _parse(v) for k, v in r.items()})
    return out


def _parse(v: str):
    if v in ("True", "False"):
        return v == "True"
    try:
        i = int(v)
        return i
    except ValueError:
        pass
    try:
        return float(v)
    except ValueError:
        return v


# ---------------------------------------------------------------------------------------------
# summary


def _stats(x: np.ndarray) -> dict[str, float]:
    x = np.asarray(x, dtype=np.float64)
    if x.size == 0:
        return {}
    q1, med, q3 = np.percentile(x, [25, 50, 75])
    return dict(
        mean=float(x.mean()),
        std=float(x.std()),
        min=float(x.min()),
        q1=float(q1),
        median=float(med),
        q3=float(q3),
        max=float(x.max()),
    )


def summarize(rows: Sequence[dict[str, Any]], reference: str = "mmd") -> dict[str, Any]:
    """Per-method statistics over scenes and the pairwise comparison with ``reference``.

    Returns ``{"methods": {m: {...}}, "vs": {baseline: {...}}}``: collision-free mean / std /
    min / quartiles, feasible share, progress and plan time per method; for every baseline the
    share of scenes where ``reference ≥ baseline`` (ties count as success, SPEC §h), on the
    scenes both completed, and the ratio of mean progress.
    """
    by: dict[str, dict[int, dict[str, Any]]] = {}
    for r in rows:
        by.setdefault(str(r["method"]), {})[int(r["scene"])] = r
    out: dict[str, Any] = {"methods": {}, "vs": {}}
    for m, d in by.items():
        rs = list(d.values())
        cf_ = np.array([r["collision_free"] for r in rs], dtype=float)
        nv = np.array([r["n_validation"] for r in rs], dtype=float)
        out["methods"][m] = dict(
            scenes=len(rs),
            collision_free=_stats(cf_),
            collision_free_pct=float(np.mean(cf_ / nv) * 100),
            feasible_share=float(np.mean([bool(r["feasible"]) for r in rs])),
            fallback_share=float(np.mean([bool(r.get("fallback", False)) for r in rs])),
            progress_m=_stats([r["progress_m"] for r in rs]),
            mean_speed=float(np.mean([r["mean_speed"] for r in rs])),
            plan_time_s=_stats([r["plan_time_s"] for r in rs]),
        )
    if reference in by:
        ref = by[reference]
        for m, d in by.items():
            if m == reference:
                continue
            common = sorted(set(ref) & set(d))
            if not common:
                continue
            a = np.array([ref[s]["collision_free"] for s in common], dtype=float)
            b = np.array([d[s]["collision_free"] for s in common], dtype=float)
            pa = np.mean([ref[s]["progress_m"] for s in common])
            pb = np.mean([d[s]["progress_m"] for s in common])
            out["vs"][m] = dict(
                scenes=len(common),
                share_ge=float(np.mean(a >= b)),
                share_gt=float(np.mean(a > b)),
                mean_diff=float(np.mean(a - b)),
                progress_ratio=float(pa / pb) if pb > 0 else math.nan,
            )
    return out


def check_bars(summary: dict[str, Any], reference: str = "mmd", baseline: str = "degroot"):
    """The issue's bars against a summary: ``{bar: {"value", "target", "ok"}}``."""
    res = {}
    m = summary["methods"].get(reference)
    if m:
        res["mean"] = (m["collision_free"]["mean"], BARS["mean"])
        res["q1"] = (m["collision_free"]["q1"], BARS["q1"])
    v = summary["vs"].get(baseline)
    if v:
        res["share_vs_degroot"] = (v["share_ge"], BARS["share_vs_degroot"])
        res["progress_ratio_vs_degroot"] = (v["progress_ratio"], BARS["progress_ratio_vs_degroot"])
    return {k: dict(value=a, target=b, ok=bool(a >= b)) for k, (a, b) in res.items()}


# ---------------------------------------------------------------------------------------------
# sweeps


def _config_overrides(config) -> dict[str, Any]:
    """A JSON-able description of a config (for the run manifest)."""
    if config is None:
        return {}
    if dataclasses.is_dataclass(config):
        return {k: repr(v) for k, v in dataclasses.asdict(config).items()}
    return {"repr": repr(config)}


def _scene_task(args) -> list[dict[str, Any]]:
    """Worker: generate scene ``index``, plan the missing methods, write one file per method."""
    index, seed, params_dict, methods, backend, out, config = args
    params = SceneParams.from_dict(params_dict)
    scene = make_scene(index, seed, params)
    rows = []
    for m in methods:
        path = _row_path(Path(out), index, m)
        if path.exists():
            continue
        row, plan = run_scene(scene, m, config=config, backend=backend)
        rec = dict(row)
        rec["plan_xy"] = np.stack([np.asarray(plan.x), np.asarray(plan.y)], -1).round(4)
        _write_json(path, rec)
        rows.append(row)
    return rows


def _worker_init() -> None:  # pragma: no cover - runs in the spawned workers
    import mmdopt  # noqa: F401  (x64 mode, jit caches live per process)


def _manifest(seed, params: SceneParams, backend, config) -> dict[str, Any]:
    return dict(
        seed=int(seed), params=params.to_dict(), backend=backend, config=_config_overrides(config)
    )


def run_synthetic(
    out: str | Path,
    *,
    scenes: int | None = None,
    seed: int = 0,
    params: SceneParams | None = None,
    methods: Sequence[str] = ("mmd", "degroot", "random", "saa"),
    backend: str = "admm",
    jobs: int = 1,
    config=None,
    progress: bool = True,
) -> dict[str, Any]:
    """Plan and score a sweep of synthetic scenes; resumable and parallel.

    Writes ``out/scenes/scene_XXXX__METHOD.json`` (one per finished plan; existing ones are
    reused, never recomputed), ``out/results.csv`` (all rows, :data:`RESULT_COLUMNS`),
    ``out/summary.json`` (:func:`summarize` + :func:`check_bars`) and ``out/run.json`` (the
    settings; resuming into a folder made with other settings raises ``ValueError``).

    Returns ``{"rows", "summary", "bars", "computed", "reused", "wall_s"}``.
    """
    from tqdm.auto import tqdm

    params = SceneParams() if params is None else params
    n = num_scenes(params, scenes)
    methods = list(dict.fromkeys(methods))
    out = Path(out)
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    man = _manifest(seed, params, backend, config)
    man_path = out / "run.json"
    if man_path.exists():
        old = json.loads(man_path.read_text())
        diff = [k for k in man if old.get(k) != man[k]]
        if diff:
            raise ValueError(
                f"{out} holds results made with different settings ({', '.join(diff)}); "
                "use another --out folder (or delete it) to start a fresh sweep"
            )
    else:
        _write_json(man_path, man)

    todo, reused = [], 0
    for i in range(n):
        missing = [m for m in methods if not _row_path(out, i, m).exists()]
        reused += len(methods) - len(missing)
        if missing:
            todo.append((i, seed, params.to_dict(), missing, backend, str(out), config))

    t0 = time.perf_counter()
    computed = 0
    bar = tqdm(total=len(todo), desc="scenes", unit="scene", disable=not progress or not todo)
    if jobs <= 1 or len(todo) <= 1:
        for task in todo:
            computed += len(_scene_task(task))
            bar.update(1)
    else:
        env_old = os.environ.get("XLA_FLAGS")
        # one XLA thread per worker: the workers, not XLA, use the cores
        os.environ["XLA_FLAGS"] = (
            env_old + " " if env_old else ""
        ) + "--xla_cpu_multi_thread_eigen=false"
        try:
            ctx = mp.get_context("spawn")
            with cf.ProcessPoolExecutor(
                max_workers=min(jobs, len(todo)), mp_context=ctx, initializer=_worker_init
            ) as ex:
                futs = [ex.submit(_scene_task, t) for t in todo]
                for f in cf.as_completed(futs):
                    computed += len(f.result())
                    bar.update(1)
        finally:
            if env_old is None:
                os.environ.pop("XLA_FLAGS", None)
            else:
                os.environ["XLA_FLAGS"] = env_old
    bar.close()
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
    _write_json(
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
