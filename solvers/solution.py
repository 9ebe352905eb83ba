"""Solution types and the status enum shared by every backend.

Habits kept from qpsolvers: ``print(sol.status)`` shows the name (``SOLVED``), while
``sol.status == 1`` and integer arrays of codes keep working; ``sol.ok`` is ``True`` for
``SOLVED`` only; ``sol.is_optimal(eps_abs, eps_rel=0)`` and ``sol.duality_gap()`` check the
returned point against the problem it solved (``eps_rel``: OSQP's relative part, what a backend's
``SOLVED`` at ``(eps_abs, eps_rel)`` promises, see below); ``repr(sol)`` is one line (status,
objective, sizes, backend, time), not the settings.

Status table
------------
What each status guarantees, for every backend: :func:`solvers.solve` and
:func:`solvers.solve_batch` pass each answer through the answer check of :mod:`solvers.check`
before returning it (``eps = max(stated eps_abs, stated eps_rel, 1e-6)``; residuals relative and
row-normalised, see that module; the outcome and any reason in ``sol.extras["check"]``).

=================== ===================================================================
status              guarantee
=================== ===================================================================
SOLVED              the backend converged and the check passed: row-normalised primal
                    residual, dual residual and duality gap each ≤ ``10·eps·(1 + scale)``
                    (``scale`` the largest of the terms summed; dual and gap where the backend
                    returned duals), primal and dual objective within ``min(1e3·eps, 0.1)``
                    of ``max(1, |objective|)``; and the backend's own test (below, in
                    :meth:`Solution.is_optimal`'s terms)
SOLVED_INACCURATE   every residual ≤ ``min(1e3·eps, 0.1)·(1 + scale)``, objectives as for
                    SOLVED; the backend said "inaccurate", or said SOLVED and the check found a
                    residual above ``10·eps``; and (backends that honour warm starts, via
                    :func:`solvers.solve`) a solve from it at a tenth of the tolerances
                    confirmed it or left its objective where it was
                    (:func:`solvers.check.confirm_inaccurate`)
MAX_ITER            no answer: the iteration or time budget ran out, or a SOLVED /
                    SOLVED_INACCURATE whose residuals or objective gap exceed
                    ``min(1e3·eps, 0.1)``, or an inaccurate answer the tighter solve could
                    not confirm and moved; ``x`` is the last iterate (for inspection only) or
                    NaN
PRIMAL_INFEASIBLE   a Farkas certificate ``y`` verified by the check is in
                    ``extras["prim_inf_cert"]``; ``x``, ``y``, objective and residuals are NaN
DUAL_INFEASIBLE     a direction ``d`` (``Pd = 0``, ``qᵀd < 0``, ``Ad`` in the recession cone)
                    verified by the check is in ``extras["dual_inf_cert"]``; ``x`` etc. NaN
ERROR               the solver failed, returned non-finite values, or claimed an infeasibility
                    that no certificate verifies (``extras["check"]["reason"]``; ``x`` NaN)
=================== ===================================================================

What ``SOLVED`` promises in :meth:`Solution.is_optimal`'s terms (``eps_abs``, ``eps_rel`` as
given, each backend's own termination test on the point it returns; see that method):

* ``osqp``: ``is_optimal(eps_abs, eps_rel)`` — OSQP's unscaled test, duality gap included
  (``check_dualgap``, on by default in OSQP 1.x); with ``eps_rel = 0``, ``is_optimal(eps_abs)``.
* ``admm``: ``is_optimal(eps_abs, eps_rel)``, tested in float64 on the returned point, and the
  primal residual within ``eps_abs + eps_rel·max(1, ‖finite l, u‖∞)``.
* ``ipm``: ``is_optimal(eps_abs, eps_rel)`` (its gap scale is the smaller of
  ``max(|f_primal|, |f_dual|)`` and ``is_optimal``'s), at its default ``1e-9``.
* ``clarabel`` (and ``qpsolvers:clarabel``, ``cvxpy`` with Clarabel): relative tests of its own,
  ``‖Ax + s − b‖ ≤ tol_feas·max(1, ‖b‖∞ + ‖x‖∞ + ‖s‖∞)``, ``‖Px + q + Aᵀz‖ ≤
  tol_feas·max(1, ‖q‖∞ + ‖x‖∞ + ‖z‖∞)`` (``tol_feas`` = ``eps_abs``) and a gap ``≤ tol_gap_abs``
  or ``≤ tol_gap_rel·max(1, min(|f_primal|, |f_dual|))`` (``eps_abs``, ``eps_rel``), on the
  homogeneous embedding: ``eps_abs`` acts as a *relative* feasibility tolerance, so
  ``is_optimal(eps_abs, eps_rel)`` holds when those sizes are about 1 and not in general.
* ``qpsolvers:scs``: ``is_optimal(eps_abs, eps_rel)`` with ``max(‖Ax‖∞, ‖s‖∞, ‖b‖∞)`` (the
  bounds' norm included) as the primal scale; ``qpsolvers:osqp`` as ``osqp``;
  ``qpsolvers:proxqp``: OSQP-like primal and dual tests, and the gap once a common ``eps_abs`` /
  ``eps_rel`` is given (it then sets ProxQP's ``check_duality_gap``; at ProxQP's own defaults the
  gap is not tested); ``qpsolvers:piqp``: OSQP-like tests with its own, tighter, gap tolerances;
  ``qpsolvers:daqp`` / ``quadprog``: active-set solves, exact to rounding.

Backend by backend (``eps`` at the backend's defaults; where the certificate comes from):

* ``clarabel`` (``eps`` = ``tol_feas`` 1e-8, floored to 1e-6): native Solved / AlmostSolved /
  MaxIterations, MaxTime / (Almost)PrimalInfeasible, (Almost)DualInfeasible; Clarabel's own
  certificate (its ``z`` or ``x`` at the infeasibility), else one computed by the check.  Its
  false DualInfeasible on Maros–Meszaros PRIMALC1/PRIMALC2 is refuted: ``ERROR``.
* ``osqp`` (1e-3): native statuses; time limit, non-convex → ``ERROR``.  Its certificates are the
  last ``δx``/``δy``, which meet OSQP's 1e-4 test but seldom the check's rounding-level one, so the
  certificate is usually computed; a false infeasibility claim (a row scaled by 1e-6 on a bounded
  LP) is ``ERROR``.
* ``cvxpy`` (the inner solver's tolerance): cvxpy's OPTIMAL(_INACCURATE) / INFEASIBLE /
  UNBOUNDED / USER_LIMIT; no certificate from cvxpy: computed.
* ``qpsolvers:<name>`` (the solver's stated tolerance): "found" is SOLVED only after its own
  residual test and then the check; infeasibility only from solvers whose status qpsolvers
  exposes (``daqp`` and ``quadprog`` report ``ERROR`` instead); certificates computed.
* ``admm`` (1e-5): its float64 re-check of the returned point, then the check; infeasibility from
  OSQP-style certificates re-checked in float64, the certificate itself computed by the check.
* ``ipm`` (1e-9, floored to 1e-6): termination on the unscaled problem, then the check;
  infeasibility from the certificates of the last step, the certificate computed by the check.

A backend's ``solve`` called directly (not through :func:`solvers.solve`) is not checked.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from .problem import QP, QPBatch

__all__ = ["Status", "StatusCodes", "STATUS_CODES", "RUNNING_CODE", "Solution", "BatchSolution"]


class Status(IntEnum):
    """Outcome of a QP solve.  Integer codes so a batch can hold them in an array.

    What each status guarantees (every answer from :func:`solvers.solve` /
    :func:`solvers.solve_batch` is checked first, :mod:`solvers.check`): ``SOLVED``, every
    relative residual within 10 × the stated tolerance (at least 1e-6); ``SOLVED_INACCURATE``,
    within ``min(1e3·eps, 0.1)``; both with primal and dual objective that close; ``MAX_ITER``,
    no answer; ``PRIMAL_INFEASIBLE`` /
    ``DUAL_INFEASIBLE``, a verified certificate in ``sol.extras``; ``ERROR``, a failure or an
    unverified infeasibility claim.  The full table is in the docstring of :mod:`solvers.solution`.

    ``str()`` and f-strings give the name (``f"{sol.status}"`` is ``"SOLVED"``); a numeric format
    (``f"{sol.status:d}"``) and comparisons with integers use the code.
    """

    SOLVED = 1
    SOLVED_INACCURATE = 2
    MAX_ITER = 3
    PRIMAL_INFEASIBLE = 4
    DUAL_INFEASIBLE = 5
    ERROR = 6

    @property
    def ok(self) -> bool:
        """True for ``SOLVED`` only."""
        return self is Status.SOLVED

    def __str__(self) -> str:
        return self.name

    def __format__(self, spec: str) -> str:
        if spec and spec[-1] in "bcdoxXneEfFgG%":  # a numeric format: the integer code
            return format(int(self), spec)
        return format(self.name, spec)


class StatusCodes(NamedTuple):
    """The integer code of every :class:`Status` member, as plain ``int`` fields.

    The one table the solvers' array code reads (``jnp.where(ok, STATUS_CODES.SOLVED, status)``,
    ``status == STATUS_CODES.MAX_ITER``): plain integers keep JAX and NumPy from seeing an enum,
    and one table keeps the codes from being restated module by module.
    """

    SOLVED: int
    SOLVED_INACCURATE: int
    MAX_ITER: int
    PRIMAL_INFEASIBLE: int
    DUAL_INFEASIBLE: int
    ERROR: int


#: ``int(Status.X)`` for every member ``X`` (built from :class:`Status`, so the two cannot drift)
STATUS_CODES = StatusCodes(**{s.name: int(s) for s in Status})

#: the per-QP code an iteration loop holds until a check decides; no :class:`Status` has it, and
#: no solver returns it
RUNNING_CODE = 0


def _check_eps(eps: Any, name: str = "eps_abs") -> None:
    if isinstance(eps, bool) or not isinstance(eps, (int, float, np.integer, np.floating)):
        hint = " (pass the problem as qp=...)" if hasattr(eps, "P") else ""
        raise ValueError(f"{name} must be a number ≥ 0, got {type(eps).__name__}{hint}")
    if not eps >= 0:
        raise ValueError(f"{name} must be a number ≥ 0, got {eps!r}")


def _optimal(problem: Any, x: np.ndarray, y: np.ndarray, eps_abs: float, eps_rel: float):
    """Per row of ``x`` (B, n), ``y`` (B, m): primal, dual residual and duality gap each within
    ``eps_abs + eps_rel·scale`` (the scales of :meth:`Solution.is_optimal`); ``False`` where
    ``x`` or ``y`` is not finite."""
    X = np.atleast_2d(np.asarray(x, dtype=np.float64))
    Y = np.atleast_2d(np.asarray(y, dtype=np.float64))
    fin = np.all(np.isfinite(X), axis=1) & np.all(np.isfinite(Y), axis=1)
    X, Y = np.where(fin[:, None], X, 0.0), np.where(fin[:, None], Y, 0.0)
    q, l, u = (np.atleast_2d(v) for v in (problem.q, problem.l, problem.u))
    P, A = problem.P, problem.A
    Px = np.asarray((P @ X.T).T)
    m = l.shape[1]
    with np.errstate(over="ignore", invalid="ignore"):
        if m:
            Ax = np.asarray((A @ X.T).T)
            ATy = np.asarray((A.T @ Y.T).T)
            viol = np.maximum(np.maximum(l - Ax, Ax - u), 0.0).max(axis=1)
            p_scale = np.maximum(np.abs(Ax).max(axis=1), np.abs(np.clip(Ax, l, u)).max(axis=1))
        else:
            ATy = np.zeros_like(Px)
            viol = p_scale = np.zeros(X.shape[0])
        dual = np.abs(Px + q + ATy).max(axis=1)
        d_scale = np.maximum.reduce(
            [np.abs(Px).max(axis=1), np.abs(ATy).max(axis=1), np.abs(q).max(axis=1)]
        )
        up = np.where(np.isfinite(u), u, 0.0) * np.maximum(Y, 0.0)
        lo = np.where(np.isfinite(l), l, 0.0) * np.minimum(Y, 0.0)
        supp = (up + lo).sum(axis=1)
        xPx = np.einsum("bi,bi->b", X, Px)
        qx = np.einsum("bi,bi->b", q, X)
        gap = np.abs(xPx + qx + supp)
        g_scale = np.maximum.reduce([np.abs(xPx), np.abs(qx), np.abs(supp)])
        ok = (
            (viol <= eps_abs + eps_rel * p_scale)
            & (dual <= eps_abs + eps_rel * d_scale)
            & (gap <= eps_abs + eps_rel * g_scale)
        )
    return ok & fin


def _fmt_time(t: float) -> str:
    """Seconds as a short string in s or ms."""
    if not np.isfinite(t):
        return "nan"
    return f"{t * 1e3:.3g} ms" if t < 1.0 else f"{t:.3g} s"


@dataclass(frozen=True, eq=False)
class Solution:
    """Result of one QP solve.

    ``x`` is always returned: the last iterate when not solved; NaN when the backend gave
    nothing, for ``PRIMAL_INFEASIBLE`` / ``DUAL_INFEASIBLE`` (the certificate is in ``extras``)
    and for an infeasibility claim refuted by the answer check (see the status table in the
    module docstring).  ``y`` follows OSQP's sign convention: ``Px + q + Aᵀy = 0`` at the
    optimum, ``y ≥ 0`` on active upper bounds and ``y ≤ 0`` on active lower bounds.
    """

    x: np.ndarray
    y: np.ndarray
    status: Status
    objective: float
    iterations: int
    solve_time: float
    primal_residual: float
    dual_residual: float
    backend: str
    settings: dict[str, Any] = field(default_factory=dict)
    extras: dict[str, Any] = field(default_factory=dict)
    #: the QP this answers (attached by :func:`solvers.solve`/:func:`solvers.solve_qp`); used by
    #: :meth:`duality_gap` and :meth:`is_optimal`
    problem: QP | None = field(default=None, repr=False)

    @property
    def ok(self) -> bool:
        """True when the backend reports ``SOLVED`` (the status only; see :meth:`is_optimal`
        for a check of the point itself)."""
        return self.status is Status.SOLVED

    def __repr__(self) -> str:
        return (
            f"Solution({getattr(self.status, 'name', self.status)}, "
            f"objective={self.objective:.6g}, "
            f"n={np.shape(self.x)[0]}, m={np.shape(self.y)[0]}, iterations={self.iterations}, "
            f"backend={self.backend!r}, solve_time={_fmt_time(self.solve_time)})"
        )

    def _qp(self, qp: QP | None) -> QP:
        qp = self.problem if qp is None else qp
        if qp is None:
            raise ValueError(
                "qp is required: this Solution carries no problem (solutions returned by "
                "solvers.solve / solve_qp / solve_batch do); pass qp=the QP it solves"
            )
        return qp

    def duality_gap(self, qp: QP | None = None) -> float:
        """``|xᵀPx + qᵀx + S(y)|``, ``S(y) = Σ u_i·max(y_i, 0) + l_i·min(y_i, 0)`` over the
        finite sides of ``[l, u]``: primal minus dual objective at ``(x, y)``, as qpsolvers'
        ``Solution.duality_gap`` (see :meth:`solvers.QP.duality_gap`); NaN when ``x`` or ``y``
        is NaN.  ``qp`` defaults to the problem this solution was returned for.
        """
        return self._qp(qp).duality_gap(self.x, self.y)

    def is_optimal(self, eps_abs: float, eps_rel: float = 0.0, qp: QP | None = None) -> bool:
        """Whether the point ``(x, y)`` meets OSQP's termination test at ``(eps_abs, eps_rel)``,
        recomputed in float64 from the problem, whatever the status says (``False`` for NaN
        ``x`` or ``y``):

        * primal residual ``max(0, l − Ax, Ax − u) ≤ eps_abs + eps_rel·max(‖Ax‖∞, ‖Π(Ax)‖∞)``
          (``Π`` the projection onto ``[l, u]``);
        * dual residual ``‖Px + q + Aᵀy‖∞ ≤ eps_abs + eps_rel·max(‖Px‖∞, ‖Aᵀy‖∞, ‖q‖∞)``;
        * :meth:`duality_gap` ``|xᵀPx + qᵀx + S(y)| ≤ eps_abs + eps_rel·max(|xᵀPx|, |qᵀx|,
          |S(y)|)``.

        ``eps_rel = 0`` (the default) is qpsolvers' ``Solution.is_optimal(eps_abs)``: all three
        ``≤ eps_abs``.  A ``SOLVED`` answer does not promise that: each backend's ``eps_abs`` and
        ``eps_rel`` are its own termination test, and ``sol.is_optimal(eps_abs, eps_rel)`` checks
        it for ``osqp``, ``admm`` and ``ipm`` exactly (Clarabel's relative test, SCS's and
        ProxQP's are listed in the module docstring).  So at ``eps_abs = eps_rel = 1e-6`` a
        ``SOLVED`` from ``osqp`` or ``ipm`` may fail ``is_optimal(1e-6)`` (a gap of ``1.5e-6`` on
        terms of size 1 is within ``1e-6 + 1e-6·1``), and passes ``is_optimal(1e-6, 1e-6)``;
        solve with ``eps_rel=0`` to get ``is_optimal(eps_abs)`` itself from those backends.
        """
        _check_eps(eps_abs)
        _check_eps(eps_rel, "eps_rel")
        qp = self._qp(qp)
        x = np.asarray(self.x, dtype=np.float64)
        y = np.asarray(self.y, dtype=np.float64)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            return False
        if eps_rel == 0:  # qpsolvers' test, on the problem's own evaluations
            return bool(
                qp.constraint_violation(x) <= eps_abs
                and qp.dual_residual(x, y) <= eps_abs
                and qp.duality_gap(x, y) <= eps_abs
            )
        return bool(_optimal(qp, x, y, eps_abs, eps_rel)[0])


@dataclass(frozen=True, eq=False)
class BatchSolution:
    """Result of a batch solve: every field of :class:`Solution` with a leading batch axis.

    ``status`` is an int array of :class:`Status` codes; ``solve_time`` is per problem and
    ``total_time`` the wall time of the whole batch call.
    """

    x: np.ndarray  # (B, n)
    y: np.ndarray  # (B, m)
    status: np.ndarray  # (B,) int codes of Status
    objective: np.ndarray  # (B,)
    iterations: np.ndarray  # (B,)
    solve_time: np.ndarray  # (B,) seconds per problem (batch wall time / B for batched backends)
    primal_residual: np.ndarray  # (B,)
    dual_residual: np.ndarray  # (B,)
    backend: str
    total_time: float = float("nan")
    settings: dict[str, Any] = field(default_factory=dict)
    extras: dict[str, Any] = field(default_factory=dict)
    #: the batch this answers (attached by :func:`solvers.solve_batch`)
    problem: QPBatch | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return self.x.shape[0]

    def __repr__(self) -> str:
        counts = ", ".join(f"{k} {v}" for k, v in self.status_counts().items())
        obj = np.asarray(self.objective, dtype=np.float64)
        fin = obj[np.isfinite(obj)]
        rng = f"[{fin.min():.6g}, {fin.max():.6g}]" if fin.size else "nan"
        return (
            f"BatchSolution({counts}; B={len(self)}, n={self.x.shape[1]}, m={self.y.shape[1]}, "
            f"objective in {rng}, backend={self.backend!r}, "
            f"total_time={_fmt_time(self.total_time)})"
        )

    def __getitem__(self, i: int) -> Solution:
        status = Status(int(self.status[i]))
        return Solution(
            x=self.x[i],
            y=self.y[i],
            status=status,
            objective=float(self.objective[i]),
            iterations=int(self.iterations[i]),
            solve_time=float(self.solve_time[i]),
            primal_residual=float(self.primal_residual[i]),
            dual_residual=float(self.dual_residual[i]),
            backend=self.backend,
            settings=self.settings,
            extras=self._extras_of(int(i), status),
            problem=None if self.problem is None else self.problem[i],
        )

    def _extras_of(self, i: int, status: Status) -> dict[str, Any]:
        """Problem ``i``'s part of the answer check's record (:mod:`solvers.check`): its
        ``extras["check"]`` and, if infeasible, its certificate under the key a single solve
        uses."""
        check = self.extras.get("check")
        if not isinstance(check, dict):
            return {}
        out: dict[str, Any] = {}
        one = {}
        for k, v in check.items():
            if isinstance(v, np.ndarray) and v.shape[:1] == (len(self),):
                one[k] = v[i].item() if isinstance(v[i], np.generic) else v[i]
            elif isinstance(v, dict):
                if i in v:
                    one[k] = v[i]
            else:
                one[k] = v
        if isinstance(one.get("status_before"), int):
            one["status_before"] = Status(one["status_before"]).name
        out["check"] = one
        cert = self.extras.get("certificates", {}).get(i)
        if cert is not None and status is Status.PRIMAL_INFEASIBLE:
            out["prim_inf_cert"] = cert
        elif cert is not None and status is Status.DUAL_INFEASIBLE:
            out["dual_inf_cert"] = cert
        return out

    @property
    def solved(self) -> np.ndarray:
        """Boolean mask of problems with status ``SOLVED``."""
        return self.status == int(Status.SOLVED)

    @property
    def ok(self) -> np.ndarray:
        """Boolean array (B,): ``True`` where the status is ``SOLVED`` (``Solution.ok`` per
        problem; the same as :attr:`solved`)."""
        return self.solved

    @property
    def status_names(self) -> tuple[str, ...]:
        """The status of each problem by name, e.g. ``("SOLVED", "MAX_ITER")``."""
        return tuple(Status(int(v)).name for v in np.asarray(self.status).ravel())

    def _batch(self, batch: QPBatch | None) -> QPBatch:
        batch = self.problem if batch is None else batch
        if batch is None:
            raise ValueError(
                "batch is required: this BatchSolution carries no problem (those returned by "
                "solvers.solve_batch do); pass batch=the QPBatch it solves"
            )
        return batch

    def duality_gap(self, batch: QPBatch | None = None) -> np.ndarray:
        """Per-problem :meth:`Solution.duality_gap`, shape (B,)."""
        return self._batch(batch).duality_gap(self.x, self.y)

    def is_optimal(
        self, eps_abs: float, eps_rel: float = 0.0, batch: QPBatch | None = None
    ) -> np.ndarray:
        """Per-problem :meth:`Solution.is_optimal`, a boolean array (B,)."""
        _check_eps(eps_abs)
        _check_eps(eps_rel, "eps_rel")
        batch = self._batch(batch)
        x = np.asarray(self.x, dtype=np.float64)
        y = np.asarray(self.y, dtype=np.float64)
        if eps_rel != 0:
            return _optimal(batch, x, y, eps_abs, eps_rel)
        with np.errstate(invalid="ignore"):
            ok = (
                (batch.constraint_violation(x) <= eps_abs)
                & (batch.dual_residual(x, y) <= eps_abs)
                & (batch.duality_gap(x, y) <= eps_abs)
            )
        return ok & np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(y), axis=1)

    @property
    def n_solved(self) -> int:
        return int(self.solved.sum())

    @property
    def all_solved(self) -> bool:
        return bool(self.solved.all())

    def status_counts(self) -> dict[str, int]:
        """``{status name: count}`` for the statuses present."""
        vals, counts = np.unique(self.status, return_counts=True)
        return {Status(int(v)).name: int(c) for v, c in zip(vals, counts, strict=True)}

    @classmethod
    def stack(
        cls,
        sols: list[Solution],
        backend: str,
        total_time: float,
        settings: dict[str, Any] | None = None,
        extras: dict[str, Any] | None = None,
    ) -> BatchSolution:
        """Stack per-problem solutions (used by backends that loop)."""
        return cls(
            x=np.stack([s.x for s in sols]),
            y=np.stack([s.y for s in sols]),
            status=np.array([int(s.status) for s in sols], dtype=np.int32),
            objective=np.array([s.objective for s in sols]),
            iterations=np.array([s.iterations for s in sols], dtype=np.int64),
            solve_time=np.array([s.solve_time for s in sols]),
            primal_residual=np.array([s.primal_residual for s in sols]),
            dual_residual=np.array([s.dual_residual for s in sols]),
            backend=backend,
            total_time=total_time,
            settings=settings if settings is not None else (sols[0].settings if sols else {}),
            extras=extras or {},
        )
