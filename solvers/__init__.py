"""QP problem/solution types and swappable backends.

Backends by name: ``clarabel``, ``osqp``, ``cvxpy``, ``qpsolvers:<name>`` (every solver qpsolvers
finds), and two batched, jitted solvers in JAX: ``admm`` (ADMM) and ``ipm`` (a primal–dual
interior-point method).  ``available_backends()`` lists those installed.

Knows nothing of vehicles.  Public contract::

    from solvers import QP, QPBatch, solve, solve_batch, solve_qp, available_backends, Status

Habits kept from qpsolvers/OSQP::

    sol = solve_qp(P, q, G, h, A, b, lb, ub, solver="osqp")   # solver= is an alias of backend=
    print(sol.status)            # SOLVED  (an IntEnum: sol.status == 1 still holds)
    sol.ok                       # True for SOLVED only
    sol.is_optimal(1e-6)         # primal, dual residual and duality gap all ≤ 1e-6
    sol.is_optimal(1e-6, 1e-6)   # each ≤ 1e-6 + 1e-6·scale: OSQP's test, what SOLVED promises
    sol.duality_gap()
    repr(sol)                    # Solution(SOLVED, objective=-0.75, n=2, m=3, ..., backend='osqp')
    batch = QPBatch.from_qpsolvers(P, qs, G, hs, lb=lb, ub=ub)   # qs (B, n), hs (B, k) or shared
    sols = solve_batch(batch, solver="ipm")
    sols.status_names, sols.ok   # ('SOLVED', ...), boolean array (B,)
    STATUS_CODES.SOLVED          # 1: the integer codes as plain ints (for array and JAX code)

A :class:`JaxProjector` is the contract of a jittable batched QP solve with ``P`` and ``A``
fixed (:func:`solvers.admm.admm_projector` builds one; the planner's projection runs it).

Importing :mod:`solvers` imports NumPy and SciPy only; each backend's package (JAX, osqp, cvxpy,
qpsolvers, ...) is imported when that backend is first used.
"""

from .base import Backend
from .diff import QPGrad, vjp
from .errors import (
    BackendUnavailableError,
    InvalidSettingError,
    NonConvexError,
    UnknownBackendError,
)
from .problem import QP, QPBatch, check_convex
from .protocols import JaxProjector, JaxQPResult
from .registry import (
    available_backends,
    get_backend,
    register_backend,
    solve,
    solve_batch,
    solve_qp,
)
from .settings import COMMON_SETTINGS, WarmStart
from .solution import STATUS_CODES, BatchSolution, Solution, Status, StatusCodes

__all__ = [
    "QP",
    "QPBatch",
    "Solution",
    "BatchSolution",
    "Status",
    "StatusCodes",
    "STATUS_CODES",
    "JaxProjector",
    "JaxQPResult",
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
    "QPGrad",
    "vjp",
]


def __getattr__(name: str):
    # ``solvers.jax`` (the differentiable JAX layer) is imported on first use: it imports JAX
    if name == "jax":
        import importlib

        return importlib.import_module(".jax", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
