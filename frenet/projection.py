"""Projection QP (Algorithm 1, line 8): the nearest feasible trajectory to each planner sample.

For every sample ``(c̄_x, c̄_y)`` (coefficients of a :mod:`frenet.basis` basis, Frenet frame)::

    min  ½‖M(c_x − c̄_x)‖² + ½‖M(c_y − c̄_y)‖²
    s.t. A_eq,x c_x = (s₀, v_s0, a_s0),  A_eq,y c_y = (d₀, v_d0, a_d0[, 0])          boundary
         y_lb ≤ y_k ≤ y_ub                                                           lane
         vx_min ≤ ẋ_k ≤ vx_max                                                       speed
         |ẏ_k| ≤ vy_max                                                        lateral_velocity
         |ẍ_k| ≤ ax_max,  |ÿ_k| ≤ ay_max                                       accel_x, accel_y
         cos φ_i ẍ_k + sin φ_i ÿ_k ≤ a_max cos(π/m),  φ_i = 2πi/m             accel_norm (optional)
         lower ≤ G_x q_x + G_y q_y ≤ upper                                     user rows (extra)

at every step ``k = 0 … K−1`` (bounds may be scalars or per-step ``(K,)`` arrays).  The optional
norm bound ``‖(ẍ_k, ÿ_k)‖ ≤ a_max`` is approximated by the regular ``m``-gon *inscribed* in the
circle (``m = accel_polygon_sides``, default 8): conservative, it admits ``‖a‖`` down to
``a_max cos(π/m)`` in the worst direction (92 % for m = 8).

**Metric.**  ``metric="waypoint"`` (default, the paper): ``M = P``, i.e. the distance between the
position samples ``(x_k, y_k)``.  ``metric="coefficient"`` (the reference code): ``M = I``.

The problem maps onto :class:`solvers.QPBatch`: ``P`` and ``A`` are shared by the batch, ``q``
(from ``c̄``) and ``l, u`` (from the boundary state and any per-sample user bounds) differ per
sample.  Variables are ``z = (c_x, c_y)`` (``2·nvar``).

User constraints (e.g. linearised collision half-planes, a speed-limit zone) are
:class:`LinearConstraints` passed as ``extra=``; their bounds may be per sample, ``(B, r)``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

import solvers

from .basis import Basis
from .planner import state_array

if TYPE_CHECKING:
    from .planner import EgoState

__all__ = [
    "ProjectionBounds",
    "LinearConstraints",
    "ProjectionProblem",
    "ProjectionResult",
    "JaxProjection",
    "DiffProjection",
]

_QUANTITY = {"position": "P", "velocity": "Pdot", "acceleration": "Pddot"}


def _per_step(v, K: int, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(K, float(a))
    if a.shape != (K,):
        raise ValueError(f"{name} must be a scalar or have shape ({K},), got {a.shape}")
    if np.any(np.isnan(a)):
        raise ValueError(f"{name} contains NaN")
    return a


@dataclass(frozen=True)
class ProjectionBounds:
    """Kinematic and lane bounds (Frenet frame, SI units); defaults as in the authors' code.

    Each bound is a scalar or a ``(K,)`` per-step array; ``±inf`` drops the corresponding rows.

    y_lb, y_ub : lane bounds on the lateral offset (m); reference ±0.3.
    vx_min, vx_max : longitudinal speed bounds (m/s); reference [0.1, 30].
    vy_max : ``|ẏ| ≤ vy_max`` (m/s).
    ax_max, ay_max : per-axis acceleration bounds ``|ẍ| ≤ ax_max``, ``|ÿ| ≤ ay_max`` (m/s²); 18.
    a_max : optional norm bound ``‖(ẍ, ÿ)‖ ≤ a_max`` (m/s²), approximated by an inscribed polygon
        with ``accel_polygon_sides`` sides (see the module docstring).  ``None``: off.
    """

    y_lb: Any = -0.3
    y_ub: Any = 0.3
    vx_min: Any = 0.1
    vx_max: Any = 30.0
    vy_max: Any = 30.0
    ax_max: Any = 18.0
    ay_max: Any = 18.0
    a_max: Any = None
    accel_polygon_sides: int = 8

    def per_step(self, K: int) -> dict[str, np.ndarray]:
        """All bounds as ``(K,)`` arrays; NaN, negative magnitudes and ``lower > upper`` raise."""
        out = {}
        for name in ("y_lb", "y_ub", "vx_min", "vx_max", "vy_max", "ax_max", "ay_max"):
            out[name] = _per_step(getattr(self, name), K, name)
        for name in ("vy_max", "ax_max", "ay_max"):
            if np.any(out[name] < 0):
                raise ValueError(f"{name} must be ≥ 0")
        for lo, hi in (("y_lb", "y_ub"), ("vx_min", "vx_max")):
            if np.any(out[lo] > out[hi]):
                raise ValueError(f"{lo} > {hi} at some step: the constraint set is empty")
        if self.a_max is not None:
            out["a_max"] = _per_step(self.a_max, K, "a_max")
            if np.any(out["a_max"] < 0):
                raise ValueError("a_max must be ≥ 0")
            if int(self.accel_polygon_sides) < 3:
                raise ValueError("accel_polygon_sides must be ≥ 3")
        return out


@dataclass(frozen=True, eq=False)
class LinearConstraints:
    """User rows ``lower ≤ G_x q_x + G_y q_y ≤ upper`` on a trajectory quantity at the grid steps.

    ``q = P c`` (``quantity="position"``), ``Ṗ c`` (``"velocity"``) or ``P̈ c`` (``"acceleration"``),
    so ``G_x, G_y`` are ``(r, K)`` weights on the K samples of each axis, shared by the batch, or
    ``(B, r, K)`` per sample (e.g. collision half-planes linearised about each sample: then the
    problems no longer share ``A``; :meth:`ProjectionProblem.project` solves them one by one and
    :meth:`ProjectionProblem.batch`/``jax_projector`` refuse them – prefer shared rows with
    per-sample bounds where the geometry allows).
    ``lower, upper`` are scalars, ``(r,)``, or ``(B, r)`` per sample; ``±inf`` for one-sided rows.

    Examples
    --------
    A half-plane ``n·(x_k, y_k) ≥ h_b`` per sample b at step k (linearised collision avoidance with
    a fixed normal, per-sample offsets) or a speed limit ``ẋ_k ≤ 8`` for ``k ≥ 40``::

        LinearConstraints.at_steps([k], nx=[n[0]], ny=[n[1]], lower=h[:, None], upper=np.inf)
        LinearConstraints.at_steps(range(40, 100), nx=1.0, ny=0.0, lower=-np.inf, upper=8.0,
                                   quantity="velocity", name="speed_zone")
    """

    Gx: np.ndarray
    Gy: np.ndarray
    lower: Any = -np.inf
    upper: Any = np.inf
    quantity: str = "position"
    name: str = "extra"

    def __post_init__(self) -> None:
        Gx, Gy = np.asarray(self.Gx, dtype=np.float64), np.asarray(self.Gy, dtype=np.float64)
        if Gx.ndim not in (2, 3) or Gx.shape != Gy.shape:
            raise ValueError(
                f"Gx and Gy must have equal shapes (r, K) or (B, r, K), got {Gx.shape}, {Gy.shape}"
            )
        if not (np.all(np.isfinite(Gx)) and np.all(np.isfinite(Gy))):
            raise ValueError("Gx/Gy contain NaN or inf")
        if self.quantity not in _QUANTITY:
            raise ValueError(f"quantity must be one of {sorted(_QUANTITY)}, got {self.quantity!r}")
        r = Gx.shape[-2]
        for nm in ("lower", "upper"):
            v = np.asarray(getattr(self, nm), dtype=np.float64)
            if v.ndim == 0:
                v = np.full(r, float(v))
            if v.shape[-1:] != (r,) or v.ndim > 2:
                raise ValueError(f"{nm} must be a scalar, (r,) or (B, r) with r={r}, got {v.shape}")
            if np.any(np.isnan(v)):
                raise ValueError(f"{nm} contains NaN")
            object.__setattr__(self, nm, v)
        if np.any(
            np.broadcast_arrays(self.lower, self.upper)[0]
            > np.broadcast_arrays(self.lower, self.upper)[1]
        ):
            raise ValueError(f"LinearConstraints {self.name!r}: lower > upper")
        object.__setattr__(self, "Gx", Gx)
        object.__setattr__(self, "Gy", Gy)

    @property
    def num_rows(self) -> int:
        return self.Gx.shape[-2]

    @property
    def per_sample(self) -> bool:
        """True when the rows themselves differ per sample (``Gx`` of shape ``(B, r, K)``)."""
        return self.Gx.ndim == 3

    @classmethod
    def at_steps(
        cls,
        steps,
        nx,
        ny,
        lower=-np.inf,
        upper=np.inf,
        *,
        num_steps: int = 100,
        quantity: str = "position",
        name: str = "extra",
    ) -> LinearConstraints:
        """One row per step in ``steps``: ``lower ≤ nx·q_x[k] + ny·q_y[k] ≤ upper``.

        ``nx, ny`` are scalars or one value per row; ``num_steps`` is the grid's K.
        """
        steps = np.asarray(list(steps), dtype=int)
        r = steps.size
        if r == 0:
            raise ValueError("steps is empty")
        if steps.min() < 0 or steps.max() >= num_steps:
            raise ValueError(f"steps must lie in [0, {num_steps - 1}]")
        Gx, Gy = np.zeros((r, num_steps)), np.zeros((r, num_steps))
        Gx[np.arange(r), steps] = np.broadcast_to(np.asarray(nx, dtype=np.float64), (r,))
        Gy[np.arange(r), steps] = np.broadcast_to(np.asarray(ny, dtype=np.float64), (r,))
        return cls(Gx, Gy, lower, upper, quantity, name)


@dataclass(frozen=True, eq=False)
class ProjectionResult:
    """Projected trajectories and diagnostics (numpy).

    cx, cy : (B, nvar) projected coefficients.
    residual : (B,) total constraint violation, the max over ``residual_groups``.
    residual_groups : {group name: (B,)} max violation of each constraint group (≥ 0).
    status : (B,) int :class:`solvers.Status` codes from the backend.
    distance : (B,) ``½‖M(c − c̄)‖²`` (the projection objective at the returned point).
    solution : the backend's :class:`solvers.BatchSolution`.
    """

    cx: np.ndarray
    cy: np.ndarray
    residual: np.ndarray
    residual_groups: dict[str, np.ndarray]
    status: np.ndarray
    distance: np.ndarray
    solution: Any = field(repr=False, default=None)

    @property
    def solved(self) -> np.ndarray:
        return self.status == solvers.STATUS_CODES.SOLVED


@dataclass(frozen=True, eq=False)
class _Group:
    name: str
    rows: slice
    # static bounds (r,), or None when filled per sample
    lower: np.ndarray | None
    upper: np.ndarray | None


class _RowBlocks:
    """The row blocks of a constraint matrix being assembled, with their groups."""

    def __init__(self) -> None:
        self.blocks: list[np.ndarray] = []
        self.groups: list[_Group] = []

    def add(self, name: str, M, lo, hi) -> None:
        """Append the rows ``M`` with bounds ``lo, hi`` (broadcast to one per row; rows unbounded
        on both sides are dropped, and the whole group when none is left).  ``lo = None``: bounds
        filled per sample (then no row is dropped)."""
        if lo is not None:
            lo = np.broadcast_to(np.asarray(lo, dtype=np.float64), (M.shape[0],))
            hi = np.broadcast_to(np.asarray(hi, dtype=np.float64), (M.shape[0],))
            keep = np.isfinite(lo) | np.isfinite(hi)
            if not np.any(keep):
                return
            M, lo, hi = M[keep], lo[keep], hi[keep]
        start = sum(x.shape[0] for x in self.blocks)
        self.blocks.append(M)
        self.groups.append(_Group(name, slice(start, start + M.shape[0]), lo, hi))


def _sample_bounds(e: LinearConstraints, lo, hi, B: int) -> tuple[np.ndarray, np.ndarray]:
    """``(lower, upper)`` of the user constraint set ``e`` as ``(B, r)`` arrays (checked)."""
    r = e.num_rows
    res = []
    for nm, v in (("lower", lo), ("upper", hi)):
        v = np.asarray(v, dtype=np.float64)
        if v.ndim == 0:
            v = np.full(r, float(v))
        if v.ndim == 1:
            v = v[None]
        if v.shape[1] != r or v.shape[0] not in (1, B) or v.ndim != 2:
            raise ValueError(
                f"{e.name} {nm} bounds must be (r,) or (B, r) = ({B}, {r}), got {v.shape}"
            )
        if np.any(np.isnan(v)):
            raise ValueError(f"{e.name} {nm} bounds contain NaN")
        res.append(np.broadcast_to(v, (B, r)))
    if np.any(res[0] > res[1]):
        raise ValueError(f"{e.name}: lower > upper for some sample")
    return res[0], res[1]


def _constraint_tuple(extra) -> tuple[LinearConstraints, ...]:
    """``extra`` (None, one :class:`LinearConstraints` or a sequence of them) as a tuple."""
    if extra is None:
        extra = ()
    elif isinstance(extra, LinearConstraints):
        extra = (extra,)
    extra = tuple(extra)
    for e in extra:
        if not isinstance(e, LinearConstraints):
            raise TypeError(f"extra must hold LinearConstraints, got {type(e).__name__}")
    return extra


def _check_modes(basis: Basis, metric: str, constraint_points: str) -> None:
    if metric not in ("waypoint", "coefficient"):
        raise ValueError(f"metric must be 'waypoint' or 'coefficient', got {metric!r}")
    if constraint_points not in ("grid", "hull"):
        raise ValueError(f"constraint_points must be 'grid' or 'hull', got {constraint_points!r}")
    if constraint_points == "hull" and not hasattr(basis, "control_point_maps"):
        raise ValueError("constraint_points='hull' needs a Bernstein basis (convex-hull property)")


def _penalised_hessian(H: np.ndarray, rho: float, Aex: np.ndarray, Aey: np.ndarray) -> np.ndarray:
    """``blockdiag(H + ρA_eq,xᵀA_eq,x, H + ρA_eq,yᵀA_eq,y)``."""
    n = H.shape[0]
    return np.block(
        [
            [H + rho * Aex.T @ Aex, np.zeros((n, n))],
            [np.zeros((n, n)), H + rho * Aey.T @ Aey],
        ]
    )


class ProjectionProblem:
    """The projection QP for one basis, set of bounds and optional user constraints.

    Parameters
    ----------
    basis : frenet.basis.Basis
    bounds : ProjectionBounds
    extra : LinearConstraints or a sequence of them, optional
    metric : "waypoint" (default; distance of the position samples, paper) or "coefficient"
    final_lateral_velocity : impose ``ẏ_{K−1} = 0`` (reference: yes).
    constraint_points : "grid" (default): the kinematic and lane bounds at every grid step.
        "hull" (Bernstein bases only): the bounds on the control points of ``p``, ``ṗ``, ``p̈``
        instead – by the convex-hull property this is *sufficient* for the bounds to hold at
        every instant of ``[0, T]`` (conservative: per-step bounds are replaced by their tightest
        value), with ~10× fewer, non-degenerate rows, on which ADMM converges much faster.
        User rows (``extra``) and the boundary equalities are the same in both modes, and
        residuals are always measured at the grid steps.

    Attributes
    ----------
    P : (2 nvar, 2 nvar) QP Hessian ``blockdiag(MᵀM + ρA_eq,xᵀA_eq,x, MᵀM + ρA_eq,yᵀA_eq,y)``: the
        metric plus an exact penalty on the boundary rows (zero on the feasible set, so the
        optimum is unchanged; it makes ``P`` positive definite).
    A : (m, 2 nvar) constraint matrix; ``groups`` names its row blocks.
    """

    def __init__(
        self,
        basis: Basis,
        bounds: ProjectionBounds | None = None,
        extra: LinearConstraints | Sequence[LinearConstraints] | None = None,
        *,
        metric: str = "waypoint",
        final_lateral_velocity: bool = True,
        constraint_points: str = "grid",
    ):
        self.basis = basis
        self.bounds = bounds if bounds is not None else ProjectionBounds()
        self.extra = _constraint_tuple(extra)
        _check_modes(basis, metric, constraint_points)
        self.metric = metric
        self.final_lateral_velocity = bool(final_lateral_velocity)
        self.constraint_points = constraint_points
        K, n = basis.num_steps, basis.nvar
        self.nvar = n
        b = self.bounds.per_step(K)
        self._bounds_k = b
        Aex, Aey = basis.boundary_rows(self.final_lateral_velocity)
        self._Aex, self._Aey = Aex, Aey
        self._grid_A, self._grid_groups = self._build_rows("grid")
        if constraint_points == "grid":
            self.A, self.groups = self._grid_A, self._grid_groups
        else:
            self.A, self.groups = self._build_rows("hull")
        self._extra_groups = tuple(
            g for g in self.groups if g.lower is None and g.name != "boundary"
        )
        Mx = basis.P if metric == "waypoint" else np.eye(n)
        H = Mx.T @ Mx
        self.metric_matrix = H  # per axis
        # Exact penalty ½ρ‖A_eq c − b‖² (zero on the feasible set: same optimum, same distance)
        # makes the Hessian positive definite (PᵀP is singular for the triple integrator).
        self._rho_eq = float(np.trace(H)) / n
        self.P = _penalised_hessian(H, self._rho_eq, Aex, Aey)
        for M in (self.A, self.P, self._grid_A):
            M.setflags(write=False)

    def _build_rows(self, kind: str) -> tuple[np.ndarray, tuple[_Group, ...]]:
        """Constraint rows and their groups, at the grid steps or on Bernstein control points."""
        basis, b = self.basis, self._bounds_k
        if kind == "grid":
            Mp, Mv, Ma = basis.P, basis.Pdot, basis.Pddot

            def bnd(key, rows):
                return b[key]
        else:
            Mp, Mv, Ma = basis.control_point_maps()

            def bnd(key, rows):  # the tightest bound over the horizon, on every control point
                v = b[key]
                return np.full(rows, v.max() if key in ("y_lb", "vx_min") else v.min())

        rows = _RowBlocks()
        Aex, Aey = self._Aex, self._Aey
        eq_rows = np.block([[Aex, np.zeros_like(Aex)], [np.zeros_like(Aey), Aey]])
        rows.add("boundary", eq_rows, None, None)
        self._add_kinematic_rows(rows, Mp, Mv, Ma, bnd)
        self._add_user_rows(rows)
        return np.vstack(rows.blocks), tuple(rows.groups)

    def _add_kinematic_rows(self, rows: _RowBlocks, Mp, Mv, Ma, bnd) -> None:
        """The lane, speed and acceleration groups on the maps ``Mp, Mv, Ma`` (position,
        velocity, acceleration samples) with ``bnd(key, num_rows)`` their bounds."""
        n = self.nvar

        def xy(Mx_, My_):
            return (
                np.hstack([Mx_, np.zeros((Mx_.shape[0], n))])
                if My_ is None
                else np.hstack([np.zeros((My_.shape[0], n)), My_])
            )

        rp, rv, ra = Mp.shape[0], Mv.shape[0], Ma.shape[0]
        rows.add("lane", xy(None, Mp), bnd("y_lb", rp), bnd("y_ub", rp))
        rows.add("speed", xy(Mv, None), bnd("vx_min", rv), bnd("vx_max", rv))
        rows.add("lateral_velocity", xy(None, Mv), -bnd("vy_max", rv), bnd("vy_max", rv))
        rows.add("accel_x", xy(Ma, None), -bnd("ax_max", ra), bnd("ax_max", ra))
        rows.add("accel_y", xy(None, Ma), -bnd("ay_max", ra), bnd("ay_max", ra))
        if "a_max" in self._bounds_k:
            m = int(self.bounds.accel_polygon_sides)
            phi = 2 * np.pi * np.arange(m) / m
            poly = np.concatenate([np.hstack([np.cos(p) * Ma, np.sin(p) * Ma]) for p in phi])
            rows.add("accel_norm", poly, -np.inf, np.tile(bnd("a_max", ra) * np.cos(np.pi / m), m))

    def _add_user_rows(self, rows: _RowBlocks) -> None:
        """One group per user constraint set (bounds filled per sample; a repeated name gets a
        suffix ``_2``, ``_3``, …).  Per-sample rows enter as the first sample's rows."""
        K = self.basis.num_steps
        names = {g.name for g in rows.groups}
        for e in self.extra:
            if e.Gx.shape[-1] != K:
                raise ValueError(
                    f"LinearConstraints {e.name!r} has {e.Gx.shape[-1]} columns, "
                    f"the grid has K={K} steps"
                )
            name = e.name
            i = 1
            while name in names:
                i += 1
                name = f"{e.name}_{i}"
            names.add(name)
            M = getattr(self.basis, _QUANTITY[e.quantity])
            G0x, G0y = (e.Gx[0], e.Gy[0]) if e.per_sample else (e.Gx, e.Gy)  # placeholder rows
            rows.add(name, np.hstack([G0x @ M, G0y @ M]), None, None)

    # ------------------------------------------------------------------ helpers
    @property
    def num_rows(self) -> int:
        return self.A.shape[0]

    def group_slices(self) -> dict[str, slice]:
        """``{group name: row slice of A}``."""
        return {g.name: g.rows for g in self.groups}

    def _coeffs(self, cx, cy) -> tuple[np.ndarray, np.ndarray]:
        cx = np.asarray(cx, dtype=np.float64)
        cy = np.asarray(cy, dtype=np.float64)
        if cx.ndim == 1:
            cx = cx[None]
        if cy.ndim == 1:
            cy = cy[None]
        n = self.nvar
        if cx.ndim != 2 or cx.shape[1] != n or cy.shape != cx.shape:
            raise ValueError(
                f"coefficients must have shape (B, {n}) for this basis, "
                f"got {cx.shape} and {cy.shape}"
            )
        if not (np.all(np.isfinite(cx)) and np.all(np.isfinite(cy))):
            raise ValueError("coefficients contain NaN or inf")
        return cx, cy

    def _extra_bounds(self, B: int, extra_bounds) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per-sample ``(lower, upper)`` (B, r) per extra group (``extra_bounds`` overrides)."""
        if extra_bounds is not None:
            if len(extra_bounds) != len(self.extra):
                raise ValueError(
                    f"extra_bounds needs one (lower, upper) per extra constraint set "
                    f"({len(self.extra)}), got {len(extra_bounds)}"
                )
        out = []
        for i, e in enumerate(self.extra):
            lo, hi = (e.lower, e.upper) if extra_bounds is None else extra_bounds[i]
            out.append(_sample_bounds(e, lo, hi, B))
        return out

    def check_state(self, state: EgoState | ArrayLike) -> NDArray[np.float64]:
        """Validate boundary states against the bounds at step 0; returns ``(B, 6)``.

        Raises ``ValueError`` when an initial state violates a bound (e.g. initial speed above
        ``vx_max``): the projection would be infeasible for that sample.
        """
        st = state_array(state)
        b = self._bounds_k
        tol = 1e-9
        checks = [
            ("initial lateral offset d", st[:, 1], b["y_lb"][0], b["y_ub"][0]),
            ("initial speed vs", st[:, 2], b["vx_min"][0], b["vx_max"][0]),
            ("initial lateral velocity vd", st[:, 3], -b["vy_max"][0], b["vy_max"][0]),
            ("initial longitudinal acceleration as_", st[:, 4], -b["ax_max"][0], b["ax_max"][0]),
            ("initial lateral acceleration ad", st[:, 5], -b["ay_max"][0], b["ay_max"][0]),
        ]
        for what, v, lo, hi in checks:
            bad = (v < lo - tol) | (v > hi + tol)
            if np.any(bad):
                i = int(np.flatnonzero(bad)[0])
                raise ValueError(
                    f"infeasible boundary state: {what} = {v[i]:g} outside [{lo:g}, {hi:g}] "
                    f"(sample {i}); the projection has no feasible point"
                )
        if "a_max" in b:
            an = np.hypot(st[:, 4], st[:, 5])
            if np.any(
                an > b["a_max"][0] * np.cos(np.pi / int(self.bounds.accel_polygon_sides)) + tol
            ):
                raise ValueError(
                    "infeasible boundary state: initial acceleration above the a_max polygon"
                )
        return st

    def bounds_arrays(
        self, state, batch: int, extra_bounds=None, *, grid: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per-sample ``(l, u)`` of shape ``(B, m)`` for the rows of :attr:`A` (``grid=True``: for
        the grid-step rows used by :meth:`residuals`, which differ in ``"hull"`` mode)."""
        st = state_array(state, batch)
        groups = self._grid_groups if grid else self.groups
        m = (self._grid_A if grid else self.A).shape[0]
        l = np.empty((batch, m))
        u = np.empty((batch, m))
        beq = np.concatenate([st[:, [0, 2, 4]], st[:, [1, 3, 5]]], axis=1)
        if self.final_lateral_velocity:
            beq = np.concatenate([beq, np.zeros((batch, 1))], axis=1)
        ex = iter(self._extra_bounds(batch, extra_bounds))
        for g in groups:
            if g.name == "boundary":
                l[:, g.rows] = beq
                u[:, g.rows] = beq
            elif g.lower is not None:
                l[:, g.rows] = g.lower
                u[:, g.rows] = g.upper
            else:
                lo, hi = next(ex)
                l[:, g.rows] = lo
                u[:, g.rows] = hi
        return l, u

    # ------------------------------------------------------------------ QP
    def batch(
        self,
        cx_bar: ArrayLike,
        cy_bar: ArrayLike,
        state: EgoState | ArrayLike,
        extra_bounds: Any = None,
    ) -> solvers.QPBatch:
        """The projection of every sample as one :class:`solvers.QPBatch` (shared ``P``, ``A``).

        ``state`` is an :class:`~frenet.planner.EgoState`, ``(6,)`` or ``(B, 6)``; ``extra_bounds``
        optionally overrides the user constraints' bounds: one ``(lower, upper)`` pair per
        :class:`LinearConstraints`, each ``(r,)`` or ``(B, r)``.
        """
        if self.per_sample_rows:
            raise ValueError(
                "the user constraints have per-sample rows, so the problems do not share A: "
                "use qps() or project()"
            )
        q, l, u = self._qlu(cx_bar, cy_bar, state, extra_bounds)
        return solvers.QPBatch(self.P, self.A, q, l, u)

    @property
    def per_sample_rows(self) -> bool:
        """True when some user constraint has per-sample rows (no shared ``A``)."""
        return any(e.per_sample for e in self.extra)

    def _qlu(self, cx_bar, cy_bar, state, extra_bounds):
        cx, cy = self._coeffs(cx_bar, cy_bar)
        B = cx.shape[0]
        st = self.check_state(state)
        if st.shape[0] not in (1, B):
            raise ValueError(f"state has batch size {st.shape[0]}, expected 1 or {B}")
        for e in self.extra:
            if e.per_sample and e.Gx.shape[0] != B:
                raise ValueError(
                    f"LinearConstraints {e.name!r} has rows for {e.Gx.shape[0]} samples, "
                    f"the batch has {B}"
                )
        q = self.linear_term(cx, cy, st)
        l, u = self.bounds_arrays(st, B, extra_bounds)
        return q, l, u

    def _sample_rows(self, Az: np.ndarray, cx: np.ndarray, cy: np.ndarray, grid: bool) -> None:
        """Overwrite the per-sample user rows of ``Az (B, m)`` with each sample's own rows."""
        gs = self._grid_groups if grid else self.groups
        ex = [g for g in gs if g.lower is None and g.name != "boundary"]
        for g, e in zip(ex, self.extra, strict=True):
            if e.per_sample:
                M = getattr(self.basis, _QUANTITY[e.quantity])
                Az[:, g.rows] = np.einsum("brk,bk->br", e.Gx, cx @ M.T) + np.einsum(
                    "brk,bk->br", e.Gy, cy @ M.T
                )

    def qps(
        self,
        cx_bar: ArrayLike,
        cy_bar: ArrayLike,
        state: EgoState | ArrayLike,
        extra_bounds: Any = None,
    ) -> list[solvers.QP]:
        """The projection of each sample as its own :class:`solvers.QP` (allows per-sample rows)."""
        q, l, u = self._qlu(cx_bar, cy_bar, state, extra_bounds)
        out = []
        n = self.nvar
        for b in range(q.shape[0]):
            A = np.array(self.A)
            for g, e in zip(self._extra_groups, self.extra, strict=True):
                if e.per_sample:
                    M = getattr(self.basis, _QUANTITY[e.quantity])
                    A[g.rows, :n] = e.Gx[b] @ M
                    A[g.rows, n:] = e.Gy[b] @ M
            out.append(solvers.QP(self.P, q[b], A, l[b], u[b]))
        return out

    def linear_term(self, cx_bar, cy_bar, state) -> np.ndarray:
        """``q (B, 2 nvar)`` of the QP: ``−blockdiag(MᵀM) c̄ − ρ A_eqᵀ b`` (see :attr:`P`)."""
        cx, cy = np.asarray(cx_bar, dtype=np.float64), np.asarray(cy_bar, dtype=np.float64)
        st = state_array(state, cx.shape[0])
        H = self.metric_matrix
        bx = st[:, [0, 2, 4]]
        by = st[:, [1, 3, 5]]
        if self.final_lateral_velocity:
            by = np.concatenate([by, np.zeros((by.shape[0], 1))], axis=1)
        return -np.concatenate(
            [cx @ H + self._rho_eq * bx @ self._Aex, cy @ H + self._rho_eq * by @ self._Aey], axis=1
        )

    def project(
        self,
        cx_bar: ArrayLike,
        cy_bar: ArrayLike,
        state: EgoState | ArrayLike,
        backend: str | None = None,
        *,
        extra_bounds: LinearConstraints | Sequence[LinearConstraints] | None = None,
        warm_start: Any = None,
        **settings: Any,
    ) -> ProjectionResult:
        """Project a batch of samples with a :mod:`solvers` backend.

        ``backend`` defaults to ``"admm"`` when available, else ``"clarabel"``; ``settings`` go to
        the native solver.  Returns a :class:`ProjectionResult` (residuals recomputed from the
        returned coefficients, status from the backend).
        """
        if backend is None:
            backend = "admm" if "admm" in solvers.available_backends() else "clarabel"
        if self.per_sample_rows:  # no shared A: one QP at a time
            t0 = time.perf_counter()
            qps = self.qps(cx_bar, cy_bar, state, extra_bounds)
            sols = [solvers.solve(qp, backend=backend, **settings) for qp in qps]
            sol = solvers.BatchSolution.stack(sols, backend, time.perf_counter() - t0)
        else:
            batch = self.batch(cx_bar, cy_bar, state, extra_bounds)
            sol = solvers.solve_batch(batch, backend=backend, warm_start=warm_start, **settings)
        n = self.nvar
        x = np.asarray(sol.x, dtype=np.float64)
        finite = np.all(np.isfinite(x), axis=1)
        status = np.asarray(sol.status).copy()
        status[~finite] = solvers.STATUS_CODES.ERROR
        cx_bar, cy_bar = self._coeffs(cx_bar, cy_bar)
        cx = np.where(finite[:, None], x[:, :n], cx_bar)
        cy = np.where(finite[:, None], x[:, n:], cy_bar)
        total, groups = self.residuals(cx, cy, state, extra_bounds)
        total = np.where(finite, total, np.inf)
        return ProjectionResult(
            cx, cy, total, groups, status, self.distance(cx, cy, cx_bar, cy_bar), sol
        )

    def jax_projector(
        self,
        num_iters: int = 100,
        dtype: str = "float32",
        split_axes: bool | None = None,
        **settings: Any,
    ) -> Callable[..., JaxProjection]:
        """A pure-JAX batched projector for use inside jitted code (Algorithm 1's inner loop).

        Built on :func:`solvers.admm.admm_factor` / :func:`solvers.admm.admm_projector` (a
        :class:`solvers.JaxProjector` running :func:`solvers.admm.admm_iterate`): ``P`` and
        ``A`` are factored once here (float64, NumPy); each call runs a fixed budget of
        ``num_iters`` ADMM iterations (rounded up to a multiple of ``check_every``; it may stop
        earlier once every sample meets the tolerances), no polish.  ``settings`` are
        :class:`solvers.admm.ADMMSettings` names (e.g. ``rho=``, ``eps_abs=``); the defaults
        here start at ``rho = 62.5`` on a ladder extended to 312.5, with adaptation (measured
        best at 25–500 iterations, docs/experiments/qp-backends.md).

        Returns ``project(cx_bar (B, nvar), cy_bar (B, nvar), state (6,) or (B, 6),
        extra_bounds=None, warm_start=None) -> JaxProjection(cx, cy, residual, groups, admm)``.
        ``extra_bounds`` is one ``(lower, upper)`` pair per user constraint set, each ``(r,)`` or
        ``(B, r)``; ``warm_start`` is a previous call's ``admm`` state (same batch size).
        The function does no input validation (it must trace): validate with
        :meth:`check_state` outside the jitted loop.  float64 needs JAX's x64 mode.

        ``split_axes``: the projection separates into one QP per axis when every row involves
        only ``cx`` or only ``cy`` (``P`` is block diagonal; true without user constraints or an
        acceleration polygon): two ADMM problems of half the size, each scaled and stepped on
        its own (≈ 1.7× faster at Algorithm 1's sizes, docs/experiments/qp-backends.md).  ``None``:
        split
        when possible; ``True``: split or raise; ``False``: one joint problem.  The returned
        ``admm`` state is in the joint row order either way.
        """
        return _jax_projector(self, num_iters, dtype, settings, split_axes)

    def differentiable_projector(
        self, method: str = "ipm", *, active_tol: float = 1e-6, **settings: Any
    ) -> Callable[..., DiffProjection]:
        """A projector that JAX differentiates end to end, through :func:`solvers.jax.solve_qp`.

        Returns ``project(cx_bar, cy_bar, state, bounds=None, weights=None, extra_bounds=None)
        -> DiffProjection(cx, cy, status)``: it builds the projection QP of this problem (the
        same rows, metric and boundary equalities as :meth:`project`) in JAX from its inputs and
        solves it with ``solve_qp(..., method=method, active_tol=active_tol, **settings)``.
        Jittable and vmappable; ``jax.grad`` (or ``jax.jvp``, ``jax.jacrev``) of a loss of the
        projected coefficients works with respect to every input:

        * ``cx_bar, cy_bar`` : ``(nvar,)`` one sample, or ``(B, nvar)`` a batch (then ``state``
          may be ``(6,)`` shared or ``(B, 6)``, and ``bounds``, ``weights``, ``extra_bounds`` are
          shared by the batch; ``jax.vmap`` the single-sample form for per-sample values).
        * ``state`` : the ego state ``(s, d, v_s, v_d, a_s, a_d)`` (or an
          :class:`~frenet.planner.EgoState` as an array), the boundary rows' right-hand side.
        * ``bounds`` : a mapping overriding :class:`ProjectionBounds` fields (``"y_lb"``,
          ``"y_ub"``, ``"vx_min"``, ``"vx_max"``, ``"vy_max"``, ``"ax_max"``, ``"ay_max"``, and
          ``"a_max"`` when the problem has the acceleration polygon), each a scalar or ``(K,)``;
          the others keep this problem's values.  Every kinematic row is in the QP (an infinite
          bound is an inactive row), so any bound can be given a finite value here.  In
          ``constraint_points="hull"`` mode each bound enters through its tightest value over
          the horizon (a max or min, differentiable almost everywhere).
        * ``weights`` : the objective ``½ Σ_axis Σ_i w_{axis,i} (M(c − c̄))_i²``: a scalar,
          ``(r,)`` (both axes) or ``(2, r)`` (x then y), ``r = K`` for ``metric="waypoint"``
          and ``r = nvar`` for ``"coefficient"``.  ``None`` (all ones) is :meth:`project`'s
          objective.  Weights must be positive (not checked inside a trace).
        * ``extra_bounds`` : one ``(lower, upper)`` pair per user constraint set, each scalar or
          ``(r,)`` (default: the sets' own bounds).

        Conventions of the derivative (those of :func:`solvers.jax.solve_qp`): it is the
        derivative of the QP's solution on the active set read from the multipliers; a weakly
        active row (at its bound with a zero multiplier) counts as inactive, which gives a
        one-sided derivative at such points.  A QP that is not solved (for instance an ego state
        outside the bounds, or ``y_lb > y_ub``) returns its :class:`solvers.Status` in
        ``status`` (``!= SOLVED``) and NaN derivatives: check ``status`` before using a
        gradient.  No input is validated inside the trace except shapes.

        ``method="ipm"`` (default) needs JAX's x64 mode (``with jax.enable_x64(True):`` around
        the trace and the calls).  A row counts as active for the derivative only when its
        multiplier is above the threshold and it is at its bound, and dependent active rows are
        regularised, so the default tolerance gives finite derivatives; a tighter solve
        (e.g. ``eps_abs=eps_rel=1e-11``) makes them match finite differences more closely where
        rows only approach their bound (a trajectory riding along the lane edge).  ``"admm"`` runs
        in float32 or float64 with an active-set polish (give it enough ``max_iter`` to be
        ``SOLVED``).
        :meth:`jax_projector` (the planner's fixed-budget ADMM projector) is separate and
        unchanged by this.  Per-sample user rows are refused (``ValueError``).
        """
        return _differentiable_projector(self, method, active_tol, settings)

    def distance(
        self, cx: ArrayLike, cy: ArrayLike, cx_bar: ArrayLike, cy_bar: ArrayLike
    ) -> NDArray[np.float64]:
        """(B,) projection objective ``½‖M(c − c̄)‖²`` summed over both axes."""
        H = self.metric_matrix
        dx, dy = np.asarray(cx) - cx_bar, np.asarray(cy) - cy_bar
        return 0.5 * (np.einsum("bi,ij,bj->b", dx, H, dx) + np.einsum("bi,ij,bj->b", dy, H, dy))

    def residuals(
        self,
        cx: ArrayLike,
        cy: ArrayLike,
        state: EgoState | ArrayLike,
        extra_bounds: Any = None,
    ) -> tuple[NDArray[np.float64], dict[str, NDArray[np.float64]]]:
        """Constraint violation of coefficient batches: ``(total (B,), {group: (B,)})``.

        Each group's value is its largest violation (m, m/s or m/s², ≥ 0); ``total`` is the max
        over groups.  The boundary group measures ``|A_eq c − b|``.
        """
        cx, cy = self._coeffs(cx, cy)
        B = cx.shape[0]
        st = state_array(state, B)
        l, u = self.bounds_arrays(st, B, extra_bounds, grid=True)
        Az = np.concatenate([cx, cy], axis=1) @ self._grid_A.T
        if self.per_sample_rows:
            self._sample_rows(Az, cx, cy, grid=True)
        viol = np.maximum(np.maximum(l - Az, Az - u), 0.0)
        groups = {g.name: viol[:, g.rows].max(axis=1, initial=0.0) for g in self._grid_groups}
        total = np.max(np.stack(list(groups.values())), axis=0)
        return total, groups


