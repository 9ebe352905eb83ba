"""Public planning API: :class:`Road`, :class:`Plan`, :func:`plan` and :func:`plan_frenet`.

::

    import jax, mmdopt, frenet
    road = mmdopt.Road(path=frenet.ReferencePath.straight(1000.0), y_lb=-0.3, y_ub=0.3)
    ego = frenet.EgoState(s=0.0, d=0.0, vs=10.0)
    p = mmdopt.plan(ego, road, obstacles, method="mmd", key=jax.random.PRNGKey(0))
    p.x, p.y, p.speed, p.cost, p.feasible, p.status

``obstacles`` are samples of the obstacles' future trajectories from any predictor, ``(O, n, K, 2)``
Cartesian ``(x, y)`` on the planner's time grid (``K = config.trajectory.num_steps``).
"""

from __future__ import annotations

import dataclasses
import enum
import math
import time
import warnings
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike, NDArray

import frenet
import solvers

from . import algorithm as alg
from ._checks import check_key
from ._x64 import x64
from .algorithm import PLANNER_PROJECTOR, MMDOptConfig, n_taylor_terms, planning_semi_axis
from .baselines import COLLISION_TERM, PLAN_METHODS, SELECTOR, select_for_method
from .collision import (
    OBSTACLE_FOOTPRINT,
    circle_centres,
    collision_free_count,
    ellipse_values,
    headings,
    mmd_cost,
)
from .predict.base import Forecast
from .risk import risk_bound, risk_floor, samples_for_risk
from .samples import ReducedSet, check_reduced_set

__all__ = [
    "Road",
    "Plan",
    "PlanStatus",
    "Planner",
    "plan",
    "plan_frenet",
    "PLAN_METHODS",
    "PLANNERS",
    "PLANNER_PROJECTOR",
]

#: largest accepted |coordinate| of obstacle samples (m): beyond it positions are not a scene
MAX_COORD = 1e7


def _straight_path() -> frenet.ReferencePath:
    return frenet.ReferencePath.straight(1000.0)


@dataclass(frozen=True, eq=False)
class Road:
    """The road the ego drives on: reference path, lane bounds and kinematic limits (SI units).

    path : :class:`frenet.ReferencePath` (default: straight along +x from the origin, 1 km, so
        Frenet = Cartesian near it).
    y_lb, y_ub : bounds of the ego's lateral offset in the path's Frenet frame (m); the reference
        experiments use ±0.3 (lane keeping: speed changes only).
    v_min, v_max : bounds of the longitudinal speed ṡ (m/s).
    vy_max : bound of |ḋ| (m/s; ``inf`` = none).
    ax_max, ay_max : bounds of |s̈|, |d̈| (m/s²).
    lane_centres : lateral offsets of the lane centres in the path's Frenet frame (m; empty: no
        lanes).  With ``MMDOptConfig.cost.w_lane > 0`` the planner's cost penalises the distance
        to the nearest lane centre (lane discipline, :func:`mmdopt.algorithm.lane_cost`).
    """

    path: frenet.ReferencePath = field(default_factory=_straight_path)
    y_lb: float = -0.3
    y_ub: float = 0.3
    v_min: float = 0.0
    v_max: float = 30.0
    vy_max: float = float("inf")
    ax_max: float = 6.0
    ay_max: float = 4.0
    lane_centres: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.path, frenet.ReferencePath):
            raise ValueError(f"Road.path must be a frenet.ReferencePath, got {type(self.path)!r}")
        for name in ("y_lb", "y_ub", "v_min", "v_max", "vy_max", "ax_max", "ay_max"):
            v = getattr(self, name)
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise ValueError(f"Road.{name} must be a real number, got {v!r}") from None
            if np.isnan(v):
                raise ValueError(f"Road.{name} is NaN")
            object.__setattr__(self, name, v)
        if self.y_lb > self.y_ub:
            raise ValueError(f"Road.y_lb = {self.y_lb} > y_ub = {self.y_ub}")
        if self.v_min > self.v_max:
            raise ValueError(f"Road.v_min = {self.v_min} > v_max = {self.v_max}")
        for name in ("vy_max", "ax_max", "ay_max"):
            if getattr(self, name) <= 0:
                raise ValueError(f"Road.{name} must be > 0")
        try:
            lanes = tuple(float(c) for c in np.ravel(np.asarray(self.lane_centres, dtype=float)))
        except (TypeError, ValueError):
            raise ValueError(
                f"Road.lane_centres must be a sequence of real numbers, got {self.lane_centres!r}"
            ) from None
        if not all(np.isfinite(lanes)):
            raise ValueError(f"Road.lane_centres must be finite, got {lanes}")
        object.__setattr__(self, "lane_centres", tuple(sorted(lanes)))

    def bounds(self) -> frenet.ProjectionBounds:
        """The projection's :class:`frenet.ProjectionBounds`."""
        return frenet.ProjectionBounds(
            y_lb=self.y_lb,
            y_ub=self.y_ub,
            vx_min=self.v_min,
            vx_max=self.v_max,
            vy_max=self.vy_max,
            ax_max=self.ax_max,
            ay_max=self.ay_max,
        )


class PlanStatus(enum.StrEnum):
    """What a :class:`Plan` is, in one word (its :attr:`Plan.message` says why).

    =================  ======================================================================
    status             meaning
    =================  ======================================================================
    ``OK``             Algorithm 1's lowest-cost plan: within the road and kinematic bounds
                       (residual ≤ ``res_tol`` on the time grid), clear of at least one
                       planning sample of every obstacle and, when a risk level ε is asked
                       (the "samples" margin mode, the default), with
                       ``Plan.risk_bound`` ≤ ε
    ``RISK_FLOOR``     as OK, but ε is below what the planning samples can confirm: even a
                       plan that meets none of them has a bound above ε
                       (``mmdopt.risk.risk_floor``); the message says how many samples
                       per obstacle would (``mmdopt.risk.samples_for_risk``)
    ``RISK_EXCEEDED``  as OK, but the plan meets so many planning samples that its bound
                       exceeds ε
    ``INACCURATE``     chosen as feasible, but its residual on the full time grid exceeds
                       ``res_tol`` (the projection's constraint points passed, the grid did
                       not)
    ``UNSAFE``         feasible, but it collides with every planning sample of some
                       obstacle: no collision-free plan was found
    ``FALLBACK``       no plan of Algorithm 1 could be used (an initial state beyond the
                       bounds, no sample meeting the constraints, a non-finite cost): a
                       braking or the least-violating plan is returned
    =================  ======================================================================

    A ``StrEnum``: ``plan.status == "ok"`` and ``str(plan.status)`` work as strings.
    """

    OK = "ok"
    RISK_FLOOR = "risk floor"
    RISK_EXCEEDED = "risk exceeded"
    INACCURATE = "inaccurate"
    UNSAFE = "unsafe"
    FALLBACK = "fallback"


def _risk_counts(config: MMDOptConfig, colliding) -> np.ndarray:
    """The counts a plan's risk bound is computed from, given the (O, n) planning samples it
    meets: (1,) the joint futures it meets with any obstacle (``safety.joint_futures``), else
    (O,) the samples of each obstacle (:func:`mmdopt.risk.risk_bound`)."""
    hits = np.asarray(colliding, bool)
    if config.bound_groups(hits.shape[0]) == 1:
        return hits.any(0).sum(keepdims=True)
    return hits.sum(-1)


def _plan_bound(config: MMDOptConfig, colliding) -> float:
    """The 95 % risk bound of a plan meeting the (O, n) planning samples ``colliding``."""
    counts = _risk_counts(config, colliding)
    return risk_bound(counts, [np.shape(colliding)[-1]] * counts.size)


def _risk_status(config: MMDOptConfig, bound: float, colliding) -> str:
    """The status of a plan that is otherwise OK against the requested risk level
    ``config.safety.risk``; ``colliding`` (O, n) the planning samples it meets, ``bound`` its
    :func:`_plan_bound`."""
    eps = float(config.safety.risk)
    hits = np.asarray(colliding, bool)
    (O, n), counts = hits.shape, _risk_counts(config, hits)
    groups = counts.size
    floor = risk_floor([n] * groups)
    if O == 1:
        who = f"the {n} samples of the obstacle"
    elif groups == 1:
        who = f"the {n} joint futures of the {O} obstacles"
    else:
        who = f"the {n} samples of each of the {O} obstacles"
    if eps < floor:
        return (
            f"risk floor: asked {eps:.3g}, {who} support {floor:.2g} at best "
            f"(95 % bound with no sample met); {samples_for_risk(eps, groups)} samples per "
            "obstacle would support it"
        )
    if bound > eps:
        what = "joint futures" if groups == 1 and O > 1 else "planning sample(s)"
        return (
            f"risk exceeded: asked {eps:.3g}, the plan meets {int(counts.sum())} {what} "
            f"({', '.join(str(int(h)) for h in hits.sum(-1))} of {n} per obstacle): its 95 % "
            f"bound is {bound:.2g}"
        )
    return "ok"


