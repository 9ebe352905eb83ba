"""Batched, jitted ADMM in JAX for many QPs that share ``P`` and ``A`` (backend name ``"admm"``).

Meant for small dense shared matrices (``n`` up to a few hundred; a warning is given above
``n = 2000``): ``P`` and ``A`` are densified, and the batch of ``q, l, u`` is solved with batched
matrix products, on GPU when JAX has one, on CPU otherwise.

Method (OSQP's ADMM, arranged for batches)
-----------------------------------------
* Ruiz equilibration of the shared KKT matrix ``[[P, Aᵀ], [A, 0]]`` plus one cost scaling
  (computed from ``P`` only, so that every QP of the batch shares it).
* For a small ladder of step sizes ``rho`` (×5 apart) the inverse
  ``K⁻¹ = (P + σI + Aᵀ R A)⁻¹`` is computed once in float64 and stored in the iteration dtype;
  ``R = rho`` on inequality rows, ``rho_eq_scale · rho`` on equality rows.  Explicit inverses
  because a batched matmul beats triangular solves by a wide margin on this shape of problem.
* Each QP carries its own rung of the ladder and re-picks it every ``check_every`` iterations
  with OSQP's residual-balancing rule; one matmul per rung in use, then a select.
* Iterations run in ``dtype`` (float32 by default) under a fixed budget ``max_iter``; converged,
  infeasible or broken QPs are frozen by a per-QP mask, so a slow QP never holds the batch.
* Every ``check_every`` iterations: OSQP's unscaled termination test, OSQP's primal and dual
  infeasibility certificates, a NaN guard.
* Then (``polish=True``) a batched active-set polish in float64 NumPy: the active set is guessed
  from ``(z, y)``, the reduced KKT system is solved by a Schur complement on the shared
  ``(P + δI)⁻¹`` with the per-QP active rows gathered and padded to the batch's largest active
  count, with iterative refinement; a few primal-dual active-set passes repair wrong guesses.  A
  polished point replaces the ADMM iterate only where it passes the same termination test (with
  its duals projected onto the normal cone) and is no worse than the ADMM iterate.
* Optional, visible and counted: ``fallback="clarabel"`` re-solves the QPs still not solved.

Statuses (per QP, :class:`solvers.Status` codes): ``SOLVED`` when the unscaled residuals meet
``eps_abs``/``eps_rel`` (OSQP's criteria), ``PRIMAL_INFEASIBLE``/``DUAL_INFEASIBLE`` from the
certificates, ``MAX_ITER`` otherwise, ``ERROR`` on NaN.  After the float32 iterations the backend
re-checks the test in float64 and reports ``SOLVED_INACCURATE`` where only float32 met it.

Backend use
-----------
::

    from solvers import solve_batch
    sol = solve_batch(batch, backend="admm", eps_abs=1e-5, polish=True, warm_start=prev)

Settings are the fields of :class:`ADMMSettings`, passed as keyword arguments; unknown names raise
``ValueError``.  The settings used are recorded in ``sol.settings``; ``sol.extras`` holds the
polish counts, the fallback count, timings and the per-QP final ``rho``.

Functional core (pure JAX, for use inside your own ``jit``)
-----------------------------------------------------------
::

    from solvers.admm import ADMMSettings, admm_factor, admm_iterate

    factor = admm_factor(P, A, ADMMSettings(), eq_rows=eq_mask)  # NumPy/float64, once per P, A
    @jax.jit
    def project(q, l, u, x0, y0):                               # (B, n), (B, m), (B, m), ...
        st = admm_iterate(factor, q, l, u, x0=x0, y0=y0, iters=200)
        return st.x, st.status

* :func:`admm_factor` precomputes the scaling, the scaled matrices and the ladder of inverses, and
  returns an :class:`ADMMFactor` pytree: its arrays are leaves (so a new ``P``/``A`` of the same
  shape does not recompile) and its settings are static metadata.  ``eq_rows`` (bool ``(m,)``)
  marks rows that are equalities in every QP (they get ``rho_eq_scale · rho``); ``free_rows``
  marks rows unbounded on both sides.  Use :func:`rows_from_bounds` to derive both from ``l, u``.
* :func:`admm_iterate` takes unscaled ``q (B, n), l (B, m), u (B, m)`` (a 1-D problem is treated
  as ``B = 1`` and squeezed back), an optional warm start ``x0 (B, n), y0 (B, m)`` (unscaled,
  OSQP sign convention) and a static iteration budget ``iters`` (rounded up to a multiple of
  ``check_every``).  It is jittable and vmappable, has no Python loop over samples, and returns an
  :class:`ADMMState` ``(x, z, y, prim_res, dual_res, status, iterations, rho, rung_matmuls)``,
  unscaled, with ``status`` the :class:`solvers.Status` integer codes (``MAX_ITER`` where the
  budget ran out).  It does not polish; :func:`polish` (NumPy, host side) can be applied after.
* ``dtype=float64`` needs JAX's x64 mode (``jax.enable_x64(True)`` as a context manager); the
  backend enables it for the call itself.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
import warnings
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from jax import lax

from .base import Backend
from .problem import QP, QPBatch
from .solution import BatchSolution, Solution, Status

__all__ = [
    "ADMMSettings",
    "ADMMFactor",
    "ADMMState",
    "ADMMBackend",
    "admm_factor",
    "admm_iterate",
    "rows_from_bounds",
    "polish",
    "flops_per_iteration",
    "make_backend",
]

_SOLVED = int(Status.SOLVED)
_MAX_ITER = int(Status.MAX_ITER)
_PINF = int(Status.PRIMAL_INFEASIBLE)
_DINF = int(Status.DUAL_INFEASIBLE)
_ERROR = int(Status.ERROR)
_RUNNING = 0

#: polish keeps repairing the active set until the residuals are this fraction of the tolerance
_POLISH_EXACT = 1e-3

#: above this many variables the dense path warns (it stores (n, n) inverses per rung)
DENSE_N_WARN = 2000


@dataclass(frozen=True)
class ADMMSettings:
    """Settings of the ``admm`` backend (all explicit; nothing else is changed behind them).

    Attributes
    ----------
    eps_abs, eps_rel : OSQP-style termination, ``‖Ax − z‖∞ ≤ eps_abs + eps_rel·max(‖Ax‖∞, ‖z‖∞)``
        and ``‖Px + q + Aᵀy‖∞ ≤ eps_abs + eps_rel·max(‖Px‖∞, ‖Aᵀy‖∞, ‖q‖∞)`` (unscaled).
    eps_prim_inf, eps_dual_inf : tolerances of OSQP's infeasibility certificates.
    max_iter : iteration budget per QP (rounded up to a multiple of ``check_every``).
    check_every : iterations between termination/infeasibility checks and rho updates.
    rho : initial step size; the ladder rung nearest to it is the start.
    rho_ladder : the step sizes whose inverses are precomputed (sorted ascending).
    rho_eq_scale : ``rho`` multiplier on rows that are equalities in every QP of the batch.
    rho_free : the (absolute) rho on rows with both bounds infinite.
    sigma : proximal term on ``x``.
    alpha : over-relaxation.
    adaptive_rho : re-pick each QP's rung at every check.
    scaling_iter : Ruiz equilibration passes (0 = no scaling).
    dtype : iteration dtype, ``"float32"`` or ``"float64"``.
    polish, polish_delta, polish_refine_iter, polish_passes : float64 active-set polish; the
        regularisation ``δ``, iterative-refinement steps, active-set repair passes.
    stage_iter : ``None`` (one stage of ``max_iter``), or run ADMM in stages of this many
        iterations: after each stage the polish is tried, the QPs it accepts leave the batch and
        the rest continue (warm-started with their rho) in a smaller batch padded to a power of
        two.  Saves the dense batch's work on QPs already solved; each new batch size compiles.
    fallback : ``None`` or ``"clarabel"``: re-solve QPs still not solved (not certified
        infeasible) with Clarabel; counted in ``extras["fallback_count"]``.
    """

    eps_abs: float = 1e-5
    eps_rel: float = 1e-5
    eps_prim_inf: float = 1e-4
    eps_dual_inf: float = 1e-4
    max_iter: int = 1000
    check_every: int = 25
    rho: float = 0.1
    rho_ladder: tuple[float, ...] = (0.1 / 125, 0.1 / 25, 0.1 / 5, 0.1, 0.5, 2.5, 12.5)
    rho_eq_scale: float = 1e3
    rho_free: float = 1e-6
    sigma: float = 1e-6
    alpha: float = 1.6
    adaptive_rho: bool = True
    scaling_iter: int = 10
    dtype: str = "float32"
    polish: bool = True
    polish_delta: float = 1e-6
    polish_refine_iter: int = 3
    polish_passes: int = 25
    stage_iter: int | None = None
    fallback: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "rho_ladder", tuple(sorted(float(r) for r in self.rho_ladder)))
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"dtype must be 'float32' or 'float64', got {self.dtype!r}")
        if self.fallback not in (None, "clarabel"):
            raise ValueError(f"fallback must be None or 'clarabel', got {self.fallback!r}")
        if self.check_every < 1 or self.max_iter < 0:
            raise ValueError("check_every must be ≥ 1 and max_iter ≥ 0")
        if not self.rho_ladder or min(self.rho_ladder) <= 0 or self.rho <= 0:
            raise ValueError("rho and rho_ladder must be positive")
        if not (0 < self.alpha < 2):
            raise ValueError("alpha must be in (0, 2)")
        for name in ("eps_abs", "eps_rel", "eps_prim_inf", "eps_dual_inf", "sigma"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be ≥ 0")

    @classmethod
    def from_kwargs(cls, **kwargs: Any) -> ADMMSettings:
        """Build from keyword arguments; unknown names raise ``ValueError`` naming them."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(kwargs) - names)
        if unknown:
            raise ValueError(
                f"unknown admm setting(s) {unknown}; valid names: {', '.join(sorted(names))}"
            )
        if "rho_ladder" in kwargs:
            kwargs["rho_ladder"] = tuple(kwargs["rho_ladder"])
        return cls(**kwargs)

    def replace(self, **kwargs: Any) -> ADMMSettings:
        return dataclasses.replace(self, **kwargs)

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


