"""Reduced-set selection: the objective, the weights, the methods and input validation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mmdopt  # noqa: F401
from mmdopt.kernels import gaussian_gram
from mmdopt.reduced_set import (
    KERNEL_POOL,
    SELECTORS,
    ReducedSetConfig,
    project_simplex,
    reduced_set_objective,
    refine_weights,
    select_reduced_set,
    select_reduced_set_unchecked,
    select_reduced_sets,
)

# the float64 numerics of these functions (the public entry points run them under x64)
pytestmark = pytest.mark.usefixtures("x64")

K_STEPS, DT = 100, 0.1


def two_intent(seed: int, n: int = 100, p_keep: float = 0.8):
    """Lane-keep (prob. p_keep) vs lane change (3.5 m, smooth, 4 s) with speeds N(5, 1) m/s.

    Returns samples (n, K, 2) and the boolean lane-keep label of each sample.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(K_STEPS) * DT
    keep = rng.random(n) < p_keep
    v = rng.normal(5.0, 1.0, n)
    s = np.clip(t / 4.0, 0.0, 1.0)
    lateral = 3.5 * (3 * s**2 - 2 * s**3)
    y = np.where(keep[:, None], 0.0, lateral[None]) + rng.normal(0.0, 0.05, n)[:, None]
    return np.stack([v[:, None] * t, y], axis=-1), keep


EGO_GUESS = np.stack([10.0 * np.arange(K_STEPS) * DT - 10.0, np.zeros(K_STEPS)], axis=-1)


def _select(method="mmd", seed=0, m=10, config=None, samples=None):
    X = two_intent(seed)[0] if samples is None else samples
    return select_reduced_set(jax.random.key(seed), X, m, method, config, ego_guess=EGO_GUESS)


@pytest.mark.parametrize("method", SELECTORS)
def test_every_method_returns_m_distinct_indices_and_weights_summing_to_one(method):
    rs = _select(method)
    idx = np.asarray(rs.indices)
    assert idx.shape == (10,) and len(set(idx.tolist())) == 10
    assert idx.min() >= 0 and idx.max() < 100
    np.testing.assert_allclose(float(jnp.sum(rs.weights)), 1.0, atol=1e-9)
    assert float(jnp.min(rs.weights)) >= 0.0  # default weights="simplex"
    assert rs.alpha.shape == (100,) and rs.method == method
    assert float(rs.mmd2) >= 0.0 and float(rs.bandwidth) > 0.0


@pytest.mark.parametrize("p_keep", [0.8, 0.2])
def test_mmd_reduced_set_favours_the_likely_intent(p_keep):
    fractions = []
    for seed in range(8):
        X, keep = two_intent(seed, p_keep=p_keep)
        likely = keep if p_keep > 0.5 else ~keep
        rs = select_reduced_set(jax.random.key(seed), X, 10, "mmd")
        fractions.append(likely[np.asarray(rs.indices)].mean())
    assert np.mean(fractions) >= 0.8, fractions


def test_objective_is_the_exact_mmd_minimised_at_uniform_weights():
    objective = jax.jit(reduced_set_objective, static_argnums=2)
    X = two_intent(0)[0].reshape(100, -1)
    K = gaussian_gram(X, None, 50.0)
    uniform = jnp.full((1, 100), 0.01)
    assert abs(float(objective(uniform, K, 10, 0.0)[0])) < 1e-12
    scales = jnp.linspace(0.2, 2.0, 19)[:, None] * uniform  # c·(1/n)1, c = 0.2 … 2
    vals = objective(scales, K, 10, 0.0)
    assert int(jnp.argmin(vals)) == 8  # c = 1 (the reference's halved linear term gives 0.5)


def test_separation_ratio_is_guarded_when_the_bottom_weights_vanish():
    K = jnp.eye(20)
    alpha = jnp.zeros((1, 20)).at[0, :5].set(1.0)
    val = float(jax.jit(reduced_set_objective, static_argnums=2)(alpha, K, 5, 1.0, 1e-6)[0])
    assert np.isfinite(val) and val > -1.01e6


