"""Circle footprints of the ego vehicle and the obstacles (paper §"Extension to ... Shapes").

A footprint is a set of circle centres at signed offsets along the body's heading:
centre_c = (x + r_c cos ψ, y + r_c sin ψ).  The heading ψ of a trajectory is taken from finite
differences of its waypoints, with the last value repeated (SPEC §f); a stationary step (zero
displacement) gets ψ = atan2(0, 0) = 0.  Coordinates may be Cartesian or Frenet (s, d): the
function is frame-agnostic, as the reference, which uses the Frenet heading in the Frenet frame.

Defaults: obstacles 3 circles at r ∈ {0, +2.5, −2.5} m (reference), ego a point (one circle at 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import jax
import jax.numpy as jnp

__all__ = [
    "CircleFootprint",
    "OBSTACLE_FOOTPRINT",
    "EGO_FOOTPRINT",
    "headings",
    "circle_centres",
]


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class CircleFootprint:
    """Circles along the heading at signed ``offsets`` (m).  The number of circles is static
    (it sets array shapes); the offset values are pytree leaves."""

    offsets: tuple[float, ...] = field(default=(0.0,))

    def __post_init__(self):
        if len(self.offsets) < 1:
            raise ValueError("offsets must name at least one circle")

    @property
    def n_circles(self) -> int:
        return len(self.offsets)

    def offsets_array(self) -> jax.Array:
        return jnp.stack([jnp.asarray(o, dtype=float) for o in self.offsets])


OBSTACLE_FOOTPRINT = CircleFootprint(offsets=(0.0, 2.5, -2.5))
EGO_FOOTPRINT = CircleFootprint(offsets=(0.0,))


def headings(xy: jax.Array) -> jax.Array:
    """Heading of each waypoint by forward differences, last value repeated.

    Parameters
    ----------
    xy : (..., K, 2) waypoints (m)

    Returns
    -------
    (..., K) heading (rad); zeros when K = 1.
    """
    xy = jnp.asarray(xy)
    if xy.shape[-2] < 2:
        return jnp.zeros(xy.shape[:-1], dtype=xy.dtype)
    d = jnp.diff(xy, axis=-2)
    psi = jnp.arctan2(d[..., 1], d[..., 0])
    return jnp.concatenate([psi, psi[..., -1:]], axis=-1)


def circle_centres(xy: jax.Array, footprint: CircleFootprint, heading: jax.Array | None = None):
    """Centres of the footprint circles along a trajectory.

    Parameters
    ----------
    xy : (..., K, 2) body reference point (m)
    footprint : :class:`CircleFootprint` with C circles
    heading : (..., K), optional; default :func:`headings` of ``xy``

    Returns
    -------
    (..., C, K, 2)
    """
    xy = jnp.asarray(xy)
    r = footprint.offsets_array().astype(xy.dtype)  # (C,)
    if heading is None:
        heading = headings(xy)
    heading = jnp.asarray(heading)
    u = jnp.stack([jnp.cos(heading), jnp.sin(heading)], axis=-1)  # (..., K, 2)
    return xy[..., None, :, :] + r[:, None, None] * u[..., None, :, :]
