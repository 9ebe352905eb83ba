"""Prediction metrics: minADE/minFDE@k and a sample-based (KDE) negative log-likelihood.

* ``minADE@k`` / ``minFDE@k``: of k samples, the smallest mean (over the future steps ``t > 0``)
  / final Euclidean error to the recorded future (m), averaged over vehicles.
* ``NLL``: Trajectron++'s KDE NLL — at every future step a Gaussian kernel density of the n
  samples (per-axis bandwidth by Scott's rule, ``σ·n^(−1/6)``, floored at ``bw_min`` m) is
  evaluated at the recorded position; the log densities are averaged over steps and vehicles
  (nats per step, lower is better).  It applies to any sampler, deterministic ones included
  (their bandwidth is the floor).
"""

from __future__ import annotations

import numpy as np

__all__ = ["min_ade_fde", "kde_nll", "evaluate_predictor"]


def _check(samples, future):
    s = np.asarray(samples, np.float64)
    f = np.asarray(future, np.float64)
    if s.ndim != 4 or s.shape[-1] != 2:
        raise ValueError(f"samples must have shape (O, n, K, 2), got {s.shape}")
    if f.shape != (s.shape[0], s.shape[2], 2):
        raise ValueError(f"future must have shape (O, K, 2) = {(s.shape[0], s.shape[2], 2)}")
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(f))):
        raise ValueError("samples/future contain NaN or inf")
    return s, f


def min_ade_fde(samples, future) -> tuple[np.ndarray, np.ndarray]:
    """Per-vehicle minADE and minFDE (O,) over all n samples given (m); steps 1…K−1."""
    s, f = _check(samples, future)
    err = np.linalg.norm(s[:, :, 1:] - f[:, None, 1:], axis=-1)  # (O, n, K-1)
    return err.mean(-1).min(-1), err[..., -1].min(-1)


def kde_nll(samples, future, bw_min: float = 0.1) -> np.ndarray:
    """Per-vehicle KDE NLL (O,) (nats per step, steps 1…K−1)."""
    s, f = _check(samples, future)
    s, f = s[:, :, 1:], f[:, 1:]
    n = s.shape[1]
    bw = np.maximum(s.std(axis=1) * n ** (-1.0 / 6.0), bw_min)  # (O, K, 2)
    z = (s - f[:, None]) / bw[:, None]
    logk = -0.5 * np.sum(z**2, -1) - np.log(2 * np.pi) - np.sum(np.log(bw), -1)[:, None]
    m = logk.max(1)
    logp = m + np.log(np.mean(np.exp(logk - m[:, None]), axis=1))  # (O, K-1)
    return -logp.mean(-1)


def evaluate_predictor(predictor, windows, key, *, k: int = 20, n_nll: int = 200) -> dict:
    """minADE/minFDE@k and KDE NLL (n_nll samples) of ``predictor`` over ``windows``
    (:class:`mmdopt.predict.train.Window`), averaged over every vehicle of every window."""
    import jax

    if not windows:
        raise ValueError("windows is empty")
    ade, fde, nll = [], [], []
    for i, w in enumerate(windows):
        kk, kn = jax.random.split(jax.random.fold_in(key, i))
        sk = predictor.sample(w.history, w.context, k, kk)
        a, f = min_ade_fde(sk, w.future)
        sn = predictor.sample(w.history, w.context, n_nll, kn)
        ade.append(a)
        fde.append(f)
        nll.append(kde_nll(sn, w.future))
    ade, fde, nll = (np.concatenate(x) for x in (ade, fde, nll))
    return dict(
        predictor=getattr(predictor, "name", type(predictor).__name__),
        n_vehicles=int(ade.size),
        n_windows=len(windows),
        k=k,
        min_ade=float(ade.mean()),
        min_fde=float(fde.mean()),
        nll=float(nll.mean()),
    )
