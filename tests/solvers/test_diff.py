"""Derivatives of QP solutions: :func:`solvers.jax.solve_qp` (implicit differentiation in JAX)
and the host-side :func:`solvers.vjp`.

Random strictly convex QPs are built from their solution: pick ``x*``, the active set and
multipliers ``y*`` with margins (inactive rows at least 0.5 from their bounds, active multipliers at
least 0.5 in magnitude), then ``q = −Px* − Aᵀy*`` and bounds that make ``(x*, y*)`` the KKT point;
there strict complementarity holds and the derivative exists.  Gradients are checked against
central finite differences of the solver itself (relative error ≤ 1e-5 in float64, relative to
``max(|fd|, 1)``), JAX against the host, forward against reverse mode, a jitted ``vmap`` against
one QP at a time, and an infeasible QP gets NaN gradients with its status.

Every JAX shape compiles once (seconds), so the JAX cases share one shape (n = 5, m = 8), the
Maros–Meszaros problem HS35 (n = 3, m = 4) apart; x64 is switched on inside each test only
(``jax.enable_x64`` as a context manager).
"""

from __future__ import annotations

import dataclasses
from functools import cache

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp

import solvers
from solvers import QP, QPGrad, Status, available_backends, solve, vjp

from .conftest import MM_DIR

N, M = 5, 8
FD_H = 1e-5
RTOL = 1e-5
NAMES = ("P", "q", "A", "l", "u")


def make_qp(seed: int, n: int = N, m: int = M, n_eq: int = 1, n_lo: int = 1, n_up: int = 2):
    """``(P, q, A, l, u, x*, y*)``: a strictly convex QP with the given active rows (equality,
    lower, upper; the rest inactive with a margin) whose solution is ``(x*, y*)``."""
    rng = np.random.default_rng(seed)
    B = rng.standard_normal((n, n))
    P = B @ B.T + np.eye(n)
    A = rng.standard_normal((m, n))
    x = rng.standard_normal(n)
    Ax = A @ x
    kind = rng.permutation(
        np.array([3] * n_eq + [1] * n_lo + [2] * n_up + [0] * (m - n_eq - n_lo - n_up))
    )
    lo_gap, up_gap = rng.uniform(0.5, 1.5, m), rng.uniform(0.5, 1.5, m)
    l, u, y = Ax - lo_gap, Ax + up_gap, np.zeros(m)
    mag = rng.uniform(0.5, 1.5, m)
    for i, k in enumerate(kind):
        if k == 1:
            l[i], y[i] = Ax[i], -mag[i]
        elif k == 2:
            u[i], y[i] = Ax[i], mag[i]
        elif k == 3:
            l[i] = u[i] = Ax[i]
            y[i] = mag[i] * rng.choice([-1.0, 1.0])
    q = -P @ x - A.T @ y
    return P, q, A, l, u, x, y


def random_direction(seed: int, data) -> list[np.ndarray]:
    """A direction in ``(P, q, A, l, u)``: symmetric in ``P``, equal in ``l`` and ``u`` on equality
    rows (moving only one side of ``l == u`` leaves the feasible set or is one-sided)."""
    rng = np.random.default_rng(seed)
    d = [rng.standard_normal(np.shape(v)) for v in data]
    d[0] = 0.5 * (d[0] + d[0].T)
    eq = data[3] == data[4]
    d[4][eq] = d[3][eq]
    return d


@cache
def jitted(method: str):
    """``(value, grad)``: jitted ``g·x*(P, q, A, l, u)`` and its gradient in every argument."""
    kw = {}

    def value(P, q, A, l, u, g):
        return solvers.jax.solve_qp(P, q, A, l, u, method=method, **kw).x @ g

    return jax.jit(value), jax.jit(jax.grad(value, argnums=(0, 1, 2, 3, 4)))


def _fd(f, data, d, h=FD_H) -> float:
    plus = [v + h * dv for v, dv in zip(data, d, strict=True)]
    minus = [v - h * dv for v, dv in zip(data, d, strict=True)]
    return (float(f(*plus)) - float(f(*minus))) / (2 * h)


def _assert_close(an: float, fd: float, what: str) -> None:
    assert abs(an - fd) <= RTOL * max(abs(fd), 1.0), f"{what}: analytic {an:.10g}, FD {fd:.10g}"


