"""Kernels and weighted MMD²: properties (hypothesis) and cancellation-free accuracy."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import mmdopt  # noqa: F401
from mmdopt.kernels import (
    gaussian_gram,
    median_heuristic,
    mmd2_to_dirac,
    mmd2_weighted,
    one_minus_gaussian_gram,
    sq_distances,
)

# the float64 numerics of these functions (the public entry points run them under x64)
pytestmark = pytest.mark.usefixtures("x64")

N, P, D = 6, 5, 3
coords = st.floats(-5.0, 5.0, allow_nan=False, allow_infinity=False)
weights = st.floats(0.0, 1.0, allow_nan=False, allow_infinity=False)
bandwidths = st.floats(0.3, 10.0)
SETTINGS = settings(max_examples=25, deadline=None)


def _naive_mmd2(x, wx, y, wy, bw):
    kxx = np.exp(-((x[:, None] - x[None]) ** 2).sum(-1) / (2 * bw**2))
    kyy = np.exp(-((y[:, None] - y[None]) ** 2).sum(-1) / (2 * bw**2))
    kxy = np.exp(-((x[:, None] - y[None]) ** 2).sum(-1) / (2 * bw**2))
    return wx @ kxx @ wx - 2 * wx @ kxy @ wy + wy @ kyy @ wy


@SETTINGS
@given(
    arrays(np.float64, (N, D), elements=coords),
    arrays(np.float64, (N,), elements=weights),
    bandwidths,
)
def test_mmd_of_a_distribution_with_itself_is_zero(x, w, bw):
    # three terms of size <= (Σw)² cancel: a few ulps of that (1.4e-14 seen with Σw = 1)
    assert 0.0 <= float(mmd2_weighted(x, w, x, w, bw)) <= 1e-13 * max(w.sum(), 1.0) ** 2


@SETTINGS
@given(
    arrays(np.float64, (N, D), elements=coords),
    arrays(np.float64, (N,), elements=weights),
    arrays(np.float64, (P, D), elements=coords),
    arrays(np.float64, (P,), elements=weights),
    bandwidths,
)
def test_mmd_is_nonnegative_symmetric_and_matches_the_textbook_expansion(x, wx, y, wy, bw):
    a = float(mmd2_weighted(x, wx, y, wy, bw))
    b = float(mmd2_weighted(y, wy, x, wx, bw))
    assert a >= 0.0
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(a, max(_naive_mmd2(x, wx, y, wy, bw), 0.0), rtol=1e-7, atol=1e-11)


@SETTINGS
@given(
    arrays(np.float64, (N, D), elements=coords),
    arrays(np.float64, (N,), elements=weights),
    arrays(np.float64, (P, D), elements=coords),
    arrays(np.float64, (P,), elements=weights),
    st.permutations(range(N)),
)
def test_mmd_is_invariant_to_permuting_samples_with_their_weights(x, wx, y, wy, perm):
    perm = np.asarray(perm)
    a = float(mmd2_weighted(x, wx, y, wy, 2.0))
    b = float(mmd2_weighted(x[perm], wx[perm], y, wy, 2.0))
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-13)


@SETTINGS
@given(
    arrays(np.float64, (N, D), elements=coords),
    arrays(np.float64, (N,), elements=weights),
    st.floats(0.0, 1.0),
)
def test_splitting_a_weight_over_a_duplicated_sample_changes_nothing(x, w, frac):
    x2 = np.concatenate([x, x[:1]])
    w2 = np.concatenate([w, [w[0] * (1 - frac)]])
    w2[0] = w[0] * frac
    y = np.zeros((2, D))
    wy = np.array([0.5, 0.5])
    np.testing.assert_allclose(
        float(mmd2_weighted(x, w, y, wy, 1.5)),
        float(mmd2_weighted(x2, w2, y, wy, 1.5)),
        rtol=1e-9,
        atol=1e-13,
    )


@SETTINGS
@given(
    arrays(np.float64, (P,), elements=st.floats(0.0, 3.0)),
    arrays(np.float64, (P,), elements=weights),
    bandwidths,
)
def test_dirac_form_agrees_with_the_general_mmd_against_a_same_mass_dirac(a, w, bw):
    general = mmd2_weighted(a[:, None], w, np.zeros((1, 1)), np.array([w.sum()]), bw)
    np.testing.assert_allclose(
        float(mmd2_to_dirac(a, w, bw)), float(general), rtol=1e-6, atol=1e-12
    )


def test_dirac_form_keeps_relative_accuracy_in_float32_where_the_expansion_loses_it():
    rng = np.random.default_rng(0)
    a = rng.uniform(1e-3, 1e-2, 30)  # small penetrations
    w = np.full(30, 1 / 10)
    ref = float(mmd2_to_dirac(a, w, 30.0))  # float64
    approx = (w @ a) ** 2 / 30.0**2  # the σ ≫ f̄ limit (the reference bandwidth)
    np.testing.assert_allclose(ref, approx, rtol=1e-3)
    f32 = float(mmd2_to_dirac(a.astype(np.float32), w.astype(np.float32), np.float32(30.0)))
    np.testing.assert_allclose(f32, ref, rtol=1e-5)
    # the reference's expansion Σwwκ − 2Σwuκ + Σuu in float32 is pure rounding noise here
    a32, w32 = a.astype(np.float32), w.astype(np.float32)
    k = np.exp(-((a32[:, None] - a32[None]) ** 2) / np.float32(1800))
    k0 = np.exp(-(a32**2) / np.float32(1800))
    naive = w32 @ k @ w32 - 2 * (w32 @ k0) * w32.sum() + w32.sum() ** 2
    assert abs(naive - ref) > ref  # (it is even negative for this seed)


def test_general_mmd_float32_agrees_with_float64_to_float32_resolution():
    # the general form is exact for P = P but not cancellation-free for distinct sets: its
    # float32 error is of the order of eps32·(Σw)², like the expansion; use float64 for tiny MMDs
    rng = np.random.default_rng(1)
    x = rng.normal(size=(20, 3))
    y = x + 1e-2 * rng.normal(size=(20, 3))
    w = np.full(20, 0.05)
    ref = float(mmd2_weighted(x, w, y, w, 5.0))
    x32, y32, w32 = (v.astype(np.float32) for v in (x, y, w))
    f32 = float(mmd2_weighted(x32, w32, y32, w32, np.float32(5.0)))
    assert abs(f32 - ref) < 1e-6 * w.sum() ** 2
    assert float(mmd2_weighted(x32, w32, x32, w32, np.float32(5.0))) <= 1e-6


def test_gram_matrices_are_batched_symmetric_with_unit_diagonal():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(4, 7, 3)) + 100.0  # a large common offset must not cost precision
    K = gaussian_gram(x, None, 1.3)
    assert K.shape == (4, 7, 7)
    np.testing.assert_array_equal(np.diagonal(K, axis1=1, axis2=2), 1.0)
    np.testing.assert_allclose(K, np.swapaxes(K, 1, 2), atol=1e-14)
    direct = np.exp(-((x[:, :, None] - x[:, None]) ** 2).sum(-1) / (2 * 1.3**2))
    np.testing.assert_allclose(K, direct, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(one_minus_gaussian_gram(x, None, 1.3), 1 - direct, atol=1e-12)
    assert float(jnp.min(sq_distances(x))) >= 0.0


def test_median_heuristic_scales_with_the_data_and_survives_identical_samples():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(30, 4))
    s = float(median_heuristic(x))
    np.testing.assert_allclose(float(median_heuristic(3.0 * x)), 3.0 * s, rtol=1e-9)
    d = np.sqrt(((x[:, None] - x[None]) ** 2).sum(-1))[np.triu_indices(30, 1)]
    np.testing.assert_allclose(s, np.median(d), rtol=1e-9)
    assert float(median_heuristic(np.ones((10, 4)))) == 1.0
    mostly_same = np.concatenate([np.zeros((8, 2)), [[3.0, 4.0]]])
    assert float(median_heuristic(mostly_same)) == 5.0  # median 0 -> mean of non-zero distances


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_median_heuristic_is_the_exact_median_of_the_distinct_pairwise_distances(dtype):
    """The sort-free (radix select) median equals NumPy's median over the n(n−1)/2 pairs."""
    rng = np.random.default_rng(1)
    for n, d in [(2, 3), (7, 1), (37, 5), (100, 20)]:
        x = (rng.normal(size=(n, d)) * rng.uniform(0.01, 100.0)).astype(dtype)
        dist = np.sqrt(((x[:, None].astype(float) - x[None]) ** 2).sum(-1))
        want = np.median(dist[np.triu_indices(n, 1)])
        got = float(median_heuristic(jnp.asarray(x)))
        assert got == pytest.approx(want, rel=1e-5 if dtype == np.float32 else 1e-12)
