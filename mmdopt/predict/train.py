"""Training the MDN predictor on plain arrays (the scenes are read in :mod:`mmdopt.bench.ngsim`).

A training set is a list of :class:`Window` — the histories, the context and the recorded
futures (on ``context.times``) of the vehicles of one scene at one time.  :func:`fit_mdn` turns
them into features and least-squares basis coefficients and maximises the mixture likelihood with
AdamW (optax) on the CPU.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .base import PredictionContext, cartesian_to_lane
from .learned import MDN, Learned, MDNConfig, encode, mixture_nll, poly_basis

__all__ = ["Window", "fit_mdn", "window_arrays"]


@dataclass(frozen=True, eq=False)
class Window:
    """One scene at one time: ``history`` (O, H, 2), ``context``, ``future`` (O, K, 2) on
    ``context.times`` (Cartesian, m; complete — no missing steps)."""

    history: np.ndarray
    context: PredictionContext
    future: np.ndarray
    scene: str = ""
    t0: float = 0.0


def window_arrays(windows: list[Window], config: MDNConfig):
    """Features (N, F) and least-squares coefficients (N, 2B) of every vehicle in ``windows``."""
    X, C = [], []
    for w in windows:
        t = w.context.times
        if abs(t[-1] - config.horizon) > 1e-6:
            raise ValueError(f"window times must end at the model horizon {config.horizon} s")
        feats, s0, vs, d0 = encode(w.history, w.context, config)
        phi = poly_basis(t, config.horizon, config.n_basis)
        pinv = np.linalg.pinv(phi)  # (B, K): least squares on the grid
        for o in range(len(feats)):
            s, d = cartesian_to_lane(w.context.centerline[o], w.future[o])
            ys = s - s0[o] - max(vs[o], 0.0) * t
            yd = d - d0[o]
            C.append(np.concatenate([pinv @ ys, pinv @ yd]))
        X.append(feats)
    if not X:
        raise ValueError("no training windows")
    return np.concatenate(X, 0), np.stack(C, 0)


def fit_mdn(
    windows: list[Window],
    config: MDNConfig | None = None,
    *,
    steps: int = 3000,
    batch: int = 256,
    lr: float = 2e-3,
    weight_decay: float = 1e-4,
    seed: int = 0,
    log_every: int = 500,
    verbose: bool = True,
) -> tuple[Learned, dict]:
    """Train the MDN by maximum likelihood; returns the predictor and a training summary."""
    config = MDNConfig() if config is None else config
    if steps < 1 or batch < 1:
        raise ValueError("steps and batch must be >= 1")
    t_start = time.perf_counter()
    X, C = window_arrays(windows, config)
    ok = np.all(np.isfinite(X), 1) & np.all(np.isfinite(C), 1)
    X, C = X[ok], C[ok]
    norm = dict(
        feat_mean=X.mean(0),
        feat_std=X.std(0) + 1e-3,
        coef_mean=C.mean(0),
        coef_std=C.std(0) + 1e-3,
    )
    Xn = jnp.asarray((X - norm["feat_mean"]) / norm["feat_std"], jnp.float32)
    Zn = jnp.asarray((C - norm["coef_mean"]) / norm["coef_std"], jnp.float32)
    key = jax.random.PRNGKey(seed)
    key, k_init = jax.random.split(key)
    model = MDN(config, k_init)
    sched = optax.cosine_decay_schedule(lr, steps, alpha=0.05)
    opt = optax.adamw(sched, weight_decay=weight_decay)
    state = opt.init(eqx.filter(model, eqx.is_array))

    @eqx.filter_jit
    def step(model, state, idx):
        loss, g = eqx.filter_value_and_grad(mixture_nll)(model, Xn[idx], Zn[idx])
        upd, state = opt.update(g, state, eqx.filter(model, eqx.is_array))
        return eqx.apply_updates(model, upd), state, loss

    N = Xn.shape[0]
    losses = []
    for i in range(steps):
        key, k = jax.random.split(key)
        idx = jax.random.randint(k, (min(batch, N),), 0, N)
        model, state, loss = step(model, state, idx)
        losses.append(float(loss))
        if verbose and (i % log_every == 0 or i == steps - 1):
            print(f"step {i:5d}  nll {np.mean(losses[-log_every:]):.4f}", flush=True)
    info = dict(
        n_train=int(N),
        steps=steps,
        batch=batch,
        lr=lr,
        seed=seed,
        final_nll=float(np.mean(losses[-100:])),
        train_s=time.perf_counter() - t_start,
    )
    return Learned.from_model(model, config, norm), info
