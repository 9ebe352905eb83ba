"""Is a junction crossing blocked by the futures or by the planner?

Drives MMD-Opt on the risk dial through ``bench highway`` episodes (``run_episode``, the
benchmark's own loop) and, at every replan, counts the planning futures that a plain "go"
would meet: from the ego's state, along its route at its lateral offset, accelerating at 1.5,
3 or 5 m/s² up to the lane's limit.  The count is the planner's own (``samples_met``: the
nominal ellipse, any step; the joint futures met with any car) on the very futures the plan was
made on.  Where no "go" ever gets a risk bound within ε, the crossing is closed by the
predicted futures themselves, whatever the planner searches; where some do and the ego still
waits, the search or the cost is at fault.

Prints, per episode: the replans, whether the ego arrived, the replans where some "go" has a
bound ≤ ε, the fewest joint futures any "go" met (and of how many), and the smallest bound a
"go" reached (the ε a crossing would have needed at best).

    python -m benchmarks.junction_gaps --env intersection-v2 --seed 72000 --episodes 2 \\
        --risk 0.001
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import frenet
from mmdopt.bench.highway.runner import (
    config_for_method,
    highway_config,
    risk_overrides,
    run_episode,
)
from mmdopt.bench.highway.settings import HighwaySettings, default_predictor
from mmdopt.counting import plan_bound, risk_counts, samples_met, to_planes

#: the accelerations (m/s²) of the "go" profiles
GO_ACCELERATIONS = (1.5, 3.0, 5.0)


def go_profiles(t: np.ndarray, v0: float, v_max: float) -> np.ndarray:
    """(G, K) arc lengths (m, from the ego) of "go" from speed ``v0``: each acceleration of
    :data:`GO_ACCELERATIONS` up to ``v_max``, then that speed."""
    out = []
    for a in GO_ACCELERATIONS:
        t_top = max(v_max - v0, 0.0) / a
        tt = np.minimum(t, t_top)
        out.append(v0 * tt + 0.5 * a * tt**2 + v_max * np.maximum(t - t_top, 0.0))
    return np.array(out)


def replan_gap(obs, plan) -> tuple[int, int, float]:
    """``(fewest joint futures met by a "go", futures per car, smallest "go" bound)`` of one
    replan (its observation with the drawn futures, and its plan)."""
    cfg = plan.config
    arr = np.ascontiguousarray(np.asarray(obs.obstacles, np.float64))
    if arr.shape[0] == 0:
        return 0, 0, 0.0
    s_off = float(obs.ego.s)
    path = obs.road.path  # converted as the planner converts them (float32 planes)
    planes = to_planes(arr, lambda b: path.to_frenet_points(b, s_off, tol=frenet.FLOAT32_TOL))
    obs_fr = planes.transpose(0, 3, 2, 1)
    s = go_profiles(np.asarray(plan.t, float), max(float(obs.ego.vs), 0.0), obs.road.v_max)
    d = np.full_like(s, float(obs.ego.d))
    met = samples_met(cfg, obs_fr, None, s, d)  # (G, O, n)
    counts = [int(risk_counts(cfg, m).sum()) for m in met]
    bounds = [plan_bound(cfg, m) for m in met]
    return min(counts), int(arr.shape[1]), float(min(bounds))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", default="intersection-v2")
    ap.add_argument("--seed", type=int, default=72000, help="the first episode's seed")
    ap.add_argument("--episodes", type=int, default=1)
    ap.add_argument("--risk", type=float, default=0.001, help="ε of the risk dial")
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds")
    ap.add_argument("--no-shield", action="store_true", help="drive without the shield")
    args = ap.parse_args(argv)
    settings = HighwaySettings(
        env=args.env,
        duration=args.duration,
        predictor=default_predictor(args.env),
        shield=not args.no_shield,
    )
    config = config_for_method("mmd", highway_config(risk_overrides({}, args.risk)))
    print(
        '| seed | replans | arrived | crashed | replans with a "go" within ε | fewest futures '
        'a "go" met | smallest "go" bound |'
    )
    print("|---|---|---|---|---|---|---|")
    for e in range(args.episodes):
        rows: list[tuple[int, int, float]] = []

        def record(i, obs, plan, outcome, rows=rows):
            rows.append(replan_gap(obs, plan))

        t0 = time.perf_counter()
        rec = run_episode(e, args.seed + e, "mmd", settings, config, callback=record)
        met = np.array([r[0] for r in rows])
        n = max((r[1] for r in rows), default=0)
        bounds = np.array([r[2] for r in rows])
        within = int(np.sum(bounds <= args.risk))
        print(
            f"| {args.seed + e} | {len(rows)} | {rec['arrived']} | {rec['crashed']} | {within} | "
            f"{int(met.min()) if met.size else '–'} of {n} | "
            f"{float(bounds.min()) if bounds.size else float('nan'):.3g} |"
        )
        print(f"<!-- {time.perf_counter() - t0:.0f} s -->")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
