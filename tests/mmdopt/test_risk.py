"""The risk level (target collision probability ε) and the sample-driven margins."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import mmdopt
from mmdopt.planner import apply_risk
from mmdopt.risk import config_for_risk, coverage_margins, risk_z

from .test_algorithm import EGO, SMALL, _obstacle


def _two_clusters(n=40, seed=0):
    """(1, n, K, 2): half the samples at 5 m/s, half at 8 m/s, each jittered by 0.5 m/s."""
    rng = np.random.default_rng(seed)
    a = _obstacle(x0=40.0, v=5.0, n=n // 2, jitter=0.5, seed=seed)
    b = _obstacle(x0=40.0, v=8.0, n=n - n // 2, jitter=0.5, seed=seed + 1)
    x = np.concatenate([a, b], axis=1)
    return x + 0.0 * rng.standard_normal(x.shape)


def test_every_method_has_a_knob_with_a_default():
    for m in mmdopt.PLAN_METHODS:
        cfg = config_for_risk(m)
        rec = mmdopt.methods.get(m)
        assert cfg.safety.margins.margin_mode == "samples"
        assert cfg.safety.risk == rec.default_risk
        if rec.collision == "embedding":  # the coverage term of the MMD cost
            assert cfg.cost.w_cover == 100.0
        want = cfg.selection.reduced_set_size // 2 if rec.auto_reselect else 0
        assert rec.reselect(cfg) == want
    assert config_for_risk("saa", 0.03).saa_level == 0.03
    # the knob only changes what it maps to: the rest of the caller's config is kept
    assert config_for_risk("mmd", 0.01, SMALL).cem.n_samples == SMALL.cem.n_samples


def test_the_default_config_is_every_methods_knob_at_its_default():
    """``plan(..., method=m)`` plans as ``plan(..., method=m, risk=ε)`` (ε the record's
    default): the sample-driven margins, the coverage term and SAA's chance level all follow
    the knob, and no method runs the re-selection pass unless asked (``reselect``);
    ``margin_mode="linear"`` keeps the old constants."""
    X = _two_clusters()
    road = mmdopt.Road()
    key = jax.random.PRNGKey(3)
    cfg = mmdopt.MMDOptConfig()
    assert (
        cfg.safety.margins.margin_mode == "samples"
        and cfg.safety.risk == 0.005
        and cfg.cost.w_cover == 100.0
    )
    get = mmdopt.methods.get
    assert [get(m).reselect(cfg) for m in mmdopt.PLAN_METHODS] == [0] * len(mmdopt.PLAN_METHODS)
    assert get("mmd").reselect(cfg.replace(reselect=7)) == 7
    assert cfg.saa_level == cfg.safety.risk
    assert cfg.replace(margin_mode="linear").saa_level == 0.02
    assert cfg.replace(saa_eps=0.1).saa_level == 0.1
    small = SMALL
    for m in mmdopt.PLAN_METHODS:
        # the config plan() runs with: the same, field by field (SAA's level made explicit)
        eps = mmdopt.methods.get(m).default_risk
        a, b = (apply_risk(m, r, small) for r in (None, eps))
        assert a.replace(saa_eps=a.saa_level) == b.replace(saa_eps=b.saa_level), m
    for m in ("mmd", "saa"):  # and the plans (the automatic re-selection, SAA's level)
        a = mmdopt.plan(EGO, road, X, method=m, config=small, key=key)
        eps = mmdopt.methods.get(m).default_risk
        b = mmdopt.plan(EGO, road, X, method=m, config=small, key=key, risk=eps)
        assert a.status in ("ok", "risk floor"), (m, a.status_text)
        np.testing.assert_array_equal(a.s, b.s, err_msg=m)
        np.testing.assert_array_equal(a.d, b.d, err_msg=m)
        assert "reselected" not in a.diagnostics
    with pytest.raises(ValueError, match="reselect"):
        mmdopt.MMDOptConfig().replace(reselect=-2)


@pytest.mark.parametrize("bad", [0.0, 0.5, -0.1, float("nan"), float("inf"), "x", True, None])
def test_bad_knob_is_a_clear_error(bad):
    if bad is None:  # None means "the default": not an error
        assert config_for_risk("mmd", None).safety.risk == mmdopt.methods.get("mmd").default_risk
        return
    with pytest.raises(ValueError, match="risk"):
        config_for_risk("mmd", bad)
    with pytest.raises(ValueError, match="method"):
        config_for_risk("nope", 0.01)


def test_margins_grow_as_the_risk_falls_and_cover_the_cluster():
    X = _two_clusters()
    idx = np.array([[0, 25]])  # one point in each speed cluster
    lo = coverage_margins(X, idx, 0.1)
    hi = coverage_margins(X, idx, 0.001)
    assert lo.shape == (3, 1, 2, X.shape[2])
    assert np.all(hi >= lo - 1e-12) and np.all(lo >= 0)
    # at ε = 0.001 every sample of a cluster lies within its point's behind / ahead margins
    for j, (p, members) in enumerate(((0, range(20)), (25, range(20, 40)))):
        e = X[0, list(members), :, 0] - X[0, p, :, 0]
        assert np.all(-e <= hi[0, 0, j] + 1e-9) and np.all(e <= hi[1, 0, j] + 1e-9)
    # the spread of a constant-speed jitter grows with time: so do the margins (no constant)
    assert hi[0, 0, 0, -1] > hi[0, 0, 0, 10] > hi[0, 0, 0, 0] - 1e-12
    assert risk_z(0.5 - 1e-12) == pytest.approx(0.0, abs=1e-9)


def _direct_margins(X, idx, eps, prior=2.0, knn=0, lateral_scale=1.0):
    """The margins' definition, point by point: each cluster's members, their deviations from
    the point, mean and (biased) variance, shrunk to the pooled spread with ``prior``."""
    z = risk_z(eps)
    O, n, K, _ = X.shape
    out = np.empty((3, O, idx.shape[1], K))
    for o in range(O):
        F = (X[o] * [1.0, lateral_scale]).reshape(n, -1)
        D = ((F[idx[o]][:, None] - F[None]) ** 2).sum(-1)  # (J, n)
        owner = D.argmin(0)
        stats = []
        for j, p in enumerate(idx[o]):
            if knn:
                members = np.argsort(D[j], kind="stable")[:knn]
            else:
                members = np.union1d(np.flatnonzero(owner == j), [p])
            dev = X[o, members] - X[o, p]  # (c, K, 2)
            stats.append((len(members), dev.mean(0), dev.var(0)))
        c = np.array([st[0] for st in stats], float)
        mu = np.stack([st[1] for st in stats])  # (J, K, 2)
        v = np.stack([st[2] for st in stats])
        pool = (c[:, None, None] * v).sum(0) / c.sum()
        sd = np.sqrt((c[:, None, None] * v + prior * pool) / (c[:, None, None] + prior))
        out[0, o] = np.maximum(z * sd[..., 0] - mu[..., 0], 0.0)
        out[1, o] = np.maximum(z * sd[..., 0] + mu[..., 0], 0.0)
        out[2, o] = np.abs(mu[..., 1]) + z * sd[..., 1]
    return out


@pytest.mark.parametrize("seed", range(6))
def test_coverage_margins_equal_their_definition_far_from_the_origin(seed):
    """The vectorised per-cluster sums give the margins of the definition, with clusters of
    one, a duplicated point, k-NN clusters and coordinates a kilometre from the origin."""
    rng = np.random.default_rng(seed)
    O, n, K = 2, int(rng.integers(5, 60)), 9
    X = rng.normal(size=(O, n, K, 2)) * [4.0, 0.8] + [1500.0, -40.0]
    J = int(rng.integers(1, n))
    idx = np.stack([rng.choice(n, J, replace=False) for _ in range(O)])
    idx = np.concatenate([idx, idx[:, :1]], axis=1)  # a duplicated point: a cluster of one
    for kw in (dict(), dict(knn=int(rng.integers(1, n + 1))), dict(lateral_scale=10.0)):
        got = coverage_margins(X, idx, 0.01, **kw)
        np.testing.assert_allclose(got, _direct_margins(X, idx, 0.01, **kw), rtol=0, atol=1e-9)


@pytest.mark.parametrize("rows", [False, True])
def test_two_samples_of_equal_coordinates_are_one_point_named_twice(rows):
    """A point set holding two samples with the same coordinates (a car at rest, a noise-free
    mode) gets the margins of that point named twice: the samples join the first copy, not
    whichever copy a matrix product's rounding makes the nearer (that depends on the BLAS)."""
    from mmdopt.risk import coverage_data

    rng = np.random.default_rng(3)
    n, K = 400, 12
    X = np.stack([np.cumsum(rng.uniform(0.5, 2, (1, n, K)), -1), rng.normal(0, 1, (1, n, K))], -1)
    X[0, 17] = X[0, 5]  # sample 17: a copy of sample 5
    pts = rng.choice(np.setdiff1d(np.arange(n), [5, 17]), 10, replace=False)
    copies = np.r_[pts, 5, 17][None]
    named_twice = np.r_[pts, 5, 5][None]
    kw = dict(lateral_scale=10.0)
    if rows:
        kw["data"] = coverage_data(X, 10.0, np.arange(0, n, 3))
    got = coverage_margins(X, copies, 0.01, **kw)
    np.testing.assert_array_equal(got, coverage_margins(X, named_twice, 0.01, **kw))


