"""Backends by name, imported lazily.

``solve(qp, backend="clarabel")`` and ``solve_batch(batch, backend="admm")`` look the backend up
here.  Built in: ``clarabel``, ``osqp``, ``cvxpy``, ``admm`` and ``ipm`` (the last two batched
and jitted in JAX).  A backend whose package is missing raises :class:`BackendUnavailableError`
naming the package and the extra that installs it.  ``qpsolvers:<name>`` selects any solver that
the ``qpsolvers`` package finds installed.  Users add their own with :func:`register_backend`.

As in qpsolvers, ``solver=`` is accepted for ``backend=`` (``solve_qp(..., solver="osqp")``); a
qpsolvers solver name that is not a backend here (``solver="piqp"``) means ``"qpsolvers:piqp"``.
Both given and different is a :class:`ValueError` naming both, except for ``backend="cvxpy"``,
whose own ``solver=`` setting picks cvxpy's solver (``solve(qp, "cvxpy", solver="OSQP")``).
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
from collections.abc import Callable
from typing import Any

import numpy as np

from .base import Backend, residual_check
from .cache import BoundedCache
from .check import check_batch_solution, check_solution, confirm_inaccurate
from .errors import BackendUnavailableError, UnknownBackendError
from .problem import QP, QPBatch
from .settings import IGNORED, as_warm_start
from .solution import BatchSolution, Solution

__all__ = [
    "BackendUnavailableError",
    "UnknownBackendError",
    "available_backends",
    "clear_backend_cache",
    "get_backend",
    "register_backend",
    "solve",
    "solve_batch",
    "solve_qp",
]

# name -> (module, packages it imports, pip extra that installs them)
_BUILTIN: dict[str, tuple[str, tuple[str, ...], str]] = {
    "clarabel": ("solvers.clarabel_", ("clarabel",), "core"),
    "osqp": ("solvers.osqp_", ("osqp",), "osqp"),
    "cvxpy": ("solvers.cvxpy_", ("cvxpy",), "cvxpy"),
    "admm": ("solvers.admm", ("jax",), "core"),
    "ipm": ("solvers.ipm", ("jax",), "core"),
}
# qpsolvers' solver name -> the module its solver imports (found without importing anything)
_QPSOLVERS_MODULES: dict[str, str] = {
    "clarabel": "clarabel",
    "daqp": "daqp",
    "ecos": "ecos",
    "highs": "highspy",
    "osqp": "osqp",
    "piqp": "piqp",
    "proxqp": "proxsuite",
    "qpalm": "qpalm",
    "qpoases": "qpoases",
    "qpswift": "qpSWIFT",
    "quadprog": "quadprog",
    "scs": "scs",
    "cvxopt": "cvxopt",
    "gurobi": "gurobipy",
    "mosek": "mosek",
    "jaxopt_osqp": "jaxopt",
    "kvxopt": "kvxopt",
}
_USER: dict[str, Callable[[], Backend]] = {}
#: backend objects by name (each keeps its own setups), see :mod:`solvers.cache`
BACKEND_CACHE_SIZE = 64
_CACHE: BoundedCache[str, Backend] = BoundedCache(BACKEND_CACHE_SIZE)


def clear_backend_cache() -> None:
    """Forget every backend object :func:`get_backend` made, and with it what each one cached
    (its setups for shared ``P``, ``A``); the next :func:`get_backend` builds a new one."""
    for be in list(_CACHE.values()):
        clear = getattr(be, "clear_cache", None)  # a duck-typed user backend may have none
        if callable(clear):
            clear()
    _CACHE.clear()


def register_backend(name: str, factory: Callable[[], Backend]) -> None:
    """Register a user backend: ``factory()`` returns a :class:`~solvers.base.Backend`."""
    if not isinstance(name, str) or not name or ":" in name:
        raise ValueError(f"backend name must be a non-empty string without ':', got {name!r}")
    _USER[name] = factory
    _CACHE.pop(name, None)


def _missing(name: str, pkg: str, extra: str, exc: Exception) -> BackendUnavailableError:
    how = f"pip install 'mmdopt[{extra}]'" if extra != "core" else f"pip install {pkg}"
    return BackendUnavailableError(
        f"backend {name!r} needs the package {pkg!r}, which could not be imported ({exc}); "
        f"install it with: {how}"
    )


def _found(module: str) -> bool:
    """Whether ``module`` can be found, without importing it (its parent package may be)."""
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a parent that is missing, or set to None in sys.modules
        return False


def get_backend(name: str) -> Backend:
    """The backend object for ``name`` (imported on first use, then cached: at most
    :data:`BACKEND_CACHE_SIZE` names, the oldest evicted first; :func:`clear_backend_cache`)."""
    if not isinstance(name, str):
        raise TypeError(f"backend must be a string, got {type(name).__name__}")
    # plain mapping operations on _CACHE (the bound is in its __setitem__), so that a copy a
    # test swaps in for it behaves the same
    if name in _CACHE:
        return _CACHE[name]
    if name in _USER:
        be = _USER[name]()
    elif name in _BUILTIN:
        module, pkgs, extra = _BUILTIN[name]
        for pkg in pkgs:
            try:
                importlib.import_module(pkg)
            except ImportError as exc:
                raise _missing(name, pkg, extra, exc) from exc
        be = importlib.import_module(module).make_backend()
    elif name.startswith("qpsolvers:"):
        try:
            importlib.import_module("qpsolvers")
        except ImportError as exc:
            raise _missing(name, "qpsolvers", "qpsolvers", exc) from exc
        from . import qpsolvers_

        be = qpsolvers_.make_backend(name.split(":", 1)[1])
    else:
        raise UnknownBackendError(
            f"unknown backend {name!r}; available: {', '.join(available_backends())}"
        )
    _CACHE[name] = be
    return be


def available_backends() -> list[str]:
    """Names of the backends whose packages are installed on this machine.

    Lazy: packages are looked up with :func:`importlib.util.find_spec`, not imported (a package
    that is found but broken raises :class:`BackendUnavailableError` on first use).
    ``qpsolvers:<name>`` lists the solvers qpsolvers would find, minus those not offered.
    """
    names = [
        name
        for name, (module, pkgs, _extra) in _BUILTIN.items()
        if all(_found(p) for p in pkgs) and _found(module)
    ]
    if _found("qpsolvers"):
        from .qpsolvers_ import EXCLUDED

        names.extend(
            f"qpsolvers:{s}"
            for s, mod in _QPSOLVERS_MODULES.items()
            if s not in EXCLUDED and _found(mod)
        )
    names.extend(_USER)
    return names


#: backends whose own ``solver=`` setting picks an inner solver: there ``solver=`` is that setting
_SOLVER_IS_A_SETTING = frozenset({"cvxpy"})


def _alias(solver: str) -> str:
    """The backend a qpsolvers-style ``solver=`` name means."""
    if solver in _USER or solver in _BUILTIN or solver.startswith("qpsolvers:"):
        return solver
    if solver in _QPSOLVERS_MODULES:
        return f"qpsolvers:{solver}"
    return solver  # unknown: get_backend names it and lists the available ones


def _resolve_backend(
    backend: str | None, solver: str | None, default: str, settings: dict[str, Any]
) -> str:
    """The backend named by ``backend=`` and/or its alias ``solver=`` (``default`` if neither);
    for a backend in :data:`_SOLVER_IS_A_SETTING`, a different ``solver=`` goes to ``settings``."""
    if solver is None:
        return default if backend is None else backend
    if not isinstance(solver, str):
        raise TypeError(
            f"solver must be a backend name (a string, an alias of backend=), got "
            f"{type(solver).__name__}"
        )
    if backend is None:
        return _alias(solver)
    if solver == backend or (isinstance(backend, str) and _alias(solver) == backend):
        return backend
    if backend in _SOLVER_IS_A_SETTING:
        settings["solver"] = solver
        return backend
    raise ValueError(
        f"backend={backend!r} and solver={solver!r} name different backends: solver= is an "
        "alias of backend= (as in qpsolvers); give one of them"
    )


def _attach(sol: Any, problem: QP | QPBatch) -> None:
    """Record on the solution the problem it answers (for ``duality_gap``/``is_optimal``)."""
    if isinstance(sol, (Solution, BatchSolution)) and sol.problem is None:
        object.__setattr__(sol, "problem", problem)


def _check_qp(qp: QP, check_convex: bool | None) -> None:
    if check_convex is True:
        qp.ensure_convex()
    elif check_convex not in (None, False):
        raise ValueError(f"check_convex must be True, False or None, got {check_convex!r}")


def _record_warm_start(settings: dict, given: bool, be: Backend) -> None:
    if given:
        settings["warm_start"] = "used" if be.honours_warm_start else IGNORED


def solve(
    qp: QP,
    backend: str | None = None,
    *,
    solver: str | None = None,
    warm_start: Any = None,
    check_convex: bool | None = None,
    **settings: Any,
) -> Solution:
    """Solve one QP with the named backend (``"clarabel"`` when none is named).

    ``solver``: an alias of ``backend`` (qpsolvers' name for it; see the module docstring).
    ``settings``: the common names (``eps_abs``, ``eps_rel``, ``max_iter``, ``time_limit``,
    ``verbose``; see :mod:`solvers.settings`) and the solver's native names; anything else raises
    :class:`~solvers.errors.InvalidSettingError`.  ``warm_start``: a previous :class:`Solution`
    or a tuple ``(x, y)`` (recorded as ``"ignored"`` by backends that cannot use it).
    ``check_convex=True`` runs the convexity check now for a QP built with
    ``check_convex=False``.  A ``SOLVED`` whose primal residual fails the backend's stated
    tolerance by orders of magnitude is flagged in ``extras["residual_check"]``; then the answer
    check of :mod:`solvers.check` (scale-aware residuals, verified infeasibility certificates)
    weakens any status the point does not support, saying why in ``extras["check"]``.  The solution
    keeps ``qp`` as ``sol.problem`` (for ``sol.duality_gap()`` and ``sol.is_optimal(eps_abs)``).

    Example::

        >>> sol = solve(QP(np.eye(2), [1.0, -1.0], np.eye(2), [-0.5, -0.5], [1.0, 1.0]),
        ...             backend="osqp", eps_abs=1e-8, eps_rel=1e-8)
        >>> sol.status.name, sol.settings["eps_abs"]
        ('SOLVED', 1e-08)
    """
    if not isinstance(qp, QP):
        raise TypeError(f"qp must be a solvers.QP, got {type(qp).__name__}")
    _check_qp(qp, check_convex)
    be = get_backend(_resolve_backend(backend, solver, "clarabel", settings))
    sol = _checked_solve(be, qp, warm_start=warm_start, **settings)
    # the confirming solve of an inaccurate answer goes through the same path
    sol = confirm_inaccurate(be, qp, sol, settings, functools.partial(_checked_solve, be))
    _attach(sol, qp)
    return sol


def _checked_solve(be: Backend, qp: QP, *, warm_start: Any = None, **settings: Any) -> Solution:
    """``be``'s answer to ``qp`` after the residual flag and the answer check of
    :mod:`solvers.check` (what :func:`solve` returns, before the confirmation of an inaccurate
    answer)."""
    ws = as_warm_start(warm_start, qp.n, qp.m)
    sol = be.solve(qp, warm_start=ws, **settings)
    _record_warm_start(sol.settings, ws is not None, be)
    residual_check(be, qp, sol)
    return check_solution(be, qp, sol)


def solve_batch(
    batch: QPBatch,
    backend: str | None = None,
    *,
    solver: str | None = None,
    warm_start: Any = None,
    check_convex: bool | None = None,
    **settings: Any,
) -> BatchSolution:
    """Solve a batch of QPs sharing ``P`` and ``A``; returns fields with a leading batch axis.

    ``backend`` defaults to ``"admm"``; ``solver`` is its alias, settings and ``warm_start`` (a
    :class:`BatchSolution` or a tuple ``(x (B, n), y (B, m))``) as in :func:`solve`.  The result
    keeps ``batch`` as ``sols.problem``; ``sols.status_names`` and ``sols.ok`` give the status
    of each QP by name and as a boolean array.  Every member's answer is checked as in
    :func:`solve` (``sols.extras["check"]`` holds arrays over the batch; certificates of
    infeasible members in ``sols.extras["certificates"]``).
    """
    if not isinstance(batch, QPBatch):
        raise TypeError(f"batch must be a solvers.QPBatch, got {type(batch).__name__}")
    if check_convex is True:
        batch.ensure_convex()
    elif check_convex not in (None, False):
        raise ValueError(f"check_convex must be True, False or None, got {check_convex!r}")
    if warm_start is not None and not isinstance(warm_start, tuple):
        if not hasattr(warm_start, "x") or np.ndim(warm_start.x) != 2:
            raise ValueError(
                "warm_start must be a BatchSolution with the same batch size, or a tuple "
                f"(x (B, n), y (B, m)); got {type(warm_start).__name__}"
            )
        if len(warm_start.x) != len(batch):
            raise ValueError(
                f"warm_start has batch size {len(warm_start.x)}, the batch has {len(batch)}"
            )
    be = get_backend(_resolve_backend(backend, solver, "admm", settings))
    ws = as_warm_start(warm_start, batch.n, batch.m, batch=len(batch))
    sol = be.solve_batch(batch, warm_start=ws, **settings)
    _record_warm_start(sol.settings, ws is not None, be)
    residual_check(be, batch, sol)
    sol = check_batch_solution(be, batch, sol)
    _attach(sol, batch)
    return sol


def solve_qp(
    P: Any,
    q: Any,
    G: Any = None,
    h: Any = None,
    A: Any = None,
    b: Any = None,
    lb: Any = None,
    ub: Any = None,
    backend: str | None = None,
    *,
    solver: str | None = None,
    warm_start: Any = None,
    check_convex: bool = True,
    **settings: Any,
) -> Solution:
    """One call, in qpsolvers' argument order: ``min ½xᵀPx + qᵀx s.t. Gx ≤ h, Ax = b,
    lb ≤ x ≤ ub``.

    Builds :meth:`QP.from_qpsolvers` (every argument validated and named in errors: ``h``,
    ``lb``, ... as given) and calls :func:`solve`; returns the same :class:`Solution` (``y`` over
    the rows ``[G; A; I]``, OSQP's sign convention).  ``backend`` (default ``"clarabel"``) or its
    qpsolvers alias ``solver`` (``solver="osqp"``, ``solver="piqp"``), settings as in
    :func:`solve`.

    Example::

        >>> import numpy as np
        >>> from solvers import solve_qp
        >>> sol = solve_qp(np.eye(2), [1.0, -1.0], G=[[1.0, 1.0]], h=[0.0],
        ...                lb=[-0.5, -0.5], ub=[1.0, 1.0], backend="clarabel")
        >>> sol.status.name, sol.x.round(6)
        ('SOLVED', array([-0.5,  0.5]))
    """
    qp = QP.from_qpsolvers(P, q, G, h, A, b, lb, ub, check_convex=check_convex)
    return solve(qp, backend, solver=solver, warm_start=warm_start, **settings)
