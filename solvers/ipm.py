"""Batched primal–dual interior-point QP solver in JAX (backend name ``"ipm"``).

Solves many QPs ``min ½xᵀPx + qᵀx  s.t.  l ≤ Ax ≤ u`` that share ``P`` and ``A`` and differ in
``q, l, u`` (a :class:`solvers.QPBatch`), in float64, one jitted call for the whole batch (``vmap``
over the QPs of a chunk, ``lax.map`` over chunks of ``chunk_size``; no Python loop over QPs).

Method
------
* Rows are classified per QP from its own ``l, u``: equalities (``l == u``), lower and/or upper
  inequalities (finite sides), free rows (both sides infinite; ignored).  Inequality sides get
  slacks ``s_l = Ax − l ≥ 0``, ``s_u = u − Ax ≥ 0`` with multipliers ``z_l, z_u ≥ 0``; equalities a
  free multiplier ``y_e``.  The returned ``y = z_u − z_l + y_e`` follows OSQP's convention
  (``Px + q + Aᵀy = 0``, ``y ≥ 0`` on active upper bounds), like every other backend.
* Infeasible-start primal–dual path following with Mehrotra's predictor–corrector.  Each Newton
  system is reduced to the condensed (normal-equations) matrix
  ``M = P + ρI + Aᵀ diag(z_l/s_l + z_u/s_u + 1/δ on equalities) A`` (n × n), factored once per
  iteration by Cholesky and reused by the predictor, the corrector and iterative refinement
  against the unregularised KKT system (the static regularisations ρ, δ are removed by it).
* ``P``, ``A`` are shared: their Ruiz equilibration, the bandwidth-reducing (reverse
  Cuthill–McKee) ordering of ``P + AᵀA`` and the gather tables that assemble ``M`` are computed once
  on the host (:func:`ipm_setup`).  When that ordering leaves ``M`` banded (half-bandwidth ``w``
  small against ``n``, as on trajectory projections), ``M`` is assembled in band storage from the
  nonzeros of ``A`` only and factored by a banded Cholesky (``O(n w²)`` per QP); otherwise dense
  (``O(n³)``, LAPACK).  The band assembly groups the rows of ``A`` by their first column
  (:func:`_slot_tables`: shifted slices, one small gather) when that pads ``m`` by at most 4×,
  else it gathers per band entry.  Products with ``A``, ``Aᵀ`` are dense batched matmuls (on a
  CPU XLA runs them faster than products over the nonzeros, slices or gathers, at these sizes;
  they are a small part of an iteration), ``P`` in band storage when banded.
* A batch passed to the backend drops the rows that are free in every one of its QPs before the
  setup (their multipliers are 0).
* Termination on the unscaled problem, per QP: ``SOLVED`` when the bound violation, the dual
  residual ``‖Px + q + Aᵀy‖∞`` and the duality gap ``|xᵀPx + qᵀx + S(y)|`` (``S`` the support
  function of ``[l, u]``) meet ``eps_abs + eps_rel · scale``; ``PRIMAL_INFEASIBLE`` /
  ``DUAL_INFEASIBLE`` from the usual certificates on the last step (``δy`` with ``Aᵀδy ≈ 0``,
  ``S(δy) < 0``; ``δx`` with ``Pδx ≈ 0``, ``qᵀδx < 0``, ``Aδx`` in the recession cone), checked in
  float64; ``MAX_ITER``; ``ERROR`` on NaN.  A finished QP is frozen while the rest of its chunk
  goes on.  Tolerances, ``max_iter``, the step fraction and the regularisations are array leaves
  of the setup pytree (changing them does not recompile).

Backend use
-----------
::

    from solvers import solve, solve_batch
    sol = solve_batch(batch, backend="ipm", eps_abs=1e-9, eps_rel=1e-9)

Settings are the fields of :class:`IPMSettings` (unknown names raise ``ValueError``); the settings
used are in ``sol.settings``, and ``sol.extras`` holds the linear-solver kind, the bandwidth, the
setup / compile / solve times.

Functional core (jittable)
--------------------------
::

    from solvers.ipm import IPMSettings, ipm_setup, ipm_iterate, ipm_solve

    with jax.enable_x64(True):
        setup = ipm_setup(P, A, IPMSettings())          # NumPy, once per (P, A)
        res = jax.jit(ipm_iterate)(setup, q, l, u)      # q (B, n), l, u (B, m); or 1-D
        res = ipm_solve(P, A, q, l, u, IPMSettings())   # the two in one call

:func:`ipm_iterate` is pure JAX (usable inside your own ``jit``/``vmap``; ``P``/``A`` enter through
the :class:`IPMSetup` pytree, whose arrays are leaves and whose structure is static) and returns an
:class:`IPMResult`.  It needs JAX's x64 mode (``with jax.enable_x64(True):`` around the trace and
the call; it raises otherwise) — this module never switches x64 on globally.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jax import lax
from scipy.sparse.csgraph import reverse_cuthill_mckee

from .base import Backend
from .cache import BoundedCache
from .problem import QP, QPBatch
from .scaling import ruiz_equilibrate
from .settings import SettingsSpec
from .solution import RUNNING_CODE, STATUS_CODES, BatchSolution, Solution, Status

__all__ = [
    "IPMSettings",
    "IPMSetup",
    "IPMResult",
    "IPMBackend",
    "ipm_setup",
    "ipm_iterate",
    "ipm_solve",
    "make_backend",
]


@dataclass(frozen=True)
class IPMSettings:
    """Settings of the ``ipm`` backend.

    Attributes
    ----------
    eps_abs, eps_rel : termination on the unscaled problem: bound violation ≤ ``eps_abs +
        eps_rel·max(‖Ax‖∞, ‖Π(Ax)‖∞)``, ``‖Px + q + Aᵀy‖∞ ≤ eps_abs + eps_rel·max(‖Px‖∞, ‖Aᵀy‖∞,
        ‖q‖∞)`` and duality gap ≤ ``eps_abs + eps_rel·min(max(|f_primal|, |f_dual|),
        max(|xᵀPx|, |qᵀx|, |S(y)|))``: a ``SOLVED`` meets ``Solution.is_optimal(eps_abs,
        eps_rel)`` (OSQP's scales), and ``is_optimal(eps_abs)`` when ``eps_rel = 0``.
    eps_prim_inf, eps_dual_inf : relative tolerances of the infeasibility certificates.
    max_iter : interior-point iterations per QP.
    step_fraction : fraction of the step to the boundary taken (``α = min(1, τ·α_max)``).
    reg_primal, reg_dual : static regularisations ρ (on ``P``) and δ (on equality rows) of the
        condensed matrix, in the scaled problem; removed by ``refine_iter`` refinement steps.
    refine_iter : iterative-refinement steps per linear solve.
    scaling_iter : Ruiz equilibration passes on ``[P Aᵀ; A 0]`` (0: none).
    linear_solver : ``"auto"``, ``"dense"`` or ``"banded"`` (see the module docstring).
    band_ratio : ``"auto"`` picks the banded Cholesky when the half-bandwidth ``w`` after RCM
        ordering satisfies ``w + 1 ≤ band_ratio · n`` and ``n ≥ 32``.
    shifted_start : the starting slacks and multipliers by Mehrotra's uniform shifts (``True``),
        or the older rule (``False``): slacks floored per row at ``min(1, half the row's width)``,
        multipliers from the penalty estimate clipped at 0.  The shifted start takes fewer
        iterations on families with tight rows (narrow ``[l, u]``, as jerk bounds are); the floored
        one is the default of the differentiable :func:`solvers.jax.solve_qp`, whose active-set
        rule reads the final iterate (see its docstring).
    chunk_size : a batch larger than this is solved in chunks of this many QPs, one after the
        other inside the same jitted call (``lax.map`` over ``vmap``-ed chunks): each chunk stops
        at its own slowest QP, and its iterates stay in cache.  ``None``: one chunk.
    """

    eps_abs: float = 1e-9
    eps_rel: float = 1e-9
    eps_prim_inf: float = 1e-7
    eps_dual_inf: float = 1e-7
    max_iter: int = 100
    step_fraction: float = 0.995
    reg_primal: float = 1e-10
    reg_dual: float = 1e-8
    refine_iter: int = 1
    scaling_iter: int = 10
    linear_solver: str = "auto"
    band_ratio: float = 0.2
    shifted_start: bool = True
    chunk_size: int | None = 32

    def __post_init__(self) -> None:
        # every real-valued setting is a real number before any comparison (a string or None
        # would otherwise fail inside NumPy with a message that does not name the setting)
        for name in (
            "eps_abs", "eps_rel", "eps_prim_inf", "eps_dual_inf", "step_fraction", "reg_primal",
            "reg_dual", "band_ratio",
        ):  # fmt: skip
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating):
                raise ValueError(f"{name} must be a real number, got {v!r}")
        if not isinstance(self.linear_solver, str) or self.linear_solver not in (
            "auto",
            "dense",
            "banded",
        ):
            raise ValueError(
                f"linear_solver must be 'auto', 'dense' or 'banded', got {self.linear_solver!r}"
            )
        if not (isinstance(self.max_iter, (int, np.integer)) and self.max_iter >= 1):
            raise ValueError(f"max_iter must be an integer ≥ 1, got {self.max_iter!r}")
        if not (0.0 < self.step_fraction < 1.0):
            raise ValueError(f"step_fraction must be in (0, 1), got {self.step_fraction!r}")
        for name in ("eps_abs", "eps_rel", "eps_prim_inf", "eps_dual_inf"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and ≥ 0, got {v!r}")
        if self.eps_abs == 0 and self.eps_rel == 0:
            raise ValueError("eps_abs and eps_rel cannot both be 0")
        for name in ("reg_primal", "reg_dual"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")
        for name in ("refine_iter", "scaling_iter"):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and v >= 0):
                raise ValueError(f"{name} must be an integer ≥ 0, got {v!r}")
        if not isinstance(self.shifted_start, (bool, np.bool_)):
            raise ValueError(f"shifted_start must be True or False, got {self.shifted_start!r}")
        if self.chunk_size is not None and not (
            isinstance(self.chunk_size, (int, np.integer)) and self.chunk_size >= 1
        ):
            raise ValueError(f"chunk_size must be None or an integer ≥ 1, got {self.chunk_size!r}")
        if not (0.0 < self.band_ratio <= 1.0):
            raise ValueError(f"band_ratio must be in (0, 1], got {self.band_ratio!r}")

    @classmethod
    def from_kwargs(cls, **kwargs: Any) -> IPMSettings:
        """Build from keyword arguments; unknown names raise ``ValueError`` naming them."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(kwargs) - names)
        if unknown:
            raise ValueError(
                f"unknown ipm setting(s) {unknown}; valid names: {', '.join(sorted(names))}"
            )
        return cls(**kwargs)

    def replace(self, **kwargs: Any) -> IPMSettings:
        return dataclasses.replace(self, **kwargs)

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


# ------------------------------------------------------------------------------- setup (host)
@jax.tree_util.register_pytree_node_class
@dataclass(frozen=True, eq=False)
class IPMSetup:
    """Scaled, reordered shared data of :func:`ipm_iterate` (a pytree; structure is static).

    Scaled problem in the permuted variable order ``perm``: ``P̄ = c·D P D``, ``Ā = E A D``,
    ``q̄ = c·D q``, ``l̄ = E l``, ``ū = E u``; ``x = D x̄``, ``y = E ȳ / c``.
    """

    arrays: dict[str, Any]
    kind: str  # "dense" or "banded"
    width: int  # half-bandwidth w of M in the permuted order (n − 1 for dense)
    n: int
    m: int
    refine_iter: int
    chunk_size: int | None = None
    #: the settings it was made with (host side only: not part of the pytree)
    settings: IPMSettings | None = None

    def tree_flatten(self):
        # tolerances, max_iter, step fraction and regularisations are the array leaf "params":
        # changing them does not recompile; only the structure is static
        keys = tuple(sorted(self.arrays))
        aux = (keys, self.kind, self.width, self.n, self.m, self.refine_iter, self.chunk_size)
        return tuple(self.arrays[k] for k in keys), aux

    @classmethod
    def tree_unflatten(cls, aux, leaves):
        keys, kind, width, n, m, refine_iter, chunk = aux
        return cls(dict(zip(keys, leaves, strict=True)), kind, width, n, m, refine_iter, chunk)

    def with_settings(self, settings: IPMSettings) -> IPMSetup:
        """The same shared data with another set of tunables (no new factorisation tables)."""
        arrays = {**self.arrays, "params": tunable_params(settings)}
        return IPMSetup(
            arrays,
            self.kind,
            self.width,
            self.n,
            self.m,
            settings.refine_iter,
            settings.chunk_size,
            settings,
        )


#: settings passed to the iteration as array leaves (in this order)
_TUNABLE = (
    "eps_abs",
    "eps_rel",
    "eps_prim_inf",
    "eps_dual_inf",
    "max_iter",
    "step_fraction",
    "reg_primal",
    "reg_dual",
    "shifted_start",
)


def tunable_params(s: IPMSettings) -> np.ndarray:
    """The tunable settings (tolerances, ``max_iter``, step fraction, regularisations) as the
    float64 vector the iteration reads, the setup's ``"params"`` leaf: an array, so that changing
    them does not recompile."""
    if not isinstance(s, IPMSettings):
        raise ValueError(f"s must be an IPMSettings, got {type(s).__name__}")
    return np.array([float(getattr(s, k)) for k in _TUNABLE], dtype=np.float64)


def _band_tables(Ps: np.ndarray, As: np.ndarray, w: int):
    """Gather tables assembling ``M = P̄ + Āᵀ diag(d) Ā`` in band storage ``Mb[j, k] = M[j+k, j]``.

    Returns ``(Pb (n, w+1), coef (n, w+1, T), rows (n, w+1, T))``; ``rows == m`` points at a zero.
    """
    n, m = Ps.shape[0], As.shape[0]
    Pb = np.zeros((n, w + 1))
    for k in range(w + 1):
        Pb[: n - k, k] = np.diagonal(Ps, -k)
    lists: dict[tuple[int, int], list[tuple[int, float]]] = {}
    for r in range(m):
        (cols,) = np.nonzero(As[r])
        for ia, a in enumerate(cols):
            for b in cols[: ia + 1]:  # a ≥ b
                lists.setdefault((int(b), int(a - b)), []).append((r, As[r, a] * As[r, b]))
    T = max(1, max((len(v) for v in lists.values()), default=1))
    coef = np.zeros((n, w + 1, T))
    rows = np.full((n, w + 1, T), m, np.int32)
    for (j, k), lst in lists.items():
        for t, (r, v) in enumerate(lst):
            rows[j, k, t] = r
            coef[j, k, t] = v
    return Pb, coef, rows


def _slot_tables(Ap: np.ndarray, max_pad: float = 4.0) -> dict[str, np.ndarray] | None:
    """Rows of ``Ā`` (permuted columns) regrouped by their first nonzero column, to assemble the
    band of ``M = P̄ + Āᵀ diag(d) Ā`` with slices instead of a gather per band entry.

    Row ``i`` starting at column ``j`` with span ``≤ s`` goes to slot ``t·n + j`` (``t`` its rank
    among the rows starting at ``j``, ``t < R``), with values ``V[k, t, j] = Ā[i, j + k]`` (``n``
    the minor axis, so that the work vectorises along it).  Then band column ``a − b`` of ``M``
    gets ``Σ_t V[a, t, c − b] V[b, t, c − b] d[t, c − b]`` at row ``c``: one term per pair
    ``b ≤ a < s``, stored shifted (``VV``).  ``d`` reaches the slots by one gather of ``n·R``
    entries (unused slots read a zero).  Returns ``None`` when the slots would pad ``m`` by
    more than ``max_pad``.
    """
    m, n = Ap.shape
    if m == 0:
        return None
    nz = Ap != 0
    has = nz.any(axis=1)
    start = np.where(has, nz.argmax(axis=1), 0)
    last = np.where(has, n - 1 - nz[:, ::-1].argmax(axis=1), 0)
    span = int(np.max(last - start + 1, initial=1))
    cnt = np.bincount(start, minlength=n)
    R = int(max(1, cnt.max()))
    if n * R > max_pad * m:
        return None
    order = np.argsort(start, kind="stable")
    first = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    rank = np.empty(m, np.int64)
    rank[order] = np.arange(m) - first[start[order]]
    slot = rank * n + start  # slot of each row
    row_of_slot = np.full(n * R, m, np.int64)  # m: an unused slot
    row_of_slot[slot] = np.arange(m)
    V = np.zeros((span, R, n))
    for k in range(span):
        cols = start + k
        ok = cols < n
        V[k, rank[ok], start[ok]] = Ap[np.nonzero(ok)[0], cols[ok]]
    pairs = [(a, b) for a in range(span) for b in range(a + 1)]

    def shifted(v: np.ndarray, k: int) -> np.ndarray:  # out[..., c] = v[..., c − k]
        out = np.zeros_like(v)
        out[..., k:] = v[..., : n - k]
        return out

    # M's terms at the column they land on: VV[p, t, c] = V[a, t, c − b] V[b, t, c − b]
    VV = np.stack([shifted(V[a] * V[b], b) for a, b in pairs])
    return {"slot_VV": VV, "row_of_slot": row_of_slot.astype(np.int32)}


def ipm_setup(P: Any, A: Any, settings: IPMSettings | None = None) -> IPMSetup:
    """Precompute the shared data for :func:`ipm_iterate` (NumPy, float64), once per ``P, A``.

    Parameters
    ----------
    P : (n, n) symmetric positive semidefinite, dense or ``scipy.sparse``.
    A : (m, n) dense or sparse; ``m`` may be 0.
    settings : :class:`IPMSettings` (defaults if ``None``).
    """
    s = settings if settings is not None else IPMSettings()
    if not isinstance(s, IPMSettings):
        raise TypeError(f"settings must be an IPMSettings, got {type(s).__name__}")
    P = np.asarray(P.toarray() if sp.issparse(P) else P, dtype=np.float64)
    A = np.asarray(A.toarray() if sp.issparse(A) else A, dtype=np.float64)
    if P.ndim != 2 or P.shape[0] != P.shape[1] or P.shape[0] == 0:
        raise ValueError(f"P must be a non-empty square matrix, got shape {P.shape}")
    n = P.shape[0]
    if A.size == 0:
        A = A.reshape(0, n)
    if A.ndim != 2 or A.shape[1] != n:
        raise ValueError(f"A must have shape (m, {n}), got {A.shape}")
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(A))):
        raise ValueError("P and A must be finite (no NaN or inf)")
    if np.max(np.abs(P - P.T), initial=0.0) > 1e-9 * max(1.0, np.max(np.abs(P), initial=0.0)):
        raise ValueError("P must be symmetric")
    m = A.shape[0]
    D, E, c = ruiz_equilibrate(P, A, s.scaling_iter)
    Ps = c * D[:, None] * P * D[None, :]
    As = E[:, None] * A * D[None, :]
    # bandwidth-reducing order of the pattern of M = P + AᵀA (shared by every QP and iteration)
    pat = sp.csr_matrix((np.abs(Ps) + np.abs(As).T @ np.abs(As)) != 0)
    perm = np.asarray(reverse_cuthill_mckee(pat, symmetric_mode=True), np.int64)
    Pp, Ap, Dp = Ps[np.ix_(perm, perm)], As[:, perm], D[perm]
    patp = np.abs(Pp) + np.abs(Ap).T @ np.abs(Ap)
    ii, jj = np.nonzero(patp)
    w = int(np.max(np.abs(ii - jj), initial=0))
    kind = s.linear_solver
    if kind == "auto":
        kind = "banded" if (n >= 32 and w + 1 <= s.band_ratio * n) else "dense"
    if kind == "dense":
        w = n - 1
    arrays: dict[str, Any] = {
        "P": Pp,
        "A": Ap,
        "D": Dp,
        "E": E,
        "c": np.asarray(c),
        "perm": perm.astype(np.int32),
        "iperm": np.argsort(perm).astype(np.int32),
        "params": tunable_params(s),
    }
    if kind == "banded":
        slots = _slot_tables(Ap)
        if slots is None:  # rows too uneven for slots: gather tables for M, dense products
            Pb, coef, rows = _band_tables(Pp, Ap, w)
            arrays["band_P"], arrays["band_coef"], arrays["band_rows"] = Pb, coef, rows
        else:
            arrays["band_P"] = _band_tables(Pp, Ap[:0], w)[0]
            arrays.update(slots)
    return IPMSetup(arrays, kind, w, n, m, s.refine_iter, s.chunk_size, s)


