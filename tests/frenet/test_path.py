"""Reference paths: Cartesian <-> Frenet round trips, geometry, bad inputs."""

import numpy as np
import pytest

from frenet import FLOAT32_TOL, ReferencePath, wrap_angle


def _circle(R=50.0, arc=1.5 * np.pi):
    th = np.linspace(0, arc, 40)
    return ReferencePath.from_waypoints(np.c_[R * np.cos(th), R * np.sin(th)])


def _s_curve():
    xs = np.linspace(0, 200, 30)
    return ReferencePath.from_waypoints(np.c_[xs, 15 * np.sin(xs / 30)])


PATHS = {
    "straight": (lambda: ReferencePath.straight(300.0, start=(5.0, -2.0), heading=0.4), 10.0),
    "circle": (_circle, 8.0),
    "s_curve": (_s_curve, 5.0),
}


@pytest.mark.parametrize("start", ["tree", "grid"])
@pytest.mark.parametrize("name", PATHS)
def test_round_trip_frenet_cartesian_frenet_within_micrometre(name, start):
    make, dmax = PATHS[name]
    path = make()
    if start == "grid":  # every tile the batch touches computed now (else once paid for)
        path._start_grid().payback_points = 0
    rng = np.random.default_rng(0)
    s = rng.uniform(
        -10.0, path.length + 10.0, (200, 100)
    )  # batches of trajectories, past the ends too
    d = rng.uniform(-dmax, dmax, (200, 100))
    h = rng.uniform(-np.pi, np.pi, (200, 100))
    x, y, hc = path.to_cartesian(s, d, h)
    s2, d2, h2 = path.to_frenet(x, y, hc)
    assert s2.shape == s.shape
    assert np.max(np.abs(s2 - s)) <= 1e-6 and np.max(np.abs(d2 - d)) <= 1e-6
    assert np.max(np.abs(wrap_angle(h2 - h))) <= 1e-9
    x3, y3 = path.to_cartesian(s2, d2)
    assert np.max(np.hypot(x3 - x, y3 - y)) <= 1e-6


@pytest.mark.parametrize("name", ["circle", "s_curve"])
def test_a_point_projects_the_same_alone_as_in_a_large_batch(name):
    """The Newton search stops each point when its own step is below the tolerance: a point's
    coordinates do not depend on which other points it is converted with (the slow points of a
    batch, far off the path or near its ends, do not move the others)."""
    make, dmax = PATHS[name]
    path = make()
    rng = np.random.default_rng(1)
    path._start_grid().payback_points = 0  # a large batch starts from the grid, a point from
    # the k-d tree
    n = 30_000
    s = rng.uniform(-10.0, path.length + 10.0, n)
    d = rng.uniform(-3 * dmax, 3 * dmax, n)  # far off the path too: more iterations
    x, y = path.to_cartesian(s, d)
    sb, db = path.to_frenet(x, y)
    for i in rng.choice(n, 40, replace=False):
        s1, d1 = path.to_frenet(x[i : i + 1], y[i : i + 1])
        assert abs(s1[0] - sb[i]) <= 1e-9 and abs(d1[0] - db[i]) <= 1e-9


@pytest.mark.parametrize("name", ["circle", "s_curve"])
def test_the_float32_tolerance_keeps_coordinates_far_below_float32_spacing(name):
    """``to_frenet_points(..., tol=FLOAT32_TOL)`` (the planner's obstacle planes, stored in
    float32) stops Newton earlier, yet stays within 10⁻⁷ m of the full search and of the true
    coordinates: a hundredth of float32's spacing at tens of metres."""
    make, dmax = PATHS[name]
    path = make()
    path._start_grid().payback_points = 0  # the large batch starts from the grid
    rng = np.random.default_rng(2)
    s = rng.uniform(0.0, path.length, 50_000)
    d = rng.uniform(-dmax, dmax, 50_000)
    x, y = path.to_cartesian(s, d)
    xy = np.stack([x, y], -1)
    s_full, d_full = path.to_frenet_points(xy, 3.0)
    s_f32, d_f32 = path.to_frenet_points(xy, 3.0, tol=FLOAT32_TOL)
    assert np.max(np.abs(s_f32 - s_full)) <= 1e-7 and np.max(np.abs(d_f32 - d_full)) <= 1e-7
    assert np.max(np.abs(s_f32 + 3.0 - s)) <= 1e-7 and np.max(np.abs(d_f32 - d)) <= 1e-7
    for bad in (0.0, -1e-8, 1.0, float("nan"), True):
        with pytest.raises(ValueError, match="tol"):
            path.to_frenet_points(xy[:3], tol=bad)


def _hairpin():
    """Out 60 m, a half turn of radius 6 m, back 60 m: the two legs 12 m apart, so the
    nearest point jumps from leg to leg on the line between them."""
    th = np.linspace(-np.pi / 2, np.pi / 2, 15)
    out = np.c_[np.linspace(-60.0, 0.0, 13)[:-1], np.full(12, -6.0)]
    turn = np.c_[6 * np.cos(th), 6 * np.sin(th)]
    back = np.c_[np.linspace(0.0, -60.0, 13)[1:], np.full(12, 6.0)]
    return ReferencePath.from_waypoints(np.r_[out, turn, back])


