"""A learned multi-modal predictor: a mixture-density network (MDN) in the lane frame (equinox).

Model.  For each obstacle, in its lane frame ``(s, d)`` (:mod:`mmdopt.predict.base`), the future
relative to constant-speed lane following is expanded in a polynomial basis::

    s(t) − s₀ − ṡ₀·t = Σ_b c^s_b φ_b(t),   d(t) − d₀ = Σ_b c^d_b φ_b(t)

(``φ_b`` the monomials ``(t/T)^(b+1)``, ``b = 0 … B−1``, orthonormalised on the grid; ``T`` the
trained horizon), and the 2B coefficients get a mixture of M
diagonal Gaussians, ``p(c | x) = Σ_m π_m(x) N(c; μ_m(x), diag σ_m(x)²)``, whose parameters are an
MLP of the features ``x``: the history in the lane frame (arc length relative to now, offset),
``ṡ₀, ḋ₀, d₀``, lane width, whether left/right lanes exist, and the six neighbour gaps and relative
speeds of :class:`~mmdopt.predict.base.PredictionContext`.  Trained by maximum likelihood on the
least-squares coefficients of recorded futures (:mod:`mmdopt.predict.train`).  Sampling: a mode
from π, coefficients from its Gaussian, the trajectory at the requested times, back to Cartesian
along the lane; deterministic for a key.

The shipped weights (``weights/mdn_ngsim_us101.eqx`` + ``.json``) were trained on the NGSIM
US-101 scenes of recordings N ≢ 0 (mod 5) (docs/experiments/ngsim.md); :class:`Learned` loads them
by default.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .base import GAP_NONE, PredictionContext, check_history, check_key, check_n, pad_rows
from .baselines import frenet_to_cartesian, lane_state

__all__ = ["MDNConfig", "MDN", "Learned", "encode", "poly_basis", "DEFAULT_WEIGHTS"]

DEFAULT_WEIGHTS = Path(__file__).parent / "weights" / "mdn_ngsim_us101"
#: weights trained on the US-101 and the Lankershim Boulevard (urban, junctions) training scenes
#: (``mdn_ngsim_urban.json`` names the files and the command)
URBAN_WEIGHTS = Path(__file__).parent / "weights" / "mdn_ngsim_urban"


@dataclass(frozen=True)
class MDNConfig:
    """Sizes of the model and the data it was trained on (stored with the weights).

    Chosen on a validation split of the training scenes (recordings N % 5 == 1): hidden 128 with
    6 modes and 4 basis functions overfitted (validation minADE@20 0.94 m); 32 hidden units,
    8 modes, 3 basis functions: 0.76 m (the lane-aware baseline: 0.84 m)."""

    history_len: int = 10
    dt_history: float = 0.1
    horizon: float = 5.0
    n_modes: int = 8
    n_basis: int = 3
    hidden: int = 32
    depth: int = 2

    @property
    def n_features(self) -> int:
        return 2 * self.history_len + 6 + 2 * 6

    @property
    def n_coef(self) -> int:
        return 2 * self.n_basis


class MDN(eqx.Module):
    """MLP → (logits (M,), means (M, 2B), log-stds (M, 2B)) of the coefficient mixture."""

    mlp: eqx.nn.MLP
    n_modes: int = eqx.field(static=True)
    n_coef: int = eqx.field(static=True)

    def __init__(self, config: MDNConfig, key):
        M, C = config.n_modes, config.n_coef
        self.mlp = eqx.nn.MLP(
            config.n_features, M * (1 + 2 * C), config.hidden, config.depth, jax.nn.gelu, key=key
        )
        self.n_modes, self.n_coef = M, C

    def __call__(self, x):
        out = self.mlp(x)
        M, C = self.n_modes, self.n_coef
        logits = out[:M]
        mean = out[M : M + M * C].reshape(M, C)
        log_std = jnp.clip(out[M + M * C :].reshape(M, C), -5.0, 3.0)
        return logits, mean, log_std


def poly_basis(times, horizon: float, n_basis: int) -> np.ndarray:
    """(K, B) basis: the monomials ``(t/T)^(b+1)``, b = 0 … B−1, orthonormalised (QR) on a
    uniform 51-point grid of ``[0, T]`` — so independent coefficient noise is white noise in
    trajectory space instead of the large cancelling terms of a raw monomial basis."""
    ref = np.linspace(0.0, 1.0, 51)[:, None] ** np.arange(1, n_basis + 1)[None, :]
    _, r = np.linalg.qr(ref)
    u = np.asarray(times, np.float64)[:, None] / float(horizon)
    return (u ** np.arange(1, n_basis + 1)[None, :]) @ np.linalg.inv(r)


def encode(history, context: PredictionContext, config: MDNConfig):
    """Raw (unnormalised) features ``(O, F)`` and each obstacle's lane state ``(s0, vs, d0)``."""
    h = check_history(history, context, min_len=config.history_len)
    if h.shape[1] != config.history_len:
        raise ValueError(
            f"history must have H = {config.history_len} rows for this model, got {h.shape[1]}"
        )
    if abs(context.dt_history - config.dt_history) > 1e-6:
        raise ValueError(
            f"context.dt_history = {context.dt_history} but the model was trained with "
            f"{config.dt_history} s"
        )
    sd, s0, vs, vd = lane_state(h, context)
    d0 = sd[:, -1, 1]
    feats = np.concatenate(
        [
            sd[:, :, 0] / 10.0,
            sd[:, :, 1] - d0[:, None],
            np.stack([vs / 10.0, vd, d0, context.lane_width / 3.5], axis=-1),
            np.stack([context.has_left, context.has_right], axis=-1).astype(np.float64),
            np.minimum(context.gaps, GAP_NONE) / GAP_NONE,
            context.rel_speed / 5.0,
        ],
        axis=-1,
    )
    return feats, s0, vs, d0


