"""Generic test/benchmark problems (no vehicles here: just boxes and finite differences).

:func:`projection_like_batch` builds the shape of QP that trajectory projection produces: project a
target sequence onto box bounds on the values, on their first and second differences, with
boundary equalities at the start.  ``n = horizon`` variables and ``m = 3·horizon`` rows for the
default horizon (value, first-difference, second-difference rows plus three boundary rows).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .problem import QP, QPBatch

__all__ = ["projection_like_batch", "random_feasible_qp"]


def _difference_matrix(n: int, order: int) -> np.ndarray:
    D = np.eye(n)
    for _ in range(order):
        D = D[1:] - D[:-1]
    return D


def projection_like_batch(
    batch_size: int = 1000,
    horizon: int = 100,
    *,
    seed: int = 0,
    dt: float = 0.15,
    smooth_weight: float = 0.0,
) -> QPBatch:
    """A batch of projection-like QPs sharing ``P`` and ``A``.

    Each problem projects a noisy, partly infeasible target ``t`` (a random smooth sequence) onto
    ``lo ≤ x ≤ hi`` (values), ``|Δx| ≤ v_max·dt`` (first differences), ``|Δ²x| ≤ a_max·dt²``
    (second differences) and ``x₀ = 0, x₁ − x₀ = v₀·dt, x₂ − 2x₁ + x₀ = 0`` (boundary
    equalities): ``min ½‖x − t‖² (+ ½·w‖Δ²x‖²)``.  Bounds differ per problem.
    """
    if batch_size < 1 or horizon < 4:
        raise ValueError("batch_size must be ≥ 1 and horizon ≥ 4")
    rng = np.random.default_rng(seed)
    n = horizon
    D1, D2 = _difference_matrix(n, 1), _difference_matrix(n, 2)
    P = np.eye(n) + smooth_weight * D2.T @ D2
    E = np.zeros((3, n))
    E[0, 0] = 1.0
    E[1, :2] = [-1.0, 1.0]
    E[2, :3] = [1.0, -2.0, 1.0]
    A = np.vstack([np.eye(n), D1, D2, E])
    t = np.linspace(0.0, 1.0, n)
    qs, ls, us = [], [], []
    for _ in range(batch_size):
        v0 = rng.uniform(2.0, 8.0)
        v_max = rng.uniform(8.0, 12.0)
        a_max = rng.uniform(1.5, 4.0)
        base = v0 * dt * np.arange(n)
        wiggle = sum(
            rng.normal(0, 3.0) * np.sin((k + 1) * np.pi * t + rng.uniform(0, np.pi))
            for k in range(4)
        )
        target = base + wiggle + rng.normal(0, 0.3, n)
        hi_pos = base[-1] * rng.uniform(0.7, 1.0) + 5.0
        lo_pos = -rng.uniform(0.5, 2.0)
        l = np.concatenate(
            [
                np.full(n, lo_pos),
                np.full(n - 1, -0.2 * dt),  # nearly no reversing
                np.full(n - 2, -a_max * dt * dt),
                [0.0, v0 * dt, 0.0],
            ]
        )
        u = np.concatenate(
            [
                np.full(n, hi_pos),
                np.full(n - 1, v_max * dt),
                np.full(n - 2, a_max * dt * dt),
                [0.0, v0 * dt, 0.0],
            ]
        )
        qs.append(-target)
        ls.append(l)
        us.append(u)
    return QPBatch(P, A, np.array(qs), np.array(ls), np.array(us))


def random_feasible_qp(
    n: int,
    m_ineq: int,
    m_eq: int,
    *,
    seed: int = 0,
    sparse: bool = False,
    psd_rank: int | None = None,
) -> QP:
    """A random convex QP that is feasible and bounded (a strictly feasible point is built in)."""
    rng = np.random.default_rng(seed)
    r = n if psd_rank is None else psd_rank
    M = rng.normal(size=(n, r))
    P = M @ M.T + 1e-2 * np.eye(n)
    q = rng.normal(size=n)
    x0 = rng.normal(size=n)
    G = rng.normal(size=(m_ineq, n))
    Aeq = rng.normal(size=(m_eq, n))
    slack = rng.uniform(0.1, 1.0, m_ineq)
    lo = np.where(rng.random(m_ineq) < 0.5, -np.inf, G @ x0 - slack)
    hi = np.where(rng.random(m_ineq) < 0.3, np.inf, G @ x0 + slack)
    A = np.vstack([G, Aeq])
    l = np.concatenate([lo, Aeq @ x0])
    u = np.concatenate([hi, Aeq @ x0])
    if sparse:
        return QP(sp.csc_matrix(P), q, sp.csc_matrix(A), l, u)
    return QP(P, q, A, l, u)
