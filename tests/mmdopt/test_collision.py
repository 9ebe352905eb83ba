"""Circle footprints, the MMD collision surrogate l_dist and the collision-free count."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mmdopt  # noqa: F401
from mmdopt import collision
from mmdopt.collision import (
    OBSTACLE_FOOTPRINT,
    CircleFootprint,
    ReducedObstacles,
    SurrogateConfig,
    circle_centres,
    collision_free_count,
    f_bar,
    headings,
    mmd_surrogate,
    mmd_surrogate_terms,
    reduced_obstacles,
)

# the float64 numerics of these functions (the public entry points run them under x64)
pytestmark = pytest.mark.usefixtures("x64")

K, DT = 50, 0.1
T = np.arange(K) * DT


def _obstacle(m=5, lateral=0.0, seed=0, speed=5.0, x0=20.0):
    """m reduced samples of one obstacle driving along x at lateral offset ``lateral`` (m)."""
    rng = np.random.default_rng(seed)
    x = x0 + (speed + rng.normal(0, 0.3, m))[:, None] * T
    y = lateral + rng.normal(0, 0.1, m)[:, None] + 0 * T
    return np.stack([x, y], -1)  # (m, K, 2)


def _ro(samples_list, weights_list=None):
    cs = [circle_centres(jnp.asarray(s), OBSTACLE_FOOTPRINT) for s in samples_list]
    if weights_list is None:
        weights_list = [np.full(len(s), 1 / len(s)) for s in samples_list]
    return ReducedObstacles(centres=jnp.stack(cs), weights=jnp.asarray(np.stack(weights_list)))


def _ego(lateral):
    """Ego at 10 m/s starting at x = 0, at the given lateral offsets -> (B, K, 2)."""
    lateral = np.atleast_1d(lateral)
    x = np.broadcast_to(10.0 * T, (len(lateral), K))
    y = np.broadcast_to(lateral[:, None], (len(lateral), K))
    return np.stack([x, y], -1)


def test_headings_follow_the_path_with_the_last_value_repeated():
    xy = np.stack([T, T], -1)  # 45°
    np.testing.assert_allclose(headings(xy), np.pi / 4)
    turn = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    np.testing.assert_allclose(headings(turn), [0.0, np.pi / 2, np.pi / 2])


def test_obstacle_circles_sit_along_the_heading():
    xy = np.stack([T, np.zeros(K)], -1)
    c = np.asarray(circle_centres(xy, OBSTACLE_FOOTPRINT))
    assert c.shape == (3, K, 2)
    np.testing.assert_allclose(c[:, 0], [[0.0, 0.0], [2.5, 0.0], [-2.5, 0.0]], atol=1e-12)
    up = np.stack([np.zeros(K), T], -1)
    c = np.asarray(circle_centres(up, OBSTACLE_FOOTPRINT))
    np.testing.assert_allclose(c[1, 3], up[3] + [0.0, 2.5], atol=1e-12)


def test_surrogate_is_exactly_zero_when_every_sample_is_clear():
    ro = _ro([_obstacle(lateral=0.0), _obstacle(lateral=3.5, seed=1)])
    ego = _ego([-8.0, 12.0])
    assert np.all(np.asarray(f_bar(ego[0][None, None, None], ro.centres, 4.5, 3.5)) == 0.0)
    np.testing.assert_array_equal(np.asarray(mmd_surrogate(ego, ro)), 0.0)
    cfg = SurrogateConfig(stack_circles=False, bandwidth=0.3)
    np.testing.assert_array_equal(np.asarray(mmd_surrogate(ego, ro, cfg)), 0.0)


@pytest.mark.parametrize("bandwidth, f_scale", [(30.0, 1.0), (0.5, 1.0), (1.0, 10.0)])
def test_surrogate_grows_monotonically_with_penetration(bandwidth, f_scale):
    ro = _ro([_obstacle(lateral=0.0)])
    offsets = np.linspace(6.0, 0.0, 25)  # ego lateral offset: from clear to head-on
    cfg = SurrogateConfig(bandwidth=bandwidth, f_scale=f_scale)
    vals = np.asarray(mmd_surrogate(_ego(offsets), ro, cfg))
    assert vals[0] == 0.0 and vals[-1] > 0.0
    assert np.all(np.diff(vals) >= 0.0), vals
    assert np.all(np.diff(vals[vals > 0]) > 0.0)


def test_surrogate_matches_the_definition_with_a_same_mass_dirac():
    rng = np.random.default_rng(3)
    ro = _ro([_obstacle(lateral=0.5)], [rng.dirichlet(np.ones(5))])
    ego = _ego([0.8])
    cfg = SurrogateConfig(bandwidth=0.7, f_scale=2.0)
    terms = np.asarray(mmd_surrogate_terms(ego, ro, cfg))[0, 0]  # (K,)
    fb = np.asarray(f_bar(ego[0][None, None], ro.centres[0], 4.5, 3.5)) * 2.0  # (m, C, K)
    w = np.repeat(np.asarray(ro.weights[0]), 3)  # replicated over the 3 circles, Σw = 3
    for k in (0, 10, 30):
        a = fb[:, :, k].reshape(-1)
        kern = np.exp(-((a[:, None] - a[None]) ** 2) / (2 * 0.7**2))
        k0 = np.exp(-(a**2) / (2 * 0.7**2))
        naive = w @ kern @ w - 2 * (w @ k0) * w.sum() + w.sum() ** 2
        np.testing.assert_allclose(terms[k], naive, rtol=1e-7, atol=1e-12)


def test_surrogate_is_accurate_in_float32_at_the_reference_bandwidth():
    ro = _ro([_obstacle(lateral=0.0)])
    ego = _ego([3.4])  # grazing: tiny penetrations
    v64 = float(mmd_surrogate(ego, ro)[0])
    ro32 = jax.tree_util.tree_map(lambda x: x.astype(jnp.float32), ro)
    cfg32 = jax.tree_util.tree_map(lambda x: jnp.float32(x), SurrogateConfig())
    v32 = float(mmd_surrogate(ego.astype(np.float32), ro32, cfg32)[0])
    assert 0.0 < v64 < 1e-4  # below the reference's float32 floor (≈2e-4)
    np.testing.assert_allclose(v32, v64, rtol=1e-4)


def test_obstacles_add_up_and_zero_weight_padding_is_inert():
    a, b = _obstacle(lateral=0.0), _obstacle(lateral=1.5, seed=2)
    ego = _ego([0.5, 1.0, 4.0])
    both = np.asarray(mmd_surrogate(ego, _ro([a, b])))
    sep = np.asarray(mmd_surrogate(ego, _ro([a]))) + np.asarray(mmd_surrogate(ego, _ro([b])))
    np.testing.assert_allclose(both, sep, rtol=1e-12)
    padded = _ro([np.concatenate([a, b[:2]])], [np.r_[np.full(5, 0.2), 0.0, 0.0]])
    np.testing.assert_allclose(
        np.asarray(mmd_surrogate(ego, padded)),
        np.asarray(mmd_surrogate(ego, _ro([a]))),
        rtol=1e-12,
    )


def test_batched_surrogate_equals_one_ego_at_a_time():
    ro = _ro([_obstacle(lateral=0.3)])
    ego = _ego(np.linspace(-1, 4, 6))
    batch = np.asarray(mmd_surrogate(ego, ro))
    single = [float(mmd_surrogate(ego[i : i + 1], ro)[0]) for i in range(6)]
    np.testing.assert_allclose(batch, single, rtol=1e-12)


def test_config_is_a_pytree_and_changing_a_scalar_does_not_recompile():
    cfg = SurrogateConfig()
    assert 30.0 in jax.tree_util.tree_leaves(cfg)
    ro = _ro([_obstacle()])
    ego = _ego([0.0])
    mmd_surrogate(ego, ro, cfg)
    before = mmd_surrogate._cache_size()
    mmd_surrogate(ego, ro, cfg.replace(bandwidth=0.4, f_scale=3.0))
    assert mmd_surrogate._cache_size() == before


def test_a_longer_ego_footprint_collides_earlier():
    ro = _ro([_obstacle(lateral=0.0, x0=15.0)])
    ego = _ego([4.5])  # beside the obstacle's lane
    point = float(mmd_surrogate(ego, ro)[0])
    wide = SurrogateConfig(ego_footprint=CircleFootprint((0.0, 2.0, -2.0)))
    long_ = float(mmd_surrogate(ego, ro, wide)[0])
    assert long_ >= point


def test_reduced_obstacles_from_reduced_sets():
    samples = np.stack([_obstacle(m=20, seed=4), _obstacle(m=20, lateral=3.5, seed=5)])
    idx = jnp.array([[3, 0, 7, 11], [5, 19, 2, 8]])
    rs = mmdopt.ReducedSet(
        idx, jnp.full((2, 4), 0.25), jnp.zeros((2, 20)), jnp.zeros(2), jnp.ones(2), "herding"
    )
    ro = reduced_obstacles(samples, rs)
    assert ro.centres.shape == (2, 4, 3, K, 2) and ro.weights.shape == (2, 4)
    np.testing.assert_allclose(
        np.asarray(ro.centres[1, 0, 0]), samples[1, int(rs.indices[1, 0])], atol=1e-12
    )


def test_collision_free_count_is_strict_and_counts_per_obstacle_and_jointly():
    a = _obstacle(m=10, lateral=0.0, seed=6)
    b = _obstacle(m=10, lateral=20.0, seed=7)
    ego_far = _ego([-30.0])[0]
    cc = collision_free_count(ego_far, np.stack([a, b]))
    np.testing.assert_array_equal(np.asarray(cc.per_obstacle), [10, 10])
    assert int(cc.joint) == 10
    ego_hit = _ego([0.0])[0]
    cc = collision_free_count(ego_hit, np.stack([a, b]))
    np.testing.assert_array_equal(np.asarray(cc.per_obstacle), [0, 10])
    assert int(cc.joint) == 0 and cc.colliding.shape == (2, 10)
    # f̄ > 0 strictly: just outside the ellipse is clear, just inside collides
    obs = np.zeros((1, 1, 2, 2))
    obs[..., 0] = 100.0  # the other circles far away: only the centre circle matters here
    fp = CircleFootprint((0.0,))
    edge = np.array([[100.0 + 4.5 + 1e-9, 0.0], [100.0 + 4.5 + 1e-9, 0.0]])
    assert int(collision_free_count(edge, obs, obstacle_footprint=fp).joint) == 1
    inside = edge - [2e-9, 0.0]
    assert int(collision_free_count(inside, obs, obstacle_footprint=fp).joint) == 0
    batch = collision_free_count(np.stack([ego_far, ego_hit]), np.stack([a, b]))
    np.testing.assert_array_equal(np.asarray(batch.joint), [10, 0])


def test_collision_free_count_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="validation_samples"):
        collision_free_count(np.zeros((K, 2)), np.zeros((2, 3, K + 1, 2)))
    with pytest.raises(ValueError, match="ego_xy"):
        collision_free_count(np.zeros((K, 3)), np.zeros((2, 3, K, 2)))


def test_surrogate_rejects_mismatched_shapes():
    ro = _ro([_obstacle()])
    with pytest.raises(ValueError, match="ego_xy"):
        mmd_surrogate(_ego([0.0])[0], ro)
    with pytest.raises(ValueError, match="obstacles.centres"):
        mmd_surrogate(_ego([0.0])[:, :10], ro)
    with pytest.raises(ValueError, match="obstacles.weights"):
        mmd_surrogate(_ego([0.0]), ReducedObstacles(ro.centres, ro.weights[:, :2]))


@pytest.mark.parametrize("mode", ["mmd", "scenario", "saa"])
def test_collision_cost_is_the_sum_over_obstacles_and_far_traffic_adds_nothing(mode):
    from mmdopt.collision import collision_cost, taylor_terms

    rng = np.random.default_rng(3)
    K = 30
    t = np.linspace(0, 5, K)
    s = jnp.asarray(np.stack([v * t for v in (2.0, 5.0, 8.0)]))  # (B = 3, K)
    d = jnp.zeros_like(s)
    near = np.stack([x0 + 4.0 * t for x0 in (10.0, 12.0)])  # two samples in the ego lane
    far = near + 500.0  # the same samples 500 m ahead: no ego point gets near
    cen = lambda xy: np.asarray(  # noqa: E731
        circle_centres(np.stack([xy, rng.normal(0, 0.3, xy.shape)], -1), OBSTACLE_FOOTPRINT)
    )
    c = jnp.asarray(np.stack([cen(near), cen(far), cen(near + 3.0)]))  # (O = 3, J = 2, C, K, 2)
    w = jnp.full((3, 2), 0.5)
    m = jnp.ones((3, 2), bool)
    kw = dict(bandwidth=0.5, f_scale=1.0, n_terms=taylor_terms(2.0, 1e-12))
    total = collision_cost(mode, s, d, c, w, m, 6.0, 3.5, **kw)
    single = [collision_cost(mode, s, d, c[o : o + 1], w[o : o + 1], m[o : o + 1], 6.0, 3.5, **kw)
              for o in range(3)]  # fmt: skip
    np.testing.assert_allclose(total, sum(single), rtol=1e-12)
    np.testing.assert_array_equal(np.asarray(single[1]), 0.0)
    assert float(jnp.max(total)) > 0
    with pytest.raises(ValueError, match="mode"):
        collision_cost("nope", s, d, c, w, m, 6.0, 3.5)


def test_reach_bound_never_misses_a_collision_and_gated_costs_equal_ungated():
    """The cheap per-step interval bound that gates each obstacle's term is an upper bound on
    max f (random batches), and an obstacle inside the batch's bounding box that no single ego
    point reaches (bound positive, every f ≤ 0) still adds exactly nothing."""
    from mmdopt.collision import _max_f_bound, collision_cost, ellipse_values, taylor_terms

    rng = np.random.default_rng(0)
    for _ in range(50):
        s, d = rng.normal(0, 20, (2, 8, 5))
        c = rng.normal(0, 20, (4, 3, 5, 2))
        a = rng.uniform(2, 8, 5)
        box = (s.min(0), s.max(0), d.min(0), d.max(0))
        bound = float(_max_f_bound(box, jnp.asarray(c), a, 2.0))
        assert bound >= float(jnp.max(ellipse_values(s, d, c[None], a, 2.0))) - 1e-12
        # following distance (per-candidate semi-axis behind a centre) and rear exemption
        a_behind = rng.uniform(2, 15, (8, 5))
        f = ellipse_values(s, d, c[None], a, 2.0, a_behind, 2.0)
        bound = float(_max_f_bound(box, jnp.asarray(c), np.maximum(a, a_behind.max(0)), 2.0))
        assert bound >= float(jnp.max(f)) - 1e-12
        # the following distance as a rule for the lane
        f = ellipse_values(s, d, c[None], a, 2.0, a_behind, 2.0, headway_lane=2.0)
        ab = np.maximum(a, a_behind.max(0))
        bound = float(_max_f_bound(box, jnp.asarray(c), ab, 2.0, lane=2.0))
        assert bound >= float(jnp.max(f)) - 1e-12
    # two ego candidates on opposite corners; the obstacle sits on the empty corner
    K = 10
    s = jnp.asarray(np.stack([np.zeros(K), np.full(K, 40.0)]))
    d = jnp.asarray(np.stack([np.full(K, 3.0), np.full(K, -3.0)]))
    corner = np.broadcast_to(np.array([0.0, -3.0]), (1, 1, K, 2))
    hit = np.broadcast_to(np.array([40.0, -3.0]), (1, 1, K, 2))
    c = jnp.asarray(np.stack([corner, hit]))  # (O = 2, J = 1, C = 1, K, 2)
    box = (jnp.min(s, 0), jnp.max(s, 0), jnp.min(d, 0), jnp.max(d, 0))
    assert float(_max_f_bound(box, c[0], 5.0, 2.0)) > 0
    assert float(jnp.max(ellipse_values(s, d, c[:1], 5.0, 2.0))) <= 0
    w, m = jnp.ones((2, 1)), jnp.ones((2, 1), bool)
    kw = dict(bandwidth=0.5, f_scale=1.0, n_terms=taylor_terms(2.0, 1e-12))
    for mode in ("mmd", "scenario", "saa"):
        total = collision_cost(mode, s, d, c, w, m, 5.0, 2.0, **kw)
        singles = [
            collision_cost(mode, s, d, c[o : o + 1], w[o : o + 1], m[o : o + 1], 5.0, 2.0, **kw)
            for o in range(2)
        ]
        np.testing.assert_array_equal(np.asarray(singles[0]), 0.0)
        np.testing.assert_allclose(total, singles[0] + singles[1], rtol=1e-12)
        assert float(total[1]) > 0 and float(total[0]) == 0.0


def test_a_following_distance_for_the_lane_gives_no_credit_for_half_a_lane_change():
    """An ego 10 m behind a car with a 30 m following distance (lateral semi-axis 3 m): with
    the ellipse, 2 m sideways lowers f by 4/9; as a rule for the lane f stays that of the
    longitudinal gap until the ego is 3 m to the side, where it owes nothing.  Ahead of the car
    and without a following distance nothing changes; the gated cost of several obstacles sees
    a point the ellipse bound alone would skip (2.9 m sideways, 20 m behind)."""
    from mmdopt.collision import collision_cost, ellipse_values

    K = 4
    c = jnp.asarray(np.broadcast_to(np.array([0.0, 0.0]), (1, 1, 1, K, 2)))
    ab = np.full((1, K), 30.0)

    def f(ds, dd, lane, a_behind=ab):
        s, d = jnp.full((1, K), ds), jnp.full((1, K), dd)
        w_h = 3.0 if lane else 0.0
        out = ellipse_values(s, d, c, 5.0, 3.0, a_behind, None, headway_lane=w_h)
        return float(out[0, 0, 0, 0, 0])

    assert f(-10.0, 2.0, False) == pytest.approx(1.0 - 100.0 / 900.0 - 4.0 / 9.0)
    assert f(-10.0, 2.0, True) == pytest.approx(1.0 - 100.0 / 900.0)
    assert f(-10.0, 0.0, True) == pytest.approx(f(-10.0, 0.0, False))
    assert f(-10.0, 3.2, True) <= 0.0 and f(-10.0, 3.2, False) <= 0.0
    assert f(3.0, 2.0, True) == pytest.approx(f(3.0, 2.0, False))  # ahead: the ellipse
    assert f(-3.0, 2.0, True, None) == pytest.approx(f(-3.0, 2.0, False, None))
    # two obstacles (the gated path): the far one adds nothing, the near one its term
    s, d = jnp.full((1, K), -20.0), jnp.full((1, K), 2.9)
    far = jnp.asarray(np.broadcast_to(np.array([500.0, 0.0]), (1, 1, 1, K, 2)))
    both = jnp.concatenate([c, far])
    w, m = jnp.ones((2, 1)), jnp.ones((2, 1), bool)
    for lane, positive in ((False, False), (True, True)):
        got = collision_cost(
            "scenario", s, d, both, w, m, 5.0, 3.0, a_behind=ab, headway_lane=3.0 * lane
        )
        assert (float(got[0]) > 0.0) is positive


@pytest.mark.parametrize("share", [0.0, 0.03, 0.1, 0.2, 0.4, 0.9])
def test_mmd_cost_on_the_active_points_equals_the_pairwise_formula(share):
    """The compacted evaluation (only points where some sample is entered, in pages of P/16:
    none, one, several or all pages) gives the pairwise kernel formula's value."""
    from mmdopt.kernels import mmd2_to_dirac

    rng = np.random.default_rng(int(share * 100))
    B, O, J, C, K = 8, 2, 5, 3, 64  # P = 1024 points: pages of 64
    f = rng.uniform(-1.0, 1.0, size=(B, O, J, C, K))
    live = rng.random((B, O, 1, 1, K)) < share
    f = jnp.asarray(np.where(live, f, -0.3))
    w = jnp.asarray(rng.dirichlet(np.ones(J), size=O))
    got = collision.mmd_cost(f, w, 0.5, 1.0, collision.taylor_terms(2.0))
    fb = jnp.maximum(jnp.max(f, axis=3), 0.0)
    a = jnp.moveaxis(fb, 2, -1)
    ref = jnp.sum(mmd2_to_dirac(a, jnp.broadcast_to(w[None, :, None], a.shape), 0.5), axis=(1, 2))
    np.testing.assert_allclose(got, ref, rtol=1e-7, atol=1e-14)
    assert (share == 0.0) == bool(np.all(np.asarray(got) == 0.0))


