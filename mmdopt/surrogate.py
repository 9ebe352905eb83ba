"""MMD collision surrogate l_dist (eqs. coll_constraints, f_bar, l_dist, mu_f_bar, mu_delta).

For an ego trajectory, every ego circle e, every obstacle o, every reduced-set sample j of o,
every circle c of that sample and every time step k:

    f = 1 − (Δx)²/a² − (Δy)²/b²,   f̄ = max(0, f)                    eqs. (coll_constraints), (f_bar)

(ellipse axis-aligned in the frame of the inputs; the reference works in the Frenet frame, so a is
the longitudinal and b the lateral semi-axis).  Per obstacle and time step, the samples
p = (j, e, c) form the embedding μ_f̄ = Σ_p ᾱ_j φ(s·f̄_p) (weights replicated over circle pairs,
``f_scale`` s), compared with a Dirac at 0 **of the same total mass** Σ_p ᾱ_j (the paper writes
unit weights, the reference 1/m; only equal masses make MMD = 0 possible when every f̄ = 0):

    l_dist = Σ_o Σ_k ‖μ_f̄,o,k − μ_δ,o,k‖²_H                            eq. (l_dist)

evaluated cancellation-free (:func:`mmdopt.kernels.mmd2_to_dirac`): a plan with f̄ ≡ 0 scores
exactly 0 and small penetrations keep relative accuracy (the reference's float32 floor is
≈ 2·10⁻⁴, SPEC §f).  Defaults are the reference's (σ = 30, s = 1, a = 4.5 m, b = 3.5 m, ego a
point); with σ ≫ s·f̄ the MMD reduces to (Σ ᾱ f̄)²/σ² (squared weighted mean penetration), so the
bandwidth and f_scale are exposed as pytree leaves, to be chosen by measurement.

``stack_circles=True`` (reference) puts all circle pairs of an obstacle into one embedding per
step; ``False`` sums separate MMDs per (ego circle, obstacle circle) pair.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from .geometry import EGO_FOOTPRINT, OBSTACLE_FOOTPRINT, CircleFootprint, circle_centres
from .kernels import mmd2_to_dirac

__all__ = [
    "SurrogateConfig",
    "ReducedObstacles",
    "reduced_obstacles",
    "ellipse_f",
    "f_bar",
    "mmd_surrogate",
    "mmd_surrogate_terms",
    "CollisionCounts",
    "collision_free_count",
]


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SurrogateConfig:
    """Collision-surrogate parameters (a pytree: scalars and ego offsets are leaves).

    bandwidth : Gaussian kernel σ on the scaled f̄ (reference 30)
    f_scale : f̄ is multiplied by this before the kernel (reference 1)
    a, b : ellipse semi-axes (m) along x (longitudinal) and y (lateral)
    ego_footprint : circles along the ego heading (default one circle at 0: a point)
    stack_circles : static; see module docstring
    """

    bandwidth: float = 30.0
    f_scale: float = 1.0
    a: float = 4.5
    b: float = 3.5
    ego_footprint: CircleFootprint = EGO_FOOTPRINT
    stack_circles: bool = field(default=True, metadata=dict(static=True))

    def replace(self, **kw) -> SurrogateConfig:
        return dataclasses.replace(self, **kw)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ReducedObstacles:
    """Reduced sets of O obstacles as circle trajectories with weights.

    centres : (O, m, C, K, 2) circle centres of the m reduced samples of each obstacle (m)
    weights : (O, m) ᾱ of each obstacle (sum 1 per obstacle; zero rows pad obstacles with
        fewer samples, and a zero weight contributes nothing)
    """

    centres: jax.Array
    weights: jax.Array


def reduced_obstacles(
    samples, reduced, footprint: CircleFootprint = OBSTACLE_FOOTPRINT, heading=None
) -> ReducedObstacles:
    """Build :class:`ReducedObstacles` from samples and reduced sets.

    Parameters
    ----------
    samples : (O, n, K, 2) obstacle samples, or a list of O arrays (n_o, K, 2)
    reduced : a :class:`~mmdopt.reduced_set.ReducedSet` with leading axis O (from
        ``select_reduced_sets``), or a list of O single ReducedSets (sizes may differ: padded
        with zero weights to the largest m)
    footprint : obstacle circles (default 3 at {0, +2.5, −2.5} m)
    heading : optional (O, n, K) headings; default finite differences of each sample
    """
    if isinstance(reduced, list | tuple):
        m_max = max(int(np.shape(r.indices)[0]) for r in reduced)
        cs, ws = [], []
        for o, r in enumerate(reduced):
            s = jnp.asarray(samples[o])
            h = None if heading is None else jnp.asarray(heading[o])[r.indices]
            c = circle_centres(s[r.indices], footprint, h)  # (m_o, C, K, 2)
            pad = m_max - c.shape[0]
            cs.append(jnp.concatenate([c, jnp.repeat(c[:1], pad, axis=0)], axis=0))
            ws.append(jnp.concatenate([r.weights, jnp.zeros((pad,), r.weights.dtype)]))
        return ReducedObstacles(centres=jnp.stack(cs), weights=jnp.stack(ws))
    samples = jnp.asarray(samples)
    idx = reduced.indices  # (O, m)
    sel = jnp.take_along_axis(samples, idx[:, :, None, None], axis=1)  # (O, m, K, 2)
    h = None if heading is None else jnp.take_along_axis(jnp.asarray(heading), idx[:, :, None], 1)
    return ReducedObstacles(centres=circle_centres(sel, footprint, h), weights=reduced.weights)


def ellipse_f(ego: jax.Array, obs: jax.Array, a, b) -> jax.Array:
    """eq. (coll_constraints): f = 1 − Δx²/a² − Δy²/b² (> 0 inside the ellipse), broadcasting."""
    d = jnp.asarray(ego) - jnp.asarray(obs)
    return 1.0 - d[..., 0] ** 2 / a**2 - d[..., 1] ** 2 / b**2


def f_bar(ego: jax.Array, obs: jax.Array, a, b) -> jax.Array:
    """eq. (f_bar): f̄ = max(0, f)."""
    return jnp.maximum(ellipse_f(ego, obs, a, b), 0.0)


def _terms_one(ego_c: jax.Array, obstacles: ReducedObstacles, cfg: SurrogateConfig) -> jax.Array:
    """Per-obstacle, per-step MMD² for one ego: ego_c (E, K, 2) -> (O, K)."""
    oc = obstacles.centres  # (O, m, C, K, 2)
    O, m, C, K, _ = oc.shape
    E = ego_c.shape[0]
    # (O, m, E, C, K)
    fb = f_bar(ego_c[None, None, :, None], oc[:, :, None], cfg.a, cfg.b) * cfg.f_scale
    w = obstacles.weights
    if cfg.stack_circles:
        a = jnp.moveaxis(fb, -1, 1).reshape(O, K, m * E * C)  # samples p = (j, e, c)
        wp = jnp.broadcast_to(w[:, :, None], (O, m, E * C)).reshape(O, 1, m * E * C)
        return mmd2_to_dirac(a, wp, cfg.bandwidth)  # (O, K)
    a = jnp.transpose(fb, (0, 2, 3, 4, 1))  # (O, E, C, K, m)
    return jnp.sum(mmd2_to_dirac(a, w[:, None, None, None, :], cfg.bandwidth), axis=(1, 2))


def _ego_centres(ego_xy, cfg, ego_heading):
    return circle_centres(ego_xy, cfg.ego_footprint, ego_heading)  # (B, E, K, 2)


@jax.jit
def mmd_surrogate_terms(
    ego_xy, obstacles: ReducedObstacles, config: SurrogateConfig, ego_heading=None
) -> jax.Array:
    """Per-step terms of :func:`mmd_surrogate`: (B, K, 2) -> (B, O, K)."""
    ego_xy = jnp.asarray(ego_xy)
    oc = obstacles.centres
    if ego_xy.ndim != 3 or ego_xy.shape[-1] != 2:
        raise ValueError(f"ego_xy must have shape (B, K, 2), got {ego_xy.shape}")
    if oc.ndim != 5 or oc.shape[-2:] != ego_xy.shape[-2:]:
        raise ValueError(
            f"obstacles.centres must have shape (O, m, C, K, 2) with K = {ego_xy.shape[1]}, "
            f"got {oc.shape}"
        )
    if obstacles.weights.shape != oc.shape[:2]:
        raise ValueError(
            f"obstacles.weights must have shape {oc.shape[:2]}, got {obstacles.weights.shape}"
        )
    ego_c = _ego_centres(ego_xy, config, ego_heading)
    return jax.vmap(lambda e: _terms_one(e, obstacles, config))(ego_c)


@jax.jit
def mmd_surrogate(
    ego_xy,
    obstacles: ReducedObstacles,
    config: SurrogateConfig = SurrogateConfig(),  # noqa: B008
    ego_heading=None,
) -> jax.Array:
    """eq. (l_dist) summed over time steps and obstacles, for a batch of ego trajectories.

    Parameters
    ----------
    ego_xy : (B, K, 2) ego waypoints (m), same frame as the obstacles
    obstacles : :class:`ReducedObstacles` (O, m, C, K, 2) + weights (O, m)
    config : :class:`SurrogateConfig`
    ego_heading : (B, K), optional (default: finite differences; only used when the ego
        footprint has non-zero offsets)

    Returns
    -------
    (B,) l_dist ≥ 0; exactly 0 when every f̄ is 0.
    """
    return jnp.sum(mmd_surrogate_terms(ego_xy, obstacles, config, ego_heading), axis=(1, 2))


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class CollisionCounts:
    """Evaluation on validation samples (SPEC §h).

    colliding : (..., O, N) bool, sample n of obstacle o has f̄ > 0 for some circle pair and step
    per_obstacle : (..., O) int, collision-free samples per obstacle (N − Σ colliding)
    joint : (...,) int, indices n clear of *every* obstacle (sample n of each obstacle taken as
        one joint draw of the scene; needs the same N for all obstacles)
    """

    colliding: jax.Array
    per_obstacle: jax.Array
    joint: jax.Array


@jax.jit
def _count(ego_xy, samples, obstacle_footprint, ego_footprint, a, b, ego_heading):
    obs_c = circle_centres(samples, obstacle_footprint)  # (O, N, C, K, 2)

    def one(ego, h):
        ego_c = circle_centres(ego, ego_footprint, h)  # (E, K, 2)
        f = ellipse_f(ego_c[None, None, :, None], obs_c[:, :, None], a, b)  # (O, N, E, C, K)
        col = jnp.any(f > 0.0, axis=(2, 3, 4))  # strict: f̄ > 0 counts as collision
        n = col.shape[-1]
        return col, n - jnp.sum(col, axis=-1), n - jnp.sum(jnp.any(col, axis=0))

    col, per, joint = jax.vmap(one)(ego_xy, ego_heading)
    return CollisionCounts(colliding=col, per_obstacle=per, joint=joint)


def collision_free_count(
    ego_xy,
    validation_samples,
    obstacle_footprint: CircleFootprint = OBSTACLE_FOOTPRINT,
    ego_footprint: CircleFootprint = EGO_FOOTPRINT,
    a: float = 4.5,
    b: float = 3.5,
    ego_heading=None,
) -> CollisionCounts:
    """Count validation samples the ego plan(s) avoid (SPEC §h: any f̄ > 0, any circle, any step).

    Parameters
    ----------
    ego_xy : (K, 2) or (B, K, 2) ego waypoints
    validation_samples : (O, N, K, 2) (or (N, K, 2) for one obstacle)
    obstacle_footprint, ego_footprint : circle footprints
    a, b : ellipse semi-axes (m)
    ego_heading : (K,) or (B, K), optional

    Returns
    -------
    :class:`CollisionCounts` with no batch axis for a single (K, 2) plan.
    """
    ego = jnp.asarray(ego_xy)
    val = jnp.asarray(validation_samples)
    if ego.ndim not in (2, 3) or ego.shape[-1] != 2:
        raise ValueError(f"ego_xy must have shape (K, 2) or (B, K, 2), got {ego.shape}")
    if val.ndim == 3:
        val = val[None]
    if val.ndim != 4 or val.shape[-1] != 2 or val.shape[-2] != ego.shape[-2]:
        raise ValueError(
            f"validation_samples must have shape (O, N, K, 2) with K = {ego.shape[-2]}, "
            f"got {np.shape(validation_samples)}"
        )
    single = ego.ndim == 2
    if single:
        ego = ego[None]
    if ego_heading is None:
        from .geometry import headings

        h = headings(ego)
    else:
        h = jnp.asarray(ego_heading).reshape(ego.shape[:2])
    out = _count(ego, val, obstacle_footprint, ego_footprint, a, b, h)
    if single:
        out = jax.tree_util.tree_map(lambda x: x[0], out)
    return out
