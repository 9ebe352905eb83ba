"""The real-traffic benchmark: plan as a recorded car in recorded US-101 traffic and score it.

One *task* is (scene, ego vehicle, planning time t0).  The ego's recorded car is removed; the
planner starts from its recorded state on a reference path along its lane (lanelet successors),
may change into an adjacent same-direction lane, and plans against every other vehicle recorded
at t0 within ``range_m`` (at most ``max_obstacles`` nearest), each with ``n_samples`` predictor
samples.  Scores (one row per method, :data:`RESULT_COLUMNS`):

* ``at_fault_collision`` / ``any_collision`` / ``collision_class``: the planned footprint (the
  removed car's length × width) against **every** other vehicle's **recorded** future footprint
  (:mod:`.metric`'s at-fault rule);
* ``min_clearance_m``: the smallest footprint distance to any recorded vehicle over the horizon;
* ``collision_free`` of ``n_validation`` fresh predictor samples (the paper's metric,
  :func:`mmdopt.evaluate.collision_free`, with the benchmark config's ellipse ``a``, ``b``);
* ``progress_m`` along the reference path, and ``recorded_progress_m`` of the human in the same
  horizon; ``feasible`` (``plan.feasible`` and no fallback) and ``plan_time_s``.

Horizon: the recorded scenes last 5–17 s (mostly 8 s), so the benchmark plans **5 s on 51 grid
points (0.1 s)** rather than the planner's default 15 s (:func:`ngsim_config`); predictions and
recorded futures are on that grid, nothing is extrapolated.

Resumable: each finished (task, method) writes ``OUT/tasks/<name>.json``; those present are
skipped; ``OUT/results.csv`` is rebuilt from all of them at the end.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import time
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

import mmdopt
from mmdopt.algorithm import PLANNER_BACKEND
from mmdopt.padding import pad_obstacles, padded_count
from mmdopt.predict import PREDICTORS, Forecast, make_predictor
from mmdopt.risk import check_risk
from solvers.cache import BoundedCache

from .inputs import NgsimParams, ScenarioError, load_ngsim_config, ngsim_config
from .metric import (
    at_fault,
    classify_collision,
    inside_any,
    rect_corners,
    rect_distance,
    rects_overlap,
    turning,
)
from .reactive import PEERS, PeerPlan, plan_reactive
from .reactive import available as available_peer
from .routes import RouteMixture, route_probabilities, shipped_route_weights
from .scene import (
    NgsimScene,
    candidate_routes,
    context_at,
    curve_speed,
    ego_road_geometry,
    future_at,
    history_at,
    load_scenario,
    present,
    route_speed_limit,
    scenario_files,
)

__all__ = [
    "RESULT_COLUMNS",
    "NgsimParams",
    "ngsim_config",
    "select_tasks",
    "explain_no_tasks",
    "file_report",
    "refused_files",
    "trained_on",
    "build_task",
    "traffic_v_des",
    "task_config",
    "PlanInputs",
    "plan_inputs",
    "PhantomPadded",
    "cached_predictor",
    "run_task",
    "peer_plan",
    "run_ngsim",
    "timing_vs_obstacles",
]

RESULT_COLUMNS = (
    "scenario",
    "ego_id",
    "t0",
    "method",
    "predictor",
    "at_fault_collision",
    "min_clearance_m",
    "collision_free",
    "n_validation",
    "progress_m",
    "recorded_progress_m",
    "feasible",
    "plan_time_s",
    "n_obstacles",
    "any_collision",
    "collision_class",
    "fallback",
    "status",
    "cem_s",
    "predict_s",
    "v0",
    "y_lb",
    "y_ub",
    "cost",
    "seed",
    # CommonRoad's checkers on the same plan (:mod:`.crcheck`; empty without the checker)
    "cr_collision_free",
    "cr_road_compliant",
    "cr_feasible",
    "risk_bound",
    "n_planning",
    # the risk level the plan was asked for (``--risk``; empty with the preset's margins)
    "risk",
    # the first call's extra time over the timed plan (``NgsimParams.warm_up``; empty without)
    "compile_s",
)


# --------------------------------------------------------------------------- task selection
def _candidates(scene: NgsimScene, k: int, K: int, p: NgsimParams) -> list[tuple[int, int]]:
    """(vehicles within range, vehicle index) of the egos possible at step k."""
    ok = present(scene, k - p.history + 1, k + K) & (scene.lane_of[:, k] >= 0)
    ok &= scene.length <= p.max_ego_length
    here = np.isfinite(scene.xy[:, k, 0]) & np.isfinite(scene.xy[:, max(k - 1, 0), 0])
    out = []
    for v in np.flatnonzero(ok):
        d = np.linalg.norm(scene.xy[:, k] - scene.xy[v, k], axis=-1)
        nb = int(np.sum(here & (d <= p.range_m) & (np.arange(len(d)) != v)))
        if nb >= 1:
            out.append((nb, v))
    return out


def select_tasks(paths, params: NgsimParams | None = None, config=None) -> list[dict]:
    """The (scene, ego, t0) tasks of the scenario files under ``paths``."""
    p = NgsimParams() if params is None else params
    cfg = ngsim_config() if config is None else config
    tasks = []
    for f in scenario_files(paths):
        sc = load_scenario(str(f))
        K = int(round(cfg.trajectory.horizon / sc.dt))
        for k in _planning_steps(sc, K, p):
            # moving cars first (a car waiting at a red light through the whole horizon is no
            # planning task), then the most neighbours
            cands = sorted(
                _candidates(sc, k, K, p),
                key=lambda c, k=k: (not sc.speed[c[1], k] >= p.min_task_speed, -c[0], sc.ids[c[1]]),
            )
            for _, v in cands[: p.egos_per_time]:
                tasks.append(
                    dict(scenario=str(f), ego_id=int(sc.ids[v]), k=k, t0=round(k * sc.dt, 3))
                )
    return tasks


def _planning_steps(sc: NgsimScene, K: int, p: NgsimParams) -> list[int]:
    """The steps k of the planning times t0 = first_t0, first_t0 + every, … whose history and
    ``K``-step horizon are inside the recording."""
    out, t0 = [], p.first_t0
    while True:
        k = int(round(t0 / sc.dt))
        if k + K >= sc.num_steps:
            return out
        if k - p.history + 1 >= 0:
            out.append(k)
        t0 += p.every


def _task_needs(p: NgsimParams, config) -> str:
    return (
        f"a task needs, at a planning time t0 = {p.first_t0:g}, {p.first_t0 + p.every:g}, … s, "
        f"a vehicle recorded over its history ({p.history} rows before t0, NgsimParams.history) "
        f"and the {config.trajectory.horizon:g} s horizon after t0, on the lane map at t0, at "
        f"most {p.max_ego_length:g} m long (max_ego_length), with another vehicle within "
        f"{p.range_m:g} m (range_m)"
    )


def file_report(f, params: NgsimParams, config) -> str:
    """One scenario file against the task conditions (:func:`select_tasks`): its length and
    vehicles and, over every planning time, how many vehicles pass each condition in turn;
    "too short" where no planning time fits."""
    p = params
    sc = load_scenario(str(f))
    K = int(round(config.trajectory.horizon / sc.dt))
    recorded = f"{sc.num_steps * sc.dt:.1f} s recorded, {len(sc.ids)} vehicle(s)"
    passed: list[set] = [set(), set(), set(), set()]  # recorded, on the map, length, neighbour
    steps = _planning_steps(sc, K, p)
    n_t0 = len(steps)
    for k in steps:
        ok = present(sc, k - p.history + 1, k + K)
        passed[0] |= set(np.flatnonzero(ok))
        ok &= sc.lane_of[:, k] >= 0
        passed[1] |= set(np.flatnonzero(ok))
        ok &= sc.length <= p.max_ego_length
        passed[2] |= set(np.flatnonzero(ok))
        here = np.isfinite(sc.xy[:, k, 0]) & np.isfinite(sc.xy[:, max(k - 1, 0), 0])
        for v in np.flatnonzero(ok):
            d = np.linalg.norm(sc.xy[:, k] - sc.xy[v, k], axis=-1)
            if np.any(here & (d <= p.range_m) & (np.arange(len(d)) != v)):
                passed[3].add(int(v))
    if n_t0 == 0:
        return (
            f"{Path(f).name}: {recorded}; too short for one planning time "
            f"(needs more than {p.first_t0 + config.trajectory.horizon:g} s)"
        )
    c = [len(x) for x in passed]
    return (
        f"{Path(f).name}: {recorded}, {n_t0} planning time(s); vehicles recorded over "
        f"history and horizon: {c[0]}"
        + (" (no car recorded long enough)" if c[0] == 0 else "")
        + f", of them on the lane map: {c[1]}"
        + (" (no route: none is on a lanelet)" if c[0] and c[1] == 0 else "")
        + f", short enough: {c[2]}, with a vehicle within range: {c[3]}"
    )


def explain_no_tasks(files, params, config) -> str:
    """Why :func:`select_tasks` finds no task in ``files``: the conditions a task's ego must
    meet (with ``params``' thresholds) and, per file, :func:`file_report`."""
    lines = [file_report(f, params, config) for f in files]
    shown = lines[:5] + ([f"… and {len(lines) - 5} more file(s)"] if len(lines) > 5 else [])
    return (
        f"no task selected from {len(lines)} scenario file(s): {_task_needs(params, config)}. "
        + "; ".join(shown)
    )


def refused_files(files, tasks, params: NgsimParams, config) -> dict[str, str]:
    """The files among ``files`` that gave none of ``tasks``, each with why
    (:func:`file_report`, after the conditions)."""
    used = {str(t["scenario"]) for t in tasks}
    need = _task_needs(params, config)
    return {
        Path(f).name: f"{file_report(f, params, config)} — {need}"
        for f in files
        if str(f) not in used
    }


# --------------------------------------------------------------------------- one task
def _quantise(x: float, step: float, up: bool) -> float:
    return float((np.ceil if up else np.floor)(x / step - 1e-9) * step)


def build_task(task: dict, params: NgsimParams, config: mmdopt.MMDOptConfig) -> dict:
    """Everything a plan needs: ego state, road, obstacle indices, histories, contexts."""
    sc = load_scenario(task["scenario"])
    v = int(np.flatnonzero(sc.ids == task["ego_id"])[0])
    k = int(task["k"])
    times = np.linspace(0.0, config.trajectory.horizon, config.trajectory.num_steps)
    path, off_l, off_r = ego_road_geometry(sc, v, k)
    x, y = sc.xy[v, k]
    ego = path.ego_state(
        float(x),
        float(y),
        float(sc.speed[v, k]),
        float(sc.heading[v, k]),
        accel=float(np.clip(sc.accel[v, k], -3.0, 3.0)),
    )
    ego = dataclasses.replace(ego, ad=0.0, vd=float(np.clip(ego.vd, -1.0, 1.0)))
    # neighbour lane centres rounded to the nearest bound_step, widened (outwards) to contain
    # the ego's own offset: few distinct bounds, so few compiled projection problems
    st = params.bound_step
    y_ub = round(off_l / st) * st if off_l is not None else params.lane_keep_margin
    y_lb = round(off_r / st) * st if off_r is not None else -params.lane_keep_margin
    if ego.vs < params.min_change_speed:
        # crawling: keep the lane (a Frenet lateral move at ~0 speed is a sideways slide)
        y_ub, y_lb = params.lane_keep_margin, -params.lane_keep_margin
    y_ub = max(y_ub, _quantise(ego.d + 0.1, st, up=True))
    y_lb = min(y_lb, _quantise(ego.d - 0.1, st, up=False))
    road = mmdopt.Road(path=path, y_lb=y_lb, y_ub=y_ub)
    here = np.isfinite(sc.xy[:, k, 0]) & np.isfinite(sc.xy[:, k - 1, 0])
    here[v] = False
    dist = np.linalg.norm(sc.xy[:, k] - sc.xy[v, k], axis=-1)
    cand = np.flatnonzero(here & (dist <= params.range_m))
    obs = cand[np.argsort(dist[cand])][: params.max_obstacles]
    # the ego's car is removed: it is nobody's neighbour in the predictor's context
    sc_wo = dataclasses.replace(sc, xy=sc.xy.copy())
    sc_wo.xy[v] = np.nan
    ctx = context_at(sc_wo, obs, k, times)
    hist = history_at(sc, obs, k, params.history)
    lane_w = sc.lanes[int(sc.lane_of[v, k])].width
    # speed of the traffic ahead, observed at t0 (for the traffic-aware desired speed)
    s_obs, d_obs = (np.asarray(a) for a in path.to_frenet(sc.xy[obs, k, 0], sc.xy[obs, k, 1]))
    # only the lanes the ego may use (its lane and the neighbours within its bounds): a queue
    # two lanes over (an exit, the HOV lane) is not the ego's traffic
    sel = (s_obs > ego.s) & np.isfinite(sc.speed[obs, k])
    sel &= (d_obs >= y_lb - 0.5 * lane_w) & (d_obs <= y_ub + 0.5 * lane_w)
    v_flow = float(np.median(sc.speed[obs[sel], k])) if np.any(sel) else None
    in_lane = sel & (np.abs(d_obs - ego.d) < 0.5 * lane_w)
    v_leader = None
    if np.any(in_lane):
        lead = np.flatnonzero(in_lane)[np.argmin(s_obs[in_lane])]
        v_leader = float(sc.speed[obs[lead], k])
    routes = tuple(np.stack(candidate_routes(sc, int(o), k)) for o in obs)
    # the map's speed limit of the lanelets the ego drives on within 2 s (>= 20 m): one
    # desired speed for the horizon, so a limit farther ahead is not the ego's yet
    v_limit = (
        route_speed_limit(sc, v, k, max(20.0, 2.0 * max(float(ego.vs), 0.0)), ahead=260.0)
        if params.speed_limits
        else None
    )
    # the speed its route's curves allow within the horizon's reach (one desired speed for the
    # horizon: a curve the plan reaches caps it from the start)
    v_curve = curve_speed(
        path, float(ego.s), max(20.0, float(ego.vs) * float(config.trajectory.horizon)),
        params.curve_accel, params.curve_steer_rate,
    )  # fmt: skip
    return dict(
        v_limit=v_limit,
        v_curve=v_curve,
        routes=routes,
        route_p=tuple(route_probabilities(hist, routes, sc.dt, shipped_route_weights())),
        v_flow=v_flow,
        v_leader=v_leader,
        scene=sc,
        v=v,
        k=k,
        times=times,
        ego=ego,
        road=road,
        obs=obs,
        ctx=ctx,
        hist=hist,
        lane_w=lane_w,
        off_l=off_l,
        off_r=off_r,
    )


def traffic_v_des(
    v_flow: float | None, params: NgsimParams, v_leader: float | None = None
) -> float | None:
    """The desired speed of a task (m/s): ``params.v_des``, capped at ``v + params.v_des_flow``
    when ``v_des_flow`` is set, with ``v`` the traffic's speed at t0: ``v_flow`` (median speed
    of the vehicles ahead within range), or the ego lane's leader ``v_leader`` when
    ``params.flow_leader`` and there is one; no cap when nobody is ahead.  ``None``: keep the
    config's."""
    if params.v_des is None:
        return None
    v = v_leader if (params.flow_leader and v_leader is not None) else v_flow
    if params.v_des_flow is None or v is None:
        return float(params.v_des)
    if not np.isfinite(v) or v < 0:
        raise ValueError(f"v_flow / v_leader must be a finite speed >= 0, got {v!r}")
    return float(min(params.v_des, v + params.v_des_flow))


def task_config(b: dict, params: NgsimParams, config: mmdopt.MMDOptConfig) -> mmdopt.MMDOptConfig:
    """The planner config of one built task (:func:`build_task`): ``config`` with the task's
    desired speed (:func:`traffic_v_des`), capped at the map's speed limit along the ego's
    route (:func:`~.scene.route_speed_limit`, ``NgsimParams.speed_limits``) and at the speed
    of its route's curves (:func:`~.scene.curve_speed`, ``NgsimParams.curve_accel`` and
    ``curve_steer_rate``)."""
    v = traffic_v_des(b.get("v_flow"), params, b.get("v_leader"))
    for cap in ("v_limit", "v_curve"):
        if b.get(cap) is not None:
            v = min(config.cost.v_des if v is None else v, float(b[cap]))
    return config if v is None else config.replace(v_des=v)


def _score_recorded(b: dict, plan, params: NgsimParams) -> dict:
    """At-fault collision, any collision, class and min clearance against recorded futures."""
    sc, v, k, times = b["scene"], b["v"], b["k"], b["times"]
    others = np.flatnonzero(np.arange(len(sc.ids)) != v)
    fut = future_at(sc, others, k, times)  # (N, K, 2)
    steps = np.clip(k + np.rint(times / sc.dt).astype(int), 0, sc.num_steps - 1)
    hd = sc.heading[others][:, steps]
    spd = sc.speed[others][:, steps]
    ok = np.all(np.isfinite(fut), -1) & np.isfinite(hd)
    ego_rect = rect_corners(plan.x, plan.y, plan.heading, sc.length[v], sc.width[v])  # (K, 4, 2)
    fx, fy = np.where(ok, fut[..., 0], 0.0), np.where(ok, fut[..., 1], 0.0)
    o_rect = rect_corners(
        fx, fy, np.where(ok, hd, 0.0), sc.length[others][:, None], sc.width[others][:, None]
    )
    dist = rect_distance(ego_rect[None], o_rect)  # (N, K)
    dist = np.where(ok, dist, np.inf)
    overlap = ok & rects_overlap(ego_rect[None], o_rect)
    min_clear = float(np.min(dist)) if np.any(ok) else float("inf")
    # lane-change state of the ego at each step: footprint across a lane line
    centres = [0.0] + [c for c in (b["off_l"], b["off_r"]) if c is not None]
    dev = np.min(np.abs(plan.d[:, None] - np.array(centres)[None]), axis=1)
    changing = dev > 0.5 * (b["lane_w"] - sc.width[v])
    decel = -np.asarray(plan.as_)
    dt = float(times[1] - times[0])
    win = max(1, int(round(1.0 / dt)))
    fault, classes = False, []
    for i in np.flatnonzero(overlap.any(1)):
        j = int(np.flatnonzero(overlap[i])[0])
        cls = classify_collision(
            ego_rect[j], plan.heading[j], plan.speed[j], o_rect[i, j], fut[i, j], spd[i, j]
        )
        dec = float(np.max(decel[max(0, j - win) : j + 1]))
        in_junction = inside_any((plan.x[j], plan.y[j]), sc.junctions)
        turns = turning(plan.heading, dt, j) or turning(hd[i], dt, j)
        f = at_fault(
            cls, dec, bool(changing[j]), params.brake_threshold, in_junction=in_junction,
            turning=turns,
        )  # fmt: skip
        classes.append(cls + ("*" if f else ""))
        fault |= f
    return dict(
        at_fault_collision=bool(fault),
        any_collision=bool(overlap.any()),
        collision_class=";".join(sorted(set(classes))),
        min_clearance_m=min_clear,
    )


class PlanInputs(NamedTuple):
    """What :func:`run_task` plans one task with (:func:`plan_inputs`)."""

    task: dict  # the built task (:func:`build_task`)
    config: mmdopt.MMDOptConfig  # with the task's desired speed (:func:`task_config`)
    planned: np.ndarray  # (O', n, K, 2) planning samples, padded with phantoms
    predictor: Any  # the predictor object that drew them
    key_validation: Any  # PRNG key of the validation draws
    key_plan: Any  # PRNG key of the plan
    predict_s: float  # wall time of the planning draws
    recorded_progress_m: float  # the human's arc length over the horizon
    forecast: Any = None  # the Forecast plan() draws from (NgsimParams.forecast), else None

    @property
    def obstacles(self):
        """What :func:`mmdopt.plan` is given: the forecast, else the fixed samples."""
        return self.planned if self.forecast is None else self.forecast


#: the most futures per obstacle a forecast draws (beyond it the status says ``risk floor``)
MAX_FORECAST_SAMPLES = 5000


@dataclass(frozen=True)
class PhantomPadded:
    """``inner``'s draws for the first ``real`` obstacles, then phantoms 500 m behind the ego
    (:func:`mmdopt.padding.pad_obstacles`, on the planner's time grid ``t``) for the rest: the
    predictor of a :class:`mmdopt.predict.Forecast` whose history and context are padded to the
    bucket, so Algorithm 1 compiles once per bucket, as with the fixed samples."""

    inner: Any
    real: int
    road: Any
    ego: Any
    t: np.ndarray

    def sample(self, history, context, n, key) -> np.ndarray:
        real = np.arange(self.real)
        out = self.inner.sample(history[: self.real], context.subset(real), n, key)
        out = np.asarray(out, np.float64)
        return pad_obstacles(out, history.shape[0], self.ego, self.road, self.t)


def _forecast(b: dict, pred, params: NgsimParams, config) -> Forecast:
    """The task's obstacles as a :class:`mmdopt.predict.Forecast` of ``pred``; with the
    time-linear margins (one n for every plan) padded with phantoms like the fixed samples, in
    the "samples" mode not (phantoms would count as obstacles in the risk bound)."""
    hist, ctx = np.asarray(b["hist"], np.float64), b["ctx"]
    O = hist.shape[0]
    kw = dict(min_samples=params.n_samples, max_samples=max(params.n_samples, MAX_FORECAST_SAMPLES))
    if config.safety.margins.margin_mode == "samples":
        return Forecast(pred, hist, ctx, **kw)
    target = padded_count(O, params.max_obstacles, params.bucket)
    if target <= O:
        return Forecast(pred, hist, ctx, **kw)
    rows = np.concatenate([np.arange(O), np.full(target - O, O - 1)])
    padded = PhantomPadded(pred, O, b["road"], b["ego"], b["times"])
    return Forecast(padded, hist[rows], ctx.subset(rows), **kw)


def plan_inputs(task: dict, params: NgsimParams, config, predictor: Any = "learned") -> PlanInputs:
    """The built task, config, planning samples and keys of one task exactly as ``mmdopt bench
    ngsim`` plans it; ``predictor`` a name of :data:`mmdopt.predict.PREDICTORS` or a predictor
    object (e.g. ``Learned(spread=...)``)."""
    b = build_task(task, params, config)
    urban = b["scene"].n_intersections > 0
    pred = cached_predictor(predictor, urban) if isinstance(predictor, str) else predictor
    if params.routes:
        pred = RouteMixture(pred, b["routes"], b["route_p"])
    key = jax.random.fold_in(jax.random.PRNGKey(params.seed), _task_seed(task))
    k_pred, k_val, k_plan = jax.random.split(key, 3)
    t1 = time.perf_counter()
    samples = pred.sample(b["hist"], b["ctx"], params.n_samples, k_pred)
    predict_s = time.perf_counter() - t1
    planned = pad_obstacles(
        samples, params.max_obstacles, b["ego"], b["road"], b["times"], bucket=params.bucket
    )
    rec = future_at(b["scene"], [b["v"]], b["k"], b["times"])[0]
    s_rec, _ = b["road"].path.to_frenet(rec[:, 0], rec[:, 1])
    cfg = task_config(b, params, config)
    fc = _forecast(b, pred, params, cfg) if params.forecast else None
    return PlanInputs(
        b, cfg, planned, pred, k_val, k_plan, predict_s, float(s_rec[-1] - s_rec[0]), fc
    )


def peer_plan(task: dict, inp: PlanInputs, n_futures: int, full_horizon: bool = False) -> PeerPlan:
    """The reactive planner's plan of one task (:func:`.reactive.plan_reactive`), against the
    first ``n_futures`` of the planning samples of each real obstacle."""
    b = inp.task
    sc, v, k, obs = b["scene"], b["v"], b["k"], b["obs"]
    futures = np.asarray(inp.planned, np.float64)[: len(obs), :n_futures]
    return plan_reactive(
        task["scenario"], b["road"], b["ego"],
        (sc.xy[v, k, 0], sc.xy[v, k, 1], sc.heading[v, k], sc.speed[v, k]),
        (sc.length[v], sc.width[v]), b["times"], futures,
        np.stack([sc.length[obs], sc.width[obs]], -1), sc.heading[obs, k],
        float(inp.config.cost.v_des), full_horizon,
    )  # fmt: skip


def _timed_plan(inp: PlanInputs, method: str, backend: str, risk, warm_up: bool):
    """``(plan, compile_s)``: the task's plan by ``method`` and, with ``warm_up``, how much longer
    an untimed first plan with another key took (the JIT compile of the task's shapes; the same
    programs, without a result the timed plan could reuse); ``compile_s`` is None without it."""
    b = inp.task

    def once(key):
        return mmdopt.plan(
            b["ego"], b["road"], inp.obstacles, method=method, config=inp.config,
            projector=backend, key=key, risk=risk,
        )  # fmt: skip

    first_s = once(jax.random.fold_in(inp.key_plan, 1)).plan_time_s if warm_up else None
    plan = once(inp.key_plan)
    if first_s is None:
        return plan, None
    return plan, max(0.0, float(first_s) - float(plan.plan_time_s))


def run_task(
    task: dict,
    methods,
    predictor: str,
    params: NgsimParams,
    config,
    backend: str = PLANNER_BACKEND,
    export: str | Path | None = None,
    risk: float | None = None,
) -> list[dict]:
    """Plan one task with every method; one result row per method.  With CommonRoad's checkers
    installed each row also has their verdicts (:data:`.crcheck.CR_COLUMNS`); ``export``: a
    folder to write each plan to as a CommonRoad solution file (:func:`.crcheck.write_solution`,
    named like the task's JSON).  ``risk`` ε: every method plans with its own mapping of ε
    (``mmdopt.plan(..., risk=ε)``) on a config in the risk mode (:func:`risk_config`)."""
    from . import crcheck

    check = crcheck.available() is None
    if export is not None and not check:
        raise ValueError(f"export needs CommonRoad's checkers: {crcheck.available()}")
    inp = plan_inputs(task, params, config, predictor)
    b, cfg = inp.task, inp.config
    val = inp.predictor.sample(b["hist"], b["ctx"], params.n_validation, inp.key_validation)
    rows = []
    for m in methods:
        if m in PEERS:
            plan = peer_plan(task, inp, params.reactive_futures, params.reactive_full_horizon)
            compile_s = None
        else:
            plan, compile_s = _timed_plan(inp, m, backend, risk, params.warm_up)
        score = _score_recorded(b, plan, params)
        # the paper's metric (§IV-A): validation draws clear of every obstacle
        cf = int(
            mmdopt.collision_free_count(
                plan.xy, val, a=float(cfg.safety.footprint.a), b=float(cfg.safety.footprint.b)
            ).joint
        )
        rows.append(
            dict(
                scenario=Path(task["scenario"]).stem,
                ego_id=task["ego_id"],
                t0=task["t0"],
                method=m,
                predictor=predictor,
                **score,
                collision_free=cf,
                n_validation=params.n_validation,
                progress_m=plan.progress,
                recorded_progress_m=inp.recorded_progress_m,
                feasible=bool(plan.feasible and not plan.fallback),
                plan_time_s=plan.plan_time_s,
                n_obstacles=len(b["obs"]),
                fallback=bool(plan.fallback),
                status=plan.status_text,
                risk_bound=float(plan.risk_bound),
                risk=risk,
                compile_s=compile_s,
                cem_s=float(plan.diagnostics.get("cem_s", np.nan)),
                predict_s=float(plan.diagnostics.get("forecast_s", inp.predict_s)),
                n_planning=int(plan.diagnostics.get("forecast_samples", params.n_samples)),
                v0=float(b["ego"].vs),
                y_lb=b["road"].y_lb,
                y_ub=b["road"].y_ub,
                cost=float(plan.cost),
                seed=params.seed,
            )
        )
        sc, v = b["scene"], b["v"]
        if check:
            rows[-1].update(
                crcheck.check_plan(
                    plan, task["scenario"], task["ego_id"], b["k"], sc.length[v], sc.width[v]
                )
            )
        if export is not None:
            crcheck.write_solution(
                plan, task["scenario"], task["ego_id"], b["k"], export,
                _task_name(task, m, predictor),
            )  # fmt: skip
    return rows


#: the predictors made in this process, by name (the one cache policy: solvers.cache)
_PRED_CACHE: BoundedCache = BoundedCache(len(PREDICTORS) + 1)


def cached_predictor(name: str, urban: bool = False):
    """The predictor ``name`` of :data:`mmdopt.predict.PREDICTORS`, made once per process and
    shared by every task (loading the learned weights once).  ``urban`` (a scene whose lanelet
    network has junctions): "learned" is the MDN trained on the US-101 and Lankershim scenes
    (``mmdopt.predict.learned.URBAN_WEIGHTS``), else the US-101 one."""
    if name not in PREDICTORS:
        raise ValueError(f"predictor must be one of {PREDICTORS}, got {name!r}")
    if name == "learned" and urban:
        from mmdopt.predict.learned import URBAN_WEIGHTS

        return _PRED_CACHE.get_or_create(
            (name, True), lambda: make_predictor(name, weights=URBAN_WEIGHTS)
        )
    return _PRED_CACHE.get_or_create(name, lambda: make_predictor(name))


def timing_vs_obstacles(
    task: dict,
    counts=(1, 2, 5, 10, 15),
    predictor: str = "lane",
    method: str = "mmd",
    repeats: int = 3,
    params: NgsimParams | None = None,
    config=None,
) -> list[dict]:
    """Plan time of one task against its c nearest vehicles, c in ``counts`` (no phantoms): the
    first call (``first_s``, includes the JIT compile) and the median of ``repeats`` more."""
    p = NgsimParams(max_obstacles=max(counts)) if params is None else params
    cfg = ngsim_config() if config is None else config
    b = build_task(task, p, cfg)
    cfg = task_config(b, p, cfg)
    samples = cached_predictor(predictor).sample(
        b["hist"], b["ctx"], p.n_samples, jax.random.PRNGKey(p.seed)
    )
    rows = []
    for c in counts:
        if c > samples.shape[0]:
            continue
        ts = []
        for r in range(repeats + 1):
            pl = mmdopt.plan(
                b["ego"],
                b["road"],
                samples[:c],
                method=method,
                config=cfg,
                key=jax.random.PRNGKey(r),
            )
            ts.append(pl.plan_time_s)
        rows.append(
            dict(
                n_obstacles=c,
                method=method,
                first_s=ts[0],
                median_s=float(np.median(ts[1:])),
                cem_s=float(pl.diagnostics.get("cem_s", np.nan)),
                feasible=bool(pl.feasible),
            )
        )
    return rows


def _task_seed(task: dict) -> int:
    """A stable (process-independent) integer of the task, for its PRNG key."""
    return zlib.crc32(f"{Path(task['scenario']).stem}/{task['ego_id']}/{task['k']}".encode()) % (
        2**31
    )


def _task_name(task: dict, method: str, predictor: str) -> str:
    return f"{Path(task['scenario']).stem}__{task['ego_id']}__{task['k']}__{method}__{predictor}"


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o)}")