def test_a_turning_ego_sweeps_wider_and_per_sample_widths_keep_the_obstacle_sum():
    """The yaw-aware footprint: a per-sample, per-step lateral semi-axis (B, K) reaches a car
    in the next lane that a straight ego clears; the gated multi-obstacle sum, the reach bound
    and the rear exemption take the per-sample widths."""
    from mmdopt.collision import _max_f_bound, collision_cost, ellipse_values, taylor_terms

    K = 20
    s = jnp.asarray(np.stack([np.linspace(0.0, 1.0, K)] * 2))  # a crawl, (B = 2, K)
    d = jnp.zeros_like(s)
    b = np.full((2, K), 2.4)
    b[1] += 2.67 * np.sin(np.radians(20.0))  # the second sample turns by 20°: +0.91 m
    beside = np.broadcast_to(np.array([0.5, -2.7]), (1, 1, K, 2))  # next lane, 2.7 m across
    far = beside + np.array([300.0, 0.0])
    c = jnp.asarray(np.stack([beside, far]))  # (O = 2, J = 1, C = 1, K, 2)
    w, m = jnp.ones((2, 1)), jnp.ones((2, 1), bool)
    kw = dict(bandwidth=0.5, f_scale=1.0, n_terms=taylor_terms(2.0, 1e-12))
    for mode in ("mmd", "scenario", "saa"):
        total = np.asarray(collision_cost(mode, s, d, c, w, m, 3.0, jnp.asarray(b), **kw))
        assert total[0] == 0.0 and total[1] > 0.0, mode  # only the turning sample collides
        one = collision_cost(mode, s, d, c[:1], w[:1], m[:1], 3.0, jnp.asarray(b), **kw)
        np.testing.assert_allclose(total, one, rtol=1e-12)
        # per-sample widths equal scoring each sample with its own (K,) width
        for i in range(2):
            alone = collision_cost(mode, s[i : i + 1], d[i : i + 1], c, w, m, 3.0, b[i], **kw)
            np.testing.assert_allclose(total[i], alone[0], rtol=1e-12)
    box = (jnp.min(s, 0), jnp.max(s, 0), jnp.min(d, 0), jnp.max(d, 0))
    f = ellipse_values(s, d, c[:1], 3.0, jnp.asarray(b), None, 2.0)
    assert float(_max_f_bound(box, c[0], 3.0, b.max(0))) >= float(jnp.max(f)) - 1e-12