# ------------------------------------------------------------------------- linear algebra (JAX)
def _band_cholesky(Mb, w: int, piv_min: float, piv_reg: float):
    """Cholesky ``M = LLᵀ`` of one SPD band matrix ``Mb[j, k] = M[j+k, j]`` (n, w+1).

    Right-looking, one column per scan step with a (w × w) window of the trailing matrix; returns
    ``Lb[j, k] = L[j+k, j]``.  Pivots below ``piv_min`` are replaced by ``piv_reg`` (dynamic
    regularisation; the refinement of the caller accounts for it).
    """
    n = Mb.shape[0]
    if w == 0:
        return jnp.sqrt(jnp.where(Mb > piv_min, Mb, piv_reg))
    pad = jnp.concatenate([Mb, jnp.zeros((w, w + 1), Mb.dtype).at[:, 0].set(1.0)], axis=0)
    i = jnp.arange(w)
    # entering column of step j: M[j+i, j+w] = Mb[j+i, w−i] (i < w) and M[j+w, j+w]
    C = pad[jnp.arange(n)[:, None] + i[None, :], (w - i)[None, :]]  # (n, w)
    dnew = pad[w : w + n, 0]
    a, b = jnp.maximum(i[:, None], i[None, :]), jnp.minimum(i[:, None], i[None, :])
    S0 = pad[b, a - b]  # M[0:w, 0:w]

    def step(S, cd):
        c, d = cd
        W = jnp.concatenate(
            [jnp.concatenate([S, c[:, None]], axis=1), jnp.concatenate([c, d[None]])[None]],
            axis=0,
        )
        piv = W[0, 0]
        piv = jnp.where(piv > piv_min, piv, piv_reg)
        l0 = jnp.sqrt(piv)
        col = W[1:, 0] / l0
        return W[1:, 1:] - col[:, None] * col[None, :], jnp.concatenate([l0[None], col])

    _, Lb = lax.scan(step, S0, (C, dnew), unroll=4)
    return Lb


