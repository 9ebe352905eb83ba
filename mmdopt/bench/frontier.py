"""Safety–progress frontier: every method's risk level swept over a grid of values.

Each method has one risk level, the target collision probability ε (:mod:`mmdopt.risk`).
:func:`run_frontier` plans every (scene, method, risk) and writes one JSON file per task into
``OUT/tasks/`` as soon as it is done (resumable, any executor of :mod:`.executors`), then
``OUT/frontier.csv`` (one row per task), ``OUT/frontier_summary.json`` (mean / LQ collision-free
and mean progress per (method, risk), and each method's progress interpolated at the target
levels) and ``OUT/frontier.png``.  Folders written when the ``risk`` column was called ``knob``
are read with the old name mapped to the new one.
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
from mmdopt.algorithm import PLANNER_BACKEND
from mmdopt.baselines import PLAN_METHODS as METHODS
from mmdopt.risk import check_risk, config_for_risk

from .executors import MISSING, check_manifest, run_tasks, worker_layout
from .results import write_json, write_results
from .scenes import SceneParams, make_scene, num_scenes
from .synthetic import config_overrides, run_scene

__all__ = [
    "DEFAULT_RISKS",
    "FRONTIER_COLUMNS",
    "TARGET_LEVELS",
    "parse_risks",
    "run_frontier",
    "frontier_points",
    "interpolate_progress",
    "frontier_figure",
]

#: default risk grid (target collision probability ε) per method: down to 1e-5, so that the
#: printed target levels 995 and 999 lie inside the swept range (docs/experiments/frontier.md)
_GRID = (1e-5, 1e-4, 0.001, 0.005, 0.02, 0.1)
DEFAULT_RISKS: dict[str, tuple[float, ...]] = {
    "mmd": _GRID,
    "degroot": _GRID,
    "random": _GRID,
    "saa": _GRID,
    "scenario_all": _GRID,
}
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
)
#: target collision-free levels (of 1000) at which progress is interpolated
TARGET_LEVELS = (990.0, 995.0, 999.0)
#: the name the ``risk`` column had in older folders (task files and ``frontier.csv``)
OLD_RISK_COLUMN = "knob"


def parse_risks(spec: str | None, methods: Sequence[str]) -> dict[str, list[float]]:
    """Risk grid per method from ``"0.1,0.02"`` (every method) or ``"mmd=0.001,0.005;saa=0.01"``
    (per method; the defaults for methods not named).  Raises ``ValueError`` for an unknown or
    unselected method or a risk outside (0, 0.5)."""
    risks = {m: list(DEFAULT_RISKS[m]) for m in methods}
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
        if m not in METHODS:
            raise ValueError(f"risks: unknown method {m!r}; choose from {', '.join(METHODS)}")
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
    """One task's row; a row of an older folder has its ``knob`` renamed ``risk`` in place."""
    row = json.loads(path.read_text())
    if OLD_RISK_COLUMN in row and "risk" not in row:
        row = {("risk" if k == OLD_RISK_COLUMN else k): v for k, v in row.items()}
    return row


def _frontier_task(args) -> int:
    """Worker: scene ``index``, plan every missing (method, risk), one file per plan."""
    index, seed, params_dict, todo, backend, out, config = args
    scene = make_scene(index, seed, SceneParams.from_dict(params_dict))
    done = 0
    for method, risk in todo:
        path = _task_path(Path(out), index, method, risk)
        if path.exists():
            continue
        cfg = config_for_risk(method, risk, config)
        row, _ = run_scene(scene, method, config=cfg, backend=backend)
        row.update(risk=float(risk), seed=int(seed))
        write_json(path, row)
        done += 1
    return done


def run_frontier(
    out: str | Path,
    *,
    risks: Mapping[str, Sequence[float]] | None = None,
    methods: Sequence[str] = METHODS,
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
) -> dict[str, Any]:
    """Sweep every method's risk level on the scenes; resumable (existing task files are reused;
    ``risks``: the grid per method, default :data:`DEFAULT_RISKS`).  ``isolate`` as in
    :func:`~mmdopt.bench.executors.run_tasks`: ``True`` (the CLI) plans every task in a worker
    process with one XLA thread, so the rows do not depend on ``jobs`` or the executor; the
    manifest records where results were computed and a folder refuses a mix.

    Returns ``{"rows", "points", "interpolated", "computed", "reused", "wall_s"}``.
    """
    params = SceneParams() if params is None else params
    n = num_scenes(params, scenes)
    methods = list(dict.fromkeys(methods))
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise ValueError(f"methods must be among {METHODS}, got {methods}")
    risks = {m: list(DEFAULT_RISKS[m]) for m in methods} if risks is None else dict(risks)
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
        ),
        # folders written before the manifest recorded it
        aliases={"workers": [MISSING]},
    )
    pairs = [(m, k) for m in methods for k in risks[m]]
    tasks, reused = [], 0
    for i in range(n):
        todo = [(m, k) for m, k in pairs if not _task_path(out, i, m, k).exists()]
        reused += len(pairs) - len(todo)
        if todo:
            tasks.append((i, seed, params.to_dict(), todo, backend, str(out), config))
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
    points = frontier_points(rows)
    interp = {m: interpolate_progress(points, m, levels) for m in methods}
    write_json(
        out / "frontier_summary.json",
        dict(points=points, interpolated=interp, scenes=n, seed=seed, params=params.to_dict()),
    )
    frontier_figure(points, out / "frontier.png", title=f"{n} scenes, seed {seed}")
    return dict(
        rows=rows,
        points=points,
        interpolated=interp,
        computed=int(sum(done)),
        reused=reused,
        wall_s=wall,
    )


def frontier_points(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per (method, risk): scenes, mean / LQ / min collision-free (scaled to 1000 validation
    samples), mean progress (m), median plan time (s), feasible share; sorted by method, risk.
    Rows of an older folder may name the risk ``knob``."""
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
            )
        )
    return pts


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


def frontier_figure(points: Sequence[Mapping[str, Any]], path: str | Path, title: str = "") -> Path:
    """Mean collision-free (of 1000) against mean progress (m), one curve per method (risk
    points in order), error bars down to the lower quartile."""
    from .plots import _label, _plt

    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for m in dict.fromkeys(p["method"] for p in points):
        ps = sorted((p for p in points if p["method"] == m), key=lambda p: p["risk"])
        x = [p["progress_m"] for p in ps]
        y = [p["mean"] for p in ps]
        lo = [max(p["mean"] - p["q1"], 0.0) for p in ps]
        ax.errorbar(x, y, yerr=[lo, [0.0] * len(ps)], marker="o", capsize=3, label=_label(m))
        for p in ps:
            ax.annotate(f"{p['risk']:g}", (p["progress_m"], p["mean"]), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")  # fmt: skip
    ax.set_xlabel("mean progress in 15 s (m)")
    ax.set_ylabel("mean collision-free validation samples (of 1000)")
    ax.set_title(("safety–progress frontier; labels: risk ε; bars: to LQ" + "\n" + title).strip())
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
