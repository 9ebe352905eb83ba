"""Plan time against the number of obstacles on a recorded scene.

``python -m mmdopt.bench.ngsim.timing --scenario FILE.xml --out DIR [--counts 1,2,5,10,15]``
plans one task (the first ego of the scene with at least max(counts) vehicles in range) against
its c nearest vehicles for every c, prints first-call (with JIT compile) and median warm times,
and writes ``DIR/timing.json`` and ``DIR/timing.png``.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path

from .plot import timing_vs_obstacles_figure
from .runner import NgsimParams, build_task, ngsim_config, select_tasks, timing_vs_obstacles


def task_with_obstacles(scenario: Path, count: int, params: NgsimParams, cfg) -> dict | None:
    """The first task of ``scenario`` (:func:`select_tasks` order) with at least ``count``
    vehicles in range, or ``None``."""
    for t in select_tasks([scenario], params, cfg):
        if len(build_task(t, params, cfg)["obs"]) >= count:
            return t
    return None


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m mmdopt.bench.ngsim.timing")
    p.add_argument("--scenario", required=True, type=Path)
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--counts", default="1,2,5,10,15")
    p.add_argument("--methods", default="mmd,degroot")
    p.add_argument("--predictor", default="lane")
    p.add_argument("--repeats", type=int, default=3)
    a = p.parse_args(argv)
    counts = tuple(int(c) for c in a.counts.split(","))
    params = NgsimParams(max_obstacles=max(counts), egos_per_time=50)
    cfg = ngsim_config()
    task = task_with_obstacles(a.scenario, max(counts), params, cfg)
    if task is None:
        raise SystemExit(f"no ego in {a.scenario} has {max(counts)} vehicles within range")
    rows = []
    for m in a.methods.split(","):
        for r in timing_vs_obstacles(
            task, counts, predictor=a.predictor, method=m, repeats=a.repeats, params=params
        ):
            r.update(scenario=a.scenario.stem, ego_id=task["ego_id"], t0=task["t0"])
            print(json.dumps(r), flush=True)
            rows.append(r)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "timing.json").write_text(json.dumps(rows, indent=1))
    timing_vs_obstacles_figure(rows, a.out / "timing.png")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
