"""Plan time of the kinematic additions on a recorded scene: ``ngsim_config()`` as shipped
(slip limit + yaw-aware footprint) against the same configuration with them off, in one run.

For each configuration: the first call (JIT compile included) and the median of ``--repeats``
warm calls against the task's c nearest vehicles (``mmdopt.bench.ngsim.runner.timing_vs_obstacles``,
the same task as ``python -m mmdopt.bench.ngsim.timing``), and the ratio of the medians.

    python -m benchmarks.ngsim_kinematic_timing \\
        --scenario ../shared/data/ngsim_us101/USA_US101-10_1_T-1.xml --counts 10 --repeats 5
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from mmdopt.bench.ngsim.runner import NgsimParams, ngsim_config, timing_vs_obstacles
from mmdopt.bench.ngsim.timing import task_with_obstacles

CONFIGS = {
    "shipped": {},
    "no_yaw": dict(yaw_extent=0.0),
    "no_yaw_no_slip": dict(yaw_extent=0.0, slip_ratio=0.0),
}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", required=True, type=Path)
    ap.add_argument("--counts", default="10")
    ap.add_argument("--method", default="mmd")
    ap.add_argument("--predictor", default="lane")
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args(argv)
    counts = tuple(int(c) for c in a.counts.split(","))
    if a.repeats < 1:
        raise SystemExit("--repeats must be >= 1")
    params = NgsimParams(max_obstacles=max(counts), egos_per_time=50)
    cfg0 = ngsim_config()
    task = task_with_obstacles(a.scenario, max(counts), params, cfg0)
    if task is None:
        raise SystemExit(f"no ego in {a.scenario} has {max(counts)} vehicles within range")
    res = {}
    for name, over in CONFIGS.items():
        rows = timing_vs_obstacles(
            task,
            counts,
            predictor=a.predictor,
            method=a.method,
            repeats=a.repeats,
            params=params,
            config=ngsim_config(**over),
        )
        for r in rows:
            r.update(config=name, scenario=a.scenario.stem, ego_id=task["ego_id"])
            print(json.dumps(r), flush=True)
            res[(name, r["n_obstacles"])] = r
    for c in counts:
        if ("shipped", c) not in res:
            continue
        base = res[("shipped", c)]["median_s"]
        for name in CONFIGS:
            r = res[(name, c)]
            print(
                f"{c:3d} obstacles  {name:15s} first {r['first_s']:.2f} s  "
                f"median {r['median_s']:.3f} s  shipped / this {base / r['median_s']:.2f}"
            )


if __name__ == "__main__":
    main()