# ---------------------------------------------------------------------------------- JAX projector
class JaxProjection(NamedTuple):
    """Output of the jittable projector (JAX arrays, leading batch axis B).

    cx, cy : (B, nvar) projected coefficients (the ADMM iterate after the fixed iteration count).
    residual : (B,) total constraint violation (max over groups, as
        :meth:`ProjectionProblem.residuals`).
    groups : {group name: (B,)} max violation per constraint group.
    admm : the :class:`solvers.admm.ADMMState` (``x``, ``y`` warm-start the next call; ``status``).
    """

    cx: Any
    cy: Any
    residual: Any
    groups: dict
    admm: Any


def _equality_correction(Pa: np.ndarray, Aeq: np.ndarray) -> np.ndarray:
    """``P⁻¹A_eqᵀ(A_eq P⁻¹ A_eqᵀ)⁻¹`` (n, r): the P-metric projection onto ``A_eq c = b``."""
    PiAt = np.linalg.solve(Pa, Aeq.T)
    return PiAt @ np.linalg.inv(Aeq @ PiAt)


def _axis_rows(M: np.ndarray, n: int) -> np.ndarray | None:
    """Per row of ``M`` (r, 2n): 0 if it involves only the x coefficients, 1 if only the y
    ones; ``None`` if some row couples both axes."""
    only_x = np.all(M[:, n:] == 0, axis=1)
    only_y = np.all(M[:, :n] == 0, axis=1)
    if np.any(~only_x & ~only_y):
        return None
    return np.where(only_x, 0, 1)