def test_yaw_widening_is_validated_off_by_default_and_follows_the_heading():
    """``MMDOptConfig.yaw_extent``: off by default (the static flag unset), validated, and the
    widening is ``e·|sin Δθ|`` of the heading relative to the path — nothing when driving
    straight, a little in a lane change at speed, much when turning at a crawl."""
    from mmdopt import algorithm as alg

    assert not mmdopt.MMDOptConfig().safety.footprint.yaw_aware
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="yaw_extent"):
            mmdopt.MMDOptConfig().replace(yaw_extent=bad)
    cfg = mmdopt.MMDOptConfig().replace(yaw_extent=2.5)
    assert cfg.safety.footprint.yaw_aware and cfg.replace(yaw_extent=3.0).safety.footprint.yaw_aware
    vs = jnp.asarray([[10.0, 10.0, 1.0, 0.0]])
    vd = jnp.asarray([[0.0, 10.0 * np.tan(np.radians(8.0)), np.tan(np.radians(20.0)), 0.0]])
    wide = np.asarray(alg.yaw_widening(cfg, vs, vd))[0]
    assert wide[0] == 0.0 and wide[3] == 0.0  # straight; at rest
    np.testing.assert_allclose(wide[1], 2.5 * np.sin(np.radians(8.0)), rtol=1e-3)
    np.testing.assert_allclose(wide[2], 2.5 * np.sin(np.radians(20.0)), rtol=2e-3)
    assert np.all(wide <= 2.5)
    with pytest.raises(ValueError, match="vs and vd"):
        alg.yaw_widening(cfg, vs, vd[:, :2])


