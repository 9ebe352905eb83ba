"""Backends by name, imported lazily.

``solve(qp, backend="clarabel")`` and ``solve_batch(batch, backend="admm")`` look the backend up
here.  A backend whose package is missing raises :class:`BackendUnavailableError` naming the
package and the extra that installs it.  ``qpsolvers:<name>`` selects any solver that the
``qpsolvers`` package finds installed.  Users add their own with :func:`register_backend`.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

from .base import Backend
from .problem import QP, QPBatch
from .solution import BatchSolution, Solution

__all__ = [
    "BackendUnavailableError",
    "UnknownBackendError",
    "available_backends",
    "get_backend",
    "register_backend",
    "solve",
    "solve_batch",
]


class BackendUnavailableError(ImportError):
    """The backend exists but its package is not installed."""


class UnknownBackendError(ValueError):
    """No backend of that name."""


# name -> (module, packages it imports, pip extra that installs them)
_BUILTIN: dict[str, tuple[str, tuple[str, ...], str]] = {
    "clarabel": ("solvers.clarabel_", ("clarabel",), "core"),
    "osqp": ("solvers.osqp_", ("osqp",), "osqp"),
    "cvxpy": ("solvers.cvxpy_", ("cvxpy",), "cvxpy"),
    "admm": ("solvers.admm", ("jax",), "core"),
    "ipm": ("solvers.ipm", ("jax",), "core"),
}
_USER: dict[str, Callable[[], Backend]] = {}
_CACHE: dict[str, Backend] = {}


def register_backend(name: str, factory: Callable[[], Backend]) -> None:
    """Register a user backend: ``factory()`` returns a :class:`~solvers.base.Backend`."""
    if not isinstance(name, str) or not name or ":" in name:
        raise ValueError(f"backend name must be a non-empty string without ':', got {name!r}")
    _USER[name] = factory
    _CACHE.pop(name, None)


def _missing(name: str, pkg: str, extra: str, exc: Exception) -> BackendUnavailableError:
    how = (
        f"pip install 'mmdopt[{extra}]'" if extra != "core" else f"pip install {pkg}"
    )
    return BackendUnavailableError(
        f"backend {name!r} needs the package {pkg!r}, which could not be imported ({exc}); "
        f"install it with: {how}"
    )


def get_backend(name: str) -> Backend:
    """The backend object for ``name`` (cached)."""
    if not isinstance(name, str):
        raise TypeError(f"backend must be a string, got {type(name).__name__}")
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
    """Names of the backends whose packages import on this machine."""
    names = []
    for name, (_module, pkgs, _extra) in _BUILTIN.items():
        try:
            for pkg in pkgs:
                importlib.import_module(pkg)
        except ImportError:
            continue
        try:
            importlib.import_module(_module)
        except ImportError:
            continue
        names.append(name)
    try:
        from . import qpsolvers_

        names.extend(f"qpsolvers:{s}" for s in qpsolvers_.installed_solvers())
    except ImportError:
        pass
    names.extend(_USER)
    return names


def solve(qp: QP, backend: str = "clarabel", **settings: Any) -> Solution:
    """Solve one QP with the named backend; ``settings`` go to the native solver.

    ``warm_start=`` (a previous :class:`Solution`) is honoured by backends that support it.
    """
    if not isinstance(qp, QP):
        raise TypeError(f"qp must be a solvers.QP, got {type(qp).__name__}")
    return get_backend(backend).solve(qp, **settings)


def solve_batch(
    batch: QPBatch,
    backend: str = "admm",
    *,
    warm_start: BatchSolution | None = None,
    **settings: Any,
) -> BatchSolution:
    """Solve a batch of QPs sharing ``P`` and ``A``; returns fields with a leading batch axis."""
    if not isinstance(batch, QPBatch):
        raise TypeError(f"batch must be a solvers.QPBatch, got {type(batch).__name__}")
    if warm_start is not None and (
        not isinstance(warm_start, BatchSolution) or len(warm_start) != len(batch)
    ):
        raise ValueError("warm_start must be a BatchSolution with the same batch size")
    return get_backend(backend).solve_batch(batch, warm_start=warm_start, **settings)
