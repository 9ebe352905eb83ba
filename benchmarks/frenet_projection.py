"""Frenet layer benchmark: planner closed form, basis fidelity, projection on every backend.

Paper sizes (T = 15 s, K = 100), the reference planner (4 segments, k_p = k_v = 2) and the
reference sampler (d ~ N(0, diag(14,14,14,14,23,23,23,23)), speeds clipped to [0.1, 30]).

Prints four tables (markdown):

1. closed-form planner, 1000 behavioural inputs: compile time and steady-state time per batch;
2. basis fidelity: how well each Bernstein degree reproduces the exact triple-integrator plans;
3. projection QP through ``solvers`` on every available backend: time per 1000 projections,
   max violation, objective gap to Clarabel (grid rows and control-point "hull" rows);
4. the jittable projector (fixed ADMM iterations): time per 1000 and residuals.

Usage::

    python benchmarks/frenet_projection.py                  # everything (~10 min on 2 cores)
    python benchmarks/frenet_projection.py --quick          # smaller batches
    python benchmarks/frenet_projection.py --only planner,basis
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import jax  # noqa: E402

import solvers  # noqa: E402
from frenet import (  # noqa: E402
    BehaviouralPlanner,
    BernsteinBasis,
    EgoState,
    ProjectionProblem,
    TimeGrid,
    TripleIntegratorBasis,
)

GRID = TimeGrid(15.0, 100)
STATE = EgoState(s=0.0, d=0.0, vs=10.0, vd=0.0, as_=0.0, ad=0.0)


def reference_d(num: int, seed: int = 0) -> np.ndarray:
    """The reference sampler's initial batch, last 10 rows zero as in the reference code."""
    rng = np.random.default_rng(seed)
    cov = np.diag([14.0] * 4 + [23.0] * 4)
    d = rng.multivariate_normal(np.zeros(8), cov, size=num)
    d[:, :4] = np.clip(d[:, :4], 0.1, 30.0)
    d[-10:] = 0.0
    return d


def timeit(fn, reps: int = 5) -> float:
    best = np.inf
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def bench_planner(num: int) -> None:
    print(f"\n### Closed-form planner, {num} behavioural inputs (one matrix product)\n")
    print("| basis | nvar | dtype | compile + first call (s) | steady state per batch (ms) |")
    print("|---|---|---|---|---|")
    d = reference_d(num)
    for basis in (TripleIntegratorBasis(GRID), BernsteinBasis(GRID, 10), BernsteinBasis(GRID, 12)):
        planner = BehaviouralPlanner(basis)
        for dt in (np.float64, np.float32):
            with jax.enable_x64(dt == np.float64):
                fn = planner.closed_form_fn(dt)
                dd, ss = d.astype(dt), STATE.as_array().astype(dt)
                t = time.perf_counter()
                jax.block_until_ready(fn(dd, ss))
                first = time.perf_counter() - t
                steady = timeit(lambda fn=fn, dd=dd, ss=ss: jax.block_until_ready(fn(dd, ss)), 20)
            name = basis.name + (f" deg {basis.degree}" if hasattr(basis, "degree") else "")
            print(
                f"| {name} | {basis.nvar} | {np.dtype(dt).name} | {first:.3f} | "
                f"{1e3 * steady:.2f} |"
            )


