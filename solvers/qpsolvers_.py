"""Backends ``qpsolvers:<name>``: any QP solver that the ``qpsolvers`` package finds installed.

Each problem goes through :meth:`QP.to_qpsolvers` (``G = [A[up]; −A[lo]]``, ``Aeq = A[eq]``) and
``qpsolvers.solve_problem(Problem(...), solver=name, **settings)``.  Settings: the common
vocabulary, mapped per solver (:data:`SPECS`), and the native solver's keyword arguments, checked
against its known names (qpsolvers itself would pass an unknown one on, where PIQP ignores it and
others fail); an unknown name raises :class:`~solvers.errors.InvalidSettingError`.  qpsolvers
defaults to ``verbose=False``.  ``qpsolvers`` is imported on first use, not at module import.

qpsolvers' duals follow the same sign convention as ours (``Px + q + Gᵀz + Aᵀy = 0``), so they
map back to OSQP's ``y`` over our rows as ``y[eq] = y_qp``, ``y[up] += z[:n_up]`` and
``y[lo] −= z[n_up:]``.

Status: ``found`` becomes ``SOLVED`` only after we check the residuals ourselves (a solver may
report success on a poor point): otherwise ``SOLVED_INACCURATE``.  When not found, the solver's own
status (in ``Solution.extras`` where qpsolvers keeps it) tells infeasibility apart; solvers whose
status qpsolvers does not expose get ``ERROR`` and ``detects_infeasibility = False``.
"""

from __future__ import annotations

import re
import time
import warnings
from typing import Any

import numpy as np
import scipy.sparse as sp

from .base import Backend, failed_solution
from .errors import UnknownBackendError
from .problem import QP
from .settings import OSQP_NATIVE, SettingsSpec
from .solution import Solution, Status

__all__ = [
    "QpsolversBackend",
    "installed_solvers",
    "make_backend",
    "RESIDUAL_RTOL",
    "GROSS_RTOL",
    "EXCLUDED",
    "SPECS",
]

#: a "found" point whose scaled primal or dual residual exceeds this is reported SOLVED_INACCURATE
#: (scaled as OSQP does: primal by max(1, ‖Ax‖∞), dual by max(1, ‖Px‖∞, ‖Aᵀy‖∞, ‖q‖∞))
RESIDUAL_RTOL = 1e-4
#: a "found" point whose scaled primal residual exceeds this is no solution at all: ERROR
GROSS_RTOL = 1e-2

# Solvers qpsolvers may list that we do not offer, and why.  Every solver installed here was checked
# on random feasible QPs, projection-like QPs, and the Maros–Meszaros subset in the tests.
EXCLUDED: dict[str, str] = {
    # Offered with caveats instead: quadprog (needs P positive definite: ERROR otherwise), daqp and
    # quadprog (qpsolvers does not expose their infeasibility status: detects_infeasibility=False),
    # proxqp (unreliable infeasibility claims, see _DETECTS), scs (first order: ask for accuracy).
    "highs": (
        "HiGHS 1.15's QP solver stops with 'Non-convex' (HighsStatus::Error) on convex "
        "projection-like QPs with P = I, and on QSHARE1B claims optimality 1e-2 off the optimum"
    ),
    "jaxopt_osqp": "jaxopt's BoxOSQP in float32 by default; too inaccurate for our tolerances",
    "gurobi": "commercial: license-dependent behaviour, not tested here",
    "mosek": "commercial: license-dependent behaviour, not tested here",
    "cvxopt": "its QP solver needs rank([P; A; G]) = n and fails on our PSD problems",
}

_EXCLUDED = EXCLUDED

