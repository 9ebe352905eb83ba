"""OSQP's modified Ruiz equilibration of a QP's KKT matrix, written once for NumPy and JAX.

:func:`ruiz_equilibrate` returns ``D (n,)``, ``E (m,)`` and ``c`` such that the scaled problem
``P̄ = c·D P D``, ``Ā = E A D``, ``q̄ = c·D q``, ``l̄ = E l``, ``ū = E u`` has a KKT matrix
``[[P̄, Āᵀ], [Ā, 0]]`` whose rows and columns have ∞-norms near 1 (Stellato et al. 2020, §5.1).
The ``ipm`` and ``admm`` backends call it on the host with ``xp=numpy`` (float64), and
:func:`solvers.jax.solve_qp` inside a trace with ``xp=jax.numpy``, so every solver scales a QP
by the same arithmetic.

Each pass divides every column of the KKT matrix by the square root of its ∞-norm (rows of
``A`` likewise), a norm below ``1e-4`` counting as 1 and every factor clipped to
``[1e-4, 1e4]``; then the cost is scaled by ``1 / mean_j ‖P̄_{:, j}‖∞`` (clipped likewise, 1 when
that mean is below ``1e-4``).  The cost scaling reads ``P`` only: ``q`` differs per QP of a batch
while the scaling is shared.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["ruiz_equilibrate"]

#: norms below this count as 1; every scaling factor is clipped to [_LO, _HI]
_LO, _HI = 1e-4, 1e4


def _check(P: Any, A: Any, iters: Any, xp: Any) -> None:
    if getattr(xp, "__name__", None) not in ("numpy", "jax.numpy"):
        raise ValueError(f"xp must be the module numpy or jax.numpy, got {xp!r}")
    for name, M in (("P", P), ("A", A)):
        if not (hasattr(M, "shape") and hasattr(M, "dtype")):
            raise ValueError(f"{name} must be an array, got {type(M).__name__}")
        if len(M.shape) != 2:
            raise ValueError(f"{name} must be a 2-D array, got shape {tuple(M.shape)}")
        if not np.issubdtype(M.dtype, np.floating):
            raise ValueError(f"{name} must have a floating dtype, got {M.dtype}")
    n = P.shape[0]
    if P.shape != (n, n):
        raise ValueError(f"P must be square, got shape {tuple(P.shape)}")
    if A.shape[1] != n:
        raise ValueError(f"A must have shape (m, {n}), got {tuple(A.shape)}")
    if A.dtype != P.dtype:
        raise ValueError(f"A must have P's dtype {P.dtype}, got {A.dtype}")
    if isinstance(iters, bool) or not isinstance(iters, (int, np.integer)) or iters < 0:
        raise ValueError(f"iters must be an integer ≥ 0, got {iters!r}")


def ruiz_equilibrate(P: Any, A: Any, iters: int, xp: Any = np) -> tuple[Any, Any, Any]:
    """``(D, E, c)``: ``iters`` passes of modified Ruiz equilibration of ``[[P, Aᵀ], [A, 0]]``
    plus a cost scaling (see the module docstring for the rule).

    Parameters
    ----------
    P : (n, n) floating array (only its entries' magnitudes are read; not modified).
    A : (m, n) floating array of ``P``'s dtype; ``m`` may be 0.
    iters : number of passes, ≥ 0 (0 gives ``D = 1``, ``E = 1``, ``c = 1``).
    xp : the array namespace, ``numpy`` (default) or ``jax.numpy``.  With ``jax.numpy`` the
        function is traceable (``jit``, ``vmap``); shapes and ``iters`` are static.

    Returns
    -------
    tuple
        ``D (n,)`` and ``E (m,)`` arrays of ``P``'s dtype and the cost scale ``c``: a Python
        ``float`` with NumPy, a 0-d array with ``jax.numpy``.
    """
    host = getattr(xp, "__name__", None) == "numpy"
    if host:
        P, A = np.asarray(P), np.asarray(A)
    _check(P, A, iters, xp)
    n, m = P.shape[0], A.shape[0]
    dt = P.dtype
    D, E, c = xp.ones(n, dt), xp.ones(m, dt), xp.ones((), dt)
    Ps, As = P, A
    lo, hi = _LO, _HI
    for _ in range(int(iters)):
        cn = xp.maximum(
            xp.max(xp.abs(Ps), axis=0, initial=0.0), xp.max(xp.abs(As), axis=0, initial=0.0)
        )
        rn = xp.max(xp.abs(As), axis=1, initial=0.0)
        dD = xp.clip(1.0 / xp.sqrt(xp.where(cn < lo, 1.0, cn)), lo, hi)
        dE = xp.clip(1.0 / xp.sqrt(xp.where(rn < lo, 1.0, rn)), lo, hi)
        Ps = dD[:, None] * Ps * dD[None, :]
        As = dE[:, None] * As * dD[None, :]
        D, E = D * dD, E * dE
        # cost scaling from P only (q differs per QP, the scaling is shared); no columns: 1
        pn = xp.mean(xp.max(xp.abs(Ps), axis=0, initial=0.0)) if n else xp.zeros((), dt)
        g = xp.clip(xp.where(pn >= lo, 1.0 / xp.where(pn >= lo, pn, 1.0), 1.0), lo, hi)
        Ps = g * Ps
        c = c * g
    if host:
        return D, E, float(c)
    return D, E, c
