"""The obstacle samples each planning method plans against (its selection step).

The methods themselves are records of :mod:`mmdopt.methods` (which samples, which collision
term, which risk passes); this module carries out a record's choice of samples:
:func:`select_for_method` runs its reduced-set selector (:mod:`mmdopt.reduced_set`) with the
record's preprocessing (the anisotropic kernel features, de Groot's constant-velocity ego
guess), or returns :func:`all_samples_set` for a method that plans on every sample.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .geometry import Footprint
from .methods import PLAN_METHODS, PlanMethod
from .reduced_set import ReducedSetConfig, select_reduced_sets
from .samples import ReducedSet

__all__ = ["PLAN_METHODS", "all_samples_set", "select_for_method"]


def all_samples_set(n: int, O: int) -> ReducedSet:
    """The "reduced set" of all ``n`` samples of ``O`` obstacles, uniform weights."""
    idx = jnp.broadcast_to(jnp.arange(n, dtype=jnp.int32), (O, n))
    w = jnp.full((O, n), 1.0 / n)
    return ReducedSet(
        indices=idx,
        weights=w,
        alpha=w,
        mmd2=jnp.zeros((O,)),
        bandwidth=jnp.full((O,), jnp.nan),
        method="all",
    )


def select_for_method(
    method: PlanMethod,
    key: Any,
    obstacles_frenet: np.ndarray,
    m: int,
    config: ReducedSetConfig,
    *,
    lateral_scale: float = 1.0,
    ego_guess: np.ndarray | None = None,
    footprint: Footprint | None = None,
) -> ReducedSet:
    """The obstacle samples ``method`` (a :class:`~mmdopt.methods.PlanMethod`) plans against,
    as a :class:`ReducedSet` (leading axis O).

    ``obstacles_frenet`` (O, n, K, 2) in the planning frame; ``lateral_scale`` multiplies the
    lateral offsets in the selection's kernel features (an anisotropic kernel: lateral intents
    count more than longitudinal spread; only for a record with ``lateral_features``);
    ``ego_guess`` (K, 2) is the constant-velocity ego guess a record with ``ego_guess`` (de
    Groot's) scores against, with the collision ellipse ``footprint`` (the planner's:
    ``config.safety.footprint``).
    """
    O, n = obstacles_frenet.shape[:2]
    if method.selector is None:
        return all_samples_set(n, O)
    feats = obstacles_frenet
    if method.lateral_features and float(lateral_scale) != 1.0:
        feats = obstacles_frenet * np.array([1.0, float(lateral_scale)])
    guess = ego_guess if method.ego_guess else None
    rs = select_reduced_sets(key, feats, m, method.selector, config, guess, footprint)
    return jax.block_until_ready(rs)
