"""Reference paths and vectorised Cartesian ↔ Frenet conversion.

:class:`ReferencePath` is a C² cubic spline ``r(s) = (x(s), y(s))`` parameterised by arc length
``s ∈ [0, length]`` (metres), with heading ``θ(s)`` and signed curvature ``κ(s)`` (positive for
left turns).  Beyond its ends the path continues along its end tangents (straight lines), so every
point of the plane has a Frenet coordinate and obstacles that run past the end still convert.

Frenet coordinates: ``s`` (arc length of the nearest path point) and ``d`` (signed lateral offset,
positive to the left of the direction of travel): ``p = r(s) + d·n(s)``, ``n = (−sin θ, cos θ)``.
The nearest point is found by a proper projection – a k-d tree over densely sampled path points,
projection onto the two adjacent chords, then Newton's method on ``(r(s) − p)·r'(s) = 0`` – not a
brute-force scan; on a straight path (:meth:`ReferencePath.straight`, or collinear way-points in
order) it is the exact projection onto the line.  Round trips are exact to ~1e-9 m wherever the
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
        return cls(sx, sy, float(s[-1]), spacing, s, tree, waypoints, _straight_line(s, px, py))

    # ------------------------------------------------------------------ geometry
    def _eval(self, s: np.ndarray):
        """Position, first and second derivatives at ``s`` (flat), linear past the ends."""
        L = self.length
        sc = np.clip(s, 0.0, L)
        x, y = self._sx(sc), self._sy(sc)
        dx, dy = self._sx(sc, 1), self._sy(sc, 1)
        ddx, ddy = self._sx(sc, 2), self._sy(sc, 2)
        out = (s < 0.0) | (s > L)
        if np.any(out):
            nrm = np.hypot(dx, dy)
            tx, ty = dx / nrm, dy / nrm
            e = s - sc
            x = np.where(out, x + e * tx, x)
            y = np.where(out, y + e * ty, y)
            dx, dy = np.where(out, tx, dx), np.where(out, ty, dy)
            ddx, ddy = np.where(out, 0.0, ddx), np.where(out, 0.0, ddy)
        return x, y, dx, dy, ddx, ddy

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
        _, _, dx, dy, _, _ = self._eval(s.ravel())
        return np.arctan2(dy, dx).reshape(s.shape)

    def curvature(self, s: ArrayLike) -> NDArray[np.float64]:
        """Signed curvature ``κ(s)`` (1/m, positive turning left); zero beyond the ends."""
        s = _as_float("s", s)
        _check_finite("s", s)
        _, _, dx, dy, ddx, ddy = self._eval(s.ravel())
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
        s = self._coarse(px, py)
        # Newton on f(s) = (r(s) − p)·r'(s), on the points not yet converged only: a point
        # whose step fell below the tolerance stops there (its next steps would be smaller
        # still), so the few slow points do not make every point iterate
        step_cap = 2.0 * self.spacing
        stop = tol * max(1.0, self.length)
        at = np.arange(s.size)
        sa, qx, qy = s, px, py
        for _ in range(max_iter):
            rx, ry, dx, dy, ddx, ddy = self._eval(sa)
            ex, ey = rx - qx, ry - qy
            f = ex * dx + ey * dy
            g = dx * dx + dy * dy + ex * ddx + ey * ddy
            step = np.where(g > 0.05, -f / np.where(g > 0.05, g, 1.0), -f)
            step = np.clip(step, -step_cap, step_cap)
            sa = sa + step
            s[at] = sa
            going = np.abs(step) >= stop
            if not going.any():
                break
            if not going.all():
                at, sa, qx, qy = at[going], sa[going], qx[going], qy[going]
        rx, ry, dx, dy, _, _ = self._eval(s)
        nrm = np.hypot(dx, dy)
        d = ((px - rx) * (-dy) + (py - ry) * dx) / nrm
        s, d = s.reshape(shape), d.reshape(shape)
        if heading is None:
            return s, d
        return s, d, self._relative_heading(heading, shape, np.arctan2(dy, dx).reshape(shape))

    def to_frenet_points(
        self, xy: ArrayLike, s_offset: float = 0.0
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Cartesian points ``xy`` (..., 2) → Frenet ``s − s_offset`` and ``d``, each (...,).

        The same coordinates as :meth:`to_frenet` (to float rounding), for many points at once:
        on a straight path four multiply-adds per point with no check of its own (a caller
        converting blocks of a checked array), on a curved one :meth:`to_frenet`.
        """
        xy = np.asarray(xy, np.float64)
        if xy.ndim < 1 or xy.shape[-1] != 2:
            raise ValueError(f"xy must have shape (..., 2), got {xy.shape}")
        x, y = xy[..., 0], xy[..., 1]
        if self._line is None:
            s, d = self.to_frenet(x, y)
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

    def _coarse(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Initial arc length: nearest dense sample, then projection onto its two chords."""
        pts = self._tree.data
        n = len(pts)
        _, i = self._tree.query(np.column_stack([px, py]))
        best_s = np.zeros_like(px)
        best_d = np.full_like(px, np.inf)
        for lo in (i - 1, i):
            a = np.clip(lo, 0, n - 2)
            b = a + 1
            ax, ay = pts[a, 0], pts[a, 1]
            vx, vy = pts[b, 0] - ax, pts[b, 1] - ay
            L2 = vx * vx + vy * vy
            t = ((px - ax) * vx + (py - ay) * vy) / L2
            # stay on the chord, except past the path's ends (linear extension)
            t = np.clip(t, np.where(a == 0, -np.inf, 0.0), np.where(b == n - 1, np.inf, 1.0))
            dist = np.hypot(ax + t * vx - px, ay + t * vy - py)
            sa, sb = self._knots[a], self._knots[b]
            cand = sa + t * (sb - sa)
            better = dist < best_d
            best_s = np.where(better, cand, best_s)
            best_d = np.where(better, dist, best_d)
        return best_s

    def to_cartesian(
        self, s: ArrayLike, d: ArrayLike, heading: ArrayLike | None = None
    ) -> tuple[NDArray[np.float64], ...]:
        """Frenet → Cartesian for arrays of any broadcastable shape.

        Returns ``(x, y)`` or ``(x, y, heading_abs)`` when a path-relative ``heading`` is given.
        """
        s, d = _broadcast(("s", "d"), s, d)
        _check_finite("s/d", s, d)
        shape = s.shape
        rx, ry, dx, dy, _, _ = self._eval(s.ravel())
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
