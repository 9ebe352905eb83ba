"""Obstacle padding with phantoms (:mod:`mmdopt.padding`): the exact-count rule of the receding
loop, the bucket rule of the recorded-traffic benchmark, and phantoms that no plan meets."""

import numpy as np
import pytest

import frenet
import mmdopt
from mmdopt.padding import pad_obstacles, padded_count

T = frenet.TimeGrid(5.0, 51).t
ROAD = mmdopt.Road()  # straight along +x: Frenet (s, d) = Cartesian (x, y)
EGO = frenet.EgoState(s=600.0, d=1.5, vs=12.0)


def _obstacles(O: int, n: int = 4) -> np.ndarray:
    rng = np.random.default_rng(O)
    return EGO.s + 20.0 + rng.normal(size=(O, n, len(T), 2))


def test_exact_count_pads_with_the_documented_phantoms():
    obs = _obstacles(2)
    out = pad_obstacles(obs, 5, EGO, ROAD, T)
    assert out.shape == (5, 4, len(T), 2)
    np.testing.assert_array_equal(out[:2], obs)  # the real obstacles first, unchanged
    # phantom sample j: 500 m + j metres behind the ego, at its offset, driving at its speed
    s, d = ROAD.path.to_frenet(out[2:, ..., 0].ravel(), out[2:, ..., 1].ravel())
    want_s = EGO.s - 500.0 - np.arange(4)[:, None] + EGO.vs * T[None, :]
    np.testing.assert_allclose(
        np.reshape(s, (3, 4, len(T))), np.broadcast_to(want_s, (3, 4, len(T))), atol=1e-9
    )
    np.testing.assert_allclose(d, EGO.d, atol=1e-9)
    # extra obstacles are dropped; None: at least one
    np.testing.assert_array_equal(pad_obstacles(obs, 1, EGO, ROAD, T), obs[:1])
    assert pad_obstacles(obs, None, EGO, ROAD, T).shape[0] == 2
    assert pad_obstacles(np.zeros((0, 4, len(T), 2)), None, EGO, ROAD, T).shape[0] == 1
    # a car reversing: its phantoms stand (the speed is clipped at 0)
    back = frenet.EgoState(s=600.0, d=0.0, vs=-2.0)
    ph = pad_obstacles(np.zeros((0, 4, len(T), 2)), 1, back, ROAD, T)
    np.testing.assert_allclose(ph[0, :, :, 0], ph[0, :, :1, 0].repeat(len(T), 1))


def test_exact_count_is_the_receding_loops_rule():
    from mmdopt.receding import pad_obstacles as receding_pad

    for O, num in ((0, 3), (2, 6), (4, 2), (3, None)):
        obs = _obstacles(O)
        np.testing.assert_array_equal(
            pad_obstacles(obs, num, EGO, ROAD, T), receding_pad(obs, num, EGO, ROAD, T)
        )


@pytest.mark.parametrize("num, bucket", [(15, 15), (15, 5), (6, 4), (3, 1)])
def test_bucket_pads_to_the_next_multiple_capped(num, bucket):
    for O in range(0, 2 * num + 2):
        want = min(-(-O // bucket) * bucket, max(num, O))
        assert padded_count(O, num, bucket) == want
        assert want >= O
        obs = _obstacles(O)
        out = pad_obstacles(obs, num, EGO, ROAD, T, bucket=bucket)
        assert out.shape == (want, 4, len(T), 2)
        np.testing.assert_array_equal(out[:O], obs)  # nothing dropped
        if want > O:  # the same phantoms as the exact-count rule
            np.testing.assert_array_equal(out[O:], pad_obstacles(obs, want, EGO, ROAD, T)[O:])
    assert padded_count(7, 15) == 15  # the bucket defaults to num


def test_bucket_needs_a_count():
    with pytest.raises(ValueError, match="bucket must be"):
        padded_count(3, 5, 0)
    with pytest.raises(ValueError, match="bucket needs num"):
        pad_obstacles(_obstacles(1), None, EGO, ROAD, T, bucket=5)
    with pytest.raises(ValueError, match="obstacles must have shape"):
        pad_obstacles(np.zeros((1, 4, 3, 2)), 2, EGO, ROAD, T)


def test_no_plan_from_the_ego_meets_a_phantom():
    """The collision term against phantoms is zero: every trajectory that starts at the ego
    (braking to a stop, at constant speed, at full acceleration, changing lanes either way)
    clears every phantom sample."""
    phantoms = pad_obstacles(np.zeros((0, 10, len(T), 2)), 3, EGO, ROAD, T)
    plans = []
    for accel in (-6.0, 0.0, 6.0):
        tt = np.minimum(T, EGO.vs / -accel if accel < 0 else np.inf)  # braking: stops, stands
        s = EGO.s + EGO.vs * tt + 0.5 * accel * tt**2
        for d_end in (-4.0, 0.0, 4.0):
            d = EGO.d + (d_end - EGO.d) * np.clip(T / 3.0, 0.0, 1.0)
            x, y = ROAD.path.to_cartesian(s, d)
            plans.append(np.stack([x, y], -1))
    counts = mmdopt.collision_free_count(np.stack(plans), phantoms, a=4.5, b=3.5)
    np.testing.assert_array_equal(np.asarray(counts.joint), 10)
    assert not np.asarray(counts.colliding).any()
