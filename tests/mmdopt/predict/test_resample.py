"""resample_prediction: a predictor's own time step onto the planner's grid."""

from __future__ import annotations

import numpy as np
import pytest

from mmdopt.predict.resample import resample_prediction


def _trajectron_like(n=5, T=12, dt=0.5, seed=0):
    """n futures at t = dt, ..., T dt of constant-acceleration motion from a known present."""
    rng = np.random.default_rng(seed)
    v = rng.uniform(3.0, 8.0, (n, 1))
    a = rng.uniform(-0.5, 0.5, (n, 1))
    t = dt * np.arange(1, T + 1)
    x = 10.0 + v * t + 0.5 * a * t**2
    y = np.broadcast_to(-1.5 + 0.1 * t, x.shape)
    return np.stack([x, y], -1), np.array([10.0, -1.5]), v, a


@pytest.mark.parametrize("kind", ["cubic", "linear"])
def test_values_at_prediction_times_are_kept_and_current_prepended(kind):
    s, cur, _, _ = _trajectron_like()
    tg = np.array([0.0, 0.5, 1.0, 3.0, 6.0])
    out = resample_prediction(s, 0.5, tg, current=cur, kind=kind)
    assert out.shape == (5, 5, 2) and out.dtype == np.float64
    np.testing.assert_allclose(out[:, 0], np.broadcast_to(cur, (5, 2)), atol=1e-12)
    np.testing.assert_allclose(out[:, 1:], s[:, [0, 1, 5, 11]], atol=1e-9)


def test_cubic_recovers_quadratic_motion_between_steps():
    # a cubic spline reproduces a quadratic exactly; linear interpolation does not
    s, cur, v, a = _trajectron_like()
    tg = np.linspace(0.0, 6.0, 100)
    truth = 10.0 + v * tg + 0.5 * a * tg**2
    cub = resample_prediction(s, 0.5, tg, current=cur)
    lin = resample_prediction(s, 0.5, tg, current=cur, kind="linear")
    np.testing.assert_allclose(cub[..., 0], truth, atol=1e-9)
    assert np.max(np.abs(lin[..., 0] - truth)) > 1e-4
    assert np.max(np.abs(lin[..., 0] - truth)) < 0.5 * 0.5**2 / 8 + 1e-9  # max|x''| dt² / 8


def test_without_current_the_first_step_is_t0():
    s, _, _, _ = _trajectron_like(T=4, dt=1.0)
    out = resample_prediction(s, 1.0, [0.0, 1.5, 3.0], kind="linear")
    np.testing.assert_allclose(out[:, 0], s[:, 0])
    np.testing.assert_allclose(out[:, 1], 0.5 * (s[:, 1] + s[:, 2]))
    np.testing.assert_allclose(out[:, 2], s[:, 3])


def test_output_feeds_the_planner_grid_shape():
    from mmdopt import MMDOptConfig

    cfg = MMDOptConfig()
    s, cur, _, _ = _trajectron_like(T=30, dt=0.5)  # 15 s
    tg = np.linspace(0.0, cfg.trajectory.horizon, cfg.trajectory.num_steps)
    out = resample_prediction(s, 0.5, tg, current=cur)
    assert out.shape == (5, cfg.trajectory.num_steps, 2)
    assert np.all(np.isfinite(out))


def test_horizon_too_short_names_argument_and_times():
    s, cur, _, _ = _trajectron_like()  # 6 s of prediction
    with pytest.raises(ValueError, match=r"t_grid ends at 15 s .* ends at 6 s"):
        resample_prediction(s, 0.5, np.linspace(0, 15, 100), current=cur)


def test_grid_before_first_prediction_time_without_current():
    s, _, _, _ = _trajectron_like()
    with pytest.raises(ValueError, match=r"t_grid starts at -1 s.*current="):
        resample_prediction(s, 0.5, [-1.0, 0.0, 1.0])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(samples=np.zeros((5, 12))), "samples must have shape"),
        (dict(samples=np.zeros((0, 12, 2))), "samples is empty"),
        (dict(samples=np.full((2, 12, 2), np.nan)), "samples contains NaN"),
        (dict(dt=0.0), "dt must be"),
        (dict(dt=float("nan")), "dt must be"),
        (dict(t_grid=[0.0, 2.0, 1.0]), "strictly increasing"),
        (dict(t_grid=[[0.0, 1.0]]), "t_grid must be"),
        (dict(t_grid=[0.0, np.inf]), "t_grid contains NaN or inf"),
        (dict(current=np.zeros(3)), "current must have shape"),
        (dict(current=[np.nan, 0.0]), "current contains NaN"),
        (dict(kind="quadratic"), "kind must be"),
    ],
)
def test_bad_inputs_raise_value_error_naming_the_argument(kwargs, match):
    args = dict(samples=np.zeros((2, 12, 2)), dt=0.5, t_grid=[0.0, 1.0], current=None)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        resample_prediction(**args)
