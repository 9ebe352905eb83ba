"""OSQP at its defaults on a folder of Maros–Meszaros ``.mat`` files: status, distance to the
optimum and the confirmation of inaccurate answers (:func:`solvers.check.confirm_inaccurate`).

The reference optimum is Clarabel's at 1e-9 (``None`` where it does not solve).  A line is
flagged ``WRONG`` when the status is ``SOLVED`` or ``SOLVED_INACCURATE`` and the objective is
more than ``--far`` (relative to ``max(1, |f*|)``) from the reference.

    python -m benchmarks.mm_confirm DIR   # qpsolvers/maros_meszaros_qpbenchmark's data/
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from pathlib import Path

import numpy as np
import scipy.io as sio
import scipy.sparse as sp

from solvers import QP, Status, solve


def load(path: Path) -> QP:
    m = sio.loadmat(path)
    P = sp.csc_matrix(m["P"], dtype=np.float64)
    vec = lambda k: np.asarray(m[k], dtype=np.float64).reshape(-1)  # noqa: E731
    return QP((P + P.T) / 2, vec("q"), sp.csc_matrix(m["A"], dtype=np.float64), vec("l"), vec("u"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--backend", default="osqp")
    ap.add_argument("--far", type=float, default=1e-2)
    args = ap.parse_args(argv)
    files = sorted(f for f in args.folder.glob("*.mat") if f.stem != "VALUES")
    if not files:
        ap.error(f"no .mat files in {args.folder}")
    outcomes, wrong = Counter(), []
    for f in files:
        qp = load(f)
        ref = solve(qp, "clarabel", eps_abs=1e-9, eps_rel=1e-9)
        f_star = float(ref.objective) if ref.status is Status.SOLVED else None
        t0 = time.perf_counter()
        sol = solve(qp, args.backend)
        dt = time.perf_counter() - t0
        err = float("nan")
        if f_star is not None and np.isfinite(sol.objective):
            err = abs(float(sol.objective) - f_star) / max(1.0, abs(f_star))
        c = sol.extras.get("confirm")
        if c is not None and "result" in c:
            outcomes[c["result"]] += 1
        flag = sol.status in (Status.SOLVED, Status.SOLVED_INACCURATE) and err > args.far
        if flag:
            wrong.append(f.stem)
        conf = f"confirm: {c['result']} ({c.get('status', '-')})" if c else ""
        print(f"{f.stem:10s} {sol.status.name:18s} err {err:8.1e} {dt:6.2f} s {conf}"
              f"{'  WRONG' if flag else ''}", flush=True)  # fmt: skip
    print(f"\n{len(files)} problems; confirmations: {dict(outcomes)}; "
          f"SOLVED/SOLVED_INACCURATE more than {args.far:g} off: {len(wrong)} {wrong}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