# ------------------------------------------------------------------------------- JAX layer
@pytest.mark.slow
@pytest.mark.parametrize("method", ["ipm", "admm"])
def test_jax_gradient_matches_finite_differences(method):
    P, q, A, l, u, xs, ys = make_qp(0)
    g = np.random.default_rng(1).standard_normal(N)
    with jax.enable_x64(True):
        value, grad = jitted(method)
        sol = solvers.jax.solve_qp(P, q, A, l, u, method=method)
        assert int(sol.status) == Status.SOLVED
        np.testing.assert_allclose(sol.x, xs, atol=1e-7)
        np.testing.assert_allclose(sol.y, ys, atol=1e-6)
        data = (P, q, A, l, u)
        grads = [np.asarray(v) for v in grad(*data, g)]
        f = lambda *dd: value(*dd, g)  # noqa: E731
        # one random direction per argument, then all at once
        d = random_direction(2, data)
        for k, name in enumerate(NAMES):
            dk = [np.zeros_like(v) if j != k else d[j].copy() for j, v in enumerate(data)]
            if name in ("l", "u"):  # one side of an equality row alone: only in the joint move
                dk[k][l == u] = 0.0
            an = float(np.sum(grads[k] * dk[k]))
            _assert_close(an, _fd(f, data, dk), f"{method}: d/d{name}")
        an = sum(float(np.sum(gk * dk)) for gk, dk in zip(grads, d, strict=True))
        _assert_close(an, _fd(f, data, d), f"{method}: all arguments")
        # every entry of ∂/∂q
        for i in range(N):
            e = [np.zeros_like(v) for v in data]
            e[1][i] = 1.0
            _assert_close(float(grads[1][i]), _fd(f, data, e), f"{method}: d/dq[{i}]")
        # forward mode gives the same directional derivative
        _, jv = jax.jvp(f, data, tuple(jnp.asarray(v) for v in d))
        _assert_close(float(jv), an, f"{method}: jvp vs grad")
        # P's gradient is symmetric (P enters through its symmetric part)
        np.testing.assert_allclose(grads[0], grads[0].T, atol=1e-12)


@pytest.mark.slow
def test_jax_jacfwd_equals_jacrev():
    P, q, A, l, u, *_ = make_qp(3)
    with jax.enable_x64(True):
        x_of_q = lambda qq: solvers.jax.solve_qp(P, qq, A, l, u).x  # noqa: E731
        Jf = jax.jacfwd(x_of_q)(q)
        Jr = jax.jacrev(x_of_q)(q)
    assert Jf.shape == (N, N)
    np.testing.assert_allclose(Jf, Jr, atol=1e-10)


def test_jax_jit_vmap_over_a_batch_matches_one_at_a_time():
    qps = [make_qp(10 + b) for b in range(4)]
    stack = [np.stack([qp[k] for qp in qps]) for k in range(5)]
    g = np.random.default_rng(4).standard_normal((4, N))
    with jax.enable_x64(True):
        _, grad = jitted("ipm")
        batched = jax.jit(jax.vmap(grad))(*stack, g)
        sols = jax.jit(jax.vmap(solvers.jax.solve_qp))(*stack)
        assert np.all(np.asarray(sols.status) == Status.SOLVED)
        for b, qp in enumerate(qps):
            np.testing.assert_allclose(sols.x[b], qp[5], atol=1e-7)
            one = grad(*qp[:5], g[b])
            for k in range(5):
                np.testing.assert_allclose(batched[k][b], one[k], rtol=1e-8, atol=1e-10)


def _infeasible(P, q, A, l, u):
    """The same shape made infeasible: row 1 repeats row 0 with a disjoint interval."""
    A, l, u = A.copy(), l.copy(), u.copy()
    A[1] = A[0]
    l[0], u[0] = 1.0, 2.0
    l[1], u[1] = -2.0, -1.0
    return P, q, A, l, u


@pytest.mark.parametrize("method", ["ipm", "admm"])
def test_jax_infeasible_qp_has_nan_gradient_and_its_status(method):
    data = _infeasible(*make_qp(5)[:5])
    g = np.ones(N)
    with jax.enable_x64(True):
        _, grad = jitted(method)
        sol = solvers.jax.solve_qp(*data, method=method)
        assert int(sol.status) != Status.SOLVED
        if method == "ipm":
            assert int(sol.status) == Status.PRIMAL_INFEASIBLE
        grads = grad(*data, g)
        for name, gk in zip(NAMES, grads, strict=True):
            assert np.all(np.isnan(np.asarray(gk))), f"{method}: d/d{name} is not all NaN"
    # and on the host
    qp = QP(*data)
    sol = solve(qp, backend="clarabel")
    assert sol.status is Status.PRIMAL_INFEASIBLE
    assert all(np.all(np.isnan(v.toarray() if sp.issparse(v) else v)) for v in vjp(qp, sol, g))


