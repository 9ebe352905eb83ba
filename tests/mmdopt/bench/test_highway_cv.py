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
