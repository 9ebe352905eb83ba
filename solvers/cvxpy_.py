"""cvxpy backend: the QP built once as a parametrised (DPP) cvxpy problem, re-solved per problem.

For users who model in cvxpy.  ``P`` and ``A`` enter as constants; ``q`` and the finite bounds are
``cp.Parameter``\\ s, so a batch (shared ``P``/``A``) is canonicalised once and re-solved with new
parameter values.  Infinite bounds are never replaced by big numbers: only rows whose bound is
finite get a constraint, so the built problem depends on the *pattern* of finite bounds too.  Built
problems are cached by the content of ``P`` and ``A`` and that pattern (a small LRU).

Settings: ``solver=`` picks cvxpy's solver (default ``"CLARABEL"``); the common vocabulary is
mapped to that solver's names (Clarabel, OSQP, SCS, PIQP, ProxQP, DAQP); other keywords go to
``cp.Problem.solve`` and thus to that solver, checked against its known names (an unknown one
raises :class:`~solvers.errors.InvalidSettingError`; for a solver not in the table they pass
unchecked).  cvxpy's own defaults are not changed.  ``warm_start`` is recorded as ignored (cvxpy
warm-starts only from its own previous solve, not from a given point).
"""

from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import cvxpy as cp
import numpy as np
import scipy.sparse as sp

from . import clarabel_
from .base import Backend, failed_solution
from .errors import InvalidSettingError
from .problem import QP
from .settings import SettingsSpec
from .solution import Solution, Status

__all__ = ["CvxpyBackend", "make_backend", "DEFAULT_SOLVER"]

DEFAULT_SOLVER = "CLARABEL"
_CACHE_SIZE = 16

_STATUS = {
    cp.OPTIMAL: Status.SOLVED,
    cp.OPTIMAL_INACCURATE: Status.SOLVED_INACCURATE,
    cp.INFEASIBLE: Status.PRIMAL_INFEASIBLE,
    cp.INFEASIBLE_INACCURATE: Status.PRIMAL_INFEASIBLE,
    cp.UNBOUNDED: Status.DUAL_INFEASIBLE,
    cp.UNBOUNDED_INACCURATE: Status.DUAL_INFEASIBLE,
    cp.USER_LIMIT: Status.MAX_ITER,
    # SOLVER_ERROR, INFEASIBLE_OR_UNBOUNDED and anything else -> ERROR
}


#: keywords of ``cp.Problem.solve`` itself, valid with every solver
_CVXPY_KW = frozenset({"solver", "verbose", "ignore_dpp", "canon_backend", "enforce_dpp"})
_C = ("eps_abs", "eps_rel", "max_iter", "time_limit", "verbose")
#: per cvxpy solver: (common -> native names, native names or None, stated tolerance keys, defaults)
_SOLVER_SPECS: dict[str, tuple[dict, frozenset | None, tuple, tuple]] = {
    "CLARABEL": (clarabel_.COMMON, clarabel_.NATIVE, ("tol_feas", "tol_feas"), (1e-8, 1e-8)),
    "OSQP": (
        {k: (k,) for k in _C},
        None,  # filled lazily from solvers.osqp_ when osqp is installed
        ("eps_abs", "eps_rel"),
        (1e-5, 1e-5),  # cvxpy's own OSQP defaults
    ),
    "SCS": (
        {
            "eps_abs": ("eps_abs",),
            "eps_rel": ("eps_rel",),
            "max_iter": ("max_iters",),
            "time_limit": ("time_limit_secs",),
            "verbose": ("verbose",),
        },
        frozenset(
            {
                "normalize",
                "scale",
                "adaptive_scale",
                "rho_x",
                "max_iters",
                "eps_abs",
                "eps_rel",
                "eps_infeas",
                "alpha",
                "time_limit_secs",
                "verbose",
                "warm_start",
                "acceleration_lookback",
                "acceleration_interval",
                "write_data_filename",
                "log_csv_filename",
                "use_indirect",
                "gpu",
                "mkl",
            }
        ),
        ("eps_abs", "eps_rel"),
        (1e-5, 1e-5),
    ),
    "PIQP": (
        {
            "eps_abs": ("eps_abs",),
            "eps_rel": ("eps_rel",),
            "max_iter": ("max_iter",),
            "verbose": ("verbose",),
        },
        None,
        ("eps_abs", "eps_rel"),
        (1e-8, 1e-9),
    ),
    "PROXQP": (
        {
            "eps_abs": ("eps_abs",),
            "eps_rel": ("eps_rel",),
            "max_iter": ("max_iter",),
            "verbose": ("verbose",),
        },
        None,
        ("eps_abs", "eps_rel"),
        (1e-5, 0.0),
    ),
    "DAQP": (
        {"eps_abs": ("primal_tol",), "max_iter": ("iter_limit",), "verbose": ("verbose",)},
        None,
        ("primal_tol", None),
        (1e-6, 0.0),
    ),
}