def test_jax_solve_qp_validates_its_arguments():
    P, q, A, l, u, *_ = make_qp(0)
    with pytest.raises(ValueError, match="method"):
        solvers.jax.solve_qp(P, q, A, l, u, method="newton")
    with pytest.raises(ValueError, match="A must have shape"):
        solvers.jax.solve_qp(P, q, A[:, :-1], l, u)
    with pytest.raises(ValueError, match="l must have shape"):
        solvers.jax.solve_qp(P, q, A, l[:-1], u)
    with pytest.raises(ValueError, match="active_tol"):
        solvers.jax.solve_qp(P, q, A, l, u, active_tol=-1.0)
    with pytest.raises(ValueError, match="unknown ipm setting"):
        solvers.jax.solve_qp(P, q, A, l, u, rho=1.0)
    with pytest.raises(ValueError, match="host"):
        solvers.jax.solve_qp(P, q, A, l, u, method="admm", fallback="clarabel")
    if not jax.config.jax_enable_x64:
        with pytest.raises(RuntimeError, match="enable_x64"):
            solvers.jax.solve_qp(P, q, A, l, u)


# ----------------------------------------------------------------------------- host vjp
def _backends_for_vjp() -> list[tuple[str, dict]]:
    tight = {"eps_abs": 1e-10, "eps_rel": 1e-10}
    want = [
        ("clarabel", tight),
        ("osqp", {**tight, "polishing": True, "max_iter": 100000}),
        ("qpsolvers:piqp", tight),
        ("ipm", {}),
        ("admm", {}),
    ]
    have = set(available_backends())
    return [pytest.param(b, s, id=b) for b, s in want if b in have]


@pytest.mark.parametrize(("name", "settings"), _backends_for_vjp())
def test_host_vjp_matches_jax_for_every_backend(name, settings):
    P, q, A, l, u, *_ = make_qp(0)
    g = np.random.default_rng(1).standard_normal(N)
    qp = QP(P, q, A, l, u)
    sol = solve(qp, backend=name, **settings)
    assert sol.status is Status.SOLVED
    host = vjp(qp, sol, g)
    assert isinstance(host, QPGrad)
    with jax.enable_x64(True):
        ref = jitted("ipm")[1](P, q, A, l, u, g)
    for arg, h, r in zip(NAMES, host, ref, strict=True):
        np.testing.assert_allclose(h, r, rtol=1e-6, atol=1e-7, err_msg=f"{name}: d/d{arg}")


@pytest.mark.parametrize("kkt", ["dense LU", "sparse LU"])
def test_host_vjp_matches_finite_differences_and_is_sparse_aware(kkt, monkeypatch):
    if kkt == "sparse LU":  # this small QP would be solved densely
        monkeypatch.setattr(solvers.diff, "DENSE_KKT_MAX", 0)
    P, q, A, l, u, *_ = make_qp(7)
    g = np.random.default_rng(8).standard_normal(N)
    data = (P, q, A, l, u)

    def f(*dd):
        sol = solve(QP(*dd), backend="clarabel", eps_abs=1e-12, eps_rel=1e-12)
        return sol.x @ g

    qp = QP(*data)
    dense = vjp(qp, solve(qp, backend="clarabel", eps_abs=1e-12, eps_rel=1e-12), g)
    d = random_direction(9, data)
    an = sum(float(np.sum(gk * dk)) for gk, dk in zip(dense, d, strict=True))
    _assert_close(an, _fd(f, data, d), "host vjp: all arguments")
    # sparse P, A with structural zeros: gradients on their pattern, equal to the dense ones there
    A_sp = A.copy()
    A_sp[np.abs(A_sp) < 0.5] = 0.0
    qps = QP(sp.csc_matrix(P), q, sp.csc_matrix(A_sp), l, u)
    qpd = QP(P, q, A_sp, l, u)
    sol = solve(qps, backend="clarabel", eps_abs=1e-12, eps_rel=1e-12)
    gs, gd = vjp(qps, sol, g), vjp(qpd, sol, g)
    assert sp.issparse(gs.P) and sp.issparse(gs.A)
    mask = A_sp != 0
    np.testing.assert_allclose(gs.A.toarray()[mask], gd.A[mask], rtol=1e-10, atol=1e-12)
    assert np.all(gs.A.toarray()[~mask] == 0.0)
    np.testing.assert_allclose(gs.P.toarray(), gd.P, rtol=1e-10, atol=1e-12)
    for k in (1, 3, 4):
        np.testing.assert_allclose(gs[k], gd[k], rtol=1e-10, atol=1e-12)


