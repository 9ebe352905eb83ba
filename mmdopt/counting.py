"""Counting the planning futures a plan meets: the shared tool behind every plan's risk bound,
the final check and the nearest-futures pass (every method uses it).

A future j meets a plan at step k when one circle c of its footprint
(:data:`~mmdopt.collision.OBSTACLE_FOOTPRINT`, along its heading) lies inside the plan's
collision ellipse there, eq. (coll_constraints) as :func:`mmdopt.collision_free_count` evaluates
it: ``q = Δs²/a² + Δd²/b² < 1``.  At ε = 10⁻³ a plan is counted against tens of thousands of
futures of 100 steps, so the count is arranged to read each future once per plan and to
store nothing of that size:

* **Circles without their centres.**  With ``e`` the plan point minus the future's reference
  point and ``u`` its heading's unit vector, circle c at offset ``r_c`` has
  ``q_c = q₀ − 2 r_c L + r_c² Q``, ``q₀ = e_s²/a² + e_d²/b²``, ``L = e_s u_s/a² + e_d u_d/b²``,
  ``Q = u_s²/a² + u_d²/b²``: once ``q₀, L, Q`` are formed each circle costs two
  multiply-adds.
* **Headings without trigonometry.**  When no body heading is given and every step of every
  future moves (:data:`~mmdopt.collision.MIN_HEADING_STEP`), ``u`` is each future's own forward
  difference over its length (:func:`mmdopt.collision.headings`' convention, the last step
  repeated), formed inside the count; otherwise the unit vectors of the carried or given
  headings are formed once per plan (:attr:`Futures.units`).
* **Float32 inside one fused loop** per plan bucket, its minimum over the steps taken on the
  bit patterns of the non-negative ``q`` (an integer minimum, which XLA's CPU backend
  vectorises; a float minimum must order NaNs).  The answer is the float64 count's except
  where a future lies within float32 rounding (~10⁻⁶ of ``q``) of the ellipse's boundary.
* **One exact pass, then bounds** (:class:`FutureIndex`): the windowed minima of ``q`` against
  one reference plan bound how close any other plan can come to each future, by the triangle
  inequality of the ellipse norm ``‖(Δs, Δd)‖ = √(Δs²/a² + Δd²/b²)``.  A plan that deviates
  from the reference by at most ``D_w`` in window w can meet only the futures with
  ``√Q_w < 1 + D_w`` in some window; those few are counted exactly, the others are certainly
  clear.  The final check of a plan against 50 000 futures reads a few hundred of them.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .collision import MIN_HEADING_STEP, OBSTACLE_FOOTPRINT, ellipse_f, headings
from .config import MMDOptConfig
from .risk import risk_bound

__all__ = [
    "aligned_empty",
    "as_aligned",
    "to_planes",
    "Futures",
    "FutureIndex",
    "smallest",
    "SampleGeometry",
    "sample_geometry",
    "samples_met",
    "risk_counts",
    "plan_bound",
    "COUNT_BUCKET",
]

#: byte alignment at which JAX's CPU backend reads a NumPy array without copying it
ALIGN = 64
#: plans are counted in buckets of 1, 2, 4, then padded to a multiple of this (one compiled
#: count per bucket)
COUNT_BUCKET = 4
#: normalised slack of the index's test (ellipse-norm units: ~5 mm on a 4.5 m semi-axis), well
#: above the float32 rounding of the count
INDEX_SLACK = 1e-3
#: the index counts candidates exactly in buckets of this many futures per obstacle (times a
#: power of 8 above it: one compiled count per bucket, a handful in all); with fewer futures than
#: twice this it counts them all
INDEX_BUCKET = 1024


def aligned_empty(shape, dtype=np.float64) -> np.ndarray:
    """An uninitialised NumPy array whose data starts at a 64-byte boundary, so that JAX reads it
    in place (a NumPy allocation is 16-byte aligned, and JAX then copies it: at 80 MB that copy
    costs more than the computation that reads it)."""
    dt = np.dtype(dtype)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
    raw = np.empty(nbytes + ALIGN, np.uint8)
    off = (-raw.ctypes.data) % ALIGN
    return raw[off : off + nbytes].view(dt).reshape(shape)


def as_aligned(arr, dtype=np.float64) -> np.ndarray:
    """``arr`` as a C-contiguous, 64-byte aligned array of ``dtype`` (itself when it is one)."""
    a = np.asarray(arr)
    if a.dtype == dtype and a.flags.c_contiguous and a.ctypes.data % ALIGN == 0:
        return a
    out = aligned_empty(a.shape, dtype)
    np.copyto(out, a, casting="unsafe")
    return out


def _window_count(K: int) -> int:
    """The windows of the index over K steps: a divisor of K in 3 … 6, nearest to 5 (K = 100:
    5; K = 51: 3), else 1 (the count keeps one running minimum per window per future)."""
    divisors = [w for w in range(3, 7) if K % w == 0]
    return min(divisors, key=lambda w: abs(w - 5)) if divisors else 1


def _circles(q0, L2, Q, offsets):
    """The least of eq. (coll_constraints) over the circles at ``offsets``:
    ``q₀ − 2 r L + r² Q`` (``L2`` = 2L); a pair ±r is ``q₀ − |r||L2| + r² Q``."""
    q = None
    for r in sorted({abs(r) for r in offsets}):
        if r == 0.0:
            qc = q0
        elif r in offsets and -r in offsets:
            qc = q0 - r * jnp.abs(L2) + (r * r) * Q
        else:
            sign = r if r in offsets else -r
            qc = q0 - sign * L2 + (r * r) * Q
        q = qc if q is None else jnp.minimum(q, qc)
    return q


def _step_bits(s, d, x, y, dx, dy, ia, ib, offsets, motion: bool):
    """(P, O, k, n) the bit patterns (int32, ordered as the non-negative floats) of the least
    ``q`` over the circles of plans ``s, d`` (P, k) against futures at ``x, y`` (O, k, n) along
    ``dx, dy``: the heading unit vectors, or (``motion``) the forward differences, normalised
    here, a step shorter than MIN_HEADING_STEP pointing along the path (right for a future none
    of whose steps moves; a future whose steps partly stop is counted apart,
    :attr:`Futures.mixed`).  Every intermediate has one consumer, so that XLA fuses the whole
    count into one loop."""
    if motion:
        n2 = dx * dx + dy * dy
        moving = n2 >= jnp.float32(MIN_HEADING_STEP * MIN_HEADING_STEP)
        inv = lax.rsqrt(jnp.where(moving, n2, 1.0))
        dx, dy = jnp.where(moving, dx, 1.0), jnp.where(moving, dy, 0.0)
    else:
        inv = jnp.ones_like(dx)
    es = s[:, None, :, None] - x[None]  # (P, O, k, n)
    ed = d[:, None, :, None] - y[None]
    q0 = es * es * ia + ed * ed * ib
    L2 = (es * dx * ia + ed * dy * ib) * (2.0 * inv)
    Q = (dx * dx * ia + dy * dy * ib) * (inv * inv)
    q = _circles(q0, L2, Q, offsets)
    return lax.bitcast_convert_type(jnp.maximum(q, 0.0), jnp.int32)  # ≥ 0 whatever the rounding


@functools.partial(jax.jit, static_argnames=("windows", "offsets"))
def _q_planes(s, d, planes, units, ia, ib, windows: int, offsets: tuple[float, ...]):
    """(P, O, W, n) float32: the least ``q`` over the footprint's circles and the steps of each
    of ``windows`` equal windows, of the plans ``s, d`` (P, K) against the futures ``planes``
    (O, 2, K, n); ``units`` (O, 2, K, n) their heading unit vectors, or ``None``: each future's
    own forward differences (:func:`_step_bits`; the last step takes the one before).  The
    steps are reduced by a chain of element-wise minima over (P, O, n), vectorised over the
    futures (XLA's CPU reduction over the step axis runs unvectorised when fused)."""
    f32 = jnp.float32
    s, d = s.astype(f32), d.astype(f32)
    x, y = planes[:, 0].astype(f32), planes[:, 1].astype(f32)  # (O, K, n)
    ia, ib = jnp.asarray(ia, f32), jnp.asarray(ib, f32)
    if units is None:  # steps 0 … K−2 by their own differences, step K−1 by the one before
        # (each formed for its one consumer: XLA fuses the whole count into one loop, where a
        # shared intermediate would be stored)
        head = _step_bits(s[:, :-1], d[:, :-1], x[:, :-1], y[:, :-1], x[:, 1:] - x[:, :-1],
                          y[:, 1:] - y[:, :-1], ia, ib, offsets, True)  # fmt: skip
        tail = _step_bits(s[:, -1:], d[:, -1:], x[:, -1:], y[:, -1:], x[:, -1:] - x[:, -2:-1],
                          y[:, -1:] - y[:, -2:-1], ia, ib, offsets, True)  # fmt: skip
        steps = [head[:, :, k] for k in range(head.shape[2])] + [tail[:, :, 0]]
    else:
        bits = _step_bits(s, d, x, y, units[:, 0], units[:, 1], ia, ib, offsets, False)
        steps = [bits[:, :, k] for k in range(bits.shape[2])]
    L = len(steps) // windows
    out = []
    for w in range(windows):
        acc = steps[w * L]
        for k in range(w * L + 1, (w + 1) * L):
            acc = jnp.minimum(acc, steps[k])
        out.append(acc)
    return lax.bitcast_convert_type(jnp.stack(out, axis=2), f32)


@jax.jit
def _mixed(planes):
    # (O, n) whether a future's steps partly move and partly stop (its headings are carried)
    x, y = planes[:, 0].astype(jnp.float32), planes[:, 1].astype(jnp.float32)
    dx, dy = x[:, 1:] - x[:, :-1], y[:, 1:] - y[:, :-1]
    moving = dx * dx + dy * dy >= jnp.float32(MIN_HEADING_STEP * MIN_HEADING_STEP)
    anyv, allv = moving[:, 0], moving[:, 0]
    for k in range(1, moving.shape[1]):  # element-wise over (O, n), as the count's steps
        anyv, allv = anyv | moving[:, k], allv & moving[:, k]
    return anyv & ~allv


def _carried_units(planes) -> np.ndarray:
    """(O, 2, K, J) float32, 64-byte aligned: the unit vectors of
    :func:`mmdopt.collision.headings` (no initial heading) of the futures ``planes``
    (O, 2, K, J), in their layout: each forward difference normalised, a step shorter than
    MIN_HEADING_STEP taking the last longer one's, before the first longer one that one's, none
    at all: along the path; the last step repeats the one before.  In NumPy (a running maximum
    of step indices and one gather), so that it runs on the futures given and no more: a jitted
    form needs them padded to a bucket of fixed shapes, 2.2 times the work at 3724 futures."""
    P = np.asarray(planes, np.float32)
    O, _, K, J = P.shape
    u = np.diff(P, axis=2)  # (O, 2, K − 1, J)
    n2 = u[:, 0] * u[:, 0] + u[:, 1] * u[:, 1]
    moving = n2 >= np.float32(MIN_HEADING_STEP * MIN_HEADING_STEP)
    inv = np.zeros_like(n2)
    np.divide(np.float32(1.0), np.sqrt(n2), out=inv, where=moving)
    u *= inv[:, None]
    steps = np.arange(K - 1, dtype=np.int32)[:, None]
    src = np.maximum.accumulate(np.where(moving, steps, -1), axis=1)  # last moving step so far
    first = np.argmax(moving, axis=1).astype(np.int32)[:, None]  # the first (0 when none)
    np.copyto(src, first, where=src < 0)
    out = aligned_empty((O, 2, K, J), np.float32)
    out[:, :, : K - 1] = np.take_along_axis(u, src[:, None], axis=2)
    still = np.broadcast_to(~moving.any(1)[:, None, :], n2.shape)  # none moves: along the path
    out[:, 0, : K - 1][still] = 1.0
    out[:, 1, : K - 1][still] = 0.0
    out[:, :, K - 1] = out[:, :, K - 2]
    return out


#: futures per block of the conversions to planes (the block's transposition stays in cache)
_BLOCK = 512


def to_planes(obs_fr, convert=None, affine=None) -> np.ndarray:
    """The futures ``obs_fr`` (O, n, K, 2) as planes (O, 2, K, n) float32, 64-byte aligned (the
    layout every count reads: :class:`Futures`); ``convert``: a map of each block of positions
    (b, K, 2) to the two coordinates to store, each (b, K) (e.g. Cartesian → Frenet,
    :meth:`frenet.ReferencePath.to_frenet_points`), applied block by block; ``affine``: instead,
    ``(M, c)`` with the coordinates ``xy @ M + c`` (a straight path,
    :meth:`frenet.ReferencePath.frenet_affine`): one product and one add per block in float64,
    rounded once (a fifth less time than the two-coordinate map at 50 000 futures)."""
    X = np.asarray(obs_fr)
    O, n, K, _ = X.shape
    if convert is not None and affine is not None:
        raise ValueError("convert and affine exclude each other")
    out = aligned_empty((O, 2, K, n), np.float32)
    if affine is not None:
        M, c = (np.asarray(a, np.float64) for a in affine)
        if M.shape != (2, 2) or c.shape != (2,):
            raise ValueError(f"affine must be (M (2, 2), c (2,)), got {M.shape}, {c.shape}")
        c, tmp = c[:, None, None], np.empty((2, K, min(n, _BLOCK)))
    for o in range(O):
        for i in range(0, n, _BLOCK):
            blk = X[o, i : i + _BLOCK]
            if affine is not None:  # the block's planes in float64 (in cache), then rounded
                t = tmp[:, :, : blk.shape[0]]
                np.add((blk @ M).transpose(2, 1, 0), c, out=t)
                out[o, :, :, i : i + _BLOCK] = t
            elif convert is None:
                out[o, :, :, i : i + _BLOCK] = blk.transpose(2, 1, 0)
            else:
                a, b = convert(blk)
                out[o, 0, :, i : i + _BLOCK] = a.T
                out[o, 1, :, i : i + _BLOCK] = b.T
    return out


@dataclass(frozen=True, eq=False)
class Futures:
    """The planning futures as the counts read them: positions in planes ``planes``
    (O, 2, K, n) float32 (s then d; 64-byte aligned, read in place by JAX) in the planning
    frame, and, where given, their body headings ``heading`` (O, n, K)."""

    planes: np.ndarray
    heading: np.ndarray | None = None

    def __post_init__(self) -> None:
        p = self.planes
        if p.ndim != 4 or p.shape[1] != 2 or p.shape[2] < 2 or p.dtype != np.float32:
            raise ValueError(f"planes must be float32 (O, 2, K >= 2, n), got {p.dtype} {p.shape}")
        if self.heading is not None and self.heading.shape != self.shape[:3]:
            raise ValueError(f"heading must have shape {self.shape[:3]}, got "
                             f"{self.heading.shape}")  # fmt: skip

    @classmethod
    def of(cls, obs_fr, obs_h=None) -> Futures:
        """The futures ``obs_fr`` (O, n, K, 2) with their headings ``obs_h`` (O, n, K)."""
        X = np.asarray(obs_fr)
        if X.ndim != 4 or X.shape[-1] != 2 or X.shape[2] < 2:
            raise ValueError(f"obs_fr must have shape (O, n, K >= 2, 2), got {X.shape}")
        return cls(to_planes(X), None if obs_h is None else np.asarray(obs_h, np.float64))

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """(O, n, K, 2), the shape of the futures as positions."""
        O, _, K, n = self.planes.shape
        return O, n, K, 2

    @property
    def xy(self) -> np.ndarray:
        """The positions (O, n, K, 2) float32: a view of the planes."""
        return self.planes.transpose(0, 3, 2, 1)

    @functools.cached_property
    def mixed(self) -> np.ndarray:
        """(O, n) the futures whose steps partly move and partly stop: their headings are
        carried (:func:`mmdopt.collision.headings`), counted apart."""
        if self.heading is not None:
            return np.zeros(self.shape[:2], bool)
        return np.asarray(_mixed(jax.device_put(self.planes, may_alias=True)))

    @functools.cached_property
    def units(self) -> np.ndarray | None:
        """The heading unit vectors (O, 2, K, n) float32 of the given body headings; ``None``
        where the count forms them from each future's motion."""
        if self.heading is None:
            return None
        h = np.asarray(self.heading).transpose(0, 2, 1)
        u = aligned_empty(self.planes.shape, np.float32)
        u[:, 0], u[:, 1] = np.cos(h), np.sin(h)
        return u

    def subset(self, idx: np.ndarray) -> Futures:
        """The futures ``idx`` (O, J) of each obstacle (their headings carried as in the whole
        set: a future's heading is its own)."""
        idx = np.asarray(idx)
        O, _, K, _ = self.planes.shape
        planes = aligned_empty((O, 2, K, idx.shape[1]), np.float32)
        for o in range(O):  # into place (a fancy index would gather into a temporary first)
            np.take(self.planes[o], idx[o], axis=2, out=planes[o])
        h = None if self.heading is None else np.take_along_axis(self.heading, idx[..., None], 1)
        out = Futures(planes, h)
        if h is None:
            mixed = np.take_along_axis(self.mixed, idx, 1)
            out.__dict__["mixed"] = mixed
            if mixed.any():  # their carried units: read from the whole set's, formed once
                whole = self._mixed_part
                o, j = np.nonzero(mixed)
                cols = whole.slot[o, idx[o, j]]
                out.__dict__["_mixed_part"] = _MixedPart.of(
                    o, j, mixed.shape, whole.part.planes[0][:, :, cols],
                    whole.part.units[0][:, :, cols],
                )  # fmt: skip
        return out

    @functools.cached_property
    def _mixed_part(self) -> _MixedPart:
        """The futures whose headings are carried (:attr:`mixed`) with their units, formed once
        per set (every count of the set and of its subsets reads them)."""
        o, j = np.nonzero(self.mixed)
        xy = np.ascontiguousarray(self.planes[o, :, :, j].transpose(1, 2, 0))  # (2, K, R)
        return _MixedPart.of(o, j, self.mixed.shape, xy, _carried_units(xy[None])[0])

    def q(self, s, d, a: float, b: float, windows: int = 1) -> np.ndarray:
        """(P, O, n, windows) float32: the least ``q = Δs²/a² + Δd²/b²`` over the footprint's
        circles and the steps of each window (K split into ``windows`` equal parts) of each
        plan ``s, d`` (P, K) against each future; the plan meets a future where ``q < 1``."""
        s, d = np.atleast_2d(s), np.atleast_2d(d)
        P, K = s.shape
        O, n = self.shape[:2]
        if K != self.shape[2] or d.shape != s.shape:
            raise ValueError(f"s and d must be (P, {self.shape[2]}), got {s.shape}, {d.shape}")
        if K % windows:
            raise ValueError(f"windows ({windows}) must divide K = {K}")
        sd = np.stack([s, d]).astype(np.float32)
        offsets = tuple(float(r) for r in OBSTACLE_FOOTPRINT.offsets)
        u = None if self.units is None else jax.device_put(self.units, may_alias=True)
        planes = jax.device_put(self.planes, may_alias=True)
        # one plan at a time: the count of one plan is one fused loop (XLA splits a batch's)
        q = np.stack([
            np.asarray(_q_planes(sd[0, p : p + 1], sd[1, p : p + 1], planes, u, 1.0 / (a * a),
                                 1.0 / (b * b), windows, offsets))[0]
            for p in range(P)
        ]).transpose(0, 1, 3, 2)  # (P, O, n, W)  # fmt: skip
        if self.mixed.any():  # their headings are carried: counted apart
            mp = self._mixed_part
            q = np.array(q)
            q[:, mp.o, mp.j] = mp.part.q(s, d, a, b, windows)[:, 0, : mp.o.size]  # (P, R, W)
        return q

    def met(self, s, d, a: float, b: float) -> np.ndarray:
        """(P, O, n) the futures each plan ``s, d`` (P, K) meets."""
        return self.q(s, d, a, b)[..., 0] < 1.0


@dataclass(frozen=True, eq=False)
class _MixedPart:
    """The futures of a set (of ``shape`` (O, n)) whose headings are carried: their obstacles
    ``o`` and positions ``j`` (R,), and ``part``: they as one row (1, 2, K, J) with their units,
    J = R padded to a bucket by repeating the first (one compiled count per bucket)."""

    o: np.ndarray
    j: np.ndarray
    shape: tuple[int, int]
    part: Futures

    @classmethod
    def of(cls, o, j, shape, xy, units) -> _MixedPart:
        """From the futures' (o, j) (R,), their positions ``xy`` and units (2, K, R)."""
        R, K = o.size, xy.shape[1]
        planes, u = (aligned_empty((1, 2, K, _size_bucket(R)), np.float32) for _ in "pu")
        planes[0, :, :, :R], u[0, :, :, :R] = xy, units
        planes[0, :, :, R:], u[0, :, :, R:] = xy[:, :, :1], units[:, :, :1]
        part = Futures(planes)
        part.__dict__["units"] = u
        part.__dict__["mixed"] = np.zeros((1, planes.shape[3]), bool)
        return cls(o, j, tuple(shape), part)

    @functools.cached_property
    def slot(self) -> np.ndarray:
        """(O, n) each future's column in ``part`` (−1: not carried)."""
        slot = np.full(self.shape, -1, np.int64)
        slot[self.o, self.j] = np.arange(self.o.size)
        return slot


def _size_bucket(c: int) -> int:
    """The futures per obstacle a subset count is padded to: :data:`INDEX_BUCKET` times the least
    power of 8 that holds ``c`` (one compiled count per bucket)."""
    size = INDEX_BUCKET
    while size < c:
        size *= 8
    return size


def smallest(v: np.ndarray, M: int) -> np.ndarray:
    """(O, M) the positions, ascending, of the ``M`` least values of each row of ``v`` (O, n),
    ties to the lower position: ``np.sort(np.argsort(v, kind="stable")[:, :M])`` by a partition
    (O(n), not a sort of every value)."""
    O, n = v.shape
    if M >= n:
        return np.tile(np.arange(n), (O, 1))
    out = np.empty((O, M), np.int64)
    for o in range(O):
        thr = np.partition(v[o], M - 1)[M - 1]
        below = np.flatnonzero(v[o] < thr)
        at = np.flatnonzero(v[o] == thr)[: M - below.size]
        out[o] = np.sort(np.concatenate([below, at]))
    return out


def _bucket(c: int) -> int:
    return 1 << (c - 1).bit_length() if c <= COUNT_BUCKET else -(-c // COUNT_BUCKET) * COUNT_BUCKET


def _norm_deviation(s, d, ref_s, ref_d, a: float, b: float, windows: int) -> np.ndarray:
    """(P, W) the largest ellipse-norm distance ``√(Δs²/a² + Δd²/b²)`` between each plan and the
    reference plan over the steps of each window."""
    dev = np.sqrt(((s - ref_s) / a) ** 2 + ((d - ref_d) / b) ** 2)  # (P, K)
    return dev.reshape(dev.shape[0], windows, -1).max(-1)


class FutureIndex:
    """What one exact pass of the count against a reference plan (``ref_s, ref_d`` (K,)) tells
    of every other plan: for each future and window, ``√Q_w`` (the least ellipse-norm distance
    of the reference plan to its circles there).  A plan within ``D_w`` of the reference in
    window w is at least ``√Q_w − D_w`` from the future there (the triangle inequality of the
    ellipse norm), so :meth:`lower` bounds its distance to every future without reading them,
    :meth:`met` counts exactly only the futures the bound cannot clear (falling back to the full
    count when they are many), and :meth:`nearest` finds the futures nearest to a plan."""

    def __init__(self, futures: Futures, ref_s, ref_d, a: float, b: float,
                 q: np.ndarray | None = None) -> None:  # fmt: skip
        self.futures, self.a, self.b = futures, float(a), float(b)
        self.ref_s = np.asarray(ref_s, np.float64)
        self.ref_d = np.asarray(ref_d, np.float64)
        self.windows = _window_count(futures.shape[2])
        if q is None:
            q = futures.q(self.ref_s[None], self.ref_d[None], a, b, self.windows)[0]
        self.root = np.sqrt(q.astype(np.float64))  # (O, n, W)

    @property
    def q_ref(self) -> np.ndarray:
        """(O, n) the reference plan's least ``q`` against each future."""
        return self.root.min(-1) ** 2

    def lower(self, s, d) -> np.ndarray:
        """(P, O, n) a lower bound of the ellipse-norm distance of each plan to each future."""
        s, d = np.atleast_2d(s), np.atleast_2d(d)
        dev = _norm_deviation(s, d, self.ref_s, self.ref_d, self.a, self.b, self.windows)
        return (self.root[None] - dev[:, None, None, :]).min(-1)

    def _exact(self, s, d, cand: np.ndarray) -> np.ndarray:
        """(P, O, n) float32 ``q`` of each plan at the futures ``cand`` (O, n) bool, +inf
        elsewhere: the candidates of each obstacle counted exactly, padded to a bucket."""
        O, n = cand.shape
        per = cand.sum(1)
        idx = np.zeros((O, _size_bucket(int(per.max()))), np.int64)
        for o in range(O):  # a handful of obstacles
            c = np.flatnonzero(cand[o])
            idx[o, : c.size] = c
            idx[o, c.size :] = c[0] if c.size else 0
        q = self.futures.subset(idx).q(s, d, self.a, self.b)[..., 0]  # (P, O, size)
        out = np.full((q.shape[0], O, n), np.inf, np.float32)
        for o in range(O):
            k = int(per[o])
            out[:, o, idx[o, :k]] = q[:, o, :k]
        return out

    @property
    def small(self) -> bool:
        """Whether the futures are few enough to count them all each time."""
        return self.futures.shape[1] < 2 * INDEX_BUCKET

    def met(self, s, d) -> np.ndarray:
        """(P, O, n) the futures each plan meets: the exact count (as :meth:`Futures.met`)."""
        s, d = np.atleast_2d(s), np.atleast_2d(d)
        if self.small:
            return self.futures.met(s, d, self.a, self.b)
        cand = self.lower(s, d) < 1.0 + INDEX_SLACK  # (P, O, n): the only ones it may meet
        if cand.any(0).sum() > cand.shape[-1] * cand.shape[-2] // 8:  # many: count them all
            return self.futures.met(s, d, self.a, self.b)
        return self._exact(s, d, cand.any(0)) < 1.0

    def nearest(self, s, d, M: int) -> np.ndarray | None:
        """(O, M) the positions, ascending, of the ``M`` futures of each obstacle with the least
        ``q`` against the plan ``s, d`` (K,) (ties to the lower position), when the bounds
        certify them from a few candidates; ``None`` when they cannot (count all)."""
        if self.small:
            return None
        lb = self.lower(np.asarray(s)[None], np.asarray(d)[None])[0]  # (O, n)
        O, n = lb.shape
        if M >= n:
            return None
        take = min(n, max(4 * M, INDEX_BUCKET // 2))
        part = np.argpartition(lb, take - 1, axis=1)[:, :take]
        thresh = np.take_along_axis(lb, part, 1).max(1)  # every other future is at least this far
        cand = np.zeros((O, n), bool)
        np.put_along_axis(cand, part, True, 1)
        q = self._exact(np.asarray(s)[None], np.asarray(d)[None], cand)[0]  # (O, n)
        near = smallest(q, M)
        mth = np.sqrt(np.take_along_axis(q, near, 1).max(1).astype(np.float64))
        if take < n and np.any(mth + INDEX_SLACK >= thresh):
            return None
        return near


# ------------------------------------------------------------------ the materialised geometry
@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SampleGeometry:
    """The planning samples with their heading unit vectors formed: positions ``xy``
    (O, n, K, 2) and ``cos``, ``sin`` (O, n, K) (:func:`mmdopt.collision.headings` where no body
    heading is given), with the footprint's circle offsets ``r`` (C,): what a measurement with the
    config's rules of the road reads (:func:`mmdopt.schedule` conflict depth).  A jitted consumer
    forms the circle centres with :meth:`circle` inside its reduction (never stored)."""

    xy: jax.Array
    cos: jax.Array
    sin: jax.Array
    r: jax.Array

    def centres(self) -> jax.Array:
        """(O, n, C, K, 2) circle centres, as :func:`mmdopt.collision.circle_centres` gives
        them (bit for bit)."""
        u = jnp.stack([self.cos, self.sin], axis=-1)
        return self.xy[..., None, :, :] + self.r[:, None, None] * u[..., None, :, :]

    def circle(self, c: int) -> tuple[jax.Array, jax.Array]:
        """The two components (O, n, K) of circle ``c``'s centres (those of :meth:`centres`)."""
        return self.xy[..., 0] + self.r[c] * self.cos, self.xy[..., 1] + self.r[c] * self.sin


def sample_geometry(obs_fr, obs_h=None) -> SampleGeometry:
    """:class:`SampleGeometry` of the samples ``obs_fr`` (O, n, K, 2) along ``obs_h`` (O, n, K)
    (``None``: each sample's motion), with :data:`mmdopt.collision.OBSTACLE_FOOTPRINT`."""
    xy = jnp.asarray(obs_fr)
    r = jnp.asarray(OBSTACLE_FOOTPRINT.offsets_array(), xy.dtype)
    c, sn = _geometry_units(xy, None if obs_h is None else jnp.asarray(obs_h, xy.dtype))
    return SampleGeometry(xy, c, sn, r)


@jax.jit
def _geometry_units(xy, h):
    if h is None:
        h = headings(xy)
    return jnp.cos(h), jnp.sin(h)


@jax.jit
def _met_from_centres(s, d, centres, a, b):
    # the count from circle centres already formed (one plan at a time)
    def one(sd):
        ego = jnp.stack(sd, -1)  # (K, 2)
        return jnp.any(ellipse_f(ego, centres, a, b) > 0.0, axis=(2, 3))

    return lax.map(one, (s, d))


def samples_met(config: MMDOptConfig, obs_fr, obs_h, s, d, centres=None,
                futures: Futures | None = None) -> np.ndarray:  # fmt: skip
    """(C, O, n) the planning samples each of the C plans (s, d) (C, K) meets, counted as
    :func:`mmdopt.collision_free_count` counts a collision (any circle, any step, the nominal
    ellipse ``a, b``): :meth:`Futures.met` of the samples ``obs_fr`` (O, n, K, 2) along ``obs_h``
    (O, n, K; ``None``: each sample's motion), or ``futures`` when already formed; ``centres``:
    their circle centres (O, n, C, K, 2), counted from those instead (float64)."""
    a, b = float(config.safety.footprint.a), float(config.safety.footprint.b)
    if centres is not None:
        xy = np.stack([np.asarray(s, np.float64), np.asarray(d, np.float64)], -1)
        C = xy.shape[0]
        xy = np.concatenate([xy, np.repeat(xy[:1], _bucket(C) - C, axis=0)])
        sj, dj = jnp.asarray(xy[..., 0]), jnp.asarray(xy[..., 1])
        return np.asarray(_met_from_centres(sj, dj, centres, a, b))[:C]
    fut = Futures.of(obs_fr, obs_h) if futures is None else futures
    return fut.met(np.asarray(s, np.float64), np.asarray(d, np.float64), a, b)


def risk_counts(config: MMDOptConfig, colliding) -> np.ndarray:
    """The counts a plan's risk bound is computed from, given the (O, n) planning samples it
    meets: (1,) the joint futures it meets with any obstacle (``safety.joint_futures``), else
    (O,) the samples of each obstacle (:func:`mmdopt.risk.risk_bound`)."""
    hits = np.asarray(colliding, bool)
    if config.bound_groups(hits.shape[0]) == 1:
        return hits.any(0).sum(keepdims=True)
    return hits.sum(-1)


def plan_bound(config: MMDOptConfig, colliding) -> float:
    """The 95 % risk bound of a plan meeting the (O, n) planning samples ``colliding``."""
    counts = risk_counts(config, colliding)
    return risk_bound(counts, [np.shape(colliding)[-1]] * counts.size)
