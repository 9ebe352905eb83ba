"""Two hand-written predictors: constant velocity and a lane-aware multi-modal baseline."""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .base import (
    PredictionContext,
    cartesian_to_lane,
    check_history,
    check_key,
    check_n,
    lane_to_cartesian,
    pad_rows,
)

__all__ = ["ConstantVelocity", "LaneAware", "lane_state", "velocity_from_history"]


def velocity_from_history(h: np.ndarray, dt: float, window: int = 5) -> np.ndarray:
    """Mean velocity over the last ``window`` history intervals: (…, H, 2) → (…, 2) (m/s)."""
    m = int(min(window, h.shape[-2] - 1))
    return (h[..., -1, :] - h[..., -1 - m, :]) / (m * dt)


def lane_state(history: np.ndarray, context: PredictionContext, window: int = 5):
    """Each obstacle's history in its lane frame: ``(sd (O, H, 2), s0 (O,), vs (O,), vd (O,))``.

    ``sd[..., 0]`` is relative to the current arc length ``s0``; ``sd[..., 1]`` is the offset ``d``.
    """
    O, H, _ = history.shape
    sd = np.empty((O, H, 2))
    for o in range(O):
        s, d = cartesian_to_lane(context.centerline[o], history[o])
        sd[o, :, 0], sd[o, :, 1] = s, d
    s0 = sd[:, -1, 0].copy()
    sd[:, :, 0] -= s0[:, None]
    v = velocity_from_history(sd, context.dt_history, window)
    return sd, s0, v[:, 0], v[:, 1]