def test_coverage_margins_check_their_inputs():
    X = _two_clusters()
    with pytest.raises(ValueError, match="obstacles_frenet"):
        coverage_margins(X[0], np.array([[0]]), 0.01)
    with pytest.raises(ValueError, match="indices"):
        coverage_margins(X, np.array([[0, 99]]), 0.01)
    with pytest.raises(ValueError, match="eps"):
        coverage_margins(X, np.array([[0]]), 0.0)
    bad = X.copy()
    bad[0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        coverage_margins(bad, np.array([[0]]), 0.01)
    with pytest.raises(ValueError, match="knn"):
        coverage_margins(X, np.array([[0]]), 0.01, knn=-1)


@pytest.mark.parametrize("eps", [0.01, 0.001])
def test_bandwidth_covers_the_tail_beyond_the_extreme_samples(eps):
    """Fresh futures from the samples' own distribution fall behind the slowest margin at about
    rate ε with the density bandwidth, and several times more often without it (each cluster's
    Gaussian understates the tail past the extreme sample)."""
    n, fresh = 20, 4000
    miss = {0.0: [], 1.0: []}
    for seed in range(20):
        X = _obstacle(x0=40.0, v=5.0, n=n, jitter=1.0, seed=seed)
        F = _obstacle(x0=40.0, v=5.0, n=fresh, jitter=1.0, seed=1000 + seed)[0, :, -1, 0]
        idx = np.sort(np.random.default_rng(seed).choice(n, 4, replace=False))[None]
        for bw in miss:
            m = coverage_margins(X, idx, eps, bandwidth=bw)
            envelope = np.min(X[0, idx[0], -1, 0] - m[0, 0, :, -1])  # slowest covered position
            miss[bw].append(np.mean(F < envelope))
    assert np.mean(miss[1.0]) <= 1.5 * eps
    assert np.mean(miss[0.0]) >= 1.5 * np.mean(miss[1.0])
    # off by default: bandwidth 0 is the plain cluster fit; the margins grow with it
    X = _two_clusters()
    idx = np.array([[0, 25]])
    m0 = coverage_margins(X, idx, 0.01)
    np.testing.assert_array_equal(m0, coverage_margins(X, idx, 0.01, bandwidth=0.0))
    m1 = coverage_margins(X, idx, 0.01, bandwidth=1.0)
    assert np.all(m1[:2] >= m0[:2] - 1e-12) and np.all(m1[2] == m0[2])
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="bandwidth"):
            coverage_margins(X, idx, 0.01, bandwidth=bad)
        with pytest.raises(ValueError, match="coverage_bandwidth"):
            mmdopt.MMDOptConfig().replace(coverage_bandwidth=bad)


