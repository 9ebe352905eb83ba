"""Counting the planning futures a plan meets (``mmdopt.counting``): the fused float32 count, the
index that bounds every other plan from one exact pass, and the searches built on them."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import frenet
from mmdopt.collision import headings
from mmdopt.config import MMDOptConfig
from mmdopt.counting import (
    INDEX_BUCKET,
    FutureIndex,
    Futures,
    _carried_units,
    samples_met,
    smallest,
    to_planes,
)
from mmdopt.risk import coverage_data, coverage_margins
from mmdopt.schedule import obstacle_centres

CFG = MMDOptConfig()
A, B = float(CFG.safety.footprint.a), float(CFG.safety.footprint.b)


def _traffic(n: int, K: int = 30, seed: int = 0, stop: bool = True) -> np.ndarray:
    """(2, n, K, 2) futures: a car ahead at 5 ± 2 m/s and an oncoming one in the next lane;
    some of the first stop half-way (their headings are carried) and some never move."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 5.0, K)
    v = rng.normal(5.0, 2.0, (n, 1))
    lane = rng.normal(0, 1.5, (n, 1)) + 0 * t
    ahead = np.stack([20 + rng.normal(0, 6, (n, 1)) + v * t, lane], -1)
    oncoming = np.stack(
        [60 - 4 * t + rng.normal(0, 3, (n, 1)), rng.normal(3.5, 1, (n, 1)) + 0 * t], -1
    )
    if stop:
        ahead[: n // 10, K // 2 :] = ahead[: n // 10, K // 2 : K // 2 + 1]  # stop half-way
        ahead[n // 10 : n // 5] = ahead[n // 10 : n // 5, :1]  # never move
    return np.stack([ahead, oncoming])


def _plans(K: int = 30, P: int = 3) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(0.0, 5.0, K)
    s = np.stack([(5.0 + p) * t for p in range(P)])
    return s, np.stack([0.6 * p + 0 * t for p in range(P)])


def _reference(obs, heading, s, d) -> np.ndarray:
    # the float64 count from the stored circle centres (collision_free_count's definition)
    with jax.enable_x64(True):
        return samples_met(CFG, obs, heading, s, d, obstacle_centres(obs, heading))


@pytest.mark.parametrize("given_heading", [False, True])
def test_the_fused_count_equals_the_float64_count_from_the_circle_centres(given_heading):
    """Every future a plan meets, with headings given and from each future's motion (stopped
    and never-moving futures included): the same (P, O, n) answer as the float64 count from the
    circles' centres."""
    obs = _traffic(600)
    heading = np.random.default_rng(3).normal(0, 0.2, obs.shape[:-1]) if given_heading else None
    s, d = _plans()
    want = _reference(obs, heading, s, d)
    got = samples_met(CFG, obs, heading, s, d)
    assert got.shape == want.shape == (3, 2, 600) and got.dtype == bool
    assert 0 < want.sum() < want.size
    np.testing.assert_array_equal(got, want)


def test_headings_without_trigonometry_equal_the_carried_headings():
    """The unit vectors the count forms for futures whose steps partly stop equal cos/sin of
    ``collision.headings`` (the last longer step carried, the first before it, the path's
    direction for a future that never moves)."""
    rng = np.random.default_rng(3)
    xy = np.cumsum(rng.normal(0, 0.3, (300, 40, 2)) * (rng.random((300, 40, 1)) < 0.7), axis=1)
    xy[:5] = 0.0
    with jax.enable_x64(True):
        h = np.asarray(headings(xy))
    u = _carried_units(xy.transpose(2, 1, 0)[None])  # the planes (1, 2, K, J)
    assert u.dtype == np.float32 and u.ctypes.data % 64 == 0
    ux, uy = u[0, 0].T, u[0, 1].T
    np.testing.assert_allclose(ux, np.cos(h), atol=1e-5)
    np.testing.assert_allclose(uy, np.sin(h), atol=1e-5)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), shift=st.floats(-3.0, 3.0), lat=st.floats(-1.5, 1.5))
def test_the_index_bounds_never_exceed_the_true_distance(seed, shift, lat):
    """For any plan, the index's lower bound of its ellipse-norm distance to every future (from
    one pass against another plan) is at most the true least distance."""
    obs = _traffic(300, seed=seed)
    s, d = _plans(P=1)
    fut = Futures.of(obs)
    index = FutureIndex(fut, s[0], d[0], A, B)
    s2, d2 = s + shift * np.linspace(0, 1, s.shape[1]), d + lat
    true = np.sqrt(fut.q(s2, d2, A, B)[0, ..., 0].astype(np.float64))
    assert np.all(index.lower(s2, d2)[0] <= true + 1e-4)


def test_the_index_counts_and_finds_the_nearest_exactly_from_a_few_futures():
    """With more futures than the index counts all at once: a plan near the reference one meets
    exactly the futures the full count says, and the M futures nearest to it are the M least of
    the full count (when the bounds certify them; the search says so otherwise)."""
    n = 4 * INDEX_BUCKET
    obs = _traffic(n, seed=7)
    s, d = _plans(P=1)
    fut = Futures.of(obs)
    index = FutureIndex(fut, s[0], d[0], A, B)
    assert not index.small
    for shift in (0.0, 0.3, 2.0, 30.0):  # the last: far from the reference (counts all)
        s2 = s + shift * np.linspace(0, 1, s.shape[1])
        np.testing.assert_array_equal(index.met(s2, d), fut.met(s2, d, A, B))
    q = fut.q(s, d, A, B)[0, ..., 0]
    near = index.nearest(s[0], d[0], 100)
    assert near is not None  # the reference plan itself: its own bounds are exact
    np.testing.assert_array_equal(near, smallest(q, 100))
    answered = 0
    for shift in (0.2, 1.0, 25.0):  # another plan: exact where it answers (it may decline)
        near2 = index.nearest(s[0] + shift, d[0], 100)
        if near2 is not None:
            answered += 1
            q2 = fut.q(s + shift, d, A, B)[0, ..., 0]
            np.testing.assert_array_equal(near2, smallest(q2, 100))
    assert answered >= 1


