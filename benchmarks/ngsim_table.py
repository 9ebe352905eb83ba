"""The results pages' table of a ``mmdopt bench ngsim`` folder: one Markdown row per method.

    python -m benchmarks.ngsim_table OUT [OUT ...]

Columns: tasks, at-fault collisions, any contact, feasible (no fallback), KS-feasible
(CommonRoad's checker), progress ÷ the human's (sums), per task min / median, tasks below 80 %
of the human, collision-free of the validation futures (mean), median plan time (s).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

NAMES = {"mmd": "MMD-Opt", "degroot": "de Groot", "reactive": "reactive (CommonRoad)"}


def rows(folder: str | Path) -> list[str]:
    r = list(csv.DictReader(open(Path(folder) / "results.csv")))
    out = []
    for m in dict.fromkeys(x["method"] for x in r):
        rr = [x for x in r if x["method"] == m]
        prog = np.array([float(x["progress_m"]) for x in rr])
        hum = np.array([float(x["recorded_progress_m"]) for x in rr])
        ratio = prog / np.maximum(hum, 0.1)

        def n(col: str, rr=rr) -> int:
            return sum(x[col] == "True" for x in rr)

        out.append(
            f"| {NAMES.get(m, m)} | {len(rr)} | {n('at_fault_collision')} | "
            f"{n('any_collision')} | {n('feasible')} | {n('cr_feasible')} | "
            f"{prog.sum() / hum.sum():.2f} | {ratio.min():.2f} / {np.median(ratio):.2f} | "
            f"{int(np.sum(prog < 0.8 * hum))} | "
            f"{np.mean([float(x['collision_free']) for x in rr]):.1f} | "
            f"{np.median([float(x['plan_time_s']) for x in rr]):.2f} |"
        )
    return out


HEADER = (
    "| method | tasks | at-fault | any contact | feasible | KS-feasible (checker) | progress ÷ "
    "human's (sum) | per task, min / median | tasks below 80 % | collision-free of 1000 "
    "futures (mean) | median plan time (s) |\n|---|---|---|---|---|---|---|---|---|---|---|"
)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="+", help="folders written by mmdopt bench ngsim")
    for f in ap.parse_args(argv).out:
        print(f"{f}\n{HEADER}")
        print("\n".join(rows(f)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
