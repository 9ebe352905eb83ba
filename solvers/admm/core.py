"""The functional core of the ``admm`` backend: settings, factorisation, batched jitted iterations.

Pure JAX, for use inside your own ``jit``::

    from solvers.admm import ADMMSettings, admm_factor, admm_iterate

    factor = admm_factor(P, A, ADMMSettings(), eq_rows=eq_mask)  # NumPy/float64, once per P, A
    @jax.jit
    def project(q, l, u, x0, y0):                               # (B, n), (B, m), (B, m), ...
        st = admm_iterate(factor, q, l, u, x0=x0, y0=y0, iters=200)
        return st.x, st.status

* :func:`admm_factor` precomputes the scaling, the scaled matrices and the ladder of inverses, and
  returns an :class:`ADMMFactor` pytree: its arrays are leaves (so a new ``P``/``A`` of the same
  shape does not recompile) and its settings are static metadata.  ``eq_rows`` (bool ``(m,)``)
  marks rows that are equalities in every QP (they get ``rho_eq_scale · rho``); ``free_rows``
  marks rows unbounded on both sides.  Use :func:`rows_from_bounds` to derive both from ``l, u``.
* :func:`admm_iterate` takes unscaled ``q (B, n), l (B, m), u (B, m)`` (a 1-D problem is treated
  as ``B = 1`` and squeezed back), an optional warm start ``x0 (B, n), y0 (B, m)`` (unscaled,
  OSQP sign convention) and a static iteration budget ``iters`` (rounded up to a multiple of
  ``check_every``).  It is jittable and vmappable, has no Python loop over samples, and returns an
  :class:`ADMMState` ``(x, z, y, prim_res, dual_res, status, iterations, rho, delta_x, delta_y,
  rung_matmuls)``,
  unscaled, with ``status`` the :class:`solvers.Status` integer codes (``MAX_ITER`` where the
  budget ran out).  It does not polish; :func:`solvers.admm.polish` (NumPy, host side) can be
  applied after.
* ``dtype=float64`` needs JAX's x64 mode (``jax.enable_x64(True)`` as a context manager); the
  backend enables it for the call itself.

Method (OSQP's ADMM, arranged for batches; Stellato et al. 2020, Algorithm 1): Ruiz equilibration
of the shared KKT matrix plus one cost scaling; for a small ladder of step sizes ``rho`` the
inverse ``K⁻¹ = (P + σI + Aᵀ R A)⁻¹`` is computed once in float64 and stored in the iteration
dtype; each QP carries its own rung and re-picks it every ``check_every`` iterations with OSQP's
residual-balancing rule; every ``check_every`` iterations OSQP's unscaled termination test, its
primal and dual infeasibility certificates, and a NaN guard.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from jax import lax

from ..errors import InvalidSettingError
from ..protocols import JaxProjector
from ..scaling import ruiz_equilibrate
from ..solution import RUNNING_CODE, STATUS_CODES

__all__ = [
    "ADMMSettings",
    "PolishSettings",
    "ADMMFactor",
    "ADMMState",
    "admm_factor",
    "admm_iterate",
    "admm_projector",
    "rows_from_bounds",
    "spd_inverse",
    "flops_per_iteration",
]


class PolishSettings(NamedTuple):
    """Numerics of the float64 active-set polish (:mod:`solvers.admm.polish`).

    In the flat settings vocabulary of ``solve``/``solve_batch`` and
    :meth:`ADMMSettings.from_kwargs` these are ``polish_delta``, ``polish_refine_iter``,
    ``polish_passes``, ``polish_stage_passes``, ``polish_settle_rows`` and ``rho_patience``.

    With stages (``ADMMSettings.stage_iter``) the polish is tried after every stage, but only on
    the QPs whose guessed active set (:func:`solvers.admm.polish.active_guess`) moved by at most
    ``settle_rows`` rows since the previous stage, and with ``stage_passes`` repair passes: a
    guess that still moves is rarely one the repair can finish, and each pass is a Cholesky of the
    active rows.  After the last stage every QP not solved gets ``passes``.

    ``rho_patience`` (flat name ``rho_patience``), with stages and without ``adaptive_rho``: every
    this many iterations that a QP runs unsolved, it tries another rung around its start, at the
    end of a stage (first the side OSQP's residual-balancing rule points to, then the other, then
    further; ``None``: never).  A fixed step finds most projections' active sets fastest; the few
    it does not suit get another one, slowly enough not to undo the rest.
    """

    delta: float = 1e-6  # regularisation δ of the reduced KKT system
    refine_iter: int = 3  # iterative-refinement steps per solve
    passes: int = 25  # active-set repair passes (after the last stage)
    stage_passes: int = 4  # active-set repair passes after an earlier stage
    settle_rows: int = 2  # after an earlier stage: polish where the guess moved ≤ this many rows
    rho_patience: int | None = 1000  # iterations between a straggler's rho moves (None: never)


#: flat setting name -> field of :class:`PolishSettings`
_POLISH_NAMES = {
    "polish_delta": "delta",
    "polish_refine_iter": "refine_iter",
    "polish_passes": "passes",
    "polish_stage_passes": "stage_passes",
    "polish_settle_rows": "settle_rows",
    "rho_patience": "rho_patience",
}


@dataclass(frozen=True)
class ADMMSettings:
    """Settings of the ``admm`` backend (all explicit; nothing else is changed behind them).

    The defaults are a fixed step ``rho = 62.5`` on the Ruiz-scaled problem, in stages of 200
    iterations with the polish tried between them.  On the six projection families of
    ``benchmarks/qp_families.py`` and ``mmdopt bench qp-backends`` a fixed step reached the
    polish's active set sooner than OSQP's residual-balancing rule over the ladder
    (``adaptive_rho=True``), which moved the step away from it (docs/experiments/qp-backends.md).

    Attributes
    ----------
    eps_abs, eps_rel : OSQP-style termination, ``‖Ax − z‖∞ ≤ eps_abs + eps_rel·max(‖Ax‖∞, ‖z‖∞)``
        and ``‖Px + q + Aᵀy‖∞ ≤ eps_abs + eps_rel·max(‖Px‖∞, ‖Aᵀy‖∞, ‖q‖∞)`` (unscaled).
    eps_prim_inf, eps_dual_inf : tolerances of OSQP's infeasibility certificates.
    max_iter : iteration budget per QP (rounded up to a multiple of ``check_every``).
    check_every : iterations between termination/infeasibility checks and rho updates.
    rho : initial step size; the ladder rung nearest to it is the start.
    rho_ladder : the step sizes whose inverses are precomputed (sorted ascending); without
        ``adaptive_rho`` only the rung nearest to ``rho`` is computed.
    rho_eq_scale : ``rho`` multiplier on rows that are equalities in every QP of the batch.
    rho_free : the (absolute) rho on rows with both bounds infinite.
    sigma : proximal term on ``x``.
    alpha : over-relaxation.
    adaptive_rho : re-pick each QP's rung at every check (OSQP's residual balancing).
    scaling_iter : Ruiz equilibration passes (0 = no scaling).
    dtype : iteration dtype, ``"float32"`` or ``"float64"``.
    polish : run the float64 active-set polish after the iterations.
    polish_settings : its numerics, a :class:`PolishSettings` (the regularisation ``δ``,
        iterative-refinement steps, active-set repair passes); given to ``solve``/``solve_batch``,
        :meth:`from_kwargs` and :meth:`replace` by the flat names ``polish_delta``,
        ``polish_refine_iter``, ``polish_passes``, ``polish_stage_passes``,
        ``polish_settle_rows``, ``rho_patience``, which are also read-only attributes.
    stage_iter : ``None`` (one stage of ``max_iter``), or run ADMM in stages of this many
        iterations: after each stage the polish is tried, the QPs it accepts leave the batch and
        the rest continue (warm-started with their rho) in a smaller batch padded to a power of
        two.  Saves the dense batch's work on QPs already solved; each new batch size compiles.
    fallback : ``None`` or ``"clarabel"``: re-solve QPs still not solved (not certified
        infeasible) with Clarabel; counted in ``extras["fallback_count"]``.
    products : how the iterations multiply by ``Ā`` and ``Āᵀ``: ``"dense"`` (batched matmuls),
        ``"sparse"`` (over the nonzeros, stored row by row and column by column, padded to the
        longest; :func:`sparse_pattern`) or ``"auto"`` (sparse when no row of ``Ā`` has more
        than ``n/8`` nonzeros and no column more than ``m/8``: a gather costs about ten matmul
        flops, so sparse pays below an eighth).  ``K⁻¹`` stays a dense inverse either way.
    """

    eps_abs: float = 1e-5
    eps_rel: float = 1e-5
    eps_prim_inf: float = 1e-4
    eps_dual_inf: float = 1e-4
    max_iter: int = 4000
    check_every: int = 25
    rho: float = 62.5
    rho_ladder: tuple[float, ...] = (
        0.1 / 125,
        0.1 / 25,
        0.1 / 5,
        0.1,
        0.5,
        2.5,
        12.5,
        62.5,
        312.5,
        1562.5,
    )
    rho_eq_scale: float = 1e3
    rho_free: float = 1e-6
    sigma: float = 1e-6
    alpha: float = 1.6
    adaptive_rho: bool = False
    scaling_iter: int = 10
    dtype: str = "float32"
    polish: bool = True
    polish_settings: PolishSettings = PolishSettings()
    stage_iter: int | None = 200
    fallback: str | None = None
    products: str = "auto"

    def __post_init__(self) -> None:
        object.__setattr__(self, "rho_ladder", tuple(sorted(float(r) for r in self.rho_ladder)))
        if not isinstance(self.polish_settings, PolishSettings):
            raise ValueError(
                "polish_settings must be a PolishSettings, got "
                f"{type(self.polish_settings).__name__}"
            )
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"dtype must be 'float32' or 'float64', got {self.dtype!r}")
        if self.products not in ("auto", "dense", "sparse"):
            raise ValueError(f"products must be 'auto', 'dense' or 'sparse', got {self.products!r}")
        if self.fallback not in (None, "clarabel"):
            raise ValueError(f"fallback must be None or 'clarabel', got {self.fallback!r}")
        if self.check_every < 1 or self.max_iter < 0:
            raise ValueError("check_every must be ≥ 1 and max_iter ≥ 0")
        if not self.rho_ladder or min(self.rho_ladder) <= 0 or self.rho <= 0:
            raise ValueError("rho and rho_ladder must be positive")
        p = self.polish_settings.rho_patience
        if p is not None and p < 1:
            raise ValueError(f"rho_patience must be None or ≥ 1, got {p!r}")
        if not (0 < self.alpha < 2):
            raise ValueError("alpha must be in (0, 2)")
        for name in ("eps_abs", "eps_rel", "eps_prim_inf", "eps_dual_inf", "sigma"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be ≥ 0")

    # the flat names of the polish numerics (read-only)
    @property
    def polish_delta(self) -> float:
        return self.polish_settings.delta

    @property
    def polish_refine_iter(self) -> int:
        return self.polish_settings.refine_iter

    @property
    def polish_passes(self) -> int:
        return self.polish_settings.passes

    @property
    def polish_stage_passes(self) -> int:
        return self.polish_settings.stage_passes

    @property
    def polish_settle_rows(self) -> int:
        return self.polish_settings.settle_rows

    @property
    def rho_patience(self) -> int | None:
        return self.polish_settings.rho_patience

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The flat setting names that :meth:`from_kwargs` (and the backend) accept."""
        out: list[str] = []
        for f in dataclasses.fields(cls):
            out.extend(_POLISH_NAMES if f.name == "polish_settings" else (f.name,))
        return tuple(out)

    @staticmethod
    def _nest(base: PolishSettings, kwargs: dict[str, Any]) -> dict[str, Any]:
        """``kwargs`` with its flat ``polish_*`` names folded into a ``polish_settings`` entry."""
        flat = {k: kwargs.pop(k) for k in list(kwargs) if k in _POLISH_NAMES}
        if flat:
            base = kwargs.get("polish_settings", base)
            kwargs["polish_settings"] = base._replace(
                **{_POLISH_NAMES[k]: v for k, v in flat.items()}
            )
        return kwargs

    @classmethod
    def from_kwargs(cls, **kwargs: Any) -> ADMMSettings:
        """Build from keyword arguments (the flat names of :meth:`names`); unknown names raise
        ``InvalidSettingError`` naming them."""
        names = set(cls.names())
        unknown = sorted(set(kwargs) - names)
        if unknown:
            raise InvalidSettingError(
                f"unknown admm setting(s) {unknown}; valid names: {', '.join(sorted(names))}"
            )
        if "rho_ladder" in kwargs:
            kwargs["rho_ladder"] = tuple(kwargs["rho_ladder"])
        return cls(**cls._nest(PolishSettings(), kwargs))

    def replace(self, **kwargs: Any) -> ADMMSettings:
        """A copy with some settings changed (field names or the flat ``polish_*`` names)."""
        return dataclasses.replace(self, **self._nest(self.polish_settings, kwargs))

    def as_dict(self) -> dict[str, Any]:
        """The settings under their flat names (what ``solve_batch(..., **settings)`` takes)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name == "polish_settings":
                out.update({k: getattr(v, fld) for k, fld in _POLISH_NAMES.items()})
            else:
                out[f.name] = v
        return out


# ----------------------------------------------------------------------------- factor (host)
class SparsePattern(NamedTuple):
    """The nonzeros of ``Ā`` for products over them (a pytree of arrays), padded with zeros.

    ``Āx = Σ_j rvals[:, j]·x[rows[:, j]]`` and ``Āᵀw = Σ_j cvals[:, j]·w[cols[:, j]]``: each row
    of ``Ā`` lists the columns of its nonzeros, each column the rows of its nonzeros.
    """

    rows: Any  # (m, kr) int32 column indices of each row's nonzeros
    rvals: Any  # (m, kr) their values (0 where padded)
    cols: Any  # (n, kc) int32 row indices of each column's nonzeros
    cvals: Any  # (n, kc)


def _padded_lists(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row's nonzero columns and values of ``M``, padded with (0, 0.0) to the longest row."""
    nz = M != 0
    k = max(1, int(nz.sum(axis=1).max(initial=0)))
    # stable sort puts each row's nonzero columns first, in increasing order
    order = np.argsort(~nz, axis=1, kind="stable")[:, :k]
    keep = np.take_along_axis(nz, order, axis=1)
    idx = np.where(keep, order, 0).astype(np.int32)
    vals = np.where(keep, np.take_along_axis(M, order, axis=1), 0.0)
    return idx, vals


