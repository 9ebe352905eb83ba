"""QP problem/solution types and swappable backends.

Backends: OSQP, Clarabel, qpsolvers, cvxpy and a batched, jitted ADMM in JAX.

Knows nothing of vehicles.  Public contract::

    from solvers import QP, QPBatch, solve, solve_batch, solve_qp, available_backends, Status

Importing :mod:`solvers` imports NumPy and SciPy only; each backend's package (JAX, osqp, cvxpy,
qpsolvers, ...) is imported when that backend is first used.
"""

from .base import Backend
from .errors import (
    BackendUnavailableError,
    InvalidSettingError,
    NonConvexError,
    UnknownBackendError,
)
from .problem import QP, QPBatch, check_convex
from .registry import (
    available_backends,
    get_backend,
    register_backend,
    solve,
    solve_batch,
    solve_qp,
)
from .settings import COMMON_SETTINGS, WarmStart
from .solution import BatchSolution, Solution, Status

__all__ = [
    "QP",
    "QPBatch",
    "Solution",
    "BatchSolution",
    "Status",
    "Backend",
    "WarmStart",
    "COMMON_SETTINGS",
    "BackendUnavailableError",
    "UnknownBackendError",
    "NonConvexError",
    "InvalidSettingError",
    "available_backends",
    "check_convex",
    "get_backend",
    "register_backend",
    "solve",
    "solve_batch",
    "solve_qp",
]
