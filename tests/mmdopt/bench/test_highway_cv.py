"""The constant-velocity highway predictor's lateral noise and its calibration
(mmdopt.bench.highway.training: cv_lateral_errors, calibrate_cv_lateral): the rule recovers a
Gaussian's σ, keeps the rate of the event that matters on lane-keeping traffic with a few lane
changes, and the predictor's samples have the calibrated rate.

The rollout tests are skipped when highway-env is not installed (``pip install -e
".[highway]"``).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

from mmdopt.bench import highway as hw
from mmdopt.bench.highway.predictors import CV_SIGMA_LAT, ConstantVelocityPredictor
from mmdopt.bench.highway.training import (
    MARKING_DEVIATION,
    calibrate_cv_lateral,
    cv_lateral_errors,
)

needs_highway = pytest.mark.skipif(
    not hw.highway_available(),
    reason='highway-env/gymnasium not installed (pip install ".[highway]")',
)
TIMES = np.arange(1, 11) * 0.5


def _rate(sigma: float, times=TIMES, deviation: float = MARKING_DEVIATION) -> float:
    return float(np.mean(2.0 * norm.sf(deviation / (sigma * times))))


def test_calibration_recovers_the_sigma_of_gaussian_lateral_velocity_noise():
    rng = np.random.default_rng(3)
    errors = rng.normal(0.0, 0.2, (20000, 1)) * TIMES  # a lateral velocity error per car
    sigma, rate = calibrate_cv_lateral(TIMES, errors)
    assert sigma == pytest.approx(0.2, rel=0.03)
    assert _rate(sigma) == pytest.approx(rate, abs=1e-9)


def test_calibration_keeps_the_rate_of_leaving_the_lane_in_lane_keeping_traffic():
    """95 % of cars stay on their lane's centre, 5 % change lanes (4 m in 3 s from a random
    start): the calibrated Gaussian crosses the marking as often as the cars do, where a robust
    fit (the median error is 0) would say no car ever leaves its lane."""
    rng = np.random.default_rng(4)
    M = 4000
    start = rng.uniform(0.0, 5.0, M)
    change = rng.random(M) < 0.05
    side = rng.choice([-1.0, 1.0], M)
    frac = np.clip((TIMES[None, :] - start[:, None]) / 3.0, 0.0, 1.0)
    errors = np.where(change[:, None], side[:, None] * 4.0 * frac, 0.0)
    sigma, rate = calibrate_cv_lateral(TIMES, errors)
    assert rate == pytest.approx(float((np.abs(errors) > 1.0).mean()))
    assert _rate(sigma) == pytest.approx(rate, abs=1e-9)
    assert np.median(np.abs(errors)) == 0.0 and 0.05 < sigma < 0.3


@pytest.mark.parametrize(
    "times, errors, deviation, match",
    [
        (TIMES, np.ones((3, 4)), 1.0, "errors must have shape"),
        (TIMES, np.zeros((0, 10)), 1.0, "errors must have shape"),
        (TIMES, np.full((3, 10), np.nan), 1.0, "errors must be finite"),
        (-TIMES, np.ones((3, 10)), 1.0, "times must be"),
        (TIMES, np.ones((3, 10)), 0.0, "deviation must be"),
        (TIMES, np.zeros((3, 10)), 1.0, "no σ matches"),
    ],
)
def test_calibration_rejects_bad_inputs(times, errors, deviation, match):
    with pytest.raises(ValueError, match=match):
        calibrate_cv_lateral(times, errors, deviation)


@pytest.mark.parametrize("field", ["sigma_long", "sigma_lat"])
@pytest.mark.parametrize("value", [-0.1, float("nan"), float("inf"), "0.1", True])
def test_constant_velocity_noise_must_be_a_finite_speed(field, value):
    with pytest.raises(ValueError, match=field):
        ConstantVelocityPredictor(**{field: value})


@needs_highway
def test_constant_velocity_errors_of_a_real_rollout_are_mostly_zero_across_the_lane():
    times, errors = cv_lateral_errors(
        "highway-v0", [100_000], env_config={"vehicles_density": 2}, duration=8.0
    )
    np.testing.assert_allclose(times, TIMES)
    assert errors.shape[1] == 10 and 6 <= errors.shape[0] <= 24
    assert np.all(np.isfinite(errors))
    assert np.median(np.abs(errors)) < 0.05  # cars keep to their lane's centre
    with pytest.raises(ValueError, match="max_obstacles"):
        cv_lateral_errors("highway-v0", [100_000], duration=8.0, max_obstacles=0)


@needs_highway
def test_constant_velocity_samples_cross_the_marking_at_the_calibrated_rate():
    """The predictor's samples of a car at speed leave its lane (1 m sideways) as often, over
    the horizon, as the calibration says: its lateral noise is N(0, (σ·t)²)."""
    src = hw.HighwaySource(hw.HighwaySettings(duration=1.0), 0, hw.highway_config(), method="idm")
    try:
        fast = [v for v in src._targets() if v.speed >= 10.0][:2]
        assert fast
        n = 4000
        pred = ConstantVelocityPredictor()
        out = pred(src.env.road, src.ego, fast, TIMES, n, np.random.default_rng(5))
        mean = (
            np.array([v.position for v in fast])[:, None, :]
            + np.array([v.velocity for v in fast])[:, None, :] * TIMES[:, None]
        )
        lateral = out[:, 1:, :, 1] - mean[:, None, :, 1]  # sample 0 is the noise-free one
        measured = float((np.abs(lateral) > MARKING_DEVIATION).mean())
        expected = _rate(CV_SIGMA_LAT)
        assert expected == pytest.approx(0.04, abs=0.005)
        se = np.sqrt(expected * (1 - expected) / (n - 1))
        assert abs(measured - expected) < 5 * se * len(TIMES) ** 0.5
    finally:
        src.close()


# ------------------------------------------------------------ the observed velocity (tracking)
def _road_with_car(position, heading, speed, steering):
    from highway_env.road.road import Road, RoadNetwork
    from highway_env.vehicle.kinematics import Vehicle

    road = Road(RoadNetwork.straight_road_network(3), np_random=np.random.RandomState(0))
    car = Vehicle(road, np.array(position, float), heading, speed)
    car.act({"steering": steering, "acceleration": 0.0})
    road.vehicles.append(car)
    return road, car


def _drive(road, pred, frames, dt=0.1):
    for _ in range(frames):
        for v in road.vehicles:
            v.step(dt)
        pred.record(road, dt)


@needs_highway
def test_a_car_reversing_and_steering_hard_is_predicted_to_move_the_way_it_moves():
    """highway-env's cars stuck behind a wreck reverse, and their steering controller turns
    them across the road: the body's heading and speed (``Vehicle.velocity``, no slip angle)
    say the car moves away from the lane to its left, its positions say it moves into it.  The
    predictor extrapolates what it observes."""
    road, car = _road_with_car([50.0, 4.0], 0.19, -1.35, -0.9)
    pred = ConstantVelocityPredictor(sigma_long=0.0, sigma_lat=0.0)
    _drive(road, pred, 4)
    assert car.velocity[1] < -0.2  # what the simulator's velocity says
    t = np.array([0.0, 0.1, 0.2])
    out = pred(road, None, [car], t, 1, np.random.default_rng(0))
    start, said = car.position.copy(), car.position + np.outer(t[1:], car.velocity)
    truth = []
    for _ in range(2):
        car.step(0.1)
        truth.append(car.position.copy())
    truth = np.array(truth)
    np.testing.assert_allclose(out[0, 0, 0], start)
    assert truth[-1, 1] - start[1] > 0.05 and out[0, 0, 2, 1] - start[1] > 0.05  # to its left
    err = np.abs(out[0, 0, 1:] - truth).max()
    assert err < 0.03 and err < np.abs(said - truth).max() / 3


@needs_highway
def test_a_reversing_car_is_predicted_to_go_on_reversing_and_no_faster():
    road, car = _road_with_car([50.0, 4.0], 0.0, -2.0, 0.0)
    pred = ConstantVelocityPredictor()
    _drive(road, pred, 3)
    t = np.arange(6) * 0.5
    out = pred(road, None, [car], t, 200, np.random.default_rng(1))
    dx = out[0, :, :, 0] - car.position[0]
    np.testing.assert_allclose(dx[0], -2.0 * t, atol=1e-9)  # sample 0: the observed velocity
    assert np.all(dx >= -2.0 * t - 1e-9)  # the noise never reverses it faster
    assert np.any(dx[:, -1] > -2.0 * 2.5 + 0.5)  # but may slow it


@needs_highway
def test_the_jump_of_a_collision_impact_is_not_taken_for_a_velocity():
    road, car = _road_with_car([50.0, 4.0], 0.0, 20.0, 0.0)
    pred = ConstantVelocityPredictor()
    _drive(road, pred, 2)
    car.impact = np.array([0.0, 0.4])  # highway-env pushes colliding cars apart in one frame
    _drive(road, pred, 2)
    np.testing.assert_allclose(pred.observed_velocity(car), [20.0, 0.0], atol=1e-9)


@needs_highway
def test_a_car_without_recorded_frames_uses_the_simulators_velocity():
    road, car = _road_with_car([50.0, 4.0], 0.05, 20.0, 0.0)
    pred = ConstantVelocityPredictor()
    np.testing.assert_allclose(pred.observed_velocity(car), car.velocity)
    _drive(road, pred, 1)
    car.position = car.position + 1.0  # moved since its last recorded frame
    np.testing.assert_allclose(pred.observed_velocity(car), car.velocity)
    with pytest.raises(ValueError, match="dt must be"):
        pred.record(road, 0.0)


def test_tracked_velocity_is_the_median_of_the_last_frame_velocities():
    from mmdopt.bench.highway.predictors import TRACK_FRAMES, tracked_velocity

    ts = np.arange(6) * 0.1
    ps = np.stack([20.0 * ts, np.zeros(6)], axis=-1)
    ps[3:, 1] += 0.5  # a one-frame jump
    np.testing.assert_allclose(tracked_velocity(ts, ps), [20.0, 0.0], atol=1e-9)
    assert TRACK_FRAMES == 3
    np.testing.assert_allclose(tracked_velocity(ts[:2], ps[:2]), [20.0, 0.0])
    with pytest.raises(ValueError, match="ts must be"):
        tracked_velocity(ts[:1], ps[:1])
    with pytest.raises(ValueError, match="ts must increase"):
        tracked_velocity(ts[::-1], ps)


@needs_highway
def test_a_car_changing_lanes_is_predicted_to_stop_at_the_next_lane_centre():
    """highway traffic changes one lane at a time: a car leaving lane 0 at 3 m/s sideways ends
    in lane 1 (centre 4 m), not across lane 2 and off the road, where it would leave lane 1
    looking free to a car entering it from the other side."""
    road, car = _road_with_car([50.0, 1.0], 0.15, 20.0, 0.0)
    t = np.arange(11) * 0.5
    out = ConstantVelocityPredictor()(road, None, [car], t, 100, np.random.default_rng(2))
    lat = out[0, :, :, 1]
    assert lat.max() <= 4.0 + 1e-9 and lat[0, -1] == pytest.approx(4.0)
    assert np.all(np.diff(lat, axis=1) >= -1e-9)  # sideways only the way it moves
    off = ConstantVelocityPredictor(lane_stop=False)
    free = off(road, None, [car], t, 1, np.random.default_rng(2))[0, 0, -1, 1]
    assert free > 8.0  # carried on across every lane
    with pytest.raises(ValueError, match="lane_stop"):
        ConstantVelocityPredictor(lane_stop=1)


def test_stop_at_next_centre_on_three_lanes():
    from types import SimpleNamespace

    from mmdopt.bench.highway.predictors import stop_at_next_centre

    lanes = [SimpleNamespace(position=lambda s, d, y=y: np.array([s, y + d])) for y in (0, 4, 8)]
    road = SimpleNamespace(network=SimpleNamespace(lanes_list=lambda: lanes))
    y0 = np.array([1.0, 4.1, 8.5, 3.0])
    vy = np.array([[3.0], [1.0], [1.0], [-2.0]])
    y = y0[:, None, None] + vy[:, :, None] * np.array([0.0, 1.0, 5.0])
    out = stop_at_next_centre(y0, vy, y, road)
    np.testing.assert_allclose(out[:, 0, -1], [4.0, 8.0, 8.5, 0.0])
    np.testing.assert_allclose(out[:, 0, 1], [4.0, 5.1, 8.5, 1.0])
