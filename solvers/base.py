"""The backend interface: every backend module provides one :class:`Backend` subclass."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from .problem import QP, QPBatch
from .solution import BatchSolution, Solution, Status

__all__ = ["Backend", "failed_solution"]


class Backend:
    """A QP solver selected by name.

    Subclasses implement :meth:`solve`; backends that can exploit a shared ``P``/``A`` override
    :meth:`solve_batch` (the default loops over :meth:`solve`, warm-starting each problem from
    ``warm_start`` when given).  Settings are passed straight through to the native solver; the
    settings actually used (the solver's defaults merged with the caller's) are recorded on the
    solution.  A backend never raises for a solver failure: it returns ``Status.ERROR``.
    """

    name: str = "backend"
    #: whether the backend reports infeasibility certificates (tests rely on this flag)
    detects_infeasibility: bool = True

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
