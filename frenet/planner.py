"""Behavioural (Frenet) planner: behavioural input ``d`` → trajectory (paper Appendix).

Behavioural input, for ``S = num_segments`` segments of the horizon (reference: 4 × 25 steps)::

    d = (v_d¹, …, v_d^S, y_d¹, …, y_d^S)          speed set-points (m/s), lateral offsets (m)

Per axis (``c_x``: longitudinal ``s``, ``c_y``: lateral ``d``), equality-constrained least squares::

    min_c  ½ w_s cᵀSc + ½ w_v Σ_k (ẍ_k − σ k_v (ẋ_k − v_d^{seg(k)}))²          (x)
           ½ w_s cᵀSc + ½ w_o Σ_k (ÿ_k − σ k_p (y_k − y_d^{seg(k)}) + σ k_d ẏ_k)²   (y)
    s.t.   (x₀, ẋ₀, ẍ₀) = (s, v_s, a_s),   (y₀, ẏ₀, ÿ₀, ẏ_{K−1}) = (d, v_d, a_d, 0)

with ``S`` the basis' smoothness (sum of squared jerk over the grid, :mod:`frenet.basis`).
Defaults reproduce the reference code: ``k_p = k_v = 2``, ``k_d = 0`` (no lateral damping),
all weights 1, ``σ = +1`` (the paper's and the code's sign, ``ẍ − k(ẋ − v_d)``; ``σ = −1`` gives
the stable feedback law ``ẍ = −k(ẋ − v_d)``; see ``PlannerConfig.feedback_sign``).

The optimum is affine in ``(d, boundary state)``: :meth:`BehaviouralPlanner.closed_form` precomputes
that map once from the KKT system in float64, after which a batch of plans is one matrix product
(JAX, jitted; float64 by default, float32 supported).  The same problem is available as explicit QPs
(:meth:`BehaviouralPlanner.qp`) for any backend of :mod:`solvers`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

import solvers

from .basis import Basis

if TYPE_CHECKING:
    import jax

__all__ = ["EgoState", "PlannerConfig", "BehaviouralPlanner", "Trajectories", "state_array"]


@dataclass(frozen=True)
class EgoState:
    """Ego state in Frenet coordinates (m, m/s, m/s²): arc length ``s``, lateral offset ``d``, their
    rates ``vs, vd`` and accelerations ``as_, ad``.  All must be finite."""

    s: float = 0.0
    d: float = 0.0
    vs: float = 10.0
    vd: float = 0.0
    as_: float = 0.0
    ad: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise ValueError(f"EgoState.{f.name} must be a real number, got {v!r}") from None
            if not np.isfinite(v):
                raise ValueError(f"EgoState.{f.name} must be finite, got {v}")
            object.__setattr__(self, f.name, v)

    def as_array(self) -> np.ndarray:
        """``(6,)`` float64 ``(s, d, vs, vd, as_, ad)``, the layout batched functions take."""
        return np.array([self.s, self.d, self.vs, self.vd, self.as_, self.ad])


def state_array(state, batch: int | None = None) -> np.ndarray:
    """``state`` (:class:`EgoState`, ``(6,)`` or ``(B, 6)``) → finite ``(B, 6)`` float64."""
    if isinstance(state, EgoState):
        arr = state.as_array()[None]
    else:
        arr = np.asarray(state, dtype=np.float64)
        if arr.ndim == 1:
            arr = arr[None]
        if arr.ndim != 2 or arr.shape[1] != 6:
            raise ValueError(
                f"state must be an EgoState or have shape (6,) or (B, 6), got {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            raise ValueError("state contains NaN or inf")
    if batch is not None:
        if arr.shape[0] == 1:
            arr = np.broadcast_to(arr, (batch, 6))
        elif arr.shape[0] != batch:
            raise ValueError(f"state has batch size {arr.shape[0]}, expected 1 or {batch}")
    return arr


@dataclass(frozen=True)
class PlannerConfig:
    """Constants of the behavioural planner (defaults: the reference code).

    num_segments : equal segments of the horizon, each with its own (v_d, y_d); K must be ≥ it.
    k_v, k_p : speed and lateral-offset tracking gains (1/s, 1/s²).
    k_d : lateral damping gain (1/s; paper's c_l has it, the code does not: default 0).
    w_smooth, w_speed, w_offset : weights of smoothness, speed tracking and offset tracking.
    feedback_sign : +1 reproduces the paper/code residual ``ẍ − k(ẋ − v_d)``; −1 uses the stable
        feedback residual ``ẍ + k(ẋ − v_d)`` (and likewise for the lateral term).
    final_lateral_velocity : impose ``ẏ_{K−1} = 0`` (reference: yes).
    """

    num_segments: int = 4
    k_v: float = 2.0
    k_p: float = 2.0
    k_d: float = 0.0
    w_smooth: float = 1.0
    w_speed: float = 1.0
    w_offset: float = 1.0
    feedback_sign: float = 1.0
    final_lateral_velocity: bool = True

    def __post_init__(self) -> None:
        if not (isinstance(self.num_segments, (int, np.integer)) and self.num_segments >= 1):
            raise ValueError(f"num_segments must be a positive integer, got {self.num_segments!r}")
        for name in ("k_v", "k_p", "k_d", "w_smooth", "w_speed", "w_offset"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be finite and ≥ 0, got {v}")
        if self.w_smooth <= 0:
            raise ValueError("w_smooth must be > 0 (it makes the planner QP strictly convex)")
        if self.feedback_sign not in (1.0, -1.0, 1, -1):
            raise ValueError(f"feedback_sign must be +1 or −1, got {self.feedback_sign}")

    @property
    def d_dim(self) -> int:
        return 2 * self.num_segments


class Trajectories(NamedTuple):
    """Sampled trajectories, each ``(B, K)``: Frenet positions, velocities and accelerations."""

    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    ax: np.ndarray
    ay: np.ndarray


def _kkt_map(H: np.ndarray, Aeq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For ``min ½cᵀHc − rᵀc s.t. Aeq c = b``: ``c = X r + Y b``.  Returns ``(X, Y)`` (float64)."""
    n, m = H.shape[0], Aeq.shape[0]
    K = np.block([[H, Aeq.T], [Aeq, np.zeros((m, m))]])
    Kinv = np.linalg.inv(K)
    return Kinv[:n, :n], Kinv[:n, n:]


class BehaviouralPlanner:
    """Frenet planner over a trajectory ``basis`` (see the module docstring for the problem).

    Parameters
    ----------
    basis : frenet.basis.Basis
    config : PlannerConfig

    Notes
    -----
    ``closed_form`` and ``closed_form_fn`` are the batched fast path; ``qp``/``solve`` pose the same
    problem for a :mod:`solvers` backend (the tests check they agree).
    """

    def __init__(self, basis: Basis, config: PlannerConfig | None = None):
        self.basis = basis
        self.config = config if config is not None else PlannerConfig()
        cfg, K = self.config, basis.num_steps
        if cfg.num_segments > K:
            raise ValueError(f"num_segments={cfg.num_segments} exceeds the number of steps K={K}")
        sgn = float(cfg.feedback_sign)
        # segment indicator E (K, S): E[k, s] = 1 when step k belongs to segment s
        seg = np.concatenate(
            [
                np.full(len(ix), i)
                for i, ix in enumerate(np.array_split(np.arange(K), cfg.num_segments))
            ]
        )
        self.segment_of_step = seg
        E = np.zeros((K, cfg.num_segments))
        E[np.arange(K), seg] = 1.0
        self._E = E
        S = basis.smoothness()
        # residual rows: x: (P̈ − σk_v Ṗ) c − (−σk_v v_d);  y: (P̈ − σk_p P + σk_d Ṗ) c − (−σk_p y_d)
        self._Av = basis.Pddot - sgn * cfg.k_v * basis.Pdot
        self._Ay = basis.Pddot - sgn * cfg.k_p * basis.P + sgn * cfg.k_d * basis.Pdot
        self._Bv = -sgn * cfg.k_v * E  # target = Bv @ v_d
        self._By = -sgn * cfg.k_p * E
        self.Hx = cfg.w_smooth * S + cfg.w_speed * self._Av.T @ self._Av
        self.Hy = cfg.w_smooth * S + cfg.w_offset * self._Ay.T @ self._Ay
        self.Aeq_x, self.Aeq_y = basis.boundary_rows(cfg.final_lateral_velocity)
        # linear term q = −Gx v_d  (Gx = w Avᵀ Bv)
        self._Gx = cfg.w_speed * self._Av.T @ self._Bv
        self._Gy = cfg.w_offset * self._Ay.T @ self._By
        # Exact penalty: + ½ρ‖A_eq c − b‖² is zero on the feasible set, so the optimum is unchanged,
        # but it makes the QP Hessians positive definite (the smoothness and tracking terms leave
        # e.g. the initial position free), which backends such as quadprog require.
        self._rho_eq_x = float(np.trace(self.Hx)) / basis.nvar
        self._rho_eq_y = float(np.trace(self.Hy)) / basis.nvar
        self.Hx_qp = self.Hx + self._rho_eq_x * self.Aeq_x.T @ self.Aeq_x
        self.Hy_qp = self.Hy + self._rho_eq_y * self.Aeq_y.T @ self.Aeq_y
        Xx, Yx = _kkt_map(self.Hx, self.Aeq_x)
        Xy, Yy = _kkt_map(self.Hy, self.Aeq_y)
        #: c_x = Fx_d @ v_d + Fx_b @ (s, vs, as);  c_y = Fy_d @ y_d + Fy_b @ (d, vd, ad[, 0])
        self.Fx_d, self.Fx_b = Xx @ self._Gx, Yx
        self.Fy_d, self.Fy_b = Xy @ self._Gy, Yy[:, :3]
        # one joint map: [cx | cy] = [d | state] @ W,  W (2S + 6, 2 nvar)
        n, Sg = basis.nvar, cfg.num_segments
        W = np.zeros((2 * Sg + 6, 2 * n))
        W[:Sg, :n] = self.Fx_d.T
        W[Sg : 2 * Sg, n:] = self.Fy_d.T
        W[2 * Sg + np.array([0, 2, 4]), :n] = self.Fx_b.T
        W[2 * Sg + np.array([1, 3, 5]), n:] = self.Fy_b.T
        self.W = W
        W.setflags(write=False)

    # ------------------------------------------------------------------ validation
    def _check_d(self, d) -> np.ndarray:
        d = np.asarray(d, dtype=np.float64)
        if d.ndim == 1:
            d = d[None]
        D = self.config.d_dim
        if d.ndim != 2 or d.shape[1] != D:
            raise ValueError(
                f"behavioural input must have shape ({D},) or (B, {D}) "
                f"(= {self.config.num_segments} speeds then {self.config.num_segments} offsets), "
                f"got {d.shape}"
            )
        if not np.all(np.isfinite(d)):
            raise ValueError("behavioural input d contains NaN or inf")
        return d

    @staticmethod
    def _beq(state: np.ndarray, final_lat: bool) -> tuple[np.ndarray, np.ndarray]:
        bx = state[:, [0, 2, 4]]
        by = state[:, [1, 3, 5]]
        if final_lat:
            by = np.concatenate([by, np.zeros((by.shape[0], 1))], axis=1)
        return bx, by

    # ------------------------------------------------------------------ QP form
    def qp_batch(
        self, d: ArrayLike, state: EgoState | ArrayLike
    ) -> tuple[solvers.QPBatch, solvers.QPBatch]:
        """The planner as two :class:`solvers.QPBatch` (x then y), one problem per row of ``d``.

        The QP objective carries the exact penalty ``½ρ‖A_eq c − b‖²`` (zero on the feasible set),
        so it equals the planner cost plus a constant on feasible points and its Hessian is
        positive definite.
        """
        d = self._check_d(d)
        B, Sg = d.shape[0], self.config.num_segments
        st = state_array(state, B)
        bx, by = self._beq(st, self.config.final_lateral_velocity)
        qx = -(d[:, :Sg] @ self._Gx.T) - self._rho_eq_x * bx @ self.Aeq_x
        qy = -(d[:, Sg:] @ self._Gy.T) - self._rho_eq_y * by @ self.Aeq_y
        return (
            solvers.QPBatch(self.Hx_qp, self.Aeq_x, qx, bx, bx),
            solvers.QPBatch(self.Hy_qp, self.Aeq_y, qy, by, by),
        )

    def qp(self, d: ArrayLike, state: EgoState | ArrayLike) -> tuple[solvers.QP, solvers.QP]:
        """The planner for one behavioural input ``d`` (2S,) as two QPs ``(x, y)``."""
        d = self._check_d(d)
        if d.shape[0] != 1:
            raise ValueError("qp() takes one behavioural input; use qp_batch() for many")
        bx_, by_ = self.qp_batch(d, state)
        return bx_[0], by_[0]

    def solve(
        self, d: ArrayLike, state: EgoState | ArrayLike, backend: str = "clarabel", **settings: Any
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Solve the planner QPs with a :mod:`solvers` backend: ``(cx (B, nvar), cy (B, nvar))``.

        Raises ``RuntimeError`` if the backend does not report ``SOLVED`` for every problem.
        """
        bx_, by_ = self.qp_batch(d, state)
        out = []
        for b in (bx_, by_):
            sol = solvers.solve_batch(b, backend=backend, **settings)
            if not sol.all_solved:
                raise RuntimeError(f"planner QP not solved by {backend!r}: {sol.status_counts()}")
            out.append(sol.x)
        return out[0], out[1]

    # ------------------------------------------------------------------ closed form
    def closed_form_fn(self, dtype=None):
        """A pure, jitted JAX function ``plan(d (B, 2S), state (6,) or (B, 6)) -> (cx, cy)``.

        ``cx, cy`` are ``(B, nvar)``.  The affine map is precomputed once in float64 and cast to
        ``dtype`` when traced; ``dtype=None`` (default) means float64 when JAX's x64 mode is on
        at trace time and float32 otherwise.  Safe to call inside other jitted code (e.g. a CEM
        loop); float64 needs x64 mode at trace and call time (``with jax.enable_x64(True):``).
        """
        return _closed_form_fn(self, None if dtype is None else _check_dtype(dtype))

    def closed_form(
        self, d_batch: ArrayLike, state: EgoState | ArrayLike, dtype: DTypeLike = np.float64
    ) -> tuple[jax.Array, jax.Array]:
        """Batched closed-form plans: ``(cx (B, nvar), cy (B, nvar))`` as JAX arrays of ``dtype``.

        One matrix product per batch.  Validates its inputs (use :meth:`closed_form_fn` inside
        jit).  float64 (the default) is computed under ``jax.enable_x64(True)``, whatever the
        global setting; float32 is supported.
        """
        import jax

        d = self._check_d(d_batch)
        st = state_array(state)
        if st.shape[0] not in (1, d.shape[0]):
            raise ValueError(f"state has batch size {st.shape[0]}, expected 1 or {d.shape[0]}")
        dt = _check_dtype(dtype)
        fn = self.closed_form_fn(dt)
        with jax.enable_x64(dt == np.float64):
            return fn(d.astype(dt), st.astype(dt))

    def trajectories(self, cx: ArrayLike, cy: ArrayLike) -> Trajectories:
        """Positions/velocities/accelerations ``(B, K)`` of coefficient batches (numpy float64)."""
        cx = np.atleast_2d(np.asarray(cx, dtype=np.float64))
        cy = np.atleast_2d(np.asarray(cy, dtype=np.float64))
        x, vx, ax = self.basis.trajectory(cx)
        y, vy, ay = self.basis.trajectory(cy)
        return Trajectories(x, y, vx, vy, ax, ay)


def _check_dtype(dtype):
    dt = np.dtype(dtype)
    if dt not in (np.float32, np.float64):
        raise ValueError(f"dtype must be float32 or float64, got {dt}")
    return dt.type


@functools.lru_cache(maxsize=32)
def _closed_form_fn(planner: BehaviouralPlanner, dtype):
    import jax
    import jax.numpy as jnp

    n = planner.basis.nvar
    W_np = np.asarray(planner.W)

    @jax.jit
    def plan(d, state):
        dt = dtype
        if dt is None:
            dt = jnp.float64 if jax.config.read("jax_enable_x64") else jnp.float32
        W = jnp.asarray(W_np, dtype=dt)
        d = jnp.asarray(d, dt)
        state = jnp.broadcast_to(jnp.atleast_2d(jnp.asarray(state, dt)), (d.shape[0], 6))
        z = jnp.concatenate([d, state], axis=1) @ W
        return z[:, :n], z[:, n:]

    return plan