def test_plan_risk_knob_trades_progress_for_safety():
    """A smaller target collision probability keeps the ego further behind the slow futures."""
    X = _two_clusters()
    road = mmdopt.Road()
    key = jax.random.PRNGKey(0)
    loose = mmdopt.plan(EGO, road, X, method="mmd", config=SMALL, key=key, risk=0.2)
    tight = mmdopt.plan(EGO, road, X, method="mmd", config=SMALL, key=key, risk=0.001)
    for p in (loose, tight):
        assert p.feasible and not p.fallback and p.status in ("ok", "risk floor"), p.status_text
    assert tight.progress <= loose.progress + 1e-6
    # the density bandwidth (an option) widens the slow tail: the plan stays further back
    wide = mmdopt.plan(
        EGO, road, X, method="mmd", config=SMALL.replace(coverage_bandwidth=1.0), key=key,
        risk=0.001,
    )  # fmt: skip
    assert wide.feasible and not wide.fallback
    assert wide.progress <= tight.progress + 1e-6
    # the tight plan keeps every planning sample clear
    assert np.all(tight.diagnostics["collision_free_planning"] == X.shape[1])
    # with the re-selection pass asked for, it adds the samples in deepest conflict with the
    # first plan to the set
    r = SMALL.selection.reduced_set_size // 2
    again = mmdopt.plan(EGO, road, X, method="mmd", config=SMALL.replace(reselect=r), key=key,
                        risk=0.001)  # fmt: skip
    extra = again.diagnostics["reselected"]
    assert extra.shape == (1, r)
    assert not set(extra[0].tolist()) & set(np.asarray(again.reduced_set.indices)[0].tolist())
    assert np.all(again.diagnostics["collision_free_planning"] == X.shape[1])
    with pytest.raises(ValueError, match="risk"):
        mmdopt.plan(EGO, road, X, method="mmd", config=SMALL, key=key, risk=0.7)