# ----------------------------------------------------------------------------- factor (host)
@jax.tree_util.register_pytree_node_class
@dataclass(frozen=True, eq=False)
class ADMMFactor:
    """Precomputed, scaled data for :func:`admm_iterate` (a pytree; settings are static).

    Scaled problem: ``P̄ = c·D P D``, ``Ā = E A D``, ``q̄ = c·D q``, ``l̄ = E l``, ``ū = E u``;
    ``x = D x̄``, ``z = E⁻¹ z̄``, ``y = E ȳ / c``.
    """

    P: Any  # (n, n) scaled P̄
    A: Any  # (m, n) scaled Ā
    D: Any  # (n,)
    E: Any  # (m,)
    c: Any  # ()
    Kinv: Any  # (L, n, n) (P̄ + σI + ĀᵀR_rĀ)⁻¹ per rung
    ladder: Any  # (L,) rho values
    Rbase: Any  # (m,) row multipliers of rho (1, rho_eq_scale, or rho_free/rho)
    free: Any  # (m,) bool, rows with the absolute rho_free
    settings: ADMMSettings

    def tree_flatten(self):
        leaves = (self.P, self.A, self.D, self.E, self.c, self.Kinv, self.ladder, self.Rbase,
                  self.free)
        return leaves, self.settings

    @classmethod
    def tree_unflatten(cls, settings, leaves):
        return cls(*leaves, settings=settings)

    @property
    def n(self) -> int:
        return self.P.shape[0]

    @property
    def m(self) -> int:
        return self.A.shape[0]


