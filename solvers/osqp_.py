"""OSQP backend (native ``osqp`` ≥ 1.0 API): first-order ADMM with a sparse factorisation.

``solve`` sets up one ``osqp.OSQP`` object per problem.  ``solve_batch`` sets up **once per
batch** (the factorisation of the KKT matrix depends only on ``P``, ``A`` and ``rho``), then for
each problem calls ``update(q=, l=, u=)`` and warm-starts from the previous problem's solution (or
from ``warm_start[i]`` when a :class:`~solvers.solution.BatchSolution` is given).

Settings are OSQP's own (``eps_abs``, ``eps_rel``, ``max_iter``, ``polishing``, ...), which include
the common vocabulary under the same names; the only default we change is ``verbose=False``.
Every setting actually used is recorded on the solution; an unknown name raises
:class:`~solvers.errors.InvalidSettingError`.

For infeasible problems OSQP fills ``x``/``y`` with a NaN placeholder (``2143289344.0``, the bits of
a float NaN read as a number); it is never read as a point: ``x``, ``y``, the objective and the
residuals are NaN and the certificate is in ``extras``.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import osqp
import scipy.sparse as sp

from .base import Backend, failed_solution
from .errors import InvalidSettingError
from .problem import QP, QPBatch
from .settings import OSQP_NATIVE, SettingsSpec
from .solution import BatchSolution, Solution, Status

__all__ = ["OSQPBackend", "make_backend"]

_S = osqp.SolverStatus
_STATUS = {
    int(_S.OSQP_SOLVED): Status.SOLVED,
    int(_S.OSQP_SOLVED_INACCURATE): Status.SOLVED_INACCURATE,
    int(_S.OSQP_MAX_ITER_REACHED): Status.MAX_ITER,
    int(_S.OSQP_PRIMAL_INFEASIBLE): Status.PRIMAL_INFEASIBLE,
    int(_S.OSQP_PRIMAL_INFEASIBLE_INACCURATE): Status.PRIMAL_INFEASIBLE,
    int(_S.OSQP_DUAL_INFEASIBLE): Status.DUAL_INFEASIBLE,
    int(_S.OSQP_DUAL_INFEASIBLE_INACCURATE): Status.DUAL_INFEASIBLE,
    # OSQP_TIME_LIMIT_REACHED, OSQP_NON_CVX, OSQP_SIGINT, OSQP_UNSOLVED -> ERROR (the default)
}
#: OSQP's own setting names (osqp 1.x)
NATIVE = OSQP_NATIVE
#: the common vocabulary: OSQP's names are the common ones
COMMON = {k: (k,) for k in ("eps_abs", "eps_rel", "max_iter", "time_limit", "verbose")}
SPEC = SettingsSpec(
    backend="osqp",
    common=COMMON,
    native=NATIVE,
    warm_start=True,
    tolerance=("eps_abs", "eps_rel"),
    tolerance_defaults=(1e-3, 1e-3),
)
#: OSQP's float NaN placeholder (0x7FC00000 read as an integer) in x/y of infeasible problems
NAN_PLACEHOLDER = 2143289344.0
# A time limit is not an iteration limit: the caller asked for a budget in seconds, and the iterate
# is no more trustworthy than an ERROR's.  NON_CVX means P is not PSD.


def _used_settings(solver: osqp.OSQP) -> dict[str, Any]:
    s = solver.settings
    out: dict[str, Any] = {}
    for k in dir(s):
        if k.startswith("_"):
            continue
        v = getattr(s, k)
        if isinstance(v, (bool, int, float, str)):
            out[k] = v
        elif not callable(v):
            out[k] = str(v)
    return out


def _finite(v: np.ndarray | None) -> bool:
    return v is not None and bool(np.all(np.isfinite(v)))


def _point(v: Any) -> np.ndarray | None:
    """OSQP's x or y as float64, or ``None`` when it is non-finite or OSQP's NaN placeholder."""
    if v is None:
        return None
    v = np.array(v, dtype=np.float64)
    if not np.all(np.isfinite(v)) or np.any(v == NAN_PLACEHOLDER):
        return None
    return v


class OSQPBackend(Backend):
    name = "osqp"
    detects_infeasibility = True
    honours_warm_start = True

    def settings_spec(self, settings: dict[str, Any] | None = None) -> SettingsSpec:
        return SPEC

    # -------------------------------------------------------------- helpers
    @staticmethod
    def _setup(P, A, q, l, u, settings: dict[str, Any]) -> osqp.OSQP:
        solver = osqp.OSQP()
        P = sp.triu(sp.csc_matrix(P), format="csc")
        A = sp.csc_matrix(A)
        # verbose=False is the one default we change; the caller may still turn it back on
        solver.setup(P=P, q=q, A=A, l=l, u=u, **({"verbose": False} | settings))
        return solver

    def _result(self, qp: QP, res: Any, dt: float, used: dict[str, Any]) -> Solution:
        info = res.info
        status = _STATUS.get(int(info.status_val), Status.ERROR)
        extras = {
            "native_status": str(info.status),
            "run_time": float(info.run_time),
            "rho_estimate": float(getattr(info, "rho_estimate", np.nan)),
        }
        if status is Status.PRIMAL_INFEASIBLE and res.prim_inf_cert is not None:
            extras["prim_inf_cert"] = np.array(res.prim_inf_cert, dtype=np.float64)
        if status is Status.DUAL_INFEASIBLE and res.dual_inf_cert is not None:
            extras["dual_inf_cert"] = np.array(res.dual_inf_cert, dtype=np.float64)
        infeasible = status in (Status.PRIMAL_INFEASIBLE, Status.DUAL_INFEASIBLE)
        # an infeasible problem has no point: never read x/y (OSQP's NaN placeholder) then
        x = None if infeasible else _point(res.x)
        y = None if infeasible else _point(res.y)
        if x is None:
            if status in (Status.SOLVED, Status.SOLVED_INACCURATE, Status.MAX_ITER):
                status = Status.ERROR  # no usable point came back
            sol = failed_solution(
                qp,
                self.name,
                status,
                x=None,
                y=None,
                solve_time=dt,
                iterations=int(info.iter),
                settings=used,
            )
            sol.extras.update(extras)
            return sol
        y = y if _finite(y) and y.shape == (qp.m,) else np.full(qp.m, np.nan)
        return Solution(
            x=x,
            y=y,
            status=status,
            objective=qp.objective(x),
            iterations=int(info.iter),
            solve_time=dt,
            primal_residual=qp.constraint_violation(x),
            dual_residual=qp.dual_residual(x, y) if _finite(y) else float("nan"),
            backend=self.name,
            settings=used,
            extras=extras,
        )

    # ------------------------------------------------------------------ API
    def solve(self, qp: QP, *, warm_start: Any = None, **settings: Any) -> Solution:
        settings, record = self.native_settings(settings)
        t0 = time.perf_counter()
        try:
            solver = self._setup(qp.P, qp.A, qp.q, qp.l, qp.u, settings)
        except (ValueError, TypeError) as exc:
            if "Unrecognized settings" in str(exc):
                raise InvalidSettingError(str(exc)) from None
            return failed_solution(
                qp,
                self.name,
                solve_time=time.perf_counter() - t0,
                settings=dict(settings),
                message=f"OSQP setup failed: {exc!r}",
            )
        except Exception as exc:  # OSQPException (e.g. non-convex P) -> status, not exception
            return failed_solution(
                qp,
                self.name,
                solve_time=time.perf_counter() - t0,
                settings=dict(settings),
                message=f"OSQP setup failed: {exc!r}",
            )
        used = _used_settings(solver) | record
        if warm_start is not None and _finite(warm_start.x) and _finite(warm_start.y):
            solver.warm_start(x=warm_start.x, y=warm_start.y)
        res = solver.solve(raise_error=False)
        return self._result(qp, res, time.perf_counter() - t0, used)

    def solve_batch(
        self, batch: QPBatch, *, warm_start: Any = None, **settings: Any
    ) -> BatchSolution:
        settings, record = self.native_settings(settings)
        t_start = time.perf_counter()
        try:
            solver = self._setup(batch.P, batch.A, batch.q[0], batch.l[0], batch.u[0], settings)
        except (ValueError, TypeError) as exc:
            if "Unrecognized settings" in str(exc):
                raise InvalidSettingError(str(exc)) from None
            return self._all_failed(batch, t_start, settings, exc)
        except Exception as exc:
            return self._all_failed(batch, t_start, settings, exc)
        used = _used_settings(solver) | record
        warm = bool(used.get("warm_starting", True))
        rho0 = float(used["rho"])
        sols: list[Solution] = []
        prev: Solution | None = None
        for i in range(len(batch)):
            t0 = time.perf_counter()
            if i:
                solver.update(q=batch.q[i], l=batch.l[i], u=batch.u[i])
            ws = warm_start[i] if warm_start is not None else prev
            if warm and ws is not None:
                usable = _finite(ws.x) and _finite(ws.y)
                if warm_start is None:  # along the batch: only from a (nearly) solved neighbour
                    usable = usable and ws.status in (Status.SOLVED, Status.SOLVED_INACCURATE)
                if usable:
                    solver.warm_start(x=ws.x, y=ws.y)
                else:
                    # the previous problem failed (e.g. infeasible: OSQP's iterate diverged and
                    # adaptive rho drifted); OSQP would otherwise start from that iterate and that
                    # rho, so start cold instead: zero iterate, the initial rho
                    solver.warm_start(x=np.zeros(batch.n), y=np.zeros(batch.m))
                    solver.update_settings(rho=rho0)
            res = solver.solve(raise_error=False)
            sol = self._result(batch[i], res, time.perf_counter() - t0, used)
            sols.append(sol)
            prev = sol
        return BatchSolution.stack(sols, self.name, time.perf_counter() - t_start, settings=used)

    def _all_failed(self, batch, t_start, settings, exc) -> BatchSolution:
        sols = [
            failed_solution(qp, self.name, settings=dict(settings), message=f"OSQP setup: {exc!r}")
            for qp in batch
        ]
        return BatchSolution.stack(sols, self.name, time.perf_counter() - t_start)


def make_backend() -> Backend:
    return OSQPBackend()
