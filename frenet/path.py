"""Reference paths and vectorised Cartesian ↔ Frenet conversion.

:class:`ReferencePath` is a C² cubic spline ``r(s) = (x(s), y(s))`` parameterised by arc length
``s ∈ [0, length]`` (metres), with heading ``θ(s)`` and signed curvature ``κ(s)`` (positive for
left turns).  Beyond its ends the path continues along its end tangents (straight lines), so every
point of the plane has a Frenet coordinate and obstacles that run past the end still convert.

Frenet coordinates: ``s`` (arc length of the nearest path point) and ``d`` (signed lateral offset,
positive to the left of the direction of travel): ``p = r(s) + d·n(s)``, ``n = (−sin θ, cos θ)``.
The nearest point is found by a proper projection – a k-d tree over densely sampled path points,
projection onto the two adjacent chords, then Newton's method on ``(r(s) − p)·r'(s) = 0`` – not a
brute-force scan; a large batch on a path converted again and again starts its Newton search
from a grid of projected nodes instead (computed in tiles where the batches go, left to the tree
where the nearest point jumps), to the same answer; on a straight path
(:meth:`ReferencePath.straight`, or collinear way-points in order) it is the exact projection
onto the line.  Round trips are exact to ~1e-9 m wherever the
nearest point is unique (``|d| < 1/|κ|``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicSpline
from scipy.spatial import cKDTree

if TYPE_CHECKING:  # planner imports nothing from here, but keep the import lazy
    from .planner import EgoState

__all__ = ["ReferencePath", "wrap_angle"]

_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(6)

#: a batch of at least this many points starts its Newton search from the path's start grid
#: where the grid has been computed: a tile of it is computed once the batches have brought it
#: ``_GRID_PAYBACK`` points per node (a node costs about what the tree start of two points
#: saves), so a path converted once or twice keeps the k-d tree
_GRID_MIN_POINTS = 4096
_GRID_PAYBACK = 2.0
#: spacing (m) of the start grid's nodes, and how far (m) it reaches beyond the path's samples
_GRID_STEP = 0.5
_GRID_MARGIN = 80.0
#: the tolerance of :meth:`ReferencePath.to_frenet_points` for coordinates stored in float32
#: (the planner's obstacle planes): Newton stops once the error left is below 10⁻⁸ × the path's
#: length (a bound that assumes curvature terms up to 100 /m; on lane-scale curves the error is
#: far smaller: 5.5·10⁻⁹ m at most over 1.5 million futures' points on a junction route, where
#: float32 spacing at 10–100 m is 10⁻⁶–10⁻⁵ m).  Most points then stop after one step from the
#: start grid instead of two.
FLOAT32_TOL = 1e-8


def wrap_angle(a: ArrayLike) -> NDArray[np.float64]:
    """Angles wrapped to ``[−π, π)``."""
    return (np.asarray(a, dtype=np.float64) + np.pi) % (2 * np.pi) - np.pi


def _as_float(name: str, v) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number or array of them, got {v!r}") from None
    return a


def _broadcast(names: tuple[str, ...], *arrays) -> list[np.ndarray]:
    """``arrays`` as float64, broadcast together; ``ValueError`` naming them if they do not."""
    arrs = [_as_float(n, a) for n, a in zip(names, arrays, strict=True)]
    try:
        return list(np.broadcast_arrays(*arrs))
    except ValueError:
        shapes = ", ".join(f"{n} {a.shape}" for n, a in zip(names, arrs, strict=True))
        raise ValueError(
            f"{'/'.join(names)} must have the same (or broadcastable) shapes, got {shapes}"
        ) from None


def _straight_line(s, px, py) -> tuple[float, float, float, float] | None:
    """``(x0, y0, ux, uy)`` when the dense samples ``(px, py)`` at arc lengths ``s`` lie on one
    straight line, in order, at their arc length from the first (to 1e-9 of the path's scale):
    the spline through them is then that line, parameterised by arc length."""
    x0, y0 = float(px[0]), float(py[0])
    ex, ey = float(px[-1]) - x0, float(py[-1]) - y0
    L = math.hypot(ex, ey)
    tol = 1e-9 * max(1.0, float(np.max(np.abs(px))), float(np.max(np.abs(py))), float(s[-1]))
    if L <= tol:
        return None
    ux, uy = ex / L, ey / L
    along = (px - x0) * ux + (py - y0) * uy
    across = -(px - x0) * uy + (py - y0) * ux
    if np.max(np.abs(across)) > tol or np.max(np.abs(along - (s - s[0]))) > tol:
        return None
    return x0, y0, ux, uy


def _check_finite(name: str, *arrays: np.ndarray) -> None:
    for a in arrays:
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} contains NaN or inf")


@dataclass(frozen=True, eq=False)
class ReferencePath:
    """An arc-length-parameterised cubic-spline path (:meth:`from_waypoints`, :meth:`straight`).

    Attributes
    ----------
    length : float
        Arc length in metres.
    spacing : float
        Spacing (m) of the dense samples (coarse nearest-point search and spline knots).
    """

    _sx: CubicSpline
    _sy: CubicSpline
    length: float
    spacing: float
    _knots: np.ndarray
    _tree: cKDTree
    waypoints: np.ndarray
    #: ``(x0, y0, ux, uy)`` when the path is a straight line (start point, unit direction):
    #: Cartesian → Frenet is then a projection, exact, with no search or Newton steps
    _line: tuple[float, float, float, float] | None = None
    #: the splines' piecewise-cubic coefficients, highest power first, one contiguous array per
    #: coefficient (x's four, then y's four), each (N − 1,): :meth:`_eval` finds a point's piece
    #: once and evaluates x, y and their derivatives by Horner's rule on these
    _coef: tuple[np.ndarray, ...] = ()

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_waypoints(cls, xy: ArrayLike, *, spacing: float = 0.5) -> ReferencePath:
        """Cubic spline (natural end conditions) through way-points ``xy`` (N, 2), N ≥ 2, then
        re-parameterised by arc length.

        The chord-length spline is sampled every ≈``spacing`` metres, the arc length of each
        piece is integrated (6-point Gauss–Legendre), and the path is re-fitted as a spline in
        ``s``.  Raises ``ValueError`` for NaN/inf, fewer than two points, repeated consecutive
        way-points or a zero-length path.
        """
        xy = np.asarray(xy, dtype=np.float64)
        if xy.ndim != 2 or xy.shape[1] != 2:
            raise ValueError(f"way-points must have shape (N, 2), got {xy.shape}")
        if xy.shape[0] < 2:
            raise ValueError(f"need at least 2 way-points, got {xy.shape[0]}")
        _check_finite("way-points", xy)
        if not (np.isfinite(spacing) and spacing > 0):
            raise ValueError(f"spacing must be positive, got {spacing}")
        seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        scale = max(1.0, float(np.abs(xy).max()))
        if seg.sum() <= 1e-9 * scale:
            raise ValueError("zero-length path: all way-points coincide")
        dup = np.flatnonzero(seg <= 1e-9 * scale)
        if dup.size:
            raise ValueError(
                f"duplicate consecutive way-points at indices {dup[:5].tolist()} (first 5 shown); "
                "remove them before building the path"
            )
        u = np.concatenate([[0.0], np.cumsum(seg)])
        bc = "natural" if xy.shape[0] > 2 else "not-a-knot"
        cx, cy = CubicSpline(u, xy[:, 0], bc_type=bc), CubicSpline(u, xy[:, 1], bc_type=bc)
        # dense parameter samples: every way-point plus ≈spacing in between
        pieces = [
            np.linspace(u[i], u[i + 1], max(2, int(np.ceil(seg[i] / spacing)) + 1))[:-1]
            for i in range(len(seg))
        ]
        ud = np.concatenate(pieces + [[u[-1]]])
        a, b = ud[:-1], ud[1:]
        half, mid = (b - a) / 2, (a + b) / 2
        nodes = mid[:, None] + half[:, None] * _GAUSS_X[None, :]
        speed = np.hypot(cx(nodes, 1), cy(nodes, 1))
        ds = half * (speed @ _GAUSS_W)
        s = np.concatenate([[0.0], np.cumsum(ds)])
        px, py = cx(ud), cy(ud)
        return cls._build(s, px, py, xy)

    @classmethod
    def straight(
        cls, length: float = 1000.0, *, start=(0.0, 0.0), heading: float = 0.0
    ) -> ReferencePath:
        """A straight path of ``length`` metres from ``start`` along ``heading`` (rad)."""
        length = float(_as_float("length", length)) if np.ndim(length) == 0 else length
        if np.ndim(length) != 0 or not (np.isfinite(length) and length > 0):
            raise ValueError(f"length must be positive and finite, got {length!r}")
        st = _as_float("start", start)
        if st.shape != (2,) or not np.all(np.isfinite(st)):
            raise ValueError(f"start must be a finite (x, y) pair, got {start!r}")
        h = _as_float("heading", heading)
        if h.ndim != 0 or not np.isfinite(h):
            raise ValueError(f"heading must be a finite angle (rad), got {heading!r}")
        x0, y0 = float(st[0]), float(st[1])
        d = np.array([np.cos(float(h)), np.sin(float(h))])
        return cls.from_waypoints(
            np.array([[x0, y0], [x0, y0] + length * d]), spacing=max(0.5, length / 2000)
        )

    @classmethod
    def _build(
        cls, s: np.ndarray, px: np.ndarray, py: np.ndarray, waypoints: np.ndarray
    ) -> ReferencePath:
        bc = "not-a-knot" if len(s) > 3 else "natural"
        sx, sy = CubicSpline(s, px, bc_type=bc), CubicSpline(s, py, bc_type=bc)
        tree = cKDTree(np.column_stack([px, py]))
        spacing = float(np.max(np.diff(s)))
        coef = tuple(np.ascontiguousarray(c) for c in np.concatenate([sx.c, sy.c]))
        line = _straight_line(s, px, py)
        return cls(sx, sy, float(s[-1]), spacing, s, tree, waypoints, line, coef)

    # ------------------------------------------------------------------ geometry
    def _piece(self, sc: np.ndarray, near: np.ndarray | None = None) -> np.ndarray:
        """Index of the spline piece holding each clipped ``sc``; ``near`` (a guess of it, as
        a Newton step leaves most points on their piece) is checked and mended before any
        binary search."""
        k = self._knots
        top = len(k) - 2
        if near is not None:
            i = near
            i = np.clip(i - (sc < k[i]) + (sc >= k[i + 1]), 0, top)
            bad = (sc < k[i]) | ((sc >= k[i + 1]) & (i < top))
            if not bad.any():
                return i
            i = i.copy()
            i[bad] = np.searchsorted(k, sc[bad], side="right") - 1
            return np.clip(i, 0, top)
        return np.clip(np.searchsorted(k, sc, side="right") - 1, 0, top)

    def _eval(self, s: np.ndarray, piece: np.ndarray | None = None):
        """Position, first and second derivatives at ``s`` (flat), linear past the ends, and
        the spline piece of each point (pass it back as ``piece`` for nearby ``s``)."""
        L = self.length
        sc = np.clip(s, 0.0, L)
        i = self._piece(sc, piece)
        a, b, c, e, p, q, r, w = (np.take(cf, i) for cf in self._coef)
        t = sc - np.take(self._knots, i)
        x = ((a * t + b) * t + c) * t + e
        y = ((p * t + q) * t + r) * t + w
        dx = (3.0 * a * t + 2.0 * b) * t + c
        dy = (3.0 * p * t + 2.0 * q) * t + r
        ddx = 6.0 * a * t + 2.0 * b
        ddy = 6.0 * p * t + 2.0 * q
        out = (s < 0.0) | (s > L)
        if np.any(out):
            nrm = np.hypot(dx, dy)
            tx, ty = dx / nrm, dy / nrm
            e = s - sc
            x = np.where(out, x + e * tx, x)
            y = np.where(out, y + e * ty, y)
            dx, dy = np.where(out, tx, dx), np.where(out, ty, dy)
            ddx, ddy = np.where(out, 0.0, ddx), np.where(out, 0.0, ddy)
        return x, y, dx, dy, ddx, ddy, i

    def point(self, s: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Cartesian ``(x, y)`` of the path at arc length ``s`` (any shape)."""
        s = _as_float("s", s)
        _check_finite("s", s)
        x, y, *_ = self._eval(s.ravel())
        return x.reshape(s.shape), y.reshape(s.shape)

    def heading(self, s: ArrayLike) -> NDArray[np.float64]:
        """Path heading ``θ(s)`` (rad, wrapped to [−π, π))."""
        s = _as_float("s", s)
        _check_finite("s", s)
        _, _, dx, dy, _, _, _ = self._eval(s.ravel())
        return np.arctan2(dy, dx).reshape(s.shape)

    def curvature(self, s: ArrayLike) -> NDArray[np.float64]:
        """Signed curvature ``κ(s)`` (1/m, positive turning left); zero beyond the ends."""
        s = _as_float("s", s)
        _check_finite("s", s)
        _, _, dx, dy, ddx, ddy, _ = self._eval(s.ravel())
        k = (dx * ddy - dy * ddx) / np.hypot(dx, dy) ** 3
        return k.reshape(s.shape)

    # ------------------------------------------------------------------ conversions
    def to_frenet(
        self,
        x: ArrayLike,
        y: ArrayLike,
        heading: ArrayLike | None = None,
        *,
        max_iter: int = 30,
        tol: float = 1e-12,
    ) -> tuple[NDArray[np.float64], ...]:
        """Cartesian → Frenet for arrays of any (matching/broadcastable) shape.

        Parameters
        ----------
        x, y : array_like, metres
        heading : array_like, optional
            Cartesian heading (rad); returned as the heading relative to the path, wrapped.

        Returns
        -------
        (s, d) or (s, d, heading_rel), each of the broadcast shape of the inputs.
        """
        x, y = _broadcast(("x", "y"), x, y)
        _check_finite("x/y", x, y)
        shape = x.shape
        px, py = x.ravel(), y.ravel()
        if self._line is not None:  # a straight path: the projection is exact
            x0, y0, ux, uy = self._line
            ex, ey = px - x0, py - y0
            s = (float(self._knots[0]) + ex * ux + ey * uy).reshape(shape)
            d = (ey * ux - ex * uy).reshape(shape)
            if heading is None:
                return s, d
            return s, d, self._relative_heading(heading, shape, math.atan2(uy, ux))
        s, d = self._project(px, py, max_iter, tol)
        if heading is None:
            return s.reshape(shape), d.reshape(shape)
        # the tangent at the final s (the search's last one is a step behind: an angle of
        # that step times the curvature)
        _, _, dx, dy, _, _, _ = self._eval(s)
        s, d = s.reshape(shape), d.reshape(shape)
        return s, d, self._relative_heading(heading, shape, np.arctan2(dy, dx).reshape(shape))

    def to_frenet_points(
        self, xy: ArrayLike, s_offset: float = 0.0, *, tol: float = 1e-12
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Cartesian points ``xy`` (..., 2) → Frenet ``s − s_offset`` and ``d``, each (...,).

        The same coordinates as :meth:`to_frenet` (to float rounding), for many points at once:
        on a straight path four multiply-adds per point with no check of its own (a caller
        converting blocks of a checked array), on a curved one :meth:`to_frenet` with ``tol``
        (its Newton search stops where the error left is below ``tol`` × the path's length; a
        caller that stores the result in float32 needs no more than :data:`FLOAT32_TOL`).
        """
        xy = np.asarray(xy, np.float64)
        if xy.ndim < 1 or xy.shape[-1] != 2:
            raise ValueError(f"xy must have shape (..., 2), got {xy.shape}")
        if isinstance(tol, bool) or not (isinstance(tol, int | float) and 0 < tol < 1):
            raise ValueError(f"tol must be a number in (0, 1), got {tol!r}")
        x, y = xy[..., 0], xy[..., 1]
        if self._line is None:
            s, d = self.to_frenet(x, y, tol=float(tol))
            return s - s_offset, d
        x0, y0, ux, uy = self._line
        s = x * ux
        s += y * uy
        s += float(self._knots[0]) - x0 * ux - y0 * uy - s_offset
        d = y * ux
        d -= x * uy
        d += x0 * uy - y0 * ux
        return s, d

    def frenet_affine(
        self, s_offset: float = 0.0
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """On a straight path the map of :meth:`to_frenet_points` as ``(M, c)``: ``(s −
        s_offset, d) = xy @ M + c`` (M (2, 2), c (2,)), so a caller converting many points can
        fuse it with its own copy; ``None`` on a curved path (there the projection iterates)."""
        if self._line is None:
            return None
        x0, y0, ux, uy = self._line
        M = np.array([[ux, -uy], [uy, ux]])
        c = np.array([float(self._knots[0]) - x0 * ux - y0 * uy - s_offset, x0 * uy - y0 * ux])
        return M, c

    @staticmethod
    def _relative_heading(heading: ArrayLike, shape: tuple, theta) -> NDArray[np.float64]:
        """``heading`` (broadcast to ``shape``) relative to the path heading ``theta``, wrapped."""
        heading = _as_float("heading", heading)
        try:
            heading = np.broadcast_to(heading, shape)
        except ValueError:
            raise ValueError(
                f"heading must have the shape of x/y {shape} (or broadcast to it), got "
                f"{heading.shape}"
            ) from None
        _check_finite("heading", heading)
        return wrap_angle(heading - theta)

    def _project(
        self, px: np.ndarray, py: np.ndarray, max_iter: int = 30, tol: float = 1e-12
    ) -> tuple[np.ndarray, np.ndarray]:
        """Arc length of the nearest path point of each (px, py) (flat) and the signed offset
        (:meth:`_newton`).

        The start of the Newton search comes from the k-d tree and chords (:meth:`_coarse`); a
        large batch (≥ ``_GRID_MIN_POINTS`` points) starts instead from a grid of projected
        points built once per path (:class:`_StartGrid`, :meth:`_start_grid`), linearised, and
        falls back to the tree
        where the grid does not reach or the nearest point is not unique near the point.  Both
        starts end in the same Newton search to the same tolerance."""
        if px.size >= _GRID_MIN_POINTS and (grid := self._start_grid()) is not None:
            s, piece, near = grid.start(px, py)
            if not near.all():
                far = ~near
                s[far], piece[far] = self._coarse(px[far], py[far])
        else:
            s, piece = self._coarse(px, py)
        return self._newton(px, py, s, piece, max_iter, tol)

    def _newton(
        self,
        px: np.ndarray,
        py: np.ndarray,
        s: np.ndarray,
        piece: np.ndarray,
        max_iter: int,
        tol: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Newton from ``s`` (modified in place) to the projection of each point.

        Returns ``s`` and the signed offset ``d``.
        A point stops when its step is below the tolerance, or when the step's square is:
        Newton converges quadratically where ``g = f'`` is not small, so the error left after
        such a step is ``|f''/2f'|·step²``, below the tolerance for ``|f''/2f'| ≤ 100 /m`` (the
        path's curvature and its rate, divided by ``g > 0.05``).  ``d`` and the tangent come
        from the last evaluation, a step of ≤ ``√(tol/100)`` before ``s``: the offset changes
        by the square of that step times the curvature (the normal is orthogonal to the step),
        the tangent by the step times the curvature (so a caller wanting the heading evaluates
        it again).
        """
        # Newton on f(s) = (r(s) − p)·r'(s), on the points not yet converged only, so the
        # few slow points (far off the path, near its ends) do not make every point iterate
        step_cap = 2.0 * self.spacing
        stop = tol * max(1.0, self.length)
        quad = math.sqrt(stop / 100.0)
        d = np.empty_like(s)
        at = np.arange(s.size)
        sa, pa, qx, qy = s, piece, px, py
        for it in range(max_iter):
            rx, ry, dx, dy, ddx, ddy, pa = self._eval(sa, pa)
            ex, ey = rx - qx, ry - qy
            f = ex * dx + ey * dy
            g = dx * dx + dy * dy + ex * ddx + ey * ddy
            fast = g > 0.05
            step = np.where(fast, -f / np.where(fast, g, 1.0), -f)
            step = np.clip(step, -step_cap, step_cap)
            sa = sa + step
            s[at] = sa
            a = np.abs(step)
            going = (a >= stop) & ((a >= quad) | ~fast)
            if it == max_iter - 1:
                going[:] = False
            done = ~going
            if done.all():
                dn, at_d = slice(None), at
            elif done.any():
                dn, at_d = done, at[done]
            else:
                continue
            ux, uy = dx[dn], dy[dn]
            d[at_d] = (ex[dn] * uy - ey[dn] * ux) / np.hypot(ux, uy)
            if dn is not done:
                break
            at, sa, pa, qx, qy = at[going], sa[going], pa[going], qx[going], qy[going]
        return s, d

    def _start_grid(self) -> _StartGrid | None:
        """The start grid of this path (created empty on first use; its tiles are computed
        where the batches go: :class:`_StartGrid`), ``None`` where it would need too many
        tiles: the tree serves every point then."""
        if "_grid_cache" not in self.__dict__:
            object.__setattr__(self, "_grid_cache", _StartGrid.build(self))
        return self.__dict__["_grid_cache"]

    def _coarse(self, px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Initial arc length and its spline piece: the nearest dense sample, then the
        projection onto the better of its two chords (past the path's ends, onto the end
        chord's straight extension)."""
        n = len(self._knots)
        _, i = self._tree.query(np.column_stack([px, py]))
        ax, ay, vx, vy, inv_l2 = self._chords()
        best_s = best_d = best_a = None
        for lo in (i - 1, i):
            a = np.clip(lo, 0, n - 2)
            cx, cy = np.take(ax, a), np.take(ay, a)
            ux, uy = np.take(vx, a), np.take(vy, a)
            rx, ry = px - cx, py - cy
            t = (rx * ux + ry * uy) * np.take(inv_l2, a)
            # stay on the chord, except past the path's ends (linear extension)
            t = np.minimum(t, 1.0, out=t, where=a != n - 2)
            t = np.maximum(t, 0.0, out=t, where=a != 0)
            rx -= t * ux
            ry -= t * uy
            dist = rx * rx + ry * ry
            sa = np.take(self._knots, a)
            cand = sa + t * (np.take(self._knots, a + 1) - sa)
            if best_s is None:
                best_s, best_d, best_a = cand, dist, a
                continue
            better = dist < best_d
            best_s = np.where(better, cand, best_s)
            best_a = np.where(better, a, best_a)
        return best_s, best_a

    def _chords(self) -> tuple[np.ndarray, ...]:
        """Start point, vector and 1/length² of each chord between the dense samples."""
        ch = self.__dict__.get("_chord_cache")
        if ch is None:
            pts = self._tree.data
            v = np.diff(pts, axis=0)
            ch = (
                np.ascontiguousarray(pts[:-1, 0]),
                np.ascontiguousarray(pts[:-1, 1]),
                np.ascontiguousarray(v[:, 0]),
                np.ascontiguousarray(v[:, 1]),
                1.0 / np.einsum("ij,ij->i", v, v),
            )
            object.__setattr__(self, "_chord_cache", ch)
        return ch

    def to_cartesian(
        self, s: ArrayLike, d: ArrayLike, heading: ArrayLike | None = None
    ) -> tuple[NDArray[np.float64], ...]:
        """Frenet → Cartesian for arrays of any broadcastable shape.

        Returns ``(x, y)`` or ``(x, y, heading_abs)`` when a path-relative ``heading`` is given.
        """
        s, d = _broadcast(("s", "d"), s, d)
        _check_finite("s/d", s, d)
        shape = s.shape
        rx, ry, dx, dy, _, _, _ = self._eval(s.ravel())
        nrm = np.hypot(dx, dy)
        dd = d.ravel()
        x = rx - dd * dy / nrm
        y = ry + dd * dx / nrm
        if heading is None:
            return x.reshape(shape), y.reshape(shape)
        heading = _as_float("heading", heading)
        try:
            heading = np.broadcast_to(heading, shape)
        except ValueError:
            raise ValueError(
                f"heading must have the shape of s/d {shape} (or broadcast to it), got "
                f"{heading.shape}"
            ) from None
        _check_finite("heading", heading)
        return (
            x.reshape(shape),
            y.reshape(shape),
            wrap_angle(heading + np.arctan2(dy, dx).reshape(shape)),
        )

    def trajectory_to_cartesian(
        self,
        s: ArrayLike,
        d: ArrayLike,
        vs: ArrayLike,
        vd: ArrayLike,
        stop_speed: float = 0.05,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Frenet trajectories (…, K) with Frenet velocities → Cartesian ``(x, y, heading, speed)``.

        Uses ``ẋ_cart = (1 − dκ) ṡ t + ḋ n``: the heading is ``θ(s) + atan2(ḋ, (1 − dκ) ṡ)``.
        Below ``stop_speed`` (m/s) the direction of motion is undefined (a solver's −10⁻³ m/s
        would turn the car round): the heading relative to the path is held from the last step
        at or above it along the last axis (0, the path's direction, before the first such
        step) — a car at rest keeps its heading.  ``stop_speed = 0`` gives the raw formula.
        """
        s, d, vs, vd = _broadcast(("s", "d", "vs", "vd"), s, d, vs, vd)
        _check_finite("trajectory", s, d, vs, vd)
        stop_speed = float(stop_speed)
        if not (math.isfinite(stop_speed) and stop_speed >= 0):
            raise ValueError(f"stop_speed must be finite and >= 0, got {stop_speed}")
        x, y = self.to_cartesian(s, d)
        k = self.curvature(s)
        vt = (1.0 - d * k) * vs
        speed = np.hypot(vt, vd)
        rel = np.arctan2(vd, vt)
        if stop_speed > 0 and rel.ndim > 0:
            moving = speed >= stop_speed
            # forward fill along the last axis: index of the last moving step so far (−1: none)
            idx = np.where(moving, np.arange(rel.shape[-1]), -1)
            idx = np.maximum.accumulate(idx, axis=-1)
            held = np.take_along_axis(rel, np.maximum(idx, 0), axis=-1)
            rel = np.where(idx >= 0, held, 0.0)
        elif stop_speed > 0 and speed < stop_speed:
            rel = np.zeros_like(rel)
        heading = wrap_angle(self.heading(s) + rel)
        return x, y, heading, speed

    def ego_state(
        self,
        x: float,
        y: float,
        speed: float,
        heading: float,
        accel: float = 0.0,
        yaw_rate: float = 0.0,
    ) -> EgoState:
        """The Frenet :class:`~frenet.planner.EgoState` of a vehicle at Cartesian pose/speed.

        ``ṡ = v cos Δψ /(1 − dκ)``, ``ḋ = v sin Δψ``, accelerations from the body-frame
        acceleration ``(a, v·ψ̇)`` rotated into the path frame (the ``κ'`` term is neglected).
        """
        from .planner import EgoState

        vals = np.array([x, y, speed, heading, accel, yaw_rate], dtype=np.float64)
        _check_finite("ego state", vals)
        s, d, dpsi = self.to_frenet(x, y, heading)
        s, d, dpsi = float(s), float(d), float(dpsi)
        k = float(self.curvature(s))
        one = 1.0 - d * k
        if one <= 0:
            raise ValueError("ego is beyond the path's centre of curvature (1 − dκ ≤ 0)")
        vs = speed * np.cos(dpsi) / one
        vd = speed * np.sin(dpsi)
        dpsi_dot = yaw_rate - k * vs
        at = accel * np.cos(dpsi) - speed * np.sin(dpsi) * dpsi_dot
        ad = accel * np.sin(dpsi) + speed * np.cos(dpsi) * dpsi_dot
        as_ = (at + k * vd * vs) / one
        return EgoState(s=s, d=d, vs=float(vs), vd=float(vd), as_=float(as_), ad=float(ad))

    def __repr__(self) -> str:
        return f"ReferencePath(length={self.length:.3f} m, {len(self.waypoints)} way-points)"


class _StartGrid:
    """Projections of a regular grid of nodes around a path, to start the Newton search of a
    large batch without the k-d tree.

    Each node holds its arc length ``s`` (the full projection), the gradient ``∂s/∂p =
    r'(s) / g`` with ``g = |r'|² + (r − p)·r''`` (the implicit-function derivative of the
    projection condition ``(r(s) − p)·r'(s) = 0``), and its spline piece.  A point starts at
    ``s + ∂s/∂p · (p − node)`` from its nearest node, a fraction of a millimetre from its
    projection on paths of metre-scale curvature radius, so Newton needs one or two steps.

    A node is *unsafe* where the projection is not a smooth function near it: ``g`` small (near a
    centre of curvature), or the linear prediction to a neighbouring node missing that node's
    arc length by more than ``_JUMP`` (the nearest point jumps between two parts of the path
    there); unsafe marks spread to the eight neighbours.  Points at unsafe nodes, or outside
    the grid, are left to the tree (``near`` false), so both routes give the same projection.

    The grid spans the path's bounding box plus ``_GRID_MARGIN`` but is built lazily, in tiles
    of ``TILE × TILE`` nodes: a tile is computed once the batches have brought it
    ``payback_points`` points (a node costs about what the tree start of two points saves), so
    only the area the futures visit is paid for, and a path converted once keeps the tree.
    """

    _JUMP = 0.25  # m; smooth-region mismatch is ≈ κ·step²/2, a few centimetres at most
    _G_MIN = 0.25
    TILE = 32
    _HALO = 2  # nodes computed around a tile, so its border nodes see every edge near them
    _MAX_TILES = 4_000_000

    def __init__(self, path: ReferencePath, lo: np.ndarray, ntx: int, nty: int) -> None:
        self.path = path
        self.x0, self.y0 = float(lo[0]), float(lo[1])
        self.step = _GRID_STEP
        self.ntx, self.nty = ntx, nty
        self.payback_points = int(_GRID_PAYBACK * self.TILE * self.TILE)
        self.seen = np.zeros(ntx * nty, np.int64)
        self.slot = np.full(ntx * nty, -1, np.int64)
        self._parts: list[tuple[np.ndarray, ...]] = []
        self.s = np.empty(0)
        self.jx = self.jy = np.empty(0, np.float32)
        self.piece = np.empty(0, np.int32)
        self.safe = np.empty(0, bool)

    @classmethod
    def build(cls, path: ReferencePath) -> _StartGrid | None:
        """The (empty) grid of ``path``; ``None`` where it would need too many tiles."""
        pts = path._tree.data
        lo = pts.min(axis=0) - _GRID_MARGIN
        side = _GRID_STEP * cls.TILE
        nt = np.ceil((pts.max(axis=0) + _GRID_MARGIN - lo) / side).astype(int)
        if int(nt[0]) * int(nt[1]) > cls._MAX_TILES:
            return None
        return cls(path, lo, int(nt[0]), int(nt[1]))

    def _add_tiles(self, tiles: np.ndarray) -> None:
        """Compute the nodes of ``tiles`` (flat tile ids) and append them to the storage."""
        T, H, h, path = self.TILE, self._HALO, self.step, self.path
        W = T + 2 * H
        tx, ty = tiles // self.nty, tiles % self.nty
        r = np.arange(W) - H
        gx = (tx[:, None] * T + r[None, :]) * h + self.x0  # (nt, W)
        gy = (ty[:, None] * T + r[None, :]) * h + self.y0
        X = np.broadcast_to(gx[:, :, None], (len(tiles), W, W)).ravel()
        Y = np.broadcast_to(gy[:, None, :], (len(tiles), W, W)).ravel()
        s0, piece0 = path._coarse(X, Y)
        s = path._newton(X, Y, s0, piece0, 30, 1e-12)[0]
        rx, ry, dx, dy, ddx, ddy, piece = path._eval(s, piece0)
        g = dx * dx + dy * dy + (rx - X) * ddx + (ry - Y) * ddy
        ok = g > self._G_MIN
        gs = np.where(ok, g, 1.0)
        jx, jy = dx / gs, dy / gs
        S, JX, JY = (a.reshape(-1, W, W) for a in (s, jx, jy))
        bad = ~ok.reshape(-1, W, W)
        # linear prediction along each grid edge, from both ends
        ex = np.abs(S[:, 1:] - S[:, :-1] - 0.5 * h * (JX[:, 1:] + JX[:, :-1])) > self._JUMP
        ey = np.abs(S[:, :, 1:] - S[:, :, :-1] - 0.5 * h * (JY[:, :, 1:] + JY[:, :, :-1]))
        ey = ey > self._JUMP
        bad[:, 1:] |= ex
        bad[:, :-1] |= ex
        bad[:, :, 1:] |= ey
        bad[:, :, :-1] |= ey
        grown = bad.copy()  # spread to the eight neighbours
        grown[:, 1:] |= bad[:, :-1]
        grown[:, :-1] |= bad[:, 1:]
        g2 = grown.copy()
        g2[:, :, 1:] |= grown[:, :, :-1]
        g2[:, :, :-1] |= grown[:, :, 1:]
        inner = (slice(None), slice(H, H + T), slice(H, H + T))
        part = (
            S[inner].ravel(),
            JX[inner].astype(np.float32).ravel(),
            JY[inner].astype(np.float32).ravel(),
            piece.reshape(-1, W, W)[inner].astype(np.int32).ravel(),
            ~g2[inner].ravel(),
        )
        first = sum(len(q[0]) for q in self._parts) // (T * T)
        self._parts.append(part)
        self.slot[tiles] = first + np.arange(len(tiles))
        self.s, self.jx, self.jy, self.piece, self.safe = (
            np.concatenate([q[i] for q in self._parts]) for i in range(5)
        )

    def start(self, px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, ...]:
        """Start ``s``, its piece, and ``near`` (false: use the tree) for each point."""
        T = self.TILE
        fx = np.rint((px - self.x0) / self.step)
        fy = np.rint((py - self.y0) / self.step)
        tx, ty = np.floor_divide(fx, T), np.floor_divide(fy, T)
        inside = (tx >= 0) & (tx < self.ntx) & (ty >= 0) & (ty < self.nty)
        tid = np.where(inside, tx * self.nty + ty, 0).astype(np.int64)
        self.seen += np.bincount(tid[inside], minlength=self.seen.size)
        new = np.flatnonzero((self.seen >= max(self.payback_points, 1)) & (self.slot < 0))
        if new.size:
            self._add_tiles(new)
        sl = self.slot[tid]
        ok = inside & (sl >= 0)
        if not ok.any():  # no point on a computed tile: every start from the tree
            return np.zeros_like(px), np.zeros(px.shape, np.intp), ok
        k = np.where(ok, sl * (T * T) + (fx - tx * T) * T + (fy - ty * T), 0).astype(np.int64)
        near = ok & np.take(self.safe, k)
        ox = px - (self.x0 + fx * self.step)
        oy = py - (self.y0 + fy * self.step)
        s = np.take(self.s, k) + np.take(self.jx, k) * ox + np.take(self.jy, k) * oy
        return s, np.take(self.piece, k).astype(np.intp), near
