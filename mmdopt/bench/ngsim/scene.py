"""CommonRoad scenes → plain arrays: lanes, recorded tracks, reference paths, predictor inputs.

The only module that imports ``commonroad`` (:func:`load_scenario`); everything downstream works on
:class:`NgsimScene` (NumPy arrays) and the types of :mod:`frenet`, :mod:`mmdopt` and
:mod:`mmdopt.predict`.

Conventions: tracks are sampled at the scene's ``dt`` (0.1 s for NGSIM), step ``k`` is time
``k·dt``; ``xy[v, k]`` is NaN where vehicle ``v`` is not in the scene.  A lane's *chain* is its
centre line joined with its first predecessors / successors (the ego's *route*), resampled every
:data:`CHAIN_SPACING` metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter1d

import frenet
from mmdopt.predict.base import GAP_NONE, PredictionContext, cartesian_to_lane, neighbour_gaps

from .inputs import ScenarioError, check_scenario_file

__all__ = [
    "CHAIN_SPACING",
    "ROUTE_SMOOTHING",
    "MAX_ROUTES",
    "route_chain",
    "route_speed_limit",
    "curve_speed",
    "WHEELBASE",
    "SPEED_LIMIT_SIGNS",
    "candidate_routes",
    "distance_to_polyline",
    "smooth_polyline",
    "Lane",
    "NgsimScene",
    "load_scenario",
    "scenario_files",
    "lane_chain",
    "history_at",
    "future_at",
    "context_at",
    "present",
]

#: Spacing (m) of resampled lane centre lines.
CHAIN_SPACING = 2.0


@dataclass(frozen=True, eq=False)
class Lane:
    """One lanelet: centre/left/right polylines (P, 2), mean width (m), graph links."""

    id: int
    center: np.ndarray
    left: np.ndarray
    right: np.ndarray
    width: float
    successors: tuple[int, ...]
    predecessors: tuple[int, ...]
    left_id: int | None  # same-direction neighbour
    right_id: int | None
    speed_limit: float | None = None  # m/s, the lanelet's speed-limit sign (None: none)


@dataclass(frozen=True, eq=False)
class NgsimScene:
    """A recorded scene as arrays: ``V`` vehicles over ``T`` steps of ``dt`` seconds."""

    name: str
    path: str
    dt: float
    lanes: dict[int, Lane]
    ids: np.ndarray  # (V,) CommonRoad obstacle ids
    xy: np.ndarray  # (V, T, 2) m, NaN when absent
    heading: np.ndarray  # (V, T) rad
    speed: np.ndarray  # (V, T) m/s
    accel: np.ndarray  # (V, T) m/s²
    length: np.ndarray  # (V,) m
    width: np.ndarray  # (V,) m
    lane_of: np.ndarray = field(repr=False)  # (V, T) lanelet id, -1 off the map / absent
    n_intersections: int = 0  # the lanelet network's intersections (junctions)
    junctions: tuple = ()  # (P, 2) polygons of the lanelets inside the junctions

    @property
    def num_steps(self) -> int:
        return int(self.xy.shape[1])

    @property
    def recording(self) -> int:
        """The recording number N of ``USA_US101-N_K_T-1`` (the train/test split key)."""
        return recording_of(self.name)


def recording_of(name: str) -> int:
    try:
        return int(Path(name).stem.split("-")[1].split("_")[0])
    except (IndexError, ValueError):
        raise ValueError(f"not a USA_US101-N_K_T-1 scene name: {name!r}") from None


def scenario_files(paths) -> list[Path]:
    """CommonRoad ``.xml`` files named by ``paths`` (files or folders, sorted, de-duplicated).
    Raises :class:`~mmdopt.bench.ngsim.inputs.ScenarioError` (a ``ValueError``) naming a path
    that is missing, not an ``.xml`` file, or a folder without ``.xml`` files."""
    if isinstance(paths, str | Path):
        paths = [paths]
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(f for f in p.glob("*.xml") if f.is_file())
            if not found:
                names = sorted(x.name for x in p.iterdir())
                what = f"holds {', '.join(names[:5])}{', …' if names[5:] else ''}"
                raise ScenarioError(
                    f"{p}: folder with no .xml files ({what if names else 'it is empty'}); "
                    "CommonRoad scenarios are .xml files"
                )
            out += found
        elif p.is_file() and p.suffix == ".xml":
            out.append(p)
        elif p.is_file():
            raise ScenarioError(f"{p}: not an .xml file (CommonRoad scenarios are .xml files)")
        else:
            raise ScenarioError(f"{p}: does not exist")
    seen, files = set(), []
    for f in out:
        if f.resolve() not in seen:
            seen.add(f.resolve())
            files.append(f)
    if not files:
        raise ScenarioError(f"no .xml scenario files under {list(map(str, paths))}")
    return files


@lru_cache(maxsize=8)
def load_scenario(path: str | Path) -> NgsimScene:
    """Read a CommonRoad scenario (commonroad-io) into an :class:`NgsimScene` (cached).  A file
    that is not a usable scenario (:func:`~mmdopt.bench.ngsim.inputs.check_scenario_file`, or
    refused by the CommonRoad reader) raises :class:`~mmdopt.bench.ngsim.inputs.ScenarioError`
    naming the file and the reason (also without commonroad-io); without commonroad-io a good
    file raises :class:`~mmdopt.bench._optional.MissingExtra` (an ``ImportError``; the CLI
    prints it, exit status 2)."""
    path = Path(path)
    if not path.is_file():
        raise ScenarioError(f"scenario file {path} does not exist")
    check_scenario_file(path)
    try:
        from commonroad.common.file_reader import CommonRoadFileReader
    except ImportError as exc:  # pragma: no cover - depends on the environment
        from .._optional import MissingExtra

        raise MissingExtra(
            "reading CommonRoad scenes needs commonroad-io: pip install 'mmdopt[commonroad]'"
        ) from exc
    try:
        scenario, _ = CommonRoadFileReader(str(path)).open()
    except Exception as e:  # the reader's errors are of many kinds; one message naming the file
        raise ScenarioError(
            f"{path}: not a readable CommonRoad scenario ({type(e).__name__}: {e})"
        ) from None
    dt = float(scenario.dt)
    net = scenario.lanelet_network
    lanes: dict[int, Lane] = {}
    for ll in net.lanelets:
        w = float(np.mean(np.linalg.norm(ll.left_vertices - ll.right_vertices, axis=-1)))
        lanes[int(ll.lanelet_id)] = Lane(
            id=int(ll.lanelet_id),
            center=np.asarray(ll.center_vertices, np.float64),
            left=np.asarray(ll.left_vertices, np.float64),
            right=np.asarray(ll.right_vertices, np.float64),
            width=w,
            successors=tuple(int(i) for i in ll.successor),
            predecessors=tuple(int(i) for i in ll.predecessor),
            left_id=int(ll.adj_left) if ll.adj_left and ll.adj_left_same_direction else None,
            right_id=int(ll.adj_right) if ll.adj_right and ll.adj_right_same_direction else None,
            speed_limit=_speed_limit(net, ll),
        )
    obs = list(scenario.dynamic_obstacles)
    T = 1 + max([o.prediction.final_time_step for o in obs if o.prediction is not None] + [0])
    V = len(obs)
    xy = np.full((V, T, 2), np.nan)
    hd, sp, ac = (np.full((V, T), np.nan) for _ in range(3))
    length, width = np.zeros(V), np.zeros(V)
    ids = np.zeros(V, dtype=np.int64)
    for v, o in enumerate(obs):
        ids[v] = o.obstacle_id
        length[v] = float(getattr(o.obstacle_shape, "length", 4.5))
        width[v] = float(getattr(o.obstacle_shape, "width", 1.8))
        states = [o.initial_state] + (
            list(o.prediction.trajectory.state_list) if o.prediction is not None else []
        )
        for st in states:
            k = int(st.time_step)
            if 0 <= k < T:
                xy[v, k] = st.position
                hd[v, k] = float(getattr(st, "orientation", np.nan))
                sp[v, k] = float(getattr(st, "velocity", np.nan))
                ac[v, k] = float(getattr(st, "acceleration", 0.0) or 0.0)
    lane_of = np.full((V, T), -1, dtype=np.int64)
    mask = np.all(np.isfinite(xy), -1)
    pts = xy[mask]
    if len(pts):
        found = net.find_lanelet_by_position([p for p in pts])
        lane_ids = [
            _pick_lane(lanes, p, h, c) for p, h, c in zip(pts, hd[mask], found, strict=True)
        ]
        lane_of[mask] = lane_ids
    return NgsimScene(
        name=path.stem,
        path=str(path),
        dt=dt,
        lanes=lanes,
        ids=ids,
        xy=xy,
        heading=hd,
        speed=sp,
        accel=ac,
        length=length,
        width=width,
        lane_of=lane_of,
        n_intersections=len(net.intersections),
        junctions=_junction_polygons(net),
    )


#: CommonRoad's speed-limit signs: the US "R2-1" and the German "274" (value in m/s)
SPEED_LIMIT_SIGNS = ("R2-1", "274")


def _speed_limit(net, lanelet) -> float | None:
    """The lanelet's speed limit (m/s) from its traffic signs, the lowest if several."""
    out = None
    for sid in lanelet.traffic_signs:
        sign = net.find_traffic_sign_by_id(sid)
        for el in getattr(sign, "traffic_sign_elements", ()):
            if str(getattr(el.traffic_sign_element_id, "value", "")) not in SPEED_LIMIT_SIGNS:
                continue
            try:
                v = float(el.additional_values[0])
            except (IndexError, TypeError, ValueError):
                continue
            if np.isfinite(v) and v > 0:
                out = v if out is None else min(out, v)
    return out


