"""Scoring a plan against recorded traffic: footprint overlap, clearance, at-fault rule.

Footprints are oriented rectangles (centre, heading, length × width).  The first contact with each
recorded vehicle is classified after nuPlan's collision metric (``no_ego_at_fault_collisions``):

========================  =========================================================  =========
class                     condition (checked in this order, at the first contact)     at fault
========================  =========================================================  =========
``stopped_ego``           ego speed < 0.05 m/s                                        if braking
``stopped_track``         the other vehicle's speed < 0.05 m/s                        yes
``front``                 the ego's front edge touches the other footprint            yes
``rear``                  the other vehicle's centre is behind the ego's rear bumper  if braking
``lateral``               anything else (side contact)                                if the ego
                                                                                      changes lane,
                                                                                      crosses a
                                                                                      junction or
                                                                                      either car
                                                                                      turns
========================  =========================================================  =========

"if braking": a contact from behind (or with a stopped ego) is the follower's fault unless the ego
braked harder than :data:`BRAKE_THRESHOLD` (3 m/s²) in the second before the contact (a brake
check).  "changes lane": the ego's footprint crosses a lane line (its offset from the nearest lane
centre exceeds ``(lane width − ego width)/2``).  The junction cases (urban scenes): a lateral
contact while the ego's centre is inside a junction (its lanelets: the successors of the
intersection's incomings) or while either car turns (heading rate above
:data:`TURNING_RATE` over the second around the contact) is the ego's fault too: there no lane
line says who keeps to what.  Replaying recorded traffic is open loop: the
recorded followers react to the human who drove the ego's car, not to the plan, which is why
rear contacts are excluded.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "BRAKE_THRESHOLD",
    "COLLISION_CLASSES",
    "TURNING_RATE",
    "at_fault",
    "inside_any",
    "turning",
    "classify_collision",
    "rect_corners",
    "rect_distance",
    "rects_overlap",
]

#: Ego deceleration (m/s²) above which a rear contact counts against the ego.
BRAKE_THRESHOLD = 3.0
#: Speed (m/s) below which a vehicle counts as stopped (nuPlan's value).
STOPPED_SPEED = 0.05
COLLISION_CLASSES = ("stopped_ego", "stopped_track", "front", "rear", "lateral")
#: Heading rate (rad/s) above which a car counts as turning (a right angle in 10 s)
TURNING_RATE = 0.15


def inside_any(p, polygons) -> bool:
    """Whether the point ``p`` (2,) lies inside any of ``polygons`` ((P, 2) arrays; ray casting)."""
    x, y = float(p[0]), float(p[1])
    for poly in polygons:
        q = np.asarray(poly, np.float64)
        xa, ya = q[:, 0], q[:, 1]
        xb, yb = np.roll(xa, -1), np.roll(ya, -1)
        cross = (ya > y) != (yb > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xi = xa + (y - ya) * (xb - xa) / (yb - ya)
        if int(np.sum(cross & (x < xi))) % 2 == 1:
            return True
    return False


def turning(heading, dt: float, j: int, window: float = 1.0) -> bool:
    """Whether a car with headings ``heading`` (K,) every ``dt`` s turns at step ``j``: its mean
    heading rate over ``window`` s around ``j`` above :data:`TURNING_RATE`."""
    h = np.unwrap(np.asarray(heading, np.float64))
    w = max(1, int(round(0.5 * window / dt)))
    a, b = max(0, j - w), min(len(h) - 1, j + w)
    if b <= a or not np.all(np.isfinite(h[[a, b]])):
        return False
    return bool(abs(h[b] - h[a]) / ((b - a) * dt) > TURNING_RATE)


def rect_corners(x, y, heading, length, width) -> np.ndarray:
    """(…, 4, 2) corners [front-left, front-right, rear-right, rear-left] of oriented rectangles."""
    x, y, h, L, W = np.broadcast_arrays(
        *(np.asarray(a, np.float64) for a in (x, y, heading, length, width))
    )
    c, s = np.cos(h), np.sin(h)
    lo = np.array([0.5, 0.5, -0.5, -0.5])
    la = np.array([0.5, -0.5, -0.5, 0.5])
    dx = lo * L[..., None]
    dy = la * W[..., None]
    cx = x[..., None] + c[..., None] * dx - s[..., None] * dy
    cy = y[..., None] + s[..., None] * dx + c[..., None] * dy
    return np.stack([cx, cy], axis=-1)


def rects_overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Separating-axis test for convex quadrilaterals ``a``, ``b`` (…, 4, 2) → bool (…)."""
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    sep = np.zeros(a.shape[:-2], bool)
    for poly in (a, b):
        for i in range(4):
            e = poly[..., (i + 1) % 4, :] - poly[..., i, :]
            n = np.stack([-e[..., 1], e[..., 0]], -1)[..., None, :]
            pa = np.sum(a * n, -1)
            pb = np.sum(b * n, -1)
            sep |= (pa.max(-1) < pb.min(-1)) | (pb.max(-1) < pa.min(-1))
    return ~sep


def _point_segment(p, a, b):
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def rect_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (m) between convex quadrilaterals (…, 4, 2); 0 where they overlap."""
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    best = np.full(a.shape[:-2], np.inf)
    for p, q in ((a, b), (b, a)):
        for i in range(4):
            for j in range(4):
                best = np.minimum(
                    best, _point_segment(p[..., i, :], q[..., j, :], q[..., (j + 1) % 4, :])
                )
    return np.where(rects_overlap(a, b), 0.0, best)


def classify_collision(ego_rect, ego_heading, ego_speed, other_rect, other_xy, other_speed) -> str:
    """Class of one contact (see the module table); rectangles (4, 2) from :func:`rect_corners`."""
    if ego_speed < STOPPED_SPEED:
        return "stopped_ego"
    if other_speed < STOPPED_SPEED:
        return "stopped_track"
    front = ego_rect[:2]  # front-left, front-right
    depth = (
        0.05 * (ego_rect[0] - ego_rect[3]) / max(np.linalg.norm(ego_rect[0] - ego_rect[3]), 1e-9)
    )
    front_strip = np.stack([front[0], front[1], front[1] - depth, front[0] - depth])
    if bool(rects_overlap(front_strip, other_rect)):
        return "front"
    rear_mid = 0.5 * (ego_rect[2] + ego_rect[3])
    u = np.array([np.cos(ego_heading), np.sin(ego_heading)])
    if float(np.dot(np.asarray(other_xy) - rear_mid, u)) < 0.0:
        return "rear"
    return "lateral"


def at_fault(
    cls: str,
    ego_decel: float,
    ego_changing_lanes: bool,
    brake_threshold: float = BRAKE_THRESHOLD,
    in_junction: bool = False,
    turning: bool = False,
) -> bool:
    """The at-fault rule of the module table.  ``ego_decel``: the ego's largest deceleration
    (m/s², positive = braking) in the second before the contact; ``in_junction`` / ``turning``:
    the junction cases of a lateral contact (the ego inside a junction, either car turning)."""
    if cls not in COLLISION_CLASSES:
        raise ValueError(f"unknown collision class {cls!r}; one of {COLLISION_CLASSES}")
    if cls in ("front", "stopped_track"):
        return True
    if cls == "lateral":
        return bool(ego_changing_lanes or in_junction or turning)
    return bool(ego_decel > brake_threshold)