def _split_status(text: str) -> tuple[PlanStatus, str]:
    """``"fallback: why"`` -> ``(PlanStatus.FALLBACK, "why")``."""
    head, _, why = text.partition(":")
    return PlanStatus(head.strip()), why.strip()


@dataclass(frozen=True, eq=False)
class Plan:
    """A planned trajectory and how it was found.  Arrays are NumPy float64, ``(K,)``.

    Cartesian: ``x, y, heading`` (rad), ``speed`` (m/s).  Frenet: ``s, d`` (m), ``vs, vd`` (m/s),
    ``as_, ad`` (m/s²).  ``cost``: Algorithm 1's cost of the plan; ``cost_trace`` (N,): best-so-far
    cost after each iteration (non-increasing); ``residual``: max constraint violation on the time
    grid; ``mmd``: l_dist of the plan against the method's obstacle samples (config's kernel);
    ``feasible``: ``residual ≤ config.projection.res_tol``; ``fallback``/``status``: see
    :func:`plan`;
    ``reduced_set``: the obstacle samples used by the cost (a :class:`ReducedSet` with leading
    axis O; all n samples for "saa"/"scenario_all"); ``plan_time_s``: wall time of the call;
    ``diagnostics``: timings, per-iteration traces, the behavioural input ``d``, collision term,
    progress, residual groups, collision-free count against the planning samples; ``state``: the
    final :class:`mmdopt.algorithm.CEMState` (``None`` for a braking fallback), to warm-start the
    next plan with ``plan(..., warm_start=mmdopt.algorithm.shift(p.state, dt))``.

    ``status``: a :class:`PlanStatus` (OK, INACCURATE, UNSAFE, FALLBACK) and ``message`` why
    (empty when OK); ``status_text`` joins them (``"fallback: no sample met …"``);
    ``risk_bound``: an upper bound, at 95 % confidence, on the probability that the plan meets an
    obstacle, from the planning samples it meets (:func:`mmdopt.risk.risk_bound`: Clopper–Pearson
    on the joint futures it meets, sample i of every obstacle being one draw of the scene, or
    with ``safety.joint_futures = False`` per obstacle and a union bound over obstacles; its
    assumptions are stated there);
    ``fallback`` is ``status == FALLBACK``.  ``config``: the config the plan was made with
    (after the risk mapping), for :meth:`next`.
    """

    x: NDArray[np.float64]
    y: NDArray[np.float64]
    heading: NDArray[np.float64]
    speed: NDArray[np.float64]
    s: NDArray[np.float64]
    d: NDArray[np.float64]
    vs: NDArray[np.float64]
    vd: NDArray[np.float64]
    as_: NDArray[np.float64]
    ad: NDArray[np.float64]
    t: NDArray[np.float64]
    cost: float
    cost_trace: NDArray[np.float64]
    residual: float
    mmd: float
    feasible: bool
    status: PlanStatus
    message: str
    method: str
    projector: str
    reduced_set: ReducedSet | None
    plan_time_s: float
    risk_bound: float = float("nan")
    diagnostics: dict[str, Any] = field(repr=False, default_factory=dict)
    state: alg.CEMState | None = field(repr=False, default=None)
    config: MMDOptConfig | None = field(repr=False, default=None)

    @property
    def xy(self) -> NDArray[np.float64]:
        """(K, 2) Cartesian waypoints."""
        return np.stack([self.x, self.y], axis=-1)

    @property
    def fallback(self) -> bool:
        """Whether a braking or least-violating fallback was returned (``status`` FALLBACK)."""
        return self.status is PlanStatus.FALLBACK

    @property
    def status_text(self) -> str:
        """The status and its message as one line: ``"ok"``, ``"fallback: why"``, …"""
        return str(self.status) if not self.message else f"{self.status}: {self.message}"

    @property
    def progress(self) -> float:
        """Arc length travelled over the horizon (m)."""
        return float(self.s[-1] - self.s[0])

    def ego_at(self, t: float) -> frenet.EgoState:
        """The planned Frenet state at ``t`` seconds from now (0 ≤ t ≤ horizon), linearly
        interpolated between the grid points (the grid need not contain ``t``)."""
        t = _check_time(t, float(self.t[-1]), "t")
        at = {k: float(np.interp(t, self.t, getattr(self, k))) for k in _FRENET_KEYS}
        return frenet.EgoState(**at)

    def next(self, dt: float) -> tuple[frenet.EgoState, alg.CEMState | None]:
        """Replanning in one line: the state ``dt`` seconds ahead and the warm start for the
        next ``plan(..., warm_start=...)`` (this plan's sampling distribution and elites moved
        ``dt`` forward, :func:`mmdopt.algorithm.shift`; ``None`` after a braking fallback, which
        has no Algorithm 1 state)::

            ego, warm = p.next(0.5)
            p = mmdopt.plan(ego, road, new_obstacles, config=config, warm_start=warm)
        """
        dt = _check_time(dt, float(self.t[-1]), "dt")
        warm = None
        if self.state is not None and self.config is not None:
            warm = alg.shift(self.config, self.state, dt)
        return self.ego_at(dt), warm

    def to_dict(self, diagnostics: bool = True) -> dict[str, Any]:
        """The plan as plain JSON-able data (``json.dumps(plan.to_dict())`` works).

        Keys: the trajectory arrays ``t, x, y, heading, speed, s, d, vs, vd, as_, ad`` as lists
        of floats (SI units, as on the :class:`Plan`); the scalars ``cost, residual, mmd,
        progress, plan_time_s`` (floats; a NaN cost, as in a braking fallback, is ``None``),
        ``cost_trace`` (list), ``feasible, fallback`` (bool), ``status, message, method,
        projector`` (str);
        ``reduced_set``: ``{"method", "indices": [[int]] (O, m), "weights": [[float]] (O, m),
        "mmd2": [float] (O,)}`` (``None`` if the plan has none); and, with ``diagnostics=True``,
        ``diagnostics`` with every array as (nested) lists.  The final ``state``
        (:class:`~mmdopt.algorithm.CEMState`) is left out: it is for warm starts, not records.
        """
        out: dict[str, Any] = {
            k: _jsonable(getattr(self, k))
            for k in ("t", "x", "y", "heading", "speed", "s", "d", "vs", "vd", "as_", "ad")
        }
        out.update(
            cost=_jsonable(self.cost),
            cost_trace=_jsonable(self.cost_trace),
            residual=_jsonable(self.residual),
            risk_bound=_jsonable(self.risk_bound),
            mmd=_jsonable(self.mmd),
            progress=_jsonable(self.progress),
            plan_time_s=_jsonable(self.plan_time_s),
            feasible=bool(self.feasible),
            fallback=bool(self.fallback),
            status=str(self.status),
            message=str(self.message),
            method=str(self.method),
            projector=str(self.projector),
        )
        rs = self.reduced_set
        if rs is None:
            out["reduced_set"] = None
        else:
            out["reduced_set"] = dict(
                method=str(getattr(rs, "method", self.method)),
                indices=np.asarray(rs.indices).astype(int).tolist(),
                weights=_jsonable(np.asarray(rs.weights, np.float64)),
                mmd2=_jsonable(np.asarray(getattr(rs, "mmd2", np.nan), np.float64)),
            )
        if diagnostics:
            out["diagnostics"] = _jsonable(self.diagnostics)
        return out


#: the Frenet fields of :class:`frenet.EgoState` and their arrays on :class:`Plan`
_FRENET_KEYS = ("s", "d", "vs", "vd", "as_", "ad")


def _check_time(t: Any, horizon: float, name: str) -> float:
    if isinstance(t, bool | str | bytes | complex):
        raise ValueError(f"{name} must be a number of seconds, got {t!r}")
    try:
        t = float(t)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number of seconds, got {t!r}") from None
    if not (math.isfinite(t) and 0.0 <= t <= horizon + 1e-9):
        raise ValueError(f"{name} must lie in [0, {horizon:g}] s (the plan's horizon), got {t}")
    return min(t, horizon)


def _jsonable(v: Any) -> Any:
    """Arrays to (nested) lists, NumPy/JAX scalars to Python numbers, NaN/inf floats to None."""
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_jsonable(x) for x in v]
    if isinstance(v, bool | np.bool_):
        return bool(v)
    if isinstance(v, str) or v is None:
        return v
    if isinstance(v, int | np.integer) and not isinstance(v, bool):
        return int(v)
    if hasattr(v, "shape") or isinstance(v, float | np.floating):
        a = np.asarray(v)
        if a.dtype == bool:
            return a.tolist()
        if np.issubdtype(a.dtype, np.integer):
            return a.tolist()
        if np.issubdtype(a.dtype, np.number):
            a = a.astype(np.float64)
            return (
                np.where(np.isfinite(a), a, None).tolist()
                if a.ndim
                else (float(a) if np.isfinite(a) else None)
            )
    return repr(v)


