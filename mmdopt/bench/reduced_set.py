"""Reduced-set selection vs random reduced sets (paper Fig. 4): each set followed by Algorithm 1.

For every scene: the selection methods (MMD, kernel herding, de Groot) and ``random_sets`` random
reduced sets (the paper's near-exhaustive search), each given to ``mmdopt.plan(...,
reduced_set=...)`` with the MMD surrogate; collision-free validation counts per (scene, selection,
draw).  Resumable: one JSON per scene in ``out/scenes/``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import MappingProxyType
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mmdopt.algorithm import PLANNER_BACKEND
from mmdopt.reduced_set import SELECTORS, select_reduced_set

from . import plots
from .executors import check_manifest, run_tasks, worker_layout
from .metric import collision_free, float_or_nan, progress
from .results import remove_temp_files, write_json, write_results
from .scenes import SceneParams, make_scene, num_scenes
from .synthetic import (
    check_sweep_config,
    load_task_file,
    manifest_aliases,
    plan_scene,
    scene_config,
    sweep_manifest,
)

__all__ = ["REDUCED_SET_COLUMNS", "SELECTIONS", "run_reduced_set"]

#: the benchmark's selection names (its ``--methods`` and the ``selection`` column) and the
#: selector of :data:`mmdopt.reduced_set.SELECTORS` each one runs; "random" draws
#: ``random_sets`` sets per scene
SELECTIONS: Mapping[str, str] = MappingProxyType(
    {"mmd": "kernel-cem", "herding": "herding", "degroot": "conflict", "random": "uniform"}
    | {name: name for name in SELECTORS}
)

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


def _reduced_set_task(args) -> list[dict[str, Any]]:
    index, seed, params_dict, methods, random_sets, backend, out, config = args
    params = SceneParams.from_dict(params_dict)
    scene = make_scene(index, seed, params)
    path = _scene_path(out, index)
    if path.exists():
        return []
    cfg = scene_config(scene, config)
    m = cfg.selection.reduced_set_size
    obs = scene.obstacles[0]
    key = scene.key()
    rs_cfg = cfg.selection.reduced_set
    ego_guess = np.stack([scene.params.ego_speed * scene.t, np.zeros_like(scene.t)], -1)
    jobs = [(meth, 0) for meth in methods if SELECTIONS[meth] != "uniform"]
    jobs += [(meth, r) for meth in methods if SELECTIONS[meth] == "uniform"
             for r in range(random_sets)]  # fmt: skip
    rows = []
    # the selection's features as in mmdopt.plan (an anisotropic kernel when the config has one)
    lam = float(cfg.selection.rs_lateral_scale)
    feats = obs * np.array([1.0, lam])
    for meth, r in jobs:
        k = jax.random.fold_in(key, 1000 + r)
        if SELECTIONS[meth] == "conflict":  # scores conflicts in metres: no feature scaling
            rs = select_reduced_set(k, obs, m, SELECTIONS[meth], rs_cfg, ego_guess=ego_guess)
        else:
            rs = select_reduced_set(k, feats, m, SELECTIONS[meth], rs_cfg)
        batched = jax.tree_util.tree_map(lambda x: jnp.asarray(x)[None], rs)
        plan, _, wall = plan_scene(scene, "mmd", config=cfg, backend=backend, reduced_set=batched)
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
                plan_time_s=float_or_nan(getattr(plan, "plan_time_s", wall)),
                x0=scene.x0,
                y0=scene.y0,
                p=scene.p,
            )
        )
    write_json(path, rows)
    return len(rows)


def _scene_path(out: str | Path, index: int) -> Path:
    return Path(out) / "scenes" / f"scene_{index:04d}__reduced_set.json"


def _check_scene_rows(rec: Any, index: int, want: int) -> str | None:
    """Why a scene file does not hold ``want`` result rows of scene ``index``, else ``None``."""
    if not isinstance(rec, list) or len(rec) != want:
        return f"is not a list of {want} rows"
    for r in rec:
        if not isinstance(r, dict) or r.get("scene") != index or "collision_free" not in r:
            return f"holds a row that is not of scene {index}"
    return None


def run_reduced_set(
    out: str | Path,
    *,
    scenes: int = 20,
    seed: int = 0,
    params: SceneParams | None = None,
    methods: Sequence[str] = ("mmd", "herding", "degroot", "random"),
    random_sets: int = 20,
    backend: str = PLANNER_BACKEND,
    jobs: int = 1,
    config=None,
    progress: bool = True,
    executor: str = "local",
    address: str | None = None,
    isolate: bool = False,
) -> dict[str, Any]:
    """Reduced-set selection methods and ``random_sets`` random reduced sets per scene (the
    paper's near-exhaustive search), each followed by Algorithm 1 with the MMD surrogate;
    collision-free validation counts per (scene, selection, draw).  Resumable (one JSON per
    scene in ``out/scenes/``); writes ``out/reduced_set.csv``, ``out/reduced_set_summary.json``
    and ``out/reduced_set.png``.
    """
    params = SceneParams() if params is None else params
    bad = [m for m in methods if m not in SELECTIONS]
    if bad:
        raise ValueError(f"methods must be among {tuple(SELECTIONS)}, got {bad}")
    n = num_scenes(params, scenes)
    check_sweep_config(params, config, ["mmd"], backend, seed)
    out = Path(out)
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    man = sweep_manifest(seed, params, backend, config, worker_layout(jobs, executor, isolate))
    man.update(methods=list(methods), random_sets=int(random_sets))
    check_manifest(out, man, "run_reduced_set.json", aliases=manifest_aliases(config))
    remove_temp_files(out / "scenes")
    remove_temp_files(out)
    n_random = sum(SELECTIONS[m] == "uniform" for m in methods)
    want = len(methods) - n_random + random_sets * n_random
    todo = [
        (i, seed, params.to_dict(), list(methods), random_sets, backend, str(out), config)
        for i in range(n)
        if load_task_file(_scene_path(out, i), lambda r, i=i: _check_scene_rows(r, i, want)) is None
    ]
    try:
        run_tasks(
            _reduced_set_task,
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
        remove_temp_files(out / "scenes")
    rows = []
    for i in range(n):
        rows += json.loads(_scene_path(out, i).read_text())
    write_results(rows, out / "reduced_set.csv", REDUCED_SET_COLUMNS)
    sel = [m for m in methods if SELECTIONS[m] != "uniform"]
    uniform = [m for m in methods if SELECTIONS[m] == "uniform"]
    per_scene = {
        m: [
            next(r["collision_free"] for r in rows if r["scene"] == i and r["selection"] == m)
            for i in range(n)
        ]
        for m in sel
    }
    rnd = [
        [r["collision_free"] for r in rows if r["scene"] == i and r["selection"] in uniform]
        for i in range(n)
    ]
    nv = rows[0]["n_validation"] if rows else 1
    table = _summary_table(rows, per_scene, rnd, nv, random_sets)
    write_json(
        out / "reduced_set_summary.json",
        dict(table=table, scenes=n, seed=seed, random_sets=random_sets, params=params.to_dict()),
    )
    if any(rnd) and sel:
        plots.reduced_set_figure(per_scene, rnd, out / "reduced_set.png", n_validation=nv)
    return dict(rows=rows, table=table)


def _summary_table(
    rows: Sequence[dict[str, Any]],
    per_scene: dict[str, list],
    rnd: list[list],
    nv: int,
    random_sets: int,
) -> list[dict[str, Any]]:
    """The printed table: per selection method, collision-free mean / std (% of the ``nv``
    validation samples) and min over scenes, mean progress and reduced-set MMD²; then the random
    sets' mean and best (oracle) per scene and the share of them MMD selection matches."""
    n = len(rnd)

    def prog(sel_name):
        return float(np.mean([r["progress_m"] for r in rows if r["selection"] == sel_name]))

    def mmd2(sel_name):
        return float(np.mean([r["rs_mmd2"] for r in rows if r["selection"] == sel_name]))

    table = []
    for m, cf in per_scene.items():
        a = np.asarray(cf, float)
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
    if not any(rnd):
        return table
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
    ours = next((m for m in per_scene if SELECTIONS[m] == "kernel-cem"), None)
    if ours is not None:
        a = np.asarray(per_scene[ours], float)
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
    return table
