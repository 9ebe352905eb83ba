"""Time grids and trajectory bases: coefficient vector ``c`` → positions, velocities, accelerations.

A basis maps a coefficient vector ``c ∈ ℝⁿᵛᵃʳ`` (one per axis) to samples on a :class:`TimeGrid`::

    p = P @ c,   v = Pdot @ c,   a = Pddot @ c,   jerk = Pdddot @ c        (each (K,))

Two bases are provided, both *derivative-consistent* (``Pdot`` is exactly the time derivative of
``P``, and so on; tested):

* :class:`TripleIntegratorBasis` – the exact zero-order-hold discrete triple integrator, state
  ``(p, v, a)``, input jerk ``u`` constant over each step.  ``c = (p₀, v₀, a₀, u₀ … u_{K−2})``,
  ``nvar = K + 2`` (102 for the paper's K = 100).  The reference code's version drops the
  ``A⁰b`` term (which leaves a dead last column and a 1.5Δ² velocity error); this one does
  not.
* :class:`BernsteinBasis` – one polynomial of degree ``n`` over the whole horizon in Bernstein form,
  ``nvar = n + 1`` (11 for the default degree 10).  Few coefficients: the fast choice for
  batched projection.

Smoothness (both bases) is the **sum over the grid of squared jerk**, ``Σ_k jerk_k² = cᵀ S c`` with
``S = Pdddotᵀ Pdddot``.  For the triple integrator this is exactly ``Σ_{k=0}^{K−2} u_k²``, the
reference code's ``‖c‖²`` up to the constant ``p₀² + v₀² + a₀²`` fixed by the boundary equalities,
so the optimum is the same; for Bernstein it is the same quantity sampled at the K grid points.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import numpy as np

__all__ = ["TimeGrid", "Basis", "TripleIntegratorBasis", "BernsteinBasis", "make_basis"]


@dataclass(frozen=True)
class TimeGrid:
    """``K = num_steps`` equally spaced times ``t_k = k·Δ`` on ``[0, horizon]`` (ends included).

    ``Δ = horizon / (K − 1)``: for the paper's T = 15 s, K = 100 that is 0.151515… s, not 0.15.
    """

    horizon: float = 15.0
    num_steps: int = 100

    def __post_init__(self) -> None:
        if not (isinstance(self.num_steps, (int, np.integer)) and self.num_steps >= 4):
            raise ValueError(f"num_steps must be an integer ≥ 4, got {self.num_steps!r}")
        h = float(self.horizon)
        if not np.isfinite(h) or h <= 0:
            raise ValueError(
                f"horizon must be a positive finite number of seconds, got {self.horizon!r}"
            )
        object.__setattr__(self, "horizon", h)
        object.__setattr__(self, "num_steps", int(self.num_steps))

    @property
    def dt(self) -> float:
        return self.horizon / (self.num_steps - 1)

    @property
    def t(self) -> np.ndarray:
        """(K,) sample times in seconds."""
        return np.linspace(0.0, self.horizon, self.num_steps)


class Basis:
    """Common interface of the trajectory bases.

    Attributes
    ----------
    grid : TimeGrid
    P, Pdot, Pddot, Pdddot : (K, nvar) float64 arrays (read-only)
        Position, velocity, acceleration and jerk at the grid times.
    nvar : int
        Number of coefficients per axis.
    """

    name = "basis"
    grid: TimeGrid
    P: np.ndarray
    Pdot: np.ndarray
    Pddot: np.ndarray
    Pdddot: np.ndarray

    def _freeze(self) -> None:
        for M in (self.P, self.Pdot, self.Pddot, self.Pdddot):
            M.setflags(write=False)

    @property
    def nvar(self) -> int:
        return self.P.shape[1]

    @property
    def num_steps(self) -> int:
        return self.grid.num_steps

    def smoothness(self) -> np.ndarray:
        """(nvar, nvar) Hessian of the smoothness cost ``Σ_k jerk_k²`` (module docstring)."""
        return self.Pdddot.T @ self.Pdddot

    def boundary_rows(self, final_lateral_velocity: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Boundary-equality rows ``(A_eq_x (3, nvar), A_eq_y (3 or 4, nvar))``.

        ``A_eq_x c_x = (s₀, v_s0, a_s0)`` and ``A_eq_y c_y = (d₀, v_d0, a_d0[, 0])``: initial
        position, velocity and acceleration per axis, plus zero lateral velocity at the last step
        when ``final_lateral_velocity`` (the reference planner's and projection's ``ẏ_{K−1} = 0``).
        """
        rows = [self.P[0], self.Pdot[0], self.Pddot[0]]
        Ax = np.stack(rows)
        Ay = np.stack(rows + [self.Pdot[-1]]) if final_lateral_velocity else Ax.copy()
        return Ax, Ay

    def trajectory(self, c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities, accelerations ``(…, K)`` for coefficients ``c`` ``(…, nvar)``."""
        c = np.asarray(c, dtype=np.float64)
        if c.shape[-1] != self.nvar:
            raise ValueError(
                f"coefficients have last dimension {c.shape[-1]}, basis has nvar={self.nvar}"
            )
        return c @ self.P.T, c @ self.Pdot.T, c @ self.Pddot.T

    def fit(self, p: np.ndarray) -> np.ndarray:
        """Least-squares coefficients reproducing positions ``p`` (…, K) (used for comparisons)."""
        p = np.asarray(p, dtype=np.float64)
        sol, *_ = np.linalg.lstsq(self.P, p.reshape(-1, self.num_steps).T, rcond=None)
        return sol.T.reshape(*p.shape[:-1], self.nvar)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(grid={self.grid}, nvar={self.nvar})"


class TripleIntegratorBasis(Basis):
    """Exact discrete triple integrator (zero-order-hold jerk), ``c = (p₀, v₀, a₀, u₀ … u_{K−2})``.

    ``s_{k+1} = A s_k + b u_k`` with ``A = [[1, Δ, Δ²/2], [0, 1, Δ], [0, 0, 1]]`` and
    ``b = (Δ³/6, Δ²/2, Δ)``, so row ``k`` of ``[P; Pdot; Pddot]`` is
    ``[A^k | A^{k−1−j} b for j < k | 0]`` – the ``j = k − 1`` term (``b`` itself) included, unlike
    the reference code.  ``Pdddot`` row ``k`` selects ``u_k`` (rows ``k = 0 … K−2``; the last row is
    zero since no jerk acts after the last sample), so ``Σ jerk² = Σ_{k=0}^{K−2} u_k²``.
    The trajectory is a piecewise cubic, C² in time, and ``Pdot``/``Pddot`` are its exact
    derivatives at the grid times.
    """

    name = "triple_integrator"

    def __init__(self, grid: TimeGrid | None = None):
        self.grid = grid if grid is not None else TimeGrid()
        K, dt = self.grid.num_steps, self.grid.dt
        A = np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
        b = np.array([dt**3 / 6, dt * dt / 2, dt])
        n = K + 2
        M = np.zeros((K, 3, n))  # state map: s_k = M[k] @ c
        M[0, :, :3] = np.eye(3)
        for k in range(1, K):
            M[k] = A @ M[k - 1]
            M[k, :, 3 + k - 1] += b
        self.P, self.Pdot, self.Pddot = M[:, 0].copy(), M[:, 1].copy(), M[:, 2].copy()
        J = np.zeros((K, n))
        J[np.arange(K - 1), 3 + np.arange(K - 1)] = 1.0
        self.Pdddot = J
        self._freeze()

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, ...]:
        """``(P, Pdot, Pddot)`` rows at times ``t`` in ``[0, horizon]`` (piecewise cubic)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        dt, K = self.grid.dt, self.grid.num_steps
        k = np.clip(np.floor(t / dt).astype(int), 0, K - 2)
        tau = t - k * dt
        rows = []
        for kk, tt in zip(k, tau, strict=True):
            base = np.stack([self.P[kk], self.Pdot[kk], self.Pddot[kk]])
            u = np.zeros(self.nvar)
            u[3 + kk] = 1.0
            p = base[0] + tt * base[1] + tt**2 / 2 * base[2] + tt**3 / 6 * u
            v = base[1] + tt * base[2] + tt**2 / 2 * u
            a = base[2] + tt * u
            rows.append((p, v, a))
        return tuple(np.array([r[i] for r in rows]) for i in range(3))


def _bernstein(n: int, tau: np.ndarray, order: int = 0) -> np.ndarray:
    """``order``-th τ-derivative of the degree-``n`` Bernstein polynomials: (len(tau), n+1)."""
    tau = np.asarray(tau, dtype=np.float64)
    if order > n:
        return np.zeros((tau.size, n + 1))
    if order == 0:
        i = np.arange(n + 1)
        coef = np.array([comb(n, j) for j in i], dtype=np.float64)
        return coef * tau[:, None] ** i * (1.0 - tau[:, None]) ** (n - i)
    low = _bernstein(n - 1, tau, order - 1)  # d/dτ B_{i,n} = n (B_{i−1,n−1} − B_{i,n−1})
    out = np.zeros((tau.size, n + 1))
    out[:, 1:] += low
    out[:, :-1] -= low
    return n * out


class BernsteinBasis(Basis):
    """One polynomial of degree ``degree`` over ``[0, horizon]`` in Bernstein form.

    ``nvar = degree + 1``.

    ``p(t) = Σ_i c_i B_{i,n}(t/T)``; derivatives are exact (``d/dt = (1/T) d/dτ``).  The
    coefficients are the Bézier control points (metres), so their scale matches the positions.
    """

    name = "bernstein"

    def __init__(self, grid: TimeGrid | None = None, degree: int = 10):
        self.grid = grid if grid is not None else TimeGrid()
        if not (isinstance(degree, (int, np.integer)) and 3 <= degree <= 30):
            raise ValueError(f"degree must be an integer in [3, 30], got {degree!r}")
        self.degree = int(degree)
        self.P, self.Pdot, self.Pddot, self.Pdddot = self.evaluate(self.grid.t, with_jerk=True)
        self._freeze()

    def evaluate(self, t: np.ndarray, with_jerk: bool = False) -> tuple[np.ndarray, ...]:
        """``(P, Pdot, Pddot[, Pdddot])`` rows at arbitrary times ``t`` (seconds)."""
        T = self.grid.horizon
        tau = np.atleast_1d(np.asarray(t, dtype=np.float64)) / T
        orders = 4 if with_jerk else 3
        return tuple(_bernstein(self.degree, tau, o) / T**o for o in range(orders))

    def control_point_maps(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Matrices ``(I, D₁, D₂)`` giving the Bézier control points of ``p``, ``ṗ`` and ``p̈``.

        ``ṗ(t) = Σ_i (D₁c)_i B_{i,n−1}(t/T)`` with ``D₁c = n (c_{i+1} − c_i) / T``, likewise ``p̈``
        of degree ``n − 2``.  By the convex-hull property, bounds on these control points bound the
        trajectory at every instant of ``[0, T]``.
        """
        n, T = self.degree, self.grid.horizon
        eye = np.eye(n + 1)
        D1 = (eye[1:] - eye[:-1]) * n / T
        D2 = (D1[1:] - D1[:-1]) * (n - 1) / T
        return eye, D1, D2

    def __repr__(self) -> str:
        return f"BernsteinBasis(grid={self.grid}, degree={self.degree})"


def make_basis(kind: str = "bernstein", grid: TimeGrid | None = None, **kw) -> Basis:
    """A basis by name: ``"bernstein"`` (default, ``degree=``) or ``"triple_integrator"``."""
    if kind == "bernstein":
        return BernsteinBasis(grid, **kw)
    if kind in ("triple_integrator", "triple"):
        if kw:
            raise ValueError(f"triple_integrator takes no options, got {sorted(kw)}")
        return TripleIntegratorBasis(grid)
    raise ValueError(f"unknown basis {kind!r}; choose 'bernstein' or 'triple_integrator'")
