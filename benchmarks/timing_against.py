"""Algorithm 1's time and first call against an earlier commit, in the same run.

A figure of ``mmdopt bench timing`` taken on another day cannot say whether the code got slower
or the machine was busier.  This script checks the commit ``--rev`` out into a temporary git
worktree and runs ``mmdopt bench timing`` (m = 20, n = 100, the paper's Algorithm 1) in turns
from it and from this checkout (the order alternating between rounds), each in a fresh process
without the persistent compilation cache (so the first call compiles), ``--rounds`` times, and
prints the medians and the ratios this checkout ÷ ``--rev``.  A ratio near 1 says the code did
not move; a slowdown shows as a ratio above 1 in every round.

    python -m benchmarks.timing_against --rev c4ea702
    python -m benchmarks.timing_against --rev HEAD~5 --rounds 3 --repeats 7
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
COLUMNS = ("algorithm1_s", "reduced_set_s", "compile_s", "plan_s", "plan_first_s")


def _timing(root: Path, out: Path, repeats: int) -> dict[str, float]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env.update(PYTHONPATH=str(root), MMDOPT_COMPILE_CACHE="0")
    cmd = [sys.executable, "-m", "mmdopt", "bench", "timing", "--sizes", "20", "--samples",
           "100", "--repeats", str(repeats), "--no-progress", "--out", str(out)]  # fmt: skip
    subprocess.run(cmd, cwd=root, env=env, check=True, capture_output=True, text=True)
    with open(out / "timing.csv", newline="") as f:
        row = next(csv.DictReader(f))
    return {k: float(row[k]) for k in COLUMNS if k in row}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rev", required=True, help="the earlier commit (any git revision)")
    ap.add_argument("--rounds", type=int, default=2, help="turns of each checkout (default 2)")
    ap.add_argument("--repeats", type=int, default=7, help="timed calls per turn (default 7)")
    args = ap.parse_args(argv)
    if args.rounds < 1 or args.repeats < 1:
        ap.error("--rounds and --repeats must be >= 1")
    with tempfile.TemporaryDirectory(prefix="mmdopt-rev-") as tmp:
        wt = Path(tmp) / "rev"
        subprocess.run(["git", "worktree", "add", "--detach", str(wt), args.rev], cwd=REPO,
                       check=True, capture_output=True)  # fmt: skip
        try:
            runs: dict[str, list[dict[str, float]]] = {"this": [], args.rev: []}
            for r in range(args.rounds):
                pair = ((args.rev, wt), ("this", REPO))
                # the order alternates between rounds (ABBA): a second process in a turn can
                # run slower than the first, and that must not read as a regression
                for name, root in pair if r % 2 == 0 else pair[::-1]:
                    out = Path(tmp) / f"{len(runs[name])}_{name.replace('/', '_')}"
                    runs[name].append(_timing(root, out, args.repeats))
                    print(f"round {r + 1} {name:>12s}: " + "  ".join(
                        f"{k} {v:.4f}" for k, v in runs[name][-1].items()), flush=True)  # fmt: skip
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(wt)], cwd=REPO,
                           capture_output=True)  # fmt: skip
    print(f"\nmedians over {args.rounds} rounds (this checkout / {args.rev} / ratio):")
    for k in runs["this"][0]:
        a = float(np.median([r[k] for r in runs["this"]]))
        b = float(np.median([r[k] for r in runs[args.rev]]))
        print(f"  {k:14s} {a:9.4f} {b:9.4f} {a / b:6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
