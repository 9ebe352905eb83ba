"""The first plan of a process: what it compiles and how long that takes, against steady state.

A user's first ``mmdopt.plan`` call traces and compiles every program the plan needs; later calls
of the same sizes reuse them.  Each method runs in a fresh subprocess without JAX's persistent
compilation cache and plans the same scenes through the scene's predictor at one risk level (the
risk dial: for MMD-Opt its main pass, re-selection / tail passes and the nearest-futures pass).
Reported per method, with the ratio against the peer method (SAA by default) of the same run:

* the first plan's wall time and the median of the others (steady state),
* the XLA compilations of the first plan (count and seconds, from JAX's compile log): Algorithm
  1's programs (``_run_fixed``) apart from everything else (host-side helpers, selection,
  counts), so a helper that compiles op by op on the host shows up as many small programs.

``--xla-flags FLAGS`` runs every method a second time with ``FLAGS`` added to ``XLA_FLAGS`` and
prints that run against the first: first plan, compile seconds, steady state (the whole plan and
Algorithm 1 alone), and whether every plan is bit for bit the same.  For example XLA's CPU fusion
emitters off and LLVM at optimisation level 1, which the test suite uses to compile faster
(``tests/conftest.py``).

    python -m benchmarks.first_plan                        # mmd vs saa, 4 scenes, ε = 0.005
    python -m benchmarks.first_plan --scenes 6 --risk 0.001 --methods mmd,degroot
    python -m benchmarks.first_plan --xla-flags=--xla_cpu_use_fusion_emitters=false
    python -m benchmarks.first_plan --fixed --xla-flags=--xla_cpu_use_fusion_emitters=false
    python -m benchmarks.first_plan --fixed \
        --xla-flags="--xla_cpu_use_fusion_emitters=false --xla_backend_optimization_level=1"
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
import platform
import re
import subprocess
import sys
import time

_COMPILED = re.compile(r"Finished XLA compilation of (.*?) in ([0-9.eE+-]+) sec")


class _CompileLog(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.records: list[tuple[str, float]] = []

    def emit(self, record: logging.LogRecord) -> None:
        m = _COMPILED.search(record.getMessage())
        if m:
            self.records.append((m.group(1), float(m.group(2))))


def _child(args) -> None:
    import jax

    jax.config.update("jax_log_compiles", True)
    log = _CompileLog()
    logger = logging.getLogger("jax")
    logger.addHandler(log)
    logger.setLevel(logging.WARNING)
    logger.propagate = False  # the log is counted, not printed

    import numpy as np

    import mmdopt
    from mmdopt.bench.scenes import make_scene
    from mmdopt.bench.synthetic import run_scene

    cfg = mmdopt.MMDOptConfig().replace(risk=args.risk)
    rows = []
    for i in range(args.scenes):
        scene = make_scene(i, seed=args.seed, params=args.preset)
        n0 = len(log.records)
        t0 = time.perf_counter()
        row, plan = run_scene(scene, args.child, config=cfg, forecast=not args.fixed)
        wall = time.perf_counter() - t0
        rec = log.records[n0:]
        alg1 = [s for name, s in rec if "_run_fixed" in name]
        rows.append(
            dict(
                wall_s=wall,
                n_futures=int(row["n_planning"]),
                alg1_programs=len(alg1),
                alg1_compile_s=sum(alg1),
                other_programs=len(rec) - len(alg1),
                other_compile_s=sum(s for _, s in rec) - sum(alg1),
                cem_s=float(plan.diagnostics["cem_s"]),
                plan_sha=hashlib.sha256(np.asarray(plan.x).tobytes()).hexdigest(),
            )
        )
    print("RESULT " + json.dumps(rows))


def _run_method(method: str, args, xla_flags: str = "") -> list[dict]:
    env = dict(os.environ)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)  # a cold start: every program compiles
    if xla_flags:
        env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} {xla_flags}".strip()
    cmd = [
        sys.executable, "-m", "benchmarks.first_plan", "--child", method,
        "--scenes", str(args.scenes), "--seed", str(args.seed), "--preset", args.preset,
        "--risk", str(args.risk), *(["--fixed"] if args.fixed else []),
    ]  # fmt: skip
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        raise SystemExit(f"{method} failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
    return json.loads(lines[-1][len("RESULT ") :])


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--methods", default="mmd,saa", help="comma-separated; the last is the peer")
    p.add_argument("--scenes", type=int, default=4)
    p.add_argument("--seed", type=int, default=777)
    p.add_argument("--preset", default="paper100")
    p.add_argument("--risk", type=float, default=0.005)
    p.add_argument(
        "--xla-flags",
        default="",
        help="also run each method with these XLA_FLAGS added and print the ratios",
    )
    p.add_argument(
        "--fixed",
        action="store_true",
        help="plan on the scene's fixed samples instead of drawing n(ε) from its predictor",
    )
    p.add_argument("--child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.scenes < 2:
        p.error("--scenes must be >= 2 (the first plan and at least one steady-state plan)")
    if args.child:
        return _child(args)
    import numpy as np

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    print(
        f"# first plan of a cold process: {args.preset} seed {args.seed}, {args.scenes} scenes, "
        f"ε = {args.risk:g}, {'fixed samples' if args.fixed else 'through the predictor'}; "
        f"{platform.machine()}, {os.cpu_count()} CPUs, no persistent cache"
    )
    variants = [("as set", "")] + ([(args.xla_flags, args.xla_flags)] if args.xla_flags else [])
    print(
        "method     futures  first plan  steady (Alg. 1)  Alg. 1 programs (s)  other (s)  XLA_FLAGS"
    )
    out, shas = {}, {}
    for m in methods:
        for label, flags in variants:
            rows = _run_method(m, args, flags)
            r = rows[0]
            steady = float(np.median([x["wall_s"] for x in rows[1:]]))
            cem = float(np.median([x["cem_s"] for x in rows[1:]]))
            compile_s = r["alg1_compile_s"] + r["other_compile_s"]
            out[m, label] = (r["wall_s"], steady, cem, compile_s)
            shas[m, label] = [x["plan_sha"] for x in rows]
            print(
                f"{m:10s} {r['n_futures']:7d} {r['wall_s']:9.1f} s {steady:6.2f} s ({cem:5.3f}) "
                f"{r['alg1_programs']:9d} ({r['alg1_compile_s']:5.1f}) "
                f"{r['other_programs']:9d} ({r['other_compile_s']:5.1f})  {label}"
            )
    peer = methods[-1]
    for m in methods[:-1]:
        (f, s, _, _), (fp, sp, _, _) = out[m, "as set"], out[peer, "as set"]
        print(f"{m} / {peer}: first plan {f / fp:.2f}, steady state {s / sp:.2f}")
    if args.xla_flags:
        for m in methods:
            (f0, s0, a0, c0), (f1, s1, a1, c1) = out[m, "as set"], out[m, args.xla_flags]
            same = shas[m, "as set"] == shas[m, args.xla_flags]
            print(
                f"{m}: with {args.xla_flags} / without: first plan {f1 / f0:.2f}, "
                f"compile {c1 / c0:.2f}, steady state {s1 / s0:.2f}, Algorithm 1 {a1 / a0:.2f}; "
                f"plans bit-identical: {same}"
            )


if __name__ == "__main__":
    main()