def test_separation_term_sums_the_m_largest_magnitudes_exactly_with_ties():
    rng = np.random.default_rng(0)
    alpha = rng.normal(size=(6, 20)) * 10.0 ** rng.integers(-4, 1, size=(6, 1))
    alpha[0] = np.round(alpha[0] * 3) / 3  # many ties, including at the m-th largest
    alpha[1] = 0.25  # every entry equal
    alpha[2, :10] = 0.0
    K = np.eye(20)
    objective = jax.jit(reduced_set_objective, static_argnums=2)
    for m in (1, 5, 12):
        mag = np.sort(np.abs(alpha), axis=-1)[:, ::-1]
        top, bottom = mag[:, :m].sum(-1), mag[:, m:].sum(-1)
        d = alpha - 1.0 / 20
        want = (d * d).sum(-1) - top / (bottom + 1e-6 * (top + bottom))
        got = np.asarray(objective(jnp.asarray(alpha), jnp.asarray(K), m, 1.0, 1e-6))
        np.testing.assert_allclose(got, want, rtol=1e-9)


def test_refinement_is_the_equality_constrained_qp_and_uniform_for_the_full_set():
    refine = jax.jit(refine_weights)
    X = two_intent(1)[0].reshape(100, -1)
    K = gaussian_gram(X, None, 50.0)
    w = refine(K, jnp.arange(100), ReducedSetConfig(weights="kkt"))
    np.testing.assert_allclose(np.asarray(w), 0.01, atol=1e-9)
    idx = jnp.arange(0, 100, 10)
    cfg = ReducedSetConfig(weights="kkt")
    w = np.asarray(refine(K, idx, cfg))
    A = np.asarray(K)[np.ix_(idx, idx)] + cfg.ridge * np.eye(10)
    b = np.asarray(K).mean(0)[idx]
    kkt = np.block([[A, np.ones((10, 1))], [np.ones((1, 10)), np.zeros((1, 1))]])
    np.testing.assert_allclose(w, np.linalg.solve(kkt, np.r_[b, 1.0])[:10], atol=1e-8)


def test_simplex_weights_are_nonnegative_and_no_worse_than_clipping():
    for seed in range(6):
        a = _select("random", seed, config=ReducedSetConfig(weights="kkt"))
        if float(jnp.min(a.weights)) < 0:
            break
    else:  # pragma: no cover
        pytest.skip("no random set with negative KKT weights")
    b = _select("random", seed, config=ReducedSetConfig(weights="simplex"))
    np.testing.assert_array_equal(np.asarray(a.indices), np.asarray(b.indices))
    assert float(jnp.min(b.weights)) >= 0.0
    assert float(b.mmd2) >= float(a.mmd2) * (1 - 1e-6)  # the signed optimum is a lower bound
    X = two_intent(seed)[0].reshape(100, -1)
    K = np.asarray(gaussian_gram(X, None, b.bandwidth))
    idx = np.asarray(a.indices)
    A = K[np.ix_(idx, idx)] + 0.01 * np.eye(10)
    q = K.mean(0)[idx]

    def obj(w):
        return 0.5 * w @ A @ w - q @ w

    clipped = np.asarray(project_simplex(a.weights))
    assert obj(np.asarray(b.weights)) <= obj(clipped) + 1e-12


