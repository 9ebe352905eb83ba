"""The answer check: every backend's answer is checked against the problem it solves.

:func:`solvers.solve` and :func:`solvers.solve_batch` pass every answer, whatever backend gave it,
through :func:`check_solution` / :func:`check_batch_solution` before returning it.  A status is
only ever made *weaker* by the check (never upgraded), and every change says why in
``sol.extras["check"]``.

Optimality (answers reported ``SOLVED`` or ``SOLVED_INACCURATE``), in float64 on the problem as
given, with ``eps = max(eps_abs, eps_rel, EPS_FLOOR)`` from the backend's stated tolerance
(:meth:`~solvers.base.Backend.stated_tolerance`).  Every test has an absolute floor, in OSQP's
manner: a residual ``r`` with ``scale`` the largest of the terms it sums passes at ``k·eps`` when
``r ≤ k·eps + k·eps·scale``, i.e. its *relative residual* ``r / (1 + scale)`` is ``≤ k·eps``.
Without the floor a point whose terms are all near zero (``x = 0`` on the bounds, multipliers of
``1e-10``) is held to ``r / scale``, about 1 whatever the accuracy.

* primal, row-normalised: each row ``a_i`` of ``A`` and its bounds are divided by ``‖a_i‖∞``;
  the violation ``max(0, l̃_i − ã_i x, ã_i x − ũ_i)`` of each row, with ``scale`` the largest of
  ``|l̃_i|``, ``|ũ_i|`` and ``|ã_i|·|x|`` (finite bounds only; ``|ã_i|·|x| ≥ |ã_i x|`` is the size
  of the terms summed, so a row whose terms cancel is not held to less than their rounding);
  ``primal`` is the largest.  A row scaled by ``1e-8`` is thus held to the same accuracy as the
  unscaled row; a residual of ``3e26`` on a row ``= 3e26`` is a relative residual of 1, not
  "small next to the data".
* dual: ``‖Px + q + Aᵀy‖∞`` with ``scale = max(‖|P||x|‖∞, ‖q‖∞, ‖|Aᵀ||y|‖∞)`` (the sizes of the
  terms summed, which bound ``‖Px‖∞`` and ``‖Aᵀy‖∞`` and are not zero where those cancel to
  rounding, e.g. at Maros–Meszaros TAME's optimum ``Px = 0``), after dropping multipliers of the
  wrong sign for an infinite side (``y_i > 0`` with ``u_i = +∞``, ``y_i < 0`` with ``l_i = −∞``),
  so a multiplier that cannot exist shows up here.
* gap: ``|xᵀPx + qᵀx + S(y)|`` (primal minus dual objective, ``S(y) = Σ u_i y_i⁺ + l_i y_i⁻``)
  less ``|x|ᵀ|Px + q + Aᵀy|``, the part the dual residual already explains (on a degenerate LP
  with large ``x``, a dual residual that passes can otherwise fail the gap alone), with
  ``scale`` the largest of its terms ``|x|ᵀ|P||x|``, ``Σ|q_i x_i|``, ``|x|ᵀ|Aᵀ||y|`` and
  ``Σ|u_i y_i⁺ + l_i y_i⁻|`` (the gap is ``xᵀ(Px + q + Aᵀy) + (S(y) − yᵀAx)``).
* objective gap: ``|f_primal − f_dual| / max(1, |f_primal|)`` with ``f_primal = ½xᵀPx + qᵀx``
  and ``f_dual = −½xᵀPx − S(y)``: how well the point pins the objective itself, relative to its
  size (the gap above is relative to the size of its terms, which may cancel).

Dual, gap and objective gap are checked only where the backend returned finite duals.  With
``worst`` the largest of the three relative residuals:

* ``worst ≤ SOLVED_FACTOR·eps`` (10) and objective gap ``≤ far = min(FAR_FACTOR·eps,
  FAR_MAX)`` (``1e3·eps``, at most ``0.1``): the status stands;
* ``SOLVED_FACTOR·eps < worst ≤ far``: ``SOLVED`` becomes ``SOLVED_INACCURATE``;
* ``worst`` or the objective gap beyond ``far`` (:data:`OBJECTIVE_GAP_FACTOR` is
  :data:`FAR_FACTOR`): ``MAX_ITER`` (the point is an unconverged iterate, kept for inspection);
* non-finite ``x`` or residuals: ``ERROR``.

The objective gap is held to the residuals' ``far``, not to ``10·eps``: an answer that meets its
tolerance has a gap of about ``eps`` times the largest term of the objective, which may be far
larger than the objective when the terms cancel.

What no test on ``(x, y)`` can see: an answer whose residuals are all within ``far`` may still sit
far from the optimum on an ill-conditioned problem.  OSQP at its default 1e-3 on Maros–Meszaros
QPCBOEI2 stops with a row-normalised primal residual of 0.05 and an objective gap of 1.6e-3, its
objective 12 % below the optimum; on QBANDM it stops with 0.05 and 1.9e-3, and on Q25FV47 with
0.1 and 1.6e-3, 1e-4 and 1.5e-3 from the optimum.  A bound that demoted the first would demote
the other two: only tighter settings tell them apart.  So :func:`solvers.solve` **confirms** an
answer that is ``SOLVED_INACCURATE`` after this check on a backend that honours warm starts
(:func:`confirm_inaccurate`): it solves again from that answer with ``eps_abs`` and ``eps_rel``
divided by :data:`CONFIRM_FACTOR`.  An answer the tighter solve reaches ``SOLVED`` or
``SOLVED_INACCURATE`` at the tighter tolerances is returned (with that status: it meets the
caller's tolerances).  An answer it cannot confirm (any other status) whose objective the
tighter run moved by more than ``max(eps_abs, eps_rel) · max(1, |f|)`` becomes ``MAX_ITER``, its
point kept; one it left where it was stays ``SOLVED_INACCURATE`` ("steady").
``extras["confirm"]`` records the outcome.  On QPCBOEI2 the tighter run stops at its iteration
limit with the objective moved by 4.7e-3 of its size: ``MAX_ITER``; on QBANDM and Q25FV47 it
confirms.

Infeasibility (answers reported ``PRIMAL_INFEASIBLE`` or ``DUAL_INFEASIBLE``): a certificate
must verify on the row-normalised data, normalised so ``‖·‖∞ = 1``, what must vanish to
:data:`CERT_ZERO` (rounding level) and the margin to :data:`CERT_TOL`:

* primal: ``y`` (OSQP convention) with ``‖Ãᵀỹ‖∞ ≤ CERT_ZERO`` and ``S̃(ỹ) ≤ −CERT_TOL``
  (then ``l ≤ Ax ≤ u`` has no solution: Farkas);
* dual: ``d`` with ``‖Pd‖∞ ≤ CERT_ZERO·‖P‖max``, ``qᵀd ≤ −CERT_TOL·‖q‖∞`` and ``Ãd`` in the
  recession cone of ``[l̃, ũ]`` to ``CERT_ZERO`` (the objective decreases without bound along
  ``d`` from any feasible point).

The backend's certificate is tried first (``extras["prim_inf_cert"]`` / ``["dual_inf_cert"]``);
when it has none or it fails, one is computed with a linear program (SciPy's HiGHS, independent
of the backends) and verified the same way.  A claim no certificate verifies becomes ``ERROR``
with the reason.  A certified answer has ``x``, ``y``, the objective and the residuals NaN and the
certificate in ``extras["prim_inf_cert"]`` / ``extras["dual_inf_cert"]``.

``extras["check"]`` (one problem) holds ``result`` (``"passed"``, ``"inaccurate"``,
``"far"``, ``"non-finite"``, ``"certified"``, ``"refuted"``; ``"skipped"`` for ``MAX_ITER`` /
``ERROR``), the three relative residuals and ``objective_gap``, ``eps``, ``status_before``,
where the status changed ``reason``, and for a certified claim ``certificate`` (``"backend"`` or
``"computed"``).  For a batch the same keys hold arrays over the batch (``reason``: a dict
``{index: text}``; ``certificate``: ``{index: "backend" | "computed"}``), certificates sit in
``extras["certificates"]`` (``{index: array}``), and ``sols[i]`` carries problem ``i``'s record
and certificate as a single solve does.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.sparse as sp

from .problem import QP, QPBatch
from .solution import STATUS_CODES, BatchSolution, Solution, Status

__all__ = [
    "CERT_TOL",
    "CERT_ZERO",
    "EPS_FLOOR",
    "FAR_FACTOR",
    "FAR_MAX",
    "OBJECTIVE_GAP_FACTOR",
    "SOLVED_FACTOR",
    "check_batch_solution",
    "check_solution",
    "dual_certificate",
    "optimality_residuals",
    "primal_certificate",
    "verify_dual_certificate",
    "verify_primal_certificate",
]

#: the check's ``eps`` never goes below this.  The check measures in its own metric (term sizes,
#: ∞-norms, float64 on the data as given), not in the solver's (Clarabel and OSQP equilibrate the
#: data and mix absolute and relative tests), so a solver that met 1e-8 in its metric can sit near
#: 1e-6 in this one: Clarabel at its defaults on Maros–Meszaros QSHARE1B (objective 5e-6 from the
#: published optimum) has a relative dual residual of 1.1e-6 here
EPS_FLOOR = 1e-6
#: a ``SOLVED`` stands while every relative residual is ≤ this times ``eps``
SOLVED_FACTOR = 10.0
#: beyond ``min(FAR_FACTOR·eps, FAR_MAX)`` the point is no solution at all: MAX_ITER
FAR_FACTOR = 1e3
FAR_MAX = 1e-1
#: beyond ``min(OBJECTIVE_GAP_FACTOR·eps, FAR_MAX)`` of ``max(1, |f_primal|)`` between the primal
#: and the dual objective, the objective itself is not known: MAX_ITER.  The same bound as the
#: residuals' ``far``: an answer within it is inaccurate at worst, and the residual tiers decide.
#: (100 × would be too tight: ProxQP at its defaults, 1e-5 and no gap test, returns the box QP
#: ``min ½‖x‖² + x0 − x1`` 1.3e-3 off, objective gap 130 × its tolerance, a usable inaccurate
#: answer; OSQP at its default 1e-3 is capped at 10 % either way)
OBJECTIVE_GAP_FACTOR = 1e3
#: what must vanish in a certificate normalised to ‖·‖∞ = 1 (``Ãᵀỹ``; ``Pd`` relative to
#: ``‖P‖max``; the excess of ``Ãd`` over the recession cone): rounding level.  A certificate only
#: approximately in the cone proves nothing (along ``d`` with ``dᵀPd = κ > 0`` the objective is
#: bounded, by ``(qᵀd)²/2κ``), so an iterate's δx or δy that meets a solver's 1e-4 test is not
#: enough; the linear program's certificates meet this
CERT_ZERO = 1e-9
#: the margin a certificate must show (``S̃(ỹ) ≤ −CERT_TOL``, ``qᵀd ≤ −CERT_TOL·‖q‖∞``)
CERT_TOL = 1e-6
_SOLVED_LIKE = (STATUS_CODES.SOLVED, STATUS_CODES.SOLVED_INACCURATE)
_INFEASIBLE = (STATUS_CODES.PRIMAL_INFEASIBLE, STATUS_CODES.DUAL_INFEASIBLE)


# --------------------------------------------------------------------------- pieces of data
def _row_norms(A: Any) -> np.ndarray:
    """``‖a_i‖∞`` per row, 1 for zero rows (a zero row is checked in absolute terms)."""
    if A.shape[0] == 0:
        return np.ones(0)
    if sp.issparse(A):
        r = np.asarray(abs(sp.csr_matrix(A)).max(axis=1).toarray()).reshape(-1)
    else:
        r = np.max(np.abs(np.asarray(A)), axis=1, initial=0.0)
    return np.where(r > 0, r, 1.0)


def _rows_times(A: Any, X: np.ndarray) -> np.ndarray:
    """``X @ Aᵀ`` for ``X`` (B, n): each row of ``X`` times ``A``."""
    return np.asarray((A @ X.T).T) if sp.issparse(A) else X @ np.asarray(A).T


def _times_rows(A: Any, Y: np.ndarray) -> np.ndarray:
    """``Y @ A`` for ``Y`` (B, m): ``Aᵀy`` per row of ``Y``."""
    return np.asarray((A.T @ Y.T).T) if sp.issparse(A) else Y @ np.asarray(A)


def _max_abs(M: Any) -> float:
    if sp.issparse(M):
        return float(abs(M).max()) if M.nnz else 0.0
    return float(np.max(np.abs(M), initial=0.0))


def _clean_duals(l: np.ndarray, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``y`` without multipliers of the wrong sign for an infinite side."""
    return np.where(((y > 0) & ~np.isfinite(u)) | ((y < 0) & ~np.isfinite(l)), 0.0, y)


