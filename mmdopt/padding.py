"""Obstacle padding: far-away *phantom* obstacles that keep the planner's array shapes fixed.

The jitted planner compiles once per obstacle count ``O``.  A source whose number of nearby
obstacles changes from plan to plan (the receding-horizon loop, the recorded-traffic benchmark)
pads its samples with phantoms up to a fixed count, so every plan sees the same ``O``.  A phantom
drives 500 m behind the ego at its lateral offset and speed: far outside every collision
ellipse, its collision term is exactly zero, so it changes no plan's cost.

:func:`pad_obstacles` pads (and cuts) to an exact count, or with ``bucket`` up to the next
multiple of a bucket (:func:`padded_count`), so that a few shapes cover every count.
"""

from __future__ import annotations

from typing import Any

import numpy as np

import frenet

__all__ = ["pad_obstacles", "padded_count"]


def padded_count(O: int, num: int, bucket: int | None = None) -> int:
    """How many obstacles ``O`` real ones are padded to with a bucket: the next multiple of
    ``bucket`` (default ``num``), at most ``max(num, O)`` (never fewer than ``O``)."""
    bucket = num if bucket is None else bucket
    if isinstance(bucket, bool) or not isinstance(bucket, int | np.integer) or bucket < 1:
        raise ValueError(f"bucket must be an int >= 1, got {bucket!r}")
    return min(-(-O // bucket) * bucket, max(num, O))


def pad_obstacles(
    obstacles,
    num: int | None,
    ego: frenet.EgoState,
    road: Any,
    t: np.ndarray,
    *,
    bucket: int | None = None,
) -> np.ndarray:
    """Obstacle samples with exactly ``num`` obstacles (``None``: at least one).

    Extra obstacles are dropped (the source should sort them by relevance); missing ones are
    phantoms driving 500 m behind the ego at its speed (their collision term is exactly zero: far
    outside every ellipse), their samples 1 m apart so kernel bandwidths stay positive.

    ``road`` is the planner's :class:`mmdopt.Road` (its path places the phantoms), ``t`` the
    planner's (K,) time grid.  With ``bucket`` nothing is dropped: the ``O`` obstacles are padded
    with the same phantoms up to :func:`padded_count` ``(O, num, bucket)`` (unchanged when that
    is ``O``), so the planner compiles once per bucket instead of once per obstacle count.
    """
    arr = np.asarray(obstacles, dtype=np.float64)
    if arr.ndim != 4 or arr.shape[-1] != 2 or arr.shape[2] != t.shape[0]:
        raise ValueError(
            f"obstacles must have shape (O, n, K, 2) with K = {t.shape[0]}, got {arr.shape}"
        )
    O, n = arr.shape[0], max(arr.shape[1], 1)
    if bucket is not None:
        if num is None:
            raise ValueError("a bucket needs num (the count padded to without one)")
        want = padded_count(O, int(num), int(bucket))
    else:
        want = max(O, 1) if num is None else int(num)
    if O >= want:
        return arr[:want]
    s = ego.s - 500.0 - np.arange(n, dtype=np.float64)[:, None] + max(ego.vs, 0.0) * t[None, :]
    x, y = road.path.to_cartesian(s, np.full_like(s, ego.d))
    phantom = np.stack([x, y], axis=-1)  # (n, K, 2)
    pad = np.broadcast_to(phantom, (want - O, n, t.shape[0], 2))
    if O == 0:
        return np.array(pad)
    return np.concatenate([arr, pad], axis=0)
