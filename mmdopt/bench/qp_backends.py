"""QP backends on batches of projection QPs: time, accuracy, ratio to PIQP.

For each family of QPs sharing ``P``/``A`` and each backend, solve the whole batch with
``solvers.solve_batch`` and print one table per family: time per QP, whole-batch time, CPU time per
QP, max constraint violation, max objective gap to the reference (Clarabel at tight tolerances),
statuses, the ratio of the time per QP to ``qpsolvers:piqp`` measured in the same run, and — kept
apart from the solve time — the JIT compile time of the JAX backends (``ipm``, ``admm``: first
call minus a warm call).

Families
--------
``single``
    ``solvers.examples.projection_like_batch(B, horizon)``: one axis, ``n = horizon`` (100),
    ``m = 3·horizon`` (300): values, first and second differences, three boundary equalities.
``two-axis``
    :func:`two_axis_projection_batch`: the two-axis (longitudinal ``x``, lateral ``y``) waypoint
    projection, ``n = 2·horizon`` (200) and ``m = 8·horizon − 4`` (796) rows: per axis values
    (position box / lane), first differences (speed / lateral speed), second differences
    (per-axis acceleration) and three boundary equalities; coupled rows
    ``|Δ²x_k ± Δ²y_k| ≤ a_max Δt²`` (the acceleration-norm bound by an inscribed square, as
    ``frenet.ProjectionBounds(a_max=…)`` does with a polygon).  This is the projection QP of
    ``frenet.projection`` written in waypoint variables (a basis whose ``P`` is the identity),
    built explicitly so its size is set directly.

Settings are explicit and printed: ``ipm`` at its defaults (eps 1e-9), OSQP at eps 1e-6 with
polishing (set up once, then ``update`` + warm start); ``admm`` and every other backend at its
own defaults.

    python -m mmdopt bench qp-backends                      # both families, 1000 QPs each
    python -m mmdopt.bench.qp_backends --quick              # 100 QPs each
    python -m mmdopt.bench.qp_backends --family two-axis --backends ipm,qpsolvers:piqp
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

import numpy as np

from solvers import QPBatch, available_backends, get_backend, solve_batch
from solvers.examples import projection_like_batch

__all__ = ["REFERENCE", "SETTINGS", "FAMILIES", "two_axis_projection_batch", "run_family", "main"]

#: the reference: Clarabel at tight tolerances (the same as the tests' reference)
REFERENCE: dict[str, Any] = {
    "tol_gap_abs": 1e-12,
    "tol_gap_rel": 1e-14,
    "tol_feas": 1e-12,
    "tol_ktratio": 1e-10,
    "max_iter": 500,
}

#: explicit per-backend settings (others: the backend's own defaults)
SETTINGS: dict[str, dict[str, Any]] = {
    # interior point at its defaults, written out
    "ipm": {"eps_abs": 1e-9, "eps_rel": 1e-9},
    # admm at its defaults (float32 iterations in stages, a float64 polish between them)
    "admm": {},
    # OSQP at a tolerance that reaches a violation comparable to admm's (polishing on)
    "osqp": {"eps_abs": 1e-6, "eps_rel": 1e-6, "polishing": True, "max_iter": 100_000},
    "qpsolvers:osqp": {"eps_abs": 1e-6, "eps_rel": 1e-6, "polishing": True, "max_iter": 100_000},
}

#: the peer every time is divided by
PEER = "qpsolvers:piqp"
#: JAX backends: their first call compiles, timed separately
JAX_BACKENDS = ("ipm", "admm")
DEFAULT_BACKENDS = ("ipm", "qpsolvers:piqp", "clarabel", "osqp", "admm")


def _diff(n: int, order: int) -> np.ndarray:
    D = np.eye(n)
    for _ in range(order):
        D = D[1:] - D[:-1]
    return D


def two_axis_projection_batch(
    batch_size: int = 1000, horizon: int = 100, *, seed: int = 0, dt: float = 0.15
) -> QPBatch:
    """Two-axis waypoint projections sharing ``P = I`` and ``A``: ``n = 2N``, ``m = 8N − 4``.

    Variables ``(x_0…x_{N−1}, y_0…y_{N−1})`` (``N = horizon``); each QP projects a noisy target
    (``min ½‖z − t‖²``) onto: ``lo ≤ x_k ≤ hi``; ``−0.2Δt ≤ Δx_k ≤ v_max Δt``;
    ``|Δ²x_k| ≤ a_x Δt²``; ``x_0 = 0, Δx_0 = v_0Δt, Δ²x_0 = 0``; ``|y_k| ≤ w_lane``;
    ``|Δy_k| ≤ v_y Δt``; ``|Δ²y_k| ≤ a_y Δt²``; ``y_0 = d_0, Δy_0 = 0, Δ²y_0 = 0``; and the
    coupled ``|Δ²x_k ± Δ²y_k| ≤ a_max Δt²``.  Bounds and targets differ per QP (seeded).
    """
    if batch_size < 1 or horizon < 4:
        raise ValueError("batch_size must be ≥ 1 and horizon ≥ 4")
    rng = np.random.default_rng(seed)
    N = horizon
    I, D1, D2 = np.eye(N), _diff(N, 1), _diff(N, 2)
    Eb = np.zeros((3, N))
    Eb[0, 0] = 1.0
    Eb[1, :2] = [-1.0, 1.0]
    Eb[2, :3] = [1.0, -2.0, 1.0]
    blocks = [I, D1, D2, Eb]
    A = np.vstack(
        [np.hstack([M, np.zeros_like(M)]) for M in blocks]
        + [np.hstack([np.zeros_like(M), M]) for M in blocks]
        + [np.hstack([D2, D2]), np.hstack([D2, -D2])]
    )
    P = np.eye(2 * N)
    t = np.linspace(0.0, 1.0, N)
    a2 = dt * dt
    qs, ls, us = [], [], []
    for _ in range(batch_size):
        v0, vmax = rng.uniform(2.0, 8.0), rng.uniform(8.0, 12.0)
        ax, ay = rng.uniform(1.5, 4.0), rng.uniform(1.0, 3.0)
        amax = rng.uniform(0.8, 1.0) * np.hypot(ax, ay)
        vy, lane = rng.uniform(0.5, 2.0), rng.uniform(1.0, 2.5)
        d0 = rng.uniform(-0.5, 0.5) * lane

        def wiggle(scale: float) -> np.ndarray:
            return sum(
                rng.normal(0.0, scale) * np.sin((k + 1) * np.pi * t + rng.uniform(0.0, np.pi))
                for k in range(4)
            )

        base = v0 * dt * np.arange(N)
        tx = base + wiggle(3.0) + rng.normal(0.0, 0.3, N)
        ty = d0 + wiggle(1.5 * lane) + rng.normal(0.0, 0.2, N)
        hi_x = base[-1] * rng.uniform(0.7, 1.0) + 5.0
        lo_x = -rng.uniform(0.5, 2.0)
        lx = [
            np.full(N, lo_x),
            np.full(N - 1, -0.2 * dt),
            np.full(N - 2, -ax * a2),
            [0, v0 * dt, 0],
        ]
        ux = [np.full(N, hi_x), np.full(N - 1, vmax * dt), np.full(N - 2, ax * a2), [0, v0 * dt, 0]]
        ly = [np.full(N, -lane), np.full(N - 1, -vy * dt), np.full(N - 2, -ay * a2), [d0, 0, 0]]
        uy = [np.full(N, lane), np.full(N - 1, vy * dt), np.full(N - 2, ay * a2), [d0, 0, 0]]
        lc = np.full(2 * (N - 2), -amax * a2)
        qs.append(-np.concatenate([tx, ty]))
        ls.append(np.concatenate([*lx, *ly, lc]))
        us.append(np.concatenate([*ux, *uy, -lc]))
    return QPBatch(P, A, np.array(qs), np.array(ls), np.array(us))


FAMILIES = {
    "single": lambda B, horizon, seed: projection_like_batch(B, horizon, seed=seed),
    "two-axis": lambda B, horizon, seed: two_axis_projection_batch(B, horizon, seed=seed),
}


def _clear_cache(name: str) -> None:
    be = get_backend(name)
    for attr in ("_factors", "_setups"):
        cache = getattr(be, attr, None)
        if isinstance(cache, dict):
            cache.clear()


def run_family(
    family: str, batch: QPBatch, names: list[str], repeats: int = 1
) -> list[dict[str, Any]]:
    """Solve ``batch`` with every backend in ``names``; print progress; return one row each."""
    B = len(batch)
    t = time.perf_counter()
    ref = solve_batch(batch, "clarabel", **REFERENCE)
    t_ref = time.perf_counter() - t
    f_ref = ref.objective
    ok_ref = ref.solved
    print(
        f"[{family}] reference clarabel {REFERENCE}: {t_ref:.2f} s, {ref.status_counts()}",
        flush=True,
    )
    rows = []
    for name in names:
        settings = SETTINGS.get(name, {})
        try:
            get_backend(name)
        except Exception as exc:  # noqa: BLE001 - a benchmark reports and goes on
            print(f"  {name}: unavailable ({exc})")
            continue
        compile_s = float("nan")
        try:
            if name in JAX_BACKENDS:
                _clear_cache(name)  # the first call pays setup + XLA compile
                t = time.perf_counter()
                solve_batch(batch, name, **settings)
                t_cold = time.perf_counter() - t
                _clear_cache(name)  # time the host setup in the warm call too
            times, cpus = [], []
            for _ in range(max(1, repeats)):
                t, c = time.perf_counter(), time.process_time()
                sol = solve_batch(batch, name, **settings)
                times.append(time.perf_counter() - t)
                cpus.append(time.process_time() - c)
                if name in JAX_BACKENDS:
                    _clear_cache(name)
        except Exception as exc:  # noqa: BLE001
            print(f"  {name}: failed ({type(exc).__name__}: {exc})")
            continue
        total, cpu = min(times), min(cpus)
        if name in JAX_BACKENDS:
            compile_s = t_cold - total
        viol = float(np.nanmax(batch.constraint_violation(np.nan_to_num(sol.x))))
        gap_abs = np.abs(sol.objective - f_ref)
        rel = np.where(np.isfinite(gap_abs), gap_abs, np.inf) / np.maximum(1.0, np.abs(f_ref))
        gap = float(np.max(rel[ok_ref])) if ok_ref.any() else float("nan")
        row = dict(
            family=family,
            name=name,
            per_qp=total / B,
            total=total,
            times=times,
            cpu=cpu / B,
            viol=viol,
            gap=gap,
            solved=sol.n_solved,
            statuses=sol.status_counts(),
            compile=compile_s,
            iterations=int(np.max(sol.iterations)),
            settings=settings or "defaults",
            extras=sol.extras,
        )
        rows.append(row)
        runs = ", ".join(f"{x:.2f}" for x in times)
        print(
            f"  {name}: batch {runs} s, violation {viol:.1e}, gap {gap:.1e}, "
            f"solved {sol.n_solved}/{B}, max iterations {row['iterations']}",
            flush=True,
        )
    return rows


def _table(rows: list[dict[str, Any]], B: int) -> None:
    peer = next((r for r in rows if r["name"] == PEER), None)
    print(
        f"\n| backend | time/QP (ms) | batch (s) | CPU time/QP (ms) | max violation "
        f"| max obj. gap (rel) | solved | time ÷ {PEER} | JIT compile (s) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        ratio = f"{r['per_qp'] / peer['per_qp']:.2f}" if peer else "–"
        comp = f"{r['compile']:.1f}" if np.isfinite(r["compile"]) else "–"
        print(
            f"| {r['name']} | {1e3 * r['per_qp']:.3f} | {r['total']:.2f} | {1e3 * r['cpu']:.3f} "
            f"| {r['viol']:.1e} | {r['gap']:.1e} | {r['solved']}/{B} | {ratio} | {comp} |"
        )


def main(argv: list[str] | None = None) -> int:
    """Command line: ``mmdopt bench qp-backends [options]``; returns the exit status."""
    ap = argparse.ArgumentParser(
        prog="mmdopt bench qp-backends",
        description="QP backends on batches of projection QPs sharing P and A: time per QP, "
        "max violation, objective gap to Clarabel, ratio to qpsolvers:piqp (same run), JIT "
        "compile time of the JAX backends.",
    )
    ap.add_argument("--batch", type=int, default=1000, help="QPs per family (default 1000)")
    ap.add_argument("--horizon", type=int, default=100, help="steps per axis (default 100)")
    ap.add_argument(
        "--family",
        default="single,two-axis",
        help="comma-separated: single, two-axis (default both)",
    )
    ap.add_argument(
        "--backends",
        default=",".join(DEFAULT_BACKENDS),
        help=f"comma-separated names, or 'all' (default {','.join(DEFAULT_BACKENDS)})",
    )
    ap.add_argument("--quick", action="store_true", help="100 QPs per family")
    ap.add_argument("--repeats", type=int, default=1, help="warm runs per backend (min is shown)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.batch < 1 or args.horizon < 4 or args.repeats < 1:
        ap.error("--batch and --repeats must be ≥ 1 and --horizon ≥ 4")
    families = [f for f in args.family.split(",") if f]
    unknown = [f for f in families if f not in FAMILIES]
    if unknown:
        ap.error(f"unknown family {unknown}; choose from {sorted(FAMILIES)}")
    names = (
        available_backends()
        if args.backends == "all"
        else [s for s in args.backends.split(",") if s]
    )
    if PEER not in names:
        names.append(PEER)
    B = 100 if args.quick else args.batch
    print(
        f"# QP backends: {B} QPs per family, families {families}\n"
        f"load average at start: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs "
        "(wall-clock timings: other work on the machine inflates them; ratios within one run "
        "are the meaningful figures)\n"
    )
    all_rows = []
    for fam in families:
        batch = FAMILIES[fam](B, args.horizon, args.seed)
        print(f"\n## family {fam}: n = {batch.n}, m = {batch.m}, {B} QPs (shared P, A)")
        rows = run_family(fam, batch, names, args.repeats)
        _table(rows, B)
        all_rows.extend(rows)
    print(
        "\nobjective gap: |f − f_ref| / max(1, |f_ref|) over the QPs the reference solved; "
        "violation: max over the batch of max(l − Ax, Ax − u, 0); CPU time: process time (all "
        "threads) per QP; JIT compile: first call minus a warm call (setup included in both)."
    )
    print("\nsettings:")
    seen = set()
    for r in all_rows:
        if r["name"] not in seen:
            seen.add(r["name"])
            print(f"  {r['name']}: {r['settings']}")
    for r in all_rows:
        if r["name"] == "ipm":
            ex = r["extras"]
            print(
                f"ipm [{r['family']}]: linear solver {ex.get('linear_solver')} (half-bandwidth "
                f"{ex.get('bandwidth')}), max iterations {r['iterations']}, "
                f"{r['statuses']}"
            )
    print(f"load average at end: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
