"""Safety–progress frontier: every method's risk level swept over a grid of values.

Each method has one risk level, the target collision probability ε (:mod:`mmdopt.risk`).
:func:`run_frontier` plans every (scene, method, risk) and writes one JSON file per task into
``OUT/tasks/`` as soon as it is done (resumable, any executor of :mod:`.executors`), then
``OUT/frontier.csv`` (one row per task), ``OUT/frontier_summary.json`` (per (method, risk): mean /
LQ collision-free, mean progress, the collision rate measured on the validation futures pooled
over scenes with its 95 % Clopper–Pearson interval, the share of plans whose status is "ok" and
the mean :attr:`mmdopt.Plan.risk_bound`; and each method's progress interpolated at the target
levels) and ``OUT/frontier.png`` (:func:`frontier_axes`: the frontier and a calibration panel).
Folders written when the ``risk`` column was called ``knob`` are read with the old name mapped
to the new one, and rows written before ``compile_s`` existed get NaN there (not measured).

``plan_time_s`` is a plan's own time: the first plan of each worker process for a (method, risk)
(the plan's shapes: the number of futures n(ε) and the config depend on them, not on the scene)
is preceded by an untimed warm-up plan of the same scene with another key, which compiles the
programs; ``compile_s`` is how much longer that first call took than the timed plan (as
``mmdopt demo`` measures it), 0.0 in the rows of later tasks.  ``predict_time_s`` is the
predictor's draw of the plan's futures, which ``plan_time_s`` leaves out.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

import mmdopt
import mmdopt.methods
from mmdopt.algorithm import PLANNER_BACKEND
from mmdopt.risk import check_risk, config_for_risk

from .executors import MISSING, check_manifest, run_tasks, worker_layout
from .results import write_json, write_results
from .scenes import SceneParams, make_scene, num_scenes
from .synthetic import config_overrides, planning_samples, run_scene

__all__ = [
    "DEFAULT_RISK_GRID",
    "default_risks",
    "FRONTIER_COLUMNS",
    "TARGET_LEVELS",
    "parse_risks",
    "run_frontier",
    "frontier_points",
    "summarise_frontier",
    "interpolate_progress",
    "progress_at_level",
    "progress_within_budget",
    "DEFAULT_BUDGETS",
    "check_budget",
    "clopper_pearson_interval",
    "frontier_axes",
    "frontier_figure",
]

#: the default risk grid (target collision probability ε) of every method: down to 1e-5, so that
#: the printed target levels 995 and 999 lie inside the swept range (docs/experiments/frontier.md)
DEFAULT_RISK_GRID: tuple[float, ...] = (1e-5, 1e-4, 0.001, 0.005, 0.02, 0.1)
#: the plan-time budgets (s) of the matched-compute readout (``bench frontier --budgets``)
DEFAULT_BUDGETS: tuple[float, ...] = (0.1, 0.25, 1.0)


def default_risks(methods: Sequence[str]) -> dict[str, list[float]]:
    """The default grid of each method (a name of :func:`mmdopt.methods.names`)."""
    return {m: list(DEFAULT_RISK_GRID) for m in (mmdopt.methods.get(x).name for x in methods)}


#: columns of ``frontier.csv`` (the first eight are the outside contract)
FRONTIER_COLUMNS = (
    "method",
    "risk",
    "scene",
    "collision_free",
    "n_validation",
    "progress_m",
    "plan_time_s",
    "feasible",
    "n_samples",
    "mean_speed",
    "fallback",
    "status",
    "seed",
    "risk_bound",
    "n_planning",
    "predict_time_s",
    "compile_s",
)
#: target collision-free levels (of 1000) at which progress is interpolated
TARGET_LEVELS = (990.0, 995.0, 999.0)
#: the name the ``risk`` column had in older folders (task files and ``frontier.csv``)
OLD_RISK_COLUMN = "knob"
#: confidence of the measured collision rate's two-sided interval
RATE_CONFIDENCE = 0.95


def parse_risks(spec: str | None, methods: Sequence[str]) -> dict[str, list[float]]:
    """Risk grid per method from ``"0.1,0.02"`` (every method) or ``"mmd=0.001,0.005;saa=0.01"``
    (per method; the defaults for methods not named).  Raises ``ValueError`` for an unknown or
    unselected method or a risk outside (0, 0.5)."""
    risks = default_risks(methods)
    if not spec:
        return risks
    if "=" not in spec:
        return {m: _risk_grid(spec, m) for m in methods}
    for part in spec.split(";"):
        part = part.strip()
        if not part:
            continue
        if "=" not in part:
            raise ValueError(f"risks: expected METHOD=v1,v2,... got {part!r}")
        m, vals = (x.strip() for x in part.split("=", 1))
        if m not in mmdopt.methods.names():
            raise ValueError(
                f"risks: unknown method {m!r}; choose from {', '.join(mmdopt.methods.names())}"
            )
        if m not in methods:
            raise ValueError(f"risks: method {m!r} is not among --methods")
        risks[m] = _risk_grid(vals, m)
    return risks


def _risk_grid(vals: str, method: str) -> list[float]:
    """``"0.02,0.001"`` -> ``[0.001, 0.02]`` (each checked, duplicates dropped)."""
    grid = []
    for v in (v.strip() for v in vals.split(",")):
        if not v:
            continue
        try:
            x = float(v)
        except ValueError:
            raise ValueError(
                f"risks: {v!r} is not a number (expected v1,v2,... or METHOD=v1,v2,...;...)"
            ) from None
        try:
            grid.append(check_risk(x, f"risk of {method}"))
        except ValueError as e:
            raise ValueError(f"risks: {e}") from None
    if not grid:
        raise ValueError(f"risks: no values for {method!r}")
    return sorted(set(grid))


def _task_path(out: Path, scene: int, method: str, risk: float) -> Path:
    return out / "tasks" / f"scene_{scene:04d}__{method}__{risk:.6g}.json"


def _read_task(path: Path) -> dict[str, Any]:
    """One task's row; a row of an older folder has its ``knob`` renamed ``risk`` in place and
    NaN as its ``compile_s`` (written before the compile was measured apart)."""
    row = json.loads(path.read_text())
    if OLD_RISK_COLUMN in row and "risk" not in row:
        row = {("risk" if k == OLD_RISK_COLUMN else k): v for k, v in row.items()}
    row.setdefault("compile_s", math.nan)
    return row


#: what the compiled programs of a plan depend on, for each one this process has planned:
#: (method, risk, backend, forecast, scene parameters, config); the first plan of each is
#: preceded by a warm-up (:func:`_warm_up`)
_WARM: set[tuple[Any, ...]] = set()


def _warm_up(scene, method: str, config, backend: str, forecast: bool) -> float:
    """Plan ``scene`` as :func:`~mmdopt.bench.synthetic.run_scene` does, with another key (the
    same shapes: the same compiled programs, without repeating the timed computation), untimed;
    returns that call's plan time, which includes the JIT compile."""
    import jax

    from .synthetic import forecast_cap, plan_scene, scene_config

    obstacles = None
    if forecast:
        cap = forecast_cap(method)
        obstacles = scene.forecast(min_samples=scene.params.n_samples, max_samples=cap)
    plan, _, wall = plan_scene(
        scene,
        method,
        config=scene_config(scene, config),
        backend=backend,
        key=jax.random.fold_in(scene.key(), 1),
        obstacles=obstacles,
    )
    return float(getattr(plan, "plan_time_s", wall))