@pytest.mark.parametrize("make", [_hairpin, _circle], ids=["hairpin", "circle"])
def test_a_large_batch_finds_the_nearest_path_point_where_it_jumps(make):
    """Between the legs of a hairpin and around a circle's centre the nearest point jumps (or
    is not unique); a large batch (started from the path's grid) must still return the
    *nearest* path point: its |d| equals the distance to a dense sampling of the path, and a
    point gets the same coordinates alone (started from the k-d tree)."""
    path = make()
    path._start_grid().payback_points = 0
    rng = np.random.default_rng(7)
    lo = path._tree.data.min(axis=0) - 8.0
    hi = path._tree.data.max(axis=0) + 8.0
    xy = rng.uniform(lo, hi, (40_000, 2))
    s, d = path.to_frenet(xy[:, 0], xy[:, 1])
    ss = np.linspace(0.0, path.length, 40_001)
    px, py = path.point(ss)
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(np.c_[px, py]).query(xy)
    inside = (s >= 0.0) & (s <= path.length)  # past the ends the path runs on straight
    spacing = path.length / 40_000
    # near a centre of curvature the distance is flat in s: a few micrometres of slack
    assert np.all(np.abs(d[inside]) <= dist[inside] + 1e-5)
    assert np.all(np.abs(d[inside]) >= dist[inside] - spacing)  # samples are spacing apart
    for i in rng.choice(len(xy), 60, replace=False):
        s1, d1 = path.to_frenet(xy[i : i + 1, 0], xy[i : i + 1, 1])
        if abs(abs(d1[0]) - abs(d[i])) <= 1e-9 and abs(s1[0] - s[i]) > 1e-6:
            continue  # equidistant from two path points: either is the nearest
        assert abs(s1[0] - s[i]) <= 1e-9 and abs(d1[0] - d[i]) <= 1e-9


def test_a_path_computes_its_start_grid_where_the_batches_pay_for_it():
    """A path converted once keeps the k-d tree (a grid node costs about what the tree start of
    two points saves); where batches come again and again the grid's tiles are computed, only
    there, and the coordinates do not depend on which start a batch had."""
    path = _s_curve()
    rng = np.random.default_rng(3)
    s = rng.uniform(20.0, 100.0, 5000)  # a part of the path's area, ~1000 points per tile
    d = rng.uniform(-5.0, 5.0, 5000)
    x, y = path.to_cartesian(s, d)
    s1, d1 = path.to_frenet(x, y)
    grid = path._start_grid()
    assert grid is not None and not np.any(grid.slot >= 0)  # nothing paid for yet
    for _ in range(20):
        path.to_frenet(x, y)
    built = int(np.sum(grid.slot >= 0))
    assert 0 < built < grid.slot.size // 4  # the visited tiles only
    s2, d2 = path.to_frenet(x, y)
    assert np.max(np.abs(s2 - s1)) <= 1e-9 and np.max(np.abs(d2 - d1)) <= 1e-9
    assert np.max(np.abs(s2 - s)) <= 1e-6 and np.max(np.abs(d2 - d)) <= 1e-6
    small = path.to_frenet(x[:10], y[:10])  # a small batch still starts from the tree
    assert np.max(np.abs(small[0] - s1[:10])) <= 1e-9


def test_circle_geometry_arc_length_heading_curvature():
    R = 50.0
    path = _circle(R)
    assert path.length == pytest.approx(1.5 * np.pi * R, rel=2e-3)
    s = np.linspace(30, path.length - 30, 50)  # natural end conditions flatten the very ends
    np.testing.assert_allclose(path.curvature(s), 1 / R, rtol=0.01)
    x, y = path.point(s)
    np.testing.assert_allclose(
        wrap_angle(path.heading(s) - (np.arctan2(y, x) + np.pi / 2)), 0, atol=5e-3
    )
    # arc-length parameterised: the polyline length of a fine sampling equals s
    ss = np.linspace(0, path.length, 20001)
    px, py = path.point(ss)
    assert np.hypot(np.diff(px), np.diff(py)).sum() == pytest.approx(path.length, abs=1e-3)


def test_point_left_of_path_has_positive_offset():
    path = ReferencePath.straight(100.0)
    s, d = path.to_frenet(np.array([10.0]), np.array([2.0]))
    assert s[0] == pytest.approx(10.0) and d[0] == pytest.approx(2.0)


def test_trajectory_to_cartesian_heading_follows_velocity():
    path = ReferencePath.straight(100.0, heading=0.3)
    x, y, heading, speed = path.trajectory_to_cartesian(
        np.array([1.0]), np.array([0.0]), np.array([3.0]), np.array([4.0])
    )
    assert speed[0] == pytest.approx(5.0)
    assert heading[0] == pytest.approx(0.3 + np.arctan2(4, 3))


