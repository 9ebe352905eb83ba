"""Baselines: every method runs the same optimiser and returns a plan; the collision terms."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mmdopt
from mmdopt import collision as baselines
from mmdopt.kernels import mmd2_to_dirac

from .test_algorithm import EGO, SMALL, _obstacle

# the float64 numerics of these functions (the public entry points run them under x64)
pytestmark = pytest.mark.usefixtures("x64")


@pytest.fixture(scope="module")
def scene():
    # a two-mode obstacle: 70 % change to the left lane, 30 % stay ahead in the ego lane
    a = _obstacle(x0=40.0, v=5.0, n=21, jitter=1.0, seed=1)
    b = _obstacle(x0=40.0, v=5.0, n=9, jitter=1.0, seed=2)
    lat = 3.5 * (1.0 - np.exp(-np.linspace(0.0, 15.0, 100) / 1.5))
    a[..., 1] = lat
    return np.concatenate([a, b], axis=1)


@pytest.mark.slow
@pytest.mark.parametrize("method", mmdopt.PLAN_METHODS)
def test_every_method_returns_a_feasible_plan(scene, method):
    p = mmdopt.plan(
        EGO, mmdopt.Road(), scene, method=method, config=SMALL, key=jax.random.PRNGKey(0)
    )
    assert p.method == method
    assert np.isfinite(p.cost) and p.feasible and not p.fallback
    J = (
        SMALL.selection.reduced_set_size
        if method in ("mmd", "random", "degroot")
        else scene.shape[1]
    )
    assert np.shape(p.reduced_set.indices) == (1, J)
    np.testing.assert_allclose(np.sum(p.reduced_set.weights, axis=1), 1.0, rtol=1e-6)
    assert p.progress > 20.0


def test_degroot_picks_the_samples_in_conflict_with_the_straight_line(scene):
    p = mmdopt.plan(EGO, mmdopt.Road(), scene, method="degroot", config=SMALL)
    # the 9 "stay" samples (indices 21..29) conflict with the constant-velocity guess
    assert set(range(21, 30)) <= set(np.asarray(p.reduced_set.indices[0]).tolist())


def test_mmd_cost_matches_the_pairwise_kernel_formula():
    rng = np.random.default_rng(0)
    f = jnp.asarray(rng.uniform(-1.0, 1.0, size=(4, 2, 6, 3, 7)))
    w = jnp.asarray(rng.dirichlet(np.ones(6), size=2))
    for bw, sc in ((0.5, 1.0), (30.0, 1.0), (0.3, 0.5)):
        got = baselines.mmd_cost(f, w, bw, sc, baselines.taylor_terms(sc / bw))
        fb = jnp.maximum(jnp.max(f, axis=3), 0.0) * sc  # (B, O, J, K)
        a = jnp.moveaxis(fb, 2, -1)  # (B, O, K, J)
        ref = jnp.sum(
            mmd2_to_dirac(a, jnp.broadcast_to(w[None, :, None], a.shape), bw), axis=(1, 2)
        )
        np.testing.assert_allclose(got, ref, rtol=1e-7, atol=1e-14)


def test_collision_terms_vanish_far_from_every_sample():
    f = -jnp.ones((3, 1, 5, 3, 10))
    mask = jnp.ones((1, 5), bool)
    assert np.all(np.asarray(baselines.scenario_cost(f, mask)) == 0.0)
    assert np.all(np.asarray(baselines.mmd_cost(f, jnp.full((1, 5), 0.2), 0.5, 1.0, 21)) == 0.0)
    pen, pi = baselines.saa_cost(f, mask, 0.02, 0.05)
    assert np.all(np.asarray(pen) == 0.0) and np.all(np.asarray(pi) < 1e-6)


def test_saa_counts_the_fraction_of_colliding_samples():
    f = jnp.concatenate([jnp.full((1, 1, 3, 1, 4), 0.5), -jnp.ones((1, 1, 7, 1, 4))], axis=2)
    pen, pi = baselines.saa_cost(f, jnp.ones((1, 10), bool), 0.1, 0.05)
    assert float(pi[0, 0]) == pytest.approx(0.3, abs=1e-3)
    assert float(pen[0]) == pytest.approx((0.3 - 0.1) / 0.1, abs=1e-2)


def test_cvar_is_the_mean_of_the_worst_tail_of_the_largest_violations():
    """CVaR_α over the masked samples (the journal's ``compute_cvar_obs``): the worst
    (1 − α)·n samples' largest violations averaged, a fractional sample weighted by its
    fraction; the largest violation when fewer than one sample is in the tail; 0 far away."""
    g = jnp.array([0.9, 0.1, 0.5, 0.0, 0.3, 0.7, 0.0, 0.2, 0.4, 0.6])  # (J,) = 10 samples
    f = jnp.stack([g - 0.05, g], axis=-1)[None, None, :, None, :]  # (1, 1, 10, 1, 2): max = g
    mask = jnp.ones((1, 10), bool)
    cost = lambda a, m=mask: float(baselines.cvar_cost(f, m, a)[0])  # noqa: E731
    assert cost(0.8) == pytest.approx((0.9 + 0.7) / 2)
    assert cost(0.75) == pytest.approx((0.9 + 0.7 + 0.5 * 0.6) / 2.5)
    assert cost(0.99) == pytest.approx(0.9)  # q = 0.1 < 1 sample: the worst one
    assert cost(0.0) == pytest.approx(float(jnp.mean(g)))
    # masked samples are not futures: the worst one masked away, the tail of the other 9
    m = mask.at[0, 0].set(False)
    assert cost(1 - 2 / 9, m) == pytest.approx((0.7 + 0.6) / 2)
    # negative f (outside every ellipse) is no violation
    assert float(baselines.cvar_cost(-jnp.ones((2, 1, 5, 3, 4)), mask[:, :5], 0.9)[0]) == 0.0


def test_cvar_sits_on_the_risk_dial():
    """α = 1 − ε in the "samples" margin mode (the CVaR averages the ε-tail the chance
    constraint speaks of), the journal's 0.98 in the "linear" mode, a set α where given."""
    cfg = mmdopt.config_for_risk("cvar", 0.01)
    assert cfg.cvar_level == pytest.approx(0.99)
    assert mmdopt.MMDOptConfig().replace(margin_mode="linear").cvar_level == 0.98
    assert cfg.replace(cvar_alpha=0.9).cvar_level == 0.9
    with pytest.raises(ValueError, match="cvar_alpha"):
        mmdopt.MMDOptConfig().replace(cvar_alpha=1.0)
    rec = mmdopt.methods.get("cvar")
    assert rec.all_samples and rec.collision == "tail"


@pytest.mark.slow
def test_baseline_margin_scale_inflates_only_the_baselines_ellipse(scene):
    """``baseline_margin_scale`` (default 0: the nominal ellipse, as de Groot et al.) scales the
    planning margins of the scenario baselines; at 1 de Groot keeps the margins MMD-Opt plans
    with and falls further behind the obstacle it follows; MMD-Opt's plan is unaffected.  (The
    time-linear margin mode: the sample-driven one has no such constants.)"""
    lin = SMALL.replace(margin_mode="linear", reselect=0)
    with pytest.raises(ValueError, match="baseline_margin_scale"):
        lin.replace(baseline_margin_scale=-0.5)
    t = np.linspace(0.0, 15.0, 5)
    np.testing.assert_allclose(
        mmdopt.algorithm.planning_semi_axis(lin, t, scale=0.0), lin.safety.footprint.a
    )
    key = jax.random.PRNGKey(0)
    nominal = mmdopt.plan(EGO, mmdopt.Road(), scene, method="degroot", config=lin, key=key)
    inflated = mmdopt.plan(
        EGO,
        mmdopt.Road(),
        scene,
        method="degroot",
        key=key,
        config=lin.replace(baseline_margin_scale=1.0),
    )
    assert inflated.progress < nominal.progress - 5.0, (inflated.progress, nominal.progress)
    m0 = mmdopt.plan(EGO, mmdopt.Road(), scene, method="mmd", config=lin, key=key)
    m1 = mmdopt.plan(
        EGO,
        mmdopt.Road(),
        scene,
        method="mmd",
        key=key,
        config=lin.replace(baseline_margin_scale=1.0),
    )
    np.testing.assert_array_equal(m0.x, m1.x)
