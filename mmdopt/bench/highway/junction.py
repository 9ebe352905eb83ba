"""Junctions in highway-env's road network: the routes a car can take from its lane, a
multi-modal predictor with one mode per route, and the conflict areas where those routes cross
the ego's path (for the shield's crossing rule, :func:`mmdopt.safety.check_crossings`).

* :func:`~.roads.routes_from` — every route from a lane over ``reach`` metres: the road
  network's successors at each node (``intersection-v2``'s entry: right, straight, left; a
  roundabout's node: on round the ring or out at the exit), never a way back.
* :class:`~.predictors.RoutePredictor` (``--predictor route``) — per car, one mode per route
  with stated weights (uniform), each a motion along that route's centre line at a speed with
  noise.
* :func:`crossings` — per car near the ego and per route of it, the interval of the ego's path
  that the route crosses and the earliest time the car can reach it.
"""

from __future__ import annotations

import numpy as np

from .predictors import ROUTE_SLACK, RoutePredictor

#: the car length and width of highway-env's vehicles (m)
CAR_LENGTH, CAR_WIDTH = 5.0, 2.0


# ------------------------------------------------------------------------------ conflict areas
#: a route crosses the ego's path where their centre lines come closer than this (m): a car
#: width plus half a metre
CROSS_DISTANCE = CAR_WIDTH + 0.5


def _closest(path_xy: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each point of ``pts`` (P, 2): the distance to the nearest of ``path_xy`` (M, 2) and
    that point's index."""
    d2 = ((pts[:, None, :] - path_xy[None, :, :]) ** 2).sum(-1)
    k = np.argmin(d2, axis=1)
    return np.sqrt(d2[np.arange(len(pts)), k]), k


def earliest_arrival(distance, v0, v_top: float, a_max: float) -> np.ndarray:
    """The earliest time (s) a car at speed ``v0`` covers ``distance`` (m, arrays broadcast)
    accelerating at ``a_max`` up to ``v_top``: 0 where ``distance <= 0``."""
    dist = np.maximum(np.asarray(distance, float), 0.0)
    v0 = np.maximum(np.asarray(v0, float), 0.0)
    vt = np.maximum(v_top, v0)
    t_acc = (vt - v0) / a_max
    d_acc = v0 * t_acc + 0.5 * a_max * t_acc**2
    t_in = (-v0 + np.sqrt(v0**2 + 2 * a_max * dist)) / a_max
    return np.where(dist <= d_acc, t_in, t_acc + (dist - d_acc) / np.maximum(vt, 1e-9))


def crossings(
    predictor: RoutePredictor,
    road,
    path,
    s_ego: float,
    cars,
    *,
    ahead: float = 60.0,
    horizon: float = 5.0,
    a_max: float = 3.0,
) -> np.ndarray:
    """Conflict areas ``(C, 3)`` = ``(s_in, s_out, t_arrive)`` on the ego's Frenet ``path`` for
    :func:`mmdopt.safety.check_crossings`: for each of ``cars`` (highway-env vehicles) and each
    of its routes (:meth:`RoutePredictor.modes`), the first stretch of the route ahead of the
    car whose centre line comes within :data:`CROSS_DISTANCE` of the ego's path within
    ``ahead`` metres ahead of the ego (``s_ego``); ``[s_in, s_out]`` is that stretch of the
    ego's path widened by a car length and width (the ego's centre positions where the two
    bodies can touch) and ``t_arrive`` the earliest the car's front can reach it
    (:func:`earliest_arrival`, accelerating at ``a_max`` up to its lane's speed limit + 2 m/s).
    Cars already on the ego's path (within :data:`CROSS_DISTANCE` of it: ahead of or behind
    the ego in its lane) are the longitudinal rule's and are left out."""
    s_grid = np.arange(max(float(s_ego) - 10.0, 0.0), min(s_ego + ahead, path.length), 0.5)
    if s_grid.size < 2:
        return np.zeros((0, 3))
    ex, ey = path.to_cartesian(s_grid, np.zeros_like(s_grid))
    ego_xy = np.stack([np.asarray(ex, float), np.asarray(ey, float)], axis=1)
    pad = 0.5 * (CAR_LENGTH + CAR_WIDTH)
    rows = []
    for v in cars:
        pos = np.asarray(v.position, float)[None, :]
        if _closest(ego_xy, pos)[0][0] < CROSS_DISTANCE:
            continue
        routes, s0, _, v0, v_top = predictor.modes(road, v, horizon)
        for route in routes:
            ch = predictor.chain(road.network, route)
            keep = (ch.s >= s0) & (ch.s <= s0 + max(v0, v_top) * horizon + ROUTE_SLACK)
            if not keep.any():
                continue
            dist, k = _closest(ego_xy, ch.xy[keep])
            near = np.flatnonzero(dist < CROSS_DISTANCE)
            if near.size == 0:
                continue
            run = near[: 1 + int(np.argmax(np.diff(near, append=near[-1] + 2) > 1))]
            s_hit = s_grid[k[run]]
            s_in, s_out = float(s_hit.min()) - pad, float(s_hit.max()) + pad
            d_car = float(ch.s[keep][run[0]]) - s0 - pad
            t_arr = float(earliest_arrival(d_car, v0, v_top, a_max))
            rows.append((s_in, s_out, t_arr))
    return np.array(rows, dtype=float).reshape(-1, 3)


__all__ = [
    "CROSS_DISTANCE",
    "crossings",
    "earliest_arrival",
]
