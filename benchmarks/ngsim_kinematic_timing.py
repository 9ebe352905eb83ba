"""Plan time of the kinematic additions on a recorded scene: ``ngsim_config()`` as shipped
(slip limit + yaw-aware footprint) against the same configuration with them off, in one run.

The measurement is :func:`mmdopt.bench.ngsim.timing.time_on_scenario` (the task and timings of
``python -m mmdopt.bench.ngsim.timing``), run once per configuration; this script adds the ratio
of the medians.

    python -m benchmarks.ngsim_kinematic_timing \\
        --scenario ../shared/data/ngsim_us101/USA_US101-10_1_T-1.xml --counts 10 --repeats 5
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mmdopt.bench.ngsim.timing import time_on_scenario

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
    try:
        rows = time_on_scenario(
            a.scenario, counts, methods=[a.method], predictor=a.predictor, repeats=a.repeats,
            configs=CONFIGS,
        )  # fmt: skip
    except ValueError as e:
        raise SystemExit(str(e)) from None
    res = {(r["config"], r["n_obstacles"]): r for r in rows}
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
