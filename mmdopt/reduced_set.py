"""Reduced-set selection: choose m of n obstacle-trajectory samples and their weights ᾱ.

One signature for every method (paper §"Proposed Reduced-Set Selection")::

    rs = select_reduced_set(key, samples, m, method="kernel-cem", config=ReducedSetConfig())
    rs.indices (m,), rs.weights (m,) summing to 1, rs.alpha (n,), rs.method, rs.mmd2, rs.bandwidth

Methods
-------
``"kernel-cem"`` the paper's eq. (red_set_opt_proposed) by CEM over α ∈ ℝⁿ, then the refinement
              eq. (red_set_opt_proposed_2) of the m weights.  Cost
                  J(α) = αᵀKα − (2/n)1ᵀKα + (1/n²)1ᵀK1 − β Σ_top-m|α| / Σ_bottom-(n−m)|α|
              i.e. the **exact** squared MMD between the uniform embedding and the α-weighted one.
              The reference code (and the paper's displayed expansion) halves the linear term,
              whose unpenalised minimiser is then 1/(2n) instead of 1/n; fixed here.
              The ratio's denominator is guarded: ``bottom + ratio_eps·(top + bottom)`` (the ratio
              is therefore ≤ 1/ratio_eps; the reference's is unbounded).
              CEM as the reference (population 100, 20 elites kept, 100 iterations, Σ₀ = 5I,
              Σ ← cov(elites) + 0.01I) but as a ``lax.scan`` (not unrolled) with a fresh PRNG key
              every iteration (the reference reuses one), and the best α seen over all
              iterations is returned (the reference: best of the last; with elitism these agree).
              The reduced set is the m largest |α*_j|.
              Three defaults differ from the reference, chosen by measurement
              (docs/experiments/synthetic.md gives the figures): CEM runs over u with α = u/n
              (``alpha_scale=None``; the reference samples α itself, where the 0.01·I floor
              alone adds noise of the order of tr K to an MMD whose differences are far
              smaller, so its selection is noise-driven), β = 0.01 (on that scale the ratio is
              O(1)) and smoothing 0.5.
              ``ReducedSetConfig.reference()`` restores the reference's settings.
              Implementation (speed, docs/experiments/synthetic.md): the CEM ranks in float32 (the
              MMD² is
              evaluated as (α − 1/n)ᵀK(α − 1/n), without cancellation), every normal draw is made
              in one call before the scan, and the top-m sum of |α| is a radix select on the
              float bit patterns (no sort).  Above n = 256 samples (``sampler="auto"``) Σ is
              kept factored (a·I + the last 16 elite sets) and drawn from without a Cholesky:
              the same distribution, O(n·E·W) instead of O(n³) per iteration.  Above n = 256
              (``gram="auto"``) the population's MMD² is ‖(α − 1/n)L‖² with L the pivoted-
              Cholesky factor of K (rank ≤ 64, used only when every residual entry of K − LLᵀ is
              ≤ ``gram_tol`` = 1e-9, else the full K): O(n·r) instead of O(n²) per candidate.
``"herding"`` greedy MMD minimisation = kernel herding without replacement (Chen et al., 2010):
              step t adds argmax_j (1/n)Σ_i K_ij − (1/(t+1)) Σ_{s∈S} K_js.
``"uniform"`` a uniformly random m-subset (the paper's "exhaustive search" baseline).
``"conflict"`` de Groot et al. as in the reference's baseline: score g_j = max_k f(ego_guess_k,
              obstacle centre_j,k), f the ellipse collision function (a, b); top-m by score.
              Needs ``ego_guess`` (K, 2).  Beyond ``KERNEL_POOL`` samples its weights,
              bandwidth and MMD² are estimated on a pool of that many (its choice and its
              scenario cost read none of them).

Weights of the m selected samples (``config.weights``), the same for every method:
``"simplex"`` (default) eq. (red_set_opt_proposed_2) with ridge,
              ``min ½ᾱᵀ(K_RR + ρI)ᾱ − (1/n)1ᵀK_NR ᾱ  s.t. 1ᵀᾱ = 1, ᾱ ≥ 0``: the closed-form KKT
              solution is used when it is already non-negative (the usual case), otherwise an
              accelerated projected-gradient solve on the simplex (warm-started from the projected
              KKT point).  Non-negative weights keep the collision surrogate a mixture of
              non-negative masses (a negative ᾱ_j would *reward* collision with sample j).
              The signed KKT solution often has negative weights, and the simplex constraint
              costs little MMD² (docs/experiments/synthetic.md).
``"kkt"``     the reference: the equality-constrained QP only (ᾱ may be negative).
``"uniform"`` ᾱ = 1/m.

Features are the flattened waypoints ``samples.reshape(n, 2K) * feature_scale`` (predictor-agnostic;
the reference uses its generator's coefficient vectors instead).  Kernel bandwidth: the median
heuristic on those features unless ``config.bandwidth`` is set (the reference's σ = 30 was on
coefficient vectors and makes K nearly flat: rank ≈ 5).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import partial
from types import MappingProxyType

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike

from ._x64 import x64
from .geometry import Footprint
from .kernels import gaussian_gram, median_heuristic, one_minus_gaussian_gram
from .samples import ReducedSet

__all__ = [
    "SELECTORS",
    "SELECTOR_ALIASES",
    "selector_name",
    "WEIGHT_MODES",
    "ReducedSetConfig",
    "ReducedSet",
    "select_reduced_set",
    "select_reduced_sets",
    "select_reduced_set_unchecked",
    "refine_weights",
    "project_simplex",
    "reduced_set_objective",
]

#: the reduced-set selectors (``method=`` of :func:`select_reduced_set`): "kernel-cem" (the
#: paper's MMD selection by CEM), "herding", "uniform" (a random m-subset), "conflict" (de
#: Groot's deepest conflicts with an ego guess)
SELECTORS = ("kernel-cem", "herding", "uniform", "conflict")

#: beyond this many samples de Groot's selector ("conflict", whose choice reads no kernel and
#: whose scenario cost reads no weight) fits the weights, bandwidth and reported MMD² of its set
#: on a pool of this many samples (evenly spaced) with the chosen ones, not on the n × n Gram,
#: which dominated its plan at the thousands of futures per car a small ε needs
#: (docs/experiments/frontier.md); its plans do not change
KERNEL_POOL = 256
#: former selector names, still accepted (they were the plan methods' names)
SELECTOR_ALIASES: Mapping[str, str] = MappingProxyType(
    {"mmd": "kernel-cem", "random": "uniform", "degroot": "conflict"}
)


def selector_name(method: str) -> str:
    """The selector named ``method`` (:data:`SELECTORS`, or a former name of
    :data:`SELECTOR_ALIASES`); ``ValueError`` naming ``method`` otherwise."""
    name = SELECTOR_ALIASES.get(method, method) if isinstance(method, str) else method
    if name not in SELECTORS:
        raise ValueError(f"method must be one of {SELECTORS}, got {method!r}")
    return name


WEIGHT_MODES = ("simplex", "kkt", "uniform")
#: how the CEM draws from N(μ, Σ): "cholesky" (a Cholesky of the n × n Σ every iteration,
#: O(n³)), "factor" (Σ kept as a·I + L Lᵀ with L the last ``cov_window`` elite sets, O(n·E·W)
#: per draw, no factorisation), "auto" = "factor" when n > FACTOR_MIN_N (both give the same
#: MMD² of the refined set; their times: benchmarks/reduced_set_timing.py --samplers,
#: docs/experiments/synthetic.md).
SAMPLERS = ("auto", "cholesky", "factor")
FACTOR_MIN_N = 256
#: how the CEM evaluates the quadratic form dᵀKd of its population: "full" (d @ K, O(n²) per
#: candidate), "lowrank" (‖dL‖² with L the rank-``gram_rank`` pivoted-Cholesky factor of K when
#: its largest residual diagonal is ≤ ``gram_tol``, else the full K: O(n·r)), "auto" = "lowrank"
#: when n > FACTOR_MIN_N.  A Gaussian Gram of smooth trajectory samples has a fast-decaying
#: spectrum, so a low rank holds it to the tolerance.
GRAM_MODES = ("auto", "full", "lowrank")


def _static(default):
    return field(default=default, metadata=dict(static=True))


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ReducedSetConfig:
    """Hyper-parameters of reduced-set selection.

    Sizes and modes are static (changing them recompiles); the scalars are pytree leaves (they
    can be changed, or vmapped, without recompiling).  ``bandwidth=None`` selects the median
    heuristic (a structural choice, hence a recompilation when toggled).
    """

    # static: sizes and modes
    population: int = _static(100)
    n_elite: int = _static(20)
    iterations: int = _static(75)  # reference: 100 (equal quality at 75, synthetic results)
    weights: str = _static("simplex")
    simplex_iterations: int = _static(300)
    sampler: str = _static("auto")  # see SAMPLERS
    cov_window: int = _static(16)  # "factor": elite sets kept in Σ (weight s^W dropped, W ≥ 1)
    gram: str = _static("auto")  # see GRAM_MODES
    gram_rank: int = _static(64)  # "lowrank": columns of the pivoted-Cholesky factor of K
    # leaves: tunable scalars
    beta: float = 0.01  # weight of the top/bottom separation term (reference: 1, on α-scale 1)
    bandwidth: float | None = None  # Gaussian kernel σ on the features; None = median heuristic
    feature_scale: float = 1.0  # features = waypoints * feature_scale
    alpha_scale: float | None = None  # α = alpha_scale·u, CEM over u; None = 1/n (reference: 1)
    mean0: float = 0.0  # CEM initial mean of every u_j (reference: 0)
    sigma0: float = 5.0  # CEM initial covariance sigma0·I (reference: 5)
    cov_reg: float = 0.01  # added to the elite covariance (reference: 0.01)
    smoothing: float = 0.5  # μ, Σ ← (1−s)·new + s·old (reference: 0)
    ratio_eps: float = 1e-6  # relative guard of the ratio's denominator
    ridge: float = 0.01  # ρ in the refinement QP (reference: 0.01)
    gram_tol: float = 1e-9  # "lowrank": largest residual diag(K − LLᵀ) accepted, else full K

    def replace(self, **kw) -> ReducedSetConfig:
        return dataclasses.replace(self, **kw)

    @classmethod
    def reference(cls, **kw) -> ReducedSetConfig:
        """The reference code's CEM: α-scale 1, β = 1, no smoothing, signed KKT weights
        (its σ = 30 was on coefficient vectors; pass ``bandwidth=`` to fix one here)."""
        base = dict(alpha_scale=1.0, beta=1.0, smoothing=0.0, weights="kkt")
        base.update(kw)
        return cls(**base)

    def __post_init__(self):
        if isinstance(self.population, int) and isinstance(self.n_elite, int):
            if not 1 <= self.n_elite < self.population:
                raise ValueError("n_elite must satisfy 1 <= n_elite < population")
            if self.n_elite < 2:
                raise ValueError("n_elite must be >= 2 (the elite covariance needs two samples)")
        if isinstance(self.iterations, int) and self.iterations < 1:
            raise ValueError("iterations must be >= 1")
        if isinstance(self.weights, str) and self.weights not in WEIGHT_MODES:
            raise ValueError(f"weights must be one of {WEIGHT_MODES}, got {self.weights!r}")
        if not isinstance(self.gram, str) or self.gram not in GRAM_MODES:
            raise ValueError(
                f"ReducedSetConfig.gram must be one of {GRAM_MODES}, got {self.gram!r}"
            )
        if not isinstance(self.sampler, str) or self.sampler not in SAMPLERS:
            raise ValueError(
                f"ReducedSetConfig.sampler must be one of {SAMPLERS}, got {self.sampler!r}"
            )
        for name in (
            "population",
            "n_elite",
            "iterations",
            "simplex_iterations",
            "cov_window",
            "gram_rank",
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer):
                raise ValueError(f"ReducedSetConfig.{name} must be an int, got {v!r}")
        if self.cov_window < 1:
            raise ValueError(f"ReducedSetConfig.cov_window must be >= 1, got {self.cov_window}")
        if self.gram_rank < 1:
            raise ValueError(f"ReducedSetConfig.gram_rank must be >= 1, got {self.gram_rank}")
        if not isinstance(self.weights, str):
            raise ValueError(f"ReducedSetConfig.weights must be a string, got {self.weights!r}")
        # leaves (checked when concrete: inside a trace they are tracers)
        # (bandwidth: its sign is checked by select_reduced_set, naming config.bandwidth)
        positive = ("sigma0", "ratio_eps", "feature_scale", "alpha_scale", "gram_tol")
        nonneg = ("beta", "cov_reg", "ridge")
        for f in dataclasses.fields(self):
            if f.metadata.get("static"):
                continue
            v = getattr(self, f.name)
            if isinstance(v, str | bytes | complex) or isinstance(v, bool):
                raise ValueError(f"ReducedSetConfig.{f.name} must be a real number, got {v!r}")
            # only plain scalars: tracers, batched arrays and pytree placeholders pass through
            if not isinstance(v, int | float | np.number) and not (
                isinstance(v, np.ndarray | jax.Array)
                and not isinstance(v, jax.core.Tracer)
                and np.ndim(v) == 0
            ):
                continue
            x = float(v)
            if not np.isfinite(x):
                raise ValueError(f"ReducedSetConfig.{f.name} must be finite, got {v}")
            if f.name in positive and not x > 0:
                raise ValueError(f"ReducedSetConfig.{f.name} must be > 0, got {v}")
            if f.name in nonneg and x < 0:
                raise ValueError(f"ReducedSetConfig.{f.name} must be >= 0, got {v}")
            if f.name == "smoothing" and not 0 <= x < 1:
                raise ValueError(f"ReducedSetConfig.smoothing must lie in [0, 1), got {v}")


# ---------------------------------------------------------------------------------------------
# building blocks


@x64
def project_simplex(v: ArrayLike) -> jax.Array:
    """Euclidean projection of ``v`` (..., m) onto the probability simplex (Duchi et al., 2008).

    ``max(v − θ, 0)`` with ``θ = max_k (Σ_{i≤k} u_i − 1)/k`` over the prefixes of ``u`` = ``v``
    sorted decreasingly.  For m ≤ 128 the prefixes are formed by pairwise comparison (one fused
    O(m²) op; XLA's CPU sort costs ≈ 10 µs per call, and the simplex refinement calls this 300×).
    """
    m = v.shape[-1]
    if m > 128:
        u = jnp.sort(v, axis=-1)[..., ::-1]
        css = jnp.cumsum(u, axis=-1) - 1.0
        k = jnp.arange(1, m + 1, dtype=v.dtype)
        theta = jnp.max(css / k, axis=-1, keepdims=True)
    else:
        # prefix ending at entry j (after its ties): {i: v_i ≥ v_j}
        ge = v[..., None, :] >= v[..., :, None]  # [..., j, i]
        s = jnp.sum(jnp.where(ge, v[..., None, :], 0.0), axis=-1) - 1.0
        c = jnp.sum(ge, axis=-1).astype(v.dtype)
        theta = jnp.max(s / c, axis=-1, keepdims=True)
    return jnp.maximum(v - theta, 0.0)


def _kkt_weights(A: jax.Array, b: jax.Array) -> jax.Array:
    """argmin ½xᵀAx − bᵀx s.t. 1ᵀx = 1, A SPD: x = A⁻¹(b + λ1), λ = (1 − 1ᵀA⁻¹b)/(1ᵀA⁻¹1)."""
    cf = jax.scipy.linalg.cho_factor(A)
    ainv_b = jax.scipy.linalg.cho_solve(cf, b)
    ainv_1 = jax.scipy.linalg.cho_solve(cf, jnp.ones_like(b))
    lam = (1.0 - jnp.sum(ainv_b)) / jnp.sum(ainv_1)
    return ainv_b + lam * ainv_1


def _simplex_qp(A: jax.Array, b: jax.Array, x0: jax.Array, iterations: int) -> jax.Array:
    """min ½xᵀAx − bᵀx on the simplex by FISTA (fixed iteration count)."""
    # λ_max(A) ≤ min(‖A‖_∞, ‖A‖_F): a safe step without an eigen-solve
    lmax = jnp.minimum(jnp.max(jnp.sum(jnp.abs(A), axis=1)), jnp.sqrt(jnp.sum(A * A)))
    step = 1.0 / lmax

    def body(_, c):
        x, y, t = c
        x_new = project_simplex(y - step * (A @ y - b))
        t_new = 0.5 * (1.0 + jnp.sqrt(1.0 + 4.0 * t * t))
        y_new = x_new + ((t - 1.0) / t_new) * (x_new - x)
        return x_new, y_new, t_new

    x, _, _ = jax.lax.fori_loop(0, iterations, body, (x0, x0, jnp.ones((), x0.dtype)))
    return x


@x64
def refine_weights(K: ArrayLike, idx: ArrayLike, config: ReducedSetConfig) -> jax.Array:
    """Weights ᾱ of the reduced set ``idx`` (eq. red_set_opt_proposed_2 with ridge ρ).

    ``min ½ᾱᵀ(K_RR + ρI)ᾱ − (1/n)1ᵀK_NR ᾱ  s.t. 1ᵀᾱ = 1`` (+ ᾱ ≥ 0 for ``weights="simplex"``);
    ½ × the squared MMD of eq. (red_set_opt_proposed_2) up to a constant, plus the ridge.
    """
    return _fit_weights(K[idx][:, idx], jnp.mean(K, axis=0)[idx], config)  # b = (1/n) K_NRᵀ 1


def _fit_weights(K_RR: jax.Array, b: jax.Array, config: ReducedSetConfig) -> jax.Array:
    """:func:`refine_weights` from the reduced set's Gram ``K_RR`` and ``b = (1/n) K_NRᵀ 1``."""
    m = K_RR.shape[0]
    if config.weights == "uniform":
        return jnp.full((m,), 1.0 / m, dtype=K_RR.dtype)
    A = K_RR + config.ridge * jnp.eye(m, dtype=K_RR.dtype)
    w = _kkt_weights(A, b)
    if config.weights == "kkt":
        return w
    return jax.lax.cond(
        jnp.all(w >= 0.0),
        lambda: w,
        lambda: _simplex_qp(A, b, project_simplex(w), config.simplex_iterations),
    )


def _reduced_mmd2(D: jax.Array, idx: jax.Array, w: jax.Array) -> jax.Array:
    """MMD² between the uniform embedding of all n samples and ᾱ on ``idx``, from D = 1 − K."""
    n = D.shape[0]
    u = jnp.full((n,), 1.0 / n, dtype=D.dtype)
    return _mmd2_from(u @ D @ u, D[idx][:, idx], u @ D[:, idx], w)


def _mmd2_from(dxx: jax.Array, D_RR: jax.Array, d_xR: jax.Array, w: jax.Array) -> jax.Array:
    """MMD² from D = 1 − K: ``dxx`` the mean of D over the samples' pairs, ``D_RR`` (m, m) its
    block on the reduced set, ``d_xR`` (m,) its mean over the samples against each point."""
    dyy = w @ D_RR @ w
    dxy = d_xR @ w
    mass = 1.0 - jnp.sum(w)
    return jnp.maximum(mass * mass + (dxy - dxx) + (dxy - dyy), 0.0)


def _top_m_sum(v: jax.Array, m: int) -> jax.Array:
    """Sum of the m largest entries of each row of ``v`` (p, n), ``v ≥ 0``; exact (ties included).

    Radix select on the IEEE bit patterns (order-preserving for non-negative floats): the m-th
    largest value τ is built one bit at a time, from the highest bit on which the row's entries
    differ, each step one compare-and-count over the population, stopping once every row has
    exactly m entries ≥ the prefix (usually after a few mantissa bits; ties need every bit);
    then ``Σ_{v≥τ} v`` (or ``Σ_{v>τ} v + (m − #{v>τ})·τ`` with ties at τ).  XLA's CPU sort /
    ``top_k`` and a pairwise-rank mask are 5–10× slower at the CEM's sizes
    (docs/experiments/synthetic.md).
    """
    ut = jnp.uint32 if v.dtype == jnp.float32 else jnp.uint64
    nbits = 32 if v.dtype == jnp.float32 else 64
    n = v.shape[-1]
    bits = jax.lax.bitcast_convert_type(v, ut)
    bits_t = jnp.swapaxes(bits, -1, -2)  # (n, p): the count reduces over the major axis (faster)
    hi = jnp.max(bits, axis=-1)
    # a lower bound of the m-th largest: the smallest of the maxima of m disjoint blocks (m
    # distinct entries are ≥ it); the leading bits it shares with the row's maximum are the
    # m-th largest's too, so the select starts below them (fewer passes than from the minimum)
    bs = -(-n // m)
    blocks = jnp.pad(bits, [(0, 0)] * (bits.ndim - 1) + [(0, m * bs - n)])  # 0 ≤ every entry
    lo = jnp.min(jnp.max(blocks.reshape(bits.shape[:-1] + (m, bs)), axis=-1), axis=-1)
    top_bit = (nbits - 1) - jax.lax.clz(hi ^ lo).astype(jnp.int32)  # −1: the m-th largest = hi
    prefix = jnp.where(top_bit >= 0, hi & ~((ut(2) << top_bit.astype(ut)) - ut(1)), hi)

    def cond(c):
        b, _, count = c
        return (b >= 0) & jnp.any(count != m)

    def body(c):
        b, cand, count = c
        trial = cand | (ut(1) << jnp.maximum(b, 0).astype(ut))
        trial_count = jnp.sum(bits_t >= trial, axis=0, dtype=jnp.int32)
        keep = trial_count >= m  # the m-th largest has this bit set
        return b - 1, jnp.where(keep, trial, cand), jnp.where(keep, trial_count, count)

    count0 = jnp.sum(bits_t >= prefix, axis=0, dtype=jnp.int32)  # ≥ m
    init = (jnp.max(top_bit), prefix, count0)
    _, cand, count = jax.lax.while_loop(cond, body, init)
    # cand is the m-th largest value, or (early stop) a prefix with exactly m entries >= it
    tau = jax.lax.bitcast_convert_type(cand, v.dtype)[..., None]
    ge_sum = jnp.sum(jnp.where(v >= tau, v, 0.0), axis=-1)
    above = v > tau
    tie_sum = (
        jnp.sum(jnp.where(above, v, 0.0), axis=-1)
        + (m - jnp.sum(above, axis=-1).astype(v.dtype)) * tau[..., 0]
    )
    return jnp.where(count == m, ge_sum, tie_sum)


def _smallest(c: jax.Array, k: int) -> jax.Array:
    """Indices of the ``k`` smallest entries of ``c`` (p,), ascending, ties by index: the same
    as ``jnp.argsort(c, stable=True)[:k]`` (NaN counts as +inf), by pairwise ranks (one fused
    p² comparison and a scatter; XLA's CPU sort costs ≈ 13 µs per call at p = 100, this ≈ 5)."""
    c = jnp.where(jnp.isnan(c), jnp.inf, c)
    p = c.shape[0]
    idx = jnp.arange(p)
    ci, cj = c[:, None], c[None, :]
    before = (cj < ci) | ((cj == ci) & (idx[None, :] < idx[:, None]))  # j precedes i
    rank = jnp.sum(before, axis=1)  # a permutation of 0 … p−1
    out = jnp.zeros((k,), jnp.int32)
    return out.at[jnp.where(rank < k, rank, k)].set(idx.astype(jnp.int32), mode="drop")


@x64
def reduced_set_objective(
    alpha: ArrayLike, K: ArrayLike, m: int, beta: float = 1.0, ratio_eps: float = 1e-6
) -> jax.Array:
    """eq. (red_set_opt_proposed) for a population ``alpha`` (p, n) -> (p,).

    ``αᵀKα − (2/n)1ᵀKα + (1/n²)1ᵀK1`` (the exact MMD², ≥ 0, minimised at α = 1/n without the
    second term) ``− β·top/(bottom + ratio_eps·(top + bottom))`` with top/bottom the sums of the
    m largest / n − m smallest |α_j| (the separation term is 0 when m = n).  The MMD² is
    evaluated as ``(α − 1/n)ᵀK(α − 1/n)`` (the same quantity, without the cancellation of the
    expanded form).
    """
    n = K.shape[0]
    d = alpha - 1.0 / n
    return _objective(alpha, jnp.sum((d @ K) * d, axis=-1), m, beta, ratio_eps)


def _objective(alpha, mmd, m: int, beta, ratio_eps):
    """eq. (red_set_opt_proposed) from the population's MMD² ``mmd`` (p,): minus β·the ratio."""
    n = alpha.shape[-1]
    if m >= n:
        return mmd
    mag = jnp.abs(alpha)
    total = jnp.sum(mag, axis=-1)
    top = _top_m_sum(mag, m)
    bottom = jnp.maximum(total - top, 0.0)
    ratio = top / (bottom + ratio_eps * total + jnp.finfo(alpha.dtype).tiny)
    return mmd - beta * ratio


# The CEM ranks candidates whose MMD² differ by ≈ 1e-5 … 1e-3 (α = u/n); float32 resolves that
# (the factored form above has no cancellation) at half the cost of float64, so the CEM runs in
# float32 whatever the input dtype; the refinement and the reported MMD² keep the input dtype.
_CEM_DTYPE = jnp.float32


def _keep_elites(elites, ecost, new, new_cost, E: int):
    """The E best of the kept elites and the new candidates (elitism), with their costs."""
    pop = jnp.concatenate([elites, new], axis=0)
    c = jnp.concatenate([ecost, new_cost])
    order = _smallest(c, E)
    return pop[order], c[order]


def _pivoted_cholesky(K: jax.Array, rank: int) -> tuple[jax.Array, jax.Array]:
    """Rank-``rank`` pivoted (partial) Cholesky factor of a PSD ``K`` (n, n): ``L`` (n, rank)
    with ``K ≈ L Lᵀ``, and the largest residual diagonal ``max diag(K − L Lᵀ)`` (≥ the error of
    every entry, since K − LLᵀ is PSD).  Greedy pivot on the residual diagonal (Harbrecht et
    al., 2012), O(n·rank²); columns after the residual vanishes are zero."""
    n = K.shape[0]
    rank = min(rank, n)

    def body(j, c):
        L, diag = c
        p = jnp.argmax(diag)
        dp = diag[p]
        col = (K[:, p] - L @ L[p]) / jnp.sqrt(jnp.maximum(dp, jnp.finfo(K.dtype).tiny))
        col = jnp.where(dp > 0, col, 0.0)
        return L.at[:, j].set(col), jnp.maximum(diag - col * col, 0.0).at[p].set(0.0)

    L0 = jnp.zeros((n, rank), K.dtype)
    L, diag = jax.lax.fori_loop(0, rank, body, (L0, jnp.diagonal(K)))
    return L, jnp.max(diag)


def _cem_alpha(
    key, K: jax.Array, m: int, cfg: ReducedSetConfig, axis_name: str | None = None
) -> jax.Array:
    """CEM over α ∈ ℝⁿ for eq. (red_set_opt_proposed); returns the best α seen.

    ``axis_name``: the vmapped axis of a batch of selections, if any; the low-rank test is then
    taken over the whole batch, so that the choice of form stays a branch, not a select that
    evaluates both forms."""
    n = K.shape[0]
    P, E = cfg.population, cfg.n_elite
    dtype = _CEM_DTYPE if jnp.finfo(K.dtype).bits > jnp.finfo(_CEM_DTYPE).bits else K.dtype
    Kc = K.astype(dtype)
    scale = 1.0 / n if cfg.alpha_scale is None else cfg.alpha_scale
    scale = jnp.asarray(scale, dtype)
    lowrank = cfg.gram == "lowrank" or (cfg.gram == "auto" and n > FACTOR_MIN_N)
    lowrank = lowrank and cfg.gram_rank < n

    if lowrank:
        # dᵀKd = ‖dL‖² + dᵀRd, R = K − LLᵀ ⪰ 0 with every entry ≤ max diag R ≤ gram_tol: the
        # factor is computed in K's dtype (float64 under select_reduced_set), ranked in float32
        L, resid = _pivoted_cholesky(K, cfg.gram_rank)
        Lc = L.astype(dtype)
        if axis_name is not None:
            resid = jax.lax.pmax(resid, axis_name)
        use_lr = resid <= cfg.gram_tol

        def quad(d):  # (p, n) -> (p,): eq. (red_set_opt_proposed)'s MMD², low rank or full
            return jax.lax.cond(
                use_lr,
                lambda d: jnp.sum(jnp.square(d @ Lc), axis=-1),
                lambda d: jnp.sum((d @ Kc) * d, axis=-1),
                d,
            )
    else:

        def quad(d):
            return jnp.sum((d @ Kc) * d, axis=-1)

    def cost(u):  # (p, n) -> (p,)
        alpha = scale * u
        return _objective(alpha, quad(alpha - 1.0 / n), m, cfg.beta, cfg.ratio_eps)

    if cfg.sampler == "factor" or (cfg.sampler == "auto" and n > FACTOR_MIN_N):
        return (scale * _cem_factor(key, cost, n, dtype, cfg)).astype(K.dtype)

    eye = jnp.eye(n, dtype=dtype)

    def stats(elites):
        mu = jnp.mean(elites, axis=0)
        c = elites - mu
        cov = c.T @ c / (E - 1) + cfg.cov_reg * eye
        return mu, cov

    # every normal draw at once (one RNG call instead of one per iteration)
    # (the non-partitionable threefry lowering is ≈ 2× faster on CPU and compiles ≈ 3× faster; it
    # is chosen at trace time, so the stream does not depend on the caller's global setting)
    with jax.threefry_partitionable(False):
        k0, k1 = jax.random.split(key)
        z0 = jax.random.normal(k0, (P, n), dtype=dtype)
        zs = jax.random.normal(k1, (cfg.iterations, P - E, n), dtype=dtype)

    mu0 = jnp.full((n,), cfg.mean0, dtype=dtype)
    cov0 = cfg.sigma0 * eye
    pop0 = mu0 + jnp.sqrt(jnp.asarray(cfg.sigma0, dtype)) * z0  # Σ₀ = sigma0·I
    c0 = cost(pop0)
    order = _smallest(c0, E)
    elites, ecost = pop0[order], c0[order]
    mu, cov = stats(elites)
    s = cfg.smoothing
    mu = (1.0 - s) * mu + s * mu0
    cov = (1.0 - s) * cov + s * cov0

    def step(carry, z):
        mu, cov, elites, ecost = carry
        new = mu + z @ jnp.linalg.cholesky(cov).T
        elites, ecost = _keep_elites(elites, ecost, new, cost(new), E)
        mu_new, cov_new = stats(elites)
        mu = (1.0 - s) * mu_new + s * mu
        cov = (1.0 - s) * cov_new + s * cov
        return (mu, cov, elites, ecost), None

    (_, _, elites, _), _ = jax.lax.scan(step, (mu, cov, elites, ecost), zs)
    # elites are kept, so elites[0] of the last iteration is the best α seen over all iterations
    return (scale * elites[0]).astype(K.dtype)


def _factor_update(a, F, C, s, r):
    """Σ ← (1−s)(CᵀC + r·I) + s·Σ on the factored Σ = a·I + Σ_w F_wᵀF_w (F: (W, E, n)): the
    new set enters first, the oldest (weight s^W) leaves, folded into a·I with its trace."""
    n = F.shape[-1]
    Fs = jnp.sqrt(s) * F
    a = (1.0 - s) * r + s * a + jnp.sum(Fs[-1] ** 2) / n
    return a, jnp.concatenate([(jnp.sqrt(1.0 - s) * C)[None], Fs[:-1]], axis=0)


def _cem_factor(key, cost, n: int, dtype, cfg: ReducedSetConfig) -> jax.Array:
    """The same CEM as :func:`_cem_alpha`, with Σ kept factored instead of Cholesky-factorised.

    Σ = cov(elites) + cov_reg·I smoothed with s is, unrolled, a·I + Σ_w F_wᵀF_w with F_w the
    centred elites of the w-th last iteration scaled by √((1−s)·s^w / (E−1)).  A draw is then
    μ + √a·z + gᵀF (z ~ N(0, Iₙ), g ~ N(0, I_EW)), exactly N(μ, Σ), in O(n·E·W) with no O(n³)
    factorisation.  Only the last ``cov_window`` sets are kept; the dropped one (weight s^W) is
    folded into a·I with its trace, so the total variance is kept.  Returns the best u seen.
    """
    P, E, W = cfg.population, cfg.n_elite, cfg.cov_window
    s = jnp.asarray(cfg.smoothing, dtype)
    r = jnp.asarray(cfg.cov_reg, dtype)
    with jax.threefry_partitionable(False):
        k0, k1, k2 = jax.random.split(key, 3)
        z0 = jax.random.normal(k0, (P, n), dtype=dtype)
        zs = jax.random.normal(k1, (cfg.iterations, P - E, n), dtype=dtype)
        gs = jax.random.normal(k2, (cfg.iterations, P - E, E * W), dtype=dtype)

    def stats(elites):  # mean and the centred elites scaled so that cov(elites) = CᵀC
        mu = jnp.mean(elites, axis=0)
        return mu, (elites - mu) / jnp.sqrt(jnp.asarray(E - 1, dtype))

    sigma0 = jnp.asarray(cfg.sigma0, dtype)
    mu0 = jnp.full((n,), cfg.mean0, dtype=dtype)
    pop0 = mu0 + jnp.sqrt(sigma0) * z0  # Σ₀ = sigma0·I
    c0 = cost(pop0)
    order = _smallest(c0, E)
    elites, ecost = pop0[order], c0[order]
    mu_new, C = stats(elites)
    mu = (1.0 - s) * mu_new + s * mu0
    a = (1.0 - s) * r + s * sigma0
    F = jnp.zeros((W, E, n), dtype).at[0].set(jnp.sqrt(1.0 - s) * C)

    def step(carry, zg):
        mu, a, F, elites, ecost = carry
        z, g = zg
        new = mu + jnp.sqrt(a) * z + g @ F.reshape(W * E, n)
        elites, ecost = _keep_elites(elites, ecost, new, cost(new), E)
        mu_new, C = stats(elites)
        mu = (1.0 - s) * mu_new + s * mu
        a, F = _factor_update(a, F, C, s, r)
        return (mu, a, F, elites, ecost), None

    (_, _, _, elites, _), _ = jax.lax.scan(step, (mu, a, F, elites, ecost), (zs, gs))
    return elites[0]


@partial(jax.jit, static_argnames=("m", "method", "axis_name"))
def select_reduced_set_unchecked(
    key: ArrayLike,
    samples: ArrayLike,
    m: int,
    method: str = "kernel-cem",
    config: ReducedSetConfig = ReducedSetConfig(),  # noqa: B008 (frozen, hashable)
    ego_guess: ArrayLike | None = None,
    axis_name: str | None = None,
    footprint: Footprint | None = None,
) -> ReducedSet:
    """Jitted core of :func:`select_reduced_set`, without input validation (traceable).

    ``axis_name``: when vmapped over obstacles with ``jax.vmap(..., axis_name=...)``, that name
    (the CEM's choice between the low-rank and the full Gram is then made once for the batch)."""
    method = selector_name(method)
    samples = jnp.asarray(samples)
    if not jnp.issubdtype(samples.dtype, jnp.floating):
        samples = samples.astype(float)
    n = samples.shape[0]
    feats = samples.reshape(n, -1) * config.feature_scale
    if method == "conflict" and n > KERNEL_POOL:
        # the choice reads no kernel, the scenario cost no weight: the weights and the MMD²
        # from a pool, not from an n × n Gram
        idx = _deepest_conflicts(samples, m, ego_guess, footprint).astype(jnp.int32)
        return _pooled_set(feats, idx, config, method)
    bw = median_heuristic(feats) if config.bandwidth is None else jnp.asarray(config.bandwidth)
    bw = bw.astype(feats.dtype)
    K = gaussian_gram(feats, None, bw)
    D = one_minus_gaussian_gram(feats, None, bw)

    if method == "kernel-cem":
        alpha = _cem_alpha(key, K, m, config, axis_name)
        _, idx = jax.lax.top_k(jnp.abs(alpha), m)
    elif method == "herding":
        kbar = jnp.mean(K, axis=1)

        def body(t, c):
            sel, ksum, idx = c
            score = kbar - ksum / (t + 1.0)
            j = jnp.argmax(jnp.where(sel, -jnp.inf, score))
            return sel.at[j].set(True), ksum + K[j], idx.at[t].set(j.astype(jnp.int32))

        init = (jnp.zeros((n,), bool), jnp.zeros((n,), K.dtype), jnp.zeros((m,), jnp.int32))
        _, _, idx = jax.lax.fori_loop(0, m, body, init)
    elif method == "uniform":
        _, idx = jax.lax.top_k(jax.random.uniform(key, (n,)), m)  # uniform m-subset
    elif method == "conflict":
        idx = _deepest_conflicts(samples, m, ego_guess, footprint)
    else:  # pragma: no cover - validated by the wrapper
        raise ValueError(f"unknown method {method!r}")

    idx = idx.astype(jnp.int32)
    w = refine_weights(K, idx, config)
    if method != "kernel-cem":
        alpha = jnp.zeros((n,), K.dtype).at[idx].set(w)
    return ReducedSet(
        indices=idx,
        weights=w,
        alpha=alpha,
        mmd2=_reduced_mmd2(D, idx, w),
        bandwidth=bw,
        method=method,
    )


def _deepest_conflicts(samples, m: int, ego_guess, footprint) -> jax.Array:
    """de Groot's choice: the m samples whose ellipse the ego guess enters deepest, g_j =
    max_k f(ego_guess_k, sample_jk)."""
    ego = jnp.asarray(ego_guess, dtype=samples.dtype)
    d = ego[None] - samples  # (n, K, 2)
    fp = Footprint() if footprint is None else footprint
    f = 1.0 - d[..., 0] ** 2 / fp.a**2 - d[..., 1] ** 2 / fp.b**2
    _, idx = jax.lax.top_k(jnp.max(f, axis=-1), m)
    return idx


def _pooled_set(feats, idx, config: ReducedSetConfig, method: str) -> ReducedSet:
    """The :class:`ReducedSet` of the chosen ``idx`` with the kernel quantities estimated on
    ``KERNEL_POOL`` evenly spaced samples (P) standing for all n: the bandwidth (median
    heuristic over P), ``b = (1/n) K_NRᵀ 1`` as the mean over P, and the MMD² terms over P."""
    n, m = feats.shape[0], idx.shape[0]
    stride = n // KERNEL_POOL
    pool = feats[stride * jnp.arange(KERNEL_POOL)]
    bw = median_heuristic(pool) if config.bandwidth is None else jnp.asarray(config.bandwidth)
    bw = bw.astype(feats.dtype)
    pts = jnp.concatenate([feats[idx], pool])
    K = gaussian_gram(pts, None, bw)
    D = one_minus_gaussian_gram(pts, None, bw)
    w = _fit_weights(K[:m, :m], jnp.mean(K[m:, :m], axis=0), config)
    mmd2 = _mmd2_from(jnp.mean(D[m:, m:]), D[:m, :m], jnp.mean(D[m:, :m], axis=0), w)
    alpha = jnp.zeros((n,), K.dtype).at[idx].set(w)
    return ReducedSet(indices=idx, weights=w, alpha=alpha, mmd2=mmd2, bandwidth=bw, method=method)


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _validate(key, samples, m, method, config, ego_guess, batched: bool, footprint=None):
    method = selector_name(method)
    if footprint is not None and not isinstance(footprint, Footprint):
        raise ValueError(f"footprint must be an mmdopt.Footprint, got {type(footprint).__name__}")
    if not isinstance(config, ReducedSetConfig):
        raise ValueError(f"config must be a ReducedSetConfig, got {type(config).__name__}")
    if isinstance(m, bool) or not isinstance(m, int | np.integer):
        raise ValueError(f"m must be an int, got {m!r}")
    m = int(m)
    if samples is None:
        raise ValueError("samples must be an array of shape (n, K, 2), got None")
    shape = np.shape(samples)
    want = 4 if batched else 3
    dims = "(O, n, K, 2)" if batched else "(n, K, 2)"
    if len(shape) != want or shape[-1] != 2:
        raise ValueError(f"samples must have shape {dims}, got {shape}")
    n, k = shape[-3], shape[-2]
    if n == 0 or k == 0 or (batched and shape[0] == 0):
        raise ValueError(f"samples is empty (shape {shape})")
    if m < 1:
        raise ValueError(f"m must be >= 1, got {m}")
    if m > n:
        raise ValueError(f"m = {m} exceeds the number of samples n = {n}")
    if _is_concrete(samples):
        arr = np.asarray(samples)
        if not np.issubdtype(arr.dtype, np.number):
            raise ValueError(f"samples must be numeric, got dtype {arr.dtype}")
        if not np.all(np.isfinite(arr)):
            raise ValueError("samples contains NaN or inf")
    if method == "conflict":
        if ego_guess is None:
            raise ValueError("ego_guess (K, 2) is required for method='conflict' (de Groot)")
        if np.shape(ego_guess) != (k, 2):
            raise ValueError(f"ego_guess must have shape ({k}, 2), got {np.shape(ego_guess)}")
        if _is_concrete(ego_guess) and not np.all(np.isfinite(np.asarray(ego_guess))):
            raise ValueError("ego_guess contains NaN or inf")
    if config.bandwidth is not None and _is_concrete(config.bandwidth):
        if not float(config.bandwidth) > 0:
            raise ValueError(f"config.bandwidth must be > 0, got {config.bandwidth}")
    if np.shape(key) == () and not jnp.issubdtype(jnp.asarray(key).dtype, jax.dtypes.prng_key):
        raise ValueError("key must be a jax PRNG key (jax.random.key or jax.random.PRNGKey)")
    return m


@x64
def select_reduced_set(
    key: ArrayLike,
    samples: ArrayLike,
    m: int,
    method: str = "kernel-cem",
    config: ReducedSetConfig | None = None,
    ego_guess: ArrayLike | None = None,
    footprint: Footprint | None = None,
) -> ReducedSet:
    """Select a reduced set of ``m`` of the ``n`` obstacle-trajectory samples, with weights.

    Parameters
    ----------
    key : jax PRNG key (used by "kernel-cem" and "uniform"; the same key gives the same set)
    samples : (n, K, 2) obstacle trajectory samples (m), any frame
    m : size of the reduced set, 1 <= m <= n
    method : "kernel-cem" | "herding" | "uniform" | "conflict" (see module docstring; the former
        names "mmd", "random", "degroot" are accepted)
    config : :class:`ReducedSetConfig`
    ego_guess : (K, 2) ego initial-guess trajectory, required for "conflict"
    footprint : the collision ellipse "conflict" scores with (default :class:`Footprint`(): the
        planner's default; :func:`mmdopt.plan` passes its config's ``safety.footprint``)

    Returns
    -------
    :class:`ReducedSet`

    Raises
    ------
    ValueError naming the argument: unknown method, wrong shapes, empty or non-finite samples,
    m < 1 or m > n, missing ego_guess for "conflict".
    """
    config = ReducedSetConfig() if config is None else config
    m = _validate(key, samples, m, method, config, ego_guess, False, footprint)
    return select_reduced_set_unchecked(
        key, samples, m, method, config, ego_guess, footprint=footprint
    )


@partial(jax.jit, static_argnames=("m", "method"))
def _select_many(keys, samples, m, method, config, ego_guess, footprint):
    return jax.vmap(
        lambda k, s: select_reduced_set_unchecked(
            k, s, m, method, config, ego_guess, "obstacles", footprint
        ),
        axis_name="obstacles",
    )(keys, samples)


@x64
def select_reduced_sets(
    key: ArrayLike,
    samples: ArrayLike,
    m: int,
    method: str = "kernel-cem",
    config: ReducedSetConfig | None = None,
    ego_guess: ArrayLike | None = None,
    footprint: Footprint | None = None,
) -> ReducedSet:
    """:func:`select_reduced_set` for O obstacles at once (vmapped; one key per obstacle).

    samples : (O, n, K, 2); returns a :class:`ReducedSet` whose arrays have a leading axis O.
    """
    config = ReducedSetConfig() if config is None else config
    m = _validate(key, samples, m, method, config, ego_guess, True, footprint)
    keys = jax.random.split(key, np.shape(samples)[0])
    if np.shape(samples)[0] == 1:
        # one obstacle (the common case): the unbatched jit; vmap over a batch of one only adds
        # batched-while-loop overhead (≈ 8 ms of ≈ 30 ms measured), with the same key
        one = select_reduced_set_unchecked(
            keys[0], samples[0], m, method, config, ego_guess, footprint=footprint
        )
        return jax.tree_util.tree_map(lambda a: a[None], one)
    return _select_many(keys, samples, m, method, config, ego_guess, footprint)