def frenet_to_cartesian(context: PredictionContext, s: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(O, n, K) lane coordinates → (O, n, K, 2) Cartesian, each obstacle in its own lane."""
    out = np.empty(s.shape + (2,))
    for o in range(s.shape[0]):
        out[o] = lane_to_cartesian(context.centerline[o], s[o], d[o])
    return out


@dataclass(frozen=True)
class ConstantVelocity:
    """Constant-velocity extrapolation in Cartesian space (no map).

    The velocity is the mean over the last 0.5 s of history (5 intervals, fewer if H is short);
    each sample perturbs it by ``speed_std`` (m/s, along the direction of travel) and
    ``lateral_std`` (m/s, across it), constant over the horizon.  ``speed_std = lateral_std = 0``
    gives the deterministic extrapolation (n identical samples).
    """

    speed_std: float = 0.5
    lateral_std: float = 0.1
    name: str = "cv"

    def __post_init__(self) -> None:
        for f in ("speed_std", "lateral_std"):
            v = float(getattr(self, f))
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"ConstantVelocity.{f} must be finite and >= 0, got {v}")

    def sample(self, history, context: PredictionContext, n: int, key) -> np.ndarray:
        h = check_history(history, context)
        n = check_n(n)
        check_key(key)
        v = velocity_from_history(h, context.dt_history)  # (O, 2)
        sp = np.linalg.norm(v, axis=-1, keepdims=True)
        u = np.where(sp > 1e-6, v / np.maximum(sp, 1e-12), np.array([1.0, 0.0]))
        nrm = np.stack([-u[:, 1], u[:, 0]], axis=-1)
        z = np.asarray(jax.random.normal(key, (h.shape[0], n, 2), dtype=jnp.float32), np.float64)
        vl = sp + self.speed_std * z[..., 0]  # (O, n)
        vt = self.lateral_std * z[..., 1]
        vel = vl[..., None] * u[:, None] + vt[..., None] * nrm[:, None]  # (O, n, 2)
        t = context.times
        return h[:, None, None, -1, :] + t[None, None, :, None] * vel[:, :, None, :]


def _smoothstep(u):
    u = jnp.clip(u, 0.0, 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u**2)  # quintic: zero velocity/accel at both ends


@dataclass(frozen=True)
class LaneAware:
    """Multi-modal, lane-aware baseline: keep lane / change left / change right.

    In each obstacle's lane frame ``(s, d)``:

    * longitudinal: speed ``v = ṡ₀ + N(0, speed_std²)`` and a constant acceleration
      ``N(0, accel_std²)``, never reversing (``ṡ ≥ 0``);
    * lateral: a quintic move from ``d₀`` to the mode's target — the lane centre (keep, 0), the
      left lane centre (``+w``) or the right one (``−w``), ``w`` the lane width — starting after
      ``U(0, 1)`` s and taking ``U(lc_min, lc_max)`` s (keep: ``U(2, 4)`` s).

    Mode weights (a simple rule, softmax of logits): keep 0; left
    ``−2 + 4·ḋ₀ + 1·[ahead gap < 30 m and left-ahead gap > ahead gap + 10 m]``; right the same
    with ``−ḋ₀`` and the right-hand gap; a side without a same-direction lane gets weight 0.
    With no lateral motion and no gap cue this is keep 0.81, left/right 0.095 each (with both
    lanes).  The sampled mode of every sample is drawn from these weights.
    """

    speed_std: float = 1.0
    accel_std: float = 0.4
    lc_min: float = 3.0
    lc_max: float = 6.0
    name: str = "lane"

    def __post_init__(self) -> None:
        for f in ("speed_std", "accel_std"):
            v = float(getattr(self, f))
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"LaneAware.{f} must be finite and >= 0, got {v}")
        if not (0 < self.lc_min <= self.lc_max):
            raise ValueError(
                f"LaneAware needs 0 < lc_min <= lc_max, got {self.lc_min, self.lc_max}"
            )

    def mode_logits(self, context: PredictionContext, vd: np.ndarray) -> np.ndarray:
        """(O, 3) logits of [keep, left, right] (−inf for a missing lane)."""
        g = context.gaps
        own = g[:, 0]
        cue_l = (own < 30.0) & (g[:, 2] > own + 10.0)
        cue_r = (own < 30.0) & (g[:, 4] > own + 10.0)
        zl = -2.0 + 4.0 * vd + 1.0 * cue_l
        zr = -2.0 - 4.0 * vd + 1.0 * cue_r
        zl = np.where(context.has_left, zl, -np.inf)
        zr = np.where(context.has_right, zr, -np.inf)
        return np.stack([np.zeros_like(zl), zl, zr], axis=-1)

    def mode_weights(self, history, context: PredictionContext) -> np.ndarray:
        """(O, 3) probabilities of [keep, left, right]."""
        h = check_history(history, context)
        _, _, _, vd = lane_state(h, context)
        z = self.mode_logits(context, vd)
        z = z - z.max(axis=-1, keepdims=True)
        p = np.exp(z)
        return p / p.sum(axis=-1, keepdims=True)

    def sample(self, history, context: PredictionContext, n: int, key) -> np.ndarray:
        h = check_history(history, context)
        n = check_n(n)
        check_key(key)
        sd, s0, vs, vd = lane_state(h, context)
        logits = self.mode_logits(context, vd)
        O = h.shape[0]
        s, d = _lane_aware_jit(
            key,
            jnp.asarray(pad_rows(logits)),
            jnp.asarray(pad_rows(s0)),
            jnp.asarray(pad_rows(np.maximum(vs, 0.0))),
            jnp.asarray(pad_rows(sd[:, -1, 1])),
            jnp.asarray(pad_rows(context.lane_width)),
            jnp.asarray(context.times),
            n,
            float(self.speed_std),
            float(self.accel_std),
            float(self.lc_min),
            float(self.lc_max),
        )
        s, d = np.asarray(s[:O], np.float64), np.asarray(d[:O], np.float64)
        return frenet_to_cartesian(context, s, d)


def _lane_aware_sample(key, logits, s0, vs, d0, w, t, n, speed_std, accel_std, lc_min, lc_max):
    O = logits.shape[0]
    km, kv, ka, ks, kd = jax.random.split(key, 5)
    mode = jax.random.categorical(km, logits[:, None, :], axis=-1, shape=(O, n))
    v = jnp.maximum(vs[:, None] + speed_std * jax.random.normal(kv, (O, n)), 0.0)
    a = accel_std * jax.random.normal(ka, (O, n))
    t_stop = jnp.where(a < 0, -v / jnp.where(a < 0, a, -1.0), jnp.inf)
    tt = jnp.minimum(t[None, None, :], t_stop[..., None])
    s = s0[:, None, None] + v[..., None] * tt + 0.5 * a[..., None] * tt**2
    target = jnp.where(mode == 1, w[:, None], jnp.where(mode == 2, -w[:, None], 0.0))
    start = jax.random.uniform(ks, (O, n), maxval=1.0)
    dur_lc = jax.random.uniform(kd, (O, n), minval=lc_min, maxval=lc_max)
    dur = jnp.where(
        mode == 0, 2.0 + (dur_lc - lc_min) / jnp.maximum(lc_max - lc_min, 1e-9) * 2.0, dur_lc
    )
    u = (t[None, None, :] - start[..., None]) / dur[..., None]
    d = d0[:, None, None] + (target - d0[:, None])[..., None] * _smoothstep(u)
    return s, d


_lane_aware_jit = jax.jit(_lane_aware_sample, static_argnums=(7,))