def rows_from_bounds(l: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(eq_rows, free_rows)``: rows equal in every QP, rows unbounded on both sides in every QP.

    ``l, u`` are ``(m,)`` or ``(B, m)``.
    """
    l2, u2 = np.atleast_2d(np.asarray(l, float)), np.atleast_2d(np.asarray(u, float))
    eq = np.all((l2 == u2) & np.isfinite(l2), axis=0)
    free = np.all(np.isinf(l2) & np.isinf(u2), axis=0)
    return eq, free


def _ruiz(P: np.ndarray, A: np.ndarray, iters: int) -> tuple[np.ndarray, np.ndarray, float]:
    """OSQP's modified Ruiz equilibration of ``[[P, Aᵀ], [A, 0]]`` plus a cost scaling."""
    n, m = P.shape[0], A.shape[0]
    D, E = np.ones(n), np.ones(m)
    Ps, As = P.copy(), A.copy()
    c = 1.0
    lo, hi = 1e-4, 1e4
    for _ in range(iters):
        cn = np.maximum(np.abs(Ps).max(axis=0, initial=0.0), np.abs(As).max(axis=0, initial=0.0))
        rn = np.abs(As).max(axis=1, initial=0.0)
        cn = np.where(cn < lo, 1.0, cn)
        rn = np.where(rn < lo, 1.0, rn)
        dD = np.clip(1.0 / np.sqrt(cn), lo, hi)
        dE = np.clip(1.0 / np.sqrt(rn), lo, hi)
        Ps = dD[:, None] * Ps * dD[None, :]
        As = dE[:, None] * As * dD[None, :]
        D, E = D * dD, E * dE
        # cost scaling from P only (q differs per QP, the factor is shared)
        pn = float(np.mean(np.abs(Ps).max(axis=0, initial=0.0))) if n else 0.0
        g = 1.0 / pn if pn >= lo else 1.0
        g = float(np.clip(g, lo, hi))
        Ps *= g
        c *= g
    return D, E, c


def _spd_inverse(K: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive definite matrix via Cholesky (LU-based ``inv`` is far
    slower here); falls back to ``inv`` when Cholesky fails."""
    try:
        return sla.cho_solve(sla.cho_factor(K, lower=True), np.eye(K.shape[0]))
    except np.linalg.LinAlgError:
        return np.linalg.inv(K)


def admm_factor(
    P: Any,
    A: Any,
    settings: ADMMSettings | None = None,
    *,
    eq_rows: np.ndarray | None = None,
    free_rows: np.ndarray | None = None,
) -> ADMMFactor:
    """Precompute the scaled data and the ladder of inverses (NumPy, float64), once per ``P, A``.

    Parameters
    ----------
    P : (n, n) symmetric PSD, dense or sparse (densified).
    A : (m, n) dense or sparse (densified).
    settings : :class:`ADMMSettings` (defaults if ``None``).
    eq_rows, free_rows : (m,) bool masks, see :func:`rows_from_bounds`.
    """
    s = settings or ADMMSettings()
    P = np.asarray(P.toarray() if sp.issparse(P) else P, dtype=np.float64)
    A = np.asarray(A.toarray() if sp.issparse(A) else A, dtype=np.float64)
    n, m = P.shape[0], A.shape[0]
    A = A.reshape(m, n)
    eq = np.zeros(m, bool) if eq_rows is None else np.asarray(eq_rows, bool)
    free = np.zeros(m, bool) if free_rows is None else np.asarray(free_rows, bool)
    free = free & ~eq
    D, E, c = _ruiz(P, A, s.scaling_iter)
    Ps = c * D[:, None] * P * D[None, :]
    As = E[:, None] * A * D[None, :]
    Rbase = np.where(eq, s.rho_eq_scale, 1.0)
    ladder = np.asarray(s.rho_ladder, np.float64)
    Kinv = np.empty((len(ladder), n, n))
    for r, rho in enumerate(ladder):
        R = np.where(free, s.rho_free, rho * Rbase)
        K = Ps + s.sigma * np.eye(n) + As.T @ (R[:, None] * As)
        Ki = _spd_inverse(K)
        Kinv[r] = 0.5 * (Ki + Ki.T)
    dt = np.dtype(s.dtype)
    return ADMMFactor(
        P=Ps.astype(dt), A=As.astype(dt), D=D.astype(dt), E=E.astype(dt), c=np.asarray(c, dt),
        Kinv=Kinv.astype(dt), ladder=ladder.astype(dt), Rbase=Rbase.astype(dt), free=free,
        settings=s,
    )


# ------------------------------------------------------------------------- iterations (JAX)
class ADMMState(NamedTuple):
    """Result of :func:`admm_iterate` (unscaled; leading batch axis ``B``)."""

    x: jax.Array  # (B, n)
    z: jax.Array  # (B, m)  A x projected on [l, u]
    y: jax.Array  # (B, m)  OSQP sign convention
    prim_res: jax.Array  # (B,) ‖Ax − z‖∞ at the last check
    dual_res: jax.Array  # (B,) ‖Px + q + Aᵀy‖∞ at the last check
    status: jax.Array  # (B,) int32 Status codes
    iterations: jax.Array  # (B,) iterations each QP ran
    rho: jax.Array  # (B,) final rho of each QP
    rung_matmuls: jax.Array  # () number of (B,n)x(n,n) K⁻¹ products executed


def _inf_norm(v):
    return jnp.max(jnp.abs(v), axis=-1, initial=0.0)


def admm_iterate(
    factor: ADMMFactor,
    q: Any,
    l: Any,
    u: Any,
    x0: Any = None,
    y0: Any = None,
    iters: int | None = None,
    rho0: Any = None,
) -> ADMMState:
    """Run batched ADMM (no polish) on unscaled ``q (B, n), l (B, m), u (B, m)``; jittable.

    ``iters`` (static; default ``settings.max_iter``) is rounded up to a multiple of
    ``check_every``.  ``rho0`` (scalar or ``(B,)``, optional) starts each QP on the ladder rung
    nearest to it (default: ``settings.rho``).  Returns an :class:`ADMMState`.
    """
    s = factor.settings
    dt = factor.P.dtype
    squeeze = jnp.ndim(q) == 1
    q, l, u = (jnp.atleast_2d(jnp.asarray(v, dt)) for v in (q, l, u))
    B = q.shape[0]
    n, m = factor.n, factor.m
    iters = s.max_iter if iters is None else int(iters)
    n_chunks = -(-iters // s.check_every)
    # (jnp.asarray: the factor may be closed over as NumPy constants inside a user's jit)
    Pb, Ab, D, E, c = (jnp.asarray(v) for v in (factor.P, factor.A, factor.D, factor.E, factor.c))
    Kinv, ladder, Rbase, free = (
        jnp.asarray(v) for v in (factor.Kinv, factor.ladder, factor.Rbase, factor.free))
    L = Kinv.shape[0]
    qb = c * D * q
    lb, ub = E * l, E * u
    Dinv, Einv = 1.0 / D, 1.0 / E
    finite_l, finite_u = jnp.isfinite(l), jnp.isfinite(u)

    if x0 is None:
        xs = jnp.zeros((B, n), dt)
    else:
        xs = jnp.atleast_2d(jnp.asarray(x0, dt)) * Dinv
    if y0 is None:
        ys = jnp.zeros((B, m), dt)
    else:
        ys = c * jnp.atleast_2d(jnp.asarray(y0, dt)) * Einv
    zs = jnp.clip(xs @ Ab.T, lb, ub)
    rung0 = int(np.argmin(np.abs(np.log(np.asarray(s.rho_ladder)) - np.log(s.rho))))
    if rho0 is None:
        rung = jnp.full((B,), rung0, jnp.int32)
    else:  # per-QP start (e.g. the rho a previous run ended with): the nearest rung
        lr = jnp.log(jnp.broadcast_to(jnp.asarray(rho0, dt), (B,)))
        rung = jnp.argmin(jnp.abs(lr[:, None] - jnp.log(ladder)[None, :]), axis=-1)
        rung = rung.astype(jnp.int32)

    def row_rho(rung):
        rho = ladder[rung]
        return jnp.where(free[None, :], jnp.asarray(s.rho_free, dt), rho[:, None] * Rbase[None, :])

    # Static fast path: every QP starts on the same rung and no rho update can happen before
    # the last iteration (one check chunk, or adaptation off), so K⁻¹ is one fixed matrix and
    # the step sizes R are constants of the loop (no per-step rung dispatch).
    fixed_rung = rho0 is None and (n_chunks == 1 or not s.adaptive_rho)
    if fixed_rung:
        R_fix = row_rho(rung)[:1]  # (1, m), identical rows
        Rinv_fix = 1.0 / R_fix
        K_fix = Kinv[rung0]

    def kinv_apply(rhs, rung, active):
        # one matmul per rung in use, then a select (a rolled loop keeps compile time small)
        def body(r, acc):
            out, cnt = acc
            sel = (rung == r) & active
            use = jnp.any(sel)
            out = lax.cond(use, lambda o: jnp.where(sel[:, None], rhs @ Kinv[r], o),
                           lambda o: o, out)
            return out, cnt + use.astype(jnp.int32)

        return lax.fori_loop(0, L, body, (jnp.zeros_like(rhs), jnp.zeros((), jnp.int32)))

    def step(carry):
        # one iteration with each QP on its own rung of the ladder
        x, z, y, rung, active, cnt = carry
        R = row_rho(rung)
        rhs = s.sigma * x - qb + (R * z - y) @ Ab
        xt, k = kinv_apply(rhs, rung, active)
        zt = xt @ Ab.T
        xn = s.alpha * xt + (1.0 - s.alpha) * x
        zr = s.alpha * zt + (1.0 - s.alpha) * z
        zn = jnp.clip(zr + y / R, lb, ub)
        yn = y + R * (zr - zn)
        a = active[:, None]
        return (jnp.where(a, xn, x), jnp.where(a, zn, z), jnp.where(a, yn, y), rung, active,
                cnt + k)

    def check(x, z, y, xp, yp, rung, status, active):
        Ax = x @ Ab.T
        Px = x @ Pb
        Aty = y @ Ab
        # unscaled residuals and norms (OSQP, scaled_termination = False)
        prim = _inf_norm(Einv * (Ax - z))
        dual = _inf_norm(Dinv * (Px + qb + Aty)) / c
        n_Ax, n_z = _inf_norm(Einv * Ax), _inf_norm(Einv * z)
        n_Px, n_Aty, n_q = (_inf_norm(Dinv * Px) / c, _inf_norm(Dinv * Aty) / c,
                            _inf_norm(Dinv * qb) / c)
        eps_p = s.eps_abs + s.eps_rel * jnp.maximum(n_Ax, n_z)
        eps_d = s.eps_abs + s.eps_rel * jnp.maximum(jnp.maximum(n_Px, n_Aty), n_q)
        solved = (prim <= eps_p) & (dual <= eps_d)
        # primal infeasibility: δy projected on the polar of the recession cone of [l, u]
        dy = E * (y - yp) / c
        dy = jnp.where(finite_u, dy, jnp.minimum(dy, 0.0))
        dy = jnp.where(finite_l, dy, jnp.maximum(dy, 0.0))
        ndy = _inf_norm(dy)
        Atdy = _inf_norm(Dinv * ((y - yp) @ Ab)) / c
        supp = jnp.sum(jnp.where(dy > 0, jnp.where(finite_u, u, 0.0) * dy, 0.0)
                       + jnp.where(dy < 0, jnp.where(finite_l, l, 0.0) * dy, 0.0), axis=-1)
        pinf = (ndy > 1e-30) & (Atdy <= s.eps_prim_inf * ndy) & (supp <= -s.eps_prim_inf * ndy)
        # dual infeasibility: δx
        dxs = x - xp
        dx = D * dxs
        ndx = _inf_norm(dx)
        Pdx = _inf_norm(Dinv * (dxs @ Pb)) / c
        qdx = jnp.sum(qb * dxs, axis=-1) / c
        Adx = Einv * (dxs @ Ab.T)
        tol = s.eps_dual_inf * ndx[:, None]
        ok_rows = jnp.where(finite_u, Adx <= tol, True) & jnp.where(finite_l, Adx >= -tol, True)
        dinf = ((ndx > 1e-30) & (Pdx <= s.eps_dual_inf * ndx) & (qdx <= -s.eps_dual_inf * ndx)
                & jnp.all(ok_rows, axis=-1))
        bad = ~(jnp.all(jnp.isfinite(x), -1) & jnp.all(jnp.isfinite(y), -1)
                & jnp.all(jnp.isfinite(z), -1))
        new = jnp.where(bad, _ERROR, jnp.where(solved, _SOLVED, jnp.where(
            pinf, _PINF, jnp.where(dinf, _DINF, _RUNNING))))
        status = jnp.where(active, new, status)
        if s.adaptive_rho:
            # OSQP's rule on scaled quantities
            sp_ = _inf_norm(Ax - z) / (jnp.maximum(_inf_norm(Ax), _inf_norm(z)) + 1e-30)
            sd_ = _inf_norm(Px + qb + Aty) / (
                jnp.maximum(jnp.maximum(_inf_norm(Px), _inf_norm(Aty)), _inf_norm(qb)) + 1e-30)
            rho_new = ladder[rung] * jnp.sqrt(sp_ / (sd_ + 1e-30))
            lr = jnp.log(jnp.clip(rho_new, 1e-30, 1e30))
            best = jnp.argmin(jnp.abs(lr[:, None] - jnp.log(ladder)[None, :]), axis=-1)
            keep = ~jnp.isfinite(lr) | (prim == 0) | (dual == 0)
            rung = jnp.where(active & (status == _RUNNING) & ~keep, best.astype(jnp.int32), rung)
        return prim, dual, status, rung

    def fixed_rung_iterations(x, z, y, active, all_active):
        # ``check_every`` iterations of ``step`` on the fixed rung, with the batch as the last
        # axis: the products become (m, n)·(n, B) instead of (B, n)·(n, m), which XLA's CPU
        # backend runs ≈ 3× faster at these shapes (n, m ≲ 100; measured, docs/benchmarks.md)
        R, Rinv = R_fix.T, Rinv_fix.T  # (m, 1)
        qT, lT, uT = qb.T, lb.T, ub.T
        a = active[None, :]

        def it(_, c_):
            xT, zT, yT, _xp, _yp = c_
            rhs = s.sigma * xT - qT + Ab.T @ (R * zT - yT)
            xt = K_fix @ rhs  # K⁻¹ is symmetric
            zt = Ab @ xt
            xn = s.alpha * xt + (1.0 - s.alpha) * xT
            zr = s.alpha * zt + (1.0 - s.alpha) * zT
            zn = jnp.clip(zr + yT * Rinv, lT, uT)
            yn = yT + R * (zr - zn)
            if not all_active:  # QPs that have stopped keep their iterate
                xn, zn, yn = (jnp.where(a, new, old) for new, old in ((xn, xT), (zn, zT), (yn, yT)))
            return xn, zn, yn, xT, yT

        xT, zT, yT = x.T, z.T, y.T
        xT, zT, yT, xpT, ypT = lax.fori_loop(0, s.check_every, it, (xT, zT, yT, xT, yT))
        return xT.T, zT.T, yT.T, xpT.T, ypT.T

    def chunk(carry, all_active=False):
        x, z, y, rung, status, iters_b, prim, dual, k, cnt = carry
        active = status == _RUNNING

        def it(_, c_):
            x, z, y, _xp, _yp, cnt = c_
            xn, zn, yn, _, _, cnt = step((x, z, y, rung, active, cnt))
            return xn, zn, yn, x, y, cnt

        if fixed_rung:
            x, z, y, xp, yp = fixed_rung_iterations(x, z, y, active, all_active)
            cnt = cnt + s.check_every * jnp.any(active).astype(jnp.int32)
        else:
            x, z, y, xp, yp, cnt = lax.fori_loop(0, s.check_every, it, (x, z, y, x, y, cnt))
        prim_n, dual_n, status_n, rung = check(x, z, y, xp, yp, rung, status, active)
        prim = jnp.where(active, prim_n, prim)
        dual = jnp.where(active, dual_n, dual)
        iters_b = iters_b + jnp.where(active, s.check_every, 0)
        return x, z, y, rung, status_n, iters_b, prim, dual, k + 1, cnt

    def cond(carry):
        status, k = carry[4], carry[8]
        return (k < n_chunks) & jnp.any(status == _RUNNING)

    inf = jnp.full((B,), jnp.inf, dt)
    init = (xs, zs, ys, rung, jnp.zeros((B,), jnp.int32), jnp.zeros((B,), jnp.int32), inf, inf,
            jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))
    if n_chunks == 1:
        # one chunk: no loop, every QP active; outputs nobody uses (the check, when a jitted
        # caller keeps only x) are then removed by XLA
        x, z, y, rung, status, iters_b, prim, dual, _, cnt = chunk(init, all_active=True)
    else:
        x, z, y, rung, status, iters_b, prim, dual, _, cnt = lax.while_loop(cond, chunk, init)
    status = jnp.where(status == _RUNNING, _MAX_ITER, status).astype(jnp.int32)
    out = ADMMState(
        x=D * x, z=Einv * z, y=E * y / c, prim_res=prim, dual_res=dual, status=status,
        iterations=iters_b, rho=ladder[rung], rung_matmuls=cnt,
    )
    if squeeze:
        out = ADMMState(*(v[0] for v in out[:-1]), out[-1])
    return out


_admm_iterate_jit = jax.jit(admm_iterate, static_argnames=("iters",))


def _flops(n: int, m: int, B: int, iters: int, rung_matmuls: int, check_every: int) -> float:
    """Matmul FLOPs of one :func:`admm_iterate` call on a dense batch of ``B``."""
    checks = (iters // check_every) * B * (8.0 * m * n + 4.0 * n * n)
    return 4.0 * m * n * B * iters + 2.0 * n * n * B * rung_matmuls + checks


def flops_per_iteration(n: int, m: int, rungs_used: float = 1.0) -> float:
    """Floating-point operations of one ADMM iteration for one QP (matmuls only).

    ``Āᵀ(Rz − y)``: 2mn; ``K⁻¹·rhs``: 2n² per rung in use; ``Āx̃``: 2mn.
    """
    return 4.0 * m * n + 2.0 * n * n * rungs_used


# ------------------------------------------------------------------------ polish (NumPy f64)
@dataclass(frozen=True, eq=False)
class _PolishData:
    P: np.ndarray  # (n, n) scaled, float64
    A: np.ndarray  # (m, n) scaled
    Hinv: np.ndarray  # (P̄ + δI)⁻¹
    S: np.ndarray  # Ā Hinv Āᵀ  (m, m)
    D: np.ndarray
    E: np.ndarray
    c: float


def _polish_data(P: np.ndarray, A: np.ndarray, s: ADMMSettings, D, E, c) -> _PolishData:
    D, E, c = np.asarray(D, float), np.asarray(E, float), float(c)
    Ps = c * D[:, None] * P * D[None, :]
    As = E[:, None] * A * D[None, :]
    H = Ps + s.polish_delta * np.eye(P.shape[0])
    Hinv = _spd_inverse(H)
    Hinv = 0.5 * (Hinv + Hinv.T)
    S = As @ Hinv @ As.T
    return _PolishData(Ps, As, Hinv, 0.5 * (S + S.T), D, E, c)


def _termination(P, A, q, l, u, x, y, s: ADMMSettings):
    """Unscaled OSQP test for (x, y) with z = Π(Ax); float64.  Returns (ok, prim, dual)."""
    Ax = x @ A.T
    z = np.clip(Ax, l, u)
    Px = x @ P
    Aty = y @ A
    prim = np.abs(Ax - z).max(axis=1, initial=0.0)
    dual = np.abs(Px + q + Aty).max(axis=1, initial=0.0)
    eps_p = s.eps_abs + s.eps_rel * np.maximum(np.abs(Ax).max(1, initial=0.0),
                                               np.abs(z).max(1, initial=0.0))
    eps_d = s.eps_abs + s.eps_rel * np.maximum.reduce(
        [np.abs(Px).max(1, initial=0.0), np.abs(Aty).max(1, initial=0.0),
         np.abs(q).max(1, initial=0.0)])
    return (prim <= eps_p) & (dual <= eps_d), prim, dual, eps_p, eps_d


def _batched_cholesky(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cholesky factors of SPD ``M (B, k, k)``; ``bad`` marks the ones that failed (identity)."""
    try:
        return np.linalg.cholesky(M), np.zeros(M.shape[0], bool)
    except np.linalg.LinAlgError:
        out = np.empty_like(M)
        bad = np.zeros(M.shape[0], bool)
        for i in range(M.shape[0]):
            try:
                out[i] = np.linalg.cholesky(M[i])
            except np.linalg.LinAlgError:
                out[i] = np.eye(M.shape[1])
                bad[i] = True
        return out, bad


def _cho_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``L Lᵀ x = b`` batched (``L (B, k, k)``, ``b (B, k)``); batched triangular solves
    (NumPy's batched ``inv`` is ~50× slower here)."""
    t = sla.solve_triangular(L, b[..., None], lower=True)
    return sla.solve_triangular(L, t, lower=True, trans="T")[..., 0]


def _reduced_kkt(pd: _PolishData, qs, low, upp, ls, us, s: ADMMSettings, x0=None, y0=None,
                 chunk: int = 256):
    """Solve the reduced KKT systems for active sets ``low``/``upp`` (B, m); scaled space.

    Each refinement step is a proximal-point step on the exact reduced KKT system; started from
    the ADMM iterate ``(x0, y0)`` it converges to the KKT point nearest to it, which keeps the
    multipliers of degenerate active sets close to ADMM's (sign-correct) ones.  NumPy float64:
    batched Cholesky of the gathered Schur complements, batched triangular solves.  (A JAX x64
    version of this was measured slower on CPU: XLA's batched triangular solves and scatters.)
    """
    B, m = low.shape
    n = pd.P.shape[0]
    xs = np.zeros((B, n))
    ys = np.zeros((B, m))
    act = low | upp
    for a in range(0, B, chunk):
        sl = slice(a, min(B, a + chunk))
        actc = act[sl]
        nb = actc.shape[0]
        k = int(actc.sum(axis=1).max(initial=0))
        q = qs[sl]
        if k == 0:  # no active row: (refined) unconstrained minimiser
            x = -q @ pd.Hinv if x0 is None else x0[sl].copy()
            for _ in range(s.polish_refine_iter + 1):
                x = x + (-q - x @ pd.P) @ pd.Hinv
            xs[sl] = x
            continue
        order = np.argsort(~actc, axis=1, kind="stable")[:, :k]
        mask = np.take_along_axis(actc, order, axis=1)
        bval = np.where(upp[sl], us[sl], ls[sl])
        b = np.where(mask, np.take_along_axis(bval, order, axis=1), 0.0)
        Sa = pd.S[order[:, :, None], order[:, None, :]]
        mm = mask[:, :, None] & mask[:, None, :]
        eye = np.eye(k)[None]
        M = np.where(mm, Sa, 0.0) + eye * np.where(mask, s.polish_delta, 1.0)[:, :, None]
        Lc, bad = _batched_cholesky(M)
        rows = np.arange(nb)[:, None]

        def solve(r1, r2, Lc=Lc, order=order, mask=mask, rows=rows, nb=nb):
            t = r1 @ pd.Hinv
            g = np.take_along_axis(t @ pd.A.T, order, axis=1)
            dy = _cho_solve(Lc, np.where(mask, g - r2, 0.0))
            dy = np.where(mask, dy, 0.0)
            yfull = np.zeros((nb, m))
            yfull[rows, order] = dy  # order is a prefix of a permutation: no repeats
            dx = t - (yfull @ pd.A) @ pd.Hinv
            return dx, yfull

        if x0 is None:
            x, y = solve(-q, b)
        else:
            x, y = x0[sl].copy(), np.where(act[sl], y0[sl], 0.0)
        for _ in range(s.polish_refine_iter + (0 if x0 is None else 1)):
            r1 = -q - x @ pd.P - y @ pd.A
            r2 = np.where(mask, b - np.take_along_axis(x @ pd.A.T, order, axis=1), 0.0)
            dx, dy = solve(r1, r2)
            x, y = x + dx, y + dy
        x[bad] = np.nan
        xs[sl], ys[sl] = x, y
    return xs, ys


def polish(
    pd: _PolishData, P, A, q, l, u, x, z, y, s: ADMMSettings
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Batched active-set polish (float64).  Inputs unscaled ``(B, ·)``.

    Returns ``(accepted, x, y, prim, dual)``: where ``accepted`` the polished point passes the
    termination test (duals projected on the normal cone) — elsewhere the inputs are returned.
    """
    D, E, c = pd.D, pd.E, pd.c
    qs, ls, us = c * D * q, E * l, E * u
    zs, ysc = E * z, c * y / E
    xsc = x / D
    eq = (ls == us) & np.isfinite(ls)
    low = ((zs - ls < -ysc) | eq) & np.isfinite(ls)
    upp = (us - zs < ysc) & np.isfinite(us) & ~low
    B = q.shape[0]
    accepted = np.zeros(B, bool)
    xo, yo = x.copy(), y.copy()
    _, prim0, dual0, eps_p0, eps_d0 = _termination(P, A, q, l, u, x, y, s)
    score0 = np.maximum(prim0 / eps_p0, dual0 / eps_d0)
    prim_o, dual_o = prim0.copy(), dual0.copy()
    best = np.full(B, np.inf)
    todo = np.arange(B)
    for _ in range(max(1, s.polish_passes)):
        if todo.size == 0:
            break
        xs_, ys_ = _reduced_kkt(pd, qs[todo], low[todo], upp[todo], ls[todo], us[todo], s,
                                x0=xsc[todo], y0=ysc[todo])
        xp = D * xs_
        yp = E * ys_ / c
        # project the duals on the normal cone of the guessed active set
        lo_t, up_t, eq_t = low[todo] & ~eq[todo], upp[todo], eq[todo]
        yproj = np.where(eq_t, yp, np.where(lo_t, np.minimum(yp, 0), np.where(
            up_t, np.maximum(yp, 0), 0.0)))
        ok, prim, dual, eps_p, eps_d = _termination(
            P, A, q[todo], l[todo], u[todo], xp, yproj, s)
        ok &= np.all(np.isfinite(xp), axis=1) & np.all(np.isfinite(yproj), axis=1)
        score = np.where(ok, np.maximum(prim / eps_p, dual / eps_d), np.inf)
        # better than the ADMM iterate and than any earlier pass
        better = ok & (score <= np.maximum(score0[todo], 1.0)) & (score < best[todo])
        acc = todo[better]
        accepted[acc] = True
        best[acc] = score[better]
        xo[acc], yo[acc] = xp[better], yproj[better]
        prim_o[acc], dual_o[acc] = prim[better], dual[better]
        # a point that passes the test with residuals ≥ 1e-3 of the tolerance usually has a
        # degenerate row misplaced: keep repairing it (the accepted point stays if none is better)
        rej = ~(ok & (score <= _POLISH_EXACT))
        if not rej.any() or q.shape[1] == 0 or l.shape[1] == 0:
            break
        idx = todo[rej]
        Axs = xs_[rej] @ pd.A.T
        yr = ys_[rej]
        lw, uw, eqr = low[idx], upp[idx], eq[idx]
        scale = np.maximum(1.0, np.abs(Axs))
        v_low = np.where(np.isfinite(ls[idx]) & ~lw, (ls[idx] - Axs) / scale, 0.0)
        v_upp = np.where(np.isfinite(us[idx]) & ~uw, (Axs - us[idx]) / scale, 0.0)
        w_low = np.where(lw & ~eqr, yr, 0.0)
        w_upp = np.where(uw, -yr, 0.0)
        rows = np.arange(idx.size)
        new_low, new_upp = lw.copy(), uw.copy()
        viol = np.maximum(v_low, v_upp)
        j = np.argmax(viol, axis=1)
        add = viol[rows, j] > 1e-12
        to_low = add & (v_low[rows, j] >= v_upp[rows, j])
        to_upp = add & ~to_low
        new_low[rows[to_low], j[to_low]] = True
        new_upp[rows[to_low], j[to_low]] = False
        new_upp[rows[to_upp], j[to_upp]] = True
        new_low[rows[to_upp], j[to_upp]] = False
        wrong = np.maximum(w_low, w_upp)
        wrong[rows[add], j[add]] = 0.0  # never drop the row just added
        k = np.argmax(wrong, axis=1)
        drop = wrong[rows, k] > 0.0
        new_low[rows[drop], k[drop]] = False
        new_upp[rows[drop], k[drop]] = False
        changed = add | drop
        low[idx], upp[idx] = new_low, new_upp
        todo = idx[changed]
    return accepted, xo, yo, prim_o, dual_o


# ------------------------------------------------------------------------------ the backend
class ADMMBackend(Backend):
    """Batched ADMM backend (see the module docstring)."""

    name = "admm"
    detects_infeasibility = True

    def __init__(self) -> None:
        self._factors: dict[tuple, tuple[ADMMFactor, _PolishData | None]] = {}

    # -- caching of the host-side precomputation per (P, A, row masks, settings)
    def _factor(self, P, A, eq, free, s: ADMMSettings, need_polish: bool):
        h = hashlib.blake2b(digest_size=16)
        for arr in (P, A, eq, free):
            h.update(np.ascontiguousarray(arr).tobytes())
            h.update(str(arr.shape).encode())
        key_s = s.replace(polish=False, fallback=None, eps_abs=0.0, eps_rel=0.0)
        key = (h.hexdigest(), key_s)
        hit = self._factors.get(key)
        if hit is None:
            f = admm_factor(P, A, key_s, eq_rows=eq, free_rows=free)
            hit = (f, None)
            if len(self._factors) > 16:
                self._factors.pop(next(iter(self._factors)))
            self._factors[key] = hit
        f, pd = hit
        if need_polish and pd is None:
            pd = _polish_data(P, A, s, f.D, f.E, f.c)
            self._factors[key] = (f, pd)
        # the tolerances are not baked into the factor arrays: swap the settings in
        return ADMMFactor(*f.tree_flatten()[0], settings=s.replace(polish=False, fallback=None)), pd

    def solve(self, qp: QP, *, warm_start: Solution | None = None, **settings: Any) -> Solution:
        batch = QPBatch(qp.P, qp.A, qp.q[None], qp.l[None], qp.u[None])
        ws = None
        if warm_start is not None:
            ws = BatchSolution.stack([warm_start], self.name, 0.0)
        sol = self.solve_batch(batch, warm_start=ws, **settings)
        out = sol[0]
        return dataclasses.replace(out, extras=dict(sol.extras))

    def solve_batch(
        self, batch: QPBatch, *, warm_start: BatchSolution | None = None, **settings: Any
    ) -> BatchSolution:
        s = ADMMSettings.from_kwargs(**settings)
        if s.dtype == "float64":
            with jax.enable_x64(True):
                return self._solve_batch(batch, warm_start, s)
        return self._solve_batch(batch, warm_start, s)

    def _solve_batch(self, batch: QPBatch, warm_start, s: ADMMSettings) -> BatchSolution:
        t0 = time.perf_counter()
        P, A = batch.dense()
        P = np.asarray(P, np.float64)
        A = np.asarray(A, np.float64).reshape(batch.m, batch.n)
        if batch.n > DENSE_N_WARN:
            warnings.warn(
                f"admm densifies P and A and stores (n, n) inverses per rho rung; n = {batch.n} "
                f"is above {DENSE_N_WARN}: expect large memory use; a sparse backend (osqp, "
                "clarabel) is likely better", stacklevel=3)
        q, l, u = batch.q, batch.l, batch.u
        eq, free = rows_from_bounds(l, u)
        factor, pd = self._factor(P, A, eq, free, s, s.polish)
        t_factor = time.perf_counter() - t0
        B, n, m = len(batch), batch.n, batch.m
        x = np.zeros((B, n))
        y = np.zeros((B, m))
        if warm_start is not None:
            x = np.nan_to_num(np.asarray(warm_start.x, float), nan=0.0, posinf=0.0, neginf=0.0)
            y = np.nan_to_num(np.asarray(warm_start.y, float), nan=0.0, posinf=0.0, neginf=0.0)
        z = np.zeros((B, m))
        rho = np.full(B, s.rho)
        status = np.full(B, _MAX_ITER, np.int32)
        admm_status = status.copy()
        iters = np.zeros(B, np.int64)
        polished = np.zeros(B, bool)
        stage = s.max_iter if s.stage_iter is None else max(s.check_every, int(s.stage_iter))
        todo = np.arange(B)
        done_iter = 0
        t_iter = t_pol = flops = 0.0
        rung_mm = iters_run = attempted = 0
        first = True
        while todo.size and (first or done_iter < s.max_iter):
            first = False
            k = min(stage, s.max_iter - done_iter)
            Bs = todo.size if todo.size == B else min(B, 1 << (todo.size - 1).bit_length())
            sub = np.concatenate([todo, np.repeat(todo[:1], Bs - todo.size)])  # padded
            t1 = time.perf_counter()
            st = _admm_iterate_jit(factor, q[sub], l[sub], u[sub], x[sub], y[sub], iters=k,
                                   rho0=rho[sub])
            st = jax.tree_util.tree_map(np.asarray, st)
            t_iter += time.perf_counter() - t1
            r = slice(0, todo.size)
            x[todo] = st.x[r]
            y[todo] = st.y[r]
            z[todo] = st.z[r]
            rho[todo] = st.rho[r]
            iters[todo] += st.iterations[r]
            stt = st.status[r].astype(np.int32)
            admm_status[todo] = stt
            status[todo] = stt
            it_s = int(st.iterations.max(initial=0))
            iters_run += it_s
            rung_mm += int(st.rung_matmuls)
            flops += _flops(n, m, Bs, it_s, int(st.rung_matmuls), s.check_every)
            done_iter += k
            # float64 re-check of what the iteration dtype declared solved
            ok64, *_ = _termination(P, A, q[todo], l[todo], u[todo], x[todo], y[todo], s)
            status[todo[(stt == _SOLVED) & ~ok64]] = int(Status.SOLVED_INACCURATE)
            t2 = time.perf_counter()
            if s.polish:
                cand = todo[~np.isin(stt, (_PINF, _DINF, _ERROR))]
                if cand.size:
                    acc, xp, yp, _, _ = polish(
                        pd, P, A, q[cand], l[cand], u[cand], x[cand], z[cand], y[cand], s)
                    ids = cand[acc]
                    x[ids], y[ids] = xp[acc], yp[acc]
                    status[ids] = _SOLVED
                    polished[ids] = True
                    attempted += int(cand.size)
            t_pol += time.perf_counter() - t2
            # only QPs that ran out of iterations and were not polished go on
            todo = todo[(stt == _MAX_ITER) & ~polished[todo]]
        extras: dict[str, Any] = {
            "admm_status_counts": _counts(admm_status),
            "iterations_run": iters_run,
            "rung_matmuls": rung_mm,
            "flops": flops,
            "rho": rho,
            "time_factor": t_factor,
            "time_iterations": t_iter,
            "time_polish": t_pol,
            "polished": polished,
        }
        if s.polish:
            extras["polish_attempted"] = attempted
            extras["polish_accepted"] = int(polished.sum())
        st = None
        fb = 0
        if s.fallback == "clarabel":
            from .clarabel_ import ClarabelBackend

            need = np.flatnonzero(~np.isin(status, (_SOLVED, _PINF, _DINF)))
            cb = ClarabelBackend()
            for i in need:
                r = cb.solve(batch[i])
                if r.status in (Status.SOLVED, Status.PRIMAL_INFEASIBLE, Status.DUAL_INFEASIBLE):
                    x[i], y[i], status[i] = r.x, r.y, int(r.status)
                    fb += 1
            extras["fallback_attempted"] = int(need.size)
        extras["fallback_count"] = fb
        total = time.perf_counter() - t0
        finite = np.all(np.isfinite(x), axis=1)
        status[~finite] = _ERROR
        xs = np.where(finite[:, None], x, 0.0)
        obj = np.where(finite, batch.objective(xs), np.nan)
        prim = np.where(finite, batch.constraint_violation(xs), np.nan)
        yfin = np.all(np.isfinite(y), axis=1)
        dual = np.where(finite & yfin, batch.dual_residual(xs, np.where(yfin[:, None], y, 0.0)),
                        np.nan)
        B = len(batch)
        return BatchSolution(
            x=x, y=y, status=status, objective=obj,
            iterations=iters,
            solve_time=np.full(B, total / B), primal_residual=prim, dual_residual=dual,
            backend=self.name, total_time=total, settings=s.as_dict(), extras=extras,
        )


def _counts(status: np.ndarray) -> dict[str, int]:
    vals, cnt = np.unique(np.asarray(status), return_counts=True)
    return {Status(int(v)).name: int(c) for v, c in zip(vals, cnt, strict=True)}


def make_backend() -> Backend:
    return ADMMBackend()