def _band_solve(Lb, b, w: int):
    """Solve ``L Lᵀ x = b`` with the band factor of :func:`_band_cholesky`."""
    n = Lb.shape[0]
    if w == 0:
        return b / (Lb[:, 0] * Lb[:, 0])
    i = jnp.arange(w)
    # row j of L left of the diagonal: L[j, j−w+i] = Lb[j−w+i, w−i] (zero for j−w+i < 0)
    src = jnp.arange(n)[:, None] - w + i[None, :]
    R = jnp.where(src >= 0, Lb[jnp.clip(src, 0), (w - i)[None, :]], 0.0)  # (n, w)
    diag = Lb[:, 0]

    def fwd(zw, rdb):  # z_j = (b_j − Σ_k L[j, j−k] z_{j−k}) / L[j, j]
        r, dj, bj = rdb
        zj = (bj - r @ zw) / dj
        return jnp.concatenate([zw[1:], zj[None]]), zj

    _, z = lax.scan(fwd, jnp.zeros(w, b.dtype), (R, diag, b), unroll=4)

    def bwd(xw, ldz):  # x_j = (z_j − Σ_k L[j+k, j] x_{j+k}) / L[j, j]
        lrow, dj, zj = ldz
        xj = (zj - lrow @ xw) / dj
        return jnp.concatenate([xj[None], xw[:-1]]), xj

    _, x = lax.scan(bwd, jnp.zeros(w, b.dtype), (Lb[:, 1:], diag, z), reverse=True, unroll=4)
    return x


