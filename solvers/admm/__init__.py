"""Batched, jitted ADMM in JAX: the functional core and the registry's ``admm`` backend.

* :mod:`solvers.admm.core` — :class:`ADMMSettings` (with :class:`PolishSettings`),
  :func:`admm_factor`, :func:`admm_iterate`, :class:`ADMMState` (pure JAX, for use inside your
  own ``jit``) and :func:`admm_projector`, the two as a :class:`solvers.JaxProjector` (what the
  planner's projector runs).
* :mod:`solvers.admm.polish` — the float64 active-set polish and termination test (NumPy).
* :mod:`solvers.admm.backend` — :class:`ADMMBackend`, what ``solve(..., backend="admm")`` runs.

Importing this package imports JAX; ``import solvers`` alone does not.
"""

from .backend import DENSE_N_WARN, ADMMBackend, make_backend
from .core import (
    ADMMFactor,
    ADMMSettings,
    ADMMState,
    PolishSettings,
    SparsePattern,
    admm_factor,
    admm_iterate,
    admm_projector,
    flops_per_iteration,
    rows_from_bounds,
    sparse_pattern,
)
from .polish import polish

__all__ = [
    "ADMMSettings",
    "ADMMFactor",
    "ADMMState",
    "PolishSettings",
    "SparsePattern",
    "ADMMBackend",
    "DENSE_N_WARN",
    "admm_factor",
    "admm_iterate",
    "admm_projector",
    "rows_from_bounds",
    "sparse_pattern",
    "polish",
    "flops_per_iteration",
    "make_backend",
]