def _spec(solver: str) -> SettingsSpec:
    common, native, tol, tol_def = _SOLVER_SPECS.get(
        solver, ({k: (k,) for k in _C}, None, ("eps_abs", "eps_rel"), (1e-6, 1e-6))
    )
    if solver == "OSQP":
        try:
            from . import osqp_

            native = osqp_.NATIVE
        except ImportError:
            native = None
    if native is not None:
        native = native | _CVXPY_KW
    common = dict(common)
    common.setdefault("verbose", ("verbose",))
    return SettingsSpec(
        backend=f"cvxpy (solver {solver})",
        common=common,
        native=native,
        warm_start=False,
        tolerance=tol,
        tolerance_defaults=tol_def,
    )


def _same(M1: Any, M2: Any) -> bool:
    if M1 is M2:
        return True
    if M1.shape != M2.shape:
        return False
    if sp.issparse(M1) or sp.issparse(M2):
        return (sp.csc_matrix(M1) != sp.csc_matrix(M2)).nnz == 0
    return bool(np.array_equal(M1, M2))


def _rows(qp: QP) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    eq = (qp.l == qp.u) & np.isfinite(qp.u)
    up = ~eq & np.isfinite(qp.u)
    lo = ~eq & np.isfinite(qp.l)
    return eq, up, lo


@dataclass
class _Built:
    P: Any
    A: Any
    pattern: bytes
    problem: cp.Problem
    x: cp.Variable
    q: cp.Parameter
    b: cp.Parameter | None
    u: cp.Parameter | None
    l: cp.Parameter | None
    c_eq: Any
    c_up: Any
    c_lo: Any


def _build(qp: QP, eq: np.ndarray, up: np.ndarray, lo: np.ndarray, pattern: bytes) -> _Built:
    n = qp.n
    A = sp.csr_matrix(qp.A) if qp.is_sparse else qp.A
    x = cp.Variable(n, name="x")
    q = cp.Parameter(n, name="q")
    # psd_wrap: P is PSD by contract; skip cvxpy's eigenvalue check, which rejects PSD-but-singular
    # matrices at rounding level
    obj = 0.5 * cp.quad_form(x, cp.psd_wrap(qp.P)) + q @ x
    cons = []
    b = u = l = None
    c_eq = c_up = c_lo = None
    if eq.any():
        b = cp.Parameter(int(eq.sum()), name="b")
        c_eq = A[eq] @ x == b
        cons.append(c_eq)
    if up.any():
        u = cp.Parameter(int(up.sum()), name="u")
        c_up = A[up] @ x <= u
        cons.append(c_up)
    if lo.any():
        l = cp.Parameter(int(lo.sum()), name="l")
        c_lo = A[lo] @ x >= l
        cons.append(c_lo)
    problem = cp.Problem(cp.Minimize(obj), cons)
    return _Built(qp.P, qp.A, pattern, problem, x, q, b, u, l, c_eq, c_up, c_lo)