def test_host_vjp_validates_and_refuses_the_opposite_dual_sign():
    P, q, A, l, u, *_ = make_qp(0)
    qp = QP(P, q, A, l, u)
    sol = solve(qp, backend="clarabel")
    with pytest.raises(ValueError, match="dx"):
        vjp(qp, sol, np.ones(N + 1))
    with pytest.raises(ValueError, match="qp"):
        vjp((P, q, A, l, u), sol, np.ones(N))
    with pytest.raises(ValueError, match="active_tol"):
        vjp(qp, sol, np.ones(N), active_tol=2.0)
    flipped = dataclasses.replace(sol, y=-sol.y)
    with pytest.raises(ValueError, match="OSQP's convention"):
        vjp(qp, flipped, np.ones(N))


def test_weakly_active_row_gives_the_one_sided_derivative():
    """min ½‖x‖² − x₁ s.t. x₂ ≤ 0: the unconstrained optimum (1, 0) sits on the bound with y = 0.
    The row counts as inactive: ∂x₂/∂q₂ = −1, the derivative for q₂ increasing (x₂ moves into
    the interior), and the gradient in u is 0."""
    qp = QP(np.eye(2), [-1.0, 0.0], [[0.0, 1.0]], [-np.inf], [0.0])
    h = 1e-2  # the map is linear on that side; an interior point sits ~1e-7 off the bound
    for name, kw in (
        ("osqp", {"polishing": True}),
        ("clarabel", {"eps_abs": 1e-12, "eps_rel": 1e-12}),
    ):
        sol = solve(qp, backend=name, **kw)
        grad = vjp(qp, sol, np.array([0.0, 1.0]))
        up = solve(QP(qp.P, qp.q + [0.0, h], qp.A, qp.l, qp.u), backend=name, **kw)
        assert grad.q[1] == pytest.approx(-1.0, abs=1e-9), name
        assert grad.q[1] == pytest.approx((up.x[1] - sol.x[1]) / h, abs=1e-3), name
        assert grad.u[0] == 0.0, name


@pytest.mark.slow
def test_admm_in_float32_without_x64():
    if jax.config.jax_enable_x64:
        pytest.skip("x64 is on globally in this process")
    P, q, A, l, u, xs, _ = make_qp(0)
    sol = solvers.jax.solve_qp(P, q, A, l, u, method="admm")
    assert sol.x.dtype == jnp.float32 and int(sol.status) == Status.SOLVED
    np.testing.assert_allclose(sol.x, xs, atol=1e-4)
    g32 = jax.grad(lambda qq: solvers.jax.solve_qp(P, qq, A, l, u, method="admm").x.sum())(
        jnp.asarray(q, jnp.float32)
    )
    with jax.enable_x64(True):
        g64 = jitted("ipm")[1](P, q, A, l, u, np.ones(N))[1]
    np.testing.assert_allclose(g32, g64, rtol=1e-3, atol=1e-4)


# ------------------------------------------------------------------------- Maros–Meszaros
@pytest.mark.slow
def test_maros_meszaros_hs35_jax_host_and_finite_differences_agree():
    path = MM_DIR / "HS35.mat"
    if not path.is_file():
        pytest.skip(f"Maros–Meszaros data absent: {path} not found (shared data not mounted)")
    from .test_maros_meszaros import load_mm

    qp, _ = load_mm(path)
    g = np.array([1.0, -2.0, 0.5])
    tight = {"eps_abs": 1e-12, "eps_rel": 1e-12}
    sol = solve(qp, backend="clarabel", **tight)
    assert sol.status is Status.SOLVED
    host = vjp(qp, sol, g)
    Pd, Ad = qp.dense()
    data = (Pd, qp.q, Ad, qp.l, qp.u)
    with jax.enable_x64(True):
        ref = jax.grad(lambda *dd: solvers.jax.solve_qp(*dd).x @ g, argnums=(0, 1, 2, 3, 4))(*data)
    for name, h, r in zip(NAMES, host, ref, strict=True):
        h = h.toarray() if sp.issparse(h) else h
        mask = h != 0 if name in ("P", "A") else np.ones(np.shape(h), bool)
        np.testing.assert_allclose(
            h[mask], np.asarray(r)[mask], rtol=1e-6, atol=1e-8, err_msg=f"HS35: d/d{name}"
        )
    # finite differences in q and in the finite bounds
    fin = [np.zeros_like(v) for v in data]
    rng = np.random.default_rng(0)
    fin[1] = rng.standard_normal(qp.n)
    fin[3] = np.where(np.isfinite(qp.l), rng.standard_normal(qp.m), 0.0)

    def f(*dd):
        return (
            solve(
                QP(sp.csc_matrix(dd[0]), dd[1], sp.csc_matrix(dd[2]), dd[3], dd[4]),
                backend="clarabel",
                **tight,
            ).x
            @ g
        )

    an = float(host.q @ fin[1] + host.l @ fin[3])
    _assert_close(an, _fd(f, data, fin), "HS35: d/dq, d/dl")


