"""The predictor protocol: black-box samplers of the other vehicles' futures on the planner's grid.

A predictor is anything with ``sample(history, context, n, key) -> (O, n, K, 2)``::

    samples = predictor.sample(history, context, n=100, key=jax.random.PRNGKey(0))
    plan = mmdopt.plan(ego, road, samples, config=config)   # K = config.trajectory.num_steps

``history`` (O, H, 2): each obstacle's recorded Cartesian positions (m) at the H times
``t = −(H−1)·dt_history, …, −dt_history, 0`` (the last row is the current position).
``context`` (:class:`PredictionContext`): the planner's time grid and, per obstacle, its lane
(centre line, width, whether same-direction lanes exist left/right) and the gaps to its
neighbours — plain arrays, no map or file format.  Output: Cartesian ``(x, y)`` samples at
``context.times`` (``times[0] = 0`` is "now"), deterministic for a given ``key``.

Lane frame: the obstacle's lane centre line is a polyline (P, 2) in the driving direction; a point
has lane coordinates ``(s, d)`` = arc length along the polyline and signed offset to its left
(:func:`lane_to_cartesian`, :func:`cartesian_to_lane`; linear beyond the polyline's ends, normals
interpolated between vertices so the map is continuous).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from .._checks import check_key

__all__ = [
    "GAP_NONE",
    "neighbour_gaps",
    "Forecast",
    "PredictionContext",
    "Predictor",
    "cartesian_to_lane",
    "check_history",
    "check_key",
    "lane_to_cartesian",
]

#: Gap (m) reported when there is no neighbour in that slot (or it is farther than this).
GAP_NONE = 100.0


def neighbour_gaps(ds, d, dv, lane_width: float) -> tuple[np.ndarray, np.ndarray]:
    """The six neighbour slots of :class:`PredictionContext` for one obstacle: ``(gaps (6,),
    rel_speed (6,))`` from the other vehicles' positions in its lane frame, ``ds`` (M,) along
    (m, ahead > 0) and ``d`` (M,) across (m, left > 0), and their speeds minus its own ``dv``
    (M,).  Slots: its lane (|d| < w/2), the left lane (w/2 ≤ d < 3w/2), the right lane; ahead and
    behind in each; the nearest vehicle per slot, :data:`GAP_NONE` and 0 where there is none
    within :data:`GAP_NONE`."""
    ds, d, dv = (np.asarray(a, dtype=np.float64) for a in (ds, d, dv))
    gaps, rel = np.full(6, GAP_NONE), np.zeros(6)
    half = 0.5 * float(lane_width)
    slots = (np.abs(d) < half, (d >= half) & (d < 3 * half), (d <= -half) & (d > -3 * half))
    for slot, m in enumerate(slots):
        for side, sel in ((0, m & (ds > 0)), (1, m & (ds <= 0))):
            if np.any(sel):
                c = np.flatnonzero(sel)[np.argmin(np.abs(ds[sel]))]
                if abs(ds[c]) < GAP_NONE:
                    gaps[2 * slot + side] = abs(ds[c])
                    rel[2 * slot + side] = dv[c]
    return gaps, rel


@dataclass(frozen=True, eq=False)
class PredictionContext:
    """What a predictor may know besides the histories (plain arrays; SI units).

    times : (K,) prediction times (s), ``times[0] = 0`` (now), increasing — the planner's grid
        (``np.linspace(0, config.trajectory.horizon, config.trajectory.num_steps)``)
    dt_history : spacing (s) of the history rows
    centerline : (O, P, 2) each obstacle's current lane centre line (Cartesian, m, driving
        direction, P ≥ 2, covering from behind the obstacle to beyond its reach over ``times``)
    lane_width : (O,) width of that lane (m)
    has_left, has_right : (O,) bool, a same-direction lane exists to the left / right
    gaps : (O, 6) distance (m, centre to centre along the lane) to the nearest vehicle
        [ahead in lane, behind in lane, ahead left, behind left, ahead right, behind right];
        :data:`GAP_NONE` where there is none
    rel_speed : (O, 6) that neighbour's speed minus the obstacle's (m/s); 0 where there is none
    """

    times: np.ndarray
    dt_history: float
    centerline: np.ndarray
    lane_width: np.ndarray
    has_left: np.ndarray
    has_right: np.ndarray
    gaps: np.ndarray
    rel_speed: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.times, dtype=np.float64)
        if t.ndim != 1 or t.size < 2:
            raise ValueError(f"context.times must have shape (K,) with K >= 2, got {t.shape}")
        if not np.all(np.isfinite(t)) or abs(t[0]) > 1e-9 or np.any(np.diff(t) <= 0):
            raise ValueError("context.times must be finite, start at 0 and increase")
        object.__setattr__(self, "times", t)
        dt = float(self.dt_history)
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"context.dt_history must be > 0, got {self.dt_history!r}")
        object.__setattr__(self, "dt_history", dt)
        c = np.asarray(self.centerline, dtype=np.float64)
        if c.ndim != 3 or c.shape[-1] != 2 or c.shape[1] < 2:
            raise ValueError(f"context.centerline must have shape (O, P, 2), P >= 2, got {c.shape}")
        if not np.all(np.isfinite(c)):
            raise ValueError("context.centerline contains NaN or inf")
        if np.any(np.linalg.norm(np.diff(c, axis=1), axis=-1) <= 1e-9):
            raise ValueError("context.centerline has repeated consecutive points")
        object.__setattr__(self, "centerline", c)
        O = c.shape[0]
        for name, shape in (("lane_width", (O,)), ("gaps", (O, 6)), ("rel_speed", (O, 6))):
            a = np.asarray(getattr(self, name), dtype=np.float64)
            if a.shape != shape:
                raise ValueError(f"context.{name} must have shape {shape}, got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"context.{name} contains NaN or inf")
            object.__setattr__(self, name, a)
        if np.any(self.lane_width <= 0):
            raise ValueError("context.lane_width must be > 0")
        for name in ("has_left", "has_right"):
            a = np.asarray(getattr(self, name))
            if a.shape != (O,):
                raise ValueError(f"context.{name} must have shape ({O},), got {a.shape}")
            object.__setattr__(self, name, a.astype(bool))

    @property
    def num_obstacles(self) -> int:
        return int(self.centerline.shape[0])

    def subset(self, idx) -> PredictionContext:
        """The context of the obstacles ``idx`` (an index array or mask)."""
        return PredictionContext(
            times=self.times,
            dt_history=self.dt_history,
            centerline=self.centerline[idx],
            lane_width=self.lane_width[idx],
            has_left=self.has_left[idx],
            has_right=self.has_right[idx],
            gaps=self.gaps[idx],
            rel_speed=self.rel_speed[idx],
        )


@runtime_checkable
class Predictor(Protocol):
    """``sample(history (O, H, 2), context, n, key) -> (O, n, K, 2)`` Cartesian samples."""

    name: str

    def sample(self, history, context: PredictionContext, n: int, key) -> np.ndarray: ...


@dataclass(frozen=True, eq=False)
class Forecast:
    """Obstacles given as a predictor to sample from, instead of a fixed array of futures.

    :func:`mmdopt.plan` draws from ``predictor`` as many futures per obstacle as the risk level
    ε asks for: n(ε) = :func:`mmdopt.risk.samples_for_risk` (ε, G), the fewest whose 95 % bound
    can confirm ε (598 for ε = 0.005, ≈ 3/ε: sample i of every obstacle is one joint draw, so
    G = 1 whatever the number of obstacles; ≈ 3·O/ε with ``SafetyConfig.joint_futures =
    False``), or more for MMD-Opt's allowed hits, at least ``min_samples`` (and
    the reduced-set size) and at most ``max_samples`` — beyond that cap the plan's status says
    ``risk floor``.  Without a risk level (the time-linear margins) it draws ``min_samples``.
    The draw's key is derived from the plan's, so the same key gives the same plan.

    predictor : anything with ``sample(history, context, n, key) -> (O, n, K, 2)``
    history : (O, H, 2) each obstacle's recent positions;  context : :class:`PredictionContext`
    whose ``times`` are the planner's grid
    """

    predictor: Predictor
    history: np.ndarray
    context: PredictionContext
    min_samples: int = 100
    max_samples: int = 5000

    def __post_init__(self) -> None:
        if not callable(getattr(self.predictor, "sample", None)):
            raise ValueError(
                "Forecast.predictor must have a sample(history, context, n, key) method, got "
                f"{type(self.predictor).__name__}"
            )
        if not isinstance(self.context, PredictionContext):
            raise ValueError(
                f"Forecast.context must be a PredictionContext, got {type(self.context).__name__}"
            )
        object.__setattr__(self, "history", check_history(self.history, self.context))
        for name in ("min_samples", "max_samples"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
                raise ValueError(f"Forecast.{name} must be an int >= 1, got {v!r}")
        if self.max_samples < self.min_samples:
            raise ValueError(
                f"Forecast.max_samples = {self.max_samples} < min_samples = {self.min_samples}"
            )

    @property
    def num_obstacles(self) -> int:
        return self.context.num_obstacles


# ------------------------------------------------------------------------------- input checks
def check_history(history, context: PredictionContext, min_len: int = 2) -> np.ndarray:
    """``history`` as a finite float64 (O, H, 2) matching ``context``; ``ValueError`` otherwise."""
    h = np.asarray(history, dtype=np.float64)
    if h.ndim != 3 or h.shape[-1] != 2:
        raise ValueError(f"history must have shape (O, H, 2), got {h.shape}")
    if h.shape[0] == 0:
        raise ValueError("history has zero obstacles")
    if h.shape[1] < min_len:
        raise ValueError(f"history needs at least {min_len} rows (H), got {h.shape[1]}")
    if not np.all(np.isfinite(h)):
        raise ValueError("history contains NaN or inf")
    if not isinstance(context, PredictionContext):
        raise ValueError(f"context must be a PredictionContext, got {type(context).__name__}")
    if context.num_obstacles != h.shape[0]:
        raise ValueError(
            f"history has {h.shape[0]} obstacles but context has {context.num_obstacles}"
        )
    return h


def pad_rows(a: np.ndarray, bucket: int = 16) -> np.ndarray:
    """``a`` with its leading axis padded (repeating row 0) to a multiple of ``bucket``, so that
    jitted samplers compile once per bucket instead of once per obstacle count."""
    O = a.shape[0]
    P = -(-O // bucket) * bucket
    if P == O:
        return a
    return np.concatenate([a, np.repeat(a[:1], P - O, axis=0)], axis=0)


def check_n(n) -> int:
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"n must be a positive int, got {n!r}")
    return int(n)


# ------------------------------------------------------------------------------- lane frame
def _poly_geometry(poly: np.ndarray):
    """Cumulative arc length (P,), unit tangents per segment (P−1, 2), vertex normals (P, 2)."""
    seg = np.diff(poly, axis=0)
    ln = np.linalg.norm(seg, axis=-1)
    tan = seg / ln[:, None]
    cum = np.concatenate([[0.0], np.cumsum(ln)])
    vt = np.concatenate([tan[:1], tan[:-1] + tan[1:], tan[-1:]], axis=0)
    vt /= np.linalg.norm(vt, axis=-1, keepdims=True)
    normals = np.stack([-vt[:, 1], vt[:, 0]], axis=-1)
    return cum, tan, normals


def lane_to_cartesian(poly: np.ndarray, s, d) -> np.ndarray:
    """Lane coordinates ``(s, d)`` (any matching shape) along polyline ``poly`` (P, 2) → ``(…, 2)``.

    Between vertices the base point is interpolated linearly and the normal is the interpolated
    vertex normal (continuous in ``s``); beyond the ends the end segments continue straight.
    """
    poly = np.asarray(poly, dtype=np.float64)
    s, d = np.broadcast_arrays(np.asarray(s, np.float64), np.asarray(d, np.float64))
    cum, tan, normals = _poly_geometry(poly)
    i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(cum) - 2)
    u = (s - cum[i]) / (cum[i + 1] - cum[i])
    base = poly[i] + (s - cum[i])[..., None] * tan[i]
    uc = np.clip(u, 0.0, 1.0)[..., None]
    nrm = (1 - uc) * normals[i] + uc * normals[i + 1]
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    return base + d[..., None] * nrm


def cartesian_to_lane(poly: np.ndarray, xy) -> tuple[np.ndarray, np.ndarray]:
    """Cartesian points ``xy`` (…, 2) → lane coordinates ``(s, d)`` along ``poly`` (P, 2).

    Nearest segment (end segments extended), then a few fixed-point steps so that
    :func:`lane_to_cartesian` inverts it (to < 1 mm on lanes with heading changes of a few
    milliradians per segment).
    """
    poly = np.asarray(poly, dtype=np.float64)
    xy = np.asarray(xy, dtype=np.float64)
    shape = xy.shape[:-1]
    p = xy.reshape(-1, 2)
    cum, tan, _ = _poly_geometry(poly)
    a = poly[:-1]
    rel = p[:, None, :] - a[None]  # (N, P-1, 2)
    ln = np.diff(cum)
    t = np.einsum("npk,pk->np", rel, tan)
    lo = np.where(np.arange(len(ln)) == 0, -np.inf, 0.0)
    hi = np.where(np.arange(len(ln)) == len(ln) - 1, np.inf, ln)
    tc = np.clip(t, lo, hi)
    foot = a[None] + tc[..., None] * tan[None]
    dist = np.linalg.norm(p[:, None, :] - foot, axis=-1)
    j = np.argmin(dist, axis=1)
    rows = np.arange(len(p))
    s = cum[j] + tc[rows, j]
    d = rel[rows, j, 0] * (-tan[j, 1]) + rel[rows, j, 1] * tan[j, 0]
    for _ in range(3):  # refine against the interpolated-normal map
        q = lane_to_cartesian(poly, s, d)
        e = p - q
        i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(cum) - 2)
        s = s + np.einsum("nk,nk->n", e, tan[i])
        d = d + e[:, 0] * (-tan[i, 1]) + e[:, 1] * tan[i, 0]
    return s.reshape(shape), d.reshape(shape)