def test_trajectory_to_cartesian_holds_the_heading_at_rest():
    """A plan that stops: below ``stop_speed`` the car keeps the heading it last moved with (a
    solver's −10⁻³ m/s must not turn it round, a stopped start points along the path)."""
    path = ReferencePath.straight(100.0, heading=0.3)
    s = np.array([[0.0, 1.0, 1.5, 1.5, 1.5], [0.0, 0.0, 0.0, 0.5, 1.0]])
    d = np.zeros_like(s)
    vs = np.array([[2.0, 1.0, 0.01, -1e-3, 0.0], [0.0, 1e-3, 0.0, 1.0, 1.0]])
    vd = np.array([[0.2, 0.1, 0.02, 0.0, 0.0], [0.0, 1e-3, 0.0, 0.1, 0.0]])
    _, _, h, v = path.trajectory_to_cartesian(s, d, vs, vd)
    rel = h - 0.3
    assert rel[0, :2] == pytest.approx(np.arctan2(vd[0, :2], vs[0, :2]))
    assert rel[0, 2:] == pytest.approx([np.arctan2(0.1, 1.0)] * 3)  # held from step 1
    assert rel[1] == pytest.approx([0.0, 0.0, 0.0, np.arctan2(0.1, 1.0), 0.0])
    assert v[0, 3] == pytest.approx(1e-3)  # the speed itself is not changed
    _, _, raw, _ = path.trajectory_to_cartesian(s, d, vs, vd, stop_speed=0.0)
    assert abs(raw[0, 3] - 0.3) == pytest.approx(np.pi)  # the raw formula turns it round
    _, _, h0, _ = path.trajectory_to_cartesian(1.0, 0.0, 0.0, 0.01)  # a scalar at rest
    assert float(h0) == pytest.approx(0.3)
    with pytest.raises(ValueError, match="stop_speed"):
        path.trajectory_to_cartesian(s, d, vs, vd, stop_speed=-1.0)


def test_ego_state_on_straight_path():
    path = ReferencePath.straight(100.0)
    st = path.ego_state(3.0, 0.5, speed=10.0, heading=0.0)
    assert (st.s, st.d, st.vs, st.vd) == pytest.approx((3.0, 0.5, 10.0, 0.0))


@pytest.mark.parametrize(
    "xy, msg",
    [
        (np.array([[0.0, 0.0], [np.nan, 1.0], [2.0, 2.0]]), "NaN"),
        (np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 1.0], [2.0, 0.0]]), "duplicate"),
        (np.array([[1.0, 1.0], [1.0, 1.0]]), "zero-length"),
        (np.array([[1.0, 1.0]]), "at least 2"),
        (np.zeros((4, 3)), "shape"),
    ],
)
def test_bad_waypoints_raise(xy, msg):
    with pytest.raises(ValueError, match=msg):
        ReferencePath.from_waypoints(xy)


def test_nan_query_raises():
    with pytest.raises(ValueError, match="NaN"):
        ReferencePath.straight(10.0).to_frenet(np.array([np.nan]), np.array([0.0]))


@pytest.mark.parametrize(
    "make",
    [
        lambda: ReferencePath.straight(300.0, start=(5.0, -2.0), heading=0.4),
        lambda: ReferencePath.straight(2000.0),
        lambda: ReferencePath.from_waypoints(
            np.c_[np.linspace(3.0, 93.0, 7), np.linspace(1, -44, 7)]
        ),
    ],
)
def test_straight_path_projection_agrees_with_the_newton_search(make):
    """A straight path converts by exact projection; the general search (k-d tree, chords,
    Newton) gives the same Frenet coordinates to 1e-9 m, past the ends too."""
    import dataclasses

    path = make()
    assert path._line is not None
    general = dataclasses.replace(path, _line=None)
    rng = np.random.default_rng(3)
    s = rng.uniform(-50.0, path.length + 50.0, (40, 30))
    d = rng.uniform(-12.0, 12.0, (40, 30))
    h = rng.uniform(-np.pi, np.pi, (40, 30))
    x, y, hc = path.to_cartesian(s, d, h)
    fast, slow = path.to_frenet(x, y, hc), general.to_frenet(x, y, hc)
    assert np.max(np.abs(fast[0] - slow[0])) <= 1e-9
    assert np.max(np.abs(fast[1] - slow[1])) <= 1e-9
    assert np.max(np.abs(wrap_angle(fast[2] - slow[2]))) <= 1e-12
    assert np.max(np.abs(fast[0] - s)) <= 1e-9 and np.max(np.abs(fast[1] - d)) <= 1e-9


def test_a_path_that_bends_or_turns_back_is_not_taken_for_a_line():
    bent = ReferencePath.from_waypoints(np.c_[np.linspace(0, 100, 5), [0, 0, 1e-3, 0, 0]])
    back = ReferencePath.from_waypoints(np.array([[0.0, 0.0], [50.0, 0.0], [20.0, 0.0]]))
    assert bent._line is None and back._line is None
    with pytest.raises(ValueError, match="heading"):
        ReferencePath.straight(100.0).to_frenet(np.zeros(3), np.zeros(3), np.zeros(4))
