"""The collision metric (paper §IV-A, "Benchmarks and Metrics") and the independent kinematic check.

A plan is scored by the number of validation samples it avoids: a sample *collides* if, at any
time step, for any of its circles (default 3 at {0, ±2.5} m along its heading) the ellipse function
``f = 1 − Δx²/a² − Δy²/b²`` (the nominal :data:`mmdopt.collision.ELLIPSE_A` × ``ELLIPSE_B``, ego a
point) is **strictly** positive (``f̄ > 0``); ``collision_free = N − #colliding``
(:func:`collision_free`, built on :func:`mmdopt.collision_free_count`).  Safety alone rewards
standing still, so every result row also carries the plan's **progress** (metres travelled along
the road), its speed, and an independent **kinematic check** (lane, speed and acceleration bounds,
evaluated on the returned trajectory, not trusted from the planner).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from mmdopt.collision import ELLIPSE_A, ELLIPSE_B, OBSTACLE_FOOTPRINT, collision_free_count

from .scenes import Scene

__all__ = ["KINEMATIC_TOL", "collision_free", "kinematic_violation", "progress", "evaluate_plan"]

#: Tolerances of the independent kinematic check (m, m/s, m/s²).
KINEMATIC_TOL = 0.05


# ---------------------------------------------------------------------------------------------
# metric


def collision_free(
    plan_xy, validation, *, a: float = ELLIPSE_A, b: float = ELLIPSE_B, obstacle_footprint=None
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
    a, b = scene.params.footprint or (ELLIPSE_A, ELLIPSE_B)  # the family's ellipse, if any
    cf_val = collision_free(xy, scene.validation, a=a, b=b)
    cf_plan = collision_free(xy, scene.obstacles, a=a, b=b)
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
        status=str(getattr(plan, "status_text", getattr(plan, "status", ""))),
        risk_bound=float_or_nan(getattr(plan, "risk_bound", math.nan)),
        cost=float_or_nan(getattr(plan, "cost", math.nan)),
        mmd=float_or_nan(getattr(plan, "mmd", math.nan)),
        residual=float_or_nan(getattr(plan, "residual", math.nan)),
        x0=scene.x0,
        y0=scene.y0,
        p=scene.p,
        obstacles=scene.num_obstacles,
        seed=scene.seed,
    )


def float_or_nan(v) -> float:
    """``float(v)``, NaN where ``v`` is no number (a missing or non-numeric plan field)."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan
