"""Reduced sets of obstacle samples: the type shared by selection, collision and planning.

:class:`ReducedSet` is what every selector of :mod:`mmdopt.reduced_set` returns and what the
collision terms of :mod:`mmdopt.collision` and :func:`mmdopt.plan` consume;
:func:`check_reduced_set` is its one validator.  This module sits below both.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import jax
import numpy as np

__all__ = ["ReducedSet", "check_reduced_set", "check_weights"]


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ReducedSet:
    """Result of a reduced-set selection (a pytree; ``method`` is static).

    indices : (m,) int, positions in ``samples``, ordered by decreasing importance
    weights : (m,) ᾱ, summing to 1
    alpha : (n,) the CEM solution α* for "mmd"; for other methods ᾱ scattered into zeros
    mmd2 : () squared MMD between the uniform embedding of all n samples and the ᾱ-weighted
        reduced one (same kernel), a diagnostic of how well the set represents the samples
    bandwidth : () the kernel bandwidth used

    Several obstacles' sets stack with a leading obstacle axis O: ``indices`` (O, m), ….
    """

    indices: jax.Array
    weights: jax.Array
    alpha: jax.Array
    mmd2: jax.Array
    bandwidth: jax.Array
    method: str = field(default="mmd", metadata=dict(static=True))


def _concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def check_weights(weights, name: str = "weights", shape: tuple | None = None) -> None:
    """``ValueError`` naming ``name`` unless ``weights`` (..., m) has ``shape`` (if given) and,
    when concrete, is finite, ``>= 0`` and sums to 1 over its last axis (a mixture ᾱ)."""
    wshape = tuple(np.shape(weights))
    if shape is not None and wshape != tuple(shape):
        raise ValueError(f"{name} must have shape {tuple(shape)}, got {wshape}")
    if not _concrete(weights):
        return
    w = np.asarray(weights, dtype=np.float64)
    if not np.all(np.isfinite(w)):
        raise ValueError(f"{name} contains NaN or inf")
    if np.any(w < 0):
        raise ValueError(f"{name} must be >= 0 (a negative weight rewards collision): {w.min()}")
    sums = w.sum(axis=-1)
    if not np.allclose(sums, 1.0, atol=1e-6):
        raise ValueError(f"{name} must sum to 1 per obstacle, got sums {np.round(sums, 6)}")


def check_reduced_set(rs, n: int, name: str = "reduced_set", O: int | None = None) -> ReducedSet:
    """``rs`` checked as the reduced set of ``n`` samples (of ``O`` obstacles when given: then
    ``indices`` must be (O, m); else (m,) or (O, m)); ``ValueError`` naming ``name`` otherwise.
    Traced values are checked for shape only."""
    if not isinstance(rs, ReducedSet):
        raise ValueError(f"{name} must be an mmdopt.ReducedSet, got {type(rs).__name__}")
    ishape = tuple(np.shape(rs.indices))
    if O is not None and (len(ishape) != 2 or ishape[0] != O):
        raise ValueError(
            f"{name}.indices must have shape (O, m) = ({O}, m) (leading obstacle axis), "
            f"got {ishape}"
        )
    if len(ishape) not in (1, 2):
        raise ValueError(f"{name}.indices must have shape (m,) or (O, m), got {ishape}")
    check_weights(rs.weights, f"{name}.weights", ishape)
    if _concrete(rs.indices):
        i = np.asarray(rs.indices)
        if not np.issubdtype(i.dtype, np.integer):
            raise ValueError(f"{name}.indices must be integers, got {i.dtype}")
        if i.size and (i.min() < 0 or i.max() >= n):
            raise ValueError(
                f"{name}.indices must lie in [0, {n}) (n samples), got {i.min()}…{i.max()}"
            )
    return rs
