"""Footprints: the collision ellipse of eq. (coll_constraints) and the circles that cover a car.

The ellipse is stated here once.  :class:`Footprint` is the safety section of
:class:`mmdopt.MMDOptConfig` that every user of the ellipse reads: the planner's collision term,
de Groot's reduced-set selection, the collision-free count of the plan, and the reference
surrogate.  :class:`CircleFootprint` places circles along a body's heading (a car is covered by
three circles on its axis, the ego by one: a point whose clearance the ellipse provides).

This module sits below :mod:`mmdopt.collision` and :mod:`mmdopt.reduced_set`, which both read it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp

__all__ = [
    "ELLIPSE_A",
    "ELLIPSE_B",
    "Footprint",
    "CircleFootprint",
    "OBSTACLE_FOOTPRINT",
    "EGO_FOOTPRINT",
]

#: longitudinal semi-axis of the collision ellipse (m), the reference's value
ELLIPSE_A = 4.5
#: lateral semi-axis of the collision ellipse (m), the reference's value
ELLIPSE_B = 3.5


def _plain_number(v) -> bool:
    # only plain numbers are validated: pytree unflattening (jit, vmap) passes other objects
    return isinstance(v, int | float) and not isinstance(v, bool)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Footprint:
    """The collision ellipse ``f = 1 − Δs²/a² − Δd²/b²`` of eq. (coll_constraints) (m).

    a, b : longitudinal and lateral semi-axes (pytree leaves: changing them does not recompile).
    yaw_extent : the body's extent ahead of and behind its reference point (m; static, 0: off).
        When > 0 the planner widens the lateral semi-axis by ``yaw_extent·|sin Δθ|`` where the
        plan turns by Δθ from the path, so a turning plan does not swing a corner into the next
        lane unseen (not in the paper; :func:`mmdopt.algorithm.yaw_widening`).
    """

    a: float = ELLIPSE_A
    b: float = ELLIPSE_B
    yaw_extent: float = field(default=0.0, metadata=dict(static=True))

    def __post_init__(self) -> None:
        for name in ("a", "b"):
            v = getattr(self, name)
            if isinstance(v, str | bytes | bool | complex):
                raise ValueError(f"Footprint.{name} must be a real number, got {v!r}")
            if _plain_number(v) and not (math.isfinite(v) and v > 0):
                raise ValueError(f"Footprint.{name} must be finite and > 0, got {v!r}")
        v = self.yaw_extent
        if not _plain_number(v) or not (math.isfinite(v) and v >= 0):
            raise ValueError(f"Footprint.yaw_extent must be a finite number >= 0, got {v!r}")

    @property
    def yaw_aware(self) -> bool:
        """Whether the lateral semi-axis follows the plan's heading (``yaw_extent > 0``)."""
        return self.yaw_extent > 0

    def replace(self, **kw) -> Footprint:
        return dataclasses.replace(self, **kw)

    @classmethod
    def from_vehicle(
        cls,
        length: float,
        width: float,
        margin: float = 0.0,
        *,
        obstacle_length: float | None = None,
        obstacle_width: float | None = None,
        yaw_extent: float = 0.0,
    ) -> Footprint:
        """The ellipse of an ego ``length`` × ``width`` (m, overall) against cars of
        ``obstacle_length`` × ``obstacle_width`` (default: the ego's), with ``margin`` (m) of
        clearance on every side.  The planner checks the ego's reference point against the
        circles on each car's axis (:data:`OBSTACLE_FOOTPRINT`, the outer ones at ±2.5 m), so
        the semi-axes are ``a = length/2 + max(obstacle_length/2 − 2.5, 0) + margin`` (the ego's
        half length plus what of the car lies beyond its outer circle) and ``b = width/2 +
        obstacle_width/2 + margin``.  Two 5 m × 2 m cars with 0.5 m of margin:
        ``Footprint(a=3.0, b=2.5)``; the paper's ``a = 4.5, b = 3.5`` are semi-axes (an
        ellipse 9 m × 7 m overall)."""
        vals = dict(length=length, width=width, margin=margin)
        vals["obstacle_length"] = length if obstacle_length is None else obstacle_length
        vals["obstacle_width"] = width if obstacle_width is None else obstacle_width
        for name, v in vals.items():
            least = 0.0 if name == "margin" else None
            if (
                not _plain_number(v)
                or not math.isfinite(v)
                or (v < 0 if least is not None else v <= 0)
            ):
                bound = ">= 0" if least is not None else "> 0"
                raise ValueError(f"{name} must be a finite number {bound} (m), got {v!r}")
        reach = max(abs(o) for o in OBSTACLE_FOOTPRINT.offsets)
        a = vals["length"] / 2 + max(vals["obstacle_length"] / 2 - reach, 0.0) + vals["margin"]
        b = vals["width"] / 2 + vals["obstacle_width"] / 2 + vals["margin"]
        return cls(a=float(a), b=float(b), yaw_extent=yaw_extent)


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


#: a car: three circles on its axis at 0 and ±2.5 m (the reference's obstacle footprint)
OBSTACLE_FOOTPRINT = CircleFootprint(offsets=(0.0, 2.5, -2.5))
#: the ego: one circle at its reference point (the ellipse provides the clearance)
EGO_FOOTPRINT = CircleFootprint(offsets=(0.0,))