# ------------------------------------------------- the active set at the default ipm tolerance
def _lane_projection():
    """A curve of 9 Bernstein coefficients projected onto ``|p(t_k)| ≤ 0.5`` and
    ``|ṗ(t_k)| ≤ v`` at 60 grid points: several grid rows near a touching point only approach
    the bound, and at ipm's default tolerance their multipliers exceed the activity threshold."""
    from math import comb

    K, deg = 60, 8
    t = np.linspace(0.0, 1.0, K)
    Bm = np.stack([comb(deg, i) * t**i * (1 - t) ** (deg - i) for i in range(deg + 1)], axis=1)
    A = np.vstack([Bm, np.diff(Bm, axis=0) * (K - 1)])
    target = 0.73794889665 * np.sin(2.89526087630 * t + 0.52467070482) + 0.14230050068
    l = np.concatenate([np.full(K, -0.5), np.full(K - 1, -2.72082466976)])
    return Bm.T @ Bm, -Bm.T @ target, A, l, -l


@pytest.mark.slow
def test_rows_approaching_their_bound_do_not_make_the_gradient_wrong():
    P, q, A, l, u = _lane_projection()
    d = np.random.default_rng(0).standard_normal(q.size)
    with jax.enable_x64(True):
        sol = solvers.jax.solve_qp(P, q, A, l, u)  # default tolerance (1e-9)
        assert int(sol.status) == Status.SOLVED
        y, Ax = np.asarray(sol.y), A @ np.asarray(sol.x)
        slack = np.minimum(Ax - l, u - Ax)
        tau = 1e-6 * np.abs(y).max()
        # the situation: a row with a multiplier above τ that is not at its bound
        assert np.any((np.abs(y) > tau) & (slack > 1e-6))

        def loss(qq):
            return jnp.sum(solvers.jax.solve_qp(P, qq, A, l, u).x ** 2)

        def tight(qq):  # finite differences of a tight solve
            return jnp.sum(
                solvers.jax.solve_qp(P, qq, A, l, u, eps_abs=1e-11, eps_rel=1e-11).x ** 2
            )

        g = np.asarray(jax.grad(loss)(jnp.asarray(q)))
        assert np.all(np.isfinite(g))
        fd = _fd(jax.jit(tight), (q,), (d,))
        # (the default tolerance leaves ~1e-4 in the derivative; the old rule was off by 10×)
        assert g @ d == pytest.approx(fd, rel=1e-3)


@pytest.mark.slow
def test_dependent_active_rows_give_a_finite_gradient():
    """A row repeated (the same constraint twice, both active): the reduced KKT system is
    singular; the derivative of ``x`` still exists and is finite, and matches finite
    differences."""
    P, q, A, l, u, _, ys = make_qp(3)
    i = int(np.argmax(np.abs(ys) * (l != u)))  # an active inequality row
    A2, l2, u2 = np.vstack([A, A[i]]), np.append(l, l[i]), np.append(u, u[i])
    data = (P, q, A2, l2, u2)
    d = random_direction(7, data)
    d[3][-1], d[4][-1] = d[3][i], d[4][i]  # move both copies of the row together
    g = np.ones(N)
    with jax.enable_x64(True):

        def value(*dd):
            return solvers.jax.solve_qp(*dd, eps_abs=1e-11, eps_rel=1e-11).x @ g

        sol = solvers.jax.solve_qp(*data)
        assert int(sol.status) == Status.SOLVED
        grads = jax.grad(value, argnums=(0, 1, 2, 3, 4))(*data)
        assert all(np.all(np.isfinite(np.asarray(gr))) for gr in grads)
        an = sum(float(np.sum(np.asarray(gr) * dv)) for gr, dv in zip(grads, d, strict=True))
        _assert_close(an, _fd(jax.jit(value), data, d), "dependent rows")
