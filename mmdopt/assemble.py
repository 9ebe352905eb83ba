"""A :class:`~mmdopt.Plan` assembled from Algorithm 1's chosen coefficients: its trajectory in
both frames, its residual on the full time grid, the MMD value, the planning samples it meets,
its 95 % risk bound and its status (by :data:`~mmdopt.plans.STATUS_PRECEDENCE`).

Every plan :func:`mmdopt.plan` returns is built here, the planner's braking fallback included
(:func:`braking_fallback`), so no plan carries a field measured on another.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial
from typing import Any

import jax
import numpy as np

import frenet

from . import algorithm as alg
from .algorithm import MMDOptConfig, n_taylor_terms, planning_semi_axis
from .collision import ellipse_values, mmd_cost
from .counting import Futures
from .methods import PlanMethod
from .plans import STATUS_PRECEDENCE, Plan, PlanStatus, Road
from .risk import risk_floor, samples_for_risk
from .samples import ReducedSet
from .schedule import plan_bound, risk_counts, samples_met

__all__ = ["PlanFrame", "assemble", "braking_fallback", "risk_status"]


@dataclass(frozen=True, eq=False)
class PlanFrame:
    """What every plan of one call is assembled in: the ego (at arc length 0: planning is done
    relative to it, ``s_offset`` shifts back), the road, the config after the risk mapping, the
    workspace, the method's record, the projector's name, the reduced set, the call's start
    time, and the planning samples (O, n, K, 2) with their body headings (or ``None``);
    ``empty``: the road has no obstacle (the samples are one phantom far behind): the plan's
    bound is 0 and its status does not depend on the phantom."""

    ego: frenet.EgoState
    road: Road
    config: MMDOptConfig
    workspace: alg.Workspace
    method: PlanMethod
    projector: str
    rs: ReducedSet
    t0: float
    s_offset: float
    obs_fr: np.ndarray
    obs_h: np.ndarray | None
    empty: bool = False
    #: the samples as the counts read them (formed from ``obs_fr`` when not given)
    futures: Futures | None = None

    def __post_init__(self) -> None:
        if self.futures is None:
            object.__setattr__(self, "futures", Futures.of(self.obs_fr, self.obs_h))


def risk_status(config: MMDOptConfig, bound: float, colliding) -> tuple[PlanStatus, str]:
    """The status of a plan that is otherwise OK against the requested risk level
    ``config.safety.risk``; ``colliding`` (O, n) the planning samples it meets, ``bound`` its
    :func:`mmdopt.schedule.plan_bound`."""
    eps = float(config.safety.risk)
    hits = np.asarray(colliding, bool)
    (O, n), counts = hits.shape, risk_counts(config, hits)
    groups = counts.size
    floor = risk_floor([n] * groups)
    if O == 1:
        who = f"the {n} samples of the obstacle"
    elif groups == 1:
        who = f"the {n} joint futures of the {O} obstacles"
    else:
        who = f"the {n} samples of each of the {O} obstacles"
    if eps < floor:
        return PlanStatus.RISK_FLOOR, (
            f"asked {eps:.3g}, {who} support {floor:.2g} at best "
            f"(95 % bound with no sample met); {samples_for_risk(eps, groups)} samples per "
            "obstacle would support it"
        )
    if bound > eps:
        what = "joint futures" if groups == 1 and O > 1 else "planning sample(s)"
        return PlanStatus.RISK_EXCEEDED, (
            f"asked {eps:.3g}, the plan meets {int(counts.sum())} {what} "
            f"({', '.join(str(int(h)) for h in hits.sum(-1))} of {n} per obstacle): its 95 % "
            f"bound is {bound:.2g}"
        )
    return PlanStatus.OK, ""


def _plan_mmd(frame: PlanFrame, obstacles: alg.ObstacleSet, s, d, vs, vd) -> float:
    """l_dist of the plan (s, d, ṡ, ḋ on the grid) against ``obstacles``, with the config's
    kernel, margins and rules (a diagnostic of the plan)."""
    config, ob = frame.config, obstacles
    return float(
        _plan_mmd_value(
            config.program(), frame.workspace.t(), ob.centres, ob.weights, ob.margins, s[None],
            d[None], vs[None], vd[None], n_terms=n_taylor_terms(config),
        )[0]
    )  # fmt: skip


@partial(jax.jit, static_argnames=("n_terms",))
def _plan_mmd_value(config: MMDOptConfig, t, centres, weights, margins, s, d, vs, vd, n_terms):
    # one compiled program per shape (eagerly: a program per op and shape)
    vs1 = vs if config.safety.rules.asymmetric else None
    wide = alg.yaw_widening(config, vs, vd) if config.safety.footprint.yaw_aware else None
    if margins is not None:
        f = alg.margin_ellipse_values(config, s, d, centres, margins, vs=vs1, widen=wide)
    else:
        a_plan = planning_semi_axis(config, t)
        a_behind = rear_w = None
        if config.safety.rules.asymmetric:
            a_behind = alg.headway_semi_axis(config, a_plan, vs1)
            a_plan = planning_semi_axis(config, t, scale=config.safety.rules.margin_ahead_scale)
            rear_w = config.safety.rules.rear_exempt_width
        f = ellipse_values(
            s,
            d,
            centres,
            a_plan,
            config.safety.footprint.b
            + config.safety.margins.margin_lat
            + (0.0 if wide is None else wide),
            a_behind=a_behind,
            rear_exempt_width=rear_w,
            headway_lane=config.safety.rules.headway_lane,
        )
    return mmd_cost(f, weights, config.cost.bandwidth, config.cost.f_scale, n_terms)


def _status(candidates: dict[PlanStatus, str]) -> tuple[PlanStatus, str]:
    """The first of :data:`STATUS_PRECEDENCE` among the statuses that apply."""
    for status in STATUS_PRECEDENCE:
        if status in candidates:
            return status, candidates[status]
    return PlanStatus.OK, ""


def assemble(
    frame: PlanFrame,
    cx: np.ndarray,
    cy: np.ndarray,
    dvec: np.ndarray,
    cost: float,
    best_iter: int,
    status: tuple[PlanStatus, str],
    state: alg.CEMState | None,
    obstacles: alg.ObstacleSet,
    diag: dict[str, Any],
    met: tuple | None = None,
) -> Plan:
    """The :class:`Plan` of the Bernstein coefficients ``cx, cy`` (planning frame), the
    behavioural input ``dvec`` that produced them, its cost and iteration, the status Algorithm 1
    gave it (``OK`` or ``FALLBACK`` with why), the final ``state``, the obstacle set its
    :attr:`~mmdopt.Plan.mmd` is measured against, the diagnostics so far and, when the final
    check counted them, ``met`` = ``(cx, cy, (O, n) samples met)``."""
    config, ws, ego = frame.config, frame.workspace, frame.ego
    B = ws.basis
    s, vs, as_ = B.P @ cx, B.Pdot @ cx, B.Pddot @ cx
    d, vd, ad = B.P @ cy, B.Pdot @ cy, B.Pddot @ cy
    residual, groups = ws.grid_projection.residuals(cx, cy, ego.as_array())  # ego at s = 0
    s_off = frame.s_offset
    x, y, heading, speed = frame.road.path.trajectory_to_cartesian(s + s_off, d, vs, vd)
    residual = float(residual[0])
    res_tol = float(config.projection.res_tol)
    feasible = residual <= res_tol + 1e-9
    found = {status[0]: status[1]}
    fallback = status[0] is PlanStatus.FALLBACK
    if not feasible:
        found[PlanStatus.INACCURATE] = (
            f"the returned plan's grid residual {residual:.3g} exceeds res_tol {res_tol:g}"
        )
    mmd_val = _plan_mmd(frame, obstacles, s, d, vs, vd)
    if met is not None and np.array_equal(met[0], cx) and np.array_equal(met[1], cy):
        colliding = met[2]  # counted by the final check
    else:
        colliding = samples_met(config, frame.obs_fr, frame.obs_h, s[None], d[None],
                                futures=frame.futures)[0]  # fmt: skip
    cf_plan = colliding.shape[1] - colliding.sum(axis=1)
    if frame.empty:  # nothing to meet: the collision probability is 0
        colliding, cf_plan = np.zeros((0, colliding.shape[1]), bool), np.zeros(0, int)
    if np.any(cf_plan == 0):
        hit = [int(o) for o in np.flatnonzero(cf_plan == 0)]
        found[PlanStatus.UNSAFE] = (
            f"the plan collides with every planning sample of obstacle(s) {hit}; "
            "no collision-free plan was found"
        )
    bound = 0.0 if frame.empty else plan_bound(config, colliding)
    if config.safety.margins.margin_mode == "samples" and not frame.empty:
        risk, why = risk_status(config, bound, colliding)
        if risk is not PlanStatus.OK:
            found[risk] = why
    found.pop(PlanStatus.OK, None)
    kind, why = _status(found) if found else (PlanStatus.OK, "")
    if fallback:
        kind, why = status
    s = s + s_off
    diag = dict(diag)
    diag.update(
        behavioural_input=np.asarray(dvec, np.float64),
        best_iteration=best_iter,
        residual_groups={k: float(v[0]) for k, v in groups.items()},
        progress_m=float(s[-1] - s[0]),
        mean_speed=float(np.mean(vs)),
        j_speed=float(np.mean((vs - float(config.cost.v_des)) ** 2)),
        j_accel=float(np.mean(as_**2 + ad**2)),
        collision_free_planning=cf_plan,
        n_planning_samples=int(frame.obs_fr.shape[1]),
        s_offset=s_off,
    )
    if state is not None:
        diag.update(
            iteration_min_cost=np.asarray(state.iter_min_cost, np.float64),
            iteration_mean_elite_cost=np.asarray(state.iter_mean_elite_cost, np.float64),
            n_feasible=np.asarray(state.n_feasible),
            n_projected=np.asarray(state.n_projected),
            collision_term=float(state.best.coll)
            if not fallback
            else float(state.least_violating.coll),
            final_mu=np.asarray(state.mu, np.float64),
            final_cov=np.asarray(state.cov, np.float64),
        )
    trace = (
        np.asarray(state.cost_trace, np.float64)
        if state is not None
        else np.full(config.cem.iterations, np.nan)
    )
    return Plan(
        x=x,
        y=y,
        heading=heading,
        speed=speed,
        s=s,
        d=d,
        vs=vs,
        vd=vd,
        as_=as_,
        ad=ad,
        t=ws.t(),
        cost=cost,
        cost_trace=trace,
        residual=residual,
        mmd=mmd_val,
        feasible=bool(feasible),
        status=kind,
        message=why,
        risk_bound=bound,
        method=frame.method.name,
        projector=frame.projector,
        reduced_set=frame.rs,
        plan_time_s=time.perf_counter() - frame.t0,
        diagnostics=diag,
        state=state,
        config=config,
    )


def braking_fallback(
    frame: PlanFrame,
    why: str,
    obstacles: alg.ObstacleSet,
    diag: dict[str, Any],
    state: alg.CEMState | None = None,
) -> Plan:
    """The planner's braking fallback (status FALLBACK, message ``why``): hold the ego's
    clipped speed and lateral offset through the Frenet planner's closed form, measured like
    any plan (residual, samples met, bound)."""
    S = frame.config.trajectory.num_segments
    road, ego = frame.road, frame.ego
    v = float(np.clip(ego.vs, max(road.v_min, 0.0), road.v_max))
    y = float(np.clip(ego.d, road.y_lb, road.y_ub))
    dvec = np.array([[v] * S + [y] * S])
    cx, cy = frame.workspace.planner.closed_form(dvec, ego)
    cx, cy = np.asarray(cx)[0], np.asarray(cy)[0]
    return assemble(
        frame, cx, cy, dvec[0], float("nan"), -1, (PlanStatus.FALLBACK, why), state, obstacles,
        diag,
    )  # fmt: skip