def test_project_simplex_projects():
    v = jnp.array([[0.5, 0.5, 0.5], [2.0, -1.0, 0.0], [0.2, 0.3, 0.5]])
    p = np.asarray(project_simplex(v))
    np.testing.assert_allclose(p.sum(-1), 1.0)
    np.testing.assert_allclose(p[0], 1 / 3)
    np.testing.assert_allclose(p[1], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(p[2], [0.2, 0.3, 0.5])


def test_herding_starts_from_the_sample_with_the_largest_mean_kernel():
    X = two_intent(2)[0]
    rs = _select("herding", samples=X)
    K = gaussian_gram(X.reshape(100, -1), None, rs.bandwidth)
    assert int(rs.indices[0]) == int(jnp.argmax(jnp.mean(K, axis=0)))


def test_degroot_picks_the_samples_deepest_in_conflict_with_the_ego_guess():
    X, keep = two_intent(3)
    rs = _select("degroot", samples=X)
    d = EGO_GUESS[None] - X
    g = np.max(1 - d[..., 0] ** 2 / 4.5**2 - d[..., 1] ** 2 / 3.5**2, axis=-1)
    assert set(np.asarray(rs.indices).tolist()) == set(np.argsort(-g)[:10].tolist())


def _value_sizes(jaxpr) -> list[int]:
    """Sizes of every value a jaxpr computes, its sub-jaxprs (jit, loops, conds) included."""
    out = []
    for e in jaxpr.eqns:
        out += [int(np.prod(v.aval.shape)) for v in e.outvars]
        for p in e.params.values():
            for q in p if isinstance(p, tuple | list) else (p,):
                sub = getattr(q, "jaxpr", q)
                if hasattr(sub, "eqns"):
                    out += _value_sizes(sub)
    return out


def test_degroot_at_thousands_of_futures_chooses_as_before_without_an_n_by_n_gram():
    """Beyond KERNEL_POOL samples de Groot's set is the same deepest conflicts; its weights
    and MMD² are estimated on a pool, and no array of the n × n Gram is ever formed."""
    n = 3000
    assert n > KERNEL_POOL
    X, keep = two_intent(5, n=n)
    rs = _select("degroot", samples=X)
    d = EGO_GUESS[None] - X
    g = np.max(1 - d[..., 0] ** 2 / 4.5**2 - d[..., 1] ** 2 / 3.5**2, axis=-1)
    assert set(np.asarray(rs.indices).tolist()) == set(np.argsort(-g)[:10].tolist())
    w = np.asarray(rs.weights)
    assert np.all(w >= -1e-12) and abs(w.sum() - 1.0) < 1e-9
    assert 0.0 <= float(rs.mmd2) < 2.0 and np.isfinite(float(rs.bandwidth))
    jaxpr = jax.make_jaxpr(
        lambda x: select_reduced_set_unchecked(
            jax.random.key(0), x, 10, "conflict", ReducedSetConfig(), EGO_GUESS
        )
    )(jnp.asarray(X))
    sizes = _value_sizes(jaxpr.jaxpr)  # every value of the program, inside the jit too
    assert max(sizes) < n * n / 10


def test_same_key_gives_the_same_reduced_set_and_different_keys_may_differ():
    X = two_intent(4)[0]
    a = select_reduced_set(jax.random.key(7), X, 10)
    b = select_reduced_set(jax.random.key(7), X, 10)
    np.testing.assert_array_equal(np.asarray(a.indices), np.asarray(b.indices))
    np.testing.assert_array_equal(np.asarray(a.weights), np.asarray(b.weights))
    others = [select_reduced_set(jax.random.key(k), X, 10).indices for k in range(8, 12)]
    assert any(set(np.asarray(o).tolist()) != set(np.asarray(a.indices).tolist()) for o in others)


def test_many_obstacles_at_once_match_one_at_a_time():
    X = np.stack([two_intent(5)[0], two_intent(6)[0] + 10.0])
    rs = select_reduced_sets(jax.random.key(0), X, 10, "herding")
    assert rs.indices.shape == (2, 10) and rs.weights.shape == (2, 10)
    np.testing.assert_allclose(np.asarray(rs.weights.sum(-1)), 1.0)
    one = select_reduced_set(jax.random.key(0), X[1], 10, "herding")  # herding is deterministic
    np.testing.assert_array_equal(np.asarray(rs.indices[1]), np.asarray(one.indices))
    np.testing.assert_allclose(np.asarray(rs.weights[1]), np.asarray(one.weights), atol=1e-9)


def test_core_is_traceable_inside_jit():
    f = jax.jit(lambda k, s: select_reduced_set_unchecked(k, s, 10, "herding").indices)
    X = two_intent(5)[0]
    np.testing.assert_array_equal(
        np.asarray(f(jax.random.key(0), jnp.asarray(X))),
        np.asarray(select_reduced_set(jax.random.key(0), X, 10, "herding").indices),
    )


def test_config_scalars_are_pytree_leaves_and_reference_config_exists():
    cfg = ReducedSetConfig(bandwidth=30.0)
    leaves = jax.tree_util.tree_leaves(cfg)
    assert 30.0 in leaves and cfg.beta in leaves
    assert ReducedSetConfig.reference().alpha_scale == 1.0
    assert cfg.replace(beta=2.0).beta == 2.0
    with pytest.raises(ValueError, match="weights"):
        ReducedSetConfig(weights="nope")


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(samples=np.full((10, 5, 2), np.nan)), "samples"),
        (dict(samples=np.zeros((0, 5, 2))), "samples"),
        (dict(samples=np.zeros((10, 5))), "samples"),
        (dict(samples=np.zeros((10, 5, 3))), "samples"),
        (dict(samples=None), "samples"),
        (dict(m=0), "m"),
        (dict(m=11), "m"),
        (dict(m=2.5), "m"),
        (dict(method="best"), "method"),
        (dict(method="degroot", ego_guess=None), "ego_guess"),
        (dict(method="degroot", ego_guess=np.zeros((4, 2))), "ego_guess"),
        (dict(config=ReducedSetConfig(bandwidth=-1.0)), "bandwidth"),
    ],
)
def test_bad_inputs_raise_value_errors_naming_the_argument(kwargs, match):
    args = dict(samples=np.zeros((10, 5, 2)), m=3, method="mmd", config=None, ego_guess=None)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        select_reduced_set(jax.random.key(0), **args)