# --------------------------------------------------------------------------- the iteration (JAX)
class IPMResult(NamedTuple):
    """Result of :func:`ipm_iterate` (unscaled, original variable order; leading batch axis).

    x (B, n), y (B, m) in OSQP's sign convention, status (B,) int :class:`Status` codes,
    iterations (B,), prim_res (B,) max bound violation, dual_res (B,) ``‖Px + q + Aᵀy‖∞``,
    gap (B,) duality gap, objective (B,) ``½xᵀPx + qᵀx``.
    """

    x: Any
    y: Any
    status: Any
    iterations: Any
    prim_res: Any
    dual_res: Any
    gap: Any
    objective: Any


def _inf_norm(v):
    return jnp.max(jnp.abs(v), initial=0.0)


class _Params(NamedTuple):
    """The tunables of :data:`_TUNABLE` as traced scalars (array leaves of the setup)."""

    eps_abs: Any
    eps_rel: Any
    eps_pinf: Any
    eps_dinf: Any
    max_iter: Any
    tau: Any  # step fraction
    rho: Any  # static primal regularisation ρ
    delta: Any  # static dual regularisation δ (equality rows)
    shifted: Any  # 1.0: Mehrotra's shifted start, 0.0: the floored one


class _Scaling(NamedTuple):
    """Ruiz scaling ``x = D x̄``, ``y = E ȳ / c`` and the inverses of ``D``, ``E``."""

    D: Any
    E: Any
    c: Any
    Dinv: Any
    Einv: Any


class _Rows(NamedTuple):
    """Row classes of one QP, from its own ``l̄, ū`` (the ``f*`` masks are float64 0/1)."""

    fin_l: Any  # bool: finite lower side
    fin_u: Any  # bool: finite upper side
    eq: Any  # bool: equality row (l == u)
    fl: Any  # lower inequality side (slack s_l, multiplier z_l)
    fu: Any  # upper inequality side (slack s_u, multiplier z_u)
    fe: Any  # equality (free multiplier y_e)
    lf: Any  # l with its infinite entries zeroed
    uf: Any  # u with its infinite entries zeroed
    n_ineq: Any  # number of inequality sides (at least 1)


def _classify_rows(l, u) -> _Rows:
    f64 = jnp.float64
    fin_l, fin_u = jnp.isfinite(l), jnp.isfinite(u)
    eq = fin_l & fin_u & (l == u)
    fl = (fin_l & ~eq).astype(f64)
    fu = (fin_u & ~eq).astype(f64)
    fe = eq.astype(f64)
    lf = jnp.where(fin_l, l, 0.0)
    uf = jnp.where(fin_u, u, 0.0)
    n_ineq = jnp.maximum(jnp.sum(fl) + jnp.sum(fu), 1.0)
    return _Rows(fin_l, fin_u, eq, fl, fu, fe, lf, uf, n_ineq)


class _LinAlg(NamedTuple):
    """Products with the shared scaled matrices and the condensed matrix's factor and solve."""

    Amul: Callable  # x ↦ Āx
    ATmul: Callable  # y ↦ Āᵀy
    Pmul: Callable  # x ↦ P̄x
    factor: Callable  # d ↦ Cholesky factor of M = P̄ + ρI + Āᵀ diag(d) Ā
    msolve: Callable  # (factor, r) ↦ M⁻¹r


def _linear_algebra(st: IPMSetup, rho) -> _LinAlg:
    """The closures of :class:`_LinAlg` for ``st``'s linear solver (banded or dense)."""
    ar, n, w, f64 = st.arrays, st.n, st.width, jnp.float64
    Ad, Pd = ar["A"], ar["P"]

    # (dense products: under vmap XLA's batched matmul beats gathers over the nonzeros of A on
    # CPU, measured 2.4 vs 6.6 ms for 200 QPs of the two-axis family)
    def Amul(x):
        return Ad @ x

    def ATmul(y):
        return y @ Ad

    def Pmul(x):
        return Pd @ x

    if "slot_VV" in ar:
        return _slot_linear_algebra(st, rho)
    if st.kind == "banded":
        Pb, coef, rows = ar["band_P"], ar["band_coef"], ar["band_rows"]

        def factor(d):
            dd = jnp.concatenate([d, jnp.zeros(1, f64)])
            Mb = Pb + jnp.sum(coef * dd[rows], axis=-1)
            Mb = Mb.at[:, 0].add(rho)
            return _band_cholesky(Mb, w, 1e-13, 1e-8)

        def msolve(L, r):
            return _band_solve(L, r, w)
    else:

        def factor(d):
            M = Pd + Ad.T @ (d[:, None] * Ad) + rho * jnp.eye(n, dtype=f64)
            return jnp.linalg.cholesky(M)

        def msolve(L, r):
            t = jax.scipy.linalg.solve_triangular(L, r, lower=True)
            return jax.scipy.linalg.solve_triangular(L, t, lower=True, trans="T")

    return _LinAlg(Amul, ATmul, Pmul, factor, msolve)


def _shift(v, k: int):
    """``out[c] = v[c − k]`` (zero for ``c < k``), along the first axis."""
    if k == 0:
        return v
    return jnp.concatenate([jnp.zeros((k, *v.shape[1:]), v.dtype), v[: v.shape[0] - k]])