def _projector_settings(problem: ProjectionProblem, num_iters, dtype, settings):
    """Check the projector's arguments; the :class:`solvers.admm.ADMMSettings` it runs with."""
    from solvers.admm import ADMMSettings

    if problem.per_sample_rows:
        raise ValueError(
            "jax_projector needs rows shared by the batch (one factorisation); these user "
            "constraints have per-sample rows – use shared rows with per-sample bounds"
        )
    if not (isinstance(num_iters, (int, np.integer)) and num_iters >= 1):
        raise ValueError(f"num_iters must be a positive integer, got {num_iters!r}")
    if dtype not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    # Start at a large step, rho = 62.5 (the backend's default 0.1 stalls at these budgets),
    # with OSQP's adaptive rule over a ladder extended upwards: measured best for residual and
    # distance at 25-500 iterations (docs/experiments/qp-backends.md).  Dense products: at the
    # planner's shapes (n, m ≲ 100, few iterations) the batched matmul is the fast one.
    base = dict(
        products="dense",
        max_iter=int(num_iters),
        check_every=min(25, int(num_iters)),
        dtype=dtype,
        polish=False,
        rho=62.5,
        adaptive_rho=True,
        rho_ladder=(0.1 / 125, 0.1 / 25, 0.1 / 5, 0.1, 0.5, 2.5, 12.5, 62.5, 312.5),
        eps_abs=1e-5,  # the early stop of a fixed budget: its own, not the backend's default
        eps_rel=1e-5,
    )
    base.update(settings or {})
    return ADMMSettings.from_kwargs(**base)