def _junction_polygons(net) -> tuple:
    """Polygons of the lanelets inside the network's junctions (the successors of every
    incoming of every intersection)."""
    ids: set[int] = set()
    for it in net.intersections:
        for inc in it.incomings:
            for group in (inc.successors_right, inc.successors_straight, inc.successors_left):
                ids |= {int(i) for i in group}
    out = []
    for i in sorted(ids):
        ll = net.find_lanelet_by_id(i)
        if ll is not None:
            out.append(np.concatenate([ll.left_vertices, ll.right_vertices[::-1]], 0))
    return tuple(out)


def _pick_lane(lanes: dict[int, Lane], p, heading, candidates) -> int:
    """Of the lanelets containing ``p``, the one whose centre line is nearest, among those
    running within 45° of ``heading`` where any does (a junction's lanelets overlap: the cross
    street's lanelet under a car is not its lane)."""
    if not candidates:
        return -1
    if len(candidates) == 1:
        return int(candidates[0])
    scored = []
    for c in candidates:
        cl = lanes[int(c)].center
        i = int(np.argmin(np.linalg.norm(cl - p, axis=-1)))
        j = min(i, len(cl) - 2)
        t = cl[j + 1] - cl[j]
        dh = (
            np.angle(np.exp(1j * (np.arctan2(t[1], t[0]) - heading))) if np.isfinite(heading) else 0
        )
        scored.append((abs(dh) > np.pi / 4, float(np.linalg.norm(cl[i] - p)), int(c)))
    return min(scored)[2]