def _slot_linear_algebra(st: IPMSetup, rho) -> _LinAlg:
    """Banded ``M`` assembled from the slots of :func:`_slot_tables` (one gather of ``d`` to the
    slots, then shifted slices), ``P̄`` applied in band storage; ``Ā`` and ``Āᵀ`` by the dense
    batched matmul, which XLA's CPU backend runs faster than any product over the nonzeros that
    was tried (slices over the slots, gathers: see docs/experiments/qp-backends.md)."""
    ar, n, w, f64 = st.arrays, st.n, st.width, jnp.float64
    Ad, VV, Pb = ar["A"], ar["slot_VV"], ar["band_P"]
    R = VV.shape[1]
    span = int(round((np.sqrt(8 * VV.shape[0] + 1) - 1) / 2))  # pairs = span(span+1)/2
    pairs = [(a, b) for a in range(span) for b in range(a + 1)]

    def Amul(x):
        return Ad @ x

    def ATmul(y):
        return y @ Ad

    def left_padded(v):  # (R·n,) → (R, n + span − 1), v at columns span − 1 …
        return jnp.concatenate([jnp.zeros((R, span - 1), f64), v.reshape(R, n)], axis=1)

    def Pmul(x):
        xe = jnp.concatenate([x, jnp.zeros(w, f64)])
        out = sum(Pb[:, k] * xe[k : k + n] for k in range(w + 1))  # on and below the diagonal
        return out + sum(_shift(Pb[:, k] * x, k) for k in range(1, w + 1))

    def factor(d):
        # d to the slots (a gather of n·R entries; the gather tables of _band_tables had
        # n·(w+1)·T), then M's band columns from shifted slices
        d = jnp.concatenate([d, jnp.zeros(1, f64)])[ar["row_of_slot"]]
        De, o = left_padded(d), span - 1
        terms: list[list[Any]] = [[] for _ in range(w + 1)]
        for p, (a, b) in enumerate(pairs):  # a row at j: Ā[·, j+a] Ā[·, j+b] → M[j+a, j+b]
            terms[a - b].append(VV[p] * De[:, o - b : o - b + n])
        cols = [
            Pb[:, k] + (jnp.sum(sum(terms[k]), axis=0) if terms[k] else 0.0) for k in range(w + 1)
        ]
        cols[0] = cols[0] + rho
        return _band_cholesky(jnp.stack(cols, axis=1), w, 1e-13, 1e-8)

    def msolve(L, r):
        return _band_solve(L, r, w)

    return _LinAlg(Amul, ATmul, Pmul, factor, msolve)


class _QP(NamedTuple):
    """One scaled QP as the iteration reads it."""

    q: Any  # (n,) q̄
    l: Any  # (m,) l̄
    u: Any  # (m,) ū
    n: int
    m: int
    refine_iter: int
    prm: _Params
    sc: _Scaling
    rows: _Rows
    la: _LinAlg


class _Carry(NamedTuple):
    """Loop state of one QP (scaled iterates, products, iteration count, last check)."""

    x: Any
    sl: Any
    su: Any
    zl: Any
    zu: Any
    ye: Any
    Ax: Any
    Px: Any
    ATy: Any
    it: Any
    status: Any
    prim: Any
    dual: Any
    gap: Any


def _kkt_solve(qp: _QP, L, dI, r1, r2):
    """Solve [H Aₑᵀ; Aₑ 0](dx, dyₑ) = (r1, r2), H = P + Aᵀ diag(dI) A.

    The regularised solve (M = H + ρI + AₑᵀAₑ/δ, dyₑ = (Aₑdx − r2)/δ), then iterative
    refinement on the unregularised system with the same factor.  Returns (dx, dyₑ, A dx).
    """
    la, fe, delta = qp.la, qp.rows.fe, qp.prm.delta
    dx = la.msolve(L, r1 + la.ATmul(fe * r2) / delta)
    Adx = la.Amul(dx)
    dye = fe * (Adx - r2) / delta

    def refine(_, c_):
        dx, dye, Adx = c_
        e2 = fe * (r2 - Adx)
        e = r1 - la.Pmul(dx) - la.ATmul(dI * Adx + fe * dye - e2 / delta)
        cx = la.msolve(L, e)
        Acx = la.Amul(cx)
        return dx + cx, dye + fe * (Acx - e2) / delta, Adx + Acx

    return lax.fori_loop(0, qp.refine_iter, refine, (dx, dye, Adx))


# ---- unscaled residuals, termination and certificates (float64)
def _termination(qp: _QP, x, y, Ax, Px, ATy):
    """Bound violation, dual residual and duality gap on the unscaled problem, and whether all
    three meet their tolerances.  Returns ``(solved, prim, dual, gap)``."""
    p, sc, r = qp.prm, qp.sc, qp.rows
    Dinv, Einv, c, q = sc.Dinv, sc.Einv, sc.c, qp.q
    Ax_u = Einv * Ax
    l_u, u_u = Einv * qp.l, Einv * qp.u
    viol = jnp.maximum(jnp.maximum(l_u - Ax_u, Ax_u - u_u), 0.0)
    prim = _inf_norm(viol)
    proj = jnp.clip(Ax_u, l_u, u_u)
    eps_p = p.eps_abs + p.eps_rel * jnp.maximum(_inf_norm(Ax_u), _inf_norm(proj))
    Px_u, ATy_u, q_u = Dinv * Px / c, Dinv * ATy / c, Dinv * q / c
    dual = _inf_norm(Px_u + q_u + ATy_u)
    eps_d = p.eps_abs + p.eps_rel * jnp.maximum(
        jnp.maximum(_inf_norm(Px_u), _inf_norm(ATy_u)), _inf_norm(q_u)
    )
    xPx, qx = x @ Px / c, q @ x / c
    supp = jnp.sum(jnp.where(y > 0, r.uf * y, r.lf * y)) / c  # S(y): support function of [l, u]
    pobj, dobj = 0.5 * xPx + qx, -0.5 * xPx - supp
    gap = jnp.abs(pobj - dobj)
    # relative to the objectives, and never looser than OSQP's scale (that of
    # Solution.is_optimal): a SOLVED meets is_optimal(eps_abs, eps_rel)
    g_osqp = jnp.maximum(jnp.maximum(jnp.abs(xPx), jnp.abs(qx)), jnp.abs(supp))
    eps_g = p.eps_abs + p.eps_rel * jnp.minimum(jnp.maximum(jnp.abs(pobj), jnp.abs(dobj)), g_osqp)
    solved = (prim <= eps_p) & (dual <= eps_d) & (gap <= eps_g)
    return solved, prim, dual, gap


def _primal_infeasible(qp: _QP, dys, ATdy):
    """δy (sign-projected on the finite sides) with Aᵀδy ≈ 0 and S(δy) < 0."""
    sc, r, eps_pinf = qp.sc, qp.rows, qp.prm.eps_pinf
    dy_u = sc.E * dys / sc.c
    keep = jnp.where(r.fin_u, True, dy_u <= 0) & jnp.where(r.fin_l, True, dy_u >= 0)
    ndy = _inf_norm(dy_u)
    ATdy_n = _inf_norm(sc.Dinv * ATdy / sc.c)
    supp_dy = jnp.sum(jnp.where(dy_u > 0, r.uf, r.lf) * sc.Einv * dy_u)
    return (
        jnp.all(keep) & (ndy > 1e-300) & (ATdy_n <= eps_pinf * ndy) & (supp_dy <= -eps_pinf * ndy)
    )


def _dual_infeasible(qp: _QP, dxs, Adx, Pdx):
    """δx with Pδx ≈ 0, qᵀδx < 0 and Aδx in the recession cone of [l, u]."""
    sc, r = qp.sc, qp.rows
    ndx = _inf_norm(sc.D * dxs)
    tol = qp.prm.eps_dinf * ndx
    Adx_u = sc.Einv * Adx
    cone = jnp.all(jnp.where(r.fin_u, Adx_u <= tol, True) & jnp.where(r.fin_l, Adx_u >= -tol, True))
    return (
        (ndx > 1e-300)
        & (_inf_norm(sc.Dinv * Pdx / sc.c) <= tol)
        & (qp.q @ dxs / sc.c <= -tol)
        & cone
    )