def _frontier_task(args) -> int:
    """Worker: scene ``index``, plan every missing (method, risk), one file per plan; the first
    plan of this process for a (method, risk) gets its compile apart (``compile_s``)."""
    index, seed, params_dict, todo, backend, out, config, forecast = args
    scene = make_scene(index, seed, SceneParams.from_dict(params_dict))
    done = 0
    for method, risk in todo:
        path = _task_path(Path(out), index, method, risk)
        if path.exists():
            continue
        cfg = config_for_risk(method, risk, config)
        shapes = (method, float(risk), backend, bool(forecast),
                  json.dumps(params_dict, sort_keys=True, default=str), repr(cfg))  # fmt: skip
        first = shapes not in _WARM
        if first:
            warm_s = _warm_up(scene, method, cfg, backend, forecast)
            _WARM.add(shapes)
        row, _ = run_scene(scene, method, config=cfg, backend=backend, forecast=forecast)
        compile_s = max(0.0, warm_s - float(row["plan_time_s"])) if first else 0.0
        row.update(risk=float(risk), seed=int(seed), compile_s=compile_s)
        write_json(path, row)
        done += 1
    return done


def run_frontier(
    out: str | Path,
    *,
    risks: Mapping[str, Sequence[float]] | None = None,
    methods: Sequence[str] | None = None,
    scenes: int | None = None,
    seed: int = 0,
    params: SceneParams | None = None,
    backend: str = PLANNER_BACKEND,
    config: mmdopt.MMDOptConfig | None = None,
    jobs: int = 1,
    executor: str = "local",
    address: str | None = None,
    progress: bool = True,
    levels: Sequence[float] = TARGET_LEVELS,
    isolate: bool = False,
    forecast: bool = False,
    budgets: Sequence[float] = DEFAULT_BUDGETS,
) -> dict[str, Any]:
    """Sweep every method's risk level on the scenes; resumable (existing task files are reused;
    ``risks``: the grid per method, default :data:`DEFAULT_RISK_GRID`).  ``forecast=True`` plans
    through the scene's predictor (:meth:`~mmdopt.bench.scenes.Scene.forecast`): n(ε) futures
    per (scene, ε), at least ``params.n_samples`` and at most
    :func:`~mmdopt.bench.synthetic.forecast_cap` (5000; 50 000 for MMD-Opt); ``False``
    on the scene's ``params.n_samples`` fixed samples (the CLI's ``--n-samples N``).  ``isolate``
    as in
    :func:`~mmdopt.bench.executors.run_tasks`: ``True`` (the CLI) plans every task in a worker
    process with one XLA thread, so the rows do not depend on ``jobs`` or the executor; the
    manifest records where results were computed and a folder refuses a mix.

    ``budgets`` (s): the plan-time budgets of the matched-compute readout ``at_budget``
    (:func:`progress_within_budget`).

    Returns ``{"rows", "points", "interpolated", "at_level", "at_level_kept", "at_budget",
    "computed", "reused", "wall_s"}`` (``at_level``: :func:`progress_at_level`, the measured
    points only; ``at_level_kept``: the same over the risk levels whose plans kept the request;
    ``at_budget``: per budget, the same over the risk levels whose median plan time is within
    it).
    """
    budgets = [check_budget(b) for b in budgets]
    params = SceneParams() if params is None else params
    n = num_scenes(params, scenes)
    methods = list(dict.fromkeys(methods))
    bad = [m for m in methods if m not in mmdopt.methods.names()]
    if bad or not methods:
        raise ValueError(f"methods must be among {mmdopt.methods.names()}, got {methods}")
    risks = default_risks(methods) if risks is None else dict(risks)
    for m in methods:
        if m not in risks or not risks[m]:
            raise ValueError(f"no risk values for method {m!r}")
        risks[m] = [check_risk(k, f"risk of {m}") for k in risks[m]]
    out = Path(out)
    (out / "tasks").mkdir(parents=True, exist_ok=True)
    check_manifest(
        out,
        dict(
            seed=int(seed),
            params=params.to_dict(),
            backend=backend,
            config=config_overrides(config),
            workers=worker_layout(jobs, executor, isolate),
            # also inside ``params``; named on their own so a refusal names them
            n_validation=params.n_validation,
            n_samples=params.n_samples,
            planning_samples=planning_samples(forecast),
        ),
        # folders written before the manifest recorded them (with the fixed samples)
        aliases={
            "workers": [MISSING],
            "n_validation": [MISSING],
            "n_samples": [MISSING],
            "planning_samples": [] if forecast else [MISSING],
        },
    )
    pairs = [(m, k) for m in methods for k in risks[m]]
    tasks, reused = [], 0
    for i in range(n):
        todo = [(m, k) for m, k in pairs if not _task_path(out, i, m, k).exists()]
        reused += len(pairs) - len(todo)
        if todo:
            tasks.append((i, seed, params.to_dict(), todo, backend, str(out), config, forecast))
    t0 = time.perf_counter()
    done = run_tasks(
        _frontier_task,
        tasks,
        jobs=jobs,
        executor=executor,
        address=address,
        progress=progress,
        desc="frontier scenes",
        unit="scene",
        isolate=isolate,
    )
    wall = time.perf_counter() - t0
    rows = []
    for i in range(n):
        for m, k in pairs:
            rows.append(_read_task(_task_path(out, i, m, k)))
    write_results(rows, out / "frontier.csv", FRONTIER_COLUMNS)
    summary = summarise_frontier(rows, methods, levels, budgets)
    write_json(
        out / "frontier_summary.json",
        dict(summary, scenes=n, seed=seed, params=params.to_dict()),
    )
    frontier_figure(summary["points"], out / "frontier.png", title=f"{n} scenes, seed {seed}")
    return dict(
        rows=rows,
        **summary,
        computed=int(sum(done)),
        reused=reused,
        wall_s=wall,
    )


