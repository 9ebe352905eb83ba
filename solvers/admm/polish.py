"""Batched active-set polish of ADMM iterates (NumPy, float64), and the float64 termination test.

The active set is guessed from ``(z, y)``; the reduced KKT system is solved by a Schur complement
on the shared ``(P + δI)⁻¹`` with the per-QP active rows gathered and padded to the batch's largest
active count, with iterative refinement; a few primal-dual active-set passes repair wrong guesses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from .core import ADMMSettings, spd_inverse

__all__ = ["PolishData", "active_guess", "polish", "polish_data", "termination"]

#: polish keeps repairing the active set until the residuals are this fraction of the tolerance
_POLISH_EXACT = 1e-3


# ------------------------------------------------------------------------ polish (NumPy f64)
@dataclass(frozen=True, eq=False)
class PolishData:
    P: np.ndarray  # (n, n) scaled, float64
    A: np.ndarray  # (m, n) scaled
    Hinv: np.ndarray  # (P̄ + δI)⁻¹
    S: np.ndarray  # Ā Hinv Āᵀ  (m, m)
    D: np.ndarray
    E: np.ndarray
    c: float


def polish_data(P: np.ndarray, A: np.ndarray, s: ADMMSettings, D, E, c) -> PolishData:
    D, E, c = np.asarray(D, float), np.asarray(E, float), float(c)
    Ps = c * D[:, None] * P * D[None, :]
    As = E[:, None] * A * D[None, :]
    H = Ps + s.polish_delta * np.eye(P.shape[0])
    Hinv = spd_inverse(H)
    Hinv = 0.5 * (Hinv + Hinv.T)
    S = As @ Hinv @ As.T
    return PolishData(Ps, As, Hinv, 0.5 * (S + S.T), D, E, c)


def termination(P, A, q, l, u, x, y, s: ADMMSettings):
    """Unscaled OSQP test for (x, y) with z = Π(Ax), duality gap included (OSQP 1.x's
    ``check_dualgap``: ``|xᵀPx + qᵀx + S(y)| ≤ eps_abs + eps_rel·max(|xᵀPx|, |qᵀx|, |S(y)|)``), in
    float64: what ``Solution.is_optimal(eps_abs, eps_rel)`` checks.  Returns ``(ok, prim, dual,
    eps_p, eps_d)``."""
    Ax = x @ A.T
    z = np.clip(Ax, l, u)
    Px = x @ P
    Aty = y @ A
    prim = np.abs(Ax - z).max(axis=1, initial=0.0)
    dual = np.abs(Px + q + Aty).max(axis=1, initial=0.0)
    supp = np.sum(
        np.where(np.isfinite(u), u, 0.0) * np.maximum(y, 0.0)
        + np.where(np.isfinite(l), l, 0.0) * np.minimum(y, 0.0),
        axis=1,
    )
    xPx, qx = np.einsum("bi,bi->b", x, Px), np.einsum("bi,bi->b", q, x)
    gap = np.abs(xPx + qx + supp)
    eps_g = s.eps_abs + s.eps_rel * np.maximum.reduce([np.abs(xPx), np.abs(qx), np.abs(supp)])
    eps_p = s.eps_abs + s.eps_rel * np.maximum(
        np.abs(Ax).max(1, initial=0.0), np.abs(z).max(1, initial=0.0)
    )
    eps_d = s.eps_abs + s.eps_rel * np.maximum.reduce(
        [
            np.abs(Px).max(1, initial=0.0),
            np.abs(Aty).max(1, initial=0.0),
            np.abs(q).max(1, initial=0.0),
        ]
    )
    with np.errstate(invalid="ignore"):
        ok = (prim <= eps_p) & (dual <= eps_d) & (gap <= eps_g)
    return ok, prim, dual, eps_p, eps_d


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
    (NumPy's batched ``inv`` is ~50× slower here).  No finiteness check: a non-finite solution
    fails the polish's own test (``np.isfinite`` on the polished iterate) and is not accepted."""
    t = sla.solve_triangular(L, b[..., None], lower=True, check_finite=False)
    return sla.solve_triangular(L, t, lower=True, trans="T", check_finite=False)[..., 0]