class _StaticRows(NamedTuple):
    """What the projector knows of the rows before a call (numpy): the bounds at a zero state
    with the user rows unbounded (the boundary and user rows are filled per call), for the rows
    of ``A`` and for the grid rows of the residuals, and ``A``'s equality and free row masks."""

    l0: np.ndarray
    u0: np.ndarray
    lg0: np.ndarray
    ug0: np.ndarray
    eq: np.ndarray
    free: np.ndarray


def _static_rows(problem: ProjectionProblem) -> _StaticRows:
    unbounded = [(-np.inf, np.inf)] * len(problem.extra)
    l0, u0 = problem.bounds_arrays(np.zeros((1, 6)), 1, unbounded)
    lg0, ug0 = problem.bounds_arrays(np.zeros((1, 6)), 1, unbounded, grid=True)
    l0, u0, lg0, ug0 = l0[0], u0[0], lg0[0], ug0[0]
    eq = np.zeros(problem.num_rows, bool)
    eq[problem.group_slices()["boundary"]] = True
    free = ~eq & np.isinf(l0) & np.isinf(u0)
    for g in problem._extra_groups:  # extra rows get their bounds per call: never "free"
        free[g.rows] = False
    return _StaticRows(l0, u0, lg0, ug0, eq, free)


# -- traced pieces shared by both projectors
def _boundary_values(st, final_lat: bool, dt):
    """``(b_x, b_y, b_eq)``: the right-hand sides of the boundary rows from states ``st``."""
    import jax.numpy as jnp

    bx = st[:, jnp.array([0, 2, 4])]
    by = st[:, jnp.array([1, 3, 5])]
    if final_lat:
        by = jnp.concatenate([by, jnp.zeros((st.shape[0], 1), dt)], axis=1)
    return bx, by, jnp.concatenate([bx, by], axis=1)