def _group_job(args) -> list[dict]:
    task, methods, predictor, params, config, out, *rest = args
    export = rest[0] if rest else None
    risk = rest[1] if len(rest) > 1 else None
    todo = [
        m
        for m in methods
        if not (out / "tasks" / (_task_name(task, m, predictor) + ".json")).exists()
    ]
    if not todo:
        return []
    try:
        rows = run_task(task, todo, predictor, params, config, export=export, risk=risk)
    except Exception as exc:  # a bad scene is reported, never crashes the sweep
        rows = [
            dict(
                scenario=Path(task["scenario"]).stem,
                ego_id=task["ego_id"],
                t0=task["t0"],
                method=m,
                predictor=predictor,
                status=f"error: {type(exc).__name__}: {exc}",
            )
            for m in todo
        ]
    for r in rows:
        path = out / "tasks" / (_task_name(task, r["method"], predictor) + ".json")
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(r, default=_json_default))
        tmp.replace(path)
    return rows


def write_results(out: Path) -> list[dict]:
    """Merge ``OUT/tasks/*.json`` into ``OUT/results.csv`` (sorted); returns the rows."""
    rows = [json.loads(p.read_text()) for p in sorted((out / "tasks").glob("*.json"))]
    rows.sort(key=lambda r: (r["scenario"], r["ego_id"], r["t0"], r["method"], r["predictor"]))
    with open(out / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=RESULT_COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({c: r.get(c, "") for c in RESULT_COLUMNS})
    return rows


def _as_config(config) -> tuple[mmdopt.MMDOptConfig, NgsimParams]:
    """``config``: None, an MMDOptConfig, or a dict / JSON file of MMDOptConfig fields with an
    optional ``"bench"`` sub-dict of :class:`NgsimParams` fields."""
    if config is None:
        return ngsim_config(), NgsimParams()
    if isinstance(config, mmdopt.MMDOptConfig):
        return config, NgsimParams()
    if not isinstance(config, str | Path | dict):
        raise ValueError(
            f"config must be None, an MMDOptConfig, a dict or a JSON path, got {config!r}"
        )
    return load_ngsim_config(config)


def trained_on(files, predictor: str) -> list[str]:
    """The names among ``files`` that the shipped ``predictor`` was trained on (its weights'
    ``train_files``: the US-101 MDN, and the urban MDN with its route weights); [] for cv/lane."""
    if predictor != "learned":
        return []
    from mmdopt.predict.learned import DEFAULT_WEIGHTS, URBAN_WEIGHTS

    seen: set[str] = set()
    for base in (DEFAULT_WEIGHTS, URBAN_WEIGHTS):
        meta = Path(f"{base}.json")
        if meta.is_file():
            info = json.loads(meta.read_text()).get("info", {})
            seen |= set(info.get("train_files", []) if isinstance(info, dict) else [])
    return sorted(Path(f).name for f in files if Path(f).name in seen)


def risk_config(config: mmdopt.MMDOptConfig, risk: float | None) -> mmdopt.MMDOptConfig:
    """``config`` in the risk mode at ε = ``risk`` (``--risk``): sample-driven margins
    (``margin_mode = "samples"``) and ``safety.risk = ε``; ``None``: ``config`` as it is."""
    if risk is None:
        return config
    return config.replace(margin_mode="samples", risk=check_risk(risk, "risk"))


def run_ngsim(
    scenarios,
    out,
    methods=("mmd", "degroot"),
    predictor: str = "learned",
    config=None,
    executor: str = "local",
    jobs: int = 1,
    params: NgsimParams | None = None,
    max_tasks: int | None = None,
    address: str | None = None,
    progress: bool = False,
    isolate: bool = False,
    export: str | Path | None = None,
    risk: float | None = None,
    holdout=None,
) -> list[dict]:
    """Run the benchmark on the scenario files/folders ``scenarios``; write ``OUT/results.csv``.

    ``config``: None (:func:`ngsim_config`), an :class:`mmdopt.MMDOptConfig`, or a dict / JSON
    file of MMDOptConfig fields (on top of :func:`ngsim_config`) with an optional ``"bench"``
    sub-dict of :class:`NgsimParams` fields; ``params`` overrides that sub-dict.  ``executor``:
    "local" (``jobs`` processes) or "ray" (:func:`mmdopt.bench.executors.run_tasks`);
    ``max_tasks``: the first tasks only (smoke runs).  Resumable: finished (task, method) files
    in ``OUT/tasks`` are skipped; ``OUT/run.json`` must match the settings.  Returns the rows.
    ``isolate`` as in :func:`~mmdopt.bench.executors.run_tasks` (the CLI: every task in a
    worker process with one XLA thread, rows independent of ``jobs`` and the executor; the
    manifest records it).  Every scenario file is read before anything is written: a bad file,
    or scenes that give no task at all, raise :class:`~mmdopt.bench.ngsim.inputs.ScenarioError`
    (a ``ValueError``) saying why (:func:`~mmdopt.bench.ngsim.inputs.explain_no_tasks`).
    ``export``: a folder for each plan computed in this run as a CommonRoad solution file
    (:func:`.crcheck.write_solution`; resumed tasks are not planned again, so not exported).
    ``risk`` ε: the planner in the risk mode at ε (:func:`risk_config`, recorded in the
    manifest's config), each method with its own mapping of ε, through the predictor's
    forecast (``params.forecast``) so that each plan draws the futures ε needs; the rows'
    ``risk`` column.  ``holdout``: file names or glob patterns (:func:`.data.split_files`): only
    the held-out files of ``scenarios`` are planned, and the split goes into ``run.json``.
    Files that give no task are named with the reason in ``OUT/refused.json``; the files the
    shipped learned predictor was trained on, in ``OUT/trained_on.json``.
    """
    from mmdopt.bench.executors import MISSING, check_manifest, run_tasks, worker_layout

    cfg, p = _as_config(config)
    p = params if params is not None else p
    cfg = risk_config(cfg, risk)
    risk = None if risk is None else float(risk)
    methods = tuple(methods)
    if not methods:
        raise ValueError("methods is empty")
    for m in methods:
        if m not in PEERS:
            mmdopt.methods.get(m)
        elif available_peer() is not None:
            raise ValueError(f"method {m!r}: {available_peer()}")
    if predictor not in PREDICTORS:
        raise ValueError(f"predictor must be one of {PREDICTORS}, got {predictor!r}")
    from .data import describe_split, split_files

    split = None
    if holdout is not None:
        train, scenarios = split_files(scenarios, holdout)
        split = describe_split(train, scenarios, holdout)
        if not scenarios:
            raise ScenarioError(f"no held-out file among the scenarios (holdout {holdout!r})")
    files = scenario_files(scenarios)
    # every scenario file is read (and checked) before anything is written into ``out``
    tasks = select_tasks(files, p, cfg)
    if not tasks:
        raise ScenarioError(explain_no_tasks(files, p, cfg))
    out = Path(out)
    (out / "tasks").mkdir(parents=True, exist_ok=True)
    (out / "refused.json").write_text(json.dumps(refused_files(files, tasks, p, cfg), indent=1))
    (out / "trained_on.json").write_text(json.dumps(trained_on(files, predictor), indent=1))
    if max_tasks is not None:
        tasks = tasks[:max_tasks]
    cfg_d = {
        f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg) if f.name != "reduced_set"
    }
    check_manifest(
        out,
        json.loads(
            json.dumps(
                dict(
                    predictor=predictor,
                    params=dataclasses.asdict(p),
                    config=cfg_d,
                    workers=worker_layout(jobs, executor, isolate),
                    split=split,
                ),
                default=str,
            )
        ),
        # folders written before the manifest recorded them
        aliases={"workers": [MISSING], "split": [MISSING]},
    )
    args = [
        (t, methods, predictor, p, cfg, out, None if export is None else Path(export), risk)
        for t in tasks
        if not all(
            (out / "tasks" / (_task_name(t, m, predictor) + ".json")).exists() for m in methods
        )
    ]
    run_tasks(
        _group_job,
        args,
        jobs=jobs,
        executor=executor,
        address=address,
        progress=progress,
        desc="ngsim",
        unit="task",
        isolate=isolate,
    )
    return write_results(out)
