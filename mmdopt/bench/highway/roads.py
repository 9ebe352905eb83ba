"""The ego's road in the planner's terms, built from highway-env's lane network.

* :class:`LaneChain` — a lane followed through its successors (``_from → _to → …``, the same lane
  id where the next road has it), sampled every 0.5 m: arc length, centre points and normals.
  A chain that returns to its first road is *closed* (a loop such as ``racetrack-v0``'s).
* :func:`build_road` — the Frenet reference path and the :class:`mmdopt.Road` at the ego's
  position.  Roads whose lanes all run straight along +x (``highway-v0``, ``highway-fast-v0``,
  ``merge-v0``'s main road) keep the straight path along +x at ``y = 0`` (Frenet ``d`` = ``y``).
  Any other road uses the centre line of the ego's own lane: on a loop a window of it that starts
  ``back`` metres behind the ego and stops short of closing, so every point has one Frenet
  coordinate; :func:`reanchor` moves the window forward as the ego drives round (the planner plans
  in arc length relative to the ego, so a moved window changes nothing but the offset).
  Lateral bounds are the centres of the outermost lanes beside the ego's; the lane-centre offsets
  are the Frenet ``d`` of every lane beside the ego's.
* :func:`on_road` — whether a point lies on any lane of the network (highway-env's ``on_lane``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

import frenet
import mmdopt

#: spacing (m) of the dense samples of a lane chain
SPACING = 0.5
#: length (m) over which a jump between consecutive lanes of a chain is blended out
BLEND = 5.0


# ------------------------------------------------------------------------------------ lane chain
def _successor(network, index):
    """The lane following ``index``: the next road (the straightest continuation where a node
    has several) and the same lane id where that road has it, else its nearest; ``None`` at a
    dead end."""
    _from, _to, _id = index
    nxt = network.graph.get(_to)
    if not nxt:
        return None
    end_heading = network.get_lane(index).heading_at(network.get_lane(index).length)

    def turn(road):
        h = network.graph[_to][road][0].heading_at(0.0)
        return abs(math.remainder(h - end_heading, 2 * math.pi))

    road = min(nxt, key=turn)
    if turn(road) > 0.5 * math.pi:  # only a way back (an exit's end meets its entry): a dead end
        return None
    return (_to, road, min(int(_id), len(nxt[road]) - 1))


def _route_successor(network, index, route):
    """The lane after ``index`` on ``route`` (highway-env's list of ``(from, to, id | None)``):
    the route's next road, its lane whose start lies nearest the end of ``index`` (the
    continuous one); ``None`` when ``index``'s road is not on the route or is its last."""
    roads = [tuple(r[:2]) for r in route]
    here = tuple(index[:2])
    if here not in roads:
        return None
    k = roads.index(here)
    if k + 1 >= len(roads):
        return None
    _from, _to = roads[k + 1]
    if _from != index[1] or _to not in network.graph.get(_from, {}):
        return None
    return _joining_lane(network, index, _to, route[k + 1][2])


def _joining_lane(network, index, to, want=None):
    """The lane of the road ``index[1] → to`` that continues lane ``index``: lane ``want`` when
    that road has it, else the one whose start lies nearest the end of ``index``."""
    end = network.get_lane(index).position(network.get_lane(index).length, 0.0)
    lanes = network.graph[index[1]][to]
    ids = range(len(lanes))
    if want is not None and 0 <= int(want) < len(lanes):
        ids = [int(want)]
    best = min(ids, key=lambda i: float(np.linalg.norm(lanes[i].position(0.0, 0.0) - end)))
    return (index[1], to, int(best))


def check_route(network, route) -> list:
    """``route`` as a list of lane indices ``(from, to, id | None)`` of ``network``, each road
    following the one before; ``ValueError`` naming the first road that is not there."""
    if route is None:
        return []
    out = []
    for k, r in enumerate(route):
        if len(r) != 3 or r[1] not in network.graph.get(r[0], {}):
            raise ValueError(f"route[{k}] = {r!r} is not a road of the network")
        if k and r[0] != out[-1][1]:
            raise ValueError(f"route[{k}] = {r!r} does not start where route[{k - 1}] ends")
        out.append((r[0], r[1], None if r[2] is None else int(r[2])))
    return out


