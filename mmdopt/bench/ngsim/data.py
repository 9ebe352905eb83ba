"""Training/evaluation windows of the recorded scenes, the train/held-out split and the
training's weight decay (shared with the highway predictor's training).

Split: the user's (``holdout``: file names, paths or glob patterns of the held-out files), else
the default rule (:func:`default_heldout`): whole recordings are held out — the scenes
``USA_US101-N_K_T-1`` with ``N % 5 == 0`` (N = 5, 10, 15, 20: 10 of the 48 shared files; the
``_K`` variants of one N share the same traffic, so splitting by file would leak) — and of other
CommonRoad scenes ``LOC-M_N_T-1`` (Lankershim: no two files share a car) the configurations
``N % 5 == 0`` (``USA_Lanker-2_5``, ``USA_Lanker-2_10``); the rest train.
"""

from __future__ import annotations

import re
from fnmatch import fnmatch
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

__all__ = [
    "HOLDOUT_MOD",
    "TRAIN_WEIGHT_DECAY",
    "default_heldout",
    "split_files",
    "describe_split",
    "scene_windows",
    "windows",
]

#: Recordings N with ``N % HOLDOUT_MOD == 0`` are held out.
HOLDOUT_MOD = 5
#: AdamW weight decay of the shipped models (``mmdopt predictor train``, on the US-101 scenes and
#: on highway-env rollouts alike; selected on recordings N % 5 == 1 of the training split: 1e-4
#: overfitted)
TRAIN_WEIGHT_DECAY = 1e-3


def default_heldout(name: str) -> bool:
    """Whether the scene ``name`` is in the default held-out split (module docstring)."""
    stem = Path(name).stem
    if "US101" in stem:
        return recording_of(stem) % HOLDOUT_MOD == 0
    m = re.match(r"^.+-\d+_(\d+)_T-\d+$", stem)
    if m is None:
        raise ValueError(
            f"{name!r}: no default split for this name (USA_US101-N_K_T-1 or another CommonRoad "
            "LOC-M_N_T-k name expected); give the held-out files (holdout / --holdout)"
        )
    return int(m.group(1)) % HOLDOUT_MOD == 0


def split_files(paths, holdout=None) -> tuple[list[Path], list[Path]]:
    """(train, held-out) scenario files under ``paths``.  ``holdout``: None (the default rule,
    :func:`default_heldout`), or file names, paths or glob patterns (``fnmatch`` on the file
    name) of the held-out files; a pattern that matches none of the files raises
    ``ValueError`` naming it."""
    files = scenario_files(paths)
    if holdout is None:
        test = [f for f in files if default_heldout(f.name)]
    else:
        pats = [holdout] if isinstance(holdout, str | Path) else list(holdout)
        test = []
        for pat in map(str, pats):
            hit = [f for f in files if fnmatch(f.name, Path(pat).name) or str(f) == pat]
            if not hit:
                raise ValueError(f"holdout pattern {pat!r} matches none of the {len(files)} files")
            test += [f for f in hit if f not in test]
        test = sorted(test)
    train = [f for f in files if f not in test]
    return train, test


def describe_split(train, test, holdout=None) -> dict:
    """The split as recorded in ``run.json`` and the weights' JSON: the rule and the files."""
    rule = (
        "default: USA_US101-N_K with N % 5 == 0, other LOC-M_N with N % 5 == 0"
        if holdout is None
        else [str(h) for h in ([holdout] if isinstance(holdout, str | Path) else holdout)]
    )
    return dict(
        holdout=rule,
        train_files=[Path(f).name for f in train],
        heldout_files=[Path(f).name for f in test],
    )


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
