"""``ipm`` on projection QP families it was not tuned for, against PIQP and Clarabel.

The families of ``mmdopt bench qp-backends`` are the team's own (Bernstein coefficients, or
waypoints in ``[x…, y…]`` order with every row finite).  These two are built differently, as a
user's projection would be:

``positions``
    Waypoint positions interleaved ``(x_0, y_0, x_1, y_1, …)``, ``N = 100`` steps, ``n = 200``,
    ``m = 796``.  ``P`` tracks a target with unequal axis weights plus a second-difference
    smoother (banded, not the identity).  Rows: the ``x_k`` values (free except an obstacle window
    ``x_k ≤ s_obs`` of ten steps), a narrowing lane ``|y_k| ≤ w_k``, ``0 ≤ Δx_k ≤ v_max Δt``,
    ``|Δy_k| ≤ v_y Δt`` (free past the middle of the horizon in half of the QPs), per-axis
    ``|Δ²·| ≤ a Δt²``, the coupled ``|Δ²x_k ± Δ²y_k| ≤ a_max Δt²`` (free in half of the QPs) and
    six initial-state equalities.  About a third of the rows are free (both bounds infinite).
``coupled``
    ``[x…, y…]`` order, ``N = 80``, ``n = 160``, ``m = 714``.  ``P`` tracks a target plus a jerk
    smoother.  Rows: two halfspaces per step ``n_k·(x_k, y_k) ≤ c_k`` (a corridor along a curving
    road: each row couples the two axes, 80 columns apart before reordering), the velocity rows
    ``|Δx_k ± Δy_k| ≤ v Δt``, per-axis acceleration ``|Δ²·|`` and jerk ``|Δ³·|`` bounds,
    progress rows ``x_k ≥ s_k`` (finite at one step in five, free elsewhere) and six
    initial-state equalities.
``blocks``
    ``[x…, y…]`` order (the two axes in blocks), ``N = 100``, ``n = 200``, ``m = 598``.  ``P``
    tracks a target (unequal axis weights) plus a second-difference smoother.  Rows: two-sided
    bounds on every ``x_k``, ``y_k``, velocity ``Δx_k``, ``Δy_k`` and acceleration ``Δ²x_k``,
    ``Δ²y_k`` rows, four initial-state equalities (position and velocity of each axis).
``blocks-coupled``
    The same blocks, ``N = 80``, ``n = 160``, ``m = 730``: velocity and acceleration rows, the
    coupled ``Δ²x_k ± Δ²y_k``, jerk ``Δ³x_k``, ``Δ³y_k`` (tight), two halfspaces
    ``±n_k·(x_k, y_k) ≤ c_k`` on 50 of the steps (a corridor whose walls turn with the road) and
    six initial-state equalities.

``--dense`` passes ``P`` and ``A`` of the two ``blocks`` families as dense NumPy arrays, as a
user building them with ``np.vstack`` would; ``--shuffle`` permutes the variables and the rows
of every family (seeded by ``--seed``) before solving, the same QPs numbered differently.

Every QP of a family shares ``P`` and ``A`` (``scipy.sparse``, as a user with this structure
passes them: the sparse solvers then see only the nonzeros); ``q``, ``l``, ``u`` differ
(seeded).  Bounds are set around a smooth reference that satisfies every row with a margin, so
each QP is feasible; targets are the reference plus smooth deviations and noise, so many rows
are active.  Each backend solves the whole batch
with ``solvers.solve_batch`` (:func:`mmdopt.bench.qp_backends.run_family`: time per QP, max
violation, max objective gap to Clarabel at tolerance 1e-12, ratio to ``qpsolvers:piqp`` in the
same run).

::

    python -m benchmarks.qp_families                               # both, 1000 QPs each
    python -m benchmarks.qp_families --family positions --batch 200 --backends ipm
    python -m benchmarks.qp_families --family blocks --backends admm,osqp --shuffle
"""

from __future__ import annotations

import argparse
import os

import numpy as np
import scipy.sparse as sp

from mmdopt.bench.qp_backends import PEER, SETTINGS, run_family
from solvers import QPBatch

__all__ = [
    "positions_batch",
    "coupled_batch",
    "blocks_batch",
    "blocks_coupled_batch",
    "shuffled",
    "FAMILIES",
    "main",
]


def _diff(n: int, order: int) -> np.ndarray:
    D = np.eye(n)
    for _ in range(order):
        D = D[1:] - D[:-1]
    return D