# ------------------------------------------------------------------------------------- validation
def _projector(projector: str, backend: str | None) -> str:
    """``projector``, or ``backend`` (its former name, deprecated) when that is given."""
    if backend is None:
        return projector
    warnings.warn(
        "backend= is now projector= (the planner's projection: 'admm-fixed', its own jitted "
        "ADMM, or a solvers backend that projects on the host)",
        DeprecationWarning,
        stacklevel=3,
    )
    if projector != PLANNER_PROJECTOR and projector != backend:
        raise ValueError(
            f"projector={projector!r} and backend={backend!r} (its former name) disagree"
        )
    return backend


def _draw_forecast(fc: Forecast, config: MMDOptConfig, method: str, key) -> tuple:
    """Draw the futures of a :class:`mmdopt.predict.Forecast`: n(ε) per obstacle for the risk
    level of ``config`` (the "samples" margin mode), clipped to the forecast's bounds."""
    O = fc.num_obstacles
    grid = frenet.TimeGrid(config.trajectory.horizon, config.trajectory.num_steps).t
    times = fc.context.times
    if times.shape != grid.shape or not np.allclose(times, grid, atol=1e-9):
        raise ValueError(
            f"obstacles.context.times must be the planner's grid ({config.trajectory.num_steps} "
            f"points over {config.trajectory.horizon} s), got {times.shape[0]} points over "
            f"{times[-1]:g} s"
        )
    lo = fc.min_samples
    if SELECTOR[method] is not None:
        lo = max(lo, config.selection.reduced_set_size)
    needed = None
    if config.safety.margins.margin_mode == "samples":
        needed = samples_for_risk(
            float(config.safety.risk), config.bound_groups(O), hits=config.risk_hits_for(method)
        )
    n = int(min(max(lo, needed or lo), max(fc.max_samples, lo)))
    t0 = time.perf_counter()
    k_pred = jax.random.fold_in(key, 0x5EED)
    samples = np.asarray(fc.predictor.sample(fc.history, fc.context, n, k_pred), np.float64)
    want = (O, n, grid.shape[0], 2)
    if samples.shape != want:
        raise ValueError(
            f"obstacles.predictor.sample returned shape {samples.shape}, expected {want}"
        )
    return samples, dict(
        forecast_samples=n,
        forecast_samples_needed=needed,
        forecast_s=time.perf_counter() - t0,
    )


def _check_common(ego, road, method, config, backend, key):
    if not isinstance(ego, frenet.EgoState):
        raise ValueError(f"ego must be a frenet.EgoState, got {type(ego).__name__}")
    if not isinstance(road, Road):
        raise ValueError(f"road must be an mmdopt.Road, got {type(road).__name__}")
    if method not in PLAN_METHODS:
        raise ValueError(f"method must be one of {PLAN_METHODS}, got {method!r}")
    if not isinstance(config, MMDOptConfig):
        raise ValueError(f"config must be an mmdopt.MMDOptConfig, got {type(config).__name__}")
    if not isinstance(backend, str) or (
        backend != PLANNER_PROJECTOR and backend not in solvers.available_backends()
    ):
        raise ValueError(
            f"projector {backend!r} is not available; available: "
            f"{[PLANNER_PROJECTOR, *solvers.available_backends()]}"
        )
    check_key(key)