def bench_basis(num: int) -> None:
    print(
        f"\n### Basis fidelity: Bernstein plans vs the exact triple-integrator plans ({num} d's)\n"
    )
    print(
        "| degree | nvar | max abs x (m) | median max abs x (m) | max abs vx (m/s) "
        "| max abs y (m) | median max abs y (m) | max abs vy (m/s) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    d = reference_d(num)
    ref = BehaviouralPlanner(TripleIntegratorBasis(GRID))
    tr0 = ref.trajectories(*ref.closed_form(d, STATE))
    for deg in (6, 8, 10, 12, 15, 20):
        pl = BehaviouralPlanner(BernsteinBasis(GRID, deg))
        tr = pl.trajectories(*pl.closed_form(d, STATE))
        ex, ey = np.abs(tr.x - tr0.x), np.abs(tr.y - tr0.y)
        print(
            f"| {deg} | {deg + 1} | {ex.max():.3f} | {np.median(ex.max(1)):.3f} | "
            f"{np.abs(tr.vx - tr0.vx).max():.3f} | {ey.max():.3f} | {np.median(ey.max(1)):.3f} | "
            f"{np.abs(tr.vy - tr0.vy).max():.3f} |"
        )


def _caps(backend: str, num: int, quick: bool) -> int:
    if backend == "cvxpy":
        return min(num, 10 if quick else 20)
    if backend.startswith("qpsolvers:"):
        return min(num, 20 if quick else 100)
    return num


def bench_projection(num: int, quick: bool, backends: list[str]) -> None:
    print(f"\n### Projection QP through `solvers`, up to {num} samples per backend\n")
    print(
        "Time per 1000 is extrapolated linearly where fewer problems were run (column n).  "
        "Gap = objective − Clarabel's on the same samples (½‖P(c − c̄)‖², m²); violation = "
        "max over samples of the max constraint violation at the grid steps.\n"
    )
    print(
        "| basis | rows | backend | n | s per 1000 | statuses | max violation | "
        "median gap | max abs gap |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    d = reference_d(num, seed=1)
    cases = [
        ("bernstein deg 10", BernsteinBasis(GRID, 10), "grid"),
        ("bernstein deg 10", BernsteinBasis(GRID, 10), "hull"),
        ("triple integrator", TripleIntegratorBasis(GRID), "grid"),
    ]
    for name, basis, rows in cases:
        planner = BehaviouralPlanner(basis)
        cx, cy = map(np.asarray, planner.closed_form(d, STATE))
        prob = ProjectionProblem(basis, constraint_points=rows)
        ti = basis.name == "triple_integrator"
        n_ref = min(num, 50 if ti else num)
        ref = prob.project(cx[:n_ref], cy[:n_ref], STATE, backend="clarabel")
        for be in backends:
            n = min(_caps(be, num, quick), n_ref if ti else num)
            if ti and be in ("cvxpy",) or (ti and be.startswith("qpsolvers:")):
                continue
            kw = {}
            try:
                if be == "admm":  # exclude the jit compile (reported separately below)
                    prob.project(cx[:n], cy[:n], STATE, backend=be)
                t = time.perf_counter()
                res = prob.project(cx[:n], cy[:n], STATE, backend=be, **kw)
                dt = time.perf_counter() - t
            except Exception as exc:  # a backend failing is a result, not a crash
                print(
                    f"| {name} | {rows} | {be} | {n} | – | error: {type(exc).__name__}: "
                    f"{str(exc)[:60]} | | | |"
                )
                continue
            m = min(n, n_ref)
            gap = res.distance[:m] - ref.distance[:m]
            counts = res.solution.status_counts()
            st = ", ".join(f"{k} {v}" for k, v in counts.items())
            print(
                f"| {name} | {rows} ({prob.num_rows}) | {be} | {n} | {dt * 1000 / n:.2f} | "
                f"{st} | "
                f"{res.residual.max():.1e} | {np.median(gap):.1e} | {np.abs(gap).max():.1e} |"
            )
        sys.stdout.flush()


def bench_jax_projector(num: int) -> None:
    try:
        from solvers.admm import admm_iterate  # noqa: F401
    except ImportError:
        print("\n(jittable projector skipped: solvers.admm functional core not available)")
        return
    print(f"\n### Jittable projector (ADMM, fixed iterations, float32, no polish), {num} samples\n")
    print(
        "| basis | rows | iterations | compile (s) | steady per batch (ms) | median residual | "
        "max residual | median gap to Clarabel (m²) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    d = reference_d(num, seed=2)
    basis = BernsteinBasis(GRID, 10)
    planner = BehaviouralPlanner(basis)
    cx, cy = map(np.asarray, planner.closed_form(d, STATE))
    st = STATE.as_array()
    for rows in ("hull", "grid"):
        prob = ProjectionProblem(basis, constraint_points=rows)
        ref = prob.project(cx[:200], cy[:200], STATE, backend="clarabel")
        for iters in (10, 25, 50, 100):
            fn = jax.jit(prob.jax_projector(iters))
            t = time.perf_counter()
            out = jax.block_until_ready(fn(cx, cy, st))
            first = time.perf_counter() - t
            steady = timeit(lambda fn=fn: jax.block_until_ready(fn(cx, cy, st)), 3)
            r = np.asarray(out.residual)
            gap = (
                prob.distance(
                    np.asarray(out.cx[:200], float),
                    np.asarray(out.cy[:200], float),
                    cx[:200],
                    cy[:200],
                )
                - ref.distance
            )
            print(
                f"| deg 10 | {rows} ({prob.num_rows}) | {iters} | {first:.1f} | "
                f"{1e3 * steady:.0f} | {np.median(r):.1e} | {r.max():.1e} | "
                f"{np.median(gap):.2g} |"
            )
            sys.stdout.flush()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="smaller batches")
    ap.add_argument(
        "--only",
        default="planner,basis,projection,jax",
        help="comma-separated subset of planner,basis,projection,jax",
    )
    ap.add_argument("--backends", default=None, help="comma-separated backends (default: all)")
    args = ap.parse_args()
    only = set(args.only.split(","))
    num = 200 if args.quick else 1000
    backends = args.backends.split(",") if args.backends else solvers.available_backends()
    print(
        f"jax {jax.__version__}, devices {jax.devices()}, cpu count {os.cpu_count()}, "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    if "planner" in only:
        bench_planner(num)
    if "basis" in only:
        bench_basis(num)
    if "projection" in only:
        bench_projection(num, args.quick, backends)
    if "jax" in only:
        bench_jax_projector(num)


if __name__ == "__main__":
    main()
