"""QP problem/solution types and swappable backends.

Backends: OSQP, Clarabel, qpsolvers, cvxpy and a batched, jitted ADMM in JAX.

Knows nothing of vehicles.  Public contract::

    from solvers import QP, QPBatch, solve, solve_batch, available_backends, Status
"""

from .base import Backend
from .problem import QP, QPBatch
from .registry import (
    BackendUnavailableError,
    UnknownBackendError,
    available_backends,
    get_backend,
    register_backend,
    solve,
    solve_batch,
)
from .solution import BatchSolution, Solution, Status

__all__ = [
    "QP",
    "QPBatch",
    "Solution",
    "BatchSolution",
    "Status",
    "Backend",
    "BackendUnavailableError",
    "UnknownBackendError",
    "available_backends",
    "get_backend",
    "register_backend",
    "solve",
    "solve_batch",
]