def sparse_pattern(A: np.ndarray, dtype: Any = np.float64) -> SparsePattern:
    """:class:`SparsePattern` of a dense ``A (m, n)`` (its exact zeros are left out)."""
    A = np.asarray(A, np.float64)
    if A.ndim != 2:
        raise ValueError(f"A must be 2-D, got shape {A.shape}")
    rows, rvals = _padded_lists(A)
    cols, cvals = _padded_lists(A.T)
    dt = np.dtype(dtype)
    return SparsePattern(rows, rvals.astype(dt), cols, cvals.astype(dt))


def _use_sparse(A: np.ndarray, products: str) -> bool:
    """Whether ``products`` (``"auto"``, ``"dense"``, ``"sparse"``) means sparse for ``A``."""
    if products != "auto":
        return products == "sparse"
    m, n = A.shape
    if m == 0 or n == 0:
        return False
    nz = A != 0
    return bool(nz.sum(axis=1).max() <= n / 8 and nz.sum(axis=0).max() <= m / 8)


@jax.tree_util.register_pytree_node_class
@dataclass(frozen=True, eq=False)
class ADMMFactor:
    """Precomputed, scaled data for :func:`admm_iterate` (a pytree; settings are static).

    Scaled problem: ``P̄ = c·D P D``, ``Ā = E A D``, ``q̄ = c·D q``, ``l̄ = E l``, ``ū = E u``;
    ``x = D x̄``, ``z = E⁻¹ z̄``, ``y = E ȳ / c``.
    """

    P: Any  # (n, n) scaled P̄
    A: Any  # (m, n) scaled Ā
    D: Any  # (n,)
    E: Any  # (m,)
    c: Any  # ()
    Kinv: Any  # (L, n, n) (P̄ + σI + ĀᵀR_rĀ)⁻¹ per rung
    ladder: Any  # (L,) rho values
    Rbase: Any  # (m,) row multipliers of rho (1, rho_eq_scale, or rho_free/rho)
    free: Any  # (m,) bool, rows with the absolute rho_free
    settings: ADMMSettings
    sparse: Any = None  # SparsePattern of Ā, or None (dense products)

    def tree_flatten(self):
        leaves = (
            self.P,
            self.A,
            self.D,
            self.E,
            self.c,
            self.Kinv,
            self.ladder,
            self.Rbase,
            self.free,
            self.sparse,
        )
        return leaves, self.settings

    @classmethod
    def tree_unflatten(cls, settings, leaves):
        *arrays, sparse = leaves
        return cls(*arrays, settings=settings, sparse=sparse)

    @property
    def n(self) -> int:
        return self.P.shape[0]

    @property
    def m(self) -> int:
        return self.A.shape[0]