def _check(qp: _QP, x, y, Ax, Px, ATy, dxs, dys, Adx, Pdx, ATdy, it):
    """Status after a step (``dxs, dys`` and the products with them: the step itself, for the
    infeasibility certificates).  Returns ``(status, prim, dual, gap)``."""
    solved, prim, dual, gap = _termination(qp, x, y, Ax, Px, ATy)
    pinf = _primal_infeasible(qp, dys, ATdy)
    dinf = _dual_infeasible(qp, dxs, Adx, Pdx)
    bad = ~(jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(y)))
    status = jnp.where(
        bad,
        STATUS_CODES.ERROR,
        jnp.where(
            solved,
            STATUS_CODES.SOLVED,
            jnp.where(
                pinf,
                STATUS_CODES.PRIMAL_INFEASIBLE,
                jnp.where(
                    dinf,
                    STATUS_CODES.DUAL_INFEASIBLE,
                    jnp.where(it >= qp.prm.max_iter, STATUS_CODES.MAX_ITER, RUNNING_CODE),
                ),
            ),
        ),
    )
    return status.astype(jnp.int32), prim, dual, gap


def _max_step(v, dv, mask):
    """Largest α with v + α·dv ≥ 0 on the masked components."""
    ratio = jnp.where((mask > 0) & (dv < 0), -v / jnp.where(dv < 0, dv, -1.0), jnp.inf)
    return jnp.min(ratio, initial=jnp.inf)


def _starting_point(qp: _QP) -> _Carry:
    """Minimise ½xᵀPx + qᵀx + ½Σ d₀(Ax − t)² (t: the middle of each row); slacks and
    multipliers from it by Mehrotra's shifts (or floored: ``shifted_start``)."""
    r, la, f64 = qp.rows, qp.la, jnp.float64
    fl, fu, fe, lf, uf, fin_l, fin_u = r.fl, r.fu, r.fe, r.lf, r.uf, r.fin_l, r.fin_u
    d0 = fl + fu - fl * fu + fe / qp.prm.delta
    t = jnp.where(
        r.eq,
        lf,
        jnp.where(fin_l & fin_u, 0.5 * (lf + uf), jnp.where(fin_l, lf, jnp.where(fin_u, uf, 0.0))),
    )
    x0 = la.msolve(la.factor(d0), -qp.q + la.ATmul(d0 * t))
    Ax0 = la.Amul(x0)
    # Mehrotra's (1992) heuristic: the slacks Ax₀ − l, u − Ax₀ and the penalty's multiplier
    # estimate ±d₀(Ax₀ − t) each shifted uniformly until positive (1.5 × the most negative entry),
    # then shifted again to balance their complementarity products.  A uniform shift keeps the
    # start scale-free: a per-row floor leaves tight rows (narrow [l, u]) at the boundary with
    # tiny multipliers, and the first steps are then short.
    big = jnp.asarray(1e300, f64)
    sl_t, su_t = fl * (Ax0 - lf), fu * (uf - Ax0)
    ypen = d0 * (Ax0 - t)
    zl_t, zu_t = -fl * ypen, fu * ypen

    def shift(vl, vu):  # 1.5 × the most negative entry on the inequality sides, or 0
        lo = jnp.minimum(
            jnp.min(jnp.where(fl > 0, vl, big), initial=big),
            jnp.min(jnp.where(fu > 0, vu, big), initial=big),
        )
        return jnp.maximum(-1.5 * lo, 0.0)

    ds, dz = shift(sl_t, su_t), shift(zl_t, zu_t)
    sl_t, su_t = fl * (sl_t + ds), fu * (su_t + ds)
    zl_t, zu_t = fl * (zl_t + dz), fu * (zu_t + dz)
    sz = jnp.sum(sl_t * zl_t) + jnp.sum(su_t * zu_t)
    ds2 = 0.5 * sz / jnp.maximum(jnp.sum(zl_t) + jnp.sum(zu_t), 1e-300)
    dz2 = 0.5 * sz / jnp.maximum(jnp.sum(sl_t) + jnp.sum(su_t), 1e-300)
    sl_s = fl * jnp.maximum(sl_t + ds2, 1e-8) + (1 - fl)
    su_s = fu * jnp.maximum(su_t + ds2, 1e-8) + (1 - fu)
    zl_s = fl * jnp.maximum(zl_t + dz2, 1e-8)
    zu_s = fu * jnp.maximum(zu_t + dz2, 1e-8)
    # the floored start (shifted_start=False): slacks floored at min(1, half the row's width),
    # multipliers the penalty estimate clipped at 0 plus one balancing shift
    width = jnp.where(fin_l & fin_u, uf - lf, jnp.inf)
    floor = jnp.minimum(1.0, 0.5 * width)
    sl_f = fl * jnp.maximum(Ax0 - lf, floor) + (1 - fl)
    su_f = fu * jnp.maximum(uf - Ax0, floor) + (1 - fu)
    zl_c, zu_c = fl * jnp.maximum(-ypen, 0.0), fu * jnp.maximum(ypen, 0.0)
    sz_f = jnp.sum(fl * sl_f * zl_c) + jnp.sum(fu * su_f * zu_c)
    dz_f = 0.5 * sz_f / jnp.maximum(jnp.sum(fl * sl_f) + jnp.sum(fu * su_f), 1e-300)
    zl_f = fl * jnp.maximum(zl_c + dz_f, 1e-8)
    zu_f = fu * jnp.maximum(zu_c + dz_f, 1e-8)
    use = qp.prm.shifted > 0.5
    sl0, su0 = jnp.where(use, sl_s, sl_f), jnp.where(use, su_s, su_f)
    zl0, zu0 = jnp.where(use, zl_s, zl_f), jnp.where(use, zu_s, zu_f)
    ye0 = jnp.zeros(qp.m, f64)
    y0 = zu0 - zl0
    Px0, ATy0 = la.Pmul(x0), la.ATmul(y0)
    inf = jnp.asarray(jnp.inf, f64)
    st0 = jnp.zeros((), jnp.int32)  # RUNNING: the first check follows the first step
    p0 = du0 = g0 = inf
    it0 = jnp.zeros((), jnp.int32)
    return _Carry(x0, sl0, su0, zl0, zu0, ye0, Ax0, Px0, ATy0, it0, st0, p0, du0, g0)


class _Newton(NamedTuple):
    """The linearisation at the current iterate that both Mehrotra passes solve with."""

    sl: Any
    su: Any
    zl: Any
    zu: Any
    slr: Any  # s_l with 1 on the rows without a lower side (safe divisor)
    sur: Any
    mu: Any  # complementarity measure
    dI: Any  # z_l/s_l + z_u/s_u
    L: Any  # factor of the condensed matrix
    rd: Any  # stationarity residual
    rpl: Any  # primal residuals of the lower, upper and equality rows
    rpu: Any
    re: Any


def _alpha_max(qp: _QP, nw: _Newton, dsl, dsu, dzl, dzu):
    """Largest step keeping ``s, z ≥ 0``."""
    fl, fu = qp.rows.fl, qp.rows.fu
    return jnp.minimum(
        jnp.minimum(_max_step(nw.sl, dsl, fl), _max_step(nw.su, dsu, fu)),
        jnp.minimum(_max_step(nw.zl, dzl, fl), _max_step(nw.zu, dzu, fu)),
    )


