"""The planner's public input checks: each names the bad argument in a ``ValueError``.

:func:`mmdopt.plan`, the :class:`~mmdopt.Planner`, the receding loop (:mod:`mmdopt.receding`) and
the benchmarks call these same checks, so every entry point refuses a bad input with the same
words.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

import frenet
import solvers

from . import algorithm as alg
from . import methods as registry
from ._checks import check_key
from .algorithm import PLANNER_PROJECTOR
from .config import MMDOptConfig
from .plans import MAX_COORD, Road
from .samples import ReducedSet, check_reduced_set

__all__ = [
    "resolve_projector",
    "check_plan_inputs",
    "check_obstacles",
    "check_obstacle_headings",
    "check_warm_start",
    "check_reduced_set_for",
]


def resolve_projector(projector: str, backend: str | None) -> str:
    """``projector``, or ``backend`` (its former name, deprecated) when that is given."""
    if backend is None:
        return projector
    warnings.warn(
        "backend= is now projector= (the planner's projection: 'admm-fixed', its own jitted "
        "ADMM, or a solvers backend that projects on the host)",
        DeprecationWarning,
        stacklevel=3,
    )
    if projector != PLANNER_PROJECTOR and projector != backend:
        raise ValueError(
            f"projector={projector!r} and backend={backend!r} (its former name) disagree"
        )
    return backend


def check_plan_inputs(
    ego: Any, road: Any, method: Any, config: Any, projector: Any, key: Any
) -> registry.PlanMethod:
    """Check a plan's ego, road, method, config, projector and key; returns the method's
    record (:func:`mmdopt.methods.get`)."""
    if not isinstance(ego, frenet.EgoState):
        raise ValueError(f"ego must be a frenet.EgoState, got {type(ego).__name__}")
    if not isinstance(road, Road):
        raise ValueError(f"road must be an mmdopt.Road, got {type(road).__name__}")
    record = registry.get(method)
    if not isinstance(config, MMDOptConfig):
        raise ValueError(f"config must be an mmdopt.MMDOptConfig, got {type(config).__name__}")
    if not isinstance(projector, str) or (
        projector != PLANNER_PROJECTOR and projector not in solvers.available_backends()
    ):
        raise ValueError(
            f"projector {projector!r} is not available; available: "
            f"{[PLANNER_PROJECTOR, *solvers.available_backends()]}"
        )
    check_key(key)
    return record


def check_obstacles(
    obstacles: Any,
    config: MMDOptConfig,
    method: Any,
    name: str = "obstacles",
    *,
    allow_empty: bool = False,
) -> np.ndarray:
    """``obstacles`` as a finite float64 array (O, n, K, 2) on the planner's grid, with at
    least the reduced-set size of samples for a method that selects; ``ValueError`` naming
    ``name`` otherwise.  ``method``: a name or a :class:`~mmdopt.methods.PlanMethod`.
    ``allow_empty``: O = 0 (an empty road) is accepted and returned as it is."""
    if obstacles is None:
        raise ValueError(f"{name} must be an array (O, n, K, 2), got None")
    try:
        raw = np.asarray(obstacles)
    except (TypeError, ValueError):
        raise ValueError(
            f"{name} must be a numeric array (O, n, K, 2); a nested list of unequal lengths "
            "is not one"
        ) from None
    if np.iscomplexobj(raw):
        raise ValueError(f"{name} must be real (x, y) positions, got a complex array")
    try:
        arr = raw.astype(np.float64, copy=False)  # the planner copies into its own frame
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array (O, n, K, 2)") from None
    K = config.trajectory.num_steps
    if arr.ndim != 4 or arr.shape[-1] != 2:
        raise ValueError(f"{name} must have shape (O, n, K, 2) = (O, n, {K}, 2), got {arr.shape}")
    O, n, k, _ = arr.shape
    if O == 0 and allow_empty and k == K:
        return arr
    if O == 0:
        raise ValueError(
            f"{name} has zero obstacles (shape {arr.shape}); pass at least one obstacle's samples"
        )
    if n == 0:
        raise ValueError(f"{name} has zero samples per obstacle (shape {arr.shape})")
    if k != K:
        raise ValueError(
            f"{name} has {k} time steps but config.num_steps = {K}: samples must be on the "
            f"planner's time grid ({config.trajectory.horizon} s, {K} points)"
        )
    hi, lo = float(np.max(arr)), float(np.min(arr))  # two reads, no temporary (NaN propagates)
    if not (math.isfinite(hi) and math.isfinite(lo)):
        raise ValueError(f"{name} contains NaN or inf")
    if max(hi, -lo) > MAX_COORD:
        raise ValueError(
            f"{name} has coordinates beyond {MAX_COORD:g} m (max |value| {max(hi, -lo):.3g})"
        )
    m = config.selection.reduced_set_size
    if registry.get(method).selector is not None and n < m:
        raise ValueError(
            f"{name} has n = {n} samples per obstacle, fewer than config.reduced_set_size = {m}"
        )
    return arr


def check_warm_start(warm_start: Any, config: MMDOptConfig) -> None:
    """``ValueError`` naming ``warm_start`` unless it is a state of a config with the same
    behavioural input size, elite count and iterations as ``config``."""
    if not isinstance(warm_start, alg.CEMState):
        raise ValueError(
            f"warm_start must be an algorithm.CEMState, got {type(warm_start).__name__}"
        )
    D, ne, N = config.d_dim, config.cem.n_elite, config.cem.iterations
    want = {"mu": (D,), "cov": (D, D), "elites": (ne, D), "cost_trace": (N,)}
    for name, shape in want.items():
        got = tuple(np.shape(getattr(warm_start, name)))
        if got != shape:
            raise ValueError(
                f"warm_start.{name} has shape {got}, but this config needs {shape} "
                "(num_segments, n_elite, iterations): warm-start from a plan made with the "
                "same sizes"
            )


def check_reduced_set_for(rs: Any, O: int, n: int, method: Any) -> ReducedSet:
    """A caller's ``reduced_set`` checked for ``O`` obstacles of ``n`` samples, for a method
    that plans on a reduced set (``ValueError`` naming ``reduced_set`` otherwise)."""
    record = registry.get(method)
    if record.selector is None:
        raise ValueError(
            f"reduced_set is not used by method {record.name!r} (it plans on all samples)"
        )
    return check_reduced_set(rs, n, "reduced_set", O)


def check_obstacle_headings(h: Any, O: int) -> np.ndarray:
    """``obstacle_headings`` as (O,) finite float64 radians, else ``ValueError`` naming it."""
    try:
        arr = np.asarray(h, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"obstacle_headings must be {O} numbers (rad), got {h!r}") from None
    if arr.shape != (O,):
        raise ValueError(
            f"obstacle_headings must have shape ({O},) (one body heading per obstacle), got "
            f"{arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError("obstacle_headings contains NaN or inf")
    return arr