# ------------------------------------------------------------------------------ optimality
def optimality_residuals(
    problem: QP | QPBatch, x: np.ndarray, y: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(primal, dual, gap)``: the scale-aware relative residuals of the module docstring.

    ``problem`` a :class:`QP` with ``x`` (n,), ``y`` (m,) (returns floats) or a
    :class:`QPBatch` with ``x`` (B, n), ``y`` (B, m) (returns arrays (B,)).  ``dual`` and
    ``gap`` are NaN where ``y`` is not finite; everything is NaN where ``x`` is not finite.
    """
    if not isinstance(problem, (QP, QPBatch)):
        raise ValueError(f"problem must be a solvers.QP or QPBatch, got {type(problem).__name__}")
    single = isinstance(problem, QP)
    X = np.atleast_2d(np.asarray(x, dtype=np.float64))
    Y = np.atleast_2d(np.asarray(y, dtype=np.float64))
    q, l, u = (np.atleast_2d(v) for v in (problem.q, problem.l, problem.u))
    B, n, m = X.shape[0], problem.n, problem.m
    if X.shape != (B, n) or q.shape[0] != B:
        raise ValueError(f"x has shape {np.shape(x)}, expected {(n,) if single else (B, n)}")
    if Y.shape != (B, m):
        raise ValueError(f"y has shape {np.shape(y)}, expected {(m,) if single else (B, m)}")
    primal, dual, gap, _ = _residuals(problem.P, problem.A, q, l, u, X, Y)
    if single:
        return float(primal[0]), float(dual[0]), float(gap[0])
    return primal, dual, gap


def _residuals(P: Any, A: Any, q, l, u, X: np.ndarray, Y: np.ndarray):
    """:func:`optimality_residuals` on arrays: ``q`` (B, n), ``l, u`` (B, m), ``X``, ``Y``.

    Returns ``(primal, dual, gap, objective_gap)``, each (B,): the three relative residuals
    (each ``residual / (1 + scale)``, ``scale`` the largest of the terms summed) and
    ``|f_primal − f_dual| / max(1, |f_primal|)``."""
    B, m = X.shape[0], l.shape[1]
    xfin = np.all(np.isfinite(X), axis=1)
    yfin = np.all(np.isfinite(Y), axis=1) & xfin
    Xs = np.where(xfin[:, None], X, 0.0)
    Ys = _clean_duals(l, u, np.where(yfin[:, None], Y, 0.0))
    with np.errstate(over="ignore", invalid="ignore"):
        # primal, row-normalised; scale: the largest of |l̃_i|, |ũ_i|, |ã_i|·|x| per row
        absA = abs(A) if sp.issparse(A) else np.abs(A)
        if m:
            rn = _row_norms(A)
            Ax = _rows_times(A, Xs) / rn
            absAx = _rows_times(absA, np.abs(Xs)) / rn
            ls, us = l / rn, u / rn
            viol = np.maximum(np.maximum(ls - Ax, Ax - us), 0.0)
            scale = np.maximum(
                absAx,
                np.maximum(
                    np.where(np.isfinite(ls), np.abs(ls), 0.0),
                    np.where(np.isfinite(us), np.abs(us), 0.0),
                ),
            )
            primal = np.max(viol / (1.0 + scale), axis=1)
        else:
            primal = np.zeros(B)
        # dual: scale the largest of the terms summed (their rounding scale)
        Px = _rows_times(P, Xs)
        absP = abs(P) if sp.issparse(P) else np.abs(P)
        absPx = _rows_times(absP, np.abs(Xs))
        ATy = _times_rows(A, Ys) if m else np.zeros_like(Px)
        if m:
            absATy = _times_rows(absA, np.abs(Ys))
        else:
            absATy = np.zeros_like(Px)
        rd = Px + q + ATy
        r = np.abs(rd).max(axis=1)
        d_scale = np.maximum.reduce(
            [np.abs(absPx).max(axis=1), np.abs(q).max(axis=1), np.abs(absATy).max(axis=1)]
        )
        dual = r / (1.0 + d_scale)
        # gap: written as xᵀ(Px + q + Aᵀy) + (S(y) − yᵀAx); scale the largest of its terms
        uf, lf = np.where(np.isfinite(u), u, 0.0), np.where(np.isfinite(l), l, 0.0)
        s_terms = uf * np.maximum(Ys, 0.0) + lf * np.minimum(Ys, 0.0)
        xPx = np.einsum("bi,bi->b", Xs, Px)
        qx = q * Xs
        g_raw = np.abs(xPx + qx.sum(axis=1) + s_terms.sum(axis=1))
        # less the part the dual residual explains (|xᵀ(Px + q + Aᵀy)|, held by the dual check)
        g = np.maximum(g_raw - np.einsum("bi,bi->b", np.abs(Xs), np.abs(rd)), 0.0)
        g_scale = np.maximum.reduce(
            [
                np.einsum("bi,bi->b", np.abs(Xs), absPx),
                np.abs(qx).sum(axis=1),
                np.einsum("bi,bi->b", np.abs(Xs), absATy),
                np.abs(s_terms).sum(axis=1),
            ]
        )
        gap = g / (1.0 + g_scale)
        # the objectives: primal ½xᵀPx + qᵀx minus dual −½xᵀPx − S(y), relative to the objective
        f_primal = 0.5 * xPx + qx.sum(axis=1)
        objective_gap = g_raw / np.maximum(1.0, np.abs(f_primal))
    primal = np.where(xfin, primal, np.nan)
    dual = np.where(yfin, dual, np.nan)
    gap = np.where(yfin, gap, np.nan)
    objective_gap = np.where(yfin, objective_gap, np.nan)
    return primal, dual, gap, objective_gap


def _far(eps: float) -> float:
    return float(min(FAR_FACTOR * eps, FAR_MAX))


def _objective_far(eps: float) -> float:
    return float(min(OBJECTIVE_GAP_FACTOR * eps, FAR_MAX))


def _verdict(
    status: int, primal: float, dual: float, gap: float, objective_gap: float, eps: float
) -> tuple[int, str, str]:
    """``(new status, result, reason)`` for a SOLVED/SOLVED_INACCURATE answer."""
    res = np.array([primal, dual, gap])
    names = ("primal", "dual", "gap")
    if not np.isfinite(primal) or np.any(np.isinf(res)) or np.isinf(objective_gap):
        return (
            STATUS_CODES.ERROR,
            "non-finite",
            "the returned point or its residuals are not finite",
        )
    known = res[np.isfinite(res)]
    worst = float(known.max(initial=0.0))
    far = _far(eps)
    if worst > SOLVED_FACTOR * eps and worst > far:
        which = names[int(np.nanargmax(res))]
        return (
            STATUS_CODES.MAX_ITER,
            "far",
            f"reported {Status(status).name} but the relative {which} residual is {worst:.3g} "
            f"(> {far:.3g}, far beyond the stated tolerance {eps:.3g}): an unconverged iterate",
        )
    obj_far = _objective_far(eps)
    if objective_gap > obj_far:
        return (
            STATUS_CODES.MAX_ITER,
            "far",
            f"reported {Status(status).name} but the primal and dual objectives differ by "
            f"{objective_gap:.3g} of the objective (|f_primal − f_dual| / max(1, |f_primal|) > "
            f"{obj_far:.3g}, {OBJECTIVE_GAP_FACTOR:g} × the stated tolerance {eps:.3g}): the "
            "objective is not known to that accuracy, an unconverged iterate",
        )
    if worst <= SOLVED_FACTOR * eps:
        return status, "passed", ""
    which = names[int(np.nanargmax(res))]
    if status == STATUS_CODES.SOLVED:
        return (
            STATUS_CODES.SOLVED_INACCURATE,
            "inaccurate",
            f"reported SOLVED but the relative {which} residual is {worst:.3g} "
            f"(> {SOLVED_FACTOR:g} × the stated tolerance {eps:.3g})",
        )
    return status, "inaccurate", ""


# ----------------------------------------------------------------------- certificates
def verify_primal_certificate(qp: QP, y: Any) -> tuple[bool, str]:
    """Whether ``y`` (OSQP's sign convention, shape (m,)) proves ``l ≤ Ax ≤ u`` infeasible, to
    :data:`CERT_TOL` on the row-normalised data; ``(ok, why not)``."""
    y = np.asarray(y, dtype=np.float64).reshape(-1)
    if y.shape != (qp.m,) or not np.all(np.isfinite(y)):
        return False, "no finite certificate of the right shape"
    rn = _row_norms(qp.A)
    yt = _clean_duals(qp.l, qp.u, y * rn)  # ỹ for the rows ã = a/‖a‖
    ny = float(np.max(np.abs(yt), initial=0.0))
    if ny == 0.0:
        return False, "the certificate is zero"
    yt = yt / ny
    At = _max_abs(_times_rows(qp.A, (yt / rn)[None])[0])
    ls, us = qp.l / rn, qp.u / rn
    supp = float(
        np.sum(np.where(yt > 0, np.where(np.isfinite(us), us, 0.0) * yt, 0.0))
        + np.sum(np.where(yt < 0, np.where(np.isfinite(ls), ls, 0.0) * yt, 0.0))
    )
    if not At <= CERT_ZERO:
        return False, f"‖Aᵀy‖∞ = {At:.3g}·‖y‖ > {CERT_ZERO:g}"
    if not supp <= -CERT_TOL:
        return False, f"uᵀy₊ + lᵀy₋ = {supp:.3g}·‖y‖, not ≤ −{CERT_TOL:g}"
    return True, ""


def verify_dual_certificate(qp: QP, d: Any) -> tuple[bool, str]:
    """Whether ``d`` (shape (n,)) proves the objective unbounded below on a nonempty feasible
    set's recession directions (``Pd ≈ 0``, ``qᵀd < 0``, ``Ad`` in the recession cone of
    ``[l, u]``), to :data:`CERT_TOL` on the row-normalised data; ``(ok, why not)``."""
    d = np.asarray(d, dtype=np.float64).reshape(-1)
    if d.shape != (qp.n,) or not np.all(np.isfinite(d)):
        return False, "no finite certificate of the right shape"
    nd = float(np.max(np.abs(d), initial=0.0))
    if nd == 0.0:
        return False, "the certificate is zero"
    d = d / nd
    qn = float(np.max(np.abs(qp.q)))
    Pd = _max_abs(qp.P @ d)
    qd = float(qp.q @ d)
    if not Pd <= CERT_ZERO * _max_abs(qp.P):
        return False, f"‖Pd‖∞ = {Pd:.3g} is not ≈ 0"
    if not qd <= -CERT_TOL * qn or qn == 0.0:
        return False, f"qᵀd = {qd:.3g}·‖d‖, not < 0"
    if qp.m:
        Ad = (qp.A @ d) / _row_norms(qp.A)
        bad = (np.isfinite(qp.u) & (Ad > CERT_ZERO)) | (np.isfinite(qp.l) & (Ad < -CERT_ZERO))
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            return False, f"Ad leaves the recession cone of [l, u] at row {i} ({Ad[i]:.3g})"
    return True, ""


def _linprog(c, A_ub, b_ub, A_eq, b_eq, bounds):
    from scipy.optimize import linprog

    try:
        res = linprog(c, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=b_eq, bounds=bounds, method="highs")
    except (ValueError, RuntimeError):
        return None
    return res.x if res.status == 0 and res.x is not None else None


def primal_certificate(qp: QP) -> np.ndarray | None:
    """A Farkas certificate ``y`` of primal infeasibility (OSQP convention), found by a linear
    program (``min S̃(ỹ)`` over ``Ãᵀỹ = 0``, ``‖ỹ‖∞ ≤ 1``, SciPy's HiGHS) and verified by
    :func:`verify_primal_certificate`; ``None`` when there is none to tolerance."""
    m = qp.m
    if m == 0:
        return None
    rn = _row_norms(qp.A)
    At = sp.diags(1.0 / rn) @ sp.csr_matrix(qp.A)
    ls, us = qp.l / rn, qp.u / rn
    up, lo = np.flatnonzero(np.isfinite(us)), np.flatnonzero(np.isfinite(ls))
    if up.size + lo.size == 0:
        return None
    # variables: y⁺ on finite-u rows, y⁻ on finite-l rows, both in [0, 1]; ỹ = y⁺ − y⁻
    Eq = sp.hstack([At[up].T, -At[lo].T], format="csr")
    c = np.concatenate([us[up], -ls[lo]])
    sol = _linprog(c, None, None, Eq, np.zeros(qp.n), (0.0, 1.0))
    if sol is None or not float(c @ sol) < 0:
        return None
    yt = np.zeros(m)
    np.add.at(yt, up, sol[: up.size])
    np.add.at(yt, lo, -sol[up.size :])
    y = yt / rn
    return y if verify_primal_certificate(qp, y)[0] else None


def dual_certificate(qp: QP) -> np.ndarray | None:
    """A direction ``d`` certifying that the objective is unbounded below (``Pd = 0``,
    ``qᵀd < 0``, ``Ãd`` in the recession cone, ``‖d‖∞ ≤ 1``), found by a linear program (SciPy's
    HiGHS) and verified by :func:`verify_dual_certificate`; ``None`` when there is none.  (With a
    feasible point this proves unboundedness; whether one exists is not decided here.)"""
    P = sp.csr_matrix(qp.P)
    pn = _row_norms(P)
    keep = np.flatnonzero(np.asarray(abs(P).sum(axis=1)).reshape(-1) > 0)
    A_eq = (sp.diags(1.0 / pn) @ P)[keep] if keep.size else None
    b_eq = np.zeros(keep.size) if keep.size else None
    A_ub, b_ub = None, None
    if qp.m:
        rn = _row_norms(qp.A)
        At = sp.diags(1.0 / rn) @ sp.csr_matrix(qp.A)
        up, lo = np.flatnonzero(np.isfinite(qp.u)), np.flatnonzero(np.isfinite(qp.l))
        if up.size + lo.size:
            A_ub = sp.vstack([At[up], -At[lo]], format="csr")
            b_ub = np.zeros(up.size + lo.size)
    qn = float(np.max(np.abs(qp.q)))
    if qn == 0.0:
        return None
    sol = _linprog(qp.q / qn, A_ub, b_ub, A_eq, b_eq, (-1.0, 1.0))
    if sol is None or not float(qp.q @ sol) < 0:
        return None
    return sol if verify_dual_certificate(qp, sol)[0] else None


def _certify(qp: QP, status: int, extras: dict[str, Any]) -> tuple[np.ndarray | None, str, str]:
    """``(certificate, source, why not)`` for an infeasibility claim."""
    primal = status == STATUS_CODES.PRIMAL_INFEASIBLE
    key = "prim_inf_cert" if primal else "dual_inf_cert"
    verify = verify_primal_certificate if primal else verify_dual_certificate
    given = extras.get(key)
    why = "the backend gave no certificate"
    if given is not None:
        ok, why = verify(qp, given)
        if ok:
            return np.asarray(given, dtype=np.float64), "backend", ""
        why = f"the backend's certificate fails: {why}"
    cert = primal_certificate(qp) if primal else dual_certificate(qp)
    if cert is not None:
        return cert, "computed", ""
    return None, "", f"{why}, and none could be computed (a linear program found none)"


# --------------------------------------------------------------------------- entry points
def _eps(be: Any, settings: dict[str, Any]) -> float:
    try:
        eps_abs, eps_rel = be.stated_tolerance(settings)
    except Exception:  # noqa: BLE001 - a user backend with odd settings: the default tolerance
        eps_abs, eps_rel = 1e-6, 1e-6
    return float(max(eps_abs, eps_rel, EPS_FLOOR))


#: the tolerances of the confirming solve of an inaccurate answer are the caller's divided by this
CONFIRM_FACTOR = 10.0


def confirm_inaccurate(
    be: Any, qp: QP, sol: Solution, settings: dict[str, Any], solve: Callable[..., Solution]
) -> Solution:
    """The confirmation of a ``SOLVED_INACCURATE`` answer (module docstring): ``solve(qp,
    warm_start=sol, **tighter)`` with the caller's ``settings`` and the backend's stated
    tolerances divided by :data:`CONFIRM_FACTOR`; ``solve`` returns a checked answer.  Any
    other answer, a backend that ignores warm starts, or settings the tighter run refuses:
    ``sol`` unchanged."""
    if sol.status is not Status.SOLVED_INACCURATE or not getattr(be, "honours_warm_start", False):
        return sol
    if not (np.all(np.isfinite(sol.x)) and np.all(np.isfinite(sol.y))):
        return sol
    try:
        eps_abs, eps_rel = be.stated_tolerance(sol.settings)
    except Exception:  # noqa: BLE001 - a user backend that cannot state its tolerance
        return sol
    tighter = dict(settings, eps_abs=float(eps_abs) / CONFIRM_FACTOR,
                   eps_rel=float(eps_rel) / CONFIRM_FACTOR)  # fmt: skip
    try:
        nxt = solve(qp, warm_start=sol, **tighter)
    except Exception as exc:  # noqa: BLE001 - e.g. native tolerance names: left as it was
        return dataclasses.replace(
            sol, extras={**sol.extras, "confirm": {"result": "skipped", "reason": repr(exc)}}
        )
    info = {
        "eps_abs": tighter["eps_abs"],
        "eps_rel": tighter["eps_rel"],
        "status": nxt.status.name,
        "iterations": int(nxt.iterations),
        "objective": float(nxt.objective),
        "objective_before": float(sol.objective),
    }
    if nxt.status in (Status.SOLVED, Status.SOLVED_INACCURATE):
        info["result"] = "confirmed"
        return dataclasses.replace(
            nxt,
            iterations=int(sol.iterations) + int(nxt.iterations),
            solve_time=float(sol.solve_time) + float(nxt.solve_time),
            settings=sol.settings,
            extras={**nxt.extras, "confirm": info},
        )
    f0 = float(sol.objective)
    moved = abs(float(nxt.objective) - f0) if np.isfinite(nxt.objective) else np.inf
    if moved <= max(float(eps_abs), float(eps_rel)) * max(1.0, abs(f0)):
        # not confirmed, but steady: the tighter run left the objective where it was
        info["result"] = "steady"
        return dataclasses.replace(sol, extras={**sol.extras, "confirm": info})
    info["result"] = "not confirmed"
    msg = (
        f"an inaccurate answer that a solve at tolerances {CONFIRM_FACTOR:g} × tighter, started "
        f"from it, could not confirm ({nxt.status.name}): the iterate is kept, not converged"
    )
    return dataclasses.replace(
        sol,
        status=Status.MAX_ITER,
        iterations=int(sol.iterations) + int(nxt.iterations),
        solve_time=float(sol.solve_time) + float(nxt.solve_time),
        extras={**sol.extras, "confirm": info, "message": msg},
    )


def check_solution(be: Any, qp: QP, sol: Solution) -> Solution:
    """``sol`` after the check of the module docstring (a new :class:`Solution` when anything
    changes; ``extras["check"]`` records the outcome).  ``be``: the backend that solved it."""
    eps = _eps(be, sol.settings)
    status = int(sol.status)
    extras = dict(sol.extras)
    info: dict[str, Any] = {"eps": eps, "status_before": Status(status).name}
    changes: dict[str, Any] = {}
    if status in _SOLVED_LIKE:
        # a point of the wrong shape is no point; duals of the wrong shape are no duals
        x = sol.x if np.shape(sol.x) == (qp.n,) else np.full(qp.n, np.nan)
        y = sol.y if np.shape(sol.y) == (qp.m,) else np.full(qp.m, np.nan)
        p, d, g, og = (
            float(v[0])
            for v in _residuals(
                qp.P,
                qp.A,
                qp.q[None],
                qp.l[None],
                qp.u[None],
                np.asarray(x, float)[None],
                np.asarray(y, float)[None],
            )
        )
        info.update(primal=p, dual=d, gap=g, objective_gap=og)
        new, result, reason = _verdict(status, p, d, g, og, eps)
        info["result"] = result
        if new != status:
            changes["status"] = Status(new)
            info["reason"] = reason
            if new == STATUS_CODES.ERROR:
                changes.update(_nan_point(qp))
    elif status in _INFEASIBLE:
        cert, source, why = _certify(qp, status, extras)
        key = "prim_inf_cert" if status == STATUS_CODES.PRIMAL_INFEASIBLE else "dual_inf_cert"
        changes.update(_nan_point(qp))
        if cert is not None:
            extras[key] = cert
            info.update(result="certified", certificate=source)
        else:
            extras.pop(key, None)
            changes["status"] = Status.ERROR
            info.update(
                result="refuted",
                reason=f"reported {Status(status).name}, not verified: {why}",
            )
    else:
        info["result"] = "skipped"
    extras["check"] = info
    changes["extras"] = extras
    return dataclasses.replace(sol, **changes)


def _nan_point(qp: QP) -> dict[str, Any]:
    nan = float("nan")
    return dict(
        x=np.full(qp.n, np.nan),
        y=np.full(qp.m, np.nan),
        objective=nan,
        primal_residual=nan,
        dual_residual=nan,
    )


def check_batch_solution(be: Any, batch: QPBatch, sol: BatchSolution) -> BatchSolution:
    """:func:`check_solution` for every problem of a batch (the optimality check vectorised;
    certificates per claimed-infeasible problem).  Returns a new :class:`BatchSolution`."""
    eps = _eps(be, sol.settings)
    before = np.asarray(sol.status, dtype=np.int32)
    status = before.copy()
    x, y = np.array(sol.x, dtype=np.float64), np.array(sol.y, dtype=np.float64)
    obj = np.array(sol.objective, dtype=np.float64)
    prim = np.array(sol.primal_residual, dtype=np.float64)
    dres = np.array(sol.dual_residual, dtype=np.float64)
    B = len(batch)
    p, d, g, og = (np.full(B, np.nan) for _ in range(4))
    result = np.full(B, "skipped", dtype=object)
    reasons: dict[int, str] = {}
    certs: dict[int, np.ndarray] = {}
    sources: dict[int, str] = {}
    idx = np.flatnonzero(np.isin(before, _SOLVED_LIKE))
    if idx.size:
        p[idx], d[idx], g[idx], og[idx] = _residuals(
            batch.P, batch.A, batch.q[idx], batch.l[idx], batch.u[idx], x[idx], y[idx]
        )
        with np.errstate(invalid="ignore"):
            worst = np.fmax(np.fmax(p[idx], d[idx]), g[idx])
            ok = np.isfinite(p[idx]) & (worst <= SOLVED_FACTOR * eps)
            ok &= ~np.isinf(d[idx]) & ~np.isinf(g[idx])
            ok &= ~(og[idx] > _objective_far(eps))
        result[idx[ok]] = "passed"
        for i in idx[~ok]:  # the rest, one by one (the reasons)
            new, result[i], reason = _verdict(int(before[i]), p[i], d[i], g[i], og[i], eps)
            if new != before[i]:
                status[i] = new
                reasons[int(i)] = reason
    for i in np.flatnonzero(np.isin(before, _INFEASIBLE)):
        qp = batch[i]
        cert, source, why = _certify(qp, int(before[i]), {})
        if cert is not None:
            certs[int(i)], sources[int(i)] = cert, source
            result[i] = "certified"
        else:
            status[i] = STATUS_CODES.ERROR
            result[i] = "refuted"
            reasons[int(i)] = f"reported {Status(int(before[i])).name}, not verified: {why}"
    nanpt = np.isin(before, _INFEASIBLE) | (
        (status == STATUS_CODES.ERROR) & np.isin(before, _SOLVED_LIKE)
    )
    x[nanpt], y[nanpt] = np.nan, np.nan
    obj[nanpt], prim[nanpt], dres[nanpt] = np.nan, np.nan, np.nan
    extras = dict(sol.extras)
    extras["check"] = {
        "eps": eps,
        "status_before": before,
        "result": result,
        "primal": p,
        "dual": d,
        "gap": g,
        "objective_gap": og,
        "reason": reasons,
        "certificate": sources,
    }
    if certs:
        extras["certificates"] = certs
    return dataclasses.replace(
        sol,
        x=x,
        y=y,
        status=status,
        objective=obj,
        primal_residual=prim,
        dual_residual=dres,
        extras=extras,
    )