class CvxpyBackend(Backend):
    name = "cvxpy"
    detects_infeasibility = True
    honours_warm_start = False

    def settings_spec(self, settings: dict[str, Any] | None = None) -> SettingsSpec:
        return _spec((settings or {}).get("solver", DEFAULT_SOLVER))

    def __init__(self) -> None:
        self._cache: OrderedDict[int, _Built] = OrderedDict()
        self._key = 0

    def clear_cache(self) -> None:
        """Forget the compiled cvxpy problems (see :mod:`solvers.cache`)."""
        self._cache.clear()

    def _get(self, qp: QP) -> tuple[_Built, np.ndarray, np.ndarray, np.ndarray]:
        eq, up, lo = _rows(qp)
        pattern = np.concatenate([eq, up, lo]).tobytes()
        for k, built in self._cache.items():
            if built.pattern == pattern and _same(built.P, qp.P) and _same(built.A, qp.A):
                self._cache.move_to_end(k)
                return built, eq, up, lo
        built = _build(qp, eq, up, lo, pattern)
        self._key += 1
        self._cache[self._key] = built
        while len(self._cache) > _CACHE_SIZE:
            self._cache.popitem(last=False)
        return built, eq, up, lo

    def solve(self, qp: QP, *, warm_start: Any = None, **settings: Any) -> Solution:
        solver = settings.get("solver", DEFAULT_SOLVER)
        if not isinstance(solver, str) or solver not in cp.installed_solvers():
            raise InvalidSettingError(
                f"solver: cvxpy solver {solver!r} is not installed; installed: "
                f"{cp.installed_solvers()}"
            )
        settings, record = self.native_settings(settings)
        settings.pop("solver", None)
        used = {"solver": solver, **settings, **record}
        t0 = time.perf_counter()
        built, eq, up, lo = self._get(qp)
        built.q.value = qp.q
        if built.b is not None:
            built.b.value = qp.u[eq]
        if built.u is not None:
            built.u.value = qp.u[up]
        if built.l is not None:
            built.l.value = qp.l[lo]
        built.x.value = None
        try:
            built.problem.solve(solver=solver, **settings)
        except TypeError as exc:  # a native name the solver's interface rejects
            raise InvalidSettingError(f"invalid setting for cvxpy solver {solver}: {exc}") from None
        except cp.error.SolverError as exc:
            return failed_solution(
                qp,
                self.name,
                solve_time=time.perf_counter() - t0,
                settings=used,
                message=f"SolverError: {exc}",
            )
        dt = time.perf_counter() - t0
        st = built.problem.status
        status = _STATUS.get(st, Status.ERROR)
        stats = built.problem.solver_stats
        iters = int(stats.num_iters) if stats is not None and stats.num_iters is not None else 0
        extras = {"native_status": st}
        xv = built.x.value
        if status in (Status.PRIMAL_INFEASIBLE, Status.DUAL_INFEASIBLE) or xv is None:
            if status in (Status.SOLVED, Status.SOLVED_INACCURATE, Status.MAX_ITER):
                status = Status.ERROR  # no point came back
            sol = failed_solution(
                qp, self.name, status, solve_time=dt, iterations=iters, settings=used
            )
            sol.extras.update(extras)
            return sol
        x = np.asarray(xv, dtype=np.float64).reshape(qp.n)
        y = np.zeros(qp.m)
        # cvxpy's duals are ≥ 0 for both `Ax <= u` and `Ax >= l`; equality duals enter the
        # Lagrangian with + sign.  OSQP's y: + on upper bounds, − on lower bounds.
        for c, mask, sign in ((built.c_eq, eq, 1.0), (built.c_up, up, 1.0), (built.c_lo, lo, -1.0)):
            if c is None:
                continue
            dv = c.dual_value
            if dv is None:
                y[:] = np.nan
                break
            y[mask] += sign * np.asarray(dv, dtype=np.float64).reshape(-1)
        finite_y = bool(np.all(np.isfinite(y)))
        return Solution(
            x=x,
            y=y,
            status=status,
            objective=qp.objective(x),
            iterations=iters,
            solve_time=dt,
            primal_residual=qp.constraint_violation(x),
            dual_residual=qp.dual_residual(x, y) if finite_y else float("nan"),
            backend=self.name,
            settings=used,
            extras=extras,
        )


def make_backend() -> Backend:
    return CvxpyBackend()
