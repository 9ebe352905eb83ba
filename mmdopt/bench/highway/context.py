"""The prediction context of a highway-env scene: each car's lane centre line (followed along the
lane network) and the :class:`~mmdopt.predict.PredictionContext` of the cars (lane widths, side
lanes, neighbour gaps) that the learned predictor and the forecasts of the benchmark read.

The convention is that of the NGSIM scenes (:mod:`mmdopt.predict.base`), so one model reads
both sources.
"""

from __future__ import annotations

import math

import numpy as np

from mmdopt.predict.base import (
    GAP_NONE,
    PredictionContext,
    cartesian_to_lane,
    neighbour_gaps,
)

__all__ = [
    "CENTERLINE_BACK",
    "CENTERLINE_AHEAD",
    "CENTERLINE_SPACING",
    "lane_centerline",
    "scene_context",
]

#: centre-line extent (m) behind / ahead of the vehicle and point spacing
CENTERLINE_BACK, CENTERLINE_AHEAD, CENTERLINE_SPACING = 50.0, 200.0, 2.5


# ------------------------------------------------------------------------------ lane geometry
def lane_centerline(network, lane_index, position) -> np.ndarray:
    """(P, 2) centre line of the lane ``lane_index`` from ``CENTERLINE_BACK`` m behind the
    longitudinal position of ``position`` to ``CENTERLINE_AHEAD`` m ahead, every
    ``CENTERLINE_SPACING`` m (P fixed).  Past the lane's end it continues on the network's next
    lane (highway-env's ``next_lane``) while that one starts where this one ends; otherwise
    (a merging lane that ends, no successor) it goes straight on along the last heading."""
    if lane_index is None:
        raise ValueError("lane_index must be a highway-env lane index, got None")
    lane = network.get_lane(lane_index)
    s0 = float(lane.local_coordinates(np.asarray(position, float))[0])
    P = int(round((CENTERLINE_BACK + CENTERLINE_AHEAD) / CENTERLINE_SPACING)) + 1
    s_all = s0 - CENTERLINE_BACK + CENTERLINE_SPACING * np.arange(P)
    out = np.empty((P, 2))
    rng = np.random.RandomState(0)  # next_lane's choice among branches (none in these maps)
    offset, index, straight = 0.0, lane_index, None  # s on `lane` = s_all - offset
    for p, s in enumerate(s_all):
        if straight is None and s - offset < 0.0:  # behind the lane's start: straight back
            h = lane.heading_at(0.0)
            out[p] = lane.position(0.0, 0.0) + (s - offset) * np.array([math.cos(h), math.sin(h)])
            continue
        while straight is None and s - offset > lane.length:
            nxt_index = network.next_lane(
                index, position=lane.position(lane.length, 0.0), np_random=rng
            )
            nxt = network.get_lane(nxt_index)
            end = lane.position(lane.length, 0.0)
            if nxt_index == index or np.linalg.norm(nxt.position(0.0, 0.0) - end) > 0.5:
                h = lane.heading_at(lane.length)
                straight = (end, np.array([math.cos(h), math.sin(h)]), offset + lane.length)
                break
            offset += lane.length
            lane, index = nxt, nxt_index
        if straight is not None:
            end, u, s_end = straight
            out[p] = end + (s - s_end) * u
        else:
            out[p] = lane.position(s - offset, 0.0)
    return out


def _side_flags(network, lane_index, position) -> tuple[bool, bool, float]:
    """(a lane to the left, a lane to the right, the lane's width) — "left" is the positive
    lateral side of the driving direction, the lane frame of :mod:`mmdopt.predict.base`."""
    lane = network.get_lane(lane_index)
    s = float(lane.local_coordinates(np.asarray(position, float))[0])
    left = right = False
    for side in network.side_lanes(lane_index):
        other = network.get_lane(side)
        if getattr(other, "forbidden", False):  # a lane one may not change into
            continue
        lat = float(lane.local_coordinates(other.position(max(s, 0.0), 0.0))[1])
        left |= lat > 0.5
        right |= lat < -0.5
    return left, right, float(lane.width_at(s))


def scene_context(
    network, lane_indices, positions, speeds, idx, times, dt_history: float
) -> PredictionContext:
    """The :class:`~mmdopt.predict.PredictionContext` of the vehicles ``idx`` in a scene of
    ``N`` vehicles at ``positions`` (N, 2), ``speeds`` (N,), on lanes ``lane_indices`` (N
    highway-env lane indices).

    Neighbours: every other vehicle of the scene, classified by its offset ``d`` in the
    vehicle's lane frame (own lane ``|d| < w/2``, left ``w/2 ≤ d < 1.5w``, right
    ``−1.5w < d ≤ −w/2``; the convention of the NGSIM scenes); the gap is the difference of arc
    lengths (centre to centre), the relative speed the difference of speeds."""
    positions = np.asarray(positions, np.float64)
    speeds = np.asarray(speeds, np.float64)
    idx = np.asarray(idx, dtype=np.int64)
    if positions.ndim != 2 or positions.shape[1] != 2:
        raise ValueError(f"positions must have shape (N, 2), got {positions.shape}")
    N, O = positions.shape[0], len(idx)
    if speeds.shape != (N,) or len(lane_indices) != N:
        raise ValueError("speeds and lane_indices must have one entry per position")
    cl, w = [], np.empty(O)
    hl, hr = np.zeros(O, bool), np.zeros(O, bool)
    gaps, rel = np.full((O, 6), GAP_NONE), np.zeros((O, 6))
    for j, v in enumerate(idx):
        cl.append(lane_centerline(network, lane_indices[v], positions[v]))
        hl[j], hr[j], w[j] = _side_flags(network, lane_indices[v], positions[v])
        others = np.flatnonzero(np.arange(N) != v)
        if len(others) == 0:
            continue
        s, d = cartesian_to_lane(cl[j], positions[others])
        s0, _ = cartesian_to_lane(cl[j], positions[v][None])
        gaps[j], rel[j] = neighbour_gaps(s - s0[0], d, speeds[others] - speeds[v], w[j])
    return PredictionContext(
        times=np.asarray(times, np.float64),
        dt_history=dt_history,
        centerline=np.stack(cl) if cl else np.zeros((0, 2, 2)),
        lane_width=w,
        has_left=hl,
        has_right=hr,
        gaps=gaps,
        rel_speed=rel,
    )
