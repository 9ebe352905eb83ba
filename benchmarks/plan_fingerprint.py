"""Plan fingerprints: does a refactor leave the plans unchanged bit for bit?

Plans the demo scene with every method and ``--scenes`` tuning scenes (``paper100``, seed 777,
which no reported figure uses) with MMD-Opt, de Groot and SAA at the default config; on the
first five scenes also MMD-Opt with the time-linear margins and with every responsibility rule
switched on.  Saves each plan's ``x``, ``y``, cost and status to an ``.npz``; ``--compare`` an
earlier file prints which arrays differ (and by how much).

    python -m benchmarks.plan_fingerprint --out before.npz          # on the old checkout
    python -m benchmarks.plan_fingerprint --out after.npz --compare before.npz
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import mmdopt
from mmdopt.bench.scenes import demo_scene, make_scene
from mmdopt.bench.synthetic import scene_config

RULES = dict(
    margin_mode="linear",
    headway_time=1.0,
    headway_gap=2.0,
    rear_exempt_width=1.5,
    slip_ratio=0.5,
    yaw_extent=2.5,
)


def fingerprints(n_scenes: int) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}

    def record(tag, scene, method, cfg):
        p = mmdopt.plan(
            scene.ego(), scene.road(), scene.obstacles, method=method, config=cfg, key=scene.key()
        )
        out[f"{tag}/x"], out[f"{tag}/y"] = np.asarray(p.x), np.asarray(p.y)
        out[f"{tag}/cost"] = np.asarray(p.cost)
        out[f"{tag}/status"] = np.asarray(str(p.status))

    sc = demo_scene()
    for m in mmdopt.PLAN_METHODS:
        record(f"demo/{m}", sc, m, scene_config(sc))
    for i in range(n_scenes):
        s = make_scene(i, seed=777, params="paper100")
        base = scene_config(s)
        for m in ("mmd", "degroot", "saa"):
            record(f"s{i}/{m}", s, m, base)
        if i < 5:
            record(f"s{i}/mmd-linear", s, "mmd", base.replace(margin_mode="linear"))
            record(f"s{i}/mmd-rules", s, "mmd", base.replace(**RULES))
    return out


def compare(before: dict, after: dict) -> int:
    """Print the arrays that differ; returns their number (statuses listed apart)."""
    diff = 0
    for k in sorted(set(before) & set(after)):
        a, b = before[k], after[k]
        if np.array_equal(a, b):
            continue
        diff += 1
        if a.dtype.kind in "fc":
            print(f"{k}: max |Δ| = {np.max(np.abs(a - b)):.3g}")
        else:
            print(f"{k}: {a} -> {b}")
    print(f"{len(set(before) & set(after)) - diff} equal, {diff} different")
    return diff


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="the .npz to write")
    ap.add_argument("--scenes", type=int, default=40, help="tuning scenes (default 40)")
    ap.add_argument("--compare", help="an earlier fingerprint file to compare with")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    fp = fingerprints(args.scenes)
    np.savez(args.out, **fp)
    print(f"{len(fp)} arrays in {time.perf_counter() - t0:.0f} s -> {args.out}", file=sys.stderr)
    if args.compare:
        with np.load(args.compare) as before:
            compare(dict(before), fp)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