def _axis_linear_term(c_bar, Hj, rho, b, Ae, dt):
    """``c̄ H + ρ bᵀA_eq`` for one axis: minus its block of the QP's ``q``."""
    import jax.numpy as jnp

    return c_bar @ Hj + rho * b @ jnp.asarray(Ae, dt)


def _run_admm(factor, q, l, u, x0, y0, iters: int):
    import jax
    import jax.numpy as jnp

    from solvers.admm import admm_projector

    fj = jax.tree_util.tree_map(jnp.asarray, factor)  # constants of the traced function
    project: solvers.JaxProjector = admm_projector(fj, iters)
    return project(q, l, u, x0=x0, y0=y0)


def _correct_equalities(z, Ae, b, M, dt):
    """The exact correction onto the boundary equalities ``A_eq c = b`` of one axis, in the
    projection's metric: ``c ← c − M (A_eq c − b)``, ``M = P⁻¹A_eqᵀ(A_eq P⁻¹ A_eqᵀ)⁻¹``.  A fixed
    ADMM budget leaves them satisfied only to ~1e-4; after this every trajectory starts at the
    ego state to float precision (the inequality residual is measured afterwards)."""
    import jax.numpy as jnp

    return z - (z @ jnp.asarray(Ae.T, dt) - b) @ jnp.asarray(M.T, dt)


