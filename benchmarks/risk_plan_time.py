"""The price of certification: MMD-Opt's plan time at a small risk level through the scene's
predictor, against the same planner on 100 fixed samples at ε = 0.1, in the same run.

Plans ``--scenes`` scenes of ``--preset`` (seed ``--seed``; the first plan of each variant is
its compile and is left out) and prints, per variant, the median ``plan_time_s`` (the
predictor's draw apart), the futures per obstacle, the median of each stage from
``Plan.diagnostics`` and the ratio of the medians: the real-time bar is ≤ 3 at
ε = 10⁻³.

    python -m benchmarks.risk_plan_time --risk 0.001 --scenes 9
    python -m benchmarks.risk_plan_time --preset static-gaussian --obstacles 3 --scenes 9
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from mmdopt.bench.scenes import PRESETS, make_scene
from mmdopt.bench.synthetic import run_scene
from mmdopt.risk import config_for_risk

STAGES = ("frenet_conversion_s", "reduced_set_s", "margins_s", "nearest_s", "cem_s")


def _variant(preset: str, seed: int, scenes: int, method: str, risk: float, forecast: bool,
             n_samples: int | None, obstacles: int | None = None) -> dict:  # fmt: skip
    params = PRESETS[preset]
    if n_samples is not None:
        params = dataclasses.replace(params, n_samples=n_samples)
    if obstacles is not None:
        params = dataclasses.replace(params, num_obstacles=obstacles)
    cfg = config_for_risk(method, risk)
    rows = []
    for i in range(scenes):
        row, plan = run_scene(make_scene(i, seed, params), method, config=cfg, forecast=forecast)
        d = plan.diagnostics or {}
        rows.append({"plan_s": plan.plan_time_s, "n": row["n_planning"], "status": plan.status,
                     **{k: float(d.get(k, np.nan)) for k in STAGES}})  # fmt: skip
    warm = rows[1:]
    out = {k: float(np.median([r[k] for r in warm])) for k in ("plan_s", "n", *STAGES)}
    out["ok"] = sum(r["status"] == "ok" for r in warm)
    out["plans"] = len(warm)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="paper100", choices=sorted(PRESETS))
    ap.add_argument("--seed", type=int, default=777, help="777: the tuning scenes")
    ap.add_argument("--scenes", type=int, default=9, help="plans per variant (first: compile)")
    ap.add_argument("--risk", type=float, default=1e-3)
    ap.add_argument("--method", default="mmd")
    ap.add_argument("--obstacles", type=int, default=None, help="obstacles (default: preset's)")
    args = ap.parse_args(argv)
    if args.scenes < 2:
        ap.error("--scenes must be >= 2 (the first plan of each variant is its compile)")
    common = (args.preset, args.seed, args.scenes, args.method)
    peer = _variant(*common, 0.1, False, 100, args.obstacles)
    dial = _variant(*common, args.risk, True, None, args.obstacles)
    print(f"{'variant':34s} {'plan_s':>7s} {'futures':>8s} {'ok':>5s} "
          + " ".join(f"{k[:-2]:>17s}" for k in STAGES))  # fmt: skip
    for name, v in (("100 fixed samples, eps 0.1", peer),
                    (f"predictor, eps {args.risk:g}", dial)):  # fmt: skip
        print(f"{name:34s} {v['plan_s']:7.3f} {v['n']:8.0f} {v['ok']:2d}/{v['plans']:<2d} "
              + " ".join(f"{v[k]:17.3f}" for k in STAGES))  # fmt: skip
    print(
        f"ratio of median plan times: {dial['plan_s'] / peer['plan_s']:.2f} "
        f"(bar: <= 3, and <= 0.15 s at eps 1e-3)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