def mixture_nll(model: MDN, x, z):
    """Mean NLL of coefficients ``z`` (N, C) under the mixture at features ``x`` (N, F)."""
    logits, mean, log_std = jax.vmap(model)(x)
    logp = jax.nn.log_softmax(logits, axis=-1)
    r = (z[:, None, :] - mean) * jnp.exp(-log_std)
    comp = -0.5 * jnp.sum(r**2, -1) - jnp.sum(log_std, -1) - 0.5 * z.shape[-1] * jnp.log(2 * jnp.pi)
    return -jnp.mean(jax.nn.logsumexp(logp + comp, axis=-1))


@eqx.filter_jit
def _sample_coef(model: MDN, x, key, n_arr, spread=1.0):
    n = n_arr.shape[0]
    logits, mean, log_std = jax.vmap(model)(x)  # (O, M), (O, M, C)
    O = x.shape[0]
    km, kz = jax.random.split(key)
    mode = jax.random.categorical(km, logits[:, None, :], axis=-1, shape=(O, n))
    mu = jnp.take_along_axis(mean, mode[..., None], axis=1)  # (O, n, C)
    sd = jnp.exp(jnp.take_along_axis(log_std, mode[..., None], axis=1)) * spread
    return mu + sd * jax.random.normal(kz, mu.shape, dtype=mu.dtype)


class Learned:
    """The MDN predictor (see the module docstring).  ``Learned()`` loads the shipped weights;
    ``Learned(path)`` loads ``path.eqx`` + ``path.json`` written by :func:`save_weights`.

    ``spread`` (> 0, default 1) scales every mixture component's standard deviation when
    sampling (a post-hoc dispersion calibration; ``benchmarks/predictor_calibration.py``)."""

    name = "learned"

    def __init__(self, weights: str | Path | None = None, spread: float = 1.0):
        if isinstance(spread, bool) or not isinstance(spread, int | float | np.number):
            raise ValueError(f"spread must be a positive number, got {spread!r}")
        if not (np.isfinite(spread) and spread > 0):
            raise ValueError(f"spread must be a positive finite number, got {spread}")
        self.spread = float(spread)
        base = DEFAULT_WEIGHTS if weights is None else Path(weights)
        base = base.with_suffix("") if base.suffix in (".eqx", ".json") else base
        meta_path, eqx_path = base.with_suffix(".json"), base.with_suffix(".eqx")
        if not meta_path.exists() or not eqx_path.exists():
            raise FileNotFoundError(
                f"learned-predictor weights not found: {eqx_path} and {meta_path} "
                "(train them with `mmdopt predictor train`)"
            )
        meta = json.loads(meta_path.read_text())
        self.config = MDNConfig(**meta["config"])
        like = MDN(self.config, jax.random.PRNGKey(0))
        self.model = eqx.tree_deserialise_leaves(eqx_path, like)
        self.norm = {k: np.asarray(meta["norm"][k], np.float64) for k in meta["norm"]}
        self.meta = meta

    @classmethod
    def from_model(cls, model: MDN, config: MDNConfig, norm: dict) -> Learned:
        self = cls.__new__(cls)
        self.spread = 1.0
        self.model, self.config = model, config
        self.norm = {k: np.asarray(v, np.float64) for k, v in norm.items()}
        self.meta = {"config": asdict(config)}
        return self

    def sample(self, history, context: PredictionContext, n: int, key) -> np.ndarray:
        n = check_n(n)
        check_key(key)
        cfg = self.config
        feats, s0, vs, d0 = encode(history, context, cfg)
        t = context.times
        if t[-1] > cfg.horizon + 1e-6:
            raise ValueError(
                f"context.times reach {t[-1]:.3g} s but the learned model predicts only "
                f"{cfg.horizon:g} s ahead (use a planner horizon ≤ {cfg.horizon:g} s)"
            )
        x = (feats - self.norm["feat_mean"]) / self.norm["feat_std"]
        O = x.shape[0]
        z = _sample_coef(
            self.model,
            jnp.asarray(pad_rows(x), jnp.float32),
            key,
            jnp.zeros(n),
            jnp.asarray(self.spread, jnp.float32),  # traced: one compilation for every spread
        )
        c = np.asarray(z[:O], np.float64) * self.norm["coef_std"] + self.norm["coef_mean"]
        B = cfg.n_basis
        phi = poly_basis(t, cfg.horizon, B)  # (K, B)
        ds = c[..., :B] @ phi.T  # (O, n, K)
        dd = c[..., B:] @ phi.T
        s = s0[:, None, None] + np.maximum(vs, 0.0)[:, None, None] * t + ds
        d = d0[:, None, None] + dd
        return frenet_to_cartesian(context, s, d)


def save_weights(path: str | Path, model: MDN, config: MDNConfig, norm: dict, info: dict) -> Path:
    """Write ``path.eqx`` (leaves) and ``path.json`` (config, normalisation, training info)."""
    base = Path(path)
    base = base.with_suffix("") if base.suffix in (".eqx", ".json") else base
    base.parent.mkdir(parents=True, exist_ok=True)
    eqx.tree_serialise_leaves(base.with_suffix(".eqx"), model)
    meta = {
        "config": asdict(config),
        "norm": {k: np.asarray(v).tolist() for k, v in norm.items()},
        "info": info,
    }
    base.with_suffix(".json").write_text(json.dumps(meta, indent=1))
    return base
