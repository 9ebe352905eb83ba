"""Receding-horizon driving with any planner of :mod:`mmdopt`: plan, execute δ seconds, replan.

::

    import jax, mmdopt
    from mmdopt.receding import RecedingConfig, run_receding

    result = run_receding(source, RecedingConfig(dt=0.5, method="mmd"), config=cfg,
                          key=jax.random.PRNGKey(0))
    result.crashed, result.plan_times, result.n_over_budget, result.steps[0].status

``source`` is any *scene source* (:class:`SceneSource`): a simulator adapter, a replay of recorded
traffic, a synthetic scene.  Each step the loop

1. ``obs = source.observe()``: the ego's Frenet state, the road, and samples of the obstacles'
   futures ``(O, n, K, 2)`` (Cartesian, on the planner's time grid; from any predictor);
2. plans with ``planner.plan`` (any :class:`PlansLike`; default the cached
   :class:`~mmdopt.Planner` of ``config``; ``method`` a name of :mod:`mmdopt.methods`),
   warm-started from the previous step's Algorithm 1 state shifted by δ (``plan(..., warm_start=
   algorithm.shift(previous.state, δ))``: the sampling mean, covariance and elites re-timed; the
   first step, and a step after a braking fallback, start cold);
3. ``source.step(plan, δ)`` executes the first δ seconds of the plan and says whether the episode
   is over and whether the ego crashed (the source's own collision checker decides).

The per-step time budget is reported, not enforced: every step records its plan time, and a step
whose plan took longer than ``budget_s`` counts as over budget (in a real car the previous plan
would still be executing).  The method is the library's: nothing here knows a simulator, a file
format or :mod:`mmdopt.bench`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import jax
import numpy as np

import frenet

from . import algorithm
from . import methods as registry
from .algorithm import PLANNER_PROJECTOR, MMDOptConfig
from .padding import pad_obstacles
from .planner import PLANNERS, apply_risk, draw_forecast
from .plans import Plan, PlanStatus, Road
from .predict.base import Forecast
from .safety import RSSConfig, obstacle_states_from_cartesian, obstacle_states_from_samples
from .safety import shield as rss_shield
from .validate import check_obstacle_headings

__all__ = [
    "Observation",
    "StepOutcome",
    "SceneSource",
    "RecedingConfig",
    "StepRecord",
    "RecedingResult",
    "run_receding",
    "PlansLike",
    "pad_obstacles",
    "warm_up",
]


@dataclass(frozen=True, eq=False)
class Observation:
    """What a scene source reports before each plan.

    ego : :class:`frenet.EgoState` in the Frenet frame of ``road.path``
    road : :class:`mmdopt.Road` (path, lane bounds, kinematic limits)
    obstacles : (O, n, K, 2) Cartesian samples of the obstacles' futures on the planner's grid
        (``K = config.trajectory.num_steps`` over ``config.trajectory.horizon``; ``t = 0`` is
        now); O may be 0 (an empty road: with the time-linear margins the loop pads with
        phantom obstacles far behind, see :func:`pad_obstacles`; on the risk dial it never
        pads, and an empty road is planned as one, status ``ok`` with a bound of 0).  Or a
        :class:`mmdopt.predict.Forecast`: the loop draws from it as :func:`mmdopt.plan` would
        (n(ε) futures per obstacle in the "samples" margin mode, ``min_samples`` with the
        time-linear margins; the plan's key), then plans and shields on the drawn futures, and
        hands the callback the observation with them
    time : simulation time (s)
    info : anything the source wants recorded with the step (e.g. ``predict_s``, the predictor's
        wall time)
    obstacle_states : optional ``(M, 4)`` Cartesian ``(x, y, vx, vy)`` of the obstacles now, for
        the safety shield (:mod:`mmdopt.safety`); may list more cars than ``obstacles`` (all
        that the sensors see).  ``None``: the shield derives them from the samples at the first
        two grid times
    frame_changed : the road's Frenet frame is not the previous observation's (a new reference
        line, e.g. the centre line of the lane the ego has moved into): the previous plan's warm
        start is in the old frame, so the loop plans this step cold
    obstacle_headings : optional (O,) Cartesian body heading of each obstacle now (rad), in the
        order of ``obstacles``: passed to :func:`mmdopt.plan` (``obstacle_headings``), so a car
        at rest is planned against along its real axis (phantoms added by the loop get the
        path's direction)
    crossings : optional ``(C, 3)`` conflict areas of crossing routes for the safety shield,
        in ``road.path``'s frame: ``(s_in, s_out, t_arrive)``, the interval of the ego's arc
        length (centre positions, inflated by both cars' half lengths) where another car's
        predicted route crosses the ego's path and the earliest time (s from now) that car could
        reach it (:func:`mmdopt.safety.check_crossings`).  ``None``: no crossing rule
    """

    ego: frenet.EgoState
    road: Road
    obstacles: np.ndarray
    time: float = 0.0
    info: dict = field(default_factory=dict)
    obstacle_states: np.ndarray | None = None
    frame_changed: bool = False
    obstacle_headings: np.ndarray | None = None
    crossings: np.ndarray | None = None


@dataclass(frozen=True)
class StepOutcome:
    """What a scene source reports after executing δ seconds of a plan."""

    done: bool
    crashed: bool
    info: dict = field(default_factory=dict)


@runtime_checkable
class SceneSource(Protocol):
    """A world the ego drives in (simulator adapter, replay, synthetic scene)."""

    def observe(self) -> Observation:
        """The current ego state, road and obstacle predictions."""
        ...

    def step(self, trajectory: Plan, dt: float) -> StepOutcome:
        """Execute the first ``dt`` seconds of ``trajectory``; report done/crashed."""
        ...


@runtime_checkable
class PlansLike(Protocol):
    """Anything that plans a step of the loop: :class:`mmdopt.Planner` is one.  ``plan`` takes
    the observation's ego, road and obstacle samples ``(O, n, K, 2)`` and the keywords
    ``method``, ``projector``, ``key`` and, when given, ``warm_start`` (the previous plan's
    :meth:`~mmdopt.Plan.next` state, or ``None`` after a plan without one) and
    ``obstacle_headings``; it returns an :class:`mmdopt.Plan`.  A ``config`` attribute, when
    present, is the loop's default config."""

    def plan(self, ego: frenet.EgoState, road: Road, obstacles: Any, **kwargs: Any) -> Plan: ...


@dataclass(frozen=True)
class RecedingConfig:
    """Settings of the receding-horizon loop (the planner's own settings are an
    :class:`mmdopt.MMDOptConfig`).

    dt : δ, seconds of each plan executed before replanning (> 0, at most the planner's horizon)
    max_steps : at most this many replans (the source may end the episode earlier)
    budget_s : per-step plan-time budget (s); longer plans are counted, not cut
    method : planning method (a name of :func:`mmdopt.methods.names`)
    projector : the projection of :func:`mmdopt.plan` (default: the planner's jitted
        projector, :data:`mmdopt.algorithm.PLANNER_PROJECTOR`; or a :mod:`solvers` backend)
    warm_start : warm-start each plan from the previous solution shifted by δ (False: all cold)
    max_obstacles : pad/truncate the obstacle axis to this many (``None``: as observed).  A fixed
        O keeps the jitted planner from recompiling for every new number of neighbours.
    shield : :class:`mmdopt.safety.RSSConfig` to check every plan against RSS's longitudinal safe
        distance before it runs and brake (a checked fallback) when it fails
        (:func:`mmdopt.safety.shield`); also against the crossings of
        :attr:`Observation.crossings` when given, and with ``RSSConfig.lateral`` RSS's lateral
        distance to the cars of :attr:`Observation.obstacle_states`; ``None`` (default): plans
        run unchecked
    """

    dt: float = 0.5
    max_steps: int = 10_000
    budget_s: float = 0.5
    method: str = "mmd"
    projector: str = PLANNER_PROJECTOR
    warm_start: bool = True
    max_obstacles: int | None = None
    shield: RSSConfig | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.dt, int | float) and math.isfinite(self.dt) and self.dt > 0):
            raise ValueError(
                f"RecedingConfig.dt must be a positive number of seconds, got {self.dt!r}"
            )
        if (
            isinstance(self.max_steps, bool)
            or not isinstance(self.max_steps, int)
            or self.max_steps < 1
        ):
            raise ValueError(
                f"RecedingConfig.max_steps must be an int >= 1, got {self.max_steps!r}"
            )
        if not (isinstance(self.budget_s, int | float) and self.budget_s > 0):
            raise ValueError(f"RecedingConfig.budget_s must be > 0, got {self.budget_s!r}")
        registry.get(self.method, "RecedingConfig.method")
        if self.max_obstacles is not None and (
            isinstance(self.max_obstacles, bool)
            or not isinstance(self.max_obstacles, int)
            or self.max_obstacles < 1
        ):
            raise ValueError(
                "RecedingConfig.max_obstacles must be None or an int >= 1, got "
                f"{self.max_obstacles!r}"
            )
        if self.shield is not None and not isinstance(self.shield, RSSConfig):
            raise ValueError(
                "RecedingConfig.shield must be None or an mmdopt.safety.RSSConfig, got "
                f"{type(self.shield).__name__}"
            )


@dataclass(frozen=True)
class StepRecord:
    """One replan: simulation time, plan time and outcome (JSON-friendly scalars); ``info`` is
    the observation's, ``timings`` the plan's own (``reduced_set_s``, ``cem_s``, ...);
    ``intervened``: the safety shield replaced the plan by its braking fallback, ``shield`` why
    and how hard it brakes, and whether even that braking fails the check (empty without a shield
    or when the plan passed).  ``cost``, ``feasible``, ``fallback``, ``status`` and
    ``risk_bound`` (:attr:`mmdopt.Plan.risk_bound`) are the planner's, before the shield."""

    time: float
    plan_time_s: float
    over_budget: bool
    warm_started: bool
    n_obstacles: int
    cost: float
    feasible: bool
    fallback: bool
    status: str
    speed: float
    s: float
    d: float
    info: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    intervened: bool = False
    shield: str = ""
    risk_bound: float = float("nan")


@dataclass
class RecedingResult:
    """The record of one receding-horizon run."""

    steps: list[StepRecord]
    crashed: bool
    done: bool
    budget_s: float
    final_info: dict = field(default_factory=dict)

    @property
    def plan_times(self) -> np.ndarray:
        """(steps,) wall time of each plan (s)."""
        return np.array([r.plan_time_s for r in self.steps], dtype=np.float64)

    @property
    def n_over_budget(self) -> int:
        return int(sum(r.over_budget for r in self.steps))

    def summary(self) -> dict[str, Any]:
        pt = self.plan_times
        return {
            "steps": len(self.steps),
            "crashed": bool(self.crashed),
            "done": bool(self.done),
            "mean_plan_s": float(pt.mean()) if pt.size else float("nan"),
            "median_plan_s": float(np.median(pt)) if pt.size else float("nan"),
            "max_plan_s": float(pt.max()) if pt.size else float("nan"),
            "over_budget": self.n_over_budget,
            "budget_s": float(self.budget_s),
            "fallbacks": int(sum(r.fallback for r in self.steps)),
            "interventions": int(sum(r.intervened for r in self.steps)),
        }


# ------------------------------------------------------------------------------------ helpers
def _drawn(obs: Observation, rc: RecedingConfig, config: MMDOptConfig, key):
    """``obs`` with its obstacles as an array: a :class:`~mmdopt.predict.Forecast` (its first
    ``rc.max_obstacles``) is drawn from exactly as :func:`mmdopt.plan` draws it with ``key``;
    returns the observation and the draw's diagnostics (none for an array)."""
    fc = obs.obstacles
    if not isinstance(fc, Forecast):
        return obs, {}
    if rc.max_obstacles is not None and fc.num_obstacles > rc.max_obstacles:
        keep = np.arange(rc.max_obstacles)
        fc = dataclasses.replace(
            fc, history=fc.history[keep], context=fc.context.subset(keep)
        )  # fmt: skip
    arr, diag = draw_forecast(fc, apply_risk(rc.method, None, config), rc.method, key)
    info = dict(obs.info, predict_s=diag["forecast_s"])
    return dataclasses.replace(obs, obstacles=arr, info=info), diag


def _observed_headings(obs: Observation) -> np.ndarray | None:
    """``obs.obstacle_headings`` checked against the observed obstacles (before the loop cuts or
    pads them); ``None`` when not given."""
    if obs.obstacle_headings is None:
        return None
    fc = obs.obstacles
    O = fc.num_obstacles if isinstance(fc, Forecast) else int(np.shape(fc)[0])
    return check_obstacle_headings(obs.obstacle_headings, O)


def _plan_once(obs: Observation, rc: RecedingConfig, planner, config: MMDOptConfig, key, warm,
               t_grid):  # fmt: skip
    """One plan of the loop: ``(plan, warm start used, obs with its obstacles drawn)``; the
    plan time covers ``planner.plan`` only (a forecast's draw is the observation's
    ``info["predict_s"]``).  On the risk dial (the "samples" margin mode) the obstacles, drawn
    from a forecast or given as arrays, are cut to ``rc.max_obstacles`` but never padded with
    phantoms: they would count as obstacles in the plan's risk bound, and an empty road would
    no longer be the planner's own case (status ``ok``, a bound of 0) but phantoms whose few
    samples support no ε (``risk floor``)."""
    heads = _observed_headings(obs)
    obs, drawn = _drawn(obs, rc, config, key)
    num = rc.max_obstacles
    if config.safety.margins.margin_mode == "samples":  # the real obstacles only, maybe none
        O = int(np.shape(obs.obstacles)[0])
        num = O if num is None else min(O, num)
    obstacles = pad_obstacles(obs.obstacles, num, obs.ego, obs.road, t_grid)
    kw: dict[str, Any] = dict(method=rc.method, projector=rc.projector, key=key)
    if heads is not None and obstacles.shape[0] > 0:
        # cut as the obstacles were; phantoms along the path at the ego
        O = obstacles.shape[0]
        pad = float(np.asarray(obs.road.path.heading(np.asarray([obs.ego.s])))[0])
        kw["obstacle_headings"] = np.concatenate(
            [heads[:O], np.full(max(O - heads.shape[0], 0), pad)]
        )
    warm_used = rc.warm_start and warm is not None
    if warm_used:
        kw["warm_start"] = warm
    t0 = time.perf_counter()
    p = planner.plan(obs.ego, obs.road, obstacles, **kw)
    if not isinstance(p, Plan):
        raise ValueError(f"planner.plan must return an mmdopt.Plan, got {type(p).__name__}")
    p.diagnostics.update(drawn, plan_wall_s=time.perf_counter() - t0)
    return p, warm_used, obs


def _shifted(p: Plan, dt: float):
    """The warm start for the next plan: the plan's Algorithm 1 state shifted by ``dt``
    (:func:`mmdopt.algorithm.shift`); ``None`` for a plan without state (a braking fallback)."""
    state = getattr(p, "state", None)
    return None if state is None else algorithm.shift(p.config, state, dt)


def _shielded(p: Plan, obs: Observation, rc: RecedingConfig, t_grid: np.ndarray):
    """``rc.shield`` applied to ``p``: the obstacles' current Frenet states from
    ``obs.obstacle_states`` when given, else from the prediction samples; the crossing rule on
    ``obs.crossings`` when given; with ``rc.shield.lateral`` and ``obs.obstacle_states``, the
    lateral rule on those cars' lateral states too.  A plan of status ``unsafe`` is replaced by
    the shield's checked braking even when it passes the rules."""
    path = obs.road.path
    lateral_states = None
    if obs.obstacle_states is not None:
        states = obstacle_states_from_cartesian(path, obs.obstacle_states)
        if rc.shield.lateral:
            lateral_states = obstacle_states_from_cartesian(path, obs.obstacle_states, lateral=True)
    else:
        states = obstacle_states_from_samples(path, obs.obstacles, t_grid)
    # a plan its planner reports unsafe (it meets every future of some car) is not run on the
    # strength of the rules alone: the shield brakes, along its checked fallbacks
    unsafe = p.status == PlanStatus.UNSAFE
    replace = f"the planner reports the plan unsafe ({p.message})" if unsafe else ""
    return rss_shield(
        p,
        path,
        states,
        rc.shield,
        executed=rc.dt,
        lane_centres=obs.road.lane_centres,
        crossings=obs.crossings,
        lateral_states=lateral_states,
        replace=replace,
    )


def warm_up(
    obs: Observation,
    receding: RecedingConfig,
    config: MMDOptConfig | None = None,
    key=None,
    *,
    planner: PlansLike | None = None,
    counts=None,
) -> float:
    """Compile the planner for the loop's shapes before timing it: one cold plan on ``obs`` and,
    when warm starts are used, one warm-started plan (a different traced input).  Returns the
    wall time (s), i.e. mostly JIT compilation.  Results are discarded; the loop's own plans are
    unaffected (they use their own keys).  ``planner`` as in :func:`run_receding`.

    ``counts``: also compile for these numbers of obstacles (ints >= 1), planning on the
    futures drawn for ``obs`` with its obstacles repeated or cut to each count.  On the risk
    dial the loop never pads with phantoms, so each number of cars it meets is a shape of its
    own; warmed up here, a car entering or leaving the scene costs a plan, not a compile (with
    the time-linear margins the loop pads to ``max_obstacles``: one shape, no counts needed).
    Nothing is done for the counts when ``obs`` has no obstacles."""
    planner, config = _planner_of(planner, config)
    key = jax.random.PRNGKey(0) if key is None else key
    ks = _check_counts(counts)
    t_grid = frenet.TimeGrid(config.trajectory.horizon, config.trajectory.num_steps).t

    def cold_and_warm(o):  # a cold plan and, with warm starts, a warm-started one
        p, _, drawn = _plan_once(o, receding, planner, config, key, None, t_grid)
        warm = _shifted(p, receding.dt) if receding.warm_start else None
        if warm is not None:
            _plan_once(o, receding, planner, config, key, warm, t_grid)
        return drawn

    t0 = time.perf_counter()
    drawn = cold_and_warm(obs)
    arr = np.asarray(drawn.obstacles)
    O = int(arr.shape[0])
    heads = _observed_headings(obs)
    for k in ks if O > 0 else ():
        if k == O:
            continue
        idx = np.resize(np.arange(O), k)  # the cars in turn: 0, 1, …, O − 1, 0, …
        variant = dataclasses.replace(
            drawn, obstacles=arr[idx], obstacle_states=None,
            obstacle_headings=None if heads is None else heads[:O][idx],
        )  # fmt: skip
        cold_and_warm(variant)
    return time.perf_counter() - t0


def _check_counts(counts) -> list[int]:
    if counts is None:
        return []
    try:
        given = list(counts)
    except TypeError:
        raise ValueError(f"counts must be an iterable of ints >= 1, got {counts!r}") from None
    if any(isinstance(c, bool) or not isinstance(c, int | np.integer) or c < 1 for c in given):
        raise ValueError(f"counts must be ints >= 1, got {given!r}")
    return sorted({int(c) for c in given})


# ------------------------------------------------------------------------------------ the loop
def _planner_of(planner: Any, config: Any) -> tuple[Any, MMDOptConfig]:
    """The loop's planner and config: the cached :class:`~mmdopt.Planner` of ``config`` when no
    planner is given; a given planner's own ``config`` (when it has one) unless ``config``
    disagrees."""
    if planner is None:
        config = MMDOptConfig() if config is None else config
        if not isinstance(config, MMDOptConfig):
            raise ValueError(f"config must be an mmdopt.MMDOptConfig, got {type(config).__name__}")
        return PLANNERS.get(config), config
    if not callable(getattr(planner, "plan", None)):
        raise ValueError(
            f"planner must have a plan(ego, road, obstacles, *, method, projector, key, ...) "
            f"method (an mmdopt.Planner or a PlansLike), got {type(planner).__name__}"
        )
    own = getattr(planner, "config", None)
    if config is None:
        config = own if isinstance(own, MMDOptConfig) else MMDOptConfig()
    elif not isinstance(config, MMDOptConfig):
        raise ValueError(f"config must be an mmdopt.MMDOptConfig, got {type(config).__name__}")
    elif isinstance(own, MMDOptConfig) and own is not config and own != config:
        raise ValueError("config differs from planner.config: pass one of them")
    return planner, config


def run_receding(
    source: SceneSource,
    receding: RecedingConfig | None = None,
    *,
    config: MMDOptConfig | None = None,
    key=None,
    callback=None,
    planner: PlansLike | None = None,
) -> RecedingResult:
    """Drive ``source`` with the receding-horizon loop until it reports done or crashed.

    Parameters
    ----------
    source : a :class:`SceneSource`
    receding : :class:`RecedingConfig` (δ, budget, method, ...)
    config : the planner's :class:`MMDOptConfig` (default: ``planner.config``, else
        ``MMDOptConfig()``); it sets the time grid the loop pads and shifts on
    planner : what plans each step: an :class:`mmdopt.Planner`, or any object with its
        ``plan`` signature (:class:`PlansLike`: a policy that is not MMD-Opt, a wrapper that
        logs); default the cached planner of ``config`` (what :func:`mmdopt.plan` uses)
    key : jax PRNG key; step ``i`` plans with ``fold_in(key, i)``, so the same key and the same
        source give the same run
    callback : optional ``callback(step_index, observation, plan, outcome)`` after each step

    Returns
    -------
    :class:`RecedingResult`: per-step records (plan time, over budget, status), crashed, done.
    """
    rc = RecedingConfig() if receding is None else receding
    if not isinstance(rc, RecedingConfig):
        raise ValueError(f"receding must be a RecedingConfig, got {type(rc).__name__}")
    planner, config = _planner_of(planner, config)
    if rc.dt > config.trajectory.horizon:
        raise ValueError(
            f"RecedingConfig.dt = {rc.dt} s exceeds the planner's horizon "
            f"{config.trajectory.horizon} s"
        )
    if not (callable(getattr(source, "observe", None)) and callable(getattr(source, "step", None))):
        raise ValueError("source must have observe() and step(trajectory, dt) (a SceneSource)")
    key = jax.random.PRNGKey(0) if key is None else key
    t_grid = frenet.TimeGrid(config.trajectory.horizon, config.trajectory.num_steps).t
    steps: list[StepRecord] = []
    warm = None
    crashed = done = False
    final: dict = {}
    for i in range(rc.max_steps):
        obs = source.observe()
        if not isinstance(obs, Observation):
            raise ValueError(f"source.observe() must return an Observation, got {type(obs)!r}")
        if obs.frame_changed:
            warm = None
        p, warm_used, obs = _plan_once(
            obs, rc, planner, config, jax.random.fold_in(key, i), warm, t_grid
        )
        plan_s = p.diagnostics["plan_wall_s"]
        planned, shield_rec = p, None
        if rc.shield is not None:
            t1 = time.perf_counter()
            p, shield_rec = _shielded(planned, obs, rc, t_grid)
            planned.diagnostics["shield_s"] = time.perf_counter() - t1
        out = source.step(p, rc.dt)
        steps.append(
            StepRecord(
                time=float(obs.time),
                plan_time_s=plan_s,
                over_budget=plan_s > rc.budget_s,
                warm_started=warm_used,
                n_obstacles=int(np.asarray(obs.obstacles).shape[0]),
                cost=float(planned.cost),
                feasible=bool(planned.feasible),
                fallback=bool(planned.fallback),
                status=planned.status_text,
                speed=float(p.speed[0]),
                s=float(p.s[0]),
                d=float(p.d[0]),
                info=dict(obs.info),
                timings={
                    k: float(v)
                    for k, v in planned.diagnostics.items()
                    if k.endswith("_s") and isinstance(v, int | float)
                },
                intervened=bool(shield_rec is not None and shield_rec.intervened),
                shield=p.message if shield_rec is not None and shield_rec.intervened else "",
                risk_bound=float(getattr(planned, "risk_bound", float("nan"))),
            )
        )
        if callback is not None:
            callback(i, obs, p, out)
        if rc.warm_start:
            warm = _shifted(p, rc.dt)
        crashed, done, final = bool(out.crashed), bool(out.done), dict(out.info)
        if crashed or done:
            break
    return RecedingResult(
        steps=steps, crashed=crashed, done=done, budget_s=rc.budget_s, final_info=final
    )