def _violation(Az, lg, ug):
    import jax.numpy as jnp

    return jnp.maximum(jnp.maximum(lg - Az, Az - ug), 0.0)


def _jax_projector(
    problem: ProjectionProblem, num_iters: int, dtype: str, settings, split_axes=None
):
    try:
        from solvers.admm import admm_factor, admm_projector  # noqa: F401
    except ImportError as exc:  # pragma: no cover - depends on the solvers package state
        raise ImportError(
            "ProjectionProblem.jax_projector needs solvers.admm.admm_factor/admm_projector"
        ) from exc

    s = _projector_settings(problem, num_iters, dtype, settings)
    if split_axes not in (None, True, False):
        raise ValueError(f"split_axes must be None, True or False, got {split_axes!r}")
    if split_axes is not False:
        axes = _axis_rows(problem.A, problem.nvar)
        grid_axes = _axis_rows(problem._grid_A, problem.nvar)
        can = axes is not None and grid_axes is not None and not problem.extra
        if split_axes and not can:
            raise ValueError(
                "split_axes=True needs every constraint row to involve one axis only and no "
                "user constraints"
            )
        if can:
            return _split_projector(problem, s, axes, grid_axes)
    return _joint_projector(problem, s)


def _joint_bounds(problem: ProjectionProblem, rows: _StaticRows, beq, extra_bounds, B: int, dt):
    """Per-sample ``(l, u)`` of the rows of ``A`` and ``(l_g, u_g)`` of the grid rows: the
    static bounds with the boundary rows set to ``b_eq`` and the user rows to their bounds."""
    import jax.numpy as jnp

    m = problem.num_rows
    bslice = problem.group_slices()["boundary"]
    extra_slices = [g.rows for g in problem._extra_groups]
    grid_extra = [g.rows for g in problem._grid_groups if g.lower is None and g.name != "boundary"]
    gboundary = {g.name: g.rows for g in problem._grid_groups}["boundary"]
    l = jnp.broadcast_to(jnp.asarray(rows.l0, dt), (B, m))
    u = jnp.broadcast_to(jnp.asarray(rows.u0, dt), (B, m))
    l = l.at[:, bslice].set(beq)
    u = u.at[:, bslice].set(beq)
    eb = [(e.lower, e.upper) for e in problem.extra] if extra_bounds is None else extra_bounds
    if len(eb) != len(extra_slices):
        raise ValueError(f"extra_bounds needs {len(extra_slices)} (lower, upper) pairs")
    for sl, (lo, hi) in zip(extra_slices, eb, strict=True):
        r = sl.stop - sl.start
        l = l.at[:, sl].set(jnp.broadcast_to(jnp.asarray(lo, dt), (B, r)))
        u = u.at[:, sl].set(jnp.broadcast_to(jnp.asarray(hi, dt), (B, r)))
    lg = jnp.broadcast_to(jnp.asarray(rows.lg0, dt), (B, rows.lg0.shape[0]))
    ug = jnp.broadcast_to(jnp.asarray(rows.ug0, dt), (B, rows.ug0.shape[0]))
    lg = lg.at[:, gboundary].set(beq)
    ug = ug.at[:, gboundary].set(beq)
    for sl, gsl in zip(extra_slices, grid_extra, strict=True):
        lg = lg.at[:, gsl].set(l[:, sl])
        ug = ug.at[:, gsl].set(u[:, sl])
    return l, u, lg, ug


def _joint_projector(problem: ProjectionProblem, s):
    """The projection as one QP in ``(c_x, c_y)`` (see :meth:`ProjectionProblem.jax_projector`)."""
    import jax.numpy as jnp

    from solvers.admm import admm_factor

    n = problem.nvar
    rows = _static_rows(problem)
    factor = admm_factor(problem.P, problem.A, s, eq_rows=rows.eq, free_rows=rows.free)
    H = problem.metric_matrix
    Aex, Aey = problem._Aex, problem._Aey
    rho = problem._rho_eq
    A_grid = problem._grid_A
    groups = [(g.name, g.rows) for g in problem._grid_groups]
    final_lat = problem.final_lateral_velocity
    dtype, iters = s.dtype, s.max_iter
    Mex = _equality_correction(problem.P[:n, :n], Aex)
    Mey = _equality_correction(problem.P[n:, n:], Aey)

    def project(cx_bar, cy_bar, state, extra_bounds=None, warm_start=None) -> JaxProjection:
        dt = jnp.dtype(dtype)
        cx_bar = jnp.asarray(cx_bar, dt)
        cy_bar = jnp.asarray(cy_bar, dt)
        B = cx_bar.shape[0]
        st = jnp.broadcast_to(jnp.atleast_2d(jnp.asarray(state, dt)), (B, 6))
        bx, by, beq = _boundary_values(st, final_lat, dt)
        Hj = jnp.asarray(H, dt)
        q = -jnp.concatenate(
            [
                _axis_linear_term(cx_bar, Hj, rho, bx, Aex, dt),
                _axis_linear_term(cy_bar, Hj, rho, by, Aey, dt),
            ],
            axis=1,
        )
        l, u, lg, ug = _joint_bounds(problem, rows, beq, extra_bounds, B, dt)
        x0 = y0 = None
        if warm_start is not None:
            x0, y0 = warm_start.x, warm_start.y
        out = _run_admm(factor, q, l, u, x0, y0, iters)
        zx = _correct_equalities(out.x[:, :n], Aex, bx, Mex, dt)
        zy = _correct_equalities(out.x[:, n:], Aey, by, Mey, dt)
        z = jnp.concatenate([zx, zy], axis=1)
        viol = _violation(z @ jnp.asarray(A_grid, dt).T, lg, ug)
        grp = {name: jnp.max(viol[:, sl], axis=1, initial=0.0) for name, sl in groups}
        total = jnp.max(jnp.stack(list(grp.values())), axis=0)
        return JaxProjection(z[:, :n], z[:, n:], total, grp, out)

    return project


