"""Clarabel backend (native API): interior point, high accuracy; the reference for the tests."""

from __future__ import annotations

import time
from typing import Any

import clarabel
import numpy as np

from .base import Backend, failed_solution
from .errors import InvalidSettingError
from .problem import QP
from .settings import SettingsSpec
from .solution import Solution, Status

_STATUS = {
    "Solved": Status.SOLVED,
    "AlmostSolved": Status.SOLVED_INACCURATE,
    "MaxIterations": Status.MAX_ITER,
    "MaxTime": Status.MAX_ITER,
    "PrimalInfeasible": Status.PRIMAL_INFEASIBLE,
    "AlmostPrimalInfeasible": Status.PRIMAL_INFEASIBLE,
    "DualInfeasible": Status.DUAL_INFEASIBLE,
    "AlmostDualInfeasible": Status.DUAL_INFEASIBLE,
}


#: Clarabel's own setting names
NATIVE = frozenset(k for k in dir(clarabel.DefaultSettings()) if not k.startswith("_"))
#: the common vocabulary in Clarabel's names (also used by cvxpy and qpsolvers with Clarabel)
COMMON = {
    "eps_abs": ("tol_gap_abs", "tol_feas"),
    "eps_rel": ("tol_gap_rel",),
    "max_iter": ("max_iter",),
    "time_limit": ("time_limit",),
    "verbose": ("verbose",),
}
SPEC = SettingsSpec(
    backend="clarabel",
    common=COMMON,
    native=NATIVE,
    warm_start=False,
    tolerance=("tol_feas", "tol_feas"),
    tolerance_defaults=(1e-8, 1e-8),
)


def _settings(user: dict[str, Any]) -> tuple[clarabel.DefaultSettings, dict[str, Any]]:
    s = clarabel.DefaultSettings()
    s.verbose = False  # quiet is the only default we change; everything else is Clarabel's
    for k, v in user.items():
        setattr(s, k, v)
    used = {
        k: getattr(s, k)
        for k in dir(s)
        if not k.startswith("_") and isinstance(getattr(s, k), (int, float, bool, str))
    }
    return s, used


class ClarabelBackend(Backend):
    name = "clarabel"
    honours_warm_start = False  # interior point: no warm start

    def settings_spec(self, settings: dict[str, Any] | None = None) -> SettingsSpec:
        return SPEC

    def solve(self, qp: QP, *, warm_start: Any = None, **settings: Any) -> Solution:
        native, record = self.native_settings(settings)
        try:
            s, used = _settings(native)
        except (TypeError, ValueError) as exc:  # a native name with a value of the wrong type
            raise InvalidSettingError(f"invalid Clarabel setting value: {exc}") from None
        used.update(record)
        P, q, A, b, cones = qp.to_clarabel()
        cone_objs = []
        for kind, size in cones:
            if size:
                cone_objs.append(
                    clarabel.ZeroConeT(size) if kind == "zero" else clarabel.NonnegativeConeT(size)
                )
        t0 = time.perf_counter()
        try:
            solver = clarabel.DefaultSolver(P, q, A, b, cone_objs, s)
            res = solver.solve()
        except Exception as exc:  # native failure -> status, never an exception
            return failed_solution(
                qp, self.name, solve_time=time.perf_counter() - t0, settings=used, message=str(exc)
            )
        dt = time.perf_counter() - t0
        status = _STATUS.get(str(res.status), Status.ERROR)
        x = np.asarray(res.x, dtype=np.float64)
        z = np.asarray(res.z, dtype=np.float64)
        y = qp.clarabel_row_map(z) if z.size == A.shape[0] else np.full(qp.m, np.nan)
        if not np.all(np.isfinite(x)):
            return failed_solution(qp, self.name, status=Status.ERROR, solve_time=dt, settings=used)
        extras: dict[str, Any] = {"native_status": str(res.status)}
        # at an infeasibility, Clarabel's (x, z) is the certificate, not a point: it goes to
        # extras, and the answer check (solvers.check) verifies it and sets x to NaN
        if status is Status.PRIMAL_INFEASIBLE and np.all(np.isfinite(y)):
            extras["prim_inf_cert"] = y
        elif status is Status.DUAL_INFEASIBLE:
            extras["dual_inf_cert"] = x
        return Solution(
            x=x,
            y=y,
            status=status,
            objective=qp.objective(x),
            iterations=int(res.iterations),
            solve_time=dt,
            primal_residual=qp.constraint_violation(x),
            dual_residual=qp.dual_residual(x, y) if np.all(np.isfinite(y)) else float("nan"),
            backend=self.name,
            settings=used,
            extras=extras,
        )


def make_backend() -> Backend:
    return ClarabelBackend()
