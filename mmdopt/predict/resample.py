"""Predictions from common predictors onto the planner's time grid.

A predictor such as Trajectron++ samples futures at its own time step (e.g. ``dt = 0.5 s`` for
12 steps, 6 s) and without the present position; :func:`mmdopt.plan` wants positions on its own
grid (``MMDOptConfig.horizon`` s on ``num_steps`` points, starting at ``t = 0``).
:func:`resample_prediction` maps one onto the other::

    from mmdopt.predict.resample import resample_prediction
    import numpy as np

    traj = predictor(history)                        # (n, 12, 2): t = 0.5, 1.0, ..., 6.0 s
    t_grid = np.linspace(0.0, 6.0, 100)              # the planner's grid, here a 6 s horizon
    obs = resample_prediction(traj, 0.5, t_grid, current=history[-1])     # (n, 100, 2)
    plan = mmdopt.plan(ego, road, obs[None], config=MMDOptConfig().replace(horizon=6.0, ...))
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["resample_prediction"]

#: slack (s) when comparing the horizons, for grids built with floating-point arithmetic
_TIME_TOL = 1e-9


def _finite(name: str, x: np.ndarray) -> None:
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} contains NaN or inf")


def resample_prediction(
    samples: ArrayLike,
    dt: float,
    t_grid: ArrayLike,
    current: ArrayLike | None = None,
    *,
    kind: Literal["cubic", "linear"] = "cubic",
) -> NDArray[np.float64]:
    """Resample a predictor's sampled futures ``(n, T, 2)`` onto the planner's time grid.

    Parameters
    ----------
    samples : (n, T, 2) positions ``(x, y)`` (m) of ``n`` sampled futures at the predictor's time
        step.  With ``current`` given, ``samples[:, j]`` is the position at ``t = (j + 1) * dt``
        (the predictor's future excludes the present, as Trajectron++'s does); without it, at
        ``t = j * dt`` (the first step is the present).
    dt : the predictor's time step (s), > 0.
    t_grid : (K,) strictly increasing times (s) of the planner's grid, e.g.
        ``np.linspace(0, config.trajectory.horizon, config.trajectory.num_steps)``.
    current : optional present position, (2,) (shared by all samples) or (n, 2), prepended at
        ``t = 0``.
    kind : ``"cubic"`` (default: a cubic spline through the points, not-a-knot end conditions,
        ``scipy.interpolate.CubicSpline``; velocities stay continuous) or ``"linear"``
        (piecewise linear; never overshoots between points).  With two time points the spline
        is linear.

    Returns
    -------
    (n, K, 2) float64 positions on ``t_grid``; at times of the prediction they equal the input.

    Raises
    ------
    ValueError
        naming the argument for a wrong shape, NaN/inf, ``dt <= 0``, an empty sample set, a
        ``t_grid`` that is not strictly increasing, an unknown ``kind``, and when the horizons do
        not cover each other: ``t_grid`` starts before the first predicted time or ends after
        the last (the message gives both times).  No extrapolation.
    """
    try:
        xs = np.asarray(samples, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("samples must be a numeric array (n, T, 2)") from None
    if xs.ndim != 3 or xs.shape[-1] != 2:
        raise ValueError(f"samples must have shape (n, T, 2), got {xs.shape}")
    n, T, _ = xs.shape
    if n == 0 or T == 0:
        raise ValueError(f"samples is empty (shape {xs.shape}): need n >= 1 samples, T >= 1 steps")
    _finite("samples", xs)
    if isinstance(dt, bool) or not isinstance(dt, int | float | np.integer | np.floating):
        raise ValueError(f"dt must be a number of seconds, got {dt!r}")
    dt = float(dt)
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"dt must be a finite time step > 0 s, got {dt}")
    try:
        tg = np.asarray(t_grid, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("t_grid must be a numeric array (K,)") from None
    if tg.ndim != 1 or tg.size == 0:
        raise ValueError(f"t_grid must be a non-empty 1-D array of times (K,), got {tg.shape}")
    _finite("t_grid", tg)
    if tg.size > 1 and not np.all(np.diff(tg) > 0):
        raise ValueError("t_grid must be strictly increasing")
    if kind not in ("cubic", "linear"):
        raise ValueError(f"kind must be 'cubic' or 'linear', got {kind!r}")

    if current is None:
        t_pred = dt * np.arange(T)
        pts = xs
    else:
        try:
            c = np.asarray(current, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError("current must be a numeric array (2,) or (n, 2)") from None
        if c.shape == (2,):
            c = np.broadcast_to(c, (n, 2))
        elif c.shape != (n, 2):
            raise ValueError(f"current must have shape (2,) or (n, 2) = ({n}, 2), got {c.shape}")
        _finite("current", c)
        t_pred = dt * np.arange(T + 1)
        pts = np.concatenate([c[:, None, :], xs], axis=1)

    t_first, t_last = float(t_pred[0]), float(t_pred[-1])
    if tg[0] < t_first - _TIME_TOL:
        raise ValueError(
            f"t_grid starts at {tg[0]:g} s, before the prediction's first time {t_first:g} s "
            + (
                "(pass current= to prepend the present position at t = 0)"
                if current is None
                else ""
            )
        )
    if tg[-1] > t_last + _TIME_TOL:
        steps = f"{T} steps × dt {dt:g} s" + (
            " after the current position" if current is not None else ""
        )
        raise ValueError(
            f"t_grid ends at {tg[-1]:g} s but the prediction (samples: {steps}) ends at "
            f"{t_last:g} s: the horizons don't cover each other (shorten the planner's horizon, "
            "MMDOptConfig.horizon, or predict further)"
        )
    tq = np.clip(tg, t_first, t_last)
    if len(t_pred) == 1:
        return np.broadcast_to(pts, (n, tg.size, 2)).copy()
    if kind == "linear" or len(t_pred) == 2:
        i = np.clip(np.searchsorted(t_pred, tq, side="right") - 1, 0, len(t_pred) - 2)
        w = ((tq - t_pred[i]) / (t_pred[i + 1] - t_pred[i]))[None, :, None]
        return (1.0 - w) * pts[:, i] + w * pts[:, i + 1]
    from scipy.interpolate import CubicSpline

    return CubicSpline(t_pred, pts, axis=1, bc_type="not-a-knot")(tq)