def _ix(a):
    """Index arrays as int32 whatever JAX's x64 mode (mixed widths fail to trace)."""
    import jax.numpy as jnp

    return jnp.asarray(a, jnp.int32)


class _AxisPart(NamedTuple):
    """One axis' QP of the split projector (numpy)."""

    rows: np.ndarray  # its rows among the rows of A
    factor: Any  # its ADMMFactor
    Ae: np.ndarray  # its boundary rows A_eq
    M: np.ndarray  # the equality correction of :func:`_correct_equalities`
    l0: np.ndarray  # static bounds of its rows
    u0: np.ndarray
    b_pos: np.ndarray  # its boundary rows: positions among its rows ...
    b_col: np.ndarray  # ... and columns of b_eq = [b_x, b_y]
    G: np.ndarray  # its grid rows (residuals)
    lg0: np.ndarray
    ug0: np.ndarray
    gb_pos: np.ndarray  # boundary grid rows: positions among its grid rows, columns of b_eq
    gb_col: np.ndarray
    groups: dict  # {group name: positions among its grid rows}


def _axis_part(problem: ProjectionProblem, s, a: int, axes, grid_axes, static: _StaticRows):
    from solvers.admm import admm_factor

    n = problem.nvar
    Ae = (problem._Aex, problem._Aey)[a]
    Pa = problem.P[:n, :n] if a == 0 else problem.P[n:, n:]
    bsl = problem.group_slices()["boundary"]
    gsl = {g.name: g.rows for g in problem._grid_groups}
    rows = np.flatnonzero(axes == a)
    grows = np.flatnonzero(grid_axes == a)
    cols = slice(a * n, (a + 1) * n)

    def positions(idx, sl):
        return [i for i, r in enumerate(idx) if sl.start <= r < sl.stop]

    b_pos = positions(rows, bsl)
    gb_pos = positions(grows, gsl["boundary"])
    groups = {}
    for name, sl in gsl.items():
        pos = positions(grows, sl)
        if pos:
            groups[name] = np.asarray(pos)
    eq, free = static.eq[rows], static.free[rows]
    return _AxisPart(
        rows=rows,
        factor=admm_factor(Pa, problem.A[rows][:, cols], s, eq_rows=eq, free_rows=free),
        Ae=Ae,
        M=_equality_correction(Pa, Ae),
        l0=static.l0[rows],
        u0=static.u0[rows],
        b_pos=np.asarray(b_pos, int),
        b_col=np.asarray([int(r - bsl.start) for r in rows[b_pos]], int),
        G=problem._grid_A[grows][:, cols],
        lg0=static.lg0[grows],
        ug0=static.ug0[grows],
        gb_pos=np.asarray(gb_pos, int),
        gb_col=np.asarray([int(r - gsl["boundary"].start) for r in grows[gb_pos]], int),
        groups=groups,
    )


def _with_boundary(v0, pos, col, beq, Bs: int, dt):
    """Static bounds ``v0`` as ``(Bs, ·)`` with the boundary entries ``pos`` set to ``b_eq``."""
    import jax.numpy as jnp

    v = jnp.broadcast_to(jnp.asarray(v0, dt), (Bs, v0.shape[0]))
    return v.at[:, _ix(pos)].set(beq[:, _ix(col)])


def _merge_axis_states(ox, oy, inv):
    """The two axes' ADMM states as one, in the joint row order (``inv``: joint row ``r`` is
    entry ``inv[r]`` of ``[x rows; y rows]``)."""
    import jax.numpy as jnp

    from solvers.admm import ADMMState

    def joint(fx, fy):  # per-row arrays in the joint row order
        return jnp.concatenate([fx, fy], axis=1)[:, _ix(inv)]

    status = jnp.where(ox.status == solvers.STATUS_CODES.SOLVED, oy.status, ox.status)
    return ADMMState(
        x=jnp.concatenate([ox.x, oy.x], axis=1),
        z=joint(ox.z, oy.z),
        y=joint(ox.y, oy.y),
        prim_res=jnp.maximum(ox.prim_res, oy.prim_res),
        dual_res=jnp.maximum(ox.dual_res, oy.dual_res),
        status=status,
        iterations=jnp.maximum(ox.iterations, oy.iterations),
        rho=jnp.maximum(ox.rho, oy.rho),
        delta_x=jnp.concatenate([ox.delta_x, oy.delta_x], axis=1),
        delta_y=joint(ox.delta_y, oy.delta_y),
        rung_matmuls=ox.rung_matmuls + oy.rung_matmuls,
    )


def _split_projector(problem: ProjectionProblem, s, axes: np.ndarray, grid_axes: np.ndarray):
    """The projection as two independent QPs, one per axis (``P`` block diagonal, every row of
    ``A`` on one axis): the same optimum as the joint problem, half the work per ADMM
    iteration.  Bounds that every sample shares stay (1, m) (broadcast, not materialised)."""
    import jax.numpy as jnp

    n = problem.nvar
    static = _static_rows(problem)
    H = problem.metric_matrix
    rho_eq = problem._rho_eq
    final_lat = problem.final_lateral_velocity
    dtype = s.dtype
    parts = [_axis_part(problem, s, a, axes, grid_axes, static) for a in (0, 1)]
    inv = np.argsort(np.concatenate([parts[0].rows, parts[1].rows]))
    group_names = [g.name for g in problem._grid_groups]

    def project_axis(a, p: _AxisPart, c_bar, b, beq, Hj, warm_start, dt):
        """One axis: ADMM, the equality correction, the grid rows' violations."""
        Bs = beq.shape[0]
        q = -_axis_linear_term(c_bar, Hj, rho_eq, b, p.Ae, dt)
        l = _with_boundary(p.l0, p.b_pos, p.b_col, beq, Bs, dt)
        u = _with_boundary(p.u0, p.b_pos, p.b_col, beq, Bs, dt)
        x0 = y0 = None
        if warm_start is not None:
            x0 = warm_start.x[:, a * n : (a + 1) * n]
            y0 = warm_start.y[:, _ix(p.rows)]
        out = _run_admm(p.factor, q, l, u, x0, y0, s.max_iter)
        z = _correct_equalities(out.x, p.Ae, b, p.M, dt)
        Az = z @ jnp.asarray(p.G, dt).T
        lg = _with_boundary(p.lg0, p.gb_pos, p.gb_col, beq, Bs, dt)
        ug = _with_boundary(p.ug0, p.gb_pos, p.gb_col, beq, Bs, dt)
        return out, z, _violation(Az, lg, ug)

    def project(cx_bar, cy_bar, state, extra_bounds=None, warm_start=None) -> JaxProjection:
        dt = jnp.dtype(dtype)
        if extra_bounds:
            raise ValueError("this projection has no user constraints: extra_bounds must be None")
        cb = (jnp.asarray(cx_bar, dt), jnp.asarray(cy_bar, dt))
        B = cb[0].shape[0]
        st = jnp.atleast_2d(jnp.asarray(state, dt))  # (1, 6) shared or (B, 6)
        bx, by, beq = _boundary_values(st, final_lat, dt)
        Hj = jnp.asarray(H, dt)
        outs, zs, viols = [], [], []
        for a, (p, b) in enumerate(zip(parts, (bx, by), strict=True)):
            out, z, viol = project_axis(a, p, cb[a], b, beq, Hj, warm_start, dt)
            outs.append(out)
            zs.append(z)
            viols.append(viol)
        grp = {}
        for name in group_names:
            vs = [
                jnp.max(v[:, _ix(p.groups[name])], axis=1)
                for p, v in zip(parts, viols, strict=True)
                if name in p.groups
            ]
            grp[name] = vs[0] if len(vs) == 1 else jnp.maximum(vs[0], vs[1])
        total = jnp.maximum(jnp.max(viols[0], axis=1), jnp.max(viols[1], axis=1))
        total = jnp.broadcast_to(total, (B,))
        return JaxProjection(zs[0], zs[1], total, grp, _merge_axis_states(*outs, inv))

    return project


# ---------------------------------------------------------------------- differentiable projector
class DiffProjection(NamedTuple):
    """Output of :meth:`ProjectionProblem.differentiable_projector` (JAX arrays).

    cx, cy : ``(nvar,)`` or ``(B, nvar)`` projected coefficients.
    status : ``()`` or ``(B,)`` int32 :class:`solvers.Status` codes (``SOLVED == 1``); the
        derivatives of a sample that is not solved are NaN.
    """

    cx: Any
    cy: Any
    status: Any