def _reduced_kkt(
    pd: PolishData, qs, low, upp, ls, us, s: ADMMSettings, x0=None, y0=None, chunk: int = 256
):
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


def active_guess(pd: PolishData, l, u, z, y) -> np.ndarray:
    """The active set that the polish guesses from an ADMM iterate: ``(B, m)`` int8, ``-1`` at
    a lower bound (or an equality), ``+1`` at an upper bound, ``0`` inactive.  OSQP's rule on the
    scaled problem: row ``i`` is at its lower bound when ``z̄ᵢ − l̄ᵢ < −ȳᵢ`` (Stellato et al.
    2020, §4.3), at its upper bound when ``ūᵢ − z̄ᵢ < ȳᵢ``."""
    E, c = pd.E, pd.c
    ls, us, zs, ysc = E * l, E * u, E * z, c * y / E
    eq = (ls == us) & np.isfinite(ls)
    low = ((zs - ls < -ysc) | eq) & np.isfinite(ls)
    upp = (us - zs < ysc) & np.isfinite(us) & ~low
    return np.where(low, -1, np.where(upp, 1, 0)).astype(np.int8)


def polish(
    pd: PolishData,
    P,
    A,
    q,
    l,
    u,
    x,
    z,
    y,
    s: ADMMSettings,
    passes: int | None = None,
    exact: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Batched active-set polish (float64).  Inputs unscaled ``(B, ·)``; ``passes`` (default
    ``s.polish_passes``) caps the active-set repair passes; ``exact`` accepts only points whose
    residuals are within ``1e-3`` of the tolerance (a guess with no misplaced row), as the
    backend asks after a stage that is not the last (the iterations go on for the others).

    Returns ``(accepted, x, y, prim, dual)``: where ``accepted`` the polished point passes the
    termination test (duals projected on the normal cone) — elsewhere the inputs are returned.
    """
    D, E, c = pd.D, pd.E, pd.c
    qs, ls, us = c * D * q, E * l, E * u
    ysc = c * y / E
    xsc = x / D
    eq = (ls == us) & np.isfinite(ls)
    guess = active_guess(pd, l, u, z, y)
    low, upp = guess < 0, guess > 0
    B = q.shape[0]
    accepted = np.zeros(B, bool)
    xo, yo = x.copy(), y.copy()
    _, prim0, dual0, eps_p0, eps_d0 = termination(P, A, q, l, u, x, y, s)
    score0 = np.maximum(prim0 / eps_p0, dual0 / eps_d0)
    prim_o, dual_o = prim0.copy(), dual0.copy()
    best = np.full(B, np.inf)
    todo = np.arange(B)
    for _ in range(max(1, s.polish_passes if passes is None else passes)):
        if todo.size == 0:
            break
        xs_, ys_ = _reduced_kkt(
            pd, qs[todo], low[todo], upp[todo], ls[todo], us[todo], s, x0=xsc[todo], y0=ysc[todo]
        )
        xp = D * xs_
        yp = E * ys_ / c
        # project the duals on the normal cone of the guessed active set
        lo_t, up_t, eq_t = low[todo] & ~eq[todo], upp[todo], eq[todo]
        yproj = np.where(
            eq_t, yp, np.where(lo_t, np.minimum(yp, 0), np.where(up_t, np.maximum(yp, 0), 0.0))
        )
        ok, prim, dual, eps_p, eps_d = termination(P, A, q[todo], l[todo], u[todo], xp, yproj, s)
        ok &= np.all(np.isfinite(xp), axis=1) & np.all(np.isfinite(yproj), axis=1)
        score = np.where(ok, np.maximum(prim / eps_p, dual / eps_d), np.inf)
        # better than the ADMM iterate and than any earlier pass, and no further outside the
        # bounds than that iterate (a point exact to 1e-3 of the tolerance aside): on a
        # near-degenerate corner a guess with one misplaced row can trade a smaller dual
        # residual for a larger violation, still within a relative tolerance of metre-scale rows
        better = ok & (score <= np.maximum(score0[todo], 1.0)) & (score < best[todo])
        better &= prim <= np.maximum(prim0[todo], _POLISH_EXACT * eps_p)
        if exact:
            better &= score <= _POLISH_EXACT
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
