"""Risk-level variants of MMD-Opt on tuning scenes (never the validation seeds 0/1).

Each variant is a method, its risk ε (``mmdopt.risk.config_for_risk``) and config overrides applied
after the mapping (e.g. ``reselect=0`` to drop the re-selection pass, ``w_cover=0`` to drop the
coverage term).  Prints, per variant, the mean and minimum collision-free count of 1000 fresh
futures, the mean progress and the median plan time over the scenes.

    python -m benchmarks.risk_variants --n-samples 1000 --scenes 6 \\
        --variants "mmd:0.005;mmd:0.1;mmd:0.1:reselect=0;mmd:0.1:w_cover=0;saa:0.005;saa:0.02"
    python -m benchmarks.risk_variants --preset lanechange --scenes 30 \\
        --variants "mmd:0.001;mmd:0.001:reselect=20;degroot:0.001;saa:0.001"
    python -m benchmarks.risk_variants --preset cutin-low --obstacles 3 --forecast --scenes 8 \\
        --variants "mmd:0.005;mmd:0.005:nearest_repeats=0"

``--forecast`` plans through the scene's predictor (n(ε) futures per obstacle, as the frontier
does) instead of on its fixed samples; ``--obstacles`` overrides the preset's obstacle count.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from mmdopt.bench.scenes import PRESETS, make_scene
from mmdopt.bench.synthetic import run_scene
from mmdopt.risk import config_for_risk


def parse_variant(spec: str) -> tuple[str, float, dict]:
    """``method:eps[:field=value,...]`` -> (method, eps, overrides)."""
    parts = spec.strip().split(":")
    if len(parts) not in (2, 3):
        raise ValueError(f"variant {spec!r}: expected method:eps[:field=value,...]")
    over = {}
    if len(parts) == 3 and parts[2]:
        for kv in parts[2].split(","):
            k, v = kv.split("=")
            over[k.strip()] = int(v) if v.strip().lstrip("-").isdigit() else float(v)
    return parts[0].strip(), float(parts[1]), over


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="paper100", choices=sorted(PRESETS))
    ap.add_argument("--seed", type=int, default=777, help="tuning seed (not 0 or 1)")
    ap.add_argument("--scenes", type=int, default=6)
    ap.add_argument("--n-samples", type=int, default=None, help="planning samples per obstacle")
    ap.add_argument("--variants", required=True, help="';'-separated method:eps[:k=v,...]")
    ap.add_argument("--obstacles", type=int, default=None, help="obstacles (default: preset's)")
    ap.add_argument("--forecast", action="store_true", help="plan through the scene's predictor")
    args = ap.parse_args(argv)
    if args.seed in (0, 1):
        ap.error("seeds 0 and 1 are the validation seeds: tune on another one")
    params = PRESETS[args.preset]
    if args.n_samples is not None:
        params = dataclasses.replace(params, n_samples=args.n_samples)
    if args.obstacles is not None:
        params = dataclasses.replace(params, num_obstacles=args.obstacles)
    variants = [parse_variant(v) for v in args.variants.split(";") if v.strip()]
    rows: dict[int, list] = {i: [] for i in range(len(variants))}
    for s in range(args.scenes):
        scene = make_scene(s, args.seed, params)
        for i, (method, eps, over) in enumerate(variants):
            cfg = config_for_risk(method, eps).replace(**over)
            row, _ = run_scene(scene, method, config=cfg, forecast=args.forecast)
            rows[i].append((row["collision_free"], row["progress_m"], row["plan_time_s"]))
    print(f"{'variant':36s} {'mean cf':>8s} {'min cf':>7s} {'progress m':>11s} {'time s':>7s}")
    for i, spec in enumerate(v.strip() for v in args.variants.split(";") if v.strip()):
        a = np.asarray(rows[i])
        print(
            f"{spec:36s} {a[:, 0].mean():8.1f} {a[:, 0].min():7.0f} {a[:, 1].mean():11.1f} "
            f"{np.median(a[:, 2]):7.2f}"
        )


if __name__ == "__main__":
    main()