_DIFF_BOUNDS = ("y_lb", "y_ub", "vx_min", "vx_max", "vy_max", "ax_max", "ay_max", "a_max")


def _check_diff_args(problem, allowed, K, r_w, cx_bar, state, bounds, weights, extra_bounds, dt):
    """The checked ``bounds``, ``weights`` and ``extra_bounds`` of a differentiable projection
    (``ValueError`` naming the argument)."""
    import jax.numpy as jnp

    batched = cx_bar.ndim == 2
    if state.shape != (6,) and not (batched and state.shape == (cx_bar.shape[0], 6)):
        raise ValueError(f"state must have shape (6,) or (B, 6), got {state.shape}")
    bounds = dict(bounds or {})
    for key, v in bounds.items():
        if key not in allowed:
            raise ValueError(f"bounds has an unknown key {key!r}; known: {allowed}")
        if np.shape(v) not in ((), (K,)):
            raise ValueError(f"bounds[{key!r}] must be a scalar or ({K},), got {np.shape(v)}")
    if weights is None:
        weights = jnp.ones((), dt)
    if np.shape(weights) not in ((), (r_w,), (2, r_w)):
        raise ValueError(
            f"weights must be a scalar, ({r_w},) or (2, {r_w}), got {np.shape(weights)}"
        )
    if extra_bounds is None:
        extra_bounds = [(e.lower, e.upper) for e in problem.extra]
    if len(extra_bounds) != len(problem.extra):
        raise ValueError(
            f"extra_bounds needs one (lower, upper) pair per user constraint set "
            f"({len(problem.extra)}), got {len(extra_bounds)}"
        )
    for e, pair in zip(problem.extra, extra_bounds, strict=True):
        for v in pair:
            if np.shape(v) not in ((), (e.num_rows,)):
                raise ValueError(
                    f"extra_bounds for {e.name!r} must be scalars or ({e.num_rows},), "
                    f"got {np.shape(v)}"
                )
    return bounds, weights, extra_bounds


def _diff_rows(problem, Mp, Mv, Ma, sides: int) -> np.ndarray:
    """The constraint matrix of the differentiable projection: boundary equalities, lane,
    speed, lateral velocity, accelerations, the acceleration polygon (``sides`` > 0) and the
    user rows (every kinematic row kept, infinite bounds making it inactive)."""
    Aex, Aey = problem._Aex, problem._Aey

    def xs(M):
        return np.hstack([M, np.zeros_like(M)])

    def ys(M):
        return np.hstack([np.zeros_like(M), M])

    blocks = [
        np.block([[Aex, np.zeros_like(Aex)], [np.zeros_like(Aey), Aey]]),
        ys(Mp),  # lane
        xs(Mv),  # speed
        ys(Mv),  # lateral velocity
        xs(Ma),  # accel_x
        ys(Ma),  # accel_y
    ]
    if sides:
        phi = 2 * np.pi * np.arange(sides) / sides
        blocks.append(np.concatenate([np.hstack([np.cos(p) * Ma, np.sin(p) * Ma]) for p in phi]))
    extra_rows = [problem.A[g.rows] for g in problem._extra_groups]
    A = np.vstack(blocks + extra_rows)
    A.setflags(write=False)
    return A


def _differentiable_projector(problem: ProjectionProblem, method: str, active_tol, settings):
    import jax
    import jax.numpy as jnp

    from solvers.jax import METHODS, solve_qp

    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if problem.per_sample_rows:
        raise ValueError(
            "differentiable_projector needs rows shared by the batch; these user constraints "
            "have per-sample rows"
        )
    basis = problem.basis
    K, n = basis.num_steps, problem.nvar
    if problem.constraint_points == "grid":
        Mp, Mv, Ma = basis.P, basis.Pdot, basis.Pddot
    else:
        Mp, Mv, Ma = basis.control_point_maps()
    Mobj = basis.P if problem.metric == "waypoint" else np.eye(n)
    r_w = Mobj.shape[0]
    Aex, Aey = problem._Aex, problem._Aey
    rho = problem._rho_eq
    final_lat = problem.final_lateral_velocity
    polygon = problem.bounds.a_max is not None
    sides = int(problem.bounds.accel_polygon_sides)
    defaults = dict(problem._bounds_k)
    hull = problem.constraint_points == "hull"

    A = _diff_rows(problem, Mp, Mv, Ma, sides if polygon else 0)
    allowed = _DIFF_BOUNDS if polygon else _DIFF_BOUNDS[:-1]

    def one(cx_bar, cy_bar, state, bounds, weights, extra_bounds):
        dt = cx_bar.dtype
        b = dict(defaults)
        b.update(bounds)

        def bound(key, rows):
            v = jnp.broadcast_to(jnp.asarray(b[key], dt), (K,))
            if hull:  # the tightest value over the horizon, on every control point
                v = jnp.max(v) if key in ("y_lb", "vx_min") else jnp.min(v)
            return jnp.broadcast_to(v, (rows,))

        rp, rv, ra = Mp.shape[0], Mv.shape[0], Ma.shape[0]
        lo = [bound("y_lb", rp), bound("vx_min", rv), -bound("vy_max", rv)]
        hi = [bound("y_ub", rp), bound("vx_max", rv), bound("vy_max", rv)]
        lo += [-bound("ax_max", ra), -bound("ay_max", ra)]
        hi += [bound("ax_max", ra), bound("ay_max", ra)]
        if polygon:
            lo.append(jnp.full(ra * sides, -jnp.inf, dt))
            hi.append(jnp.tile(bound("a_max", ra) * np.cos(np.pi / sides), sides))
        for e, (el, eu) in zip(problem.extra, extra_bounds, strict=True):
            lo.append(jnp.broadcast_to(jnp.asarray(el, dt), (e.num_rows,)))
            hi.append(jnp.broadcast_to(jnp.asarray(eu, dt), (e.num_rows,)))
        st = jnp.asarray(state, dt)
        bx = st[jnp.array([0, 2, 4])]
        by = st[jnp.array([1, 3, 5])]
        if final_lat:
            by = jnp.concatenate([by, jnp.zeros(1, dt)])
        beq = jnp.concatenate([bx, by])
        l = jnp.concatenate([beq] + lo)
        u = jnp.concatenate([beq] + hi)
        w = jnp.broadcast_to(jnp.asarray(weights, dt), (2, r_w))
        Mj = jnp.asarray(Mobj, dt)
        Hx = Mj.T @ (w[0][:, None] * Mj)
        Hy = Mj.T @ (w[1][:, None] * Mj)
        Aexj, Aeyj = jnp.asarray(Aex, dt), jnp.asarray(Aey, dt)
        Z = jnp.zeros((n, n), dt)
        P = jnp.block([[Hx + rho * Aexj.T @ Aexj, Z], [Z, Hy + rho * Aeyj.T @ Aeyj]])
        q = -jnp.concatenate([Hx @ cx_bar + rho * Aexj.T @ bx, Hy @ cy_bar + rho * Aeyj.T @ by])
        sol = solve_qp(
            P, q, jnp.asarray(A, dt), l, u, method=method, active_tol=active_tol, **settings
        )
        return DiffProjection(sol.x[:n], sol.x[n:], sol.status)

    def project(
        cx_bar, cy_bar, state, bounds=None, weights=None, extra_bounds=None
    ) -> DiffProjection:
        dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
        cx_bar, cy_bar = jnp.asarray(cx_bar, dt), jnp.asarray(cy_bar, dt)
        if cx_bar.shape != cy_bar.shape or cx_bar.ndim not in (1, 2) or cx_bar.shape[-1] != n:
            raise ValueError(
                f"cx_bar and cy_bar must both have shape ({n},) or (B, {n}), "
                f"got {cx_bar.shape} and {cy_bar.shape}"
            )
        from .planner import EgoState

        state = jnp.asarray(state.as_array() if isinstance(state, EgoState) else state, dt)
        batched = cx_bar.ndim == 2
        bounds, weights, extra_bounds = _check_diff_args(
            problem, allowed, K, r_w, cx_bar, state, bounds, weights, extra_bounds, dt
        )
        extra_bounds = [tuple(pair) for pair in extra_bounds]
        if not batched:
            return one(cx_bar, cy_bar, state, bounds, weights, extra_bounds)
        st_axis = 0 if state.ndim == 2 else None
        return jax.vmap(one, in_axes=(0, 0, st_axis, None, None, None))(
            cx_bar, cy_bar, state, bounds, weights, extra_bounds
        )

    return project
