"""Where a plan's time goes, per method, at a given number of planning samples.

Plans ``--scenes`` synthetic scenes (tuning seed by default) with every variant, one process,
and prints the medians of ``Plan.plan_time_s`` and of its stages from ``Plan.diagnostics``
(Frenet conversion, reduced-set selection, coverage margins, Algorithm 1 including the
re-selection pass), the first plan of each variant (its compile) excluded, and each variant's
plan time as a ratio to the peer's (``--peer``, default the last variant) in the same run.

    python -m benchmarks.plan_stages --n-samples 1000 --scenes 8 \\
        --variants "mmd:0.02;mmd:0.02:reduced_set_size=40,coverage_knn=50;saa:0.02"
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from benchmarks.risk_variants import parse_variant
from mmdopt.bench.scenes import PRESETS, make_scene
from mmdopt.bench.synthetic import run_scene
from mmdopt.risk import config_for_risk

STAGES = ("frenet_conversion_s", "reduced_set_s", "margins_s", "cem_s")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="paper100", choices=sorted(PRESETS))
    ap.add_argument("--seed", type=int, default=777)
    ap.add_argument("--scenes", type=int, default=8, help="plans per variant (first: compile)")
    ap.add_argument("--n-samples", type=int, default=1000, help="planning samples per obstacle")
    ap.add_argument("--variants", required=True, help="';'-separated method:eps[:k=v,...]")
    ap.add_argument("--peer", type=int, default=-1, help="index of the peer variant")
    args = ap.parse_args(argv)
    if args.scenes < 2:
        ap.error("--scenes must be >= 2 (the first plan of each variant is its compile)")
    params = dataclasses.replace(PRESETS[args.preset], n_samples=args.n_samples)
    specs = [v.strip() for v in args.variants.split(";") if v.strip()]
    variants = [parse_variant(v) for v in specs]
    rows: list[list] = [[] for _ in variants]
    for s in range(args.scenes):
        scene = make_scene(s, args.seed, params)
        for i, (method, eps, over) in enumerate(variants):
            row, plan = run_scene(
                scene, method, config=config_for_risk(method, eps).replace(**over)
            )
            d = plan.diagnostics
            rows[i].append(
                [row["collision_free"], row["progress_m"], plan.plan_time_s]
                + [float(d.get(k, 0.0)) for k in STAGES]
            )
    med = [np.median(np.asarray(r[1:]), axis=0) for r in rows]  # first plan: compile
    peer = med[args.peer][2]
    print(
        f"n = {args.n_samples} planning samples, {args.scenes - 1} plans per variant "
        f"(medians, s); ratio: plan time / that of {specs[args.peer]!r}"
    )
    head = ["variant", "cf", "prog m", "plan", "frenet", "select", "margins", "alg1", "ratio"]
    print(f"{head[0]:52s}" + "".join(f"{h:>8s}" for h in head[1:]))
    for spec, r, m in zip(specs, rows, med, strict=True):
        a = np.asarray(r)
        vals = [a[:, 0].mean(), a[:, 1].mean(), *m[2:], m[2] / peer]
        print(
            f"{spec:52s}"
            + "".join(f"{v:8.3f}" if j > 1 else f"{v:8.1f}" for j, v in enumerate(vals))
        )


if __name__ == "__main__":
    main()