def rows_from_bounds(l: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(eq_rows, free_rows)``: rows equal in every QP, rows unbounded on both sides in every QP.

    ``l, u`` are ``(m,)`` or ``(B, m)``.
    """
    l2, u2 = np.atleast_2d(np.asarray(l, float)), np.atleast_2d(np.asarray(u, float))
    eq = np.all((l2 == u2) & np.isfinite(l2), axis=0)
    free = np.all(np.isinf(l2) & np.isinf(u2), axis=0)
    return eq, free


def spd_inverse(K: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive definite matrix via Cholesky (LU-based ``inv`` is far
    slower here); falls back to ``inv`` when Cholesky fails."""
    try:
        return sla.cho_solve(sla.cho_factor(K, lower=True), np.eye(K.shape[0]))
    except np.linalg.LinAlgError:
        return np.linalg.inv(K)


def admm_factor(
    P: Any,
    A: Any,
    settings: ADMMSettings | None = None,
    *,
    eq_rows: np.ndarray | None = None,
    free_rows: np.ndarray | None = None,
) -> ADMMFactor:
    """Precompute the scaled data and the ladder of inverses (NumPy, float64), once per ``P, A``.

    Parameters
    ----------
    P : (n, n) symmetric PSD, dense or sparse (densified).
    A : (m, n) dense or sparse (densified).
    settings : :class:`ADMMSettings` (defaults if ``None``).
    eq_rows, free_rows : (m,) bool masks, see :func:`rows_from_bounds`.
    """
    s = settings or ADMMSettings()
    P = np.asarray(P.toarray() if sp.issparse(P) else P, dtype=np.float64)
    A = np.asarray(A.toarray() if sp.issparse(A) else A, dtype=np.float64)
    n, m = P.shape[0], A.shape[0]
    A = A.reshape(m, n)
    eq = np.zeros(m, bool) if eq_rows is None else np.asarray(eq_rows, bool)
    free = np.zeros(m, bool) if free_rows is None else np.asarray(free_rows, bool)
    free = free & ~eq
    D, E, c = ruiz_equilibrate(P, A, s.scaling_iter)
    Ps = c * D[:, None] * P * D[None, :]
    As = E[:, None] * A * D[None, :]
    Rbase = np.where(eq, s.rho_eq_scale, 1.0)
    ladder = np.asarray(s.rho_ladder, np.float64)
    if _single_rung(s):  # only the start rung is ever used: compute its inverse alone
        r0 = _nearest_rung(s)
        ladder = ladder[r0 : r0 + 1]
    Kinv = np.empty((len(ladder), n, n))
    for r, rho in enumerate(ladder):
        R = np.where(free, s.rho_free, rho * Rbase)
        K = Ps + s.sigma * np.eye(n) + As.T @ (R[:, None] * As)
        Ki = spd_inverse(K)
        Kinv[r] = 0.5 * (Ki + Ki.T)
    dt = np.dtype(s.dtype)
    return ADMMFactor(
        sparse=sparse_pattern(As, dt) if _use_sparse(As, s.products) else None,
        P=Ps.astype(dt),
        A=As.astype(dt),
        D=D.astype(dt),
        E=E.astype(dt),
        c=np.asarray(c, dt),
        Kinv=Kinv.astype(dt),
        ladder=ladder.astype(dt),
        Rbase=Rbase.astype(dt),
        free=free,
        settings=s,
    )


# ------------------------------------------------------------------------- iterations (JAX)
class ADMMState(NamedTuple):
    """Result of :func:`admm_iterate` (unscaled; leading batch axis ``B``)."""

    x: jax.Array  # (B, n)
    z: jax.Array  # (B, m)  A x projected on [l, u]
    y: jax.Array  # (B, m)  OSQP sign convention
    prim_res: jax.Array  # (B,) ‖Ax − z‖∞ at the last check
    dual_res: jax.Array  # (B,) ‖Px + q + Aᵀy‖∞ at the last check
    status: jax.Array  # (B,) int32 Status codes
    iterations: jax.Array  # (B,) iterations each QP ran
    rho: jax.Array  # (B,) final rho of each QP
    delta_x: jax.Array  # (B, n) x − x_prev at the last check (dual infeasibility certificate)
    delta_y: jax.Array  # (B, m) y − y_prev at the last check (primal infeasibility certificate)
    rung_matmuls: jax.Array  # () number of (B,n)x(n,n) K⁻¹ products executed


class _Scaled(NamedTuple):
    """The scaled batch inside :func:`admm_iterate`: the factor's arrays and the scaled data."""

    P: jax.Array  # (n, n) P̄
    A: jax.Array  # (m, n) Ā
    D: jax.Array  # (n,)
    E: jax.Array  # (m,)
    c: jax.Array  # ()
    Dinv: jax.Array  # (n,)
    Einv: jax.Array  # (m,)
    Kinv: jax.Array  # (L, n, n)
    ladder: jax.Array  # (L,)
    Rbase: jax.Array  # (m,)
    free: jax.Array  # (m,) bool
    sp: SparsePattern | None  # nonzeros of Ā (sparse products) or None (dense)
    q: jax.Array  # (B, n) q̄ = c·D q
    lb: jax.Array  # (B, m) l̄ = E l
    ub: jax.Array  # (B, m) ū = E u
    l: jax.Array  # (B, m) unscaled l (infeasibility certificates)
    u: jax.Array  # (B, m) unscaled u


class _Carry(NamedTuple):
    """Loop state of :func:`admm_iterate` (scaled iterates), one check chunk per loop step."""

    x: jax.Array  # (B, n)
    z: jax.Array  # (B, m)
    y: jax.Array  # (B, m)
    rung: jax.Array  # (B,) int32 ladder index of each QP
    status: jax.Array  # (B,) int32, RUNNING_CODE until a check decides
    iterations: jax.Array  # (B,) int32 iterations each QP ran
    prim: jax.Array  # (B,) unscaled primal residual at the last check
    dual: jax.Array  # (B,) unscaled dual residual at the last check
    dx: jax.Array  # (B, n) x − x_prev at the last check (scaled)
    dy: jax.Array  # (B, m) y − y_prev at the last check (scaled)
    chunk: jax.Array  # () int32 chunks done
    matmuls: jax.Array  # () int32 K⁻¹ products executed


def _inf_norm(v):
    return jnp.max(jnp.abs(v), axis=-1, initial=0.0)


def _scale_problem(factor: ADMMFactor, q, l, u) -> _Scaled:
    # (jnp.asarray: the factor may be closed over as NumPy constants inside a user's jit)
    Pb, Ab, D, E, c = (jnp.asarray(v) for v in (factor.P, factor.A, factor.D, factor.E, factor.c))
    Kinv, ladder, Rbase, free = (
        jnp.asarray(v) for v in (factor.Kinv, factor.ladder, factor.Rbase, factor.free)
    )
    return _Scaled(
        P=Pb,
        A=Ab,
        D=D,
        E=E,
        c=c,
        Dinv=1.0 / D,
        Einv=1.0 / E,
        Kinv=Kinv,
        ladder=ladder,
        Rbase=Rbase,
        free=free,
        sp=None if factor.sparse is None else SparsePattern(*map(jnp.asarray, factor.sparse)),
        q=c * D * q,
        lb=E * l,
        ub=E * u,
        l=l,
        u=u,
    )


def _mul_A(pb: _Scaled, x):
    """``Ā x`` for ``x (B, n)`` -> ``(B, m)``: a matmul, or a sum over the nonzeros."""
    if pb.sp is None:
        return x @ pb.A.T
    return jnp.sum(x[:, pb.sp.rows] * pb.sp.rvals, axis=-1)


def _mul_At(pb: _Scaled, y):
    """``Āᵀ y`` for ``y (B, m)`` -> ``(B, n)``."""
    if pb.sp is None:
        return y @ pb.A
    return jnp.sum(y[:, pb.sp.cols] * pb.sp.cvals, axis=-1)


def _mul_A_last(pb: _Scaled, xT):
    """``Ā x`` with the batch as the last axis: ``(n, B)`` -> ``(m, B)``."""
    if pb.sp is None:
        return pb.A @ xT
    return jnp.sum(pb.sp.rvals[:, :, None] * xT[pb.sp.rows], axis=1)


def _mul_At_last(pb: _Scaled, yT):
    """``Āᵀ y`` with the batch as the last axis: ``(m, B)`` -> ``(n, B)``."""
    if pb.sp is None:
        return pb.A.T @ yT
    return jnp.sum(pb.sp.cvals[:, :, None] * yT[pb.sp.cols], axis=1)


def _initial_rung(pb: _Scaled, s: ADMMSettings, B: int, rho0, dt) -> jax.Array:
    if rho0 is None:
        return jnp.full((B,), _start_rung(s), jnp.int32)
    # per-QP start (e.g. the rho a previous run ended with): the nearest rung
    lr = jnp.log(jnp.broadcast_to(jnp.asarray(rho0, dt), (B,)))
    rung = jnp.argmin(jnp.abs(lr[:, None] - jnp.log(pb.ladder)[None, :]), axis=-1)
    return rung.astype(jnp.int32)


def _single_rung(s: ADMMSettings) -> bool:
    """Whether no rule can move a QP off its start rung (no adaptive rho, and no stages with a
    patience): the factor then holds that rung alone."""
    return not s.adaptive_rho and (s.stage_iter is None or s.rho_patience is None)


def _start_rung(s: ADMMSettings) -> int:
    """The start rung's index in the factor's ladder (:func:`_single_rung`: its only one)."""
    return 0 if _single_rung(s) else _nearest_rung(s)


def _nearest_rung(s: ADMMSettings) -> int:
    return int(np.argmin(np.abs(np.log(np.asarray(s.rho_ladder)) - np.log(s.rho))))


def _row_rho(pb: _Scaled, s: ADMMSettings, rung):
    """Per-row step sizes ``R`` (B, m): rung's rho × row multiplier, or rho_free on free rows."""
    rho = pb.ladder[rung]
    dt = pb.P.dtype
    return jnp.where(
        pb.free[None, :], jnp.asarray(s.rho_free, dt), rho[:, None] * pb.Rbase[None, :]
    )


def _kinv_apply(pb: _Scaled, rhs, rung, active, batch_last: bool = False):
    """``K⁻¹_r · rhs`` for each QP's rung ``r``: one matmul per rung in use, then a select (a
    rolled loop keeps compile time small).  ``rhs`` is ``(B, n)``, or ``(n, B)`` with
    ``batch_last``.  Returns ``(out, rung matmuls executed)``."""

    def body(r, acc):
        out, cnt = acc
        sel = (rung == r) & active
        use = jnp.any(sel)
        if batch_last:  # K⁻¹ is symmetric: K⁻¹·rhs either way
            new, mask = (lambda: pb.Kinv[r] @ rhs), sel[None, :]
        else:
            new, mask = (lambda: rhs @ pb.Kinv[r]), sel[:, None]
        out = lax.cond(use, lambda o: jnp.where(mask, new(), o), lambda o: o, out)
        return out, cnt + use.astype(jnp.int32)

    L = pb.Kinv.shape[0]
    return lax.fori_loop(0, L, body, (jnp.zeros_like(rhs), jnp.zeros((), jnp.int32)))


def _step(pb: _Scaled, s: ADMMSettings, x, z, y, rung, active):
    """One ADMM iteration (OSQP's, over-relaxed) with each QP on its own rung of the ladder."""
    R = _row_rho(pb, s, rung)
    rhs = s.sigma * x - pb.q + _mul_At(pb, R * z - y)
    xt, k = _kinv_apply(pb, rhs, rung, active)  # x̃ = K⁻¹(σx − q + Āᵀ(Rz − y))
    zt = _mul_A(pb, xt)
    xn = s.alpha * xt + (1.0 - s.alpha) * x
    zr = s.alpha * zt + (1.0 - s.alpha) * z
    zn = jnp.clip(zr + y / R, pb.lb, pb.ub)  # z ← Π[l,u](αz̃ + (1−α)z + y/R)
    yn = y + R * (zr - zn)
    a = active[:, None]
    return jnp.where(a, xn, x), jnp.where(a, zn, z), jnp.where(a, yn, y), k


def _fixed_rung_iterations(pb: _Scaled, s: ADMMSettings, K_fix, R_fix, x, z, y, active, all_active):
    """``check_every`` iterations of :func:`_step` on one fixed rung, with the batch as the last
    axis: the products become (m, n)·(n, B) instead of (B, n)·(n, m), which XLA's CPU backend
    runs ≈ 3× faster at these shapes (n, m ≲ 100; measured, docs/experiments/qp-backends.md).
    Returns ``(x, z, y, x_prev, y_prev)``."""
    R, Rinv = R_fix.T, (1.0 / R_fix).T  # (m, 1)
    x, z, y, xp, yp, _ = _last_axis_iterations(
        pb, s, lambda rhs: (K_fix @ rhs, 0), R, Rinv, x, z, y, active, all_active
    )
    return x, z, y, xp, yp


def _ladder_iterations(pb: _Scaled, s: ADMMSettings, x, z, y, rung, active):
    """``check_every`` iterations of :func:`_step` (each QP on its own rung) with the batch as
    the last axis, the layout of the sparse products (a gather then reads each of ``x``'s rows
    as one contiguous batch vector).  Returns ``(x, z, y, x_prev, y_prev, K⁻¹ products)``."""
    R = _row_rho(pb, s, rung).T  # (m, B)

    def kinv(rhs):
        return _kinv_apply(pb, rhs, rung, active, batch_last=True)

    return _last_axis_iterations(pb, s, kinv, R, 1.0 / R, x, z, y, active, False)


def _last_axis_iterations(pb: _Scaled, s: ADMMSettings, kinv, R, Rinv, x, z, y, active, all_active):
    """The ADMM iterations of :func:`_step` on transposed iterates ``(n, B)``, ``(m, B)``;
    ``kinv(rhs) -> (K⁻¹ rhs, products)``.  Returns ``(x, z, y, x_prev, y_prev, products)``."""
    qT, lT, uT = pb.q.T, pb.lb.T, pb.ub.T
    a = active[None, :]

    def it(_, c_):
        xT, zT, yT, _xp, _yp, cnt = c_
        rhs = s.sigma * xT - qT + _mul_At_last(pb, R * zT - yT)
        xt, k = kinv(rhs)  # K⁻¹ is symmetric
        zt = _mul_A_last(pb, xt)
        xn = s.alpha * xt + (1.0 - s.alpha) * xT
        zr = s.alpha * zt + (1.0 - s.alpha) * zT
        zn = jnp.clip(zr + yT * Rinv, lT, uT)
        yn = yT + R * (zr - zn)
        if not all_active:  # QPs that have stopped keep their iterate
            xn, zn, yn = (jnp.where(a, new, old) for new, old in ((xn, xT), (zn, zT), (yn, yT)))
        return xn, zn, yn, xT, yT, cnt + k

    xT, zT, yT = x.T, z.T, y.T
    zero = jnp.zeros((), jnp.int32)
    xT, zT, yT, xpT, ypT, cnt = lax.fori_loop(0, s.check_every, it, (xT, zT, yT, xT, yT, zero))
    return xT.T, zT.T, yT.T, xpT.T, ypT.T, cnt


class _Residuals(NamedTuple):
    prim: jax.Array  # (B,) unscaled ‖Ax − z‖∞
    dual: jax.Array  # (B,) unscaled ‖Px + q + Aᵀy‖∞
    solved: jax.Array  # (B,) bool, OSQP's termination test
    Ax: jax.Array  # scaled products, reused by the rho update
    Px: jax.Array
    Aty: jax.Array


def _residuals(pb: _Scaled, s: ADMMSettings, x, z, y) -> _Residuals:
    """OSQP's unscaled termination test (``scaled_termination = False``)."""
    Ax = _mul_A(pb, x)
    Px = x @ pb.P
    Aty = _mul_At(pb, y)
    Dinv, Einv, c = pb.Dinv, pb.Einv, pb.c
    prim = _inf_norm(Einv * (Ax - z))
    dual = _inf_norm(Dinv * (Px + pb.q + Aty)) / c
    n_Ax, n_z = _inf_norm(Einv * Ax), _inf_norm(Einv * z)
    n_Px, n_Aty, n_q = (
        _inf_norm(Dinv * Px) / c,
        _inf_norm(Dinv * Aty) / c,
        _inf_norm(Dinv * pb.q) / c,
    )
    eps_p = s.eps_abs + s.eps_rel * jnp.maximum(n_Ax, n_z)
    eps_d = s.eps_abs + s.eps_rel * jnp.maximum(jnp.maximum(n_Px, n_Aty), n_q)
    solved = (prim <= eps_p) & (dual <= eps_d)
    return _Residuals(prim, dual, solved, Ax, Px, Aty)


def _primal_infeasible(pb: _Scaled, s: ADMMSettings, y, yp):
    """OSQP's certificate: δy projected on the polar of the recession cone of [l, u]."""
    finite_l, finite_u = jnp.isfinite(pb.l), jnp.isfinite(pb.u)
    dy = pb.E * (y - yp) / pb.c
    dy = jnp.where(finite_u, dy, jnp.minimum(dy, 0.0))
    dy = jnp.where(finite_l, dy, jnp.maximum(dy, 0.0))
    ndy = _inf_norm(dy)
    Atdy = _inf_norm(pb.Dinv * _mul_At(pb, y - yp)) / pb.c
    supp = jnp.sum(
        jnp.where(dy > 0, jnp.where(finite_u, pb.u, 0.0) * dy, 0.0)
        + jnp.where(dy < 0, jnp.where(finite_l, pb.l, 0.0) * dy, 0.0),
        axis=-1,
    )
    return (ndy > 1e-30) & (Atdy <= s.eps_prim_inf * ndy) & (supp <= -s.eps_prim_inf * ndy)


def _dual_infeasible(pb: _Scaled, s: ADMMSettings, x, xp):
    """OSQP's certificate on δx: Pδx ≈ 0, qᵀδx < 0, Aδx in the recession cone of [l, u]."""
    finite_l, finite_u = jnp.isfinite(pb.l), jnp.isfinite(pb.u)
    dxs = x - xp
    dx = pb.D * dxs
    ndx = _inf_norm(dx)
    Pdx = _inf_norm(pb.Dinv * (dxs @ pb.P)) / pb.c
    qdx = jnp.sum(pb.q * dxs, axis=-1) / pb.c
    Adx = pb.Einv * _mul_A(pb, dxs)
    tol = s.eps_dual_inf * ndx[:, None]
    ok_rows = jnp.where(finite_u, Adx <= tol, True) & jnp.where(finite_l, Adx >= -tol, True)
    return (
        (ndx > 1e-30)
        & (Pdx <= s.eps_dual_inf * ndx)
        & (qdx <= -s.eps_dual_inf * ndx)
        & jnp.all(ok_rows, axis=-1)
    )


def _adapt_rung(pb: _Scaled, s: ADMMSettings, r: _Residuals, z, rung, status, active):
    """OSQP's residual-balancing rho rule on scaled quantities, snapped to the nearest rung."""
    sp_ = _inf_norm(r.Ax - z) / (jnp.maximum(_inf_norm(r.Ax), _inf_norm(z)) + 1e-30)
    sd_ = _inf_norm(r.Px + pb.q + r.Aty) / (
        jnp.maximum(jnp.maximum(_inf_norm(r.Px), _inf_norm(r.Aty)), _inf_norm(pb.q)) + 1e-30
    )
    rho_new = pb.ladder[rung] * jnp.sqrt(sp_ / (sd_ + 1e-30))
    lr = jnp.log(jnp.clip(rho_new, 1e-30, 1e30))
    best = jnp.argmin(jnp.abs(lr[:, None] - jnp.log(pb.ladder)[None, :]), axis=-1)
    keep = ~jnp.isfinite(lr) | (r.prim == 0) | (r.dual == 0)
    return jnp.where(active & (status == RUNNING_CODE) & ~keep, best.astype(jnp.int32), rung)


def _check(pb: _Scaled, s: ADMMSettings, x, z, y, xp, yp, rung, status, active):
    """Termination, certificates and NaN guard for the active QPs; then the rho update.
    Returns ``(prim, dual, status, rung)``."""
    r = _residuals(pb, s, x, z, y)
    pinf = _primal_infeasible(pb, s, y, yp)
    dinf = _dual_infeasible(pb, s, x, xp)
    bad = ~(
        jnp.all(jnp.isfinite(x), -1) & jnp.all(jnp.isfinite(y), -1) & jnp.all(jnp.isfinite(z), -1)
    )
    new = jnp.where(
        bad,
        STATUS_CODES.ERROR,
        jnp.where(
            r.solved,
            STATUS_CODES.SOLVED,
            jnp.where(
                pinf,
                STATUS_CODES.PRIMAL_INFEASIBLE,
                jnp.where(dinf, STATUS_CODES.DUAL_INFEASIBLE, RUNNING_CODE),
            ),
        ),
    )
    status = jnp.where(active, new, status)
    if s.adaptive_rho:
        rung = _adapt_rung(pb, s, r, z, rung, status, active)
    return r.prim, r.dual, status, rung


def _chunk(pb: _Scaled, s: ADMMSettings, fixed, carry: _Carry, all_active=False) -> _Carry:
    """``check_every`` iterations, then one check.  ``fixed`` is ``(K⁻¹, R)`` of the static
    fixed-rung path, or ``None``."""
    x, z, y, rung = carry.x, carry.z, carry.y, carry.rung
    cnt = carry.matmuls
    active = carry.status == RUNNING_CODE

    def it(_, c_):
        x, z, y, _xp, _yp, cnt = c_
        xn, zn, yn, k = _step(pb, s, x, z, y, rung, active)
        return xn, zn, yn, x, y, cnt + k

    if fixed is not None:
        K_fix, R_fix = fixed
        x, z, y, xp, yp = _fixed_rung_iterations(pb, s, K_fix, R_fix, x, z, y, active, all_active)
        cnt = cnt + s.check_every * jnp.any(active).astype(jnp.int32)
    elif pb.sp is not None:
        x, z, y, xp, yp, k = _ladder_iterations(pb, s, x, z, y, rung, active)
        cnt = cnt + k
    else:
        x, z, y, xp, yp, cnt = lax.fori_loop(0, s.check_every, it, (x, z, y, x, y, cnt))
    prim_n, dual_n, status_n, rung = _check(pb, s, x, z, y, xp, yp, rung, carry.status, active)
    return _Carry(
        x=x,
        y=y,
        z=z,
        rung=rung,
        status=status_n,
        iterations=carry.iterations + jnp.where(active, s.check_every, 0),
        prim=jnp.where(active, prim_n, carry.prim),
        dual=jnp.where(active, dual_n, carry.dual),
        dx=jnp.where(active[:, None], x - xp, carry.dx),
        dy=jnp.where(active[:, None], y - yp, carry.dy),
        chunk=carry.chunk + 1,
        matmuls=cnt,
    )


def admm_iterate(
    factor: ADMMFactor,
    q: Any,
    l: Any,
    u: Any,
    x0: Any = None,
    y0: Any = None,
    iters: int | None = None,
    rho0: Any = None,
) -> ADMMState:
    """Run batched ADMM (no polish) on unscaled ``q (B, n), l (B, m), u (B, m)``; jittable.

    ``iters`` (static; default ``settings.max_iter``) is rounded up to a multiple of
    ``check_every``.  ``rho0`` (scalar or ``(B,)``, optional) starts each QP on the ladder rung
    nearest to it (default: ``settings.rho``).  Returns an :class:`ADMMState`.
    """
    s = factor.settings
    dt = factor.P.dtype
    squeeze = jnp.ndim(q) == 1
    q, l, u = (jnp.atleast_2d(jnp.asarray(v, dt)) for v in (q, l, u))
    B = q.shape[0]
    n, m = factor.n, factor.m
    iters = s.max_iter if iters is None else int(iters)
    n_chunks = -(-iters // s.check_every)
    pb = _scale_problem(factor, q, l, u)

    # warm start, scaled: x̄ = D⁻¹x, ȳ = c E⁻¹ y, z̄ = Π(Āx̄)
    xs = jnp.zeros((B, n), dt) if x0 is None else jnp.atleast_2d(jnp.asarray(x0, dt)) * pb.Dinv
    if y0 is None:
        ys = jnp.zeros((B, m), dt)
    else:
        ys = pb.c * jnp.atleast_2d(jnp.asarray(y0, dt)) * pb.Einv
    zs = jnp.clip(_mul_A(pb, xs), pb.lb, pb.ub)
    rung = _initial_rung(pb, s, B, rho0, dt)

    # Static fast path: every QP starts on the same rung and no rho update can happen before
    # the last iteration (one check chunk, or adaptation off), so K⁻¹ is one fixed matrix and
    # the step sizes R are constants of the loop (no per-step rung dispatch).
    fixed = None
    if rho0 is None and (n_chunks == 1 or not s.adaptive_rho):
        fixed = (pb.Kinv[_start_rung(s)], _row_rho(pb, s, rung)[:1])  # R: (1, m), equal rows

    inf = jnp.full((B,), jnp.inf, dt)
    zero_b = jnp.zeros((B,), jnp.int32)
    zero = jnp.zeros((), jnp.int32)
    init = _Carry(
        xs,
        zs,
        ys,
        rung,
        zero_b,
        zero_b,
        inf,
        inf,
        jnp.zeros_like(xs),
        jnp.zeros_like(ys),
        zero,
        zero,
    )
    if n_chunks == 1:
        # one chunk: no loop, every QP active; outputs nobody uses (the check, when a jitted
        # caller keeps only x) are then removed by XLA
        out = _chunk(pb, s, fixed, init, all_active=True)
    else:
        out = lax.while_loop(
            lambda c: (c.chunk < n_chunks) & jnp.any(c.status == RUNNING_CODE),
            lambda c: _chunk(pb, s, fixed, c),
            init,
        )
    status = jnp.where(out.status == RUNNING_CODE, STATUS_CODES.MAX_ITER, out.status).astype(
        jnp.int32
    )
    res = ADMMState(
        x=pb.D * out.x,
        z=pb.Einv * out.z,
        y=pb.E * out.y / pb.c,
        prim_res=out.prim,
        dual_res=out.dual,
        status=status,
        iterations=out.iterations,
        rho=pb.ladder[out.rung],
        delta_x=pb.D * out.dx,
        delta_y=pb.E * out.dy / pb.c,
        rung_matmuls=out.matmuls,
    )
    if squeeze:
        res = ADMMState(*(v[0] for v in res[:-1]), res[-1])
    return res


#: :func:`admm_iterate` jitted once for the host-side backend (``iters`` static); one module-level
#: function so that every backend call shares its compiled code
admm_iterate_jit = jax.jit(admm_iterate, static_argnames=("iters",))


def admm_projector(factor: ADMMFactor, iters: int | None = None) -> JaxProjector:
    """:func:`admm_iterate` on ``factor`` as a :class:`solvers.JaxProjector`: the jittable
    ``project(q, l, u, x0=None, y0=None) -> ADMMState`` of a fixed ``P`` and ``A``.

    ``iters`` (default ``settings.max_iter``) is the fixed budget of every call; the call is
    exactly ``admm_iterate(factor, q, l, u, x0=x0, y0=y0, iters=iters)``.
    """
    if not isinstance(factor, ADMMFactor):
        raise ValueError(f"factor must be an ADMMFactor, got {type(factor).__name__}")
    if iters is not None and (
        isinstance(iters, bool) or not isinstance(iters, (int, np.integer)) or iters < 0
    ):
        raise ValueError(f"iters must be None or an integer ≥ 0, got {iters!r}")

    def project(q: Any, l: Any, u: Any, x0: Any = None, y0: Any = None) -> ADMMState:
        return admm_iterate(factor, q, l, u, x0=x0, y0=y0, iters=iters)

    return project


def flops_per_call(
    n: int, m: int, B: int, iters: int, rung_matmuls: int, check_every: int
) -> float:
    """Matmul FLOPs of one :func:`admm_iterate` call on a dense batch of ``B`` that ran ``iters``
    iterations and ``rung_matmuls`` ``K⁻¹`` products (what the backend reports as its work)."""
    for name, v in (("n", n), ("m", m), ("B", B), ("iters", iters), ("rung_matmuls", rung_matmuls)):
        if v < 0:
            raise ValueError(f"{name} must be ≥ 0, got {v!r}")
    if check_every < 1:
        raise ValueError(f"check_every must be ≥ 1, got {check_every!r}")
    checks = (iters // check_every) * B * (8.0 * m * n + 4.0 * n * n)
    return 4.0 * m * n * B * iters + 2.0 * n * n * B * rung_matmuls + checks


def flops_per_iteration(n: int, m: int, rungs_used: float = 1.0) -> float:
    """Floating-point operations of one ADMM iteration for one QP (matmuls only).

    ``Āᵀ(Rz − y)``: 2mn; ``K⁻¹·rhs``: 2n² per rung in use; ``Āx̃``: 2mn.
    """
    return 4.0 * m * n + 2.0 * n * n * rungs_used