def test_elite_ranking_equals_a_stable_argsort_with_ties_and_nan():
    """The CEM's sort-free elite selection is ``argsort(c, stable)[:k]`` exactly (NaN last)."""
    from mmdopt.reduced_set import _smallest

    rng = np.random.default_rng(0)
    f = jax.jit(_smallest, static_argnums=1)
    for trial in range(20):
        c = rng.integers(0, 6, 100).astype(np.float32) if trial % 2 else rng.normal(size=100)
        if trial % 5 == 0:
            c[rng.integers(0, 100, 7)] = np.nan
        want = np.argsort(np.where(np.isnan(c), np.inf, c), kind="stable")[:20]
        np.testing.assert_array_equal(np.asarray(f(jnp.asarray(c), 20)), want)


def test_factored_cem_covariance_is_the_smoothed_elite_covariance():
    """The large-n sampler keeps Σ = a·I + Σ_w F_wᵀF_w: equal to the Cholesky path's
    Σ ← (1−s)(cov(elites) + r·I) + s·Σ while the window holds every set, and with the same
    trace (total variance) once older sets are folded into a·I."""
    from mmdopt.reduced_set import _factor_update

    rng = np.random.default_rng(0)
    n, E, s, r, sig0 = 12, 4, 0.5, 0.01, 5.0
    Cs = [rng.normal(size=(E, n)) for _ in range(6)]
    for W, exact in ((8, True), (2, False)):
        cov = (1 - s) * (Cs[0].T @ Cs[0] + r * np.eye(n)) + s * sig0 * np.eye(n)
        a = (1 - s) * r + s * sig0
        F = jnp.zeros((W, E, n)).at[0].set(np.sqrt(1 - s) * Cs[0])
        for C in Cs[1:]:
            cov = (1 - s) * (C.T @ C + r * np.eye(n)) + s * cov
            a, F = _factor_update(a, F, jnp.asarray(C), s, r)
        L = np.asarray(F).reshape(W * E, n)
        got = float(a) * np.eye(n) + L.T @ L
        np.testing.assert_allclose(np.trace(got), np.trace(cov), rtol=1e-12)
        if exact:
            np.testing.assert_allclose(got, cov, rtol=1e-12, atol=1e-12)
        else:
            assert np.abs(got - cov).max() > 1e-3  # the folded sets lose their shape only