def _rows_between(ref: np.ndarray, rng: np.random.Generator, lo: float, hi: float, floor: float):
    """Two-sided bounds around ``ref``: a margin in ``[lo, hi]`` times ``floor`` each side."""
    return (
        ref - floor * rng.uniform(lo, hi, ref.shape),
        ref + floor * rng.uniform(lo, hi, ref.shape),
    )


def _wiggle(rng: np.random.Generator, t: np.ndarray, scale: float, noise: float) -> np.ndarray:
    """A smooth random deviation (four sines of random phase) plus white noise."""
    T = t[-1] if t[-1] > 0 else 1.0
    smooth = sum(
        rng.normal(0.0, scale) * np.sin((k + 1) * np.pi * t / T + rng.uniform(0.0, np.pi))
        for k in range(4)
    )
    return smooth + rng.normal(0.0, noise, t.shape)


def positions_batch(batch_size: int = 1000, horizon: int = 100, *, seed: int = 0) -> QPBatch:
    """The ``positions`` family (module docstring): ``n = 2N``, ``m = 8N − 4``."""
    if batch_size < 1 or horizon < 8:
        raise ValueError("batch_size must be ≥ 1 and horizon ≥ 8")
    N, dt = horizon, 0.1
    rng = np.random.default_rng(seed)
    Sx, Sy = np.zeros((N, 2 * N)), np.zeros((N, 2 * N))
    Sx[np.arange(N), 2 * np.arange(N)] = 1.0  # interleaved variables
    Sy[np.arange(N), 2 * np.arange(N) + 1] = 1.0
    D1, D2 = _diff(N, 1), _diff(N, 2)
    A = np.vstack(
        [Sx, Sy, D1 @ Sx, D1 @ Sy, D2 @ Sx, D2 @ Sy, D2 @ Sx + D2 @ Sy, D2 @ Sx - D2 @ Sy]
        + [Sx[:1], Sy[:1], (D1 @ Sx)[:1], (D1 @ Sy)[:1], (D2 @ Sx)[:1], (D2 @ Sy)[:1]]
    )
    wx, wy, lam = 1.0, 4.0, 0.5
    W = np.diag(np.tile([wx, wy], N))
    P = W + lam * ((D2 @ Sx).T @ (D2 @ Sx) + (D2 @ Sy).T @ (D2 @ Sy))
    t = np.arange(N) * dt
    inf = np.inf
    qs, ls, us = [], [], []
    for _ in range(batch_size):
        v0, acc = rng.uniform(4.0, 10.0), rng.uniform(-0.5, 0.5)
        amp, freq = rng.uniform(0.2, 0.8), rng.uniform(0.3, 1.0)
        rx = v0 * t + 0.5 * acc * t**2
        ry = amp * np.sin(freq * t + rng.uniform(0.0, np.pi))
        ref = np.stack([rx, ry], axis=1).reshape(-1)
        Ar = A @ ref
        lx, ux = np.full(N, -inf), np.full(N, inf)
        k0 = rng.integers(20, N - 10)
        ux[k0 : k0 + 10] = rx[k0 : k0 + 10] + rng.uniform(0.2, 1.0)  # obstacle ahead
        lane = np.abs(ry).max() + rng.uniform(0.05, 0.3) + np.linspace(0.5, 0.0, N)
        ly, uy = -lane, lane
        dx = Ar[2 * N : 3 * N - 1]
        ldx, udx = np.zeros(N - 1), np.full(N - 1, max(dx.max(), 0.0) + rng.uniform(0.05, 0.3))
        ldy, udy = _rows_between(Ar[3 * N - 1 : 4 * N - 2], rng, 0.5, 2.0, 0.05)
        if rng.random() < 0.5:  # lateral speed free in the second half
            ldy[N // 2 :], udy[N // 2 :] = -inf, inf
        rest = Ar[4 * N - 2 : 8 * N - 10]
        la, ua = _rows_between(rest, rng, 0.5, 2.0, 0.02)
        if rng.random() < 0.5:  # no coupled acceleration rows in this QP
            la[2 * (N - 2) :], ua[2 * (N - 2) :] = -inf, inf
        eq = Ar[8 * N - 10 :]
        noise = np.stack([_wiggle(rng, t, 2.0, 0.2), _wiggle(rng, t, 1.0, 0.1)], axis=1)
        target = ref + noise.reshape(-1) + np.tile([rng.uniform(0.0, 3.0), 0.0], N)
        qs.append(-W @ target)
        ls.append(np.concatenate([lx, ly, ldx, ldy, la, eq]))
        us.append(np.concatenate([ux, uy, udx, udy, ua, eq]))
    return QPBatch(sp.csc_matrix(P), sp.csc_matrix(A), np.array(qs), np.array(ls), np.array(us))


def coupled_batch(batch_size: int = 1000, horizon: int = 80, *, seed: int = 0) -> QPBatch:
    """The ``coupled`` family (module docstring): ``n = 2N``, ``m = 9N − 6``."""
    N, dt, rng, X, Y = _two_axes(batch_size, horizon, seed)
    D1, D2, D3 = _diff(N, 1), _diff(N, 2), _diff(N, 3)
    t = np.arange(N) * dt
    # corridor along a road of constant curvature: unit normals rotate with the heading
    heading = 0.25 * t
    nx, ny = -np.sin(heading), np.cos(heading)
    H = np.vstack([nx[:, None] * X + ny[:, None] * Y, -(nx[:, None] * X + ny[:, None] * Y)])
    A = np.vstack(
        [H, D1 @ X + D1 @ Y, D1 @ X - D1 @ Y, D2 @ X, D2 @ Y, D3 @ X, D3 @ Y, X]
        + [X[:1], Y[:1], (D1 @ X)[:1], (D1 @ Y)[:1], (D2 @ X)[:1], (D2 @ Y)[:1]]
    )
    W = np.diag(np.concatenate([np.full(N, 1.0), np.full(N, 2.0)]))
    P = W + 2.0 * ((D3 @ X).T @ (D3 @ X) + (D3 @ Y).T @ (D3 @ Y))
    inf = np.inf
    qs, ls, us = [], [], []
    for _ in range(batch_size):
        v0 = rng.uniform(3.0, 8.0)
        # the reference follows the road's centre line (arc length v0 t) with a lateral offset
        s = v0 * t
        off = rng.uniform(-0.3, 0.3) * np.sin(rng.uniform(0.2, 0.8) * t)
        cx = np.cumsum(v0 * dt * np.cos(heading)) - v0 * dt
        cy = np.cumsum(v0 * dt * np.sin(heading)) - v0 * dt * np.sin(heading[0])
        rx, ry = cx + off * nx, cy + off * ny
        ref = np.concatenate([rx, ry])
        Ar = A @ ref
        half = rng.uniform(0.5, 1.5)
        uh = np.concatenate([Ar[:N] + half - off, Ar[N : 2 * N] + half + off])
        lh = np.full(2 * N, -inf)
        lv, uv = _rows_between(Ar[2 * N : 4 * N - 2], rng, 0.5, 2.0, 0.1)
        lk, uk = _rows_between(Ar[4 * N - 2 : 8 * N - 8], rng, 0.5, 2.0, 0.01)
        lp, up = np.full(N, -inf), np.full(N, inf)
        every = np.arange(0, N, 5)
        lp[every] = Ar[8 * N - 8 : 9 * N - 8][every] - rng.uniform(0.0, 0.5)
        eq = Ar[9 * N - 8 :]
        target = ref + np.concatenate([_wiggle(rng, t, 1.0, 0.1), _wiggle(rng, t, 1.5, 0.1)])
        target[:N] += rng.uniform(-0.5, 0.5) * s  # faster or slower than the reference
        qs.append(-W @ target)
        ls.append(np.concatenate([lh, lv, lk, lp, eq]))
        us.append(np.concatenate([uh, uv, uk, up, eq]))
    return QPBatch(sp.csc_matrix(P), sp.csc_matrix(A), np.array(qs), np.array(ls), np.array(us))


def _blocks_reference(rng: np.random.Generator, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A smooth random drive: longitudinal ``x`` at a speed with a small acceleration, lateral
    ``y`` a slow lane change."""
    v0, acc = rng.uniform(4.0, 10.0), rng.uniform(-0.5, 0.5)
    rx = v0 * t + 0.5 * acc * t**2
    T = t[-1]
    ry = rng.uniform(-1.5, 1.5) * (1 - np.cos(np.pi * t / T)) / 2 + 0.2 * np.sin(
        rng.uniform(0.5, 1.5) * t + rng.uniform(0.0, np.pi)
    )
    return rx, ry


def _as_input(P: np.ndarray, A: np.ndarray, dense: bool):
    """``P, A`` as a user passes them: dense arrays, or ``scipy.sparse`` (CSC)."""
    if dense:
        return np.array(P), np.array(A)
    return sp.csc_matrix(P), sp.csc_matrix(A)


def _two_axes(batch_size: int, horizon: int, seed: int):
    """The families' common set-up: ``(N, dt, rng, X, Y)``, ``X`` and ``Y`` the
    selectors of the two axes in the ``[x…, y…]`` order."""
    if batch_size < 1 or horizon < 8:
        raise ValueError("batch_size must be ≥ 1 and horizon ≥ 8")
    I, Z = np.eye(horizon), np.zeros((horizon, horizon))
    return horizon, 0.1, np.random.default_rng(seed), np.hstack([I, Z]), np.hstack([Z, I])


def blocks_batch(
    batch_size: int = 1000, horizon: int = 100, *, seed: int = 0, dense: bool = False
) -> QPBatch:
    """The ``blocks`` family (module docstring): ``n = 2N``, ``m = 6N − 2``."""
    N, dt, rng, X, Y = _two_axes(batch_size, horizon, seed)
    D1, D2 = _diff(N, 1), _diff(N, 2)
    A = np.vstack(
        [X, Y, D1 @ X, D1 @ Y, D2 @ X, D2 @ Y] + [X[:1], Y[:1], (D1 @ X)[:1], (D1 @ Y)[:1]]
    )
    W = np.diag(np.concatenate([np.full(N, 1.0), np.full(N, 3.0)]))
    P = W + 0.5 * ((D2 @ X).T @ (D2 @ X) + (D2 @ Y).T @ (D2 @ Y))
    t = np.arange(N) * dt
    qs, ls, us = [], [], []
    for _ in range(batch_size):
        rx, ry = _blocks_reference(rng, t)
        ref = np.concatenate([rx, ry])
        Ar = A @ ref
        lb, ub = _rows_between(Ar[: 2 * N], rng, 0.5, 2.0, 0.3)
        lv, uv = _rows_between(Ar[2 * N : 4 * N - 2], rng, 0.5, 2.0, 0.05)
        la, ua = _rows_between(Ar[4 * N - 2 : 6 * N - 6], rng, 0.5, 2.0, 0.01)
        eq = Ar[6 * N - 6 :]
        target = ref + np.concatenate([_wiggle(rng, t, 1.5, 0.2), _wiggle(rng, t, 1.0, 0.1)])
        target[:N] += rng.uniform(-0.5, 0.5) * t * 5.0
        qs.append(-W @ target)
        ls.append(np.concatenate([lb, lv, la, eq]))
        us.append(np.concatenate([ub, uv, ua, eq]))
    Pi, Ai = _as_input(P, A, dense)
    return QPBatch(Pi, Ai, np.array(qs), np.array(ls), np.array(us))


def blocks_coupled_batch(
    batch_size: int = 1000, horizon: int = 80, *, seed: int = 0, dense: bool = False
) -> QPBatch:
    """The ``blocks-coupled`` family (module docstring): ``n = 2N``, ``m = 730`` at ``N = 80``."""
    N, dt, rng, X, Y = _two_axes(batch_size, horizon, seed)
    D1, D2, D3 = _diff(N, 1), _diff(N, 2), _diff(N, 3)
    t = np.arange(N) * dt
    # halfspaces n_k·(x_k, y_k) ≤ c_k: a corridor whose walls turn with a curving road, one
    # wall per step on each side over the steps ks (the obstacle stretch)
    ks = np.arange(N // 8, N // 8 + 5 * N // 8)
    heading = 0.2 * t[ks]
    nx, ny = -np.sin(heading), np.cos(heading)
    Hk = nx[:, None] * X[ks] + ny[:, None] * Y[ks]
    A = np.vstack(
        [D1 @ X, D1 @ Y, D2 @ X, D2 @ Y, D2 @ X + D2 @ Y, D2 @ X - D2 @ Y]
        + [D3 @ X, D3 @ Y, Hk, -Hk]
        + [X[:1], Y[:1], (D1 @ X)[:1], (D1 @ Y)[:1], (D2 @ X)[:1], (D2 @ Y)[:1]]
    )
    W = np.diag(np.concatenate([np.full(N, 1.0), np.full(N, 2.0)]))
    P = W + 1.0 * ((D2 @ X).T @ (D2 @ X) + (D2 @ Y).T @ (D2 @ Y))
    inf = np.inf
    nh = len(ks)
    qs, ls, us = [], [], []
    for _ in range(batch_size):
        rx, ry = _blocks_reference(rng, t)
        ref = np.concatenate([rx, ry])
        Ar = A @ ref
        o = 0
        lv, uv = _rows_between(Ar[o : o + 2 * N - 2], rng, 0.5, 2.0, 0.05)
        o += 2 * N - 2
        la, ua = _rows_between(Ar[o : o + 4 * N - 8], rng, 0.5, 2.0, 0.01)
        o += 4 * N - 8
        lj, uj = _rows_between(Ar[o : o + 2 * N - 6], rng, 0.5, 2.0, 0.002)
        o += 2 * N - 6
        half = rng.uniform(0.3, 1.0)
        uh = Ar[o : o + 2 * nh] + half
        lh = np.full(2 * nh, -inf)
        o += 2 * nh
        eq = Ar[o:]
        target = ref + np.concatenate([_wiggle(rng, t, 1.0, 0.1), _wiggle(rng, t, 1.5, 0.1)])
        target[:N] += rng.uniform(-0.5, 0.5) * t * 5.0
        qs.append(-W @ target)
        ls.append(np.concatenate([lv, la, lj, lh, eq]))
        us.append(np.concatenate([uv, ua, uj, uh, eq]))
    Pi, Ai = _as_input(P, A, dense)
    return QPBatch(Pi, Ai, np.array(qs), np.array(ls), np.array(us))


def shuffled(batch: QPBatch, seed: int = 0) -> QPBatch:
    """``batch`` with its variables and rows in a random (seeded) order, ``P`` and ``A`` in the
    format they came in: the same QPs, numbered differently."""
    rng = np.random.default_rng(seed)
    pv, pr = rng.permutation(batch.n), rng.permutation(batch.m)
    if sp.issparse(batch.P):
        P = sp.csc_matrix(sp.csr_matrix(batch.P)[pv][:, pv])
        A = sp.csc_matrix(sp.csr_matrix(batch.A)[pr][:, pv])
    else:
        P = np.asarray(batch.P)[np.ix_(pv, pv)]
        A = np.asarray(batch.A)[np.ix_(pr, pv)]
    return QPBatch(P, A, batch.q[:, pv], batch.l[:, pr], batch.u[:, pr])


FAMILIES = {
    "positions": positions_batch,
    "coupled": coupled_batch,
    "blocks": blocks_batch,
    "blocks-coupled": blocks_coupled_batch,
}


def main(argv: list[str] | None = None) -> int:
    """Command line; returns the exit status."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--batch", type=int, default=1000, help="QPs per family (default 1000)")
    ap.add_argument("--family", default="positions,coupled", help="comma-separated names")
    ap.add_argument("--backends", default="ipm,qpsolvers:piqp,clarabel", help="comma-separated")
    ap.add_argument("--repeats", type=int, default=1, help="warm runs per backend (min is shown)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--shuffle", action="store_true", help="permute variables and rows (seeded) first"
    )
    ap.add_argument(
        "--dense", action="store_true", help="pass P, A of the blocks families as dense arrays"
    )
    args = ap.parse_args(argv)
    if args.batch < 1 or args.repeats < 1:
        ap.error("--batch and --repeats must be ≥ 1")
    families = [f for f in args.family.split(",") if f]
    unknown = sorted(set(families) - set(FAMILIES))
    if unknown:
        ap.error(f"unknown family {unknown}; choose from {sorted(FAMILIES)}")
    names = [s for s in args.backends.split(",") if s]
    if PEER not in names:
        names.append(PEER)
    print(f"load average at start: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    for fam in families:
        make = FAMILIES[fam]
        if fam.startswith("blocks"):
            batch = make(args.batch, seed=args.seed, dense=args.dense)
        else:
            batch = make(args.batch, seed=args.seed)
        if args.shuffle:
            batch = shuffled(batch, seed=args.seed)
        free = np.mean(np.isinf(batch.l) & np.isinf(batch.u))
        how = ("dense" if not sp.issparse(batch.A) else "sparse") + (
            ", shuffled" if args.shuffle else ""
        )
        print(
            f"\n## {fam}: n = {batch.n}, m = {batch.m}, {len(batch)} QPs, {free:.0%} free rows "
            f"({how} P, A)"
        )
        rows = run_family(fam, batch, names, args.repeats)
        peer = next((r for r in rows if r["name"] == PEER), None)
        print(
            "\n| backend | time per QP (ms) | max violation | max obj. gap (rel) | solved "
            f"| ÷ {PEER} |\n|---|---:|---:|---:|---:|---:|"
        )
        for r in rows:
            ratio = f"{r['per_qp'] / peer['per_qp']:.2f}" if peer else "–"
            print(
                f"| {r['name']} | {1e3 * r['per_qp']:.2f} | {r['viol']:.1e} | {r['gap']:.1e} "
                f"| {r['solved']}/{len(batch)} | {ratio} |"
            )
        for r in rows:
            if r["name"] == "ipm":
                ex = r["extras"]
                print(
                    f"ipm: linear solver {ex.get('linear_solver')}, half-bandwidth "
                    f"{ex.get('bandwidth')}, max iterations {r['iterations']}, "
                    f"compile {r['compile']:.1f} s"
                )
    print(f"\nsettings: { {n: SETTINGS.get(n, 'defaults') for n in names} }")
    print(f"load average at end: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
