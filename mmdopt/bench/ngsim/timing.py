"""Plan time against the number of obstacles on a recorded scene.

``python -m mmdopt.bench.ngsim.timing --scenario FILE.xml --out DIR [--counts 1,2,5,10,15]``
plans one task (the first ego of the scene with at least max(counts) vehicles in range) against
its c nearest vehicles for every c, prints first-call (with JIT compile) and median warm times,
and writes ``DIR/timing.json`` and ``DIR/timing.png``.  :func:`time_on_scenario` is the
measurement (``benchmarks/ngsim_kinematic_timing.py`` times several configurations with it).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping, Sequence
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


def time_on_scenario(
    scenario: Path,
    counts: Sequence[int] = (1, 2, 5, 10, 15),
    *,
    methods: Sequence[str] = ("mmd", "degroot"),
    predictor: str = "lane",
    repeats: int = 3,
    configs: Mapping[str, dict] | None = None,
    echo: bool = True,
) -> list[dict]:
    """Plan time of one task of ``scenario`` (the first with at least ``max(counts)`` vehicles in
    range, chosen with :func:`ngsim_config`) against its c nearest vehicles for every c in
    ``counts``, per method (:func:`timing_vs_obstacles`); each row also names the scenario, ego
    and start time.  ``configs`` (name -> :func:`ngsim_config` overrides) times each
    configuration in turn, its name in the rows' ``config``; default: the shipped one, no
    ``config`` field.  ``echo`` prints each row as a JSON line as soon as it is measured.
    Raises ``ValueError`` for empty ``counts``, ``repeats < 1`` or a scenario without such a
    task."""
    counts = tuple(int(c) for c in counts)
    if not counts or min(counts) < 1:
        raise ValueError(f"counts must be positive integers, got {counts}")
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    params = NgsimParams(max_obstacles=max(counts), egos_per_time=50)
    task = task_with_obstacles(scenario, max(counts), params, ngsim_config())
    if task is None:
        raise ValueError(f"no ego in {scenario} has {max(counts)} vehicles within range")
    rows = []
    for name, over in (configs or {None: {}}).items():
        config = None if name is None else ngsim_config(**over)
        for m in methods:
            for r in timing_vs_obstacles(
                task, counts, predictor=predictor, method=m, repeats=repeats, params=params,
                config=config,
            ):  # fmt: skip
                if name is not None:
                    r.update(config=name)
                r.update(scenario=Path(scenario).stem, ego_id=task["ego_id"], t0=task["t0"])
                if echo:
                    print(json.dumps(r), flush=True)
                rows.append(r)
    return rows


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
    try:
        rows = time_on_scenario(
            a.scenario, counts, methods=a.methods.split(","), predictor=a.predictor,
            repeats=a.repeats,
        )  # fmt: skip
    except ValueError as e:
        raise SystemExit(str(e)) from None
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "timing.json").write_text(json.dumps(rows, indent=1))
    timing_vs_obstacles_figure(rows, a.out / "timing.png")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
