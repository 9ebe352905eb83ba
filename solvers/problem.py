"""QP problem types in OSQP form.

``min ½ xᵀPx + qᵀx  s.t.  l ≤ Ax ≤ u``  (``±inf`` bounds allowed, ``l == u`` for equalities).

:class:`QP` is one problem; :class:`QPBatch` is many problems that share ``P`` and ``A`` and differ
in ``q``, ``l`` and ``u`` (what the Frenet projection produces).  Both validate their inputs on
construction: wrong shapes, NaN/inf in the matrices or in ``q``, NaN in the bounds and ``l > u``
raise :class:`ValueError` naming the argument.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

__all__ = ["QP", "QPBatch", "INF"]

INF = np.inf
#: magnitude at or above which a bound is treated as infinite (Maros–Meszaros uses 1e20)
BOUND_INF = 1e20

Matrix = np.ndarray | sp.spmatrix | sp.sparray


def _as_matrix(M: Any, name: str, shape: tuple[int, int]) -> np.ndarray | sp.csc_matrix:
    if sp.issparse(M):
        M = sp.csc_matrix(M, dtype=np.float64)
        data = M.data
    else:
        try:
            M = np.asarray(M, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be a numeric matrix: {exc}") from None
        if M.ndim == 1 and shape[0] == 0:
            M = M.reshape(0, shape[1])
        data = M
    if M.shape != shape:
        raise ValueError(f"{name} has shape {M.shape}, expected {shape}")
    if not np.all(np.isfinite(data)):
        raise ValueError(f"{name} contains NaN or inf")
    return M


def _as_vector(v: Any, name: str, size: int, *, allow_inf: bool, batch: int | None = None):
    try:
        v = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric: {exc}") from None
    shape = (size,) if batch is None else (batch, size)
    if v.shape != shape:
        raise ValueError(f"{name} has shape {v.shape}, expected {shape}")
    if np.any(np.isnan(v)):
        raise ValueError(f"{name} contains NaN")
    if not allow_inf and not np.all(np.isfinite(v)):
        raise ValueError(f"{name} contains inf")
    if allow_inf:
        v = np.where(v >= BOUND_INF, np.inf, np.where(v <= -BOUND_INF, -np.inf, v))
    return v


def _check_bounds(l: np.ndarray, u: np.ndarray) -> None:
    bad = l > u
    if np.any(bad):
        idx = np.argwhere(bad)[:5].tolist()
        raise ValueError(f"infeasible bounds: l > u at index {idx} (first 5 shown)")


def _is_symmetric(P: np.ndarray | sp.csc_matrix) -> bool:
    D = P - P.T
    if sp.issparse(D):
        return D.nnz == 0 or float(abs(D).max()) <= 1e-9 * max(1.0, float(abs(P).max()))
    scale = max(1.0, float(np.max(np.abs(P), initial=0.0)))
    return bool(np.max(np.abs(D), initial=0.0) <= 1e-9 * scale)


@dataclass(frozen=True, eq=False)
class QP:
    """One convex QP ``min ½xᵀPx + qᵀx s.t. l ≤ Ax ≤ u``.

    Parameters
    ----------
    P : (n, n) symmetric positive semidefinite, dense or ``scipy.sparse``.
        If only the upper triangle is given (as some formats store it), pass ``P + P.T - diag(P)``.
    q : (n,)
    A : (m, n) dense or sparse; ``m`` may be 0.
    l, u : (m,) with ``-inf``/``+inf`` allowed and ``l ≤ u``.  Magnitudes ≥ 1e20 are read as inf.
    """

    P: Matrix
    q: np.ndarray
    A: Matrix
    l: np.ndarray
    u: np.ndarray

    def __post_init__(self) -> None:
        q = np.asarray(self.q, dtype=np.float64) if not isinstance(self.q, np.ndarray) else self.q
        if q.ndim != 1:
            raise ValueError(f"q must be 1-D, got shape {np.shape(q)}")
        n = q.shape[0]
        if n == 0:
            raise ValueError("q is empty: a QP needs at least one variable")
        A_shape = np.shape(self.A) if not sp.issparse(self.A) else self.A.shape
        if len(A_shape) == 1 and A_shape[0] == 0:
            A_shape = (0, n)
        if len(A_shape) != 2:
            raise ValueError(f"A must be 2-D, got shape {A_shape}")
        m = A_shape[0]
        object.__setattr__(self, "P", _as_matrix(self.P, "P", (n, n)))
        object.__setattr__(self, "q", _as_vector(self.q, "q", n, allow_inf=False))
        object.__setattr__(self, "A", _as_matrix(self.A, "A", (m, n)))
        l = _as_vector(self.l, "l", m, allow_inf=True)
        u = _as_vector(self.u, "u", m, allow_inf=True)
        _check_bounds(l, u)
        object.__setattr__(self, "l", l)
        object.__setattr__(self, "u", u)
        if not _is_symmetric(self.P):
            raise ValueError("P must be symmetric")

    # ------------------------------------------------------------------ sizes
    @property
    def n(self) -> int:
        """Number of variables."""
        return self.q.shape[0]

    @property
    def m(self) -> int:
        """Number of constraint rows."""
        return self.l.shape[0]

    @property
    def is_sparse(self) -> bool:
        return sp.issparse(self.P) or sp.issparse(self.A)

    def dense(self) -> tuple[np.ndarray, np.ndarray]:
        """``(P, A)`` as dense arrays."""
        P = self.P.toarray() if sp.issparse(self.P) else self.P
        A = self.A.toarray() if sp.issparse(self.A) else self.A
        return P, A

    def sparse(self) -> tuple[sp.csc_matrix, sp.csc_matrix]:
        """``(P, A)`` as CSC matrices."""
        return sp.csc_matrix(self.P), sp.csc_matrix(self.A)

    # ---------------------------------------------------------- evaluations
    def objective(self, x: np.ndarray) -> float:
        """``½xᵀPx + qᵀx``."""
        x = np.asarray(x, dtype=np.float64)
        return float(0.5 * x @ (self.P @ x) + self.q @ x)

    def constraint_violation(self, x: np.ndarray) -> float:
        """``max(0, max(l - Ax), max(Ax - u))`` (∞-norm of the bound violation)."""
        if self.m == 0:
            return 0.0
        Ax = self.A @ np.asarray(x, dtype=np.float64)
        return float(max(0.0, np.max(self.l - Ax), np.max(Ax - self.u)))

    primal_residual = constraint_violation

    def dual_residual(self, x: np.ndarray, y: np.ndarray) -> float:
        """``‖Px + q + Aᵀy‖∞`` (stationarity of the Lagrangian, OSQP sign convention)."""
        x = np.asarray(x, dtype=np.float64)
        r = self.P @ x + self.q
        if self.m:
            r = r + self.A.T @ np.asarray(y, dtype=np.float64)
        return float(np.max(np.abs(r)))

    # -------------------------------------------------------------- formats
    @classmethod
    def from_qpsolvers(
        cls,
        P: Matrix,
        q: np.ndarray,
        G: Matrix | None = None,
        h: np.ndarray | None = None,
        A: Matrix | None = None,
        b: np.ndarray | None = None,
        lb: np.ndarray | None = None,
        ub: np.ndarray | None = None,
    ) -> QP:
        """Build from the qpsolvers form ``Gx ≤ h, Ax = b, lb ≤ x ≤ ub``."""
        q = np.asarray(q, dtype=np.float64)
        n = q.shape[0]
        rows, lo, hi = [], [], []
        if G is not None:
            if h is None:
                raise ValueError("h is required when G is given")
            G = sp.csc_matrix(G)
            rows.append(G)
            h = np.asarray(h, dtype=np.float64).reshape(-1)
            lo.append(np.full(h.shape, -np.inf))
            hi.append(h)
        if A is not None:
            if b is None:
                raise ValueError("b is required when A is given")
            A = sp.csc_matrix(A)
            b = np.asarray(b, dtype=np.float64).reshape(-1)
            rows.append(A)
            lo.append(b)
            hi.append(b)
        if lb is not None or ub is not None:
            lbv = np.full(n, -np.inf) if lb is None else np.asarray(lb, dtype=np.float64)
            ubv = np.full(n, np.inf) if ub is None else np.asarray(ub, dtype=np.float64)
            rows.append(sp.identity(n, format="csc"))
            lo.append(lbv)
            hi.append(ubv)
        Acat = sp.vstack(rows, format="csc") if rows else sp.csc_matrix((0, n))
        l = np.concatenate(lo) if lo else np.zeros(0)
        u = np.concatenate(hi) if hi else np.zeros(0)
        dense = not sp.issparse(P)
        if dense:
            Acat = Acat.toarray()
        return cls(P, q, Acat, l, u)

    def to_qpsolvers(self) -> dict[str, Any]:
        """Return the qpsolvers form as a dict with keys ``P, q, G, h, A, b, lb, ub``.

        Rows with ``l == u`` become equalities; finite sides of the other rows become ``Gx ≤ h``
        (a lower bound ``l ≤ aᵀx`` becomes ``-aᵀx ≤ -l``).  ``lb``/``ub`` are left ``None``.
        Dense input gives dense output, sparse gives CSC.
        """
        P, A = self.sparse()
        eq = self.l == self.u
        up = ~eq & np.isfinite(self.u)
        lo = ~eq & np.isfinite(self.l)
        G = sp.vstack([A[up], -A[lo]], format="csc")
        h = np.concatenate([self.u[up], -self.l[lo]])
        Aeq = A[eq]
        beq = self.u[eq]
        if not self.is_sparse:
            P, G, Aeq = P.toarray(), G.toarray(), Aeq.toarray()
        return {
            "P": P,
            "q": self.q.copy(),
            "G": G if G.shape[0] else None,
            "h": h if G.shape[0] else None,
            "A": Aeq if Aeq.shape[0] else None,
            "b": beq if Aeq.shape[0] else None,
            "lb": None,
            "ub": None,
        }

    def to_clarabel(self) -> tuple[sp.csc_matrix, np.ndarray, sp.csc_matrix, np.ndarray, list]:
        """Clarabel's cone form ``(P_triu, q, A_cone, b, cones)``.

        Clarabel solves ``min ½xᵀPx + qᵀx s.t. A_cone x + s = b, s ∈ K``.  Rows are ordered
        equalities (ZeroCone), then upper bounds ``Ax ≤ u`` and lower bounds ``-Ax ≤ -l``
        (NonnegativeCone).  Returns the cone *sizes* as ``[("zero", k), ("nonneg", k)]`` so this
        module does not import clarabel; :mod:`solvers.clarabel_` turns them into cone objects.
        Use :meth:`clarabel_row_map` to map cone duals back to the OSQP ``y``.
        """
        P, A = self.sparse()
        eq, up, lo = self._clarabel_rows()
        A_cone = sp.vstack([A[eq], A[up], -A[lo]], format="csc")
        b = np.concatenate([self.u[eq], self.u[up], -self.l[lo]])
        cones = [("zero", int(eq.sum())), ("nonneg", int(up.sum() + lo.sum()))]
        return sp.triu(P, format="csc"), self.q.copy(), A_cone, b, cones

    def _clarabel_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        eq = self.l == self.u
        up = ~eq & np.isfinite(self.u)
        lo = ~eq & np.isfinite(self.l)
        return eq, up, lo

    def clarabel_row_map(self, z: np.ndarray) -> np.ndarray:
        """Map Clarabel's cone dual ``z`` (ordered as :meth:`to_clarabel`) to OSQP's ``y``.

        OSQP convention: ``y > 0`` on an active upper bound, ``y < 0`` on an active lower bound,
        and ``Px + q + Aᵀy = 0``.
        """
        eq, up, lo = self._clarabel_rows()
        ne, nu = int(eq.sum()), int(up.sum())
        y = np.zeros(self.m)
        y[eq] = z[:ne]
        y[up] += z[ne : ne + nu]
        y[lo] -= z[ne + nu :]
        return y


@dataclass(frozen=True, eq=False)
class QPBatch:
    """Many QPs sharing ``P`` (n, n) and ``A`` (m, n); per-problem ``q`` (B, n), ``l``/``u`` (B, m).

    Iterating or indexing yields :class:`QP` objects, so any backend can loop over a batch.
    """

    P: Matrix
    A: Matrix
    q: np.ndarray
    l: np.ndarray
    u: np.ndarray

    def __post_init__(self) -> None:
        q = np.asarray(self.q, dtype=np.float64)
        if q.ndim != 2:
            raise ValueError(f"q must have shape (B, n) with a leading batch axis, got {q.shape}")
        B, n = q.shape
        if B == 0:
            raise ValueError("q has an empty batch axis: a batch needs at least one problem")
        A_shape = self.A.shape if sp.issparse(self.A) else np.shape(self.A)
        if len(A_shape) != 2:
            raise ValueError(f"A must be 2-D, got shape {A_shape}")
        m = A_shape[0]
        object.__setattr__(self, "P", _as_matrix(self.P, "P", (n, n)))
        object.__setattr__(self, "A", _as_matrix(self.A, "A", (m, n)))
        object.__setattr__(self, "q", _as_vector(q, "q", n, allow_inf=False, batch=B))
        l = _as_vector(self.l, "l", m, allow_inf=True, batch=B)
        u = _as_vector(self.u, "u", m, allow_inf=True, batch=B)
        _check_bounds(l, u)
        object.__setattr__(self, "l", l)
        object.__setattr__(self, "u", u)
        if not _is_symmetric(self.P):
            raise ValueError("P must be symmetric")

    @property
    def batch_size(self) -> int:
        return self.q.shape[0]

    @property
    def n(self) -> int:
        return self.q.shape[1]

    @property
    def m(self) -> int:
        return self.l.shape[1]

    def __len__(self) -> int:
        return self.batch_size

    def __getitem__(self, i: int) -> QP:
        return QP(self.P, self.q[i], self.A, self.l[i], self.u[i])

    def __iter__(self):
        for i in range(self.batch_size):
            yield self[i]

    def dense(self) -> tuple[np.ndarray, np.ndarray]:
        P = self.P.toarray() if sp.issparse(self.P) else self.P
        A = self.A.toarray() if sp.issparse(self.A) else self.A
        return P, A

    @classmethod
    def from_qps(cls, qps: list[QP]) -> QPBatch:
        """Stack QPs that share ``P`` and ``A`` (checked) into a batch."""
        if not qps:
            raise ValueError("qps is empty")
        P0, A0 = qps[0].dense()
        for i, qp in enumerate(qps[1:], 1):
            P, A = qp.dense()
            if P.shape != P0.shape or A.shape != A0.shape or not (
                np.array_equal(P, P0) and np.array_equal(A, A0)
            ):
                raise ValueError(f"qps[{i}] does not share P and A with qps[0]")
        return cls(
            qps[0].P,
            qps[0].A,
            np.stack([qp.q for qp in qps]),
            np.stack([qp.l for qp in qps]),
            np.stack([qp.u for qp in qps]),
        )

    def objective(self, x: np.ndarray) -> np.ndarray:
        """Per-problem objective ``½xᵀPx + qᵀx`` for ``x`` of shape (B, n)."""
        x = np.asarray(x, dtype=np.float64)
        Px = (self.P @ x.T).T
        return 0.5 * np.einsum("bi,bi->b", x, Px) + np.einsum("bi,bi->b", self.q, x)

    def constraint_violation(self, x: np.ndarray) -> np.ndarray:
        """Per-problem ∞-norm bound violation for ``x`` of shape (B, n)."""
        if self.m == 0:
            return np.zeros(self.batch_size)
        Ax = (self.A @ np.asarray(x, dtype=np.float64).T).T
        v = np.maximum(self.l - Ax, Ax - self.u)
        return np.maximum(0.0, v.max(axis=1))

    primal_residual = constraint_violation

    def dual_residual(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Per-problem ``‖Px + q + Aᵀy‖∞``."""
        x = np.asarray(x, dtype=np.float64)
        r = (self.P @ x.T).T + self.q
        if self.m:
            r = r + (self.A.T @ np.asarray(y, dtype=np.float64).T).T
        return np.abs(r).max(axis=1)
