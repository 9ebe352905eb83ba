"""Training/evaluation windows of the recorded scenes, the train/held-out split and the
training's weight decay (shared with the highway predictor's training).

Split: whole recordings are held out — the scenes ``USA_US101-N_K_T-1`` with ``N % 5 == 0``
(N = 5, 10, 15, 20: 10 of the 48 shared files) are the **held-out** split, the rest train.  The
``_K`` variants of one N share the same traffic, so splitting by file would leak.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mmdopt.predict.train import Window

from .scene import (
    context_at,
    future_at,
    history_at,
    load_scenario,
    present,
    recording_of,
    scenario_files,
)

__all__ = ["HOLDOUT_MOD", "TRAIN_WEIGHT_DECAY", "split_files", "scene_windows", "windows"]

#: Recordings N with ``N % HOLDOUT_MOD == 0`` are held out.
HOLDOUT_MOD = 5
#: AdamW weight decay of the shipped models (``mmdopt predictor train``, on the US-101 scenes and
#: on highway-env rollouts alike; selected on recordings N % 5 == 1 of the training split: 1e-4
#: overfitted)
TRAIN_WEIGHT_DECAY = 1e-3


def split_files(paths) -> tuple[list[Path], list[Path]]:
    """(train, held-out) scenario files under ``paths`` (by recording number)."""
    files = scenario_files(paths)
    test = [f for f in files if recording_of(f.stem) % HOLDOUT_MOD == 0]
    train = [f for f in files if recording_of(f.stem) % HOLDOUT_MOD != 0]
    return train, test


def scene_windows(
    path, *, horizon: float = 5.0, history: int = 10, stride: int = 5, first_step: int | None = None
) -> list[Window]:
    """Every ``stride`` steps, one :class:`Window` of the vehicles recorded over the whole
    history and horizon (``history`` rows, ``horizon`` s at the scene's dt)."""
    sc = load_scenario(str(path))
    K = int(round(horizon / sc.dt))
    times = np.arange(K + 1) * sc.dt
    out = []
    k0 = history - 1 if first_step is None else first_step
    for k in range(k0, sc.num_steps - K, stride):
        idx = np.flatnonzero(
            present(sc, k - history + 1, k + K) & np.all(sc.lane_of[:, [k]] >= 0, 1)
        )
        if len(idx) == 0:
            continue
        ctx = context_at(sc, idx, k, times)
        out.append(
            Window(
                history=history_at(sc, idx, k, history),
                context=ctx,
                future=future_at(sc, idx, k, times),
                scene=sc.name,
                t0=k * sc.dt,
            )
        )
    return out


def windows(files, **kw) -> list[Window]:
    """:func:`scene_windows` of every file."""
    out: list[Window] = []
    for f in files:
        out += scene_windows(f, **kw)
    return out