def _assert_same_quality(n: int, field: str, base: str, other: str, seeds: int = 8) -> None:
    """Two values of a ReducedSetConfig field select m = 10 MMD sets of the same quality over
    ``seeds`` two-intent mixtures of n samples: ≥ 75 % from the likely intent for both, and
    median MMD² within a factor 2 (the median moves by ±30 % with the random stream alone)."""
    out = {}
    for value in (base, other):
        frac, mmd2 = [], []
        for seed in range(seeds):
            X, keep = two_intent(seed, n=n)
            cfg = ReducedSetConfig(**{field: value})
            rs = select_reduced_set(jax.random.key(seed), X, 10, "mmd", cfg)
            frac.append(keep[np.asarray(rs.indices)].mean())
            mmd2.append(float(rs.mmd2))
        out[value] = (np.mean(frac), np.median(mmd2))
    assert out[base][0] >= 0.75 and out[other][0] >= 0.75, out
    assert 0.5 <= out[other][1] / out[base][1] <= 2.0, out


def test_factored_sampler_selects_as_well_as_cholesky():
    """``sampler="factor"`` (the default above 256 samples) draws from the same distribution as
    the Cholesky sampler: over 8 mixtures, the same share from the likely intent and a median
    MMD² within a factor 2 (the median moves by ±30 % with the random stream alone)."""
    _assert_same_quality(100, "sampler", "cholesky", "factor")


def test_large_n_selection_uses_the_factored_sampler_and_is_valid():
    X, keep = two_intent(0, n=400)
    rs = select_reduced_set(jax.random.key(0), X, 10, "mmd")  # auto: n > 256, factored Σ
    idx = np.asarray(rs.indices)
    assert len(set(idx.tolist())) == 10 and idx.max() < 400
    np.testing.assert_allclose(float(jnp.sum(rs.weights)), 1.0, atol=1e-9)
    assert keep[idx].mean() >= 0.6


def test_pivoted_cholesky_reproduces_a_low_rank_gram_and_reports_its_residual():
    from mmdopt.reduced_set import _pivoted_cholesky

    rng = np.random.default_rng(0)
    B = rng.normal(size=(300, 7))
    K = jnp.asarray(B @ B.T)  # PSD, rank 7
    L, resid = _pivoted_cholesky(K, 12)
    assert L.shape == (300, 12)
    np.testing.assert_allclose(np.asarray(L @ L.T), np.asarray(K), atol=1e-9)
    assert float(resid) <= 1e-9
    L3, resid3 = _pivoted_cholesky(K, 3)  # too few columns: the residual says so
    R = np.asarray(K - L3 @ L3.T)
    assert float(resid3) == pytest.approx(np.diag(R).max(), rel=1e-9)
    assert np.abs(R).max() <= float(resid3) * (1 + 1e-9)  # every entry of a PSD R ≤ max diag


#: float32 rounding of the CEM's weights, accumulated over its iterations (two separately
#: compiled programs of the same arithmetic agree to it, not bit for bit)
ROUNDING = 1e-4


def test_low_rank_gram_selects_as_well_as_the_full_gram():
    """Above 256 samples the CEM ranks its population by ‖(α − 1/n)L‖² with a pivoted-Cholesky
    factor L of K (smooth trajectories: the Gaussian Gram is numerically low rank).  It is the
    same objective to ≈ 1e-9 of K's entries, so over 8 mixtures the share from the likely intent
    and the median MMD² agree with the full Gram's (the float32 ranking noise alone sends the
    two CEM runs apart in some seeds, so not bit for bit)."""
    _assert_same_quality(300, "gram", "full", "lowrank")