def _predictor_corrector(qp: _QP, nw: _Newton):
    """Mehrotra's direction ``(dx, dsl, dsu, dzl, dzu, dye, A dx)``.

    Pass 0, the predictor (affine scaling): complementarity target 0.  Pass 1, the corrector:
    target σμ with centering σ = (μ_aff/μ)³ and the second-order term Δs_aff∘Δz_aff of the
    predictor (one traced solve serves both passes).
    """
    r, f64 = qp.rows, jnp.float64
    fl, fu = r.fl, r.fu
    sl, su, zl, zu, slr, sur, mu = nw.sl, nw.su, nw.zl, nw.zu, nw.slr, nw.sur, nw.mu

    def mehrotra(k, prev):
        _, dsla, dsua, dzla, dzua, _, _ = prev
        aa = jnp.minimum(1.0, _alpha_max(qp, nw, dsla, dsua, dzla, dzua))
        mu_aff = (
            jnp.sum(fl * (sl + aa * dsla) * (zl + aa * dzla))
            + jnp.sum(fu * (su + aa * dsua) * (zu + aa * dzua))
        ) / r.n_ineq
        sigma = jnp.clip((mu_aff / jnp.maximum(mu, 1e-300)) ** 3, 0.0, 1.0)
        sigma = jnp.where(k == 0, 0.0, sigma)
        rcl = fl * (sl * zl + dsla * dzla - sigma * mu)
        rcu = fu * (su * zu + dsua * dzua - sigma * mu)
        # Newton step of the perturbed KKT system, condensed onto (dx, dyₑ)
        g = fu * (-rcu + zu * nw.rpu) / sur + fl * (rcl + zl * nw.rpl) / slr
        dx, dye, Adx = _kkt_solve(qp, nw.L, nw.dI, -nw.rd - qp.la.ATmul(g), -nw.re)
        dsl = fl * (Adx + nw.rpl)
        dsu = fu * (-Adx - nw.rpu)
        dzl = fl * (-rcl - zl * dsl) / slr
        dzu = fu * (-rcu - zu * dsu) / sur
        return dx, dsl, dsu, dzl, dzu, dye, Adx

    zn, zm = jnp.zeros(qp.n, f64), jnp.zeros(qp.m, f64)
    zero = (zn, zm, zm, zm, zm, zm, zm)
    return lax.fori_loop(0, 2, mehrotra, zero)


def _ipm_step(qp: _QP, carry: _Carry) -> _Carry:
    """One interior-point iteration: linearise, Mehrotra's direction, step, check."""
    r, la = qp.rows, qp.la
    fl, fu, fe = r.fl, r.fu, r.fe
    x, sl, su, zl, zu, ye, Ax, Px, ATy, it = carry[:10]
    y = zu - zl + ye
    rd = Px + qp.q + ATy  # stationarity residual
    rpl = fl * (Ax - sl - r.lf)
    rpu = fu * (Ax + su - r.uf)
    re = fe * (Ax - r.lf)
    mu = (jnp.sum(fl * sl * zl) + jnp.sum(fu * su * zu)) / r.n_ineq
    slr = jnp.where(fl > 0, sl, 1.0)
    sur = jnp.where(fu > 0, su, 1.0)
    dI = fl * zl / slr + fu * zu / sur
    L = la.factor(dI + fe / qp.prm.delta)
    nw = _Newton(sl, su, zl, zu, slr, sur, mu, dI, L, rd, rpl, rpu, re)
    dx, dsl, dsu, dzl, dzu, dye, Adx = _predictor_corrector(qp, nw)
    # step length: a fraction τ of the way to the boundary of s, z ≥ 0 (one α for all)
    a = jnp.minimum(1.0, qp.prm.tau * _alpha_max(qp, nw, dsl, dsu, dzl, dzu))
    xn = x + a * dx
    sln = jnp.where(fl > 0, sl + a * dsl, 1.0)
    sun = jnp.where(fu > 0, su + a * dsu, 1.0)
    zln = fl * (zl + a * dzl)
    zun = fu * (zu + a * dzu)
    yen = ye + a * dye
    yn = zun - zln + yen
    Axn, Pxn, ATyn = la.Amul(xn), la.Pmul(xn), la.ATmul(yn)
    itn = it + 1
    stn, prim, dual, gap = _check(
        qp, xn, yn, Axn, Pxn, ATyn, xn - x, yn - y, Axn - Ax, Pxn - Px, ATyn - ATy, itn
    )
    return _Carry(xn, sln, sun, zln, zun, yen, Axn, Pxn, ATyn, itn, stn, prim, dual, gap)


def _ipm_one(st: IPMSetup, q, l, u):
    """One QP (scaled, permuted ``q̄ (n,), l̄, ū (m,)``); vmapped by :func:`ipm_iterate`."""
    ar = st.arrays
    prm = _Params(*(ar["params"][i] for i in range(len(_TUNABLE))))
    D, E, c = ar["D"], ar["E"], ar["c"]
    sc = _Scaling(D, E, c, 1.0 / D, 1.0 / E)
    rows = _classify_rows(l, u)
    m = l.shape[0]
    qp = _QP(q, l, u, st.n, m, st.refine_iter, prm, sc, rows, _linear_algebra(st, prm.rho))
    out = lax.while_loop(
        lambda carry: carry.status == RUNNING_CODE,
        lambda carry: _ipm_step(qp, carry),
        _starting_point(qp),
    )
    y = out.zu - out.zl + out.ye
    obj = (0.5 * out.x @ out.Px + q @ out.x) / c
    return D * out.x, E * y / c, out.status, out.it, out.prim, out.dual, out.gap, obj