_C = ("eps_abs", "eps_rel", "max_iter", "time_limit", "verbose")
_OSQP_NATIVE = OSQP_NATIVE | {"raise_error"}  # qpsolvers adds raise_error
#: per qpsolvers solver: common -> native names, native names (None: unchecked), whether a warm
#: start (qpsolvers' ``initvals``) is used, stated tolerance keys and defaults
SPECS: dict[str, tuple[dict, frozenset | None, bool, tuple, tuple]] = {
    "clarabel": (
        {
            "eps_abs": ("tol_gap_abs", "tol_feas"),
            "eps_rel": ("tol_gap_rel",),
            "max_iter": ("max_iter",),
            "time_limit": ("time_limit",),
        },
        None,  # filled from solvers.clarabel_ in spec_for
        False,
        ("tol_feas", "tol_feas"),
        (1e-8, 1e-8),
    ),
    "osqp": ({k: (k,) for k in _C}, _OSQP_NATIVE, True, ("eps_abs", "eps_rel"), (1e-3, 1e-3)),
    "piqp": (
        {"eps_abs": ("eps_abs",), "eps_rel": ("eps_rel",), "max_iter": ("max_iter",)},
        frozenset(
            {
                "backend",
                "check_duality_gap",
                "compute_timings",
                "delta_init",
                "eps_abs",
                "eps_dual_inf",
                "eps_duality_gap_abs",
                "eps_duality_gap_rel",
                "eps_primal_inf",
                "eps_rel",
                "infeasibility_threshold",
                "iterative_refinement_always_enabled",
                "iterative_refinement_eps_abs",
                "iterative_refinement_eps_rel",
                "iterative_refinement_max_iter",
                "iterative_refinement_min_improvement_rate",
                "iterative_refinement_static_regularization_eps",
                "iterative_refinement_static_regularization_rel",
                "kkt_solver",
                "max_factor_retires",
                "max_iter",
                "num_threads",
                "preconditioner_iter",
                "preconditioner_reuse_on_update",
                "preconditioner_scale_cost",
                "reg_finetune_dual_update_threshold",
                "reg_finetune_lower_limit",
                "reg_finetune_primal_update_threshold",
                "reg_lower_limit",
                "rho_init",
                "tau",
            }
        ),
        False,  # qpsolvers: "warm-start values are ignored by PIQP"
        ("eps_abs", "eps_rel"),
        (1e-8, 1e-9),
    ),
    # ProxQP tests no duality gap unless asked (check_duality_gap, off by default): at
    # eps_abs = eps_rel = 1e-6 it said SOLVED with gaps up to 6e-5 on unit-scale random QPs.  The
    # common tolerances mean primal, dual residual *and* gap, so they also set its gap tolerances
    # and switch the gap test on (a native check_duality_gap given explicitly wins).
    "proxqp": (
        {
            "eps_abs": ("eps_abs", "eps_duality_gap_abs", "check_duality_gap"),
            "eps_rel": ("eps_rel", "eps_duality_gap_rel", "check_duality_gap"),
            "max_iter": ("max_iter",),
        },
        frozenset(
            {
                "backend",
                "x",
                "y",
                "z",
                "rho",
                "mu_eq",
                "mu_in",
                "alpha_bcl",
                "alpha_gpdal",
                "bcl_update",
                "beta_bcl",
                "check_duality_gap",
                "cold_reset_mu_eq",
                "cold_reset_mu_in",
                "compute_preconditioner",
                "compute_timings",
                "default_H_eigenvalue_estimate",
                "default_mu_eq",
                "default_mu_in",
                "default_rho",
                "eps_abs",
                "eps_dual_inf",
                "eps_duality_gap_abs",
                "eps_duality_gap_rel",
                "eps_primal_inf",
                "eps_rel",
                "frequence_infeasibility_check",
                "initial_guess",
                "max_iter",
                "max_iter_in",
                "merit_function_type",
                "mu_max_eq_inv",
                "mu_max_in_inv",
                "mu_min_eq",
                "mu_min_in",
                "mu_update_factor",
                "nb_iterative_refinement",
                "preconditioner_accuracy",
                "preconditioner_max_iter",
                "primal_infeasibility_solving",
                "refactor_dual_feasibility_threshold",
                "refactor_rho_threshold",
                "sparse_backend",
                "update_preconditioner",
                "manual_minimal_H_eigenvalue",
            }
        ),
        True,  # initvals -> ProxQP's x
        ("eps_abs", "eps_rel"),
        (1e-5, 0.0),
    ),
    "daqp": (
        {"eps_abs": ("primal_tol",), "max_iter": ("iter_limit",)},
        frozenset(
            {
                "primal_tol",
                "dual_tol",
                "zero_tol",
                "pivot_tol",
                "progress_tol",
                "cycle_tol",
                "iter_limit",
                "fval_bound",
                "eps_prox",
                "eta_prox",
                "rho_soft",
                "rel_subopt",
                "abs_subopt",
                "sing_tol",
                "refactor_tol",
                "eq_reduction",
                "presolve",
                "time_limit",
            }
        ),
        False,  # qpsolvers: "warm-start values are ignored by DAQP"
        ("primal_tol", None),
        (1e-6, 0.0),
    ),
    "quadprog": ({}, frozenset({"factorized"}), False, (None, None), (1e-9, 1e-9)),
    "scs": (
        {
            "eps_abs": ("eps_abs",),
            "eps_rel": ("eps_rel",),
            "max_iter": ("max_iters",),
            "time_limit": ("time_limit_secs",),
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
                "acceleration_lookback",
                "acceleration_interval",
                "write_data_filename",
                "log_csv_filename",
                "use_indirect",
                "gpu",
                "mkl",
            }
        ),
        True,  # initvals -> SCS's x
        ("eps_abs", "eps_rel"),
        (1e-4, 1e-4),
    ),
}


