"""``ipm`` under a renumbering of the variables and rows: the setup's reordering is invisible to
the caller (``x``, ``y`` and gradients come back in the caller's order, equal to those of the
unshuffled QP permuted back), and a banded family whose band is hidden by a random numbering
still gets the banded linear algebra.

A small two-axis family (``N = 20`` steps, ``n = 40``), the axes in blocks (``x…`` then ``y…``):
velocity, acceleration, coupled ``Δ²x ± Δ²y``, jerk and halfspace rows, initial-state
equalities.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp

import solvers.jax
from solvers import QPBatch, Status, solve_batch
from solvers.ipm import IPMSettings, ipm_setup

from .tolerances import REFERENCE_SETTINGS

N = 20
TIGHT = {"eps_abs": 1e-11, "eps_rel": 1e-11}


def _diff(n: int, order: int) -> np.ndarray:
    D = np.eye(n)
    for _ in range(order):
        D = D[1:] - D[:-1]
    return D


def _blocks(batch: int, seed: int = 0) -> QPBatch:
    rng = np.random.default_rng(seed)
    I, Z = np.eye(N), np.zeros((N, N))
    X, Y = np.hstack([I, Z]), np.hstack([Z, I])
    D1, D2, D3 = _diff(N, 1), _diff(N, 2), _diff(N, 3)
    ks = np.arange(3, 15)
    nx, ny = -np.sin(0.3 * ks), np.cos(0.3 * ks)
    H = nx[:, None] * X[ks] + ny[:, None] * Y[ks]
    A = np.vstack(
        [D1 @ X, D1 @ Y, D2 @ X + D2 @ Y, D2 @ X - D2 @ Y, D3 @ X, D3 @ Y, H, -H, X[:1], Y[:1]]
    )
    W = np.diag(np.concatenate([np.full(N, 1.0), np.full(N, 2.0)]))
    P = W + (D2 @ X).T @ (D2 @ X) + (D2 @ Y).T @ (D2 @ Y)
    t = np.arange(N) * 0.1
    qs, ls, us = [], [], []
    for _ in range(batch):
        ref = np.concatenate([rng.uniform(3.0, 6.0) * t, 0.3 * np.sin(t + rng.uniform(0, 3))])
        Ar = A @ ref
        margin = rng.uniform(0.01, 0.1, A.shape[0])
        lo, hi = Ar - margin, Ar + margin
        nh = len(ks)
        o = A.shape[0] - 2 - 2 * nh
        lo[o : o + 2 * nh] = -np.inf  # halfspaces: one-sided
        lo[-2:] = hi[-2:] = Ar[-2:]  # initial position: equalities
        target = ref + rng.normal(0.0, 0.5, 2 * N)
        qs.append(-W @ target)
        ls.append(lo)
        us.append(hi)
    return QPBatch(sp.csc_matrix(P), sp.csc_matrix(A), np.array(qs), np.array(ls), np.array(us))


def _shuffle(batch: QPBatch, seed: int):
    rng = np.random.default_rng(seed)
    pv, pr = rng.permutation(batch.n), rng.permutation(batch.m)
    P, A = batch.dense()
    out = QPBatch(
        P[np.ix_(pv, pv)], A[np.ix_(pr, pv)], batch.q[:, pv], batch.l[:, pr], batch.u[:, pr]
    )
    return out, pv, pr


@pytest.mark.parametrize("seed", [1, 2])
def test_a_shuffled_qp_gives_the_solution_permuted_back(seed):
    batch = _blocks(4)
    shuf, pv, pr = _shuffle(batch, seed)
    a = solve_batch(batch, "ipm", **TIGHT)
    b = solve_batch(shuf, "ipm", **TIGHT)
    assert np.all(a.status == Status.SOLVED) and np.all(b.status == Status.SOLVED)
    # caller's order: variable i of the shuffled QP is variable pv[i] of the original
    np.testing.assert_allclose(b.x, a.x[:, pv], atol=1e-8)
    np.testing.assert_allclose(b.y, a.y[:, pr], atol=1e-8)
    ref = solve_batch(batch, "clarabel", **REFERENCE_SETTINGS)
    np.testing.assert_allclose(b.objective, ref.objective, rtol=1e-8, atol=1e-8)


def test_the_setup_finds_the_band_of_a_shuffled_family():
    batch = _blocks(1)
    shuf, _, _ = _shuffle(batch, 3)
    P, A = shuf.dense()
    for inputs in ((P, A), (sp.csc_matrix(P), sp.csc_matrix(A))):
        setup = ipm_setup(*inputs, IPMSettings())
        assert setup.kind == "banded"
        assert setup.width <= 8  # the coupled axes interleaved: a few columns
    sol = solve_batch(shuf, "ipm")
    assert sol.extras["linear_solver"] == "banded"


def test_gradients_of_a_shuffled_qp_match_finite_differences():
    batch = _blocks(1)
    shuf, pv, _ = _shuffle(batch, 4)
    P, A = shuf.dense()
    q, l, u = shuf.q[0], shuf.l[0], shuf.u[0]
    P0, A0 = batch.dense()
    d = np.random.default_rng(0).standard_normal(q.size)
    with jax.enable_x64(True):

        def loss(qq, P=P, A=A, l=l, u=u, **kw):
            x = solvers.jax.solve_qp(P, qq, A, l, u, **kw).x
            return jnp.sum(jnp.sin(x))

        g = np.asarray(jax.grad(loss)(jnp.asarray(q)))
        tight = jax.jit(lambda qq: loss(qq, **TIGHT))
        h = 1e-6
        fd = (float(tight(q + h * d)) - float(tight(q - h * d))) / (2 * h)
        assert g @ d == pytest.approx(fd, rel=1e-4, abs=1e-6)
        # the unshuffled QP's gradient, permuted: the same numbers in the caller's order
        g0 = np.asarray(jax.grad(loss)(jnp.asarray(batch.q[0]), P0, A0, batch.l[0], batch.u[0]))
    np.testing.assert_allclose(g, g0[pv], atol=1e-6)
