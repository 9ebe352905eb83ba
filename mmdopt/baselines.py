"""The planning methods: which obstacle samples each one plans against, with which collision term.

Every method runs the *same* optimiser (:mod:`mmdopt.algorithm`: sampling, Frenet planner,
projection, ConstraintEliteSet, EliteSet, MPPI update); they differ only in which obstacle samples
enter the cost and in the collision term (paper, "Baselines": "we just replace our MMD cost with a
deterministic collision cost").  The collision terms live in :mod:`mmdopt.collision`.

==================  ==========================================  ===============================
method              obstacle samples in the cost                collision term
==================  ==========================================  ===============================
``"mmd"``           m-sample reduced set by MMD, weights ᾱ      ``w_mmd · l_dist`` (l_dist)
``"random"``        m-sample uniformly random subset, ᾱ         ``w_mmd · l_dist``
``"degroot"``       m-sample de Groot set (deepest conflict     ``w_coll · Σ_j Σ_k f̄_jk``
                    with a constant-velocity ego guess)         (deterministic scenario cost)
``"scenario_all"``  all n samples                               ``w_coll · Σ_j Σ_k f̄_jk``
``"saa"``           all n samples                               ``w_saa · Σ_o (π̂_o − ε)₊/ε``
==================  ==========================================  ===============================

**Scenario formulation chosen** (the authors' reference code puts the reduced-set collision
constraints into its non-convex polar-form projection instead): here collisions enter as a
*deterministic collision cost* on the scenario samples, as the paper's Baselines paragraph says.
Linearised half-planes as projection rows were not chosen: the normal of each half-plane depends on
the sample's own trajectory, so the constraint matrix would differ per sample and the batched
projection (one factorisation shared by the batch) would no longer apply.

To add a method: a row in :data:`SELECTOR` (which samples: a selector of
:mod:`mmdopt.reduced_set`, or ``None`` for all samples) and in :data:`COLLISION_TERM` (which
collision term of :mod:`mmdopt.collision`).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .geometry import Footprint
from .reduced_set import ReducedSetConfig, select_reduced_sets
from .samples import ReducedSet

__all__ = ["PLAN_METHODS", "COLLISION_TERM", "SELECTOR", "all_samples_set", "select_for_method"]

#: the planning methods, in the order of the public API (the first is MMD-Opt)
PLAN_METHODS = ("mmd", "degroot", "random", "saa", "scenario_all")
#: the collision term of each plan method (:data:`mmdopt.collision.COLLISION_TERMS`)
COLLISION_TERM = MappingProxyType(
    {
        "mmd": "mmd",
        "random": "mmd",
        "degroot": "scenario",
        "scenario_all": "scenario",
        "saa": "saa",
    }
)
#: the reduced-set selector of each plan method (``None``: plan against all n samples)
SELECTOR: Mapping[str, str | None] = MappingProxyType(
    {
        "mmd": "mmd",
        "random": "random",
        "degroot": "degroot",
        "scenario_all": None,
        "saa": None,
    }
)


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
    method: str,
    key: Any,
    obstacles_frenet: np.ndarray,
    m: int,
    config: ReducedSetConfig,
    *,
    lateral_scale: float = 1.0,
    ego_guess: np.ndarray | None = None,
    footprint: Footprint | None = None,
) -> ReducedSet:
    """The obstacle samples ``method`` plans against, as a :class:`ReducedSet` (leading axis O).

    ``obstacles_frenet`` (O, n, K, 2) in the planning frame; ``lateral_scale`` multiplies the
    lateral offsets in the selection's kernel features (an anisotropic kernel: lateral intents
    count more than longitudinal spread; not for "degroot", which scores conflicts in metres);
    ``ego_guess`` (K, 2) is the constant-velocity ego guess "degroot" scores against, with the
    collision ellipse ``footprint`` (the planner's: ``config.safety.footprint``).
    """
    O, n = obstacles_frenet.shape[:2]
    sel = SELECTOR[method]
    if sel is None:
        return all_samples_set(n, O)
    feats = obstacles_frenet
    if sel != "degroot" and float(lateral_scale) != 1.0:
        feats = obstacles_frenet * np.array([1.0, float(lateral_scale)])
    guess = ego_guess if sel == "degroot" else None
    rs = select_reduced_sets(key, feats, m, sel, config, guess, footprint)
    return jax.block_until_ready(rs)