def _check_obstacles(obstacles, config: MMDOptConfig, method: str, name="obstacles"):
    if obstacles is None:
        raise ValueError(f"{name} must be an array (O, n, K, 2), got None")
    if np.iscomplexobj(obstacles):
        raise ValueError(f"{name} must be real (x, y) positions, got a complex array")
    try:
        arr = np.asarray(obstacles, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array (O, n, K, 2)") from None
    K = config.trajectory.num_steps
    if arr.ndim != 4 or arr.shape[-1] != 2:
        raise ValueError(f"{name} must have shape (O, n, K, 2) = (O, n, {K}, 2), got {arr.shape}")
    O, n, k, _ = arr.shape
    if O == 0:
        raise ValueError(
            f"{name} has zero obstacles (shape {arr.shape}); pass at least one obstacle's samples"
        )
    if n == 0:
        raise ValueError(f"{name} has zero samples per obstacle (shape {arr.shape})")
    if k != K:
        raise ValueError(
            f"{name} has {k} time steps but config.num_steps = {K}: samples must be on the "
            f"planner's time grid ({config.trajectory.horizon} s, {K} points)"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    if np.max(np.abs(arr)) > MAX_COORD:
        raise ValueError(
            f"{name} has coordinates beyond {MAX_COORD:g} m (max |value| {np.max(np.abs(arr)):.3g})"
        )
    m = config.selection.reduced_set_size
    if SELECTOR[method] is not None and n < m:
        raise ValueError(
            f"{name} has n = {n} samples per obstacle, fewer than config.reduced_set_size = {m}"
        )
    return arr


# ------------------------------------------------------------------------------------- planner
class Planner:
    """Algorithm 1 for one configuration, owning what it compiles and factorises.

    A planner keeps one :class:`mmdopt.algorithm.Workspace` (basis, planner matrix, projection
    factorisation, jitted steps) per road's bounds and static configuration it has planned
    with, at most :attr:`max_workspaces` of them (the oldest dropped first).  Reuse one planner
    to plan many times without compiling again::

        planner = mmdopt.Planner(config)
        p = planner.plan(ego, road, obstacles, method="mmd", key=jax.random.PRNGKey(0))

    The same steps one at a time (the step API of :mod:`mmdopt.algorithm`; the state holds
    arrays only)::

        problem = planner.problem(ego, road)
        obstacles = mmdopt.algorithm.ObstacleSet.create(config, centres, weights, "mmd")
        state = planner.init(problem, key)
        state = planner.update(problem, state, obstacles)      # one CEM iteration
        state = planner.run(problem, obstacles, key)           # all of them, one jitted scan
        warm = planner.shift(state, dt)                        # receding horizon

    :func:`plan` is this class behind one bounded cache of planners.
    """

    max_workspaces = 8

    def __init__(self, config: MMDOptConfig | None = None) -> None:
        config = MMDOptConfig() if config is None else config
        if not isinstance(config, MMDOptConfig):
            raise ValueError(f"config must be an mmdopt.MMDOptConfig, got {type(config).__name__}")
        self.config = config
        self._workspaces: dict[tuple, alg.Workspace] = {}

    def __repr__(self) -> str:
        return f"Planner({len(self._workspaces)} workspace(s))"

    def workspace(
        self, bounds: frenet.ProjectionBounds | tuple, config: MMDOptConfig | None = None
    ) -> alg.Workspace:
        """The workspace of ``config`` (default: the planner's) and the projection ``bounds``
        (a :class:`frenet.ProjectionBounds` or its :func:`mmdopt.algorithm.bounds_key`), built
        on first use."""
        cfg = self.config if config is None else config
        bkey = bounds if isinstance(bounds, tuple) else alg.bounds_key(bounds)
        key = (alg.statics(cfg), bkey)
        ws = self._workspaces.get(key)
        if ws is None:
            b = alg.bounds_from_key(bkey) if isinstance(bounds, tuple) else bounds
            ws = alg.Workspace(cfg, b)
            if len(self._workspaces) >= self.max_workspaces:
                self._workspaces.pop(next(iter(self._workspaces)))
            self._workspaces[key] = ws
        return ws

    # ------------------------------------------------------------------------------ step API
    def problem(self, ego: frenet.EgoState, road: Road) -> alg.Problem:
        """The planning problem of ``ego`` on ``road`` (:meth:`mmdopt.algorithm.Problem.create`)."""
        if not isinstance(road, Road):
            raise ValueError(f"road must be an mmdopt.Road, got {type(road).__name__}")
        return alg.Problem.create(self.config, ego, road.bounds(), lanes=road.lane_centres)

    def _ws(self, problem: Any) -> alg.Workspace:
        if not isinstance(problem, alg.Problem):
            raise ValueError(f"problem must be an algorithm.Problem, got {type(problem).__name__}")
        return self.workspace(problem.bounds)

    def init(
        self, problem: alg.Problem, key: Any, warm_start: alg.CEMState | None = None
    ) -> alg.CEMState:
        """:func:`mmdopt.algorithm.init` with this planner's config and workspace."""
        return alg.init(self._ws(problem), self.config, problem, key, warm_start)

    def update(
        self,
        problem: alg.Problem,
        state: alg.CEMState,
        obstacles: alg.ObstacleSet,
        projector: str = PLANNER_PROJECTOR,
        **projector_settings: Any,
    ) -> alg.CEMState:
        """One CEM iteration (:func:`mmdopt.algorithm.update`)."""
        ws = self._ws(problem)
        return alg.update(
            ws, self.config, problem, state, obstacles, projector, **projector_settings
        )

    def run(
        self,
        problem: alg.Problem,
        obstacles: alg.ObstacleSet,
        key: Any,
        projector: str = PLANNER_PROJECTOR,
        warm_start: alg.CEMState | None = None,
        **projector_settings: Any,
    ) -> alg.CEMState:
        """Every iteration (:func:`mmdopt.algorithm.run`)."""
        ws = self._ws(problem)
        return alg.run(
            ws, self.config, problem, obstacles, key, projector, warm_start, **projector_settings
        )

    def shift(self, state: alg.CEMState, dt: float) -> alg.CEMState:
        """The warm start ``dt`` seconds later (:func:`mmdopt.algorithm.shift`)."""
        return alg.shift(self.config, state, dt)

    # ---------------------------------------------------------------------------------- plan
    @x64
    def plan(
        self,
        ego: frenet.EgoState,
        road: Road,
        obstacles: ArrayLike,
        *,
        method: str = "mmd",
        projector: str = PLANNER_PROJECTOR,
        key: ArrayLike | None = None,
        reduced_set: ReducedSet | None = None,
        warm_start: alg.CEMState | None = None,
        risk: float | None = None,
        obstacle_headings: ArrayLike | None = None,
        backend: str | None = None,
        **projector_settings: Any,
    ) -> Plan:
        """:func:`plan` with this planner's config."""
        return self._plan(
            self.config, ego, road, obstacles, method, _projector(projector, backend), key,
            reduced_set, warm_start, risk, projector_settings, frenet_frame=False,
            obstacle_headings=obstacle_headings,
        )  # fmt: skip

    @x64
    def plan_frenet(
        self,
        ego: frenet.EgoState,
        road: Road,
        obstacles_frenet: ArrayLike,
        *,
        method: str = "mmd",
        projector: str = PLANNER_PROJECTOR,
        key: ArrayLike | None = None,
        reduced_set: ReducedSet | None = None,
        warm_start: alg.CEMState | None = None,
        risk: float | None = None,
        obstacle_headings: ArrayLike | None = None,
        backend: str | None = None,
        **projector_settings: Any,
    ) -> Plan:
        """:func:`plan_frenet` with this planner's config."""
        return self._plan(
            self.config, ego, road, obstacles_frenet, method, _projector(projector, backend), key,
            reduced_set, warm_start, risk, projector_settings, frenet_frame=True,
            obstacle_headings=obstacle_headings,
        )  # fmt: skip

    def _plan(
        self, config, ego, road, obstacles, method, backend, key, reduced_set, warm_start, risk,
        backend_settings, frenet_frame: bool, obstacle_headings=None,
    ) -> Plan:  # fmt: skip
        t0 = time.perf_counter()
        key = jax.random.PRNGKey(0) if key is None else key
        _check_common(ego, road, method, config, backend, key)
        config = _apply_risk(method, risk, config)
        alg.check_backend(backend, backend_settings)
        forecast_diag: dict[str, Any] = {}
        if isinstance(obstacles, Forecast):
            obstacles, forecast_diag = _draw_forecast(obstacles, config, method, key)
        if frenet_frame:
            arr = _check_obstacles(obstacles, config, method, name="obstacles_frenet")
            obs_fr, diag = arr, {"frenet_conversion_s": 0.0}
        else:
            arr = _check_obstacles(obstacles, config, method)
            t1 = time.perf_counter()
            s, d = road.path.to_frenet(arr[..., 0], arr[..., 1])
            obs_fr = np.stack([s, d], axis=-1)
            if not np.all(np.isfinite(obs_fr)):
                raise ValueError(
                    "obstacles could not be converted to the road's Frenet frame (non-finite)"
                )
            diag = {"frenet_conversion_s": time.perf_counter() - t1}
        diag.update(forecast_diag)
        h0 = None
        if obstacle_headings is not None:
            h0 = _check_obstacle_headings(obstacle_headings, obs_fr.shape[0])
            if not frenet_frame:  # relative to the path's tangent where each obstacle starts
                h0 = h0 - np.asarray(road.path.heading(obs_fr[:, 0, 0, 0]), np.float64)
        return _plan_impl(
            self, ego, road, obs_fr, method, config, backend, key, backend_settings, t0, diag,
            reduced_set, warm_start, h0,
        )  # fmt: skip


class _PlannerCache:
    """The one cache of planners behind :func:`plan` and :func:`plan_frenet`: one
    :class:`Planner` per static configuration (sizes, modes, rules: what changes the compiled
    program), at most :attr:`maxsize` of them, the oldest dropped first.  Configs that differ
    only in their tunable scalars share a planner, so they do not compile again.  Use your own
    :class:`Planner` to control what stays alive; :meth:`clear` frees the cached ones."""

    maxsize = 8

    def __init__(self) -> None:
        self._planners: dict[Any, Planner] = {}

    def get(self, config: MMDOptConfig) -> Planner:
        key = alg.statics(config)
        hit = self._planners.get(key)
        if hit is None:
            hit = Planner(config)
            if len(self._planners) >= self.maxsize:
                self._planners.pop(next(iter(self._planners)))
            self._planners[key] = hit
        return hit

    def clear(self) -> None:
        self._planners.clear()


#: the planners of :func:`plan` (:class:`_PlannerCache`; the method's only mutable module state)
PLANNERS = _PlannerCache()


def _cached_planner(config: Any) -> tuple[MMDOptConfig, Planner]:
    config = MMDOptConfig() if config is None else config
    if not isinstance(config, MMDOptConfig):
        raise ValueError(f"config must be an mmdopt.MMDOptConfig, got {type(config).__name__}")
    return config, PLANNERS.get(config)


# ------------------------------------------------------------------------------------------ API
@x64
def plan(
    ego: frenet.EgoState,
    road: Road,
    obstacles: ArrayLike,
    *,
    method: str = "mmd",
    config: MMDOptConfig | None = None,
    projector: str = PLANNER_PROJECTOR,
    key: ArrayLike | None = None,
    reduced_set: ReducedSet | None = None,
    warm_start: alg.CEMState | None = None,
    risk: float | None = None,
    obstacle_headings: ArrayLike | None = None,
    backend: str | None = None,
    **projector_settings: Any,
) -> Plan:
    """Plan with Algorithm 1 against Cartesian obstacle-trajectory samples.

    Parameters
    ----------
    ego : :class:`frenet.EgoState` in the Frenet frame of ``road.path``
    road : :class:`Road`
    obstacles : (O, n, K, 2) Cartesian ``(x, y)`` samples of each obstacle's future (m), or a
        :class:`mmdopt.predict.Forecast` (a predictor, the histories and the context): then
        ``plan`` draws as many futures as the risk level needs, n(ε) per obstacle
        (:func:`mmdopt.risk.samples_for_risk`, within the forecast's ``min_samples`` …
        ``max_samples``; ``diagnostics["forecast_samples"]``)
    method : "mmd" (MMD-Opt) | "degroot" | "random" | "saa" | "scenario_all"
        (:mod:`mmdopt.baselines`)
    config : :class:`MMDOptConfig` (default: the paper's sizes, and the method's risk knob at
        ε = ``risk`` = 0.005 with sample-driven margins; ``MMDOptConfig().replace(margin_mode=
        "linear")`` plans with the time-linear tuned margins of the paper reproduction)
    projector : the projection of every CEM iteration: ``"admm-fixed"`` (default), the planner's
        own fixed-budget ADMM projector inside the one jit of the whole algorithm (its settings
        are ``config.projection``); or the name of any :mod:`solvers` backend (``"admm"``,
        ``"clarabel"``, ``"osqp"``, ...) projects on the host each iteration
        (``projector_settings`` go to it); ``backend=``, its former name, still works with a
        ``DeprecationWarning``
    key : jax PRNG key (default ``PRNGKey(0)``); the same key gives the same plan
    reduced_set : optional precomputed :class:`ReducedSet` with leading axis O (indices into the
        n samples, weights ᾱ ≥ 0 summing to 1 per obstacle) used instead of the method's own
        selection (methods whose cost uses a reduced set: "mmd", "random", "degroot")
    warm_start : optional :class:`mmdopt.algorithm.CEMState` (e.g. ``algorithm.shift`` of the
        previous plan's ``state``): the sampling distribution and elites start from it
    risk : optional target collision probability ε in (0, 0.5), the method's risk knob: the
        method's margins and chance level follow from it (:func:`mmdopt.risk.config_for_risk`,
        applied to ``config``); ``None``: ``config`` as given (whose default is the knob at
        0.005: ``plan(..., method=m)`` plans as ``plan(..., method=m, risk=0.005)``)
    obstacle_headings : optional (O,) body heading of each obstacle when observed (rad,
        Cartesian): its footprint circles follow it until a sample's own motion gives a heading
        (:func:`mmdopt.collision.headings`), so a car at rest turned across its lane is planned
        against along its real axis, with certainty, in every sample.  ``None``: headings from
        the samples' motion only (along the path for a sample at rest)

    Returns
    -------
    :class:`Plan`.  Never raises for an infeasible situation: if the initial state violates the
    bounds (e.g. speed above ``v_max``) or the cost is not finite, a braking profile is returned,
    and if no sample satisfies the constraints the least-violating one, all with
    ``fallback=True`` and a ``status`` that says why.

    Raises
    ------
    ValueError naming the argument for bad inputs (wrong shapes or horizon, NaN, zero obstacles,
    fewer samples than the reduced-set size, unknown method or backend, a malformed reduced set).
    """
    config, planner = _cached_planner(config)
    return planner._plan(
        config, ego, road, obstacles, method, _projector(projector, backend), key, reduced_set,
        warm_start, risk, projector_settings, frenet_frame=False,
        obstacle_headings=obstacle_headings,
    )  # fmt: skip


@x64
def plan_frenet(
    ego: frenet.EgoState,
    road: Road,
    obstacles_frenet: ArrayLike,
    *,
    method: str = "mmd",
    config: MMDOptConfig | None = None,
    projector: str = PLANNER_PROJECTOR,
    key: ArrayLike | None = None,
    reduced_set: ReducedSet | None = None,
    warm_start: alg.CEMState | None = None,
    risk: float | None = None,
    obstacle_headings: ArrayLike | None = None,
    backend: str | None = None,
    **projector_settings: Any,
) -> Plan:
    """:func:`plan` with obstacle samples already in the Frenet frame of ``road.path``:
    ``obstacles_frenet`` (O, n, K, 2) as ``(s, d)`` (and ``obstacle_headings``, if given,
    relative to the path's tangent).  On a straight path starting at the origin
    along +x (the default :class:`Road`) this is the same as Cartesian."""
    config, planner = _cached_planner(config)
    return planner._plan(
        config, ego, road, obstacles_frenet, method, _projector(projector, backend), key,
        reduced_set, warm_start, risk, projector_settings, frenet_frame=True,
        obstacle_headings=obstacle_headings,
    )  # fmt: skip


def _apply_risk(method: str, risk: Any, config: MMDOptConfig) -> MMDOptConfig:
    if risk is not None:
        from .risk import config_for_risk

        config = config_for_risk(method, risk, config)
    if config.safety.reselect is None:  # automatic: the method's re-selection pass size
        config = config.replace(reselect=config.reselect_for(method))
    return config


def _check_warm_start(warm_start: Any, config: MMDOptConfig) -> None:
    """``ValueError`` naming ``warm_start`` unless it is a state of a config with the same
    behavioural input size, elite count and iterations as ``config``."""
    if not isinstance(warm_start, alg.CEMState):
        raise ValueError(
            f"warm_start must be an algorithm.CEMState, got {type(warm_start).__name__}"
        )
    D, ne, N = config.d_dim, config.cem.n_elite, config.cem.iterations
    want = {"mu": (D,), "cov": (D, D), "elites": (ne, D), "cost_trace": (N,)}
    for name, shape in want.items():
        got = tuple(np.shape(getattr(warm_start, name)))
        if got != shape:
            raise ValueError(
                f"warm_start.{name} has shape {got}, but this config needs {shape} "
                "(num_segments, n_elite, iterations): warm-start from a plan made with the "
                "same sizes"
            )


def _check_reduced_set(rs: Any, O: int, n: int, method: str) -> ReducedSet:
    if SELECTOR[method] is None:
        raise ValueError(f"reduced_set is not used by method {method!r} (it plans on all samples)")
    return check_reduced_set(rs, n, "reduced_set", O)


@dataclass
class _Ctx:
    """What one plan() call carries from the selection to the assembled :class:`Plan`."""

    ego: frenet.EgoState
    road: Road
    config: MMDOptConfig
    prob: alg.Workspace
    method: str
    backend: str
    rs: Any
    t0: float
    diag: dict
    obs_fr: np.ndarray
    obstacles: alg.ObstacleSet | None = None
    #: (O, n, K) Frenet headings of the samples' bodies when the caller gave obstacle headings
    obs_h: np.ndarray | None = None
    #: the final check's chosen plan (cx, cy) and the (O, n) samples it meets, reused by
    #: :func:`_assemble` when that plan is the one returned
    met: tuple | None = None
    _all_centres: jax.Array | None = None

    def centres(self, idx: np.ndarray | None = None) -> jax.Array:
        """Footprint circle centres (O, J, C, K, 2) of the samples ``idx`` (O, J) (all: None,
        computed once per plan: every conflict-depth pass measures against them)."""
        if idx is not None:
            return _obstacle_centres(self.obs_fr, self.obs_h, idx)
        if self._all_centres is None:
            self._all_centres = _obstacle_centres(self.obs_fr, self.obs_h)
        return self._all_centres


def _check_obstacle_headings(h: Any, O: int) -> np.ndarray:
    """``obstacle_headings`` as (O,) finite float64 radians, else ``ValueError`` naming it."""
    try:
        arr = np.asarray(h, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"obstacle_headings must be {O} numbers (rad), got {h!r}") from None
    if arr.shape != (O,):
        raise ValueError(
            f"obstacle_headings must have shape ({O},) (one body heading per obstacle), got "
            f"{arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError("obstacle_headings contains NaN or inf")
    return arr


def _obstacle_centres(obs_fr, obs_h, idx=None) -> jax.Array:
    """Footprint circle centres (O, J, C, K, 2) of the samples ``idx`` (O, J) of ``obs_fr``
    (all when None), along ``obs_h`` (O, n, K) where given, else along each sample's motion."""
    sel, h = obs_fr, obs_h
    if idx is not None:
        idx = np.asarray(idx)
        sel = np.take_along_axis(obs_fr, idx[:, :, None, None], axis=1)
        h = None if obs_h is None else np.take_along_axis(obs_h, idx[:, :, None], axis=1)
    hj = None if h is None else jnp.asarray(h)
    return circle_centres(jnp.asarray(sel), OBSTACLE_FOOTPRINT, hj)


def _plan_impl(
    planner, ego, road, obs_fr, method, config, backend, key, backend_settings, t0, diag, rs,
    warm_start, h0=None,
):  # fmt: skip
    # plan in arc length relative to the ego (float32 keeps ~1e-6 relative precision: absolute
    # arc lengths of kilometres would cost millimetres); shifted back in _assemble
    s_off = float(ego.s)
    ego = dataclasses.replace(ego, s=0.0)
    obs_fr = np.array(obs_fr, dtype=np.float64, copy=True)
    obs_fr[..., 0] -= s_off
    O, n, K, _ = obs_fr.shape
    diag["s_offset"] = s_off
    # a body heading given for each obstacle holds before (and without) motion of its own
    obs_h = None if h0 is None else np.asarray(headings(obs_fr, h0[:, None]), np.float64)
    if warm_start is not None:
        _check_warm_start(warm_start, config)
    prob = planner.workspace(road.bounds(), config)
    k_rs, k_cem = jax.random.split(key)
    # --- obstacle samples used by the cost
    t1 = time.perf_counter()
    if rs is not None:
        rs = _check_reduced_set(rs, O, n, method)
    else:
        ego_guess = None
        if method == "degroot":
            t = prob.t()
            ego_guess = np.stack([ego.s + ego.vs * t, np.full(K, ego.d)], axis=-1)
        pool = _selection_pool(method, config, n, k_rs)
        rs = select_for_method(
            method,
            k_rs,
            obs_fr if pool is None else obs_fr[:, pool],
            config.selection.reduced_set_size,
            config.selection.reduced_set,
            lateral_scale=float(config.selection.rs_lateral_scale),
            ego_guess=ego_guess,
            footprint=config.safety.footprint,
        )
        if pool is not None:  # back to positions among all n samples
            alpha = np.zeros((O, n))
            alpha[:, pool] = np.asarray(rs.alpha)
            rs = dataclasses.replace(
                rs, indices=jnp.asarray(pool[np.asarray(rs.indices)]), alpha=jnp.asarray(alpha)
            )
    diag["reduced_set_s"] = time.perf_counter() - t1
    centres = _obstacle_centres(obs_fr, obs_h, rs.indices)  # (O, J, C, K, 2)
    margins = None
    if config.safety.margins.margin_mode == "samples":
        t3 = time.perf_counter()
        knn = 0
        if SELECTOR[method] is None:
            knn = config.safety.margins.coverage_knn
            if knn is None:  # automatic: the samples a reduced-set point stands for
                knn = max(2, n // config.selection.reduced_set_size)
        margins = _coverage(config, obs_fr, np.asarray(rs.indices), knn=knn)
        diag["margins_s"] = time.perf_counter() - t3
    obstacles = alg.ObstacleSet.create(
        config, centres, np.asarray(rs.weights, np.float64), COLLISION_TERM[method], margins=margins
    )
    ctx = _Ctx(ego, road, config, prob, method, backend, rs, t0, diag, obs_fr, obstacles, obs_h)

    # --- infeasible initial state: braking profile, flagged
    try:
        prob.projection.check_state(ego)
    except ValueError as exc:
        return _braking_fallback(ctx, f"fallback: {exc}")

    t2 = time.perf_counter()
    problem = alg.Problem.create(config, ego, road.bounds(), lanes=road.lane_centres)
    state = alg.run(
        prob, config, problem, obstacles, k_cem, backend, warm_start=warm_start,
        **backend_settings,
    )  # fmt: skip
    state = jax.block_until_ready(state)
    passes = [state]
    if config.safety.reselect > 0 and SELECTOR[method] is not None:
        state = _reselect_pass(ctx, state, problem, k_cem, backend, backend_settings)
        passes.append(state)
    if config.safety.margins.margin_mode == "samples":
        # below the floor of the n futures (ε < what they can confirm) there is no allowance
        # for the pass to use: the margins alone extrapolate the tail the futures do not show
        if (
            method == "mmd"
            and config.safety.nearest_futures > 0
            and risk_floor([n] * config.bound_groups(O)) <= float(config.safety.risk)
        ):
            passes += _nearest_passes(planner, ctx, passes[-1], problem, k_cem, backend,
                                      backend_settings)  # fmt: skip
        state = _final_check(ctx, passes, problem, k_cem, backend, backend_settings)
    diag["cem_s"] = time.perf_counter() - t2
    best, lv = state.best, state.least_violating
    if not math.isfinite(float(best.cost)) or float(best.cost) >= 1e29:
        return _braking_fallback(
            ctx,
            f"fallback: the cost is not finite (best {float(best.cost):.3g}: NaN/inf in the "
            "cost terms); braking plan returned",
            state,
        )
    fallback = False
    status = "ok"
    chosen = best
    if not float(lv.res) <= float(config.projection.res_tol):
        fallback = True
        chosen = lv
        status = (
            f"fallback: no sample met the constraints (least residual {float(lv.res):.3g} "
            f"> res_tol {float(config.projection.res_tol):g}); least-violating plan returned"
        )
    return _assemble(
        ctx,
        np.asarray(chosen.cx, np.float64),
        np.asarray(chosen.cy, np.float64),
        # the set-points the Frenet planner followed (lane centres with lane_setpoints)
        np.asarray(alg.lane_inputs(config, chosen.d[None], problem.lanes, problem.state)[0]),
        float(chosen.cost),
        int(chosen.iteration),
        fallback,
        status,
        state,
    )


def _coverage(config: MMDOptConfig, obs_fr, idx, level=None, knn: int = 0) -> np.ndarray:
    """:func:`mmdopt.risk.coverage_margins` of the points ``idx`` among ``obs_fr`` at ``level``
    (default: the risk level ε) with ``config``'s coverage settings (every pass plans with
    these)."""
    from .risk import coverage_margins

    return coverage_margins(
        obs_fr,
        idx,
        float(config.safety.risk) if level is None else float(level),
        lateral_scale=float(config.selection.rs_lateral_scale),
        prior=float(config.safety.margins.coverage_prior),
        knn=knn,
        bandwidth=float(config.safety.margins.coverage_bandwidth),
    )


def _conflict_depth(ctx: _Ctx, best) -> np.ndarray:
    """(O, n) deepest conflict over time of the plan ``best`` with every planning sample: the
    nominal ellipse ``a, b`` with the geometry and responsibility rules of the config (yaw
    widening, rear exemption); > 0 where the plan enters a sample's ellipse."""
    config, Bs = ctx.config, ctx.prob.basis
    cx1 = np.asarray(best.cx, np.float64)
    cy1 = np.asarray(best.cy, np.float64)
    s1, d1 = (Bs.P @ cx1)[None], (Bs.P @ cy1)[None]
    vs1, vd1 = (Bs.Pdot @ cx1)[None], (Bs.Pdot @ cy1)[None]
    # (O, n, C, K, 2) centres of every sample
    return np.asarray(_depth_values(config.program(), s1, d1, vs1, vd1, ctx.centres()))


@jax.jit
def _depth_values(config: MMDOptConfig, s1, d1, vs1, vd1, centres):
    # one compiled program per shape for _conflict_depth (eagerly: a program per op and shape)
    b = jnp.asarray(config.safety.footprint.b)
    if config.safety.footprint.yaw_aware:
        b = b + alg.yaw_widening(config, vs1, vd1)  # (1, K)
    rear = float(config.safety.rules.rear_exempt_width) if config.safety.rules.asymmetric else None
    f = ellipse_values(s1, d1, centres, config.safety.footprint.a, b, rear_exempt_width=rear)
    return jnp.max(f[0], axis=(2, 3))


def _reselect_pass(ctx: _Ctx, state, problem, key, backend, backend_settings):
    """Second pass of Algorithm 1 (``config.safety.reselect`` > 0): the reduced set plus the
    ``reselect`` samples in deepest conflict with the first pass's plan (weight 1/n each) after
    the ⌊ε·n⌋ deepest (``ε = config.safety.risk``: the conflicts a chance constraint at level ε may
    leave, as in sampling-and-discarding), warm-started from the first pass; ``ctx`` is updated
    in place.  Conflict is measured on the nominal ellipse ``a, b`` with the geometry and
    responsibility rules of the config (yaw widening, rear exemption), the margins of the
    config's ``margin_mode`` then apply to the added samples as to every reduced-set point
    (sample-driven coverage margins recomputed, or the time-linear ones)."""
    config, prob, obs_fr = ctx.config, ctx.prob, ctx.obs_fr
    O, n = obs_fr.shape[:2]
    depth = _conflict_depth(ctx, state.best)  # (O, n)
    idx0 = np.asarray(ctx.rs.indices)
    # sampling and discarding (Campi & Garatti 2011): a plan that may collide with probability ε
    # may leave the ⌊ε·n⌋ deepest conflicts of the n samples unresolved; the next r are added
    k = int(math.floor(float(config.safety.risk) * n))
    r = min(int(config.safety.reselect), n - idx0.shape[1] - k)
    if r <= 0:
        return state
    d = depth.copy()
    np.put_along_axis(d, idx0, -np.inf, axis=1)  # already in the reduced set
    order = np.argsort(-d, axis=1, kind="stable").astype(idx0.dtype)
    extra = order[:, k : k + r]
    idx = np.concatenate([idx0, extra], axis=1)
    w = np.concatenate(
        [np.asarray(ctx.rs.weights, np.float64) * (1.0 - r / n), np.full((O, r), 1.0 / n)], 1
    )
    cen = ctx.centres(idx)
    margins = None
    if config.safety.margins.margin_mode == "samples":
        margins = _coverage(config, obs_fr, idx)
    obstacles = alg.ObstacleSet.create(config, cen, w, COLLISION_TERM[ctx.method], margins=margins)
    ctx.obstacles = obstacles
    ctx.diag["reselected"] = extra
    ctx.diag["discarded"] = order[:, :k]
    ctx.diag["conflict_depth"] = depth
    warm = alg.shift(config, state, 0.0)
    out = alg.run(
        prob, config, problem, obstacles, jax.random.fold_in(key, 1), backend, warm_start=warm,
        **backend_settings,
    )  # fmt: skip
    return jax.block_until_ready(out)


# ------------------------------------------------------------------ the risk dial's final check
#: the most repeats of the nearest-futures pass while its plan's bound exceeds ε, each around
#: the last plan with one allowed hit fewer (:func:`_nearest_pass`'s ``fewer``)
NEAREST_REPEATS = 2
#: the nearest-futures pass's coverage margins are at level min(this · ε, 0.45): it plans
#: against the futures that matter themselves, and the final check's bound covers the rest
NEAREST_MARGIN_FACTOR = 10.0


def _nearest_passes(planner, ctx: _Ctx, state, problem, key, backend, backend_settings) -> list:
    """:func:`_nearest_pass` from ``state``, then while the last one's plan has a bound
    against all n futures above ε (it met a future beyond the M it saw, or one more than the
    soft count allowed) up to :data:`NEAREST_REPEATS` more around that plan, each allowing one
    hit fewer: every pass's state, in order."""
    out = [_nearest_pass(planner, ctx, state, problem, key, backend, backend_settings)]
    for rep in range(1, NEAREST_REPEATS + 1):
        if _bounds_of(ctx, [out[-1].best])[0][0] <= float(ctx.config.safety.risk):
            break
        out.append(_nearest_pass(planner, ctx, out[-1], problem, jax.random.fold_in(key, rep),
                                 backend, backend_settings, fewer=rep))  # fmt: skip
    return out


def _nearest_pass(planner, ctx: _Ctx, state, problem, key, backend, backend_settings, fewer=0):
    """MMD-Opt's nearest-futures pass (``config.safety.nearest_futures`` = M > 0, "samples"
    margin mode): one more pass of Algorithm 1, warm-started from ``state``, against the M
    planning futures per obstacle in deepest conflict with its plan (:func:`_conflict_depth`;
    all n when n ≤ M, padded to M), each of weight 1/M with the k-NN coverage margins of the
    methods that plan on all samples at the loose level min(:data:`NEAREST_MARGIN_FACTOR` · ε,
    0.45), and SAA's sample-average chance term (:func:`mmdopt.collision.saa_cost`) at level
    (k + ½)/M, where k = :func:`mmdopt.risk.hits_for_risk` (ε, n, G) − ``fewer`` (≥ 0) and
    hits_for_risk is the most futures a plan may meet (joint futures, G = 1, by default; per
    obstacle with ``safety.joint_futures = False``) while its 95 % bound stays ≤ ε.  With
    several obstacles in conflict the per-obstacle chance terms may together meet more joint
    futures than k: the repeats (:func:`_nearest_passes`) then allow fewer.  The reduced set
    decides where the plan goes; this pass lets it pass as close to the futures that matter as
    the bound allows.  Its plan is one more candidate of :func:`_final_check`.  Not run when ε
    is below the floor of the n futures (:func:`mmdopt.risk.risk_floor`): no plan's bound can
    then meet ε, and threading between futures too few to show the tail would only add risk."""
    from .risk import hits_for_risk

    config, obs_fr = ctx.config, ctx.obs_fr
    O, n = obs_fr.shape[:2]
    P = int(config.safety.nearest_futures)  # one compiled program for every n: pad to P
    M = min(n, P)
    t0 = time.perf_counter()
    if M < n:
        depth = _conflict_depth(ctx, state.best)  # (O, n), as the re-selection pass
        idx = np.sort(np.argsort(-depth, axis=1, kind="stable")[:, :M], axis=1)
    else:
        idx = np.tile(np.arange(n), (O, 1))
    # padding (fewer than P futures): copies of the first, masked out of the chance term
    pad = np.concatenate([idx, np.repeat(idx[:, :1], P - M, axis=1)], axis=1)
    mask = np.arange(P)[None, :].repeat(O, 0) < M
    G = config.bound_groups(O)
    k = max(hits_for_risk(float(config.safety.risk), int(n), G) - int(fewer), 0)
    k = min(k, M - 1)  # a level below 1 (with as many hits as futures seen, all may be met)
    cfg = config.replace(saa_eps=(k + 0.5) / M)
    level = min(NEAREST_MARGIN_FACTOR * float(config.safety.risk), _LEVEL_CAP)
    knn = max(2, n // config.selection.reduced_set_size)
    obstacles = alg.ObstacleSet.create(
        cfg, ctx.centres(pad), np.where(mask, 1.0 / M, 0.0), "saa", mask=mask,
        margins=_coverage(config, obs_fr, pad, level=level, knn=knn),
    )  # fmt: skip
    out = alg.run(
        planner.workspace(ctx.road.bounds(), cfg), cfg, problem, obstacles,
        jax.random.fold_in(key, 0x501), backend, warm_start=alg.shift(config, state, 0.0),
        **backend_settings,
    )  # fmt: skip
    out = jax.block_until_ready(out)
    d = ctx.diag
    if not fewer:  # the first pass's futures and level; the repeats' levels and time add up
        d.update(nearest_futures=idx, nearest_level=(k + 0.5) / M, nearest_levels=[], nearest_s=0.0)
    d["nearest_levels"].append((k + 0.5) / M)
    d["nearest_s"] += time.perf_counter() - t0
    return out


#: the most samples MMD-Opt's kernel selection sees in the risk mode: beyond it the reduced set
#: is chosen among a random subset of this size (the n² kernel would dominate the plan time),
#: while the margins and the final check use every sample
SELECTION_POOL = 1000


def _selection_pool(method: str, config: MMDOptConfig, n: int, key) -> np.ndarray | None:
    """Sorted positions of the :data:`SELECTION_POOL` samples MMD-Opt selects from (the same
    for every obstacle; derived from ``key``), or ``None``: all of them (fewer samples, another
    method, or the time-linear margins, whose plans stay as they were)."""
    if method != "mmd" or n <= SELECTION_POOL or config.safety.margins.margin_mode != "samples":
        return None
    perm = np.asarray(jax.random.permutation(jax.random.fold_in(key, 0x9001), n))
    return np.sort(perm[:SELECTION_POOL])


#: the most "tail" passes of :func:`_final_check` (each adds the planning samples the best plan
#: so far meets to the reduced set and plans again, warm-started)
TAIL_PASSES = 3


#: MMD-Opt's margin ladder in the final check: besides the passes whose coverage margins are
#: at ε, one pass per rung (coverage margins at level rung·ε, capped at :data:`_LEVEL_CAP`;
#: ``math.inf``: the cap), each warm-started from the one before on the same reduced set, then
#: one refining tail pass (:func:`_refine`).  Their plans are candidates like any other: one is
#: returned only if its bound against all n planning samples is ≤ ε and its task cost the
#: least, so the plan at ε stays the answer whenever the samples allow no closer one.  Off by
#: default (``()``): with ``(4.0, 16.0)`` each MMD-Opt point moved 1–3 m beyond its frontier, but
#: the read-outs at 995 / 999 gained on one scene family and lost on another, for up to three
#: more passes per plan (docs/experiments/frontier.md, "What we tried")
MARGIN_LADDER: tuple[float, ...] = ()
#: the loosest coverage level of a rung (z = Φ⁻¹(0.55) ≈ 0.13 standard deviations)
_LEVEL_CAP = 0.45


def _rung_level(eps: float, factor: float) -> float:
    return min(factor * eps, _LEVEL_CAP)


def _ladder_passes(ctx: _Ctx, state, problem, key, backend, backend_settings):
    """The passes of :data:`MARGIN_LADDER` and their levels (MMD-Opt in the "samples" margin
    mode only; none otherwise): Algorithm 1 on the last pass's reduced set and weights, margins
    at each rung's level (a rung no looser than the one before is skipped), each warm-started
    from the previous pass."""
    config = ctx.config
    if ctx.method != "mmd" or not MARGIN_LADDER or ctx.obstacles is None:
        return [], []
    idx = np.asarray(ctx.rs.indices)
    if "reselected" in ctx.diag:
        idx = np.concatenate([idx, np.asarray(ctx.diag["reselected"])], 1)
    base = ctx.obstacles
    if idx.shape != tuple(base.weights.shape) or base.margins is None:
        return [], []
    eps = float(config.safety.risk)
    out, levels = [], [eps]
    for i, factor in enumerate(MARGIN_LADDER):
        level = _rung_level(eps, factor)
        if level <= levels[-1]:
            continue
        levels.append(level)
        margins = _coverage(config, ctx.obs_fr, idx, level)
        obstacles = alg.ObstacleSet.create(
            config, base.centres, base.weights, base.mode, mask=base.mask, margins=margins
        )
        state = alg.run(
            ctx.prob, config, problem, obstacles, jax.random.fold_in(key, 0x1AD + i), backend,
            warm_start=alg.shift(config, state, 0.0), **backend_settings,
        )  # fmt: skip
        out.append(jax.block_until_ready(state))
    return out, levels[1:]


def _refine(ctx, states, levels, bound, task, hits, eps, problem, key, backend, backend_settings):
    """One tail pass (:func:`_tail_pass`) from the cheapest ladder candidate that meets planning
    samples (bound > ε) while costing less than every candidate whose bound is ≤ ε: the samples
    it meets join the reduced set, the margins at its rung's level, so the plan may keep close
    to the samples but clear of them; appended to ``states``, the arrays returned extended."""
    first = len(states) - len(levels)
    good = bound <= eps
    best_good = np.min(task[good]) if good.any() else np.inf
    cand = [
        i
        for i in range(first, len(states))
        if np.isfinite(bound[i]) and not good[i] and task[i] < best_good and hits[i].any()
    ]
    if not cand:
        return bound, task, hits
    j = min(cand, key=lambda i: task[i])
    nxt = _tail_pass(ctx, states[j], hits[j], problem, jax.random.fold_in(key, 0x2EF), backend,
                     backend_settings, level=levels[j - first])  # fmt: skip
    if nxt is None:
        return bound, task, hits
    states.append(nxt)
    b, t, h = _bounds_of(ctx, [nxt.best])
    return np.concatenate([bound, b]), np.concatenate([task, t]), np.concatenate([hits, h])


#: plans are scored against every sample in batches padded to a multiple of this
_COUNT_BUCKET = 4


def _samples_met(ctx: _Ctx, s, d) -> np.ndarray:
    """(C, O, n) the planning samples each of the C plans (s, d) (C, K) meets, counted as
    :func:`collision_free_count` counts a collision (any circle pair, any step); the plans are
    padded to a multiple of :data:`_COUNT_BUCKET`, so one compiled count serves 1–4 of them."""
    config = ctx.config
    xy = np.stack([np.asarray(s, np.float64), np.asarray(d, np.float64)], -1)
    C = xy.shape[0]
    pad = -(-C // _COUNT_BUCKET) * _COUNT_BUCKET - C
    cnt = collision_free_count(
        np.concatenate([xy, np.repeat(xy[:1], pad, axis=0)]),
        ctx.obs_fr,
        a=config.safety.footprint.a,
        b=config.safety.footprint.b,
        obstacle_heading=ctx.obs_h,
    )
    return np.asarray(cnt.colliding)[:C]


def _bounds_of(ctx: _Ctx, bests) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The 95 % risk bound (C,), task cost (C,) and planning samples met (C, O, n) of candidate
    plans ``bests`` against every planning sample (as :func:`collision_free_count` counts a
    collision: any circle pair, any step)."""
    config, B = ctx.config, ctx.prob.basis
    cx = np.stack([np.asarray(b.cx, np.float64) for b in bests])
    cy = np.stack([np.asarray(b.cy, np.float64) for b in bests])
    s, d = cx @ B.P.T, cy @ B.P.T
    hits = _samples_met(ctx, s, d)  # (C, O, n)
    bound = np.array([_plan_bound(config, h) for h in hits])
    vs, as_, ad = cx @ B.Pdot.T, cx @ B.Pddot.T, cy @ B.Pddot.T
    c = config.cost
    task = c.w_speed * np.mean((vs - c.v_des) ** 2, -1) + c.w_accel * np.mean(as_**2 + ad**2, -1)
    ok = np.array([math.isfinite(float(b.cost)) and float(b.res) <= config.projection.res_tol
                   for b in bests])  # fmt: skip
    return np.where(ok, bound, np.inf), task, hits


def _final_check(ctx: _Ctx, passes, problem, key, backend, backend_settings):
    """The risk dial's final check ("samples" margin mode): every pass's best plan is scored
    against **all** n planning samples and its :func:`mmdopt.risk.risk_bound` computed (for
    MMD-Opt also the plans of :data:`MARGIN_LADDER`'s looser margins); while no
    candidate's bound is ≤ ε (and the method selects a reduced set), up to :data:`TAIL_PASSES`
    more passes (:func:`_tail_pass`) add the samples the best-bounded candidate meets to the
    reduced set and plan again, warm-started.
    (ε here is at least the floor of the n samples, :func:`mmdopt.risk.risk_floor`.)  Returns the
    state of the pass whose best is the chosen plan: among candidates with bound ≤ ε the one of
    least task cost (speed tracking and comfort, the terms every pass shares),
    else the one of least bound (its status then says "risk exceeded")."""
    n = ctx.obs_fr.shape[1]
    # below the floor of n samples no bound reaches ε: the aim is then a plan clear of them all
    G = ctx.config.bound_groups(ctx.obs_fr.shape[0])
    eps = max(float(ctx.config.safety.risk), risk_floor([n] * G) * (1 + 1e-9))
    ladder, levels = _ladder_passes(ctx, passes[-1], problem, key, backend, backend_settings)
    states = list(passes) + ladder
    bound, task, hits = _bounds_of(ctx, [p.best for p in states])
    if ladder:
        bound, task, hits = _refine(ctx, states, levels, bound, task, hits, eps, problem, key,
                                    backend, backend_settings)  # fmt: skip
    tails = 0
    while not np.any(bound <= eps) and SELECTOR[ctx.method] is not None and tails < TAIL_PASSES:
        j = int(np.argmin(bound))
        if not np.isfinite(bound[j]) or not hits[j].any():
            break
        nxt = _tail_pass(ctx, states[j], hits[j], problem, jax.random.fold_in(key, 2 + tails),
                         backend, backend_settings)  # fmt: skip
        if nxt is None:
            break
        states.append(nxt)
        b, t, h = _bounds_of(ctx, [nxt.best])
        bound, task, hits = (np.concatenate([bound, b]), np.concatenate([task, t]),
                             np.concatenate([hits, h]))  # fmt: skip
        tails += 1
    good = np.flatnonzero(bound <= eps)
    j = int(good[np.argmin(task[good])]) if good.size else int(np.argmin(bound))
    if not np.isfinite(bound[j]):
        j = len(passes) - 1
    ctx.diag.update(
        final_check_bounds=bound, final_check_task=task, final_check_choice=j, tail_passes=tails
    )
    best = states[j].best
    ctx.met = (np.asarray(best.cx, np.float64), np.asarray(best.cy, np.float64), hits[j])
    return states[j]


def _tail_pass(ctx: _Ctx, state, hits, problem, key, backend, backend_settings, level=None):
    """One more pass of Algorithm 1, warm-started from ``state``, on the reduced set plus r
    extra points (r = the re-selection pass's size, m/2 where that is off: one compiled program
    for every such pass): first the planning samples ``hits`` (O, n) that ``state``'s best plan
    meets, then the extra points of the previous pass (re-selected or tail), weight 1/n each;
    coverage margins at ε, or at ``level``; ``None`` when it meets no sample outside the
    reduced set."""
    config, obs_fr = ctx.config, ctx.obs_fr
    O, n = obs_fr.shape[:2]
    m = config.selection.reduced_set_size
    r = config.reselect_for(ctx.method) or max(1, m // 2)
    idx0 = np.asarray(ctx.rs.indices)
    prev = ctx.diag.get("tail_extra", ctx.diag.get("reselected"))
    h = np.asarray(hits, bool).copy()
    np.put_along_axis(h, idx0, False, axis=1)
    if not h.any():
        return None
    extra = np.empty((O, r), idx0.dtype)
    for o in range(O):  # a handful of obstacles
        cand = list(np.flatnonzero(h[o]))
        if prev is not None:
            cand += [int(i) for i in np.asarray(prev)[o] if not h[o, i]]
        cand = list(dict.fromkeys(cand)) or [int(idx0[o, 0])]
        extra[o] = (cand * r)[:r]  # repeats pad an obstacle with fewer (weight split below)
    idx = np.concatenate([idx0, extra], 1)
    w = np.concatenate(
        [np.asarray(ctx.rs.weights, np.float64) * (1.0 - r / n), np.full((O, r), 1.0 / n)], 1
    )
    cen = ctx.centres(idx)
    margins = _coverage(config, obs_fr, idx, level)
    obstacles = alg.ObstacleSet.create(config, cen, w, COLLISION_TERM[ctx.method], margins=margins)
    ctx.obstacles = obstacles
    ctx.diag["tail_extra"] = extra
    out = alg.run(
        ctx.prob, config, problem, obstacles, key, backend,
        warm_start=alg.shift(config, state, 0.0), **backend_settings,
    )  # fmt: skip
    return jax.block_until_ready(out)


def _braking_fallback(ctx: _Ctx, status: str, state=None) -> Plan:
    S = ctx.config.trajectory.num_segments
    road, ego = ctx.road, ctx.ego
    v = float(np.clip(ego.vs, max(road.v_min, 0.0), road.v_max))
    y = float(np.clip(ego.d, road.y_lb, road.y_ub))
    dvec = np.array([[v] * S + [y] * S])
    cx, cy = ctx.prob.planner.closed_form(dvec, ego)
    cx, cy = np.asarray(cx)[0], np.asarray(cy)[0]
    return _assemble(ctx, cx, cy, dvec[0], float("nan"), -1, True, status, state)


def _plan_mmd(ctx: _Ctx, s, d, vs, vd) -> float:
    """l_dist of the plan (s, d, ṡ, ḋ on the grid) against the method's obstacle samples, with
    the config's kernel, margins and rules (a diagnostic of the plan)."""
    config, ob = ctx.config, ctx.obstacles
    return float(
        _plan_mmd_value(
            config.program(), ctx.prob.t(), ob.centres, ob.weights, ob.margins, s[None], d[None],
            vs[None], vd[None], n_terms=n_taylor_terms(config),
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


def _assemble(ctx: _Ctx, cx, cy, dvec, cost, best_iter, fallback, status, state) -> Plan:
    config, prob, ego, diag = ctx.config, ctx.prob, ctx.ego, ctx.diag
    B = prob.basis
    s, vs, as_ = B.P @ cx, B.Pdot @ cx, B.Pddot @ cx
    d, vd, ad = B.P @ cy, B.Pdot @ cy, B.Pddot @ cy
    residual, groups = prob.grid_projection.residuals(cx, cy, ego.as_array())  # ego at s = 0
    s_off = float(diag.get("s_offset", 0.0))
    x, y, heading, speed = ctx.road.path.trajectory_to_cartesian(s + s_off, d, vs, vd)
    residual = float(residual[0])
    feasible = residual <= float(config.projection.res_tol) + 1e-9
    if not fallback and not feasible:
        status = (
            f"inaccurate: the returned plan's grid residual {residual:.3g} exceeds res_tol "
            f"{float(config.projection.res_tol):g}"
        )
    mmd_val = _plan_mmd(ctx, s, d, vs, vd)
    if ctx.met is not None and np.array_equal(ctx.met[0], cx) and np.array_equal(ctx.met[1], cy):
        colliding = ctx.met[2]  # counted by the final check
    else:
        colliding = _samples_met(ctx, s[None], d[None])[0]  # (O, n)
    cf_plan = colliding.shape[1] - colliding.sum(axis=1)
    if not fallback and np.any(cf_plan == 0):
        hit = [int(o) for o in np.flatnonzero(cf_plan == 0)]
        status = (
            f"unsafe: the plan collides with every planning sample of obstacle(s) {hit}; "
            "no collision-free plan was found"
        )
    bound = _plan_bound(config, colliding)
    if status == "ok" and config.safety.margins.margin_mode == "samples":
        status = _risk_status(config, bound, colliding)
    kind, why = _split_status(status)
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
        n_planning_samples=int(ctx.obs_fr.shape[1]),
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
        t=prob.t(),
        cost=cost,
        cost_trace=trace,
        residual=residual,
        mmd=mmd_val,
        feasible=bool(feasible),
        status=kind,
        message=why,
        risk_bound=bound,
        method=ctx.method,
        projector=ctx.backend,
        reduced_set=ctx.rs,
        plan_time_s=time.perf_counter() - ctx.t0,
        diagnostics=diag,
        state=state,
        config=config,
    )