def chain_indices(network, index, length: float | None = None, *, start_s: float = 0.0, route=None):
    """``(indices, closed)``: the lanes of the chain from ``index`` (see :meth:`LaneChain.follow`)
    without sampling them.  With ``route`` (highway-env's route of a vehicle: road after road to
    its destination), the chain follows it where it can and the straightest successors after
    its end."""
    route = check_route(network, route)
    lanes, idx, total, closed = [], tuple(index), 0.0, False
    for _ in range(10_000):
        lanes.append(idx)
        total += network.get_lane(idx).length
        nxt = _route_successor(network, idx, route) if route else None
        if nxt is None:
            nxt = _successor(network, idx)
        if nxt is None:
            break
        if nxt[:2] == tuple(index)[:2]:
            closed = True
            break
        if length is not None and total - start_s >= length:
            break
        idx = nxt
    return lanes, closed


@dataclass(frozen=True, eq=False)
class LaneChain:
    """The centre line of a lane followed through its successors (see the module docstring).

    ``indices``: the lane indices in order; ``s`` (M,): arc length; ``xy`` (M, 2): centre points;
    ``normal`` (M, 2): unit normals to the left of travel (highway-env's lateral direction, the
    Frenet ``+d``); ``closed``: whether the chain returns to its first road (then ``length`` is
    the lap and the samples do not repeat the first point).
    """

    indices: tuple
    s: np.ndarray
    xy: np.ndarray
    normal: np.ndarray
    closed: bool
    length: float

    @classmethod
    def follow(
        cls,
        network,
        index,
        length: float | None = None,
        *,
        start_s: float = 0.0,
        route=None,
    ):
        """The chain from lane ``index`` of highway-env's ``network``: until it returns to its
        first road (closed), reaches a dead end, or covers ``length`` metres past ``start_s``
        (the longitudinal position on the first lane where the chain begins); along ``route``
        (road after road, :func:`chain_indices`) where one is given."""
        if length is not None and not (math.isfinite(length) and length > 0):
            raise ValueError(f"length must be > 0 m, got {length!r}")
        lanes, closed = chain_indices(network, index, length, start_s=start_s, route=route)
        objs = [network.get_lane(li) for li in lanes]
        kinks = _kinks(objs, closed)
        lo = [0.0] * len(objs)
        hi = [float(lane.length) for lane in objs]
        for k, cut in kinks.items():
            hi[k] = float(objs[k].length) - cut
            lo[(k + 1) % len(objs)] = cut
        pts, nrm, lane_no, s_lane = [], [], [], []
        for k, lane in enumerate(objs):
            last = k == len(objs) - 1 and not closed
            n = max(2, int(math.ceil((hi[k] - lo[k]) / SPACING)) + 1)
            ss = np.linspace(lo[k], hi[k], n)[: (None if last or k in kinks else -1)]
            for s in ss:
                pts.append(lane.position(float(s), 0.0))
                h = lane.heading_at(float(s))
                nrm.append((-math.sin(h), math.cos(h)))
            lane_no += [k] * len(ss)
            s_lane += list(ss)
            if k in kinks:  # the smooth join to the next lane (lane number -1: not blended)
                nxt = objs[(k + 1) % len(objs)]
                jp, jn = _hermite_join(lane, hi[k], nxt, lo[(k + 1) % len(objs)])
                pts += list(jp)
                nrm += list(jn)
                lane_no += [-1] * len(jp)
                s_lane += [0.0] * len(jp)
        xy, normal = np.array(pts, float), np.array(nrm, float)
        lane_no, s_lane = np.array(lane_no), np.array(s_lane)
        _blend_jumps(xy, lanes, lane_no, s_lane, network, closed, skip=set(kinks))
        seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        keep = np.concatenate([[True], seg > 1e-6])
        xy, normal = xy[keep], normal[keep]
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
        lap = s[-1] + (float(np.linalg.norm(xy[0] - xy[-1])) if closed else 0.0)
        return cls(tuple(lanes), s, xy, normal, closed, float(lap))

    def _wrap(self, s):
        s = np.asarray(s, dtype=float)
        return np.mod(s, self.length) if self.closed else s

    def position(self, s, d=0.0) -> np.ndarray:
        """Points ``(..., 2)`` at arc length ``s`` (modulo the lap on a closed chain; linear past
        an open chain's ends) and lateral offset ``d`` (m, left of travel)."""
        s = self._wrap(s)
        s, d = np.broadcast_arrays(s, np.asarray(d, dtype=float))
        if self.closed:  # the closing segment: append the first sample at the lap's length
            ks = np.append(self.s, self.length)
            kxy, kn = np.vstack([self.xy, self.xy[:1]]), np.vstack([self.normal, self.normal[:1]])
        else:
            ks, kxy, kn = self.s, self.xy, self.normal
        out = np.empty(s.shape + (2,))
        for c in (0, 1):
            out[..., c] = np.interp(s, ks, kxy[:, c]) + d * np.interp(s, ks, kn[:, c])
        if not self.closed:  # straight extension beyond the ends
            t0 = (kxy[1] - kxy[0]) / np.linalg.norm(kxy[1] - kxy[0])
            t1 = (kxy[-1] - kxy[-2]) / np.linalg.norm(kxy[-1] - kxy[-2])
            before, after = s < 0, s > ks[-1]
            out[before] = kxy[0] + s[before, None] * t0 + d[before, None] * kn[0]
            e = s[after, None] - ks[-1]
            out[after] = kxy[-1] + e * t1 + d[after, None] * kn[-1]
        return out

    def window(self, start: float, length: float) -> np.ndarray:
        """Centre points from arc length ``start`` over ``length`` metres (every sample in
        between, unwrapped round a closed chain), for a :class:`frenet.ReferencePath`."""
        if self.closed and length >= self.length:
            raise ValueError(
                f"length {length:.1f} m must be shorter than the lap {self.length:.1f} m"
            )
        if self.closed:
            start = float(np.mod(start, self.length))
        laps = np.arange(-1, 2 + int(length // max(self.length, 1e-9)))
        if self.closed:
            s_all = (self.s[None, :] + self.length * laps[:, None]).ravel()
            xy_all = np.tile(self.xy, (len(laps), 1))
        else:
            s_all, xy_all = self.s, self.xy
        inside = (s_all > start) & (s_all < start + length)
        ends = self.position(np.array([start, start + length]))
        pts = np.vstack([ends[:1], xy_all[inside], ends[1:]])
        step = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        return pts[np.concatenate([[True], step > 0.05])]


#: a join between consecutive lanes whose headings differ by more than this (rad) is a kink
#: (``roundabout-v1``'s entries and exits meet the ring at 47°): the chain joins them smoothly
KINK = 0.1
#: metres of each lane replaced by the smooth join at a kink (at most 40 % of a lane)
JOIN = 6.0


def _kinks(lanes, closed) -> dict[int, float]:
    """``{k: cut}``: the joins ``k → k + 1`` of ``lanes`` (highway-env lane objects) whose
    headings differ by more than :data:`KINK`, with the metres cut from either lane there."""
    out = {}
    n = len(lanes)
    for k in range(n if closed else n - 1):
        a, b = lanes[k], lanes[(k + 1) % n]
        dh = math.remainder(b.heading_at(0.0) - a.heading_at(a.length), 2 * math.pi)
        if abs(dh) > KINK:
            out[k] = min(JOIN, 0.4 * float(a.length), 0.4 * float(b.length))
    return out


def _hermite_join(a, s_a: float, b, s_b: float):
    """Points and left normals strictly between lane ``a`` at ``s_a`` and lane ``b`` at ``s_b``
    on the cubic Hermite curve that leaves ``a`` along its heading and meets ``b`` along its own
    (tangent lengths the chord's): continuous position and heading where two lanes meet at an
    angle."""
    p0, p1 = np.asarray(a.position(s_a, 0.0), float), np.asarray(b.position(s_b, 0.0), float)
    h0, h1 = float(a.heading_at(s_a)), float(b.heading_at(s_b))
    m = float(np.linalg.norm(p1 - p0))
    t0 = m * np.array([math.cos(h0), math.sin(h0)])
    t1 = m * np.array([math.cos(h1), math.sin(h1)])
    n = max(2, int(math.ceil(1.3 * m / SPACING)))
    u = np.linspace(0.0, 1.0, n + 1)[1:-1, None]
    pts = (
        (2 * u**3 - 3 * u**2 + 1) * p0
        + (u**3 - 2 * u**2 + u) * t0
        + (-2 * u**3 + 3 * u**2) * p1
        + (u**3 - u**2) * t1
    )
    der = (6 * u**2 - 6 * u) * p0 + (3 * u**2 - 4 * u + 1) * t0
    der = der + (-6 * u**2 + 6 * u) * p1 + (3 * u**2 - 2 * u) * t1
    der = der / np.linalg.norm(der, axis=1, keepdims=True)
    return pts, np.stack([-der[:, 1], der[:, 0]], axis=1)


def _blend_jumps(xy, lanes, lane_no, s_lane, network, closed, skip=frozenset()) -> None:
    """Spread each jump between the end of a lane and the start of the next (highway-env's lanes
    need not meet exactly: up to 2.6 m on ``racetrack-v0``) linearly over ``BLEND`` metres on
    either side, in place, so the centre line is continuous; points farther from a junction are
    unchanged.  The joins in ``skip`` (kinks, already joined smoothly) are left alone."""
    n_lanes = len(lanes)
    for k in range(n_lanes if closed else n_lanes - 1):
        if k in skip:
            continue
        a = network.get_lane(lanes[k])
        b = network.get_lane(lanes[(k + 1) % n_lanes])
        gap = b.position(0.0, 0.0) - a.position(a.length, 0.0)
        if float(np.linalg.norm(gap)) < 1e-6:
            continue
        on_a = lane_no == k
        w_a = np.clip(1.0 - (a.length - s_lane[on_a]) / BLEND, 0.0, 1.0)
        xy[on_a] += 0.5 * w_a[:, None] * gap
        on_b = lane_no == (k + 1) % n_lanes
        w_b = np.clip(1.0 - s_lane[on_b] / BLEND, 0.0, 1.0)
        xy[on_b] -= 0.5 * w_b[:, None] * gap


# ------------------------------------------------------------------------------------ the road
@dataclass(frozen=True, eq=False)
class RoadModel:
    """The planner's road: ``road`` (:class:`mmdopt.Road`, with ``road.path``), the lane-centre
    offsets ``lane_centres`` (m, Frenet ``d``), ``chain`` (the ego's lane chain; ``None`` on a
    straight road along +x), ``start`` (arc length along ``chain`` of the path's ``s = 0``) and
    ``reach`` (m of path the ego needs ahead of it before :func:`reanchor` moves the window)."""

    road: mmdopt.Road
    lane_centres: tuple[float, ...]
    chain: LaneChain | None = None
    start: float = 0.0
    reach: float = math.inf

    @property
    def path(self) -> frenet.ReferencePath:
        return self.road.path


def straight_along_x(network, lanes) -> bool:
    """Whether every lane in ``lanes`` (indices of ``network``) is a straight lane along +x."""
    from highway_env.road.lane import StraightLane

    for li in lanes:
        lane = network.get_lane(li)
        if type(lane) is not StraightLane or abs(math.sin(lane.heading)) > 1e-9:
            return False
        if math.cos(lane.heading) < 0:
            return False
    return True


#: on a curved road, the clearance (m) kept between the car's side and the road's edge when the
#: lateral bounds reach past the outermost lane centres (see :func:`build_road`)
EDGE_CLEARANCE = 0.5
#: half the car's width (m) for that clearance (highway-env's cars are 2 m wide)
HALF_WIDTH = 1.0


def _make_road(path, offsets, limits: dict, edge: float = 0.0) -> mmdopt.Road:
    return mmdopt.Road(
        path=path,
        y_lb=min(offsets) - edge,
        y_ub=max(offsets) + edge,
        lane_centres=tuple(offsets),
        **limits,
    )


def build_road(
    network,
    lane_index,
    position,
    *,
    limits: dict,
    back: float = 40.0,
    ahead: float = 80.0,
    horizon: float = 5.0,
    route=None,
) -> RoadModel:
    """The :class:`RoadModel` of a vehicle at ``position`` on lane ``lane_index`` of highway-env's
    ``network`` (see the module docstring).

    ``limits``: the :class:`mmdopt.Road` fields other than the path and lane bounds (``v_max``,
    ``ax_max``, ...); on a curved road ``v_max`` is also capped at the lane's speed limit (the
    Frenet bounds do not limit the centripetal acceleration), and the lateral bounds reach past the
    outermost lane centres to :data:`HALF_WIDTH` + :data:`EDGE_CLEARANCE` inside the road's edge
    (a tracked car drifts outward in a bend; the lane-centring cost keeps plans at the centres).
    On a straight road along +x they are the outermost lane centres.  ``back``: metres of path
    behind the vehicle; ``ahead``: the perception range (m) and ``horizon`` the planning horizon
    (s): the path keeps ``ahead + v_max·horizon + 10`` m ahead of the vehicle (on a loop by
    :func:`reanchor`).  On a curved road the path is the centre line of the vehicle's own lane;
    the benchmark rebuilds it when the ego has moved into another lane
    (:meth:`~.adapter.HighwaySource.observe`), so the ego plans near ``d = 0`` where arc length
    and distance driven agree.  ``route`` (the vehicle's route to its destination, highway-env's
    list of lane indices): the path follows it through a junction (:func:`chain_indices`).
    """
    for name, v in (("back", back), ("ahead", ahead), ("horizon", horizon)):
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be > 0, got {v!r}")
    if "v_max" not in limits:
        raise ValueError("limits must contain v_max (m/s)")
    position = np.asarray(position, dtype=float)
    side = network.all_side_lanes(lane_index)
    lane = network.get_lane(lane_index)
    s_lane = float(lane.local_coordinates(position)[0])
    need = back + ahead + float(limits["v_max"]) * horizon + 410.0
    indices, _ = chain_indices(network, lane_index, need, start_s=s_lane, route=route)
    if straight_along_x(network, [li for c in indices for li in network.all_side_lanes(c)]):
        path = frenet.ReferencePath.straight(20_000.0, start=(-5000.0, 0.0))
        ys = [float(network.get_lane(i).position(s_lane, 0.0)[1]) for i in side]
        return RoadModel(_make_road(path, sorted(ys), limits), tuple(sorted(ys)))
    chain = LaneChain.follow(network, lane_index, need, start_s=s_lane, route=route)
    limits = dict(limits)
    if lane.speed_limit is not None:
        limits["v_max"] = min(float(limits["v_max"]), float(lane.speed_limit))
    reach = ahead + limits["v_max"] * horizon + 10.0
    start = s_lane - back
    if chain.closed:
        length = chain.length - back
        if length - back < reach:
            raise ValueError(
                f"the loop of lane {lane_index} ({chain.length:.0f} m) is too short for "
                f"{reach:.0f} m ahead and {back:.0f} m behind the ego"
            )
    else:
        length = chain.s[-1] - start
    path = frenet.ReferencePath.from_waypoints(chain.window(start, length), spacing=SPACING)
    offsets = []
    for li in side:
        other = network.get_lane(li)
        p = other.position(float(other.local_coordinates(position)[0]), 0.0)
        offsets.append(float(path.to_frenet(p[0], p[1])[1]))
    offsets = sorted(offsets)
    edge = max(0.0, 0.5 * float(lane.width_at(s_lane)) - HALF_WIDTH - EDGE_CLEARANCE)
    road = _make_road(path, offsets, limits, edge)
    return RoadModel(road, tuple(offsets), chain, start, reach)


def reanchor(model: RoadModel, s: float, *, back: float = 40.0) -> tuple[RoadModel, float]:
    """On a loop, when the vehicle at Frenet ``s`` has less than ``model.reach`` metres of path
    ahead, the same road with the path window moved to start ``back`` metres behind it; returns
    ``(model, shift)`` where ``shift`` (m) is subtracted from arc lengths of the old path to get
    those of the new one (0 and the same model when nothing moved)."""
    if model.chain is None or not model.chain.closed or s + model.reach <= model.path.length:
        return model, 0.0
    shift = float(s) - back
    start = model.start + shift
    path = frenet.ReferencePath.from_waypoints(
        model.chain.window(start, model.path.length), spacing=SPACING
    )
    road = dataclasses.replace(model.road, path=path)
    return dataclasses.replace(model, road=road, start=start), shift


def on_road(network, position) -> bool:
    """Whether ``position`` lies on some lane of highway-env's ``network`` (``lane.on_lane``:
    within half its width of its centre line, between its ends), or past the end of the road
    in line with a lane that ends there (``merge-v0``'s road ends 460 m from the start: driving
    on past it is the episode outlasting the road, not a departure from it)."""
    p = np.asarray(position, dtype=float)
    if any(lane.on_lane(p) for lane in network.lanes_list()):
        return True
    for tos in network.graph.values():
        for to, lanes in tos.items():
            if network.graph.get(to):  # the road goes on after these lanes
                continue
            for lane in lanes:
                s, d = (float(c) for c in lane.local_coordinates(p))
                if s > float(lane.length) and abs(d) <= 0.5 * float(lane.width_at(s)):
                    return True
    return False


def follow_lanes(network, vehicles, t, v_long, v_lat) -> np.ndarray:
    """Positions ``(O, n, K, 2)`` of ``vehicles`` moving along their lanes: each starts at its
    lane coordinates ``(s, d)`` and moves by ``v_long`` (O, n) m/s along its lane's centre line
    (through the lane's successors, :class:`LaneChain`) and ``v_lat`` (O, n) m/s across it, at the
    times ``t`` (K,) s — constant velocity in the lane's own frame, which follows the curves."""
    t = np.asarray(t, dtype=float)
    v_long, v_lat = np.asarray(v_long, dtype=float), np.asarray(v_lat, dtype=float)
    if v_long.shape != v_lat.shape or v_long.shape[0] != len(vehicles):
        raise ValueError(
            f"v_long and v_lat must have shape (O, n) with O = {len(vehicles)}, got "
            f"{v_long.shape}, {v_lat.shape}"
        )
    out = np.empty(v_long.shape + (t.shape[0], 2))
    for o, v in enumerate(vehicles):
        lane = network.get_lane(v.lane_index)
        s0, d0 = (float(c) for c in lane.local_coordinates(np.asarray(v.position, float)))
        reach = float(np.max(np.abs(v_long[o]))) * float(t[-1]) + 10.0
        chain = LaneChain.follow(network, v.lane_index, reach, start_s=max(s0, 0.0))
        s = s0 + v_long[o][:, None] * t[None, :]
        d = d0 + v_lat[o][:, None] * t[None, :]
        out[o] = chain.position(s, d)
    return out


# ------------------------------------------------------------------------------ route and arrival
def route_of(vehicle) -> list | None:
    """The route of a highway-env vehicle to its destination (its ``route``, a list of lane
    indices) when it has one through more than one road (``plan_route_to`` of the env's
    configured destination), else None: on a road without destination the ego drives on."""
    route = getattr(vehicle, "route", None)
    if not route or len({tuple(r[:2]) for r in route}) < 2:
        return None
    return [tuple(r) for r in route]


#: how far (m) along the last road of its route a vehicle has arrived (intersection-v2's own
#: ``has_arrived`` distance on its exit lanes)
ARRIVAL_DISTANCE = 25.0


def arrived(env, vehicle, route) -> bool:
    """Whether ``vehicle`` has reached the end of ``route``: the env's own ``has_arrived`` where
    it has one (intersection-v2: on an exit lane, 25 m along it), else on the route's last road
    at least ``min(ARRIVAL_DISTANCE, half its length)`` along it, or on a road that starts
    where the route ends (past it).  False without a route."""
    if not route or getattr(vehicle, "lane_index", None) is None:
        return False
    if hasattr(env, "has_arrived"):
        return bool(env.has_arrived(vehicle))
    net = env.road.network
    here = tuple(vehicle.lane_index[:2])
    last = tuple(route[-1][:2])
    if here[0] == last[1]:
        return True
    if here != last:
        return False
    lane = net.get_lane(vehicle.lane_index)
    s = float(lane.local_coordinates(np.asarray(vehicle.position, float))[0])
    return s >= min(ARRIVAL_DISTANCE, 0.5 * float(lane.length))


# ------------------------------------------------------------------------------ routes of a car
#: the most routes per car (:func:`routes_from`: the first found, depth first, straightest first)
MAX_ROUTES = 6


def _next_roads(network, index):
    """The lanes that can follow lane ``index``: one per road leaving its end node (the lane of
    that road that starts nearest its end), without the ways back (a turn of more than 90°)."""
    nxt = network.graph.get(index[1]) or {}
    lane = network.get_lane(index)
    end_h = lane.heading_at(lane.length)
    out = []
    for road in nxt:
        cand = _joining_lane(network, index, road)
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
