"""Paper Fig. 5 (§IV-C): MMD-Opt vs the baselines on the synthetic multi-modal scenes.

A thin wrapper of the CLI (``mmdopt bench synthetic``), kept so that every benchmark question has
a script in ``benchmarks/``.  Same options, e.g.::

    python benchmarks/synthetic.py --scenes 100 --seed 0 --out results/synthetic
    # = mmdopt bench synthetic --scenes 100 --seed 0 --out results/synthetic

Writes ``OUT/results.csv`` (one row per scene and method), ``OUT/summary.json``,
``OUT/collision_free.png`` and ``OUT/scenes/*.json`` (resumable); prints the summary table.
Numbers and commands: ``docs/experiments/synthetic.md``.
"""

import sys

from mmdopt.bench.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", "synthetic", *sys.argv[1:]]))
