"""Projection QP (Algorithm 1, line 8): the nearest feasible trajectory to each planner sample.

For every sample ``(c̄_x, c̄_y)`` (coefficients of a :mod:`frenet.basis` basis, Frenet frame)::

    min  ½‖M(c_x − c̄_x)‖² + ½‖M(c_y − c̄_y)‖²
    s.t. A_eq,x c_x = (s₀, v_s0, a_s0),  A_eq,y c_y = (d₀, v_d0, a_d0[, 0])          boundary
         y_lb ≤ y_k ≤ y_ub                                                           lane
         vx_min ≤ ẋ_k ≤ vx_max                                                       speed
         |ẏ_k| ≤ vy_max                                                              lateral_velocity
         |ẍ_k| ≤ ax_max,  |ÿ_k| ≤ ay_max                                             accel_x, accel_y
         cos φ_i ẍ_k + sin φ_i ÿ_k ≤ a_max cos(π/m),  φ_i = 2πi/m                   accel_norm (optional)
         lower ≤ G_x q_x + G_y q_y ≤ upper                                           user rows (extra)

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

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import solvers

from .basis import Basis
from .planner import state_array

__all__ = ["ProjectionBounds", "LinearConstraints", "ProjectionProblem", "ProjectionResult"]

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
    """Kinematic and lane bounds (Frenet frame, SI units).  Defaults: the reference code (SPEC §d).

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
        """All bounds as ``(K,)`` arrays, validated (NaN, negative magnitudes and ``lower > upper`` raise)."""
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
    so ``G_x, G_y`` are ``(r, K)`` weights on the K samples of each axis (shared by the batch).
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
        if Gx.ndim != 2 or Gx.shape != Gy.shape:
            raise ValueError(
                f"Gx and Gy must be 2-D with equal shapes (r, K), got {Gx.shape}, {Gy.shape}"
            )
        if not (np.all(np.isfinite(Gx)) and np.all(np.isfinite(Gy))):
            raise ValueError("Gx/Gy contain NaN or inf")
        if self.quantity not in _QUANTITY:
            raise ValueError(f"quantity must be one of {sorted(_QUANTITY)}, got {self.quantity!r}")
        r = Gx.shape[0]
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
        return self.Gx.shape[0]

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
        return self.status == int(solvers.Status.SOLVED)


@dataclass(frozen=True, eq=False)
class _Group:
    name: str
    rows: slice
    # static bounds (r,), or None when filled per sample
    lower: np.ndarray | None
    upper: np.ndarray | None