def spec_for(solver: str) -> SettingsSpec:
    """The settings spec of ``qpsolvers:<solver>`` (unchecked pass-through for other solvers)."""
    common, native, warm, tol, tol_def = SPECS.get(
        solver, ({k: (k,) for k in _C}, None, False, ("eps_abs", "eps_rel"), (1e-6, 1e-6))
    )
    if solver == "clarabel":
        from .clarabel_ import NATIVE as native
    common = dict(common)
    common["verbose"] = ("verbose",)  # qpsolvers' own keyword, for every solver
    return SettingsSpec(
        backend=f"qpsolvers:{solver}",
        common=common,
        native=None if native is None else native | {"verbose"},
        warm_start=warm,
        tolerance=tol,
        tolerance_defaults=tol_def,
        convert=_CONVERT.get(solver, {}),
    )


def _switch_on(_value: Any) -> bool:
    return True


#: per solver: native keys a common value sets through a conversion (see SettingsSpec.convert)
_CONVERT: dict[str, dict[str, Any]] = {"proxqp": {"check_duality_gap": _switch_on}}


# Solvers whose failure status qpsolvers keeps in `Solution.extras` (so infeasibility can be told).
_STATUS_IN_EXTRAS = {"clarabel", "osqp", "piqp", "proxqp", "scs", "qpalm", "kvxopt", "ecos"}
# ...and of those, the ones whose infeasibility claims we rely on (`detects_infeasibility`).
# ProxQP is left out: it did not detect dual infeasibility of an unbounded LP (MAX_ITER) and it
# claimed PRIMAL_INFEASIBLE on feasible problems (QPCBLEND, QSHARE1B, small random QPs); its
# statuses are still mapped, but the tests only require that it never reports a wrong SOLVED.
_DETECTS = _STATUS_IN_EXTRAS - {"proxqp"}


def installed_solvers() -> list[str]:
    """qpsolvers' installed solvers usable on our QPs (``EXCLUDED`` says why not the rest)."""
    import qpsolvers

    return [s for s in qpsolvers.available_solvers if s not in EXCLUDED]


def _norm(s: str) -> str:
    return re.sub(r"[^a-z]", "", s.lower())


def _native_status(extras: Any) -> str | None:
    if not isinstance(extras, dict):
        return None
    for key in ("status", "info"):
        v = extras.get(key)
        if v is None:
            continue
        if isinstance(v, dict):  # scs: info dict with a "status" string
            v = v.get("status", None)
            if v is None:
                continue
        st = getattr(v, "status", v)  # piqp/proxqp/osqp info objects carry .status
        return str(st)
    return None


def _map_failed(native: str | None) -> Status:
    if native is None:
        return Status.ERROR
    s = _norm(native)
    if "primalinfeasible" in s or s.startswith("infeasible"):
        return Status.PRIMAL_INFEASIBLE
    if "dualinfeasible" in s or s.startswith("unbounded"):
        return Status.DUAL_INFEASIBLE
    if "maxiter" in s or "maximumiter" in s or "iterlimit" in s or "iterationlimit" in s:
        return Status.MAX_ITER
    if "inaccurate" in s or "almostsolved" in s:
        return Status.SOLVED_INACCURATE
    return Status.ERROR


