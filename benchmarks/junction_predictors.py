"""Predictors at junctions: cv, route and learned on held-out highway-env rollouts of
``intersection-v2`` and ``roundabout-v1`` (seeds 0 … N−1; the benchmark's episodes use others),
scored as the highway predictors are (:func:`mmdopt.bench.highway.training.evaluate_live`: every
second, the six cars nearest to the ego, 5 s ahead on the planner's grid): minADE/minFDE@20 (m),
coverage within 2 m of the first 20 samples and the KDE NLL of 200.

    python -m benchmarks.junction_predictors --seeds 10 --duration 13
"""

from __future__ import annotations

import argparse
import time

from mmdopt.bench.highway.predictors import (
    ConstantVelocityPredictor,
    LearnedPredictor,
    RoutePredictor,
)
from mmdopt.bench.highway.training import evaluate_live

ENVS = ("intersection-v2", "roundabout-v1")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="held-out seeds 0 … N−1 per env")
    ap.add_argument("--duration", type=float, default=13.0, help="seconds per rollout")
    ap.add_argument("--envs", default=",".join(ENVS))
    args = ap.parse_args(argv)
    preds = {"cv": ConstantVelocityPredictor, "route": RoutePredictor, "learned": LearnedPredictor}
    print("| env (held-out seeds) | cars | predictor | minADE@20 (m) | minFDE@20 (m) | "
          "coverage (2 m) | KDE NLL |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    for env in args.envs.split(","):
        t0 = time.perf_counter()
        res = evaluate_live(preds, env, range(args.seeds), duration=args.duration)
        for name, r in res.items():
            print(
                f"| `{env}` (0–{args.seeds - 1}) | {r['n_vehicles']} | {name} | "
                f"{r['min_ade']:.2f} | {r['min_fde']:.2f} | {r['coverage']:.3f} | "
                f"{r['kde_nll']:.1f} |"
            )
        print(f"<!-- {env}: {time.perf_counter() - t0:.0f} s -->")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
