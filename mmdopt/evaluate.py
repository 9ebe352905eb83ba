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
    ``|v_d| ≤ vy_max``, ``|a_s| ≤ ax_max``, ``|a_d| ≤ ay_max`` (bounds from ``road`` where it has
    them; otherwise 0 and 30 m/s, 18 m/s² as the reference) and finiteness (non-finite plans
    score ``inf``).
    """
    arr = lambda n: np.asarray(getattr(plan, n), dtype=np.float64)  # noqa: E731
    names = [n for n in ("s", "d", "vs", "vd", "as_", "ad") if hasattr(plan, n)]
    vals = {n: arr(n) for n in names}
    if not all(np.all(np.isfinite(v)) for v in vals.values()):
        return math.inf
    lo = _bound(road, ("y_lb",), -np.inf) if y_lb is None else float(y_lb)
    hi = _bound(road, ("y_ub",), np.inf) if y_ub is None else float(y_ub)
    d, vs = vals["d"], vals["vs"]
    viol = [
        np.max(lo - d),
        np.max(d - hi),
        np.max(_bound(road, ("v_min",), 0.0) - vs),
        np.max(vs - _bound(road, ("v_max",), 30.0)),
    ]
    limits = {
        "vd": _bound(road, ("vy_max",), np.inf),
        "as_": _bound(road, ("ax_max", "a_max"), 18.0),
        "ad": _bound(road, ("ay_max", "a_max"), 18.0),
    }
    viol += [np.max(np.abs(vals[n])) - lim for n, lim in limits.items() if n in vals]
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


# ---------------------------------------------------------------------------------------------
# Algorithm 1 config helpers (field names of helper E's MMDOptConfig)

_REDUCED_SIZE_FIELDS = ("num_reduced", "n_reduced", "reduced_set_size", "m")


def with_reduced_set_size(config, m: int):
    """``config`` with reduced-set size ``m`` (whichever field name the config uses)."""
    for name in _REDUCED_SIZE_FIELDS:
        if _has_field(config, name):
            return config.replace(**{name: int(m)})
    raise ValueError(f"{type(config).__name__} has no reduced-set size field")


def _block(plan) -> None:
    np.asarray(plan.x)


def _time_calls(fn, key, repeats: int) -> tuple[float, float]:
    """``(first call, median of repeats)`` wall time (s) of ``fn(key)`` (a fresh key each call)."""
    import jax

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


# ---------------------------------------------------------------------------------------------
# experiment 3: computation time (paper Table II)

TIMING_COLUMNS = (
    "reduced_set_size",
    "reduced_set_s",
    "algorithm1_s",
    "compile_s",
    "n_samples",
    "backend",
)


def run_timing(
    out: str | Path,
    *,
    sizes: Sequence[int] = (10, 20, 30, 40, 50),
    samples: Sequence[int] = (50, 100, 200),
    repeats: int = 5,
    backend: str = "admm",
    config=None,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Median wall time of reduced-set selection, of Algorithm 1 (the CEM loop,
    ``plan.diagnostics["cem_s"]``) and of the whole ``mmdopt.plan`` call (``plan_s``) per
    reduced-set size ``m`` (at n = 100 samples) and per sample count n (at the smallest m), on
    the demo scene; ``compile_s`` is Algorithm 1's first-call extra time (jit compilation).
    Writes ``out/timing.csv`` (:data:`TIMING_COLUMNS` + first-call and plan times) and
    ``out/timing.png``.
    """
    import jax
    from tqdm.auto import tqdm

    import mmdopt

    from . import plots
    from .reduced_set import ReducedSetConfig, select_reduced_set
    from .scenarios import demo_scene, make_scene

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    base = demo_scene()
    n_def = 100
    pairs = [(int(m), n_def) for m in sizes] + [(min(sizes), int(n)) for n in samples]
    pairs = [p for p in dict.fromkeys(pairs) if p[0] <= p[1]]
    cfg0 = scene_config(base, config)
    rows = []
    scenes: dict[int, Scene] = {}
    for m, n in tqdm(pairs, desc="timing", disable=not progress):
        if n not in scenes:
            scenes[n] = make_scene(base.index, base.seed, base.params.replace(n_samples=n))
        sc = scenes[n]
        key = sc.key()
        obs = jax.numpy.asarray(sc.obstacles[0])
        rs_cfg = ReducedSetConfig()
        rs_first, rs_med = _time_calls(
            lambda k, obs=obs, m=m, c=rs_cfg: select_reduced_set(k, obs, m, "mmd", c).weights,
            key,
            repeats,
        )
        cfg = with_reduced_set_size(cfg0, m)
        cem_times: list[float] = []

        def one_plan(k, sc=sc, cfg=cfg, sink=cem_times):
            p = mmdopt.plan(
                sc.ego(), sc.road(), sc.obstacles, method="mmd", config=cfg, backend=backend, key=k
            )
            sink.append(float(p.diagnostics["cem_s"]))
            return p.x

        p_first, p_med = _time_calls(one_plan, key, repeats)
        # Algorithm 1 = the CEM loop alone (plan.diagnostics["cem_s"]); the whole plan() call
        # (+ Frenet conversion, its own reduced-set selection, assembling the plan) is plan_s
        a_first, a_med = cem_times[0], float(np.median(cem_times[1:]))
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
                plan_s=p_med,
                plan_first_s=p_first,
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
    with open(out / "timing.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        w.writerows(rows)
    plots.timing_figure(rows, out / "timing.png")
    return rows


# ---------------------------------------------------------------------------------------------
# experiment 2: reduced-set selection vs random reduced sets (paper Fig. 4)

REDUCED_SET_COLUMNS = (
    "scene",
    "selection",
    "draw",
    "collision_free",
    "n_validation",
    "progress_m",
    "feasible",
    "rs_mmd2",
    "plan_time_s",
)


def plan_with_reduced_set(scene: Scene, reduced, *, config=None, backend="admm"):
    """Algorithm 1 with the MMD surrogate on a *given* reduced set (a single-obstacle
    :class:`~mmdopt.reduced_set.ReducedSet`): ``(plan, wall_s)``.

    ``mmdopt.plan`` selects its reduced set itself; for this experiment the selection step is
    swapped for the given set (``mmdopt.api.select_reduced_sets`` is replaced for the duration of
    the call), everything else - weights ᾱ, cost, optimiser, key - is the same as MMD-Opt's.
    """
    import jax

    import mmdopt
    from mmdopt import api

    batched = jax.tree_util.tree_map(lambda x: jax.numpy.asarray(x)[None], reduced)
    cfg = scene_config(scene, config)
    orig = api.select_reduced_sets
    api.select_reduced_sets = lambda *a, **k: batched
    try:
        t0 = time.perf_counter()
        plan = mmdopt.plan(
            scene.ego(),
            scene.road(),
            scene.obstacles,
            method="mmd",
            config=cfg,
            backend=backend,
            key=scene.key(),
        )
        _block(plan)
    finally:
        api.select_reduced_sets = orig
    return plan, time.perf_counter() - t0


def _reduced_set_task(args) -> list[dict[str, Any]]:
    index, seed, params_dict, methods, random_sets, backend, out, config = args
    import jax

    from .reduced_set import ReducedSetConfig, select_reduced_set

    params = SceneParams.from_dict(params_dict)
    scene = make_scene(index, seed, params)
    path = Path(out) / "scenes" / f"scene_{index:04d}__reduced_set.json"
    if path.exists():
        return []
    cfg = scene_config(scene, config)
    m = _reduced_size(cfg)
    obs = scene.obstacles[0]
    key = scene.key()
    rs_cfg = getattr(cfg, "reduced_set", None)
    rs_cfg = rs_cfg if isinstance(rs_cfg, ReducedSetConfig) else ReducedSetConfig()
    ego_guess = np.stack([scene.params.ego_speed * scene.t, np.zeros_like(scene.t)], -1)
    jobs = [(meth, 0) for meth in methods if meth != "random"]
    jobs += [("random", r) for r in range(random_sets if "random" in methods else 0)]
    rows = []
    # the selection's features as in mmdopt.plan (an anisotropic kernel when the config has one)
    lam = float(getattr(cfg, "rs_lateral_scale", 1.0))
    feats = obs * np.array([1.0, lam])
    for meth, r in jobs:
        k = jax.random.fold_in(key, 1000 + r)
        if meth == "degroot":
            rs = select_reduced_set(k, obs, m, meth, rs_cfg, ego_guess=ego_guess)
        else:
            rs = select_reduced_set(k, feats, m, meth, rs_cfg)
        plan, wall = plan_with_reduced_set(scene, rs, config=cfg, backend=backend)
        xy = np.stack([np.asarray(plan.x), np.asarray(plan.y)], -1)
        rows.append(
            dict(
                scene=index,
                selection=meth,
                draw=r,
                collision_free=collision_free(xy, scene.validation),
                n_validation=int(scene.validation.shape[1]),
                progress_m=progress(plan),
                feasible=bool(getattr(plan, "feasible", True)),
                rs_mmd2=float(rs.mmd2),
                plan_time_s=_float(getattr(plan, "plan_time_s", wall)),
                x0=scene.x0,
                y0=scene.y0,
                p=scene.p,
            )
        )
    _write_json(path, rows)
    return rows


def _reduced_size(cfg) -> int:
    for name in _REDUCED_SIZE_FIELDS:
        if _has_field(cfg, name):
            return int(getattr(cfg, name))
    return 10


def run_reduced_set(
    out: str | Path,
    *,
    scenes: int = 20,
    seed: int = 0,
    params: SceneParams | None = None,
    methods: Sequence[str] = ("mmd", "herding", "degroot", "random"),
    random_sets: int = 20,
    backend: str = "admm",
    jobs: int = 1,
    config=None,
    progress: bool = True,
) -> dict[str, Any]:
    """Reduced-set selection methods and ``random_sets`` random reduced sets per scene (the
    paper's near-exhaustive search), each followed by Algorithm 1 with the MMD surrogate;
    collision-free validation counts per (scene, selection, draw).  Resumable (one JSON per
    scene in ``out/scenes/``); writes ``out/reduced_set.csv``, ``out/reduced_set_summary.json``
    and ``out/reduced_set.png``.
    """
    from tqdm.auto import tqdm

    from . import plots

    params = SceneParams() if params is None else params
    n = num_scenes(params, scenes)
    out = Path(out)
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    man = _manifest(seed, params, backend, config)
    man.update(methods=list(methods), random_sets=int(random_sets))
    man_path = out / "run_reduced_set.json"
    if man_path.exists():
        old = json.loads(man_path.read_text())
        diff = [k for k in man if old.get(k) != man[k]]
        if diff:
            raise ValueError(
                f"{out} holds reduced-set results made with different settings "
                f"({', '.join(diff)}); use another --out folder"
            )
    else:
        _write_json(man_path, man)
    todo = [
        (i, seed, params.to_dict(), list(methods), random_sets, backend, str(out), config)
        for i in range(n)
        if not (out / "scenes" / f"scene_{i:04d}__reduced_set.json").exists()
    ]
    bar = tqdm(total=len(todo), desc="scenes", unit="scene", disable=not progress or not todo)
    if jobs <= 1 or len(todo) <= 1:
        for t in todo:
            _reduced_set_task(t)
            bar.update(1)
    else:
        ctx = mp.get_context("spawn")
        with cf.ProcessPoolExecutor(
            max_workers=min(jobs, len(todo)), mp_context=ctx, initializer=_worker_init
        ) as ex:
            for f in cf.as_completed([ex.submit(_reduced_set_task, t) for t in todo]):
                f.result()
                bar.update(1)
    bar.close()
    rows = []
    for i in range(n):
        rows += json.loads((out / "scenes" / f"scene_{i:04d}__reduced_set.json").read_text())
    with open(out / "reduced_set.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(REDUCED_SET_COLUMNS) + ["x0", "y0", "p"])
        w.writeheader()
        w.writerows(rows)
    sel = [m for m in methods if m != "random"]
    per_scene = {
        m: [
            next(r["collision_free"] for r in rows if r["scene"] == i and r["selection"] == m)
            for i in range(n)
        ]
        for m in sel
    }
    rnd = [
        [r["collision_free"] for r in rows if r["scene"] == i and r["selection"] == "random"]
        for i in range(n)
    ]
    nv = rows[0]["n_validation"] if rows else 1

    def prog(sel_name):
        return float(np.mean([r["progress_m"] for r in rows if r["selection"] == sel_name]))

    def mmd2(sel_name):
        return float(np.mean([r["rs_mmd2"] for r in rows if r["selection"] == sel_name]))

    table = []
    for m in sel:
        a = np.asarray(per_scene[m], float)
        table.append(
            dict(
                selection=m,
                mean_pct=a.mean() / nv * 100,
                std_pct=a.std() / nv * 100,
                min=a.min(),
                progress_m=prog(m),
                rs_mmd2=mmd2(m),
                scenes=n,
            )
        )
    if any(rnd):
        mean_r = np.array([np.mean(r) for r in rnd]) / nv * 100
        best_r = np.array([np.max(r) for r in rnd]) / nv * 100
        table.append(
            dict(
                selection=f"random x{random_sets} (mean)",
                mean_pct=mean_r.mean(),
                std_pct=mean_r.std(),
                min=float(np.min([np.min(r) for r in rnd])),
                progress_m=prog("random"),
                rs_mmd2=mmd2("random"),
                scenes=n,
            )
        )
        table.append(
            dict(
                selection=f"random x{random_sets} (best, oracle)",
                mean_pct=best_r.mean(),
                std_pct=best_r.std(),
                min=float(np.min([np.max(r) for r in rnd])),
                scenes=n,
            )
        )
        if "mmd" in per_scene:
            a = np.asarray(per_scene["mmd"], float)
            frac = [np.mean(a[i] >= np.asarray(rnd[i])) for i in range(n)]
            table.append(
                dict(
                    selection="mmd >= random set (share)",
                    mean_pct=float(np.mean(frac)) * 100,
                    std_pct=float(np.std(frac)) * 100,
                    min=float(np.min(frac)),
                    scenes=n,
                )
            )
    _write_json(
        out / "reduced_set_summary.json",
        dict(table=table, scenes=n, seed=seed, random_sets=random_sets, params=params.to_dict()),
    )
    if any(rnd) and sel:
        plots.reduced_set_figure(per_scene, rnd, out / "reduced_set.png", n_validation=nv)
    return dict(rows=rows, table=table)


# ---------------------------------------------------------------------------------------------
# qp-backends: benchmarks/qp_backends.py


def load_qp_backends_benchmark():
    """Import ``benchmarks/qp_backends.py`` (as ``benchmarks.qp_backends`` if importable, else
    from the repository checkout next to this package).  Raises ``ImportError`` if absent."""
    import importlib
    import importlib.util

    try:
        return importlib.import_module("benchmarks.qp_backends")
    except ImportError:
        pass
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "qp_backends.py"
    if not path.is_file():
        raise ImportError(
            "benchmarks/qp_backends.py was not found (it ships with the repository checkout, "
            "not the installed package); run from a clone of the repository"
        )
    spec = importlib.util.spec_from_file_location("benchmarks_qp_backends", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
