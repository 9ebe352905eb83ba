"""The backend interface: every backend module provides one :class:`Backend` subclass."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from .problem import QP, QPBatch
from .settings import SettingsSpec, translate
from .solution import STATUS_CODES, BatchSolution, Solution, Status

__all__ = [
    "Backend",
    "RESIDUAL_FLAG_FACTOR",
    "failed_solution",
    "primal_tolerance",
    "residual_check",
]

#: a SOLVED whose unscaled primal residual exceeds this many times the backend's stated tolerance
#: is flagged in ``extras["residual_check"]`` ("orders of magnitude": rounding never gets there)
RESIDUAL_FLAG_FACTOR = 100.0


class Backend:
    """A QP solver selected by name.

    Subclasses implement :meth:`solve`; backends that can exploit a shared ``P``/``A`` override
    :meth:`solve_batch` (the default loops over :meth:`solve`, warm-starting each problem from
    ``warm_start`` when given).  Settings: the common vocabulary of :mod:`solvers.settings` and
    the solver's native names, translated by :meth:`native_settings` (override
    :meth:`settings_spec`); the settings actually used (the solver's defaults merged with the
    caller's) are recorded on the solution.  A backend never raises for a solver failure: it
    returns ``Status.ERROR``.  ``warm_start`` is anything with ``.x`` and ``.y``.

    A user backend that overrides nothing about settings passes them through unchecked.
    """

    name: str = "backend"
    #: whether the backend reports infeasibility certificates (tests rely on this flag)
    detects_infeasibility: bool = True
    #: whether a warm start is used (else the solution records ``warm_start: "ignored"``)
    honours_warm_start: bool = False

    def settings_spec(self, settings: dict[str, Any] | None = None) -> SettingsSpec:
        """How this backend reads the common settings (``settings``: for specs that depend on
        a setting, e.g. cvxpy's ``solver``).  Default: common names passed through as-is."""
        return SettingsSpec(
            backend=self.name,
            common={k: (k,) for k in ("eps_abs", "eps_rel", "max_iter", "time_limit", "verbose")},
            native=None,
        )

    def native_settings(self, settings: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
        """``(native keyword arguments, record of the common names)``; unknown names raise
        :class:`~solvers.errors.InvalidSettingError`."""
        return translate(self.settings_spec(settings), settings)

    def stated_tolerance(self, used: dict[str, Any]) -> tuple[float, float]:
        """``(eps_abs, eps_rel)`` the backend claims for a solve whose recorded settings are
        ``used``: what the residual check holds a ``SOLVED`` to."""
        return self.settings_spec(used).stated_tolerance(used)

    def clear_cache(self) -> None:
        """Forget what the backend keeps between calls (its setups for shared ``P``, ``A``);
        the next call rebuilds it, with the same results (see :mod:`solvers.cache`).  Default:
        nothing is kept."""

    def solve(self, qp: QP, *, warm_start: Solution | None = None, **settings: Any) -> Solution:
        raise NotImplementedError

    def solve_batch(
        self, batch: QPBatch, *, warm_start: BatchSolution | None = None, **settings: Any
    ) -> BatchSolution:
        t0 = time.perf_counter()
        sols = []
        for i, qp in enumerate(batch):
            ws = warm_start[i] if warm_start is not None else None
            sols.append(self.solve(qp, warm_start=ws, **settings))
        total = time.perf_counter() - t0
        return BatchSolution.stack(sols, self.name, total)


def failed_solution(
    qp: QP,
    backend: str,
    status: Status = Status.ERROR,
    *,
    x: np.ndarray | None = None,
    y: np.ndarray | None = None,
    solve_time: float = 0.0,
    iterations: int = 0,
    settings: dict[str, Any] | None = None,
    message: str = "",
) -> Solution:
    """A solution object for a failed solve: NaN ``x`` unless the solver gave an iterate."""
    x = np.full(qp.n, np.nan) if x is None else np.asarray(x, dtype=np.float64)
    y = np.full(qp.m, np.nan) if y is None else np.asarray(y, dtype=np.float64)
    finite = bool(np.all(np.isfinite(x)))
    return Solution(
        x=x,
        y=y,
        status=status,
        objective=qp.objective(x) if finite else float("nan"),
        iterations=iterations,
        solve_time=solve_time,
        primal_residual=qp.constraint_violation(x) if finite else float("nan"),
        dual_residual=(
            qp.dual_residual(x, y) if finite and bool(np.all(np.isfinite(y))) else float("nan")
        ),
        backend=backend,
        settings=settings or {},
        extras={"message": message} if message else {},
    )


def primal_tolerance(l: np.ndarray, u: np.ndarray, eps_abs: float, eps_rel: float) -> np.ndarray:
    """``eps_abs + eps_rel·max(1, ‖finite l, u‖∞)`` per problem (``l, u`` of shape (m,) or (B, m)).

    The relative part scales with the data's bounds, not with the iterate: a point whose
    ``‖Ax‖`` blew up cannot loosen it (OSQP's ``max(‖Ax‖∞, ‖z‖∞)`` can).
    """
    l2, u2 = np.atleast_2d(l), np.atleast_2d(u)
    fin = np.maximum(
        np.where(np.isfinite(l2), np.abs(l2), 0.0).max(axis=1, initial=0.0),
        np.where(np.isfinite(u2), np.abs(u2), 0.0).max(axis=1, initial=0.0),
    )
    tol = eps_abs + eps_rel * np.maximum(1.0, fin)
    return tol if np.ndim(l) == 2 else tol[0]


def residual_check(be: Backend, problem: QP | QPBatch, sol: Solution | BatchSolution) -> None:
    """Check every ``SOLVED`` answer's unscaled primal residual (float64) against the backend's
    stated tolerance; record the outcome in ``sol.extras["residual_check"]``.

    This flag changes nothing; where the residual exceeds :data:`RESIDUAL_FLAG_FACTOR` times the
    tolerance, ``extras["residual_check"]["result"]`` is ``"failed"`` (for a batch: a boolean
    array ``"failed"`` per problem).  The answer check that runs after it
    (:mod:`solvers.check`) is what weakens a status the point does not support.
    """
    try:
        eps_abs, eps_rel = be.stated_tolerance(sol.settings)
    except Exception:  # a user backend with odd settings: no stated tolerance to check against
        return
    tol = primal_tolerance(problem.l, problem.u, eps_abs, eps_rel)
    prim = np.asarray(sol.primal_residual, dtype=np.float64)
    solved = np.asarray(sol.status) == STATUS_CODES.SOLVED
    with np.errstate(invalid="ignore"):
        failed = solved & ~(prim <= RESIDUAL_FLAG_FACTOR * tol)
    info: dict[str, Any] = {
        "eps_abs": eps_abs,
        "eps_rel": eps_rel,
        "tolerance": tol if np.ndim(tol) else float(tol),
        "flag_factor": RESIDUAL_FLAG_FACTOR,
    }
    if isinstance(sol, BatchSolution):
        info.update(failed=failed, primal_residual=prim, n_failed=int(failed.sum()))
        info["result"] = "failed" if failed.any() else "passed"
    else:
        if not solved:
            return
        info.update(primal_residual=float(prim), result="failed" if bool(failed) else "passed")
    sol.extras["residual_check"] = info