def test_low_rank_gram_falls_back_to_the_full_gram_when_k_is_not_low_rank():
    """White-noise samples with a small bandwidth: K ≈ I has full rank, the factor's residual
    stays far above ``gram_tol`` and the CEM uses the full K: the same set as ``gram="full"``
    (the weights to float32 rounding: the two are separately compiled programs, and XLA may order
    a sum differently in each)."""
    X = np.random.default_rng(1).normal(size=(300, 4, 2))
    cfg = ReducedSetConfig(bandwidth=0.5, iterations=5)
    a = select_reduced_set(jax.random.key(0), X, 10, "mmd", cfg.replace(gram="lowrank"))
    b = select_reduced_set(jax.random.key(0), X, 10, "mmd", cfg.replace(gram="full"))
    np.testing.assert_array_equal(np.asarray(a.indices), np.asarray(b.indices))
    np.testing.assert_allclose(np.asarray(a.alpha), np.asarray(b.alpha), rtol=ROUNDING)
    # (the factor alone would be a different objective: accepted at any residual, it differs)
    c = select_reduced_set(
        jax.random.key(0), X, 10, "mmd", cfg.replace(gram="lowrank", gram_tol=1e9)
    )
    assert not np.allclose(np.asarray(c.alpha), np.asarray(b.alpha), rtol=ROUNDING)


def test_batched_selection_takes_the_low_rank_form_only_when_every_obstacle_allows_it():
    """``select_reduced_sets`` decides once for the batch (a collective over the vmapped axis):
    one obstacle whose Gram is not low rank sends the whole batch to the full K, the
    ``gram="full"`` result (to float32 rounding); a batch of smooth obstacles uses the (here
    deliberately coarse) factor, which gives a different, valid result."""
    # a deliberately coarse factor that tells the two apart: rank 8 leaves a residual of 0.24
    # for the smooth samples (accepted by gram_tol = 0.3: a visibly different objective) and 0.50
    # for white noise (K ≈ 0.6 + 0.4·I, rejected)
    smooth = two_intent(0, n=300)[0]
    noise = np.random.default_rng(1).normal(size=smooth.shape)
    cfg = ReducedSetConfig(iterations=10, gram_rank=8, gram_tol=0.3)
    lo, full = cfg.replace(gram="lowrank"), cfg.replace(gram="full")
    key = jax.random.key(0)
    pair = np.stack([smooth, smooth[::-1]])  # both accept the factor: the batch uses it
    a = select_reduced_sets(key, pair, 10, "mmd", lo)
    b = select_reduced_sets(key, pair, 10, "mmd", full)
    assert not np.allclose(np.asarray(a.alpha), np.asarray(b.alpha), rtol=ROUNDING)
    for o in range(2):
        idx = np.asarray(a.indices[o])
        assert len(set(idx.tolist())) == 10 and idx.max() < 300
    mixed = np.stack([smooth, noise])  # (the same shapes: no new compilation)
    a = select_reduced_sets(key, mixed, 10, "mmd", lo)
    b = select_reduced_sets(key, mixed, 10, "mmd", full)
    np.testing.assert_array_equal(np.asarray(a.indices), np.asarray(b.indices))
    np.testing.assert_allclose(np.asarray(a.alpha), np.asarray(b.alpha), rtol=ROUNDING)


def test_gram_mode_is_validated():
    with pytest.raises(ValueError, match="gram"):
        ReducedSetConfig(gram="nystrom")
    with pytest.raises(ValueError, match="gram_rank"):
        ReducedSetConfig(gram_rank=0)
    with pytest.raises(ValueError, match="gram_tol"):
        ReducedSetConfig(gram_tol=0.0)
    with pytest.raises(ValueError, match="gram_tol"):
        ReducedSetConfig(gram_tol=float("nan"))


def test_sampler_is_validated():
    with pytest.raises(ValueError, match="sampler"):
        ReducedSetConfig(sampler="qr")
    with pytest.raises(ValueError, match="cov_window"):
        ReducedSetConfig(cov_window=0)