def test_a_follower_that_runs_through_the_ego_stays_exempt_but_a_cut_in_does_not():
    """Rear exemption over time: a predicted follower that closes in and runs through the ego
    (in line throughout: a rear-end collision the follower causes) costs nothing at any step;
    a car that passes beside and cuts in ahead is a leader again; width 0 is the plain ellipse."""
    K = 6
    s = jnp.zeros((1, K))  # the ego stands at s = 0, d = 0
    d = jnp.zeros((1, K))
    s_pt = jnp.array([-6.0, -3.0, 0.0, 2.0, 4.0, 6.0])
    through = jnp.stack([s_pt, jnp.zeros(K)], -1)  # in line all along
    cut_in = jnp.stack([s_pt, jnp.array([3.5, 3.5, 3.5, 1.0, 0.0, 0.0])], -1)  # beside, then in
    centres = jnp.stack([through, cut_in])[None, :, None]  # (O=1, J=2, C=1, K, 2)
    a, b, w = 5.0, 2.4, 2.0
    ev = collision.ellipse_values
    plain = np.asarray(ev(s, d, centres, a, b))[0, 0, :, 0]  # (J, K)
    f = np.asarray(ev(s, d, centres, a, b, rear_exempt_width=w))[0, 0, :, 0]
    assert plain[0, 3] > 0  # the follower 2 m ahead of the ego: inside the plain ellipse
    np.testing.assert_allclose(f[0], (0.0 - w) / b)  # exempt at every step, also once through
    np.testing.assert_array_equal(f[1, 3:], plain[1, 3:])  # the cut-in ahead costs as before
    assert f[1, 3] > 0
    f0 = np.asarray(ev(s, d, centres, a, b, rear_exempt_width=0.0))[0, 0, :, 0]
    np.testing.assert_array_equal(f0, plain)


