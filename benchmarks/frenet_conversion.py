"""Cartesian -> Frenet conversion of many obstacle futures: a straight path's exact projection
against the general search (k-d tree, chords, Newton steps) on the same points.

A plan that draws its futures from a predictor converts every one of them (n futures x K = 100
steps) before it plans; at MMD-Opt's n(0.001) = 50 000 futures that is 5 million points.
Prints, per size, the time of each way (best of ``--repeats``), their ratio and the largest
difference of their (s, d), and the general search on a curved path of the same length:
started from the path's grid of projected nodes (its tiles computed first, untimed) and, as
the peer in the same run, from the k-d tree and chords alone, with the largest
difference of the two; and the grid start at the planner's tolerance for float32 planes
(``frenet.FLOAT32_TOL``), its ratio to the full search and its largest difference from it.

    python -m benchmarks.frenet_conversion --futures 5000,50000 --repeats 3
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

import frenet.path as frenet_path
from frenet import ReferencePath


def _best(fn, repeats: int) -> tuple[float, tuple]:
    best, out = np.inf, None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--futures", default="5000,50000", help="comma-separated numbers of futures")
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    straight = ReferencePath.straight(2000.0)
    general = dataclasses.replace(straight, _line=None)
    xs = np.linspace(0.0, 2000.0, 200)
    curved = ReferencePath.from_waypoints(np.c_[xs, 40.0 * np.sin(xs / 150.0)])
    for p in (curved, general):  # every grid tile a batch visits computed at its first visit
        p._start_grid().payback_points = 0
    rng = np.random.default_rng(0)
    print(
        "| futures | points | straight projection (s) | general search (s) | ratio "
        "| max abs diff (m) | curved path, grid start (s) | curved path, tree start (s) "
        "| ratio | max abs diff (m) | grid start, float32 tolerance (s) | ratio to full "
        "| max abs diff (m) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for n in (int(v) for v in args.futures.split(",")):
        K = args.steps
        s0 = rng.uniform(40.0, 80.0, (n, 1)) + np.cumsum(rng.uniform(0.3, 1.0, (n, K)), axis=1)
        d0 = rng.uniform(-4.0, 4.0, (n, 1)) + rng.normal(0.0, 0.05, (n, K)).cumsum(axis=1)
        x, y = straight.to_cartesian(s0, d0)
        cx, cy = curved.to_cartesian(s0, d0)
        t_fast, fast = _best(lambda x=x, y=y: straight.to_frenet(x, y), args.repeats)
        t_gen, slow = _best(lambda x=x, y=y: general.to_frenet(x, y), args.repeats)
        t = time.perf_counter()
        curved.to_frenet(cx, cy)  # computes the grid's tiles these points visit (untimed)
        general.to_frenet(x, y)
        print(f"(grid tiles for {n} futures: {time.perf_counter() - t:.2f} s, both paths)")
        t_cur, grid = _best(lambda cx=cx, cy=cy: curved.to_frenet(cx, cy), args.repeats)
        floor = frenet_path._GRID_MIN_POINTS
        frenet_path._GRID_MIN_POINTS = np.iinfo(np.int64).max  # the tree for every batch
        try:
            t_tree, tree = _best(lambda cx=cx, cy=cy: curved.to_frenet(cx, cy), args.repeats)
        finally:
            frenet_path._GRID_MIN_POINTS = floor
        t_f32, f32 = _best(
            lambda cx=cx, cy=cy: curved.to_frenet(cx, cy, tol=frenet_path.FLOAT32_TOL),
            args.repeats,
        )
        d32 = max(np.max(np.abs(f32[0] - grid[0])), np.max(np.abs(f32[1] - grid[1])))
        diff = max(np.max(np.abs(fast[0] - slow[0])), np.max(np.abs(fast[1] - slow[1])))
        dgrid = max(np.max(np.abs(grid[0] - tree[0])), np.max(np.abs(grid[1] - tree[1])))
        print(
            f"| {n} | {n * K} | {t_fast:.3f} | {t_gen:.3f} | {t_gen / t_fast:.0f} x | "
            f"{diff:.1e} | {t_cur:.3f} | {t_tree:.3f} | {t_tree / t_cur:.1f} x | {dgrid:.1e} | "
            f"{t_f32:.3f} | {t_f32 / t_cur:.2f} | {d32:.1e} |"
        )


if __name__ == "__main__":
    main()
