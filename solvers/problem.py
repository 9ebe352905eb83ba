"""QP problem types in OSQP form.

``min ½ xᵀPx + qᵀx  s.t.  l ≤ Ax ≤ u``  (``±inf`` bounds allowed, ``l == u`` for equalities).

:class:`QP` is one problem; :class:`QPBatch` is many problems that share ``P`` and ``A`` and differ
in ``q``, ``l`` and ``u`` (what the Frenet projection produces).  Both validate their inputs on
construction: wrong shapes, NaN/inf in the matrices or in ``q``, NaN in the bounds and ``l > u``
raise :class:`ValueError` naming the argument.

From qpsolvers' form ``Gx ≤ h, Ax = b, lb ≤ x ≤ ub``: :meth:`QP.from_qpsolvers` for one problem,
:meth:`QPBatch.from_qpsolvers` for many sharing ``P``, ``G``, ``A`` (``q, h, b, lb, ub`` shared or
one row per QP); their errors name ``h``, ``lb``, ... as the user wrote them.  ``repr`` of either
is one line of sizes, never the arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from .errors import NonConvexError

__all__ = ["QP", "QPBatch", "INF", "BOUND_INF", "check_convex"]

INF = np.inf
#: magnitude at or above which a bound is treated as infinite (Maros–Meszaros uses 1e20)
BOUND_INF = 1e20

Matrix = np.ndarray | sp.spmatrix | sp.sparray


def real_array(v: Any, name: str) -> np.ndarray:
    """``v`` as a float64 array; complex, strings and other non-numbers raise ``ValueError``
    naming ``name`` (the caller's name for the argument).  Shared by every input check."""
    if not isinstance(name, str):
        raise ValueError(f"name must be a string, got {type(name).__name__}")
    a = np.asarray(v)
    if a.dtype.kind == "c":
        raise ValueError(
            f"{name} is complex (dtype {a.dtype}): a QP needs real data; the imaginary part is "
            "not dropped silently"
        )
    if a.dtype.kind == "O":
        try:
            a = a.astype(np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be numeric: {exc}") from None
    elif a.dtype.kind not in "biuf":
        raise ValueError(f"{name} must be numeric, got dtype {a.dtype} ({np.ravel(a)[:3]!r})")
    return a.astype(np.float64, copy=False)


def _as_matrix(M: Any, name: str, shape: tuple[int, int]) -> np.ndarray | sp.csc_matrix:
    if M is None:
        raise ValueError(f"{name} is required, got None")
    if sp.issparse(M):
        if M.dtype.kind == "c":
            raise ValueError(f"{name} is complex (dtype {M.dtype}): a QP needs real data")
        if M.dtype.kind not in "biuf":
            raise ValueError(f"{name} must be numeric, got dtype {M.dtype}")
        M = sp.csc_matrix(M, dtype=np.float64)
        data = M.data
    else:
        M = real_array(M, name)
        if M.ndim == 1 and shape[0] == 0:
            M = M.reshape(0, shape[1])
        data = M
    if M.shape != shape:
        raise ValueError(f"{name} has shape {M.shape}, expected {shape}")
    if not np.all(np.isfinite(data)):
        raise ValueError(f"{name} contains NaN or inf")
    return M


def _square_size(P: Any, name: str = "P") -> int:
    """``n`` from ``P``, which must be a square 2-D matrix: the size every other argument is
    checked against (so a ``q`` of the wrong length is reported as ``q``, not as ``P``)."""
    if P is None:
        raise ValueError(f"{name} is required, got None")
    shape = tuple(P.shape) if sp.issparse(P) else real_array(P, name).shape
    if len(shape) != 2 or shape[0] != shape[1]:
        raise ValueError(f"{name} has shape {shape}, expected a square (n, n) matrix")
    if shape[0] == 0:
        raise ValueError(f"{name} has shape {shape}: a QP needs at least one variable")
    return int(shape[0])


def _check_q_size(q: np.ndarray, n: int, expected: str) -> None:
    """``q``'s last axis against ``n`` (the size of ``P``); ``expected``: the shapes allowed."""
    if q.shape[-1] != n:
        raise ValueError(f"q has shape {q.shape}, expected {expected}: n = {n} is the size of P")


def _as_vector(v: Any, name: str, size: int, *, allow_inf: bool, batch: int | None = None):
    if v is None:
        raise ValueError(f"{name} is required, got None")
    v = real_array(v, name)
    shape = (size,) if batch is None else (batch, size)
    if v.shape != shape:
        raise ValueError(f"{name} has shape {v.shape}, expected {shape}")
    if np.any(np.isnan(v)):
        raise ValueError(f"{name} contains NaN")
    if not allow_inf and not np.all(np.isfinite(v)):
        raise ValueError(f"{name} contains inf")
    return v


#: how many offending indices an error message lists
_SHOWN = 5


def _where(bad: np.ndarray) -> str:
    """Where ``bad`` holds, for an error message: ``"index 3"`` or ``"indices [0, 4]"`` for one
    problem's vector; ``"index 1 of QP 0"`` or ``"(QP, index) [(0, 1), (2, 1)]"`` for a batch's
    ``(B, ·)`` array.  Plain ints; at most :data:`_SHOWN` listed, with the total when more."""
    bad = np.asarray(bad, dtype=bool)
    if bad.ndim <= 1:
        hits: list = np.flatnonzero(bad).tolist()
        one, many = f"index {hits[0]}" if hits else "", "indices"
    else:
        hits = [tuple(int(v) for v in row) for row in np.argwhere(bad)]
        one = f"index {hits[0][1]} of QP {hits[0][0]}" if hits else ""
        many = "(QP, index)"
    if len(hits) == 1:
        return one
    more = f" (first {_SHOWN} of {len(hits)})" if len(hits) > _SHOWN else ""
    return f"{many} {hits[:_SHOWN]}{more}"


def _values(bad: np.ndarray, **arrays: np.ndarray) -> str:
    """`` (l = 1, u = 0)``: the offending values when exactly one entry is bad, else ``""``."""
    bad = np.asarray(bad, dtype=bool)
    if int(bad.sum()) != 1:
        return ""
    parts = []
    for name, a in arrays.items():
        v = np.broadcast_to(np.asarray(a), bad.shape)[bad][0]
        parts.append(f"{name} = {float(v):g}")
    return f" ({', '.join(parts)})"


def _bounds(l: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Apply the 1e20 rule and check ``l ≤ u``; returns the bounds to store.

    A magnitude ≥ :data:`BOUND_INF` means "no bound" only in the direction of no bound (``l ≤
    −1e20`` → ``−inf``, ``u ≥ 1e20`` → ``+inf``) and never on a row with ``l == u``: a finite
    equality stays the number it is.  A lower bound of ``+inf`` or an upper bound of ``−inf``
    (an equality at infinity included) can never be met and is refused.
    """
    eq = l == u
    l = np.where((l <= -BOUND_INF) & ~eq, -np.inf, l)
    u = np.where((u >= BOUND_INF) & ~eq, np.inf, u)
    for name, bad, value, why in (
        ("l", l == np.inf, "+inf", "a lower bound of +inf can never be met"),
        ("u", u == -np.inf, "-inf", "an upper bound of -inf can never be met"),
    ):
        if np.any(bad):
            both = " (l == u == ±inf: an equality at infinity)" if np.any(eq & bad) else ""
            raise ValueError(f"{name} is {value} at {_where(bad)}: {why}{both}")
    bad = l > u
    if np.any(bad):
        raise ValueError(f"infeasible bounds: l > u at {_where(bad)}{_values(bad, l=l, u=u)}")
    return l, u


def _check_bounds(l: np.ndarray, u: np.ndarray) -> None:
    _bounds(l, u)


def _is_symmetric(P: np.ndarray | sp.csc_matrix) -> bool:
    D = P - P.T
    if sp.issparse(D):
        return D.nnz == 0 or float(abs(D).max()) <= 1e-9 * max(1.0, float(abs(P).max()))
    scale = max(1.0, float(np.max(np.abs(P), initial=0.0)))
    return bool(np.max(np.abs(D), initial=0.0) <= 1e-9 * scale)


#: P + ε·I must factor (Cholesky) with ε = PSD_RTOL·‖P‖∞: eigenvalues above −ε count as zero.
#: Matrices given to ~6 significant digits are PSD only to that precision: Maros–Meszaros VALUES
#: (entries printed with 6 decimals) has λ_min = −1.3e-5 at ‖P‖∞ = 10.9 and every solver reaches
#: its published optimum; diag(1, −1) (λ_min = −‖P‖∞) is refused.
PSD_RTOL = 1e-5
#: above this many variables a sparse P is checked by a sparse LDLᵀ-like LU instead of densified
_PSD_DENSE_MAX = 3000


def check_convex(P: Any, name: str = "P") -> None:
    """Raise :class:`~solvers.errors.NonConvexError` unless ``P`` is positive semidefinite.

    Cheap: a Cholesky factorisation of ``P + εI``, ``ε = 1e-5·‖P‖∞`` (max absolute row sum), so
    the negative eigenvalues that rounding of the data leaves in a PSD matrix pass (see
    :data:`PSD_RTOL`); on failure the smallest eigenvalue is reported.
    Sparse ``P`` with more than 3000 variables: an LU of ``P + εI`` without pivoting
    (``SymmetricMode``), whose pivots are positive exactly when ``P + εI`` is positive definite.
    """
    n = P.shape[0]
    if n == 0:
        return
    row_sums = abs(P).sum(axis=1) if sp.issparse(P) else np.abs(P).sum(axis=1)
    scale = float(np.max(row_sums))
    if scale == 0.0:
        return
    eps = PSD_RTOL * scale
    if sp.issparse(P) and n > _PSD_DENSE_MAX:
        import scipy.sparse.linalg as spla

        M = sp.csc_matrix(P) + eps * sp.identity(n, format="csc")
        try:
            lu = spla.splu(
                M,
                permc_spec="MMD_AT_PLUS_A",
                diag_pivot_thresh=0.0,
                options={"SymmetricMode": True},
            )
            ok = bool(np.all(lu.U.diagonal() > 0))
        except RuntimeError:  # exactly singular: not positive definite
            ok = False
        if not ok:
            raise NonConvexError(
                f"{name} is not positive semidefinite (P + {eps:.1e}·I has a non-positive "
                "pivot): the QP is non-convex and is refused; pass check_convex=False to skip "
                "this check"
            )
        return
    Pd = P.toarray() if sp.issparse(P) else np.asarray(P)
    try:
        np.linalg.cholesky(Pd + eps * np.eye(n))
        return
    except np.linalg.LinAlgError:
        pass
    lam = float(np.linalg.eigvalsh(0.5 * (Pd + Pd.T))[0])
    if lam >= -eps:  # Cholesky's rounding, not an indefinite P
        return
    raise NonConvexError(
        f"{name} is not positive semidefinite (smallest eigenvalue {lam:.3g}, ‖{name}‖∞ "
        f"{scale:.3g}): the QP is non-convex and is refused; pass check_convex=False to skip "
        "this check"
    )


def _from_qpsolvers_form(
    P: Any,
    q: Any,
    G: Any,
    h: Any,
    A: Any,
    b: Any,
    lb: Any,
    ub: Any,
    *,
    batched: bool,
    batch_size: int | None = None,
) -> tuple[Matrix, np.ndarray, np.ndarray, np.ndarray]:
    """qpsolvers' ``(P, q, G, h, A, b, lb, ub)`` as OSQP's ``(A, q, l, u)``, rows ``[G; A; I]``.

    ``batched=False``: ``q, h, b, lb, ub`` are 1-D and so are the returned ``q, l, u``.
    ``batched=True``: each of them is 1-D (shared) or ``(B, ·)`` (one row per QP); ``B`` is the
    common leading size (or ``batch_size``) and ``q, l, u`` come back as ``(B, ·)``.  Errors name
    the user's argument (``h``, ``lb``, ...), never the internal ``l``/``u``.
    """
    if q is None:
        raise ValueError("q is required, got None")
    q = real_array(q, "q")
    if not batched and (q.ndim != 1 or q.shape[0] == 0):
        raise ValueError(f"q must be a non-empty 1-D vector, got shape {q.shape}")
    if batched and (q.ndim not in (1, 2) or q.shape[-1] == 0):
        raise ValueError(
            f"q must have shape (n,) (shared by every QP) or (B, n) (one row per QP) with n ≥ 1, "
            f"got {q.shape}"
        )
    if P is None:  # QP(...) says "P is required"
        n = q.shape[-1]
    else:  # the size comes from P: q, G, A, lb, ub are checked against it
        n = _square_size(P, "P")
        shared = f"({n},) (shared by every QP) or (B, {n}) (one row per QP)"
        _check_q_size(q, n, shared if batched else f"({n},)")
    sizes: dict[str, int] = {}  # argument -> its leading batch size, for the per-QP ones
    if batched and q.ndim == 2:
        sizes["q"] = q.shape[0]

    def _rows(M: Any, name: str) -> sp.csc_matrix:
        if not sp.issparse(M):
            M = real_array(M, name)
            if M.ndim == 1:
                M = M.reshape(1, -1)
            if M.ndim != 2:
                shared = " shared by every QP" if batched else ""
                raise ValueError(f"{name} must be one 2-D matrix{shared}, got shape {M.shape}")
        M = _as_matrix(M, name, (M.shape[0], n))
        return sp.csc_matrix(M)

    def _rhs(v: Any, name: str, k: int) -> np.ndarray:
        v = real_array(v, name)
        if batched and v.ndim == 2:
            if v.shape[1] != k:
                raise ValueError(
                    f"{name} has shape {v.shape}, expected ({k},) (shared by every QP) or "
                    f"(B, {k}) (one row per QP)"
                )
            sizes[name] = v.shape[0]
        elif batched and v.ndim > 2:
            raise ValueError(
                f"{name} has shape {v.shape}, expected ({k},) (shared by every QP) or (B, {k}) "
                "(one row per QP)"
            )
        else:  # 1-D (or a scalar for one row); a single QP's column vector keeps its error
            v = _as_vector(v.reshape(-1) if v.ndim <= 1 else v, name, k, allow_inf=True)
        if np.any(np.isnan(v)):
            raise ValueError(f"{name} contains NaN")
        return v

    rows: list[sp.csc_matrix] = []
    rhs: list[tuple[str, np.ndarray, np.ndarray]] = []  # (argument, lower, upper)
    for M, v, Mname, vname in ((G, h, "G", "h"), (A, b, "A", "b")):
        if M is None and v is None:
            continue
        if M is None or v is None:
            given, missing = (Mname, vname) if v is None else (vname, Mname)
            raise ValueError(f"{missing} is required when {given} is given")
        Ms = _rows(M, Mname)
        vv = _rhs(v, vname, Ms.shape[0])
        if vname == "b" and not np.all(np.isfinite(vv)):
            raise ValueError("b contains inf: an equality at infinity can never be met")
        if vname == "h" and np.any(vv == -np.inf):
            raise ValueError(f"h is -inf at {_where(vv == -np.inf)}: G x ≤ -inf can never be met")
        rows.append(Ms)
        rhs.append((vname, np.full(vv.shape, -np.inf) if vname == "h" else vv, vv))
    if lb is not None or ub is not None:
        lbv = np.full(n, -np.inf) if lb is None else _rhs(lb, "lb", n)
        ubv = np.full(n, np.inf) if ub is None else _rhs(ub, "ub", n)
        for name, v, bad_value, what in (
            ("lb", lbv, np.inf, "x ≥ +inf"),
            ("ub", ubv, -np.inf, "x ≤ -inf"),
        ):
            if np.any(v == bad_value):
                raise ValueError(
                    f"{name} is {bad_value:+} at {_where(v == bad_value)}: {what} can never be met"
                )
        bad = lbv > ubv
        if np.any(bad):
            raise ValueError(f"lb > ub at {_where(bad)}{_values(bad, lb=lbv, ub=ubv)}")
        rows.append(sp.identity(n, format="csc"))
        rhs.append(("lb/ub", lbv, ubv))
    Acat = sp.vstack(rows, format="csc") if rows else sp.csc_matrix((0, n))
    if P is not None and not sp.issparse(P):
        Acat = Acat.toarray()
    if not batched:
        l = np.concatenate([lo for _, lo, _ in rhs]) if rhs else np.zeros(0)
        u = np.concatenate([hi for _, _, hi in rhs]) if rhs else np.zeros(0)
        return Acat, q, l, u
    B = _batch_size(sizes, batch_size)
    m = Acat.shape[0]
    q = np.broadcast_to(q, (B, n)).copy()
    l = np.concatenate([np.broadcast_to(lo, (B, lo.shape[-1])) for _, lo, _ in rhs], axis=1)
    u = np.concatenate([np.broadcast_to(hi, (B, hi.shape[-1])) for _, _, hi in rhs], axis=1)
    return Acat, q, l.reshape(B, m), u.reshape(B, m)


def _batch_size(sizes: dict[str, int], batch_size: int | None) -> int:
    """The common leading size ``B`` of the per-QP arguments ``sizes`` (argument -> size)."""
    if batch_size is not None:
        if isinstance(batch_size, bool) or not isinstance(batch_size, (int, np.integer)):
            raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
        if batch_size < 1:
            raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
        sizes = {"batch_size": int(batch_size), **sizes}
    if not sizes:
        raise ValueError(
            "none of q, h, b, lb, ub has a leading batch axis (shape (B, ·)): give at least one "
            "of them one row per QP, or pass batch_size=B to repeat one QP B times"
        )
    first, B = next(iter(sizes.items()))
    for name, k in sizes.items():
        if k != B:
            raise ValueError(
                f"{name} has {k} rows (one per QP) but {first} has {B}: every per-QP argument "
                "needs the same leading batch size"
            )
    if B == 0:
        raise ValueError(f"{first} has an empty batch axis: a batch needs at least one problem")
    return B


def _support(l: np.ndarray, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Elementwise ``u·max(y, 0) + l·min(y, 0)`` over the finite sides only (as qpsolvers'
    duality gap leaves out infinite ``lb``/``ub``); NaN where ``y`` is NaN."""
    up = np.where(np.isfinite(u), u, 0.0) * np.maximum(y, 0.0)
    lo = np.where(np.isfinite(l), l, 0.0) * np.minimum(y, 0.0)
    return up + lo


def _problem_repr(kind: str, p: Any) -> str:
    """One line: sizes, storage and the row kinds, never the arrays."""
    eq = int(np.sum(p.l == p.u))
    batch = f"B={p.l.shape[0]}, " if p.l.ndim == 2 else ""
    storage = "sparse" if (sp.issparse(p.P) or sp.issparse(p.A)) else "dense"
    rows = f" ({eq} equalities)" if eq and p.l.ndim == 1 else ""
    return f"{kind}({batch}n={p.n}, m={p.m}{rows}, {storage})"


@dataclass(frozen=True, eq=False)
class QP:
    """One convex QP ``min ½xᵀPx + qᵀx s.t. l ≤ Ax ≤ u`` (OSQP's form).

    Parameters
    ----------
    P : (n, n) symmetric positive semidefinite, dense or ``scipy.sparse``.
        If only the upper triangle is given (as some formats store it), pass ``P + P.T - diag(P)``.
    q : (n,)
    A : (m, n) dense or sparse; ``m`` may be 0.
    l, u : (m,) with ``-inf``/``+inf`` allowed and ``l ≤ u``; ``l == u`` makes an equality.
        ``l ≤ −1e20`` and ``u ≥ 1e20`` are read as infinite (never on a row with ``l == u``).
    check_convex : refuse a ``P`` that is not positive semidefinite with
        :class:`~solvers.errors.NonConvexError` (a Cholesky of ``P + εI``); ``False`` skips the
        check on large problems, at the caller's risk.

    Notes
    -----
    Every argument is validated on construction: wrong shapes, non-numeric or complex data,
    NaN/inf in the matrices or in ``q``, NaN in the bounds, ``l > u``, ``l = +inf``, ``u = −inf``
    raise :class:`ValueError` naming the argument.  The size ``n`` is ``P``'s (``P`` must be
    square) and ``m`` is ``A``'s number of rows; ``q``, ``A``'s columns and ``l``, ``u`` are checked
    against them, so the message names the argument that disagrees with ``P``.  Indices in
    messages are plain ints (``l > u at index 0 (l = 1, u = 0)``, ``at indices [0, 3]``).

    Examples
    --------
    >>> import numpy as np
    >>> from solvers import QP, solve
    >>> qp = QP(np.eye(2), [1.0, -1.0], np.eye(2), [-0.5, -0.5], [1.0, 1.0])
    >>> solve(qp, backend="clarabel").x.round(6)
    array([-0.5,  1. ])
    """

    P: Matrix
    q: np.ndarray
    A: Matrix
    l: np.ndarray
    u: np.ndarray
    check_convex: bool = True

    def __post_init__(self) -> None:
        if self.q is None:
            raise ValueError("q is required, got None")
        q = real_array(self.q, "q")
        if q.ndim != 1:
            raise ValueError(f"q must be 1-D, got shape {np.shape(q)}")
        if q.shape[0] == 0:
            raise ValueError("q is empty: a QP needs at least one variable")
        n = _square_size(self.P, "P")  # the QP's size comes from P; q is checked against it
        _check_q_size(q, n, f"({n},)")
        if self.A is None:
            raise ValueError("A is required (use np.zeros((0, n)) for no constraints), got None")
        A_shape = np.shape(self.A) if not sp.issparse(self.A) else self.A.shape
        if len(A_shape) == 1 and A_shape[0] == 0:
            A_shape = (0, n)
        if len(A_shape) != 2:
            raise ValueError(f"A must be 2-D, got shape {A_shape}")
        m = A_shape[0]
        object.__setattr__(self, "P", _as_matrix(self.P, "P", (n, n)))
        object.__setattr__(self, "q", _as_vector(q, "q", n, allow_inf=False))
        object.__setattr__(self, "A", _as_matrix(self.A, "A", (m, n)))
        l = _as_vector(self.l, "l", m, allow_inf=True)
        u = _as_vector(self.u, "u", m, allow_inf=True)
        l, u = _bounds(l, u)
        object.__setattr__(self, "l", l)
        object.__setattr__(self, "u", u)
        if not isinstance(self.check_convex, (bool, np.bool_)):
            raise ValueError(f"check_convex must be True or False, got {self.check_convex!r}")
        if not _is_symmetric(self.P):
            raise ValueError("P must be symmetric")
        if self.check_convex:
            check_convex(self.P)
        object.__setattr__(self, "_convex_checked", bool(self.check_convex))

    def ensure_convex(self) -> None:
        """Run the convexity check now if it was skipped at construction (cached)."""
        if not getattr(self, "_convex_checked", False):
            check_convex(self.P)
            object.__setattr__(self, "_convex_checked", True)

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

    def duality_gap(self, x: np.ndarray, y: np.ndarray) -> float:
        """``|xᵀPx + qᵀx + S(y)|`` with ``S(y) = Σ u_i·max(y_i, 0) + l_i·min(y_i, 0)``.

        Primal minus dual objective at ``(x, y)`` (OSQP's sign convention for ``y``), zero at an
        optimum: qpsolvers' ``Solution.duality_gap`` in this form (``h``, ``b``, ``lb``, ``ub``
        are the finite ``u``/``l`` of the rows ``[G; A; I]``).  Infinite sides are left out, as
        qpsolvers leaves out infinite ``lb``/``ub``; NaN in ``x`` or ``y`` gives NaN.
        """
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        return float(
            np.abs(x @ (self.P @ x) + self.q @ x + _support(self.l, self.u, y).sum(axis=-1))
        )

    def __repr__(self) -> str:
        return _problem_repr("QP", self)

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
        *,
        check_convex: bool = True,
    ) -> QP:
        """Build from qpsolvers' form ``min ½xᵀPx + qᵀx s.t. Gx ≤ h, Ax = b, lb ≤ x ≤ ub``.

        Rows are stacked as ``[G; A; I]`` with bounds ``(−inf, h)``, ``(b, b)``, ``(lb, ub)``.
        Dense ``P`` gives a dense ``A``; sparse ``P`` a CSC one.  Each argument is checked and
        named in errors (``G`` without ``h``, wrong lengths, NaN, complex data, ``h = -inf``,
        ``lb = +inf``, ``ub = -inf``, ``lb > ub``, ``b = ±inf``).  Many QPs that share ``P``,
        ``G`` and ``A``: :meth:`QPBatch.from_qpsolvers`.

        Example::

            >>> qp = QP.from_qpsolvers(np.eye(2), [1.0, -1.0], G=[[1.0, 1.0]], h=[0.5],
            ...                        lb=[-1.0, -1.0], ub=[1.0, 1.0])
            >>> qp.m  # one inequality row and two bound rows
            3
        """
        Acat, q, l, u = _from_qpsolvers_form(P, q, G, h, A, b, lb, ub, batched=False)
        return cls(P, q, Acat, l, u, check_convex=check_convex)

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
    Validated like :class:`QP` (``n`` from ``P``; ``check_convex`` included, once for the shared
    ``P``); a bad entry of a per-QP array is located as ``index i of QP k``.  From
    qpsolvers' form (shared ``P``, ``G``, ``A``; per-QP ``q, h, b, lb, ub``):
    :meth:`from_qpsolvers`.
    """

    P: Matrix
    A: Matrix
    q: np.ndarray
    l: np.ndarray
    u: np.ndarray
    check_convex: bool = True

    def __post_init__(self) -> None:
        if self.q is None:
            raise ValueError("q is required, got None")
        q = real_array(self.q, "q")
        if q.ndim != 2:
            raise ValueError(f"q must have shape (B, n) with a leading batch axis, got {q.shape}")
        B, n_q = q.shape
        if B == 0:
            raise ValueError("q has an empty batch axis: a batch needs at least one problem")
        if n_q == 0:
            raise ValueError("q has shape (B, 0): a QP needs at least one variable")
        n = _square_size(self.P, "P")  # the QPs' size comes from P; q is checked against it
        _check_q_size(q, n, f"({B}, {n})")
        if self.A is None:
            raise ValueError("A is required (use np.zeros((0, n)) for no constraints), got None")
        A_shape = self.A.shape if sp.issparse(self.A) else np.shape(self.A)
        if len(A_shape) != 2:
            raise ValueError(f"A must be 2-D, got shape {A_shape}")
        m = A_shape[0]
        object.__setattr__(self, "P", _as_matrix(self.P, "P", (n, n)))
        object.__setattr__(self, "A", _as_matrix(self.A, "A", (m, n)))
        object.__setattr__(self, "q", _as_vector(q, "q", n, allow_inf=False, batch=B))
        l = _as_vector(self.l, "l", m, allow_inf=True, batch=B)
        u = _as_vector(self.u, "u", m, allow_inf=True, batch=B)
        l, u = _bounds(l, u)
        object.__setattr__(self, "l", l)
        object.__setattr__(self, "u", u)
        if not isinstance(self.check_convex, (bool, np.bool_)):
            raise ValueError(f"check_convex must be True or False, got {self.check_convex!r}")
        if not _is_symmetric(self.P):
            raise ValueError("P must be symmetric")
        if self.check_convex:
            check_convex(self.P)
        object.__setattr__(self, "_convex_checked", bool(self.check_convex))

    def ensure_convex(self) -> None:
        """Run the convexity check now if it was skipped at construction (cached)."""
        if not getattr(self, "_convex_checked", False):
            check_convex(self.P)
            object.__setattr__(self, "_convex_checked", True)

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
        # P was checked (or the check skipped) for the whole batch: not again per problem
        qp = QP(self.P, self.q[i], self.A, self.l[i], self.u[i], check_convex=False)
        object.__setattr__(qp, "_convex_checked", getattr(self, "_convex_checked", False))
        return qp

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
            if (
                P.shape != P0.shape
                or A.shape != A0.shape
                or not (np.array_equal(P, P0) and np.array_equal(A, A0))
            ):
                raise ValueError(f"qps[{i}] does not share P and A with qps[0]")
        return cls(
            qps[0].P,
            qps[0].A,
            np.stack([qp.q for qp in qps]),
            np.stack([qp.l for qp in qps]),
            np.stack([qp.u for qp in qps]),
            check_convex=qps[0].check_convex,
        )

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
        *,
        batch_size: int | None = None,
        check_convex: bool = True,
    ) -> QPBatch:
        """Many QPs in qpsolvers' form ``min ½xᵀPx + qᵀx s.t. Gx ≤ h, Ax = b, lb ≤ x ≤ ub``.

        ``P``, ``G`` and ``A`` are shared (one matrix each, dense or ``scipy.sparse``); each of
        ``q``, ``h``, ``b``, ``lb``, ``ub`` is either shared (1-D) or one row per QP, shape
        ``(B, ·)``.  ``B`` is inferred from the per-QP arguments (they must agree); when all are
        shared, pass ``batch_size=B``.  Rows are stacked as in :meth:`QP.from_qpsolvers`, so
        ``batch[i]`` is ``QP.from_qpsolvers`` of the ``i``-th rows.  Errors name the argument
        (``h``, ``lb``, ...): wrong lengths, mismatched ``B``, ``h = -inf``, ``lb > ub``, ...

        Example::

            >>> qs = np.array([[1.0, -1.0], [-1.0, 1.0], [0.0, 0.0]])      # B = 3
            >>> batch = QPBatch.from_qpsolvers(np.eye(2), qs, G=[[1.0, 1.0]], h=[0.5],
            ...                                lb=[-1.0, -1.0], ub=[1.0, 1.0])
            >>> batch.batch_size, batch.m
            (3, 3)
        """
        Acat, q, l, u = _from_qpsolvers_form(
            P, q, G, h, A, b, lb, ub, batched=True, batch_size=batch_size
        )
        return cls(P, Acat, q, l, u, check_convex=check_convex)

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

    def duality_gap(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Per-problem :meth:`QP.duality_gap` for ``x`` (B, n), ``y`` (B, m)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        xPx = np.einsum("bi,bi->b", x, (self.P @ x.T).T)
        qx = np.einsum("bi,bi->b", self.q, x)
        return np.abs(xPx + qx + _support(self.l, self.u, y).sum(axis=-1))

    def __repr__(self) -> str:
        return _problem_repr("QPBatch", self)