class QpsolversBackend(Backend):
    """One qpsolvers solver; ``settings`` go to ``qpsolvers.solve_problem`` untouched."""

    def __init__(self, solver: str) -> None:
        import qpsolvers

        if solver not in qpsolvers.available_solvers:
            raise UnknownBackendError(
                f"qpsolvers has no installed solver {solver!r}; installed: "
                f"{', '.join(qpsolvers.available_solvers)}"
            )
        if solver in EXCLUDED:
            raise UnknownBackendError(
                f"qpsolvers solver {solver!r} is not offered: {_EXCLUDED[solver]}"
            )
        self.solver = solver
        self.name = f"qpsolvers:{solver}"
        self.detects_infeasibility = solver in _DETECTS
        self._status_known = solver in _STATUS_IN_EXTRAS
        self._sparse = solver in qpsolvers.sparse_solvers
        self._spec = spec_for(solver)
        self.honours_warm_start = self._spec.warm_start

    def settings_spec(self, settings: dict[str, Any] | None = None) -> SettingsSpec:
        return self._spec

    def _matrices(self, qp: QP) -> dict[str, Any]:
        d = qp.to_qpsolvers()
        conv = (
            (lambda M: sp.csc_matrix(M))
            if self._sparse
            else (lambda M: M.toarray() if sp.issparse(M) else np.asarray(M))
        )
        for k in ("P", "G", "A"):
            if d[k] is not None:
                d[k] = conv(d[k])
        return d

    def _to_y(self, qp: QP, sol: Any) -> np.ndarray:
        eq = qp.l == qp.u
        up = ~eq & np.isfinite(qp.u)
        lo = ~eq & np.isfinite(qp.l)
        n_eq, n_up, n_lo = int(eq.sum()), int(up.sum()), int(lo.sum())
        y = np.zeros(qp.m)
        zy = None if sol.y is None else np.asarray(sol.y, dtype=np.float64).reshape(-1)
        zz = None if sol.z is None else np.asarray(sol.z, dtype=np.float64).reshape(-1)
        if n_eq:
            if zy is None or zy.size != n_eq:
                return np.full(qp.m, np.nan)
            y[eq] = zy
        if n_up + n_lo:
            if zz is None or zz.size != n_up + n_lo:
                return np.full(qp.m, np.nan)
            y[up] += zz[:n_up]
            y[lo] -= zz[n_up:]
        return y

    def solve(self, qp: QP, *, warm_start: Any = None, **settings: Any) -> Solution:
        import qpsolvers

        settings, record = self.native_settings(settings)
        used = {"solver": self.solver, **settings, **record}
        kw = dict(settings)
        if self.honours_warm_start and warm_start is not None and np.all(np.isfinite(warm_start.x)):
            kw.setdefault("initvals", np.asarray(warm_start.x, dtype=np.float64))
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                problem = qpsolvers.Problem(**self._matrices(qp))
                res = qpsolvers.solve_problem(problem, solver=self.solver, **kw)
            except Exception as exc:  # ProblemError (e.g. P not PD for quadprog), SolverError...
                return failed_solution(
                    qp,
                    self.name,
                    solve_time=time.perf_counter() - t0,
                    settings=used,
                    message=f"{type(exc).__name__}: {exc}",
                )
        dt = time.perf_counter() - t0
        msgs = [str(w.message) for w in caught]
        native = _native_status(res.extras)
        extras: dict[str, Any] = {"native_status": native, "found": bool(res.found)}
        if msgs:
            extras["warnings"] = msgs
        x = None if res.x is None else np.asarray(res.x, dtype=np.float64).reshape(-1)
        iters = _iterations(res.extras)
        if not res.found or x is None or x.shape != (qp.n,) or not np.all(np.isfinite(x)):
            status = _map_failed(native) if self._status_known else Status.ERROR
            if status in (Status.SOLVED, Status.SOLVED_INACCURATE) and (
                x is None or not np.all(np.isfinite(x))
            ):
                status = Status.ERROR
            ok_x = x is not None and x.shape == (qp.n,) and bool(np.all(np.isfinite(x)))
            keep_x = ok_x and status not in (Status.PRIMAL_INFEASIBLE, Status.DUAL_INFEASIBLE)
            sol = failed_solution(
                qp,
                self.name,
                status,
                x=x if keep_x else None,
                solve_time=dt,
                iterations=iters,
                settings=used,
            )
            sol.extras.update(extras)
            return sol
        y = self._to_y(qp, res)
        prim = qp.constraint_violation(x)
        dual = qp.dual_residual(x, y) if np.all(np.isfinite(y)) else float("nan")
        Ax = qp.A @ x if qp.m else np.zeros(0)
        if prim > GROSS_RTOL * max(1.0, float(np.max(np.abs(Ax), initial=0.0))):
            # "found" at a point that violates the constraints grossly (DAQP does this on
            # inconsistent equalities): not a solution at all
            status = Status.ERROR
            extras["message"] = f"solver reported success at an infeasible point ({prim:.3g})"
        elif _residuals_ok(qp, x, y, prim, dual):
            status = Status.SOLVED
        else:
            status = Status.SOLVED_INACCURATE
        return Solution(
            x=x,
            y=y,
            status=status,
            objective=qp.objective(x),
            iterations=iters,
            solve_time=dt,
            primal_residual=prim,
            dual_residual=dual,
            backend=self.name,
            settings=used,
            extras=extras,
        )


