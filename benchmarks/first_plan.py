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

``--xla-default`` runs every method a second time with XLA's default compile options for the
package's programs (``XLA_FLAGS=--xla_cpu_use_fusion_emitters=true``, :mod:`solvers.xla`) and
prints the package's options against them: first plan, compile seconds, steady state, and
whether every plan is bit for bit the same.

    python -m benchmarks.first_plan                        # mmd vs saa, 4 scenes, ε = 0.005
    python -m benchmarks.first_plan --scenes 6 --risk 0.001 --methods mmd,degroot
    python -m benchmarks.first_plan --methods mmd,saa --xla-default
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
        row, plan = run_scene(scene, args.child, config=cfg, forecast=True)
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
                plan_sha=hashlib.sha256(np.asarray(plan.x).tobytes()).hexdigest(),
            )
        )
    print("RESULT " + json.dumps(rows))


def _run_method(method: str, args, xla_default: bool = False) -> list[dict]:
    env = dict(os.environ)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)  # a cold start: every program compiles
    if xla_default:  # a flag the caller sets wins over solvers.xla.compile_options
        flags = env.get("XLA_FLAGS", "") + " --xla_cpu_use_fusion_emitters=true"
        env["XLA_FLAGS"] = flags.strip()
    cmd = [
        sys.executable, "-m", "benchmarks.first_plan", "--child", method,
        "--scenes", str(args.scenes), "--seed", str(args.seed), "--preset", args.preset,
        "--risk", str(args.risk),
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
        "--xla-default",
        action="store_true",
        help="also run each method with XLA's default compile options and print the ratios",
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
        f"ε = {args.risk:g}; {platform.machine()}, {os.cpu_count()} CPUs, no persistent cache"
    )
    variants = [("package", False)] + ([("XLA default", True)] if args.xla_default else [])
    print("method     options      futures  first plan  steady  Alg. 1 programs (s)  other (s)")
    out, shas = {}, {}
    for m in methods:
        for label, xla_default in variants:
            rows = _run_method(m, args, xla_default)
            r = rows[0]
            steady = float(np.median([x["wall_s"] for x in rows[1:]]))
            compile_s = r["alg1_compile_s"] + r["other_compile_s"]
            out[m, label] = (r["wall_s"], steady, compile_s)
            shas[m, label] = [x["plan_sha"] for x in rows]
            print(
                f"{m:10s} {label:12s} {r['n_futures']:7d} {r['wall_s']:9.1f} s {steady:6.2f} s "
                f"{r['alg1_programs']:9d} ({r['alg1_compile_s']:5.1f}) "
                f"{r['other_programs']:9d} ({r['other_compile_s']:5.1f})"
            )
    peer = methods[-1]
    for m in methods[:-1]:
        (f, s, _), (fp, sp, _) = out[m, "package"], out[peer, "package"]
        print(f"{m} / {peer}: first plan {f / fp:.2f}, steady state {s / sp:.2f}")
    if args.xla_default:
        for m in methods:
            (f, s, c), (fd, sd, cd) = out[m, "package"], out[m, "XLA default"]
            same = shas[m, "package"] == shas[m, "XLA default"]
            print(
                f"{m}: package options / XLA default: first plan {f / fd:.2f}, "
                f"compile {c / cd:.2f}, steady state {s / sd:.2f}; plans bit-identical: {same}"
            )


if __name__ == "__main__":
    main()
