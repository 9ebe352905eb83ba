"""Forward + backward time per QP through :func:`solvers.jax.solve_qp`, against qpax, and the
host-side :func:`solvers.vjp` against OSQP's own adjoint.

Part 1: a batch of random strictly convex QPs (``n`` variables, ``m`` two-sided inequality rows,
some active at each bound), built from their solution.  Timed, after one compile each: the
jitted, vmapped forward solve, and the jitted, vmapped ``value_and_grad`` of ``Σ g·x*`` with
respect to every argument (forward + backward; their difference, the backward pass, and its
ratio to the forward are printed too; the calls alternate), for ``method="ipm"``,
``method="admm"`` and, when it is installed, qpax (``pip install qpax``:
``qpax.solve_qp_primal`` on the same QPs as ``Gx ≤ h`` with ``G = [A; −A]``, ``h = [u; −l]``;
its gradient smooths complementarity, so its numbers differ: run at its defaults,
``solver_tol=1e-5, target_kappa=1e-3``, and tight, ``1e-9, 1e-9``).  Printed per QP, with the
ratio to ``ipm`` and the largest difference of all the gradients from ``ipm``'s, relative to
the largest entry of each (``A`` apart: qpax's gradient in ``G`` disagrees with finite
differences of its own solution on these QPs, while ``ipm``'s and ``admm``'s agree with them
and with OSQP's adjoint; tests/solvers/test_diff.py).

Part 2: one QP of the same family solved by OSQP (``osqp`` ≥ 1.0, polished); the adjoint
derivative of ``g·x*`` from ``adjoint_derivative_compute`` + ``get_mat`` + ``get_vec`` against
:func:`solvers.vjp` at OSQP's returned solution, timed over repeats, and their agreement.

::

    python -m benchmarks.qp_diff                       # 1000 QPs, n = 20, m = 30
    python -m benchmarks.qp_diff --batch 100 --repeat 3

On JAX 0.10.2's CPU backend the batch of 1000 hung (every thread waiting, inside jaxlib's
threaded batched LAPACK, ``ParallelBatchMap``) in two runs out of three on a 2-core machine; with
``XLA_FLAGS=--xla_cpu_multi_thread_eigen=false`` it ran to the end.  A batch of 100 did not hang.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

import solvers
from solvers import QP, solve, vjp


def random_qps(B: int, n: int, m: int, seed: int = 0):
    """``(P, q, A, l, u)`` stacked over ``B`` QPs: per QP, two rows active at the lower bound, two
    at the upper bound (multipliers of magnitude in [0.5, 1.5]), the rest inactive by ≥ 0.5."""
    rng = np.random.default_rng(seed)
    out = {k: [] for k in "PqAlu"}
    for _ in range(B):
        M = rng.standard_normal((n, n))
        P = M @ M.T / n + np.eye(n)
        A = rng.standard_normal((m, n))
        x = rng.standard_normal(n)
        Ax = A @ x
        l, u = Ax - rng.uniform(0.5, 1.5, m), Ax + rng.uniform(0.5, 1.5, m)
        y = np.zeros(m)
        rows = rng.permutation(m)[:4]
        mag = rng.uniform(0.5, 1.5, 4)
        l[rows[:2]], y[rows[:2]] = Ax[rows[:2]], -mag[:2]
        u[rows[2:]], y[rows[2:]] = Ax[rows[2:]], mag[2:]
        for k, v in zip("PqAlu", (P, -P @ x - A.T @ y, A, l, u), strict=True):
            out[k].append(v)
    return tuple(np.stack(out[k]) for k in "PqAlu")


def _time(fns, args, repeat: int) -> list[float]:
    """Best wall time of ``repeat`` calls of each of ``fns`` (results blocked on), after one
    warm-up call each; the calls alternate, so a change in the machine's load hits all alike."""
    for fn in fns:
        jax.block_until_ready(fn(*args))
    best = [np.inf] * len(fns)
    for _ in range(repeat):
        for i, fn in enumerate(fns):
            t0 = time.perf_counter()
            jax.block_until_ready(fn(*args))
            best[i] = min(best[i], time.perf_counter() - t0)
    return best


def _ours(method: str):
    def value(P, q, A, l, u, g):
        sol = solvers.jax.solve_qp(P, q, A, l, u, method=method)
        return sol.x @ g, sol.x

    def fwd(P, q, A, l, u, g):
        return jax.vmap(lambda *a: value(*a)[1])(P, q, A, l, u, g)

    vg = jax.value_and_grad(lambda *a: value(*a)[0], argnums=(0, 1, 2, 3, 4))
    return jax.jit(fwd), jax.jit(jax.vmap(vg))


def _qpax(**kw):
    import qpax

    def value(P, q, A, l, u, g):
        G = jnp.concatenate([A, -A])
        h = jnp.concatenate([u, -l])
        Ae, be = jnp.zeros((0, P.shape[0])), jnp.zeros(0)
        return qpax.solve_qp_primal(P, q, Ae, be, G, h, **kw) @ g

    def fwd(P, q, A, l, u, g):
        G = jnp.concatenate([A, -A], axis=1)
        h = jnp.concatenate([u, -l], axis=1)
        Ae, be = jnp.zeros((0, P.shape[-1])), jnp.zeros(0)
        return jax.vmap(lambda P, q, G, h: qpax.solve_qp_primal(P, q, Ae, be, G, h, **kw))(
            P, q, G, h
        )

    vg = jax.value_and_grad(value, argnums=(0, 1, 2, 3, 4))
    return jax.jit(fwd), jax.jit(jax.vmap(vg))