def _residuals_ok(qp: QP, x: np.ndarray, y: np.ndarray, prim: float, dual: float) -> bool:
    """Primal residual, dual residual and duality gap, each scaled as OSQP scales them.

    Multipliers of the wrong sign for a bound (``y > 0`` where ``u = inf``, ``y < 0`` where
    ``l = -inf``) are dropped first, so they show up in the dual residual instead of making the
    support function infinite: a solver may return ``1e-18`` there.
    """
    Ax = qp.A @ x if qp.m else np.zeros(0)
    p_scale = max(1.0, float(np.max(np.abs(Ax), initial=0.0)))
    if prim > RESIDUAL_RTOL * p_scale:
        return False
    if not np.isfinite(dual):
        return True  # solver gave no duals: only the primal side can be checked
    y = np.where(((y > 0) & ~np.isfinite(qp.u)) | ((y < 0) & ~np.isfinite(qp.l)), 0.0, y)
    Px = qp.P @ x
    ATy = qp.A.T @ y if qp.m else np.zeros(qp.n)
    d_scale = max(
        1.0, float(np.max(np.abs(Px))), float(np.max(np.abs(ATy))), float(np.max(np.abs(qp.q)))
    )
    if float(np.max(np.abs(Px + qp.q + ATy))) > RESIDUAL_RTOL * d_scale:
        return False
    # duality gap xᵀPx + qᵀx + S(y), S the support function of [l, u]
    pos, neg = y > 0, y < 0
    s_terms = np.concatenate([qp.u[pos] * y[pos], qp.l[neg] * y[neg]])
    xPx, qx = float(x @ Px), float(qp.q @ x)
    gap = abs(xPx + qx + float(s_terms.sum()))
    g_scale = max(1.0, abs(xPx), abs(qx), float(np.max(np.abs(s_terms), initial=0.0)))
    return gap <= RESIDUAL_RTOL * g_scale


def _iterations(extras: Any) -> int:
    if not isinstance(extras, dict):
        return 0
    for key in ("iterations", "iter"):  # quadprog, scs
        if key in extras:
            try:
                return int(extras[key])
            except (TypeError, ValueError):
                return 0
    info = extras.get("info")
    for attr in ("iter", "iterations", "iter_ext"):
        v = info.get(attr) if isinstance(info, dict) else getattr(info, attr, None)
        if v is not None:
            try:
                return int(v)
            except (TypeError, ValueError):
                pass
    return 0


def make_backend(solver_name: str) -> Backend:
    return QpsolversBackend(solver_name)
