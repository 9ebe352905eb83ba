"""The planner's public types: :class:`Road`, :class:`PlanStatus`, :class:`Plan`, and how a plan
is written as plain data (:meth:`Plan.to_dict`, :func:`to_jsonable`)."""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

import frenet

from . import algorithm as alg
from .config import MMDOptConfig
from .samples import ReducedSet

__all__ = [
    "Road",
    "PlanStatus",
    "STATUS_PRECEDENCE",
    "Plan",
    "replacement_plan",
    "to_jsonable",
    "check_time",
    "MAX_COORD",
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
    ``SHIELDED``       the safety shield (``mmdopt.safety.shield``) replaced the plan by a
                       checked braking manoeuvre; nothing measured on the replaced plan is
                       kept (its cost, bound, MMD and feasibility are NaN / False)
    =================  ======================================================================

    A ``StrEnum``: ``plan.status == "ok"`` and ``str(plan.status)`` work as strings.
    When several apply, the first of :data:`STATUS_PRECEDENCE` is the plan's status.
    """

    OK = "ok"
    RISK_FLOOR = "risk floor"
    RISK_EXCEEDED = "risk exceeded"
    INACCURATE = "inaccurate"
    UNSAFE = "unsafe"
    FALLBACK = "fallback"
    SHIELDED = "shielded"


#: which status a plan gets when several apply, first wins: a replaced plan, then no usable
#: plan, then a plan that meets every sample of an obstacle, then one off the time grid's
#: bounds, then the risk level's verdicts
STATUS_PRECEDENCE: tuple[PlanStatus, ...] = (
    PlanStatus.SHIELDED,
    PlanStatus.FALLBACK,
    PlanStatus.UNSAFE,
    PlanStatus.INACCURATE,
    PlanStatus.RISK_FLOOR,
    PlanStatus.RISK_EXCEEDED,
    PlanStatus.OK,
)


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
    axis O; all n samples for "saa"/"scenario_all"); ``plan_time_s``: wall time of the call, less a
    predictor's draw (:attr:`predict_time_s`);
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

    def __repr__(self) -> str:
        bound = "nan" if not math.isfinite(self.risk_bound) else f"{self.risk_bound:.3g}"
        return (
            f"Plan({self.status.name}, method={self.method!r}, progress={self.progress:.3g} m, "
            f"risk_bound={bound}, cost={self.cost:.4g}, K={self.t.shape[0]}, "
            f"plan_time_s={self.plan_time_s:.3g})"
        )

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
    def predict_time_s(self) -> float:
        """Seconds the predictor took to draw this plan's futures (a
        :class:`~mmdopt.predict.Forecast`; 0 for fixed samples).  :attr:`plan_time_s` leaves it
        out: it is the planner's own time."""
        return float((self.diagnostics or {}).get("forecast_s", 0.0))

    @property
    def progress(self) -> float:
        """Arc length travelled over the horizon (m)."""
        return float(self.s[-1] - self.s[0])

    def ego_at(self, t: float) -> frenet.EgoState:
        """The planned Frenet state at ``t`` seconds from now (0 ≤ t ≤ horizon), linearly
        interpolated between the grid points (the grid need not contain ``t``)."""
        t = check_time(t, float(self.t[-1]), "t")
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
        dt = check_time(dt, float(self.t[-1]), "dt")
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
            k: to_jsonable(getattr(self, k))
            for k in ("t", "x", "y", "heading", "speed", "s", "d", "vs", "vd", "as_", "ad")
        }
        out.update(
            cost=to_jsonable(self.cost),
            cost_trace=to_jsonable(self.cost_trace),
            residual=to_jsonable(self.residual),
            risk_bound=to_jsonable(self.risk_bound),
            mmd=to_jsonable(self.mmd),
            progress=to_jsonable(self.progress),
            plan_time_s=to_jsonable(self.plan_time_s),
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
                weights=to_jsonable(np.asarray(rs.weights, np.float64)),
                mmd2=to_jsonable(np.asarray(getattr(rs, "mmd2", np.nan), np.float64)),
            )
        if diagnostics:
            out["diagnostics"] = to_jsonable(self.diagnostics)
        return out


def replacement_plan(
    plan: Plan,
    path: frenet.ReferencePath,
    frenet_arrays: dict[str, np.ndarray],
    status: PlanStatus,
    message: str,
    **diagnostics: Any,
) -> Plan:
    """The one constructor of a plan that replaces ``plan`` by a manoeuvre that Algorithm 1 did
    not plan (a braking fallback, the shield's intervention): the Frenet arrays
    ``frenet_arrays`` (``s, d, vs, vd, as_, ad`` on ``plan``'s grid), their Cartesian form on
    ``path``, ``status`` and ``message``; everything measured on the replaced plan is reset (cost,
    residual, MMD and risk bound NaN, ``feasible`` False, no Algorithm 1 state: the next plan
    starts cold), and ``diagnostics`` are added to the replaced plan's."""
    if not isinstance(plan, Plan):
        raise ValueError(f"plan must be an mmdopt.Plan, got {type(plan).__name__}")
    missing = [k for k in _FRENET_KEYS if k not in frenet_arrays]
    if missing:
        raise ValueError(f"frenet_arrays lacks {missing}")
    arr = {k: np.asarray(frenet_arrays[k], np.float64) for k in _FRENET_KEYS}
    x, y, heading, speed = path.trajectory_to_cartesian(arr["s"], arr["d"], arr["vs"], arr["vd"])
    diag = dict(plan.diagnostics)
    diag.update(diagnostics, replaced_status=str(plan.status))
    return dataclasses.replace(
        plan,
        x=x,
        y=y,
        heading=heading,
        speed=speed,
        **arr,
        cost=float("nan"),
        cost_trace=np.full_like(np.asarray(plan.cost_trace, np.float64), np.nan),
        residual=float("nan"),
        mmd=float("nan"),
        feasible=False,
        risk_bound=float("nan"),
        status=PlanStatus(status),
        message=str(message),
        diagnostics=diag,
        state=None,
    )


#: the Frenet fields of :class:`frenet.EgoState` and their arrays on :class:`Plan`
_FRENET_KEYS = ("s", "d", "vs", "vd", "as_", "ad")


def check_time(t: Any, horizon: float, name: str) -> float:
    if isinstance(t, bool | str | bytes | complex):
        raise ValueError(f"{name} must be a number of seconds, got {t!r}")
    try:
        t = float(t)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number of seconds, got {t!r}") from None
    if not (math.isfinite(t) and 0.0 <= t <= horizon + 1e-9):
        raise ValueError(f"{name} must lie in [0, {horizon:g}] s (the plan's horizon), got {t}")
    return min(t, horizon)


def to_jsonable(v: Any) -> Any:
    """Arrays to (nested) lists, NumPy/JAX scalars to Python numbers, NaN/inf floats to None."""
    if isinstance(v, dict):
        return {str(k): to_jsonable(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [to_jsonable(x) for x in v]
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
