"""Junctions in highway-env's road network: the routes a car can take from its lane, a
multi-modal predictor with one mode per route, and the conflict areas where those routes cross
the ego's path (for the shield's crossing rule, :func:`mmdopt.safety.check_crossings`).

* :func:`routes_from` — every route from a lane over ``reach`` metres: the road network's
  successors at each node (``intersection-v2``'s entry: right, straight, left; a roundabout's
  node: on round the ring or out at the exit), never a way back.
* :class:`RoutePredictor` (``--predictor route``) — per car, one mode per route with stated
  weights (uniform), each a motion along that route's centre line at a speed with noise.
* :func:`crossings` — per car near the ego and per route of it, the interval of the ego's path
  that the route crosses and the earliest time the car can reach it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .roads import LaneChain, _route_successor

#: the most routes per car (the first found, depth first, straightest first)
MAX_ROUTES = 6
#: metres of route beyond the farthest a car can go in the horizon
ROUTE_SLACK = 20.0
#: the car length and width of highway-env's vehicles (m)
CAR_LENGTH, CAR_WIDTH = 5.0, 2.0


def _next_roads(network, index):
    """The lanes that can follow lane ``index``: one per road leaving its end node (the lane of
    that road that starts nearest its end), without the ways back (a turn of more than 90°)."""
    _from, _to, _id = index
    nxt = network.graph.get(_to) or {}
    lane = network.get_lane(index)
    end_h = lane.heading_at(lane.length)
    out = []
    for road in nxt:
        cand = _route_successor(network, index, [(_from, _to, _id), (_to, road, None)])
        if cand is None:
            continue
        h = network.get_lane(cand).heading_at(0.0)
        turn = abs(math.remainder(h - end_h, 2 * math.pi))
        if turn <= 0.5 * math.pi:
            out.append((turn, cand))
    return [c for _, c in sorted(out)]


def routes_from(network, index, reach: float, *, start_s: float = 0.0) -> list[tuple]:
    """Every route (a tuple of lane indices) from lane ``index`` of ``network`` until it covers
    ``reach`` metres past ``start_s`` or ends, straightest first, at most :data:`MAX_ROUTES`."""
    if not (math.isfinite(reach) and reach > 0):
        raise ValueError(f"reach must be > 0 m, got {reach!r}")
    out: list[tuple] = []
    stack = [((tuple(index),), float(network.get_lane(index).length) - float(start_s))]
    while stack and len(out) < MAX_ROUTES:
        route, covered = stack.pop()
        nxt = [] if covered >= reach else _next_roads(network, route[-1])
        nxt = [c for c in nxt if c[:2] not in {r[:2] for r in route}]
        if not nxt:
            out.append(route)
            continue
        for c in reversed(nxt):  # straightest popped first
            stack.append((route + (c,), covered + float(network.get_lane(c).length)))
    return out


@dataclass
class RoutePredictor:
    """A multi-modal predictor that is not the simulator: one mode per route a car can take from
    its lane (:func:`routes_from` over the horizon's reach), with the stated weights ``weights``
    ("uniform": each route equally likely; the samples split among the modes as evenly as
    whole samples allow, mode ``j % M`` for sample ``j``).  In each mode the car moves along
    the route's centre line (:class:`~.roads.LaneChain`, through the junction) at its observed
    speed along its lane with a constant acceleration drawn from N(0, ``sigma_accel``²) (the
    first sample of each mode noise-free), clipped to ``[-accel_limit, accel_limit / 2]``, its
    speed kept within ``[0, lane speed limit + 2 m/s]``, and keeps its lateral offset from the
    centre line.  A car's speed is the one observed (its tracked motion, as the cv predictor's).
    After each call ``last_modes`` (O, n) gives each sample's mode and ``last_routes`` each car's
    routes (for videos and the shield's crossing rule)."""

    sigma_accel: float = 1.5
    accel_limit: float = 6.0
    weights: str = "uniform"
    name: str = "route"
    last_time_s: float = 0.0
    last_modes: np.ndarray | None = None
    last_routes: list = field(default_factory=list)
    _tracker: object = field(default=None, init=False, repr=False)
    _chains: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        for f in ("sigma_accel", "accel_limit"):
            v = getattr(self, f)
            if isinstance(v, bool) or not isinstance(v, int | float) or not (0 <= v < math.inf):
                raise ValueError(f"{f} must be a finite number >= 0 (m/s²), got {v!r}")
        if self.weights != "uniform":
            raise ValueError(f"weights must be 'uniform', got {self.weights!r}")
        from .predictors import ConstantVelocityPredictor

        self._tracker = ConstantVelocityPredictor()

    def record(self, road, dt: float) -> None:
        """Track every car's position (the observed velocities, as the cv predictor does)."""
        self._tracker.record(road, dt)

    def chain(self, network, route: tuple) -> LaneChain:
        """The centre line of ``route`` (cached: the network does not change in an episode)."""
        key = (id(network), route)
        ch = self._chains.get(key)
        if ch is None:
            total = sum(float(network.get_lane(li).length) for li in route)
            ch = LaneChain.follow(network, route[0], total, route=list(route))
            self._chains[key] = ch
        return ch

    def modes(self, road, vehicle, horizon: float) -> tuple[list[tuple], float, float, float]:
        """``(routes, s0, d0, v0)`` of ``vehicle``: its routes over the horizon's reach, its
        lane coordinates and its observed speed along its lane."""
        net = road.network
        lane = net.get_lane(vehicle.lane_index)
        s0, d0 = (float(c) for c in lane.local_coordinates(np.asarray(vehicle.position, float)))
        h = float(lane.heading_at(max(s0, 0.0)))
        vel = self._tracker.observed_velocity(vehicle)
        v0 = max(float(vel[0] * math.cos(h) + vel[1] * math.sin(h)), 0.0)
        v_top = float(lane.speed_limit or 20.0) + 2.0
        reach = max(v0, v_top) * horizon + ROUTE_SLACK
        return routes_from(net, vehicle.lane_index, reach, start_s=max(s0, 0.0)), s0, d0, v0

    def __call__(self, road, ego_vehicle, targets, t_grid: np.ndarray, n: int, rng) -> np.ndarray:
        t0 = time.perf_counter()
        t = np.asarray(t_grid, dtype=float)
        O, K = len(targets), t.shape[0]
        out = np.zeros((O, n, K, 2))
        modes = np.zeros((O, n), dtype=np.int64)
        self.last_routes = []
        for o, v in enumerate(targets):
            routes, s0, d0, v0 = self.modes(road, v, float(t[-1]))
            self.last_routes.append(routes)
            m = np.arange(n) % len(routes)
            first = np.zeros(n, bool)
            first[: len(routes)] = True
            a = rng.normal(size=n) * self.sigma_accel
            a[first] = 0.0
            a = np.clip(a, -self.accel_limit, 0.5 * self.accel_limit)
            lane = road.network.get_lane(v.lane_index)
            v_top = float(lane.speed_limit or 20.0) + 2.0
            vt = np.clip(v0 + a[:, None] * t[None, :], 0.0, max(v_top, v0))  # (n, K)
            dt = np.diff(t, prepend=t[0])
            s = s0 + np.cumsum(0.5 * (vt + np.concatenate([vt[:, :1], vt[:, :-1]], 1)) * dt, 1)
            for j, route in enumerate(routes):
                sel = m == j
                if sel.any():
                    out[o, sel] = self.chain(road.network, route).position(s[sel], d0)
            modes[o] = m
        self.last_modes = modes
        self.last_time_s = time.perf_counter() - t0
        return out


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
        routes, s0, d0, v0 = predictor.modes(road, v, horizon)
        v_top = float(road.network.get_lane(v.lane_index).speed_limit or 20.0) + 2.0
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
    "MAX_ROUTES",
    "RoutePredictor",
    "crossings",
    "earliest_arrival",
    "routes_from",
]