# --------------------------------------------------------------------------- lane chains
def _dedup(xy: np.ndarray) -> np.ndarray:
    keep = np.concatenate([[True], np.linalg.norm(np.diff(xy, axis=0), axis=-1) > 1e-6])
    return xy[keep]


def _resample(xy: np.ndarray, s_from: float, s_to: float, spacing: float) -> np.ndarray:
    """Polyline ``xy`` resampled at ``spacing`` on ``[s_from, s_to]`` of its arc length
    (linear extension beyond its ends)."""
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=-1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.arange(s_from, s_to + 1e-9, spacing)
    i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(cum) - 2)
    tan = np.diff(xy, axis=0) / seg[:, None]
    return xy[i] + (s - cum[i])[:, None] * tan[i]


def _predecessors(lanes: dict[int, Lane], lane_id: int) -> list[np.ndarray]:
    """Centre lines of ``lane_id``'s chain of (first) predecessors, farthest first."""
    parts, seen, cur = [], {lane_id}, lanes[lane_id]
    while cur.predecessors and cur.predecessors[0] not in seen and cur.predecessors[0] in lanes:
        cur = lanes[cur.predecessors[0]]
        seen.add(cur.id)
        parts.insert(0, cur.center)
    return parts


def lane_chain(scene: NgsimScene, lane_id: int, prefer=()) -> np.ndarray:
    """Centre line of ``lane_id`` joined with its predecessors (first one) and successors (the
    first that is in ``prefer``, else the first), as a de-duplicated (P, 2) polyline."""
    lanes = scene.lanes
    parts = _predecessors(lanes, lane_id) + [lanes[lane_id].center]
    seen = {lane_id}
    cur = lanes[lane_id]
    while cur.successors:
        nxt = [s for s in cur.successors if s in prefer] or list(cur.successors)
        if nxt[0] in seen:
            break
        cur = lanes[nxt[0]]
        seen.add(cur.id)
        parts.append(cur.center)
    return _dedup(np.concatenate(parts, 0))