class ProjectionProblem:
    """The projection QP for one basis, set of bounds and optional user constraints.

    Parameters
    ----------
    basis : frenet.basis.Basis
    bounds : ProjectionBounds
    extra : LinearConstraints or a sequence of them, optional
    metric : "waypoint" (default; distance of the position samples, paper) or "coefficient"
    final_lateral_velocity : impose ``ẏ_{K−1} = 0`` (reference: yes).

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
    ):
        self.basis = basis
        self.bounds = bounds if bounds is not None else ProjectionBounds()
        if extra is None:
            extra = ()
        elif isinstance(extra, LinearConstraints):
            extra = (extra,)
        self.extra = tuple(extra)
        for e in self.extra:
            if not isinstance(e, LinearConstraints):
                raise TypeError(f"extra must hold LinearConstraints, got {type(e).__name__}")
        if metric not in ("waypoint", "coefficient"):
            raise ValueError(f"metric must be 'waypoint' or 'coefficient', got {metric!r}")
        self.metric = metric
        self.final_lateral_velocity = bool(final_lateral_velocity)
        K, n = basis.num_steps, basis.nvar
        self.nvar = n
        b = self.bounds.per_step(K)
        Z = np.zeros((K, n))
        blocks: list[np.ndarray] = []
        groups: list[_Group] = []

        def add(name, M, lo, hi):
            lo = (
                np.broadcast_to(np.asarray(lo, dtype=np.float64), (M.shape[0],))
                if lo is not None
                else None
            )
            hi = (
                np.broadcast_to(np.asarray(hi, dtype=np.float64), (M.shape[0],))
                if hi is not None
                else None
            )
            if lo is not None and hi is not None:
                keep = np.isfinite(lo) | np.isfinite(hi)
                if not np.any(keep):
                    return
                M, lo, hi = M[keep], lo[keep], hi[keep]
            start = sum(x.shape[0] for x in blocks)
            blocks.append(M)
            groups.append(_Group(name, slice(start, start + M.shape[0]), lo, hi))

        Aex, Aey = basis.boundary_rows(self.final_lateral_velocity)
        add(
            "boundary", np.block([[Aex, np.zeros_like(Aex)], [np.zeros_like(Aey), Aey]]), None, None
        )
        add("lane", np.hstack([Z, basis.P]), b["y_lb"], b["y_ub"])
        add("speed", np.hstack([basis.Pdot, Z]), b["vx_min"], b["vx_max"])
        add("lateral_velocity", np.hstack([Z, basis.Pdot]), -b["vy_max"], b["vy_max"])
        add("accel_x", np.hstack([basis.Pddot, Z]), -b["ax_max"], b["ax_max"])
        add("accel_y", np.hstack([Z, basis.Pddot]), -b["ay_max"], b["ay_max"])
        if "a_max" in b:
            m = int(self.bounds.accel_polygon_sides)
            phi = 2 * np.pi * np.arange(m) / m
            rows = np.concatenate(
                [np.hstack([np.cos(p) * basis.Pddot, np.sin(p) * basis.Pddot]) for p in phi]
            )
            add("accel_norm", rows, -np.inf, np.tile(b["a_max"] * np.cos(np.pi / m), m))
        names = {g.name for g in groups}
        for e in self.extra:
            if e.Gx.shape[1] != K:
                raise ValueError(
                    f"LinearConstraints {e.name!r} has {e.Gx.shape[1]} columns, the grid has K={K} steps"
                )
            name = e.name
            i = 1
            while name in names:
                i += 1
                name = f"{e.name}_{i}"
            names.add(name)
            M = getattr(basis, _QUANTITY[e.quantity])
            start = sum(x.shape[0] for x in blocks)
            blocks.append(np.hstack([e.Gx @ M, e.Gy @ M]))
            groups.append(_Group(name, slice(start, start + e.num_rows), None, None))
        self.A = np.vstack(blocks)
        self.groups = tuple(groups)
        self._extra_groups = tuple(g for g in groups if g.lower is None and g.name != "boundary")
        Mx = basis.P if metric == "waypoint" else np.eye(n)
        H = Mx.T @ Mx
        self.metric_matrix = H  # per axis
        # Exact penalty ½ρ‖A_eq c − b‖² (zero on the feasible set: same optimum, same distance)
        # makes the Hessian positive definite (PᵀP is singular for the triple integrator).
        self._rho_eq = float(np.trace(H)) / n
        self._Aex, self._Aey = Aex, Aey
        self.P = np.block(
            [
                [H + self._rho_eq * Aex.T @ Aex, np.zeros((n, n))],
                [np.zeros((n, n)), H + self._rho_eq * Aey.T @ Aey],
            ]
        )
        self._bounds_k = b
        for M in (self.A, self.P):
            M.setflags(write=False)

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
                f"coefficients must have shape (B, {n}) for this basis, got {cx.shape} and {cy.shape}"
            )
        if not (np.all(np.isfinite(cx)) and np.all(np.isfinite(cy))):
            raise ValueError("coefficients contain NaN or inf")
        return cx, cy

    def _extra_bounds(self, B: int, extra_bounds) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per-sample ``(lower, upper)`` (B, r) for every extra group (``extra_bounds`` overrides)."""
        if extra_bounds is not None:
            if len(extra_bounds) != len(self.extra):
                raise ValueError(
                    f"extra_bounds needs one (lower, upper) per extra constraint set "
                    f"({len(self.extra)}), got {len(extra_bounds)}"
                )
        out = []
        for i, e in enumerate(self.extra):
            lo, hi = (e.lower, e.upper) if extra_bounds is None else extra_bounds[i]
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
            out.append((res[0], res[1]))
        return out

    def check_state(self, state) -> np.ndarray:
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

    def bounds_arrays(self, state, batch: int, extra_bounds=None) -> tuple[np.ndarray, np.ndarray]:
        """Per-sample ``(l, u)`` of shape ``(B, m)`` for the rows of :attr:`A`."""
        st = state_array(state, batch)
        l = np.empty((batch, self.num_rows))
        u = np.empty((batch, self.num_rows))
        beq = np.concatenate([st[:, [0, 2, 4]], st[:, [1, 3, 5]]], axis=1)
        if self.final_lateral_velocity:
            beq = np.concatenate([beq, np.zeros((batch, 1))], axis=1)
        ex = iter(self._extra_bounds(batch, extra_bounds))
        for g in self.groups:
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
    def batch(self, cx_bar, cy_bar, state, extra_bounds=None) -> solvers.QPBatch:
        """The projection of every sample as one :class:`solvers.QPBatch` (shared ``P``, ``A``).

        ``state`` is an :class:`~frenet.planner.EgoState`, ``(6,)`` or ``(B, 6)``; ``extra_bounds``
        optionally overrides the user constraints' bounds: one ``(lower, upper)`` pair per
        :class:`LinearConstraints`, each ``(r,)`` or ``(B, r)``.
        """
        cx, cy = self._coeffs(cx_bar, cy_bar)
        B = cx.shape[0]
        st = self.check_state(state)
        if st.shape[0] not in (1, B):
            raise ValueError(f"state has batch size {st.shape[0]}, expected 1 or {B}")
        q = self.linear_term(cx, cy, st)
        l, u = self.bounds_arrays(st, B, extra_bounds)
        return solvers.QPBatch(self.P, self.A, q, l, u)

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
        cx_bar,
        cy_bar,
        state,
        backend: str | None = None,
        *,
        extra_bounds=None,
        warm_start=None,
        **settings,
    ) -> ProjectionResult:
        """Project a batch of samples with a :mod:`solvers` backend.

        ``backend`` defaults to ``"admm"`` when available, else ``"clarabel"``; ``settings`` go to
        the native solver.  Returns a :class:`ProjectionResult` (residuals recomputed from the
        returned coefficients, status from the backend).
        """
        if backend is None:
            backend = "admm" if "admm" in solvers.available_backends() else "clarabel"
        batch = self.batch(cx_bar, cy_bar, state, extra_bounds)
        sol = solvers.solve_batch(batch, backend=backend, warm_start=warm_start, **settings)
        n = self.nvar
        x = np.asarray(sol.x, dtype=np.float64)
        finite = np.all(np.isfinite(x), axis=1)
        status = np.asarray(sol.status).copy()
        status[~finite] = int(solvers.Status.ERROR)
        cx_bar, cy_bar = self._coeffs(cx_bar, cy_bar)
        cx = np.where(finite[:, None], x[:, :n], cx_bar)
        cy = np.where(finite[:, None], x[:, n:], cy_bar)
        total, groups = self.residuals(cx, cy, state, extra_bounds)
        total = np.where(finite, total, np.inf)
        return ProjectionResult(
            cx, cy, total, groups, status, self.distance(cx, cy, cx_bar, cy_bar), sol
        )

    def distance(self, cx, cy, cx_bar, cy_bar) -> np.ndarray:
        """(B,) projection objective ``½‖M(c − c̄)‖²`` summed over both axes."""
        H = self.metric_matrix
        dx, dy = np.asarray(cx) - cx_bar, np.asarray(cy) - cy_bar
        return 0.5 * (np.einsum("bi,ij,bj->b", dx, H, dx) + np.einsum("bi,ij,bj->b", dy, H, dy))

    def residuals(
        self, cx, cy, state, extra_bounds=None
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Constraint violation of coefficient batches: ``(total (B,), {group: (B,)})``.

        Each group's value is its largest violation (m, m/s or m/s², ≥ 0); ``total`` is the max
        over groups.  The boundary group measures ``|A_eq c − b|``.
        """
        cx, cy = self._coeffs(cx, cy)
        B = cx.shape[0]
        st = state_array(state, B)
        l, u = self.bounds_arrays(st, B, extra_bounds)
        Az = np.concatenate([cx, cy], axis=1) @ self.A.T
        viol = np.maximum(np.maximum(l - Az, Az - u), 0.0)
        groups = {g.name: viol[:, g.rows].max(axis=1, initial=0.0) for g in self.groups}
        total = np.max(np.stack(list(groups.values())), axis=0)
        return total, groups