def part1(B: int, n: int, m: int, repeat: int) -> None:
    data = random_qps(B, n, m)
    g = np.random.default_rng(1).standard_normal((B, n))
    rows, ref = [], None
    with jax.enable_x64(True):
        args = tuple(jnp.asarray(v) for v in (*data, g))
        runs = [
            ("solvers.jax ipm", lambda: _ours("ipm")),
            ("solvers.jax admm", lambda: _ours("admm")),
        ]
        try:
            import qpax  # noqa: F401

            runs.append(("qpax defaults", _qpax))
            tight = {"solver_tol": 1e-9, "target_kappa": 1e-9, "max_iter": 60}
            runs.append(("qpax tight", lambda: _qpax(**tight)))
        except ImportError:
            print("qpax not installed (pip install qpax): its row is left out")
        for name, make in runs:
            fwd, both = make()
            t_f, t_b = _time((fwd, both), args, repeat)
            grads = [np.asarray(v) for v in both(*args)[1]]
            if ref is None:
                ref = grads
            diff = [
                float(np.max(np.abs(a - b)) / np.max(np.abs(b)))
                for a, b in zip(grads, ref, strict=True)
            ]
            rows.append((name, t_f / B, t_b / B, max(diff[:2] + diff[3:]), diff[2]))
    print(f"\nForward and forward+backward per QP, batch of {B} QPs, n = {n}, m = {m} (float64)")
    print(
        f"{'solver':22s} {'forward':>12s} {'fwd+bwd':>12s} {'backward':>12s} {'bwd/fwd':>8s} "
        f"{'fwd ratio':>10s} {'f+b ratio':>10s} {'∂P,q,l,u vs ipm':>16s} {'∂A vs ipm':>10s}"
    )
    for name, tf, tb, d, dA in rows:
        # backward: value_and_grad minus the forward solve (the JVP rule solves once)
        print(
            f"{name:22s} {tf * 1e6:10.1f}µs {tb * 1e6:10.1f}µs {(tb - tf) * 1e6:10.1f}µs "
            f"{(tb - tf) / tf:8.2f} {tf / rows[0][1]:10.2f} {tb / rows[0][2]:10.2f} {d:16.1e} "
            f"{dA:10.1e}"
        )


def part2(n: int, m: int, repeat: int) -> None:
    import osqp

    P, q, A, l, u = (v[0] for v in random_qps(1, n, m, seed=7))
    g = np.random.default_rng(2).standard_normal(n)
    Ps, As = sp.csc_matrix(P), sp.csc_matrix(A)
    solver = osqp.OSQP()
    solver.setup(
        sp.triu(Ps, format="csc"),
        q,
        As,
        l,
        u,
        verbose=False,
        eps_abs=1e-10,
        eps_rel=1e-10,
        polishing=True,
        max_iter=100000,
    )
    res = solver.solve()

    def adjoint():
        solver.adjoint_derivative_compute(dx=g)
        dP, dA = solver.adjoint_derivative_get_mat(as_dense=True, dP_as_triu=False)
        dq, dl, du = solver.adjoint_derivative_get_vec()
        return dP, dq, dA, dl, du

    qp = QP(Ps, q, As, l, u)
    sol = solve(qp, backend="osqp", eps_abs=1e-10, eps_rel=1e-10, polishing=True, max_iter=100000)

    def ours():
        return vjp(qp, sol, g)

    t = {}
    for name, fn in (("osqp adjoint", adjoint), ("solvers.vjp", ours)):
        fn()
        best = np.inf
        for _ in range(max(repeat, 20)):
            t0 = time.perf_counter()
            fn()
            best = min(best, time.perf_counter() - t0)
        t[name] = best
    a = [np.asarray(v) for v in adjoint()]
    b = [v.toarray() if sp.issparse(v) else np.asarray(v) for v in ours()]
    print(
        f"\nOne QP (n = {n}, m = {m}), OSQP {osqp.__version__} status {res.info.status}: "
        "gradient of g·x* at OSQP's solution"
    )
    print(f"{'':14s} {'time':>10s} {'ratio':>7s}")
    for name, tt in t.items():
        print(f"{name:14s} {tt * 1e6:8.1f}µs {tt / t['osqp adjoint']:7.2f}")
    for k, (va, vb) in zip("PqAlu", zip(a, b, strict=True), strict=True):
        err = np.max(np.abs(va - vb)) / max(np.max(np.abs(vb)), 1e-300)
        print(f"  max relative difference in ∂/∂{k}: {err:.1e}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batch", type=int, default=1000, help="QPs in the batch (default 1000)")
    ap.add_argument("--n", type=int, default=20, help="variables per QP (default 20)")
    ap.add_argument("--m", type=int, default=30, help="constraint rows per QP (default 30)")
    ap.add_argument("--repeat", type=int, default=3, help="timed repetitions, best kept")
    a = ap.parse_args(argv)
    for k in ("batch", "n", "repeat"):
        if getattr(a, k) < 1:
            raise ValueError(f"--{k} must be ≥ 1, got {getattr(a, k)}")
    if a.m < 4:
        raise ValueError(f"--m must be ≥ 4 (four active rows per QP), got {a.m}")
    print(f"JAX {jax.__version__} on {jax.devices()[0].platform}")
    part1(a.batch, a.n, a.m, a.repeat)
    part2(a.n, a.m, a.repeat)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