def test_a_subset_counts_as_the_whole_set_at_its_futures():
    """Any subset of futures, stopped and never-moving ones among them, in any order and with
    repeats (how the index pads its candidates), gets the whole set's ``q`` at each of its
    futures, bit for bit: a future's carried heading is its own, whichever set it is counted
    in."""
    obs = _traffic(900, seed=5)
    s, d = _plans()
    fut = Futures.of(obs)
    whole = fut.q(s, d, A, B, windows=3)
    assert fut.mixed[0].any() and not fut.mixed[1].any()
    rng = np.random.default_rng(0)
    for J in (7, 300, 1500):
        idx = rng.integers(0, 900, (2, J))
        idx[0, : J // 2] = rng.integers(0, 90, J // 2)  # the stopped ones of the first car
        got = fut.subset(idx).q(s, d, A, B, windows=3)
        want = np.stack([whole[:, o, idx[o]] for o in range(2)], 1)
        np.testing.assert_array_equal(got, want)


def test_smallest_is_a_stable_partial_sort():
    rng = np.random.default_rng(0)
    for _ in range(100):
        v = rng.integers(0, 15, (3, 40)).astype(float)
        M = int(rng.integers(1, 45))
        want = np.sort(np.argsort(v, kind="stable", axis=1)[:, : min(M, 40)], axis=1)
        np.testing.assert_array_equal(smallest(v, M), want)


def test_planes_hold_the_frenet_positions_of_a_straight_and_a_curved_path():
    """The conversion block by block into the count's float32 planes gives the path's own
    Frenet coordinates, relative to the ego's arc length."""
    obs = _traffic(700, seed=2, stop=False)
    bend = np.stack([np.linspace(-50, 250, 40), 10 * np.sin(np.linspace(0, 3, 40))], -1)
    straight = frenet.ReferencePath.straight(500.0, start=(-10.0, 2.0), heading=0.3)
    for path in (straight, frenet.ReferencePath.from_waypoints(bend)):
        planes = to_planes(obs, lambda b, path=path: path.to_frenet_points(b, 7.0))
        s, d = path.to_frenet(obs[..., 0], obs[..., 1])
        got = planes.transpose(0, 3, 2, 1)
        np.testing.assert_allclose(got[..., 0], s - 7.0, atol=2e-4 * (1 + np.abs(s).max()))
        np.testing.assert_allclose(got[..., 1], d, atol=2e-4 * (1 + np.abs(d).max()))
        assert planes.dtype == np.float32 and planes.ctypes.data % 64 == 0


@pytest.mark.parametrize("knn", [0, 40])
def test_margins_from_a_pool_of_rows_equal_those_of_the_rows_and_the_points(knn):
    """Coverage margins estimated from R of the n futures are the margins of the samples those
    rows and the points themselves make up (nearest-point clusters, or k-NN among the rows)."""
    rng = np.random.default_rng(0)
    n, K = 3000, 20
    X = np.stack([np.cumsum(rng.uniform(0.5, 2, (2, n, K)), -1), rng.normal(0, 1, (2, n, K))], -1)
    rows = np.linspace(0, n - 1, 700).round().astype(np.int64)
    idx = np.concatenate([rng.choice(n, (2, 15), replace=False),
                          np.repeat(rng.choice(n, (2, 1)), 2, 1)], 1)  # fmt: skip
    sub = np.concatenate([X[:, rows], np.take_along_axis(X, idx[:, :, None, None], 1)], 1)
    sidx = np.tile(len(rows) + np.arange(idx.shape[1]), (2, 1))
    pool = np.tile(np.arange(len(rows)), (2, 1)) if knn else None
    want = coverage_margins(sub, sidx, 0.01, lateral_scale=10.0, knn=knn, pool=pool)
    got = coverage_margins(X, idx, 0.01, lateral_scale=10.0, knn=knn,
                           data=coverage_data(X, 10.0, rows))  # fmt: skip
    np.testing.assert_allclose(got, want, atol=1e-9)
    with pytest.raises(ValueError, match="rows"):
        coverage_data(X, 10.0, np.array([0, n]))


def test_the_affine_conversion_matches_the_pointwise_one_on_a_straight_road():
    """A straight road's Frenet map fused into the copy to planes gives the coordinates of
    :meth:`frenet.ReferencePath.to_frenet_points`, rounded once to float32."""
    rng = np.random.default_rng(4)
    path = frenet.ReferencePath.from_waypoints(np.array([[100.0, 50.0], [400.0, 450.0]]))
    xy = rng.normal(0.0, 30.0, (2, 700, 6, 2)) + np.array([250.0, 250.0])
    want = to_planes(xy, lambda b: path.to_frenet_points(b, 37.5))
    got = to_planes(xy, affine=path.frenet_affine(37.5))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-4)
    assert (
        frenet.ReferencePath.from_waypoints(
            np.array([[0.0, 0.0], [50.0, 10.0], [100.0, 40.0]])
        ).frenet_affine()
        is None
    )
    with pytest.raises(ValueError, match="affine"):
        to_planes(xy, affine=(np.eye(3), np.zeros(2)))