def _length(xy: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(xy, axis=0), axis=-1)))


def distance_to_polyline(poly: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(N,) distance of each point ``pts`` (N, 2) to the polyline ``poly`` (P, 2)."""
    a, b = poly[:-1], poly[1:]
    ab = b - a
    L2 = np.maximum(np.sum(ab * ab, -1), 1e-12)
    u = np.clip(np.einsum("nsk,sk->ns", pts[:, None] - a[None], ab) / L2, 0.0, 1.0)
    near = a[None] + u[..., None] * ab[None]
    return np.min(np.linalg.norm(pts[:, None] - near, axis=-1), axis=1)


#: most successor routes compared by :func:`route_chain`
MAX_ROUTES = 64


def _aligned_lanes(lanes: dict[int, Lane], p, heading: float, radius: float) -> list[int]:
    """Lanelets whose centre line passes within ``radius`` m of ``p`` running within 45° of
    ``heading`` there, nearest first."""
    out = []
    for lid, lane in lanes.items():
        cl = lane.center
        if len(cl) < 2:
            continue
        a, b = cl[:-1], cl[1:]
        ab = b - a
        u = np.clip(np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-12), 0, 1)
        dist = np.linalg.norm(a + u[:, None] * ab - p, axis=-1)
        i = int(np.argmin(dist))
        dh = np.angle(np.exp(1j * (np.arctan2(ab[i, 1], ab[i, 0]) - heading)))
        if dist[i] <= radius and abs(dh) <= np.pi / 4:
            out.append((float(dist[i]), lid))
    return [lid for _, lid in sorted(out)]


def _start_lanes(lanes: dict[int, Lane], lid: int, p, heading: float) -> list[int]:
    """Where a car's routes start: its ``lane_of`` lanelet ``lid`` where that runs within 45° of
    its heading; else (inside a junction the lanelet under a car may be a crossing one) the
    lanelets within a lane width (4 m) of it that do, nearest first (at most 4); else ``lid``."""
    if lid in _aligned_lanes({lid: lanes[lid]}, p, heading, np.inf):
        return [lid]
    return _aligned_lanes(lanes, p, heading, 4.0)[:4] or [lid]


def _successor_routes(lanes: dict[int, Lane], lid: int, need: float) -> list[tuple[int, ...]]:
    """Lanelet sequences from ``lid`` through its successors (every branch) until ``need`` m
    long or a dead end; at most :data:`MAX_ROUTES`."""
    done, stack = [], [((lid,), _length(lanes[lid].center))]
    while stack and len(done) < MAX_ROUTES:
        seq, L = stack.pop()
        nxt = [x for x in lanes[seq[-1]].successors if x not in seq and x in lanes]
        if not nxt or L >= need:
            done.append(seq)
            continue
        stack.extend((seq + (x,), L + _length(lanes[x].center)) for x in reversed(nxt))
    return done + [seq for seq, _ in stack[: max(0, MAX_ROUTES - len(done))]]


def route_chain(scene: NgsimScene, v: int, k: int, ahead: float = 260.0) -> tuple[np.ndarray, int]:
    """Vehicle ``v``'s route at step ``k`` through the lanelet graph: a (P, 2) polyline and the
    lanelet it starts in.

    Start lanelet: its lanelet of ``lane_of`` where that runs within 45° of its heading; else
    (inside a junction the lanelet under a car may be a crossing one) those within a lane width
    (4 m) of it that do, else its ``lane_of`` lanelet.  From each, every successor sequence (to
    ``ahead`` m or a dead end, at most :data:`MAX_ROUTES`), preceded by the start's chain of
    first predecessors.  Chosen: the one
    whose centre line is nearest (mean distance) to the car's recorded positions from ``k`` on:
    at a junction, the turn the recorded car took."""
    return _route(scene, v, k, ahead)[:2]


@lru_cache(maxsize=256)
def _route(scene: NgsimScene, v: int, k: int, ahead: float):
    """:func:`route_chain`'s (chain, start lanelet) and the lanelet sequence from the start;
    cached (the path and the speed limit of a task read the same route)."""
    lanes = scene.lanes
    lid = int(scene.lane_of[v, k])
    if lid < 0:
        raise ValueError(f"vehicle {scene.ids[v]} is off the lane map at step {k}")
    rec = scene.xy[v, k:]
    rec = rec[np.all(np.isfinite(rec), -1)]
    best, best_d = (None, lid, (lid,)), np.inf
    for start in _start_lanes(lanes, lid, rec[0], float(scene.heading[v, k])):
        back = _predecessors(lanes, start)
        for seq in _successor_routes(lanes, start, ahead + _length(lanes[start].center)):
            chain = _dedup(np.concatenate(back + [lanes[i].center for i in seq], 0))
            dist = float(np.mean(distance_to_polyline(chain, rec)))
            if dist < best_d:
                best, best_d = (chain, start, seq), dist
    best[0].setflags(write=False)
    return best


def route_speed_limit(
    scene: NgsimScene, v: int, k: int, reach: float, ahead: float = 260.0
) -> float | None:
    """The lowest speed limit (m/s) of the lanelets of the ego's route (:func:`route_chain`
    to ``ahead`` m, the route of its reference path) that start within ``reach`` m ahead of
    it; None where none has a sign."""
    _, start, seq = _route(scene, int(v), int(k), float(ahead))
    lanes = scene.lanes
    s0, _ = cartesian_to_lane(lanes[start].center, scene.xy[v, k][None])
    along, limits = -float(s0[0]), []
    for lid in seq:
        if along > reach:
            break
        if lanes[lid].speed_limit is not None:
            limits.append(lanes[lid].speed_limit)
        along += _length(lanes[lid].center)
    return min(limits) if limits else None


def _turning(xy: np.ndarray) -> float:
    """Total absolute heading change (rad) along a polyline."""
    d = np.diff(xy, axis=0)
    h = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    return float(np.sum(np.abs(np.diff(h))))


def candidate_routes(
    scene: NgsimScene,
    v: int,
    k: int,
    behind: float = 30.0,
    ahead: float = 170.0,
    max_routes: int = 4,
) -> list[np.ndarray]:
    """The routes vehicle ``v`` can still take at step ``k``, from what is known at ``k`` only
    (its position and heading, the lanelet graph; never its recorded future): the successor
    branches from its lanelet (:func:`route_chain`'s start rule) that part within its reach
    (1.5 × its speed × 5 s, at least 40 m; later partings are one route), each resampled from
    ``behind`` m behind the car to ``ahead`` m ahead (``(behind + ahead)/CHAIN_SPACING + 1``
    points, so every route of every car has one shape), the straightest first, at most
    ``max_routes``.  Off the map: the nearest lanelet's straightest chain."""
    return list(_routes_ahead(scene, int(v), int(k), float(behind), float(ahead))[:max_routes])


@lru_cache(maxsize=1024)
def _routes_ahead(scene: NgsimScene, v: int, k: int, behind: float, ahead: float) -> tuple:
    """Every route of :func:`candidate_routes`, straightest first (read-only arrays); cached:
    a task's planner inputs and the predictor's context read the same routes."""
    lanes = scene.lanes
    lid = int(scene.lane_of[v, k])
    p = scene.xy[v, k]
    if lid < 0:
        lid = min(lanes, key=lambda i: np.min(np.linalg.norm(lanes[i].center - p, axis=-1)))
    else:
        lid = _start_lanes(lanes, lid, p, float(scene.heading[v, k]))[0]
    back = _predecessors(lanes, lid)
    # routes that part beyond the car's reach are one route (1.5 × its speed × 5 s, ≥ 40 m)
    v0 = float(scene.speed[v, k]) if np.isfinite(scene.speed[v, k]) else 0.0
    n_reach = int((behind + max(40.0, 7.5 * v0)) / CHAIN_SPACING) + 1
    out: list[np.ndarray] = []
    for seq in _successor_routes(lanes, lid, ahead + _length(lanes[lid].center)):
        chain = _dedup(np.concatenate(back + [lanes[i].center for i in seq], 0))
        s0, _ = cartesian_to_lane(chain, p[None])
        r = _resample(chain, float(s0[0]) - behind, float(s0[0]) + ahead, CHAIN_SPACING)
        if all(np.max(np.linalg.norm(r[:n_reach] - q[:n_reach], axis=-1)) > 0.5 for q in out):
            r.setflags(write=False)
            out.append(r)
    out.sort(key=_turning)
    return tuple(out)


def vehicle_centerline(
    scene: NgsimScene, v: int, k: int, behind: float = 30.0, ahead: float = 170.0
) -> np.ndarray:
    """Vehicle ``v``'s lane centre line at step ``k``, resampled from ``behind`` m behind it to
    ``ahead`` m ahead (fixed length: ``(behind + ahead)/CHAIN_SPACING + 1`` points): the
    straightest of its :func:`candidate_routes` (at a branch, the predictor's context does not
    know which way the car will go)."""
    return candidate_routes(scene, v, k, behind, ahead, max_routes=1)[0]


# --------------------------------------------------------------------------- predictor inputs
def present(scene: NgsimScene, k_from: int, k_to: int) -> np.ndarray:
    """(V,) bool: vehicle recorded at every step ``k_from … k_to`` (inclusive)."""
    if k_from < 0 or k_to >= scene.num_steps:
        return np.zeros(len(scene.ids), bool)
    return np.all(np.isfinite(scene.xy[:, k_from : k_to + 1, 0]), axis=1)


def history_at(scene: NgsimScene, idx, k: int, H: int) -> np.ndarray:
    """(O, H, 2) positions at steps ``k−H+1 … k``.  Rows before a vehicle entered the scene are
    extrapolated backwards at its first recorded velocity (so vehicles that just appeared still
    have an H-row history); each vehicle must be present at ``k`` and ``k−1``."""
    idx = np.asarray(idx)
    out = np.empty((len(idx), H, 2))
    for j, v in enumerate(idx):
        steps = np.arange(k - H + 1, k + 1)
        rows = np.full((H, 2), np.nan)
        ok = (steps >= 0) & (steps < scene.num_steps)
        rows[ok] = scene.xy[v, steps[ok]]
        fin = np.all(np.isfinite(rows), -1)
        if not (fin[-1] and fin[-2]):
            raise ValueError(f"vehicle {scene.ids[v]} is not present at steps {k - 1}, {k}")
        f0 = int(np.flatnonzero(fin)[0])
        v0 = rows[f0 + 1] - rows[f0] if fin[f0 + 1] else rows[-1] - rows[-2]
        for i in range(f0 - 1, -1, -1):  # before the vehicle entered: backwards at v0
            rows[i] = rows[i + 1] - v0
        for i in range(f0 + 1, H):  # (interior gaps do not occur in these files; bridge them)
            if not fin[i]:
                rows[i] = rows[i - 1] + v0
        out[j] = rows
    return out


def future_at(scene: NgsimScene, idx, k: int, times) -> np.ndarray:
    """(O, K, 2) recorded positions at ``k·dt + times`` (linear interpolation between steps;
    NaN where the vehicle is not recorded)."""
    idx = np.asarray(idx)
    tq = k + np.asarray(times, np.float64) / scene.dt
    lo = np.floor(tq + 1e-9).astype(int)
    u = (tq - lo)[:, None]
    hi = np.minimum(lo + 1, scene.num_steps - 1)
    out = np.full((len(idx), len(tq), 2), np.nan)
    valid = lo < scene.num_steps
    lo_c = np.minimum(lo, scene.num_steps - 1)
    for j, v in enumerate(idx):
        a, b = scene.xy[v, lo_c], scene.xy[v, hi]
        b = np.where(u < 1e-9, a, b)
        out[j] = np.where(valid[:, None], (1 - u) * a + u * b, np.nan)
    return out


def context_at(
    scene: NgsimScene, idx, k: int, times, dt_history: float | None = None
) -> PredictionContext:
    """The :class:`~mmdopt.predict.PredictionContext` of vehicles ``idx`` at step ``k``.

    Neighbours: every other vehicle recorded at ``k`` (the ego included — it is a car on the road
    when the scene is used for training), classified by its offset ``d`` in the vehicle's lane
    frame: own lane ``|d| < w/2``, left ``w/2 ≤ d < 1.5w``, right ``−1.5w < d ≤ −w/2``; the gap is
    the difference of arc lengths (centre to centre)."""
    idx = np.asarray(idx)
    O = len(idx)
    here = np.flatnonzero(np.isfinite(scene.xy[:, k, 0]))
    cl = np.empty((O, int(round(200.0 / CHAIN_SPACING)) + 1, 2))
    w = np.empty(O)
    hl, hr = np.zeros(O, bool), np.zeros(O, bool)
    gaps = np.full((O, 6), GAP_NONE)
    rel = np.zeros((O, 6))
    for j, v in enumerate(idx):
        cl[j] = vehicle_centerline(scene, v, k)
        lid = int(scene.lane_of[v, k])
        lane = scene.lanes.get(lid)
        w[j] = lane.width if lane is not None else 3.5
        hl[j] = lane is not None and lane.left_id is not None
        hr[j] = lane is not None and lane.right_id is not None
        others = here[here != v]
        if len(others) == 0:
            continue
        s, d = cartesian_to_lane(cl[j], scene.xy[others, k])
        s0, _ = cartesian_to_lane(cl[j], scene.xy[v, k][None])
        dv = scene.speed[others, k] - scene.speed[v, k]
        dv = np.where(np.isfinite(dv), dv, 0.0)
        gaps[j], rel[j] = neighbour_gaps(s - s0[0], d, dv, w[j])
    return PredictionContext(
        times=np.asarray(times, np.float64),
        dt_history=scene.dt if dt_history is None else dt_history,
        centerline=cl,
        lane_width=w,
        has_left=hl,
        has_right=hr,
        gaps=gaps,
        rel_speed=rel,
    )


# --------------------------------------------------------------------------- ego road
#: σ (m) of the Gaussian smoothing of the ego's route before its spline is fitted: the lanelet
#: polylines' corners would otherwise give the path curvature steps that no car can steer
#: (CommonRoad's KS model refuses plans that follow them; :mod:`.crcheck`)
ROUTE_SMOOTHING = 2.0


def smooth_polyline(xy: np.ndarray, sigma: float, spacing: float = CHAIN_SPACING) -> np.ndarray:
    """``xy`` (P, 2), evenly spaced ``spacing`` m apart, Gaussian-smoothed with σ = ``sigma`` m
    along its length; the ends are point-reflected first, so a straight end stays put."""
    xy = np.asarray(xy, np.float64)
    n = int(np.ceil(4 * sigma / spacing))
    if sigma <= 0 or len(xy) < 3 or n < 1:
        return xy
    n = min(n, len(xy) - 1)
    pad = np.concatenate([2 * xy[0] - xy[n:0:-1], xy, 2 * xy[-1] - xy[-2 : -n - 2 : -1]])
    return gaussian_filter1d(pad, sigma / spacing, axis=0, mode="nearest")[n:-n]


#: the wheelbase (m) of the curve-speed rule's steering rate: CommonRoad's BMW 320i, the car
#: whose KS model the drivability checker reproduces plans with
WHEELBASE = 2.578


def curve_speed(
    path: frenet.ReferencePath,
    s0: float,
    reach: float,
    lateral_accel: float | None,
    steer_rate: float | None,
    wheelbase: float = WHEELBASE,
    step: float = 0.5,
) -> float | None:
    """The highest speed (m/s) at which a car can drive ``path`` from arc length ``s0`` to
    ``s0 + reach``: its lateral acceleration ``v²|κ|`` at most ``lateral_accel`` (m/s²) and its
    steering rate ``δ̇ ≈ wheelbase · v · |dκ/ds|`` at most ``steer_rate`` (rad/s), the
    kinematic single-track car's rate of steering along a curvature that changes with arc
    length; each bound ``None`` is not applied.  None where neither binds (a straight path)."""
    for name, val in (("reach", reach), ("wheelbase", wheelbase), ("step", step)):
        if not (np.isfinite(val) and val > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {val!r}")
    for name, val in (("lateral_accel", lateral_accel), ("steer_rate", steer_rate)):
        if val is not None and not (np.isfinite(val) and val > 0):
            raise ValueError(f"{name} must be None or a finite number > 0, got {val!r}")
    s = float(s0) + np.arange(0.0, float(reach) + step, step)
    kappa = np.abs(np.asarray(path.curvature(s), np.float64))
    caps = [np.inf]
    tiny = 1e-9  # curvature (1/m) and its change (1/m²) below this are a straight line's
    if lateral_accel is not None and np.any(kappa > tiny):
        caps.append(float(np.sqrt(lateral_accel / np.max(kappa))))
    if steer_rate is not None and s.size > 1:
        dk = float(np.max(np.abs(np.gradient(kappa, step))))
        if dk > tiny:
            caps.append(steer_rate / (wheelbase * dk))
    v = min(caps)
    return v if np.isfinite(v) else None


def ego_road_geometry(
    scene: NgsimScene, v: int, k: int, behind: float = 30.0, ahead: float = 260.0
):
    """The ego's reference path (its route, :func:`route_chain`, smoothed by
    :data:`ROUTE_SMOOTHING`: a ``frenet.ReferencePath``) and the offsets (m)
    of the same-direction neighbour lanes' centres in that path's frame (``None`` if absent),
    measured as the median over the 100 m ahead of the ego."""
    chain, lid = route_chain(scene, v, k, ahead)
    s0, _ = cartesian_to_lane(chain, scene.xy[v, k][None])
    pts = _resample(chain, float(s0[0]) - behind, float(s0[0]) + ahead, CHAIN_SPACING)
    path = frenet.ReferencePath.from_waypoints(smooth_polyline(pts, ROUTE_SMOOTHING), spacing=0.5)
    lane = scene.lanes[lid]
    offsets = []
    for nb in (lane.left_id, lane.right_id):
        if nb is None:
            offsets.append(None)
            continue
        nchain = lane_chain(scene, nb)
        s, d = path.to_frenet(nchain[:, 0], nchain[:, 1])
        se, _ = path.to_frenet(*scene.xy[v, k])
        near = (s >= float(se) - 10) & (s <= float(se) + 100)
        offsets.append(float(np.median(d[near])) if np.any(near) else None)
    return path, offsets[0], offsets[1]
