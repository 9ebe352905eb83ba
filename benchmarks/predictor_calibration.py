"""Dispersion calibration of the learned predictor: probability integral transform (PIT) of the
distance each recorded car travelled, among the predictor's samples.

For every vehicle of every window (``mmdopt.bench.ngsim.data.windows``, every 2 s) and a time
t, u = the share of 200 samples that travelled less far from the current position than the car
did.  For a calibrated predictor u is uniform: P(u < 0.01) ≈ 0.01 and P(u < 0.05) ≈ 0.05.  The
lower tail (the car was slower than almost every sample) is where a follower's plan meets the
car it follows.  ``--spread`` scales every mixture component's standard deviation
(``Learned(spread=...)``).  The training split is the default (``--split train``): choose a
spread there, never on the held-out recordings.

    python benchmarks/predictor_calibration.py --spread 1.0 1.3 1.6
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

from mmdopt.bench.ngsim.cli import default_data_dir
from mmdopt.bench.ngsim.data import split_files, windows
from mmdopt.predict import make_predictor

STEPS = (9, 29, 49)  # 1, 3 and 5 s at 0.1 s


def pit(predictor, wins, n: int = 200, seed: int = 5) -> dict[int, np.ndarray]:
    out: dict[int, list] = {k: [] for k in STEPS}
    for i, w in enumerate(wins):
        S = predictor.sample(
            w.history, w.context, n, jax.random.fold_in(jax.random.PRNGKey(seed), i)
        )
        x0 = w.history[:, -1, :]
        for k in STEPS:
            ds = np.linalg.norm(S[:, :, k] - x0[:, None], axis=-1)  # (O, n)
            dr = np.linalg.norm(w.future[:, k] - x0, axis=-1)  # (O,)
            out[k].append((ds < dr[:, None]).mean(axis=1))
    return {k: np.concatenate(v) for k, v in out.items()}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--split", choices=("train", "heldout"), default="train")
    ap.add_argument("--predictor", default="learned", choices=("learned", "lane", "cv"))
    ap.add_argument("--spread", type=float, nargs="+", default=[1.0])
    ap.add_argument("--stride", type=int, default=20)
    a = ap.parse_args(argv)
    train, test = split_files(default_data_dir() if a.data is None else a.data)
    wins = windows(train if a.split == "train" else test, stride=a.stride)
    print(f"# {a.split} split: {len(wins)} windows; 200 samples per vehicle")
    print(
        "| predictor | spread | t (s) | vehicles | P(u<0.01) | P(u<0.05) | P(u>0.95) | P(u>0.99) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for sp in a.spread if a.predictor == "learned" else [1.0]:
        kw = {"spread": sp} if a.predictor == "learned" else {}
        u = pit(make_predictor(a.predictor, **kw), wins)
        for k in STEPS:
            x = u[k]
            print(
                f"| {a.predictor} | {sp:g} | {(k + 1) * 0.1:.0f} | {x.size} "
                f"| {np.mean(x < 0.01):.3f} | {np.mean(x < 0.05):.3f} "
                f"| {np.mean(x > 0.95):.3f} | {np.mean(x > 0.99):.3f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
