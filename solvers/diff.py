"""Host-side derivatives of a solved QP: :func:`vjp` (NumPy/SciPy, sparse-aware).

For ``min ½xᵀPx + qᵀx  s.t.  l ≤ Ax ≤ u`` solved by any backend, :func:`vjp` returns the gradient
of ``dx · x*`` with respect to ``P, q, A, l, u`` by implicit differentiation of the KKT conditions
at the returned primal–dual point ``(sol.x, sol.y)``: one solve with the reduced KKT matrix

    K = [[P, Aᵀ S], [S A, −(I − S)]],       K (w_x, w_y) = (dx, 0),

then ``∂/∂q = −w_x``, ``∂/∂P = −½(w_x xᵀ + x w_xᵀ)``, ``∂/∂A = −(y w_xᵀ + w_y xᵀ)``,
``∂/∂l = W_l w_y``, ``∂/∂u = W_u w_y``.  The conventions are those of :mod:`solvers.jax` (the JAX
layer computes the same numbers): row ``i`` is active at its lower bound when ``y_i < −τ``, at its
upper bound when ``y_i > τ`` (``τ = active_tol · max(1, ‖y‖∞)``), and in both cases only if it is
at that bound (its slack relative to ``max(1, |bound|, (|A||x|)_i)`` at most ``|y_i| / max(1,
‖y‖∞)``, plus ten times the solution's own bound violation); equality rows are always active,
their sensitivity going to ``l`` or ``u`` by the sign of ``y_i`` (half to each when ``|y_i| ≤ τ``);
weakly active rows count as inactive (a one-sided derivative; an interior-point backend's ``y_i``
there is of the order of its barrier's ``√μ``, so solve tightly, e.g. ``eps_abs=1e-10``, or
polish); a QP that is not ``SOLVED`` gets NaN gradients.  Linearly dependent active rows make
``K`` singular: it is solved with a proximal ``−ε`` on the active rows' diagonal and one
refinement step (the gradients in ``P, q`` are then those of ``x*``; those in ``l, u, A`` are one
of the non-unique splits between the dependent rows).

``sol.y`` is in OSQP's sign convention (``Px + q + Aᵀy = 0``, ``y ≥ 0`` at upper bounds): every
backend of :mod:`solvers` returns it so (Clarabel's cone duals, cvxpy's per-constraint duals and
qpsolvers' ``(z, y)`` are mapped onto the rows of ``A`` by the backend), and :func:`vjp` refuses a
``y`` that only fits the opposite sign.

Sparse ``P`` or ``A`` give a sparse KKT matrix (SuperLU; a dense LU below
``DENSE_KKT_MAX = 200`` rows, where it is faster) and sparse gradients on the sparsity pattern of
``P`` and ``A`` (the derivative with respect to an entry that is structurally zero is
not formed); dense inputs give dense gradients.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .problem import QP
from .solution import Status

__all__ = ["QPGrad", "vjp", "DENSE_KKT_MAX"]

#: a sparse QP whose KKT system has at most this many rows (``n + m``) is solved densely (LAPACK
#: beats building and factoring a SciPy sparse matrix at these sizes); the gradients stay sparse
DENSE_KKT_MAX = 200


class QPGrad(NamedTuple):
    """Gradients of a scalar ``dx · x*`` with respect to the data of a :class:`solvers.QP`.

    ``P`` (symmetric) and ``A`` are dense arrays, or ``scipy.sparse`` CSC matrices on the pattern
    of the QP's own ``P`` and ``A`` when those are sparse; ``q (n,)``, ``l, u (m,)``.
    """

    P: Any
    q: np.ndarray
    A: Any
    l: np.ndarray
    u: np.ndarray


def _active(y: np.ndarray, l: np.ndarray, u: np.ndarray, active_tol: float, Ax=None, size=None):
    """Active rows, as in :func:`solvers.jax._active_set` (with ``Ax``, ``size = |A||x|``: a side
    also has to be at its bound, its relative slack at most its relative multiplier plus ten
    times the solution's own bound violation)."""
    ymax = max(1.0, float(np.max(np.abs(y), initial=0.0)))
    tau = active_tol * ymax
    fin_l, fin_u = np.isfinite(l), np.isfinite(u)
    eq = fin_l & (l == u)
    lo, up = y < -tau, y > tau
    if Ax is not None:
        lf, uf = np.where(fin_l, l, 0.0), np.where(fin_u, u, 0.0)
        viol = np.where(fin_l, np.maximum(lf - Ax, 0.0), 0.0) + np.where(
            fin_u, np.maximum(Ax - uf, 0.0), 0.0
        )
        slack_tol = 10.0 * (
            float(np.max(viol, initial=0.0)) + 1e-9 * max(1.0, np.max(np.abs(Ax), initial=0.0))
        )
        yn = np.abs(y) / ymax
        lo = (
            lo & fin_l & (Ax - lf <= yn * np.maximum(np.maximum(1.0, np.abs(lf)), size) + slack_tol)
        )
        up = (
            up & fin_u & (uf - Ax <= yn * np.maximum(np.maximum(1.0, np.abs(uf)), size) + slack_tol)
        )
    zero = ~(lo | up)
    a = (lo | up | eq).astype(np.float64)
    wl = np.where(lo, 1.0, np.where(eq & zero, 0.5, 0.0))
    wu = np.where(up, 1.0, np.where(eq & zero, 0.5, 0.0))
    return a, wl, wu


def _nan_grad(qp: QP) -> QPGrad:
    def mat(M: Any) -> Any:
        if sp.issparse(M):
            out = sp.csc_matrix(M, dtype=np.float64, copy=True)
            out.data[:] = np.nan
            return out
        return np.full(np.shape(M), np.nan)

    nan = lambda k: np.full(k, np.nan)  # noqa: E731
    return QPGrad(mat(qp.P), nan(qp.n), mat(qp.A), nan(qp.m), nan(qp.m))


def _on_pattern(M: Any, left: list[np.ndarray], right: list[np.ndarray], scale: float) -> Any:
    """``scale · Σ left_k right_kᵀ``: dense, or on the sparsity pattern of a sparse ``M``."""
    if not sp.issparse(M):
        return scale * sum(np.outer(a, b) for a, b in zip(left, right, strict=True))
    C = sp.coo_matrix(M)
    vals = scale * sum(a[C.row] * b[C.col] for a, b in zip(left, right, strict=True))
    return sp.csc_matrix((vals, (C.row, C.col)), shape=C.shape)


def vjp(qp: QP, sol: Any, dx: Any, *, active_tol: float = 1e-6) -> QPGrad:
    """Gradient of ``dx · x*`` with respect to ``P, q, A, l, u`` at a backend's solution.

    Parameters
    ----------
    qp : the :class:`solvers.QP` that was solved.
    sol : its :class:`solvers.Solution` (any backend; ``sol.x``, ``sol.y``, ``sol.status`` are
        read).  Not ``SOLVED``, or without finite duals: every gradient entry is NaN.
    dx : (n,) the cotangent of ``x*`` (e.g. ``∂loss/∂x``).
    active_tol : relative threshold on ``|y_i|`` for a row to be active (see the module docstring).

    Returns
    -------
    QPGrad
        ``(P, q, A, l, u)`` gradients; see :class:`QPGrad` for dense/sparse.
    """
    if not isinstance(qp, QP):
        raise ValueError(f"qp must be a solvers.QP, got {type(qp).__name__}")
    for attr in ("x", "y", "status"):
        if not hasattr(sol, attr):
            raise ValueError(
                f"sol must be a solvers.Solution (with .{attr}), got {type(sol).__name__}"
            )
    if isinstance(active_tol, bool) or not (
        isinstance(active_tol, (int, float, np.floating)) and 0.0 <= active_tol < 1.0
    ):
        raise ValueError(f"active_tol must be a number in [0, 1), got {active_tol!r}")
    n, m = qp.n, qp.m
    g = np.asarray(dx, dtype=np.float64)
    if g.shape != (n,) or not np.all(np.isfinite(g)):
        raise ValueError(f"dx must be a finite array of shape ({n},), got shape {g.shape}")
    x = np.asarray(sol.x, dtype=np.float64).reshape(-1)
    y = np.asarray(sol.y, dtype=np.float64).reshape(-1)
    if x.shape != (n,) or y.shape != (m,):
        raise ValueError(
            f"sol does not match qp: sol.x has shape {x.shape} (expected ({n},)), "
            f"sol.y {y.shape} (expected ({m},))"
        )
    if Status(int(sol.status)) is not Status.SOLVED or not (
        np.all(np.isfinite(x)) and np.all(np.isfinite(y))
    ):
        return _nan_grad(qp)
    P, A = qp.P, qp.A
    if m:
        # OSQP's sign convention, as every backend returns it: refuse the opposite one
        base = P @ x + qp.q
        r_plus = np.max(np.abs(base + A.T @ y))
        r_minus = np.max(np.abs(base - A.T @ y))
        if r_minus < 1e-3 * r_plus and r_plus > 1e-6 * max(1.0, np.max(np.abs(base))):
            raise ValueError(
                "sol.y fits Px + q − Aᵀy = 0: pass duals in OSQP's convention "
                "(Px + q + Aᵀy = 0, y ≥ 0 at upper bounds), as solvers' backends return them"
            )
    Ax = np.asarray(A @ x, np.float64).reshape(-1)
    size = np.asarray(abs(A) @ np.abs(x), np.float64).reshape(-1)
    a, wl, wu = _active(y, qp.l, qp.u, active_tol, Ax, size)
    rhs = np.concatenate([g, np.zeros(m)])
    # a proximal −ε on the active rows' diagonal keeps K nonsingular when active rows are
    # linearly dependent; one refinement step against K itself (as in the JAX layer)
    if qp.is_sparse and n + m > DENSE_KKT_MAX:
        Ps, As = sp.csc_matrix(P), sp.csc_matrix(A)
        K = sp.bmat([[Ps, As.T @ sp.diags(a)], [sp.diags(a) @ As, sp.diags(a - 1.0)]], format="csc")
        eps = 1e-12 * max(1.0, float(np.max(np.abs(K.data), initial=0.0)))
        reg = sp.diags(np.concatenate([np.zeros(n), a * eps]))
        try:
            solve_reg = spla.splu(sp.csc_matrix(K - reg)).solve
        except RuntimeError:  # singular beyond the proximal term
            return _nan_grad(qp)
    else:
        Pd, Ad = (np.asarray(v, np.float64) for v in qp.dense())
        K = np.block([[Pd, Ad.T * a[None, :]], [a[:, None] * Ad, np.diag(a - 1.0)]])
        eps = 1e-12 * max(1.0, float(np.max(np.abs(K), initial=0.0)))
        try:
            lu = sla.lu_factor(K - np.diag(np.concatenate([np.zeros(n), a * eps])))
        except (np.linalg.LinAlgError, sla.LinAlgError):
            return _nan_grad(qp)
        solve_reg = lambda r: sla.lu_solve(lu, r)  # noqa: E731
    w = solve_reg(rhs)
    w = w + solve_reg(rhs - K @ w)
    if not np.all(np.isfinite(w)):
        return _nan_grad(qp)
    wx, wy = w[:n], w[n:]
    gP = _on_pattern(P, [wx, x], [x, wx], -0.5)
    gA = _on_pattern(A, [y, wy], [wx, x], -1.0)
    return QPGrad(P=gP, q=-wx, A=gA, l=wl * wy, u=wu * wy)
