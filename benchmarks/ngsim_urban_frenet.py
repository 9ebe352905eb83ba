"""Frenet <-> Cartesian round trip of the recorded ego along its reference path on urban scenes.

    python -m benchmarks.ngsim_urban_frenet [--data DIR] [--every N]

For every N-th task (``select_tasks``) of each scene under ``--data`` (default
``../shared/data/ngsim_urban``): the ego's reference path (``ego_road_geometry``, the lanelets its
recorded car drives through), the recorded next 5 s mapped to Frenet and back; prints the largest
and median round-trip error (m), the largest offset of the recorded car from its path and how many
egos turn by more than 45 degrees in those 5 s.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mmdopt.bench.ngsim.runner import select_tasks
from mmdopt.bench.ngsim.scene import ego_road_geometry, load_scenario, scenario_files


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ngsim_urban"
    ap.add_argument("--data", default=str(default))
    ap.add_argument("--every", type=int, default=3)
    args = ap.parse_args()
    if args.every < 1:
        ap.error(f"argument --every: must be >= 1, got {args.every}")
    errs, offs, turns = [], [], 0
    for f in scenario_files([args.data]):
        sc = load_scenario(str(f))
        for t in select_tasks([f])[:: args.every]:
            v = int(np.flatnonzero(sc.ids == t["ego_id"])[0])
            path, _, _ = ego_road_geometry(sc, v, t["k"])
            rows = slice(t["k"], t["k"] + 51)
            xy, hd = sc.xy[v, rows], sc.heading[v, rows]
            xy, hd = xy[np.all(np.isfinite(xy), -1)], hd[np.isfinite(hd)]
            s, d = (np.asarray(a) for a in path.to_frenet(xy[:, 0], xy[:, 1]))
            x2, y2 = (np.asarray(a) for a in path.to_cartesian(s, d))
            errs.append(float(np.max(np.hypot(x2 - xy[:, 0], y2 - xy[:, 1]))))
            offs.append(float(np.max(np.abs(d))))
            turns += abs(np.angle(np.exp(1j * (hd[-1] - hd[0])))) > np.pi / 4
    print(
        f"{len(errs)} tasks: round trip max {max(errs):.2g} m, median {np.median(errs):.2g} m; "
        f"recorded ego at most {max(offs):.2f} m from its path; {turns} turn by > 45 deg"
    )


if __name__ == "__main__":
    main()