def test_a_car_at_rest_keeps_a_heading_instead_of_taking_one_from_noise():
    """The direction of millimetre steps is noise: a car that stops keeps the heading it drove
    with, one at rest over the whole horizon is aligned with the path, and its footprint
    circles do not turn across the next lane."""
    from mmdopt.collision import MIN_HEADING_STEP, headings

    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 5.0, 51)
    x = np.minimum(t, 2.0) * 3.0  # drives along +x at 3 m/s, stops at t = 2 s
    drive = np.stack([x, 0.5 * x], -1) + 1e-3 * rng.standard_normal((51, 2))
    h = np.asarray(headings(drive))
    np.testing.assert_allclose(h, np.arctan2(0.5, 1.0), atol=0.01)
    rest = np.array([10.0, 4.0]) + 1e-3 * rng.standard_normal((51, 2))
    np.testing.assert_array_equal(np.asarray(headings(rest)), 0.0)
    centres = np.asarray(mmdopt.circle_centres(rest[None], mmdopt.OBSTACLE_FOOTPRINT))
    assert np.abs(centres[..., 1] - 4.0).max() < 0.01  # all three circles on the car's line
    assert MIN_HEADING_STEP <= 0.1  # a car at 1 m/s on a 0.1 s grid still has a heading


def test_a_samples_headings_do_not_depend_on_the_other_samples_of_the_batch():
    """Headings are computed for a whole batch of samples at once (a fast path when every
    sample moves at every step): a moving sample's headings are the same bit for bit alone,
    in a batch of moving samples and beside a sample that stops, and equal the direction of
    its forward differences with the last one repeated."""
    from mmdopt.collision import headings

    rng = np.random.default_rng(4)
    t = np.linspace(0.0, 5.0, 41)[:, None]
    moving = np.concatenate([5 * t + rng.normal(0, 0.2, (41, 1)), 0.3 * t**2], -1)
    other = np.concatenate([4 * t, 0.1 * t], -1)
    stops = np.concatenate([np.minimum(t, 1.0) * 4, 0 * t], -1)  # at rest after 1 s
    with jax.enable_x64(True):
        alone = np.asarray(headings(moving[None]))[0]
        in_moving = np.asarray(headings(np.stack([moving, other])))[0]
        beside_stop = np.asarray(headings(np.stack([moving, stops])))
    step = np.diff(moving, axis=0)
    want = np.arctan2(step[:, 1], step[:, 0])
    np.testing.assert_allclose(alone, np.append(want, want[-1]), rtol=0, atol=1e-14)
    assert np.array_equal(alone, in_moving) and np.array_equal(alone, beside_stop[0])
    np.testing.assert_allclose(beside_stop[1, 11:], 0.0, atol=1e-14)  # keeps its heading