def summarise_frontier(
    rows: Sequence[Mapping[str, Any]],
    methods: Sequence[str],
    levels: Sequence[float] = TARGET_LEVELS,
    budgets: Sequence[float] = DEFAULT_BUDGETS,
) -> dict[str, Any]:
    """The readouts of a frontier's rows: ``points`` (:func:`frontier_points`), progress at each
    target level ``interpolated`` along the frontier, ``at_level`` (measured points only),
    ``at_level_kept`` (over the risk levels whose plans kept the request) and ``at_budget`` (per
    plan-time budget, over the risk levels within it: :func:`progress_within_budget`)."""
    points = frontier_points(rows)
    return dict(
        points=points,
        interpolated={m: interpolate_progress(points, m, levels) for m in methods},
        at_level={m: progress_at_level(points, m, levels) for m in methods},
        at_level_kept={m: progress_at_level(points, m, levels, KEPT_SHARE) for m in methods},
        at_budget={
            f"{b:g}": {m: progress_within_budget(points, m, b, levels) for m in methods}
            for b in budgets
        },  # fmt: skip
    )


def frontier_points(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per (method, risk): scenes, mean / LQ / min collision-free (scaled to 1000 validation
    samples), mean progress (m), median plan time (s), feasible share, median planning futures
    per obstacle (``n_planning``); the measured collision
    rate pooled over scenes (``collisions`` of ``validation`` futures, ``rate``) with its 95 %
    Clopper–Pearson interval (``rate_lo``, ``rate_hi``); the share of plans whose status begins
    with "ok" (``ok_share``) and the mean :attr:`mmdopt.Plan.risk_bound` (``risk_bound``); NaN
    where the rows lack the column (older folders).  Sorted by method, risk.  Rows of an older
    folder may name the risk ``knob``."""
    groups: dict[tuple[str, float], list] = {}
    for r in rows:
        risk = r["risk"] if "risk" in r else r[OLD_RISK_COLUMN]
        groups.setdefault((r["method"], float(risk)), []).append(r)
    pts = []
    for (m, k), rs in sorted(groups.items()):
        cf = np.array([1000.0 * float(r["collision_free"]) / float(r["n_validation"]) for r in rs])
        pts.append(
            dict(
                method=m,
                risk=k,
                scenes=len(rs),
                mean=float(cf.mean()),
                q1=float(np.percentile(cf, 25)),
                min=float(cf.min()),
                progress_m=float(np.mean([float(r["progress_m"]) for r in rs])),
                plan_time_s=float(np.median([float(r["plan_time_s"]) for r in rs])),
                feasible=float(np.mean([bool(r["feasible"]) for r in rs])),
                n_planning=float(
                    np.median([_num(r.get("n_planning", r.get("n_samples"))) for r in rs])
                ),
                **_measured(rs),
            )
        )
    return pts


def _measured(rs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Pooled measured collision rate with its interval, ok share and mean risk bound."""
    nv = sum(int(r["n_validation"]) for r in rs)
    k = nv - sum(int(r["collision_free"]) for r in rs)
    lo, hi = clopper_pearson_interval(k, nv, RATE_CONFIDENCE)
    status = [str(r["status"]) for r in rs if r.get("status") not in (None, "")]
    bounds = [_num(r.get("risk_bound")) for r in rs]
    bounds = [b for b in bounds if math.isfinite(b)]
    return dict(
        collisions=int(k),
        validation=int(nv),
        rate=k / nv,
        rate_lo=lo,
        rate_hi=hi,
        ok_share=float(np.mean([t.startswith("ok") for t in status])) if status else math.nan,
        risk_bound=float(np.mean(bounds)) if bounds else math.nan,
    )


def _num(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def clopper_pearson_interval(
    k: int, n: int, confidence: float = RATE_CONFIDENCE
) -> tuple[float, float]:
    """Two-sided Clopper–Pearson interval at ``confidence`` on a probability seen ``k`` times in
    ``n`` independent trials: the ``α/2`` quantile of Beta(k, n − k + 1) (0 when ``k = 0``) and
    the ``1 − α/2`` quantile of Beta(k + 1, n − k) (1 when ``k = n``), α = 1 − confidence."""
    from scipy.stats import beta

    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or not 0 <= k <= n:
        raise ValueError(f"k must be an integer in [0, n={n}], got {k!r}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    a = 1.0 - confidence
    lo = 0.0 if k == 0 else float(beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def interpolate_progress(
    points: Sequence[Mapping[str, Any]], method: str, levels: Sequence[float] = TARGET_LEVELS
) -> dict[str, float]:
    """``method``'s progress (m) at each target mean collision-free level: the most progress on
    its piecewise-linear frontier (risk points joined in order of safety) with mean ≥ level;
    NaN where no point of the sweep reaches the level."""
    pts = sorted(
        ((p["mean"], p["progress_m"]) for p in points if p["method"] == method),
        key=lambda x: x[0],
    )
    res = {}
    for lv in levels:
        best = -math.inf
        for c, prog in pts:
            if c >= lv:
                best = max(best, prog)
        for (c0, p0), (c1, p1) in zip(pts, pts[1:], strict=False):
            if c0 < lv <= c1 and c1 > c0:
                best = max(best, p0 + (p1 - p0) * (lv - c0) / (c1 - c0))
        res[f"{lv:g}"] = best if math.isfinite(best) else float("nan")
    return res


#: the share of a risk level's plans whose status is ok for the level to count as kept
KEPT_SHARE = 0.95


def progress_at_level(
    points: Sequence[Mapping[str, Any]],
    method: str,
    levels: Sequence[float] = TARGET_LEVELS,
    min_ok_share: float | None = None,
) -> dict[str, float]:
    """``method``'s progress (m) at each target mean collision-free level, measured points only:
    the most mean progress among its risk levels whose mean collision-free count reaches the
    level (no interpolation between risk levels); NaN where none reaches it.  With
    ``min_ok_share`` only risk levels where at least that share of the plans kept the request
    (status ok: :attr:`mmdopt.Plan.risk_bound` ≤ ε) count (summary key ``at_level_kept``, at
    :data:`KEPT_SHARE`)."""
    if min_ok_share is not None and not 0.0 <= float(min_ok_share) <= 1.0:
        raise ValueError(f"min_ok_share must be in [0, 1], got {min_ok_share!r}")
    pts = [
        (p["mean"], p["progress_m"])
        for p in points
        if p["method"] == method
        and (min_ok_share is None or float(p.get("ok_share", math.nan)) >= float(min_ok_share))
    ]
    res = {}
    for lv in levels:
        reached = [prog for c, prog in pts if c >= lv]
        res[f"{lv:g}"] = max(reached) if reached else float("nan")
    return res


def check_budget(b: Any) -> float:
    """A plan-time budget: a positive finite number of seconds (``ValueError`` otherwise)."""
    if isinstance(b, bool) or not isinstance(b, int | float) or not 0 < b < math.inf:
        raise ValueError(f"a budget must be a positive number of seconds, got {b!r}")
    return float(b)


def progress_within_budget(
    points: Sequence[Mapping[str, Any]],
    method: str,
    budget: float,
    levels: Sequence[float] = TARGET_LEVELS,
) -> dict[str, float]:
    """Progress at matched compute: :func:`progress_at_level` over only those of ``method``'s
    risk levels whose median plan time (``plan_time_s``, without the compile and the
    predictor's draw) is within ``budget`` seconds; NaN where none within the budget reaches the
    level."""
    budget = check_budget(budget)
    within = [p for p in points if p["method"] == method and float(p["plan_time_s"]) <= budget]
    return progress_at_level(within, method, levels)


#: markers per method (in order of appearance) of :func:`frontier_axes`
_MARKERS = ("o", "s", "^", "D", "v", "P", "X")


def _zero_floor(values: Sequence[float], default: float) -> float:
    """Where a zero is drawn on a log axis: ``default``, or a power of ten below the least
    positive value when that is not above ``default``."""
    pos = [v for v in values if v > 0 and math.isfinite(v)]
    if not pos or min(pos) > default:
        return default
    return 10.0 ** (math.floor(math.log10(min(pos))) - 1)


def _PlainLogFormatter(**kw):
    """matplotlib's ``LogFormatter`` (which minor ticks it labels) printing ``f"{v:g}"``."""
    from matplotlib.ticker import LogFormatter

    class Plain(LogFormatter):
        def _num_to_string(self, x, vmin, vmax):
            return f"{x:g}"

    return Plain(**kw)


def frontier_axes(points: Sequence[Mapping[str, Any]], title: str = ""):
    """The frontier figure of :func:`frontier_points` ``points`` as an open matplotlib figure
    with three axes (the third: progress at 995 and 999 within a plan-time budget,
    :func:`progress_within_budget`).  Left: collisions per 1000 validation futures
    (``1000 − mean``, log axis; a zero is drawn at a floor named in the axis label) against
    mean progress, one line per method through its risk points (ε named at both ends of each
    line).  Middle: calibration, the requested ε against the measured collision rate pooled over
    scenes, with its 95 % Clopper–Pearson interval and the line measured = requested."""
    from .plots import method_colour
    from .plots import method_label as _label
    from .plots import pyplot as _plt

    if not points:
        raise ValueError("points must not be empty")
    plt = _plt()
    fig, (ax, cal, cmp) = plt.subplots(1, 3, figsize=(17, 4.8))
    methods = list(dict.fromkeys(p["method"] for p in points))
    per = {m: sorted((p for p in points if p["method"] == m), key=lambda p: p["risk"])
           for m in methods}  # fmt: skip
    coll = {m: [max(1000.0 - p["mean"], 0.0) for p in ps] for m, ps in per.items()}
    floor = _zero_floor([c for cs in coll.values() for c in cs], 0.01)
    rfloor = _zero_floor([p["rate"] for p in points], floor / 1000.0)
    # the grid most methods share is named in the title; ends of other grids are annotated
    grids = {m: tuple(p["risk"] for p in ps) for m, ps in per.items()}
    common = max(grids.values(), key=list(grids.values()).count)
    spread = 10.0 ** (0.04 * (np.arange(len(methods)) - (len(methods) - 1) / 2))
    for j, m in enumerate(methods):
        ps, colour = per[m], method_colour(m)
        style = dict(marker=_MARKERS[j % len(_MARKERS)], color=colour, label=_label(m))
        x = [p["progress_m"] for p in ps]
        y = [max(c, floor) for c in coll[m]]
        ax.plot(x, y, ms=5, **style)
        for p, xy, side in ((ps[0], (x[0], y[0]), -1), (ps[-1], (x[-1], y[-1]), 1)):
            if grids[m] == common or (side == 1 and len(ps) == 1):
                continue
            ax.annotate(f"ε={p['risk']:g}", xy, fontsize=7, color=colour,
                        xytext=(4 * side, 6 if j % 2 else -10), textcoords="offset points",
                        ha="left" if side == 1 else "right")  # fmt: skip
        eps = np.array([p["risk"] for p in ps]) * spread[j]
        rate = np.array([max(p["rate"], rfloor) for p in ps])
        lo = np.array([max(p["rate_lo"], rfloor) for p in ps])
        hi = np.array([max(p["rate_hi"], rfloor) for p in ps])
        cal.errorbar(eps, rate, yerr=[rate - lo, hi - rate], capsize=3, ms=5, lw=1, **style)
    ax.set_yscale("log")
    # 0.01, 5, 40 rather than 10^x; minor ticks labelled only on short ranges, as matplotlib's
    ax.yaxis.set_major_formatter(plt.FuncFormatter(lambda v, _: f"{v:g}"))
    ax.yaxis.set_minor_formatter(_PlainLogFormatter(labelOnlyBase=False))
    zero = any(c <= 0 for cs in coll.values() for c in cs)
    if zero:
        ax.axhline(floor, color="0.6", lw=0.8, ls=":")
    ax.set_xlabel("mean progress in 15 s (m)")
    ax.set_ylabel(
        "collisions per 1000 validation futures\n(log; lower is safer"
        + (f"; 0 drawn at {floor:g})" if zero else ")")
    )
    ends = f"ε = {common[0]:g} … {common[-1]:g}" if len(common) > 1 else f"ε = {common[0]:g}"
    ax.set_title(
        f"safety–progress frontier (best: bottom right)\none marker per risk level, {ends}",
        fontsize=10,
    )
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="best", framealpha=0.85)
    req = [p["risk"] for p in points]
    lim = [min(min(req), rfloor) / 2, max(max(req), max(p["rate_hi"] for p in points)) * 2]
    cal.plot(lim, lim, color="k", lw=0.8, ls="--", label="measured = requested")
    rzero = any(p["rate"] <= 0 for p in points)
    if rzero:
        cal.axhline(rfloor, color="0.6", lw=0.8, ls=":")
    cal.set_xscale("log")
    cal.set_yscale("log")
    cal.set_xlim(min(req) / 3, max(req) * 3)
    cal.set_ylim((rfloor if rzero else min(p["rate_lo"] for p in points)) / 2, lim[1])
    cal.set_xlabel("requested risk ε (log)")
    cal.set_ylabel(
        "measured collision rate, pooled over scenes\n(log"
        + (f"; 0 drawn at {rfloor:g})" if rzero else ")")
    )
    cal.set_title("calibration: bars are 95 % Clopper–Pearson intervals", fontsize=10)
    cal.grid(alpha=0.3)
    (diag,) = [h for h in cal.lines if h.get_label() == "measured = requested"]
    cal.legend(handles=[diag], fontsize=7, loc="upper left")
    _budget_axes(cmp, points, methods)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def _budget_axes(ax, points: Sequence[Mapping[str, Any]], methods: Sequence[str]) -> None:
    """Matched compute: per method, the most progress that reaches 995 (solid) and 999 (dashed)
    collision-free per 1000 within a plan-time budget, as the budget grows (a step at each of its
    risk levels' median plan times)."""
    from .plots import method_colour
    from .plots import method_label as _label

    times = sorted({float(p["plan_time_s"]) for p in points if float(p["plan_time_s"]) > 0})
    if not times:
        ax.set_axis_off()
        return
    grid = np.geomspace(times[0] / 1.5, times[-1] * 1.5, 200)
    drawn = False
    for m in methods:
        for lv, ls in ((995.0, "-"), (999.0, "--")):
            y = [progress_within_budget(points, m, b, (lv,))[f"{lv:g}"] for b in grid]
            if all(math.isnan(v) for v in y):
                continue
            ax.step(grid, y, where="post", ls=ls, color=method_colour(m),
                    label=f"{_label(m)}, {lv:g}")  # fmt: skip
            drawn = True
    ax.set_xscale("log")
    ax.set_xlabel("plan-time budget: median plan_time_s (s, log)")
    ax.set_ylabel("mean progress at the level (m)")
    ax.set_title("matched compute: progress at 995 (solid) and 999 (dashed)\nwithin a budget",
                 fontsize=10)  # fmt: skip
    ax.grid(alpha=0.3, which="both")
    if drawn:
        ax.legend(fontsize=6, loc="best", framealpha=0.85)


def frontier_figure(points: Sequence[Mapping[str, Any]], path: str | Path, title: str = "") -> Path:
    """Save :func:`frontier_axes` of ``points`` to ``path`` (PNG)."""
    from .plots import pyplot as _plt

    fig = frontier_axes(points, title)
    path = Path(path)
    fig.savefig(path, dpi=120)
    _plt().close(fig)
    return path