def test_reselection_leaves_the_eps_n_deepest_conflicts_to_the_chance_level():
    """Sampling and discarding: at risk ε the second pass skips the ⌊ε·n⌋ samples in deepest
    conflict with the first plan and adds the next ones."""
    X = _two_clusters()
    n = X.shape[1]
    road = mmdopt.Road()
    key = jax.random.PRNGKey(0)
    cfg = SMALL.replace(reselect=SMALL.selection.reduced_set_size // 2)
    for risk in (0.001, 0.05, 0.2):
        p = mmdopt.plan(EGO, road, X, method="mmd", config=cfg, key=key, risk=risk)
        assert p.feasible and not p.fallback
        k = int(np.floor(risk * n))
        extra, dropped = p.diagnostics["reselected"], p.diagnostics["discarded"]
        depth = p.diagnostics["conflict_depth"][0]
        assert dropped.shape == (1, k)
        assert extra.shape == (
            1,
            min(SMALL.selection.reduced_set_size // 2, n - SMALL.selection.reduced_set_size - k),
        )
        chosen = set(np.asarray(p.reduced_set.indices)[0].tolist())
        assert not (set(extra[0].tolist()) | set(dropped[0].tolist())) & chosen
        assert not set(extra[0].tolist()) & set(dropped[0].tolist())
        if k:
            # every dropped sample conflicts at least as deeply as every added one
            assert depth[dropped[0]].min() >= depth[extra[0]].max()


@pytest.mark.slow
def test_reselection_pass_also_runs_with_the_time_linear_margins():
    """``reselect`` > 0 with ``margin_mode = "linear"``: the samples in deepest conflict with
    the first plan join the reduced set (none of them already in it) and the plan that comes
    back is feasible and keeps every planning sample at least as clear as without the pass."""
    X = _two_clusters()
    road = mmdopt.Road()
    key = jax.random.PRNGKey(0)
    cfg = SMALL.replace(reduced_set_size=4, margin_mode="linear", reselect=0)
    one = mmdopt.plan(EGO, road, X, method="mmd", config=cfg, key=key)
    two = mmdopt.plan(EGO, road, X, method="mmd", config=cfg.replace(reselect=3), key=key)
    assert "reselected" not in one.diagnostics
    for p in (one, two):
        assert p.feasible and not p.fallback
    extra = two.diagnostics["reselected"]
    assert extra.shape == (1, 3)
    assert not set(extra[0].tolist()) & set(np.asarray(two.reduced_set.indices)[0].tolist())
    depth = two.diagnostics["conflict_depth"][0]
    others = np.setdiff1d(np.arange(X.shape[1]), np.asarray(two.reduced_set.indices)[0])
    assert depth[extra[0]].min() >= np.sort(depth[others])[-3]  # the three deepest
    free = two.diagnostics["collision_free_planning"]
    assert np.all(free >= one.diagnostics["collision_free_planning"] - 1)


def test_coverage_data_built_once_gives_the_same_margins_bit_for_bit():
    """A planner builds the samples' CoverageData once and asks for the margins of several point
    sets (nearest-point clusters, k-NN clusters, with the kernel smoothing): each equals the
    margins computed from the samples alone, bit for bit; data of other samples is refused."""
    from mmdopt.risk import coverage_data

    rng = np.random.default_rng(3)
    X = rng.normal(size=(2, 300, 12, 2)) * [4.0, 1.0] + [50.0, 0.0]
    data = coverage_data(X, lateral_scale=10.0)
    for J, knn, bw in ((8, 0, 0.0), (8, 0, 0.5), (20, 30, 0.0)):
        idx = np.stack([rng.choice(300, J, replace=False) for _ in range(2)])
        idx[:, -1] = idx[:, 0]  # a repeated point
        kw = dict(lateral_scale=10.0, knn=knn, bandwidth=bw)
        a = coverage_margins(X, idx, 0.01, **kw)
        b = coverage_margins(X, idx, 0.01, data=data, **kw)
        assert np.array_equal(a, b)
    with pytest.raises(ValueError, match="lateral_scale"):
        coverage_margins(X, idx, 0.01, lateral_scale=1.0, data=data)
    with pytest.raises(ValueError, match="data"):
        coverage_margins(X, idx, 0.01, data="cached")


def test_coverage_pool_forms_the_knn_clusters_among_a_subset():
    """With a pool the k-NN cluster of a point is the point and its k nearest pool samples: the
    pool of all samples gives the margins without one bit for bit, the definition holds for a
    pool that leaves the points out, and an evenly spaced fifth of the samples with k scaled
    by a fifth gives the full clusters' margins (the same neighbourhoods, a fifth of the
    work): their sums agree to 6 %, the margins of single points scatter by the noise of
    fewer members."""
    rng = np.random.default_rng(8)
    n, K = 2000, 10
    t = np.linspace(0.0, 5.0, K)
    v = np.where(rng.random((n, 1)) < 0.5, 5.0, 9.0) + rng.normal(0, 1.0, (n, 1))
    lane = np.where(rng.random((n, 1)) < 0.3, 3.5, 0.0) * np.minimum(t / 3.0, 1.0)
    X = np.stack([30 + v * t, lane + rng.normal(0, 0.3, (n, 1))], -1)[None]  # two intents
    idx = np.sort(rng.choice(n, 25, replace=False))[None]
    full = coverage_margins(X, idx, 0.01, knn=200)
    assert np.array_equal(coverage_margins(X, idx, 0.01, knn=200, pool=np.arange(n)[None]), full)
    rest = np.setdiff1d(np.arange(n), idx[0])  # the points left out of the pool
    got = coverage_margins(X, idx, 0.01, knn=50, pool=rest[None], prior=0.0)
    for j, p in enumerate(idx[0]):  # (no shrinkage: each cluster on its own)
        own = X[:, np.concatenate([[p], rest])]  # the point and the pool
        want = _direct_margins(own, np.array([[0]]), 0.01, prior=0.0, knn=51)
        np.testing.assert_allclose(got[:, :, j], want[:, :, 0], rtol=0, atol=1e-9)
    pool = np.linspace(0, n - 1, n // 5).round().astype(int)[None]
    fifth = coverage_margins(X, idx, 0.01, knn=40, pool=pool)
    for side in range(3):  # behind, ahead, lateral: no bias, the noise of fewer members
        assert abs(fifth[side].sum() / full[side].sum() - 1.0) < 0.06
        assert np.linalg.norm(fifth[side] - full[side]) < 0.25 * np.linalg.norm(full[side])
    with pytest.raises(ValueError, match="pool needs knn"):
        coverage_margins(X, idx, 0.01, pool=pool)
    with pytest.raises(ValueError, match="pool must have shape"):
        coverage_margins(X, idx, 0.01, knn=5, pool=pool[0])
    with pytest.raises(ValueError, match="pool must be integers"):
        coverage_margins(X, idx, 0.01, knn=5, pool=pool + n)