def ipm_iterate(setup: IPMSetup, q: Any, l: Any, u: Any) -> IPMResult:
    """Run the batched interior-point method on unscaled ``q (B, n), l (B, m), u (B, m)``.

    Jittable (``setup`` is a pytree; its structure is static).  1-D ``q, l, u`` solve one QP and
    return unbatched fields.  Needs x64 mode (``with jax.enable_x64(True):``).  ``±inf`` bounds
    are allowed; ``l == u`` marks an equality.  Returns an :class:`IPMResult`.
    """
    if not jax.config.jax_enable_x64:
        raise RuntimeError(
            "ipm_iterate computes in float64: call it (and trace your jit) inside "
            "`with jax.enable_x64(True):`"
        )
    ar = setup.arrays
    squeeze = jnp.ndim(q) == 1
    q, l, u = (jnp.atleast_2d(jnp.asarray(v, jnp.float64)) for v in (q, l, u))
    if q.shape[-1] != setup.n or l.shape[-1] != setup.m or u.shape[-1] != setup.m:
        raise ValueError(
            f"q, l, u must have last dimensions ({setup.n}, {setup.m}, {setup.m}), got "
            f"{q.shape}, {l.shape}, {u.shape}"
        )
    arr = {k: jnp.asarray(v) for k, v in ar.items()}
    stj = IPMSetup(
        arr, setup.kind, setup.width, setup.n, setup.m, setup.refine_iter, setup.chunk_size
    )
    perm, iperm = arr["perm"], arr["iperm"]
    D, E, c = arr["D"], arr["E"], arr["c"]
    qs = c * D * q[:, perm]  # D is stored in the permuted order
    ls, us = E * l, E * u

    def one(qi, li, ui):
        return _ipm_one(stj, qi, li, ui)

    B, C = qs.shape[0], setup.chunk_size
    if C is None or B <= C:
        x, y, status, it, prim, dual, gap, obj = jax.vmap(one)(qs, ls, us)
    else:  # chunks of C QPs in sequence (the last padded with copies of the first QP)
        nc = -(-B // C)
        pad = nc * C - B

        def chunked(v):
            v = jnp.concatenate([v, jnp.broadcast_to(v[:1], (pad, *v.shape[1:]))])
            return v.reshape(nc, C, *v.shape[1:])

        outs = lax.map(lambda a: jax.vmap(one)(*a), (chunked(qs), chunked(ls), chunked(us)))
        x, y, status, it, prim, dual, gap, obj = (v.reshape(nc * C, *v.shape[2:])[:B] for v in outs)
    out = IPMResult(x[:, iperm], y, status, it, prim, dual, gap, obj)
    if squeeze:
        out = IPMResult(*(v[0] for v in out))
    return out


_ipm_iterate_jit = jax.jit(ipm_iterate)


def ipm_solve(
    P: Any, A: Any, q: Any, l: Any, u: Any, settings: IPMSettings | None = None
) -> IPMResult:
    """:func:`ipm_setup` then :func:`ipm_iterate` (jitted), in x64 mode.

    ``P``, ``A`` must be concrete (NumPy/SciPy; inside a user's ``jit`` they are constants);
    ``q, l, u`` may be traced.  Returns an :class:`IPMResult` of float64 arrays.
    """
    setup = ipm_setup(P, A, settings)
    with jax.enable_x64(True):
        squeeze = np.ndim(q) == 1
        q, l, u = (jnp.atleast_2d(jnp.asarray(v, jnp.float64)) for v in (q, l, u))
        out = _ipm_iterate_jit(setup, q, l, u)  # 2-D inputs: the backend's compiled code
        return IPMResult(*(v[0] for v in out)) if squeeze else out


# ------------------------------------------------------------------------------ the backend
SPEC = SettingsSpec(
    backend="ipm",
    common={"eps_abs": ("eps_abs",), "eps_rel": ("eps_rel",), "max_iter": ("max_iter",)},
    native=frozenset(f.name for f in dataclasses.fields(IPMSettings)),
    warm_start=False,
    tolerance=("eps_abs", "eps_rel"),
    tolerance_defaults=(IPMSettings.eps_abs, IPMSettings.eps_rel),
)


#: setups (scaling, ordering, band tables) an :class:`IPMBackend` keeps, oldest evicted first
SETUP_CACHE_SIZE = 16


class IPMBackend(Backend):
    """Batched interior-point backend (see the module docstring)."""

    name = "ipm"
    detects_infeasibility = True
    honours_warm_start = False

    def settings_spec(self, settings: dict[str, Any] | None = None) -> SettingsSpec:
        return SPEC

    def __init__(self) -> None:
        # one setup per (P, A, scaling and linear-solver settings): see solvers.cache
        self._setups: BoundedCache[tuple, IPMSetup] = BoundedCache(SETUP_CACHE_SIZE)

    def clear_cache(self) -> None:
        """Forget the cached setups (the next batch recomputes its scaling and tables)."""
        self._setups.clear()

    def _setup(self, P: np.ndarray, A: np.ndarray, s: IPMSettings) -> tuple[IPMSetup, bool]:
        h = hashlib.blake2b(digest_size=16)
        for arr in (P, A):
            h.update(np.ascontiguousarray(arr).tobytes())
            h.update(str(arr.shape).encode())
        key = (h.hexdigest(), s.scaling_iter, s.linear_solver, s.band_ratio)
        if key not in self._setups:
            return self._setups.get_or_create(key, lambda: ipm_setup(P, A, s)), False
        # tolerances are not baked into the tables: swap the tunables in
        return self._setups[key].with_settings(s), True

    def solve(self, qp: QP, *, warm_start: Solution | None = None, **settings: Any) -> Solution:
        # interior point: no warm start (warm_start is accepted and ignored)
        batch = QPBatch(qp.P, qp.A, qp.q[None], qp.l[None], qp.u[None])
        sol = self.solve_batch(batch, **settings)
        return dataclasses.replace(sol[0], extras=dict(sol.extras))

    def solve_batch(
        self, batch: QPBatch, *, warm_start: BatchSolution | None = None, **settings: Any
    ) -> BatchSolution:
        native, record = self.native_settings(settings)
        s = IPMSettings.from_kwargs(**native)
        sol = self._solve_batch(batch, s)
        sol.settings.update(record)
        return sol

    def _solve_batch(self, batch: QPBatch, s: IPMSettings) -> BatchSolution:
        t0 = time.perf_counter()
        P, A = batch.dense()
        P = np.asarray(P, np.float64)
        A = np.asarray(A, np.float64).reshape(batch.m, batch.n)
        # rows free in every QP of the batch (both bounds infinite) leave the iteration
        keep = ~np.all(np.isneginf(batch.l) & np.isposinf(batch.u), axis=0)
        setup, cached = self._setup(P, A[keep], s)
        t_setup = time.perf_counter() - t0
        t1 = time.perf_counter()
        try:
            with jax.enable_x64(True):
                res = _ipm_iterate_jit(setup, batch.q, batch.l[:, keep], batch.u[:, keep])
                res = jax.tree_util.tree_map(np.asarray, res)
            if not keep.all():  # a free row's multiplier is 0
                y_all = np.zeros((len(batch), batch.m))
                y_all[:, keep] = res.y
                res = res._replace(y=y_all)
        except Exception as exc:  # noqa: BLE001 - a backend returns a status, never raises
            B = len(batch)
            sols = [
                Solution(
                    x=np.full(batch.n, np.nan),
                    y=np.full(batch.m, np.nan),
                    status=Status.ERROR,
                    objective=float("nan"),
                    iterations=0,
                    solve_time=0.0,
                    primal_residual=float("nan"),
                    dual_residual=float("nan"),
                    backend=self.name,
                    settings=s.as_dict(),
                )
                for _ in range(B)
            ]
            return BatchSolution.stack(
                sols, self.name, time.perf_counter() - t0, extras={"message": str(exc)}
            )
        t_solve = time.perf_counter() - t1
        x = np.asarray(res.x, np.float64)
        y = np.asarray(res.y, np.float64)
        status = np.asarray(res.status, np.int32).copy()
        finite = np.all(np.isfinite(x), axis=1)
        status[~finite] = STATUS_CODES.ERROR
        xs = np.where(finite[:, None], x, 0.0)
        yfin = np.all(np.isfinite(y), axis=1)
        obj = np.where(finite, batch.objective(xs), np.nan)
        prim = np.where(finite, batch.constraint_violation(xs), np.nan)
        dual = np.where(
            finite & yfin, batch.dual_residual(xs, np.where(yfin[:, None], y, 0.0)), np.nan
        )
        total = time.perf_counter() - t0
        B = len(batch)
        extras = {
            "linear_solver": setup.kind,
            "bandwidth": setup.width,
            "setup_cached": cached,
            "time_setup": t_setup,
            "time_solve": t_solve,
            "gap": np.asarray(res.gap),
        }
        return BatchSolution(
            x=x,
            y=y,
            status=status,
            objective=obj,
            iterations=np.asarray(res.iterations, np.int64),
            solve_time=np.full(B, total / B),
            primal_residual=prim,
            dual_residual=dual,
            backend=self.name,
            total_time=total,
            settings=s.as_dict(),
            extras=extras,
        )


def make_backend() -> Backend:
    return IPMBackend()
