"""``ipm`` on banded and sparse QPs: the band assembly of the condensed matrix from the rows'
slots gives the answer of the dense linear algebra and of Clarabel, whatever the column order
of ``A``; rows free in every QP of a batch leave the iteration and get a zero multiplier.

Small sizes (n = 40, m = 70: banded by the ``auto`` rule), one compile per shape.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp

from solvers import QPBatch, Status, solve_batch
from solvers.ipm import IPMSettings, IPMSetup, _band_tables, _linear_algebra, ipm_setup

from .tolerances import REFERENCE_SETTINGS

N, M, B = 40, 70, 4


def _banded_batch(seed: int, shuffle: bool = False) -> QPBatch:
    """Rows with 1–4 consecutive nonzeros at random places, ``P`` tridiagonal SPD; bounds of
    every kind around a feasible point (two-sided, one-sided, equality, free).  ``shuffle``
    permutes the columns (the band is then hidden until the setup's reordering)."""
    rng = np.random.default_rng(seed)
    A = np.zeros((M, N))
    for i in range(M):
        span = rng.integers(1, 5)
        j = rng.integers(0, N - span + 1)
        A[i, j : j + span] = rng.normal(size=span)
    P = np.diag(rng.uniform(1.0, 2.0, N)) + np.diag(np.full(N - 1, -0.4), 1)
    P = P + np.diag(np.full(N - 1, -0.4), -1)
    if shuffle:
        perm = rng.permutation(N)
        A, P = A[:, perm], P[np.ix_(perm, perm)]
    x0 = rng.normal(size=(B, N))
    Ax0 = x0 @ A.T
    lo = Ax0 - rng.uniform(0.0, 1.0, (B, M))
    hi = Ax0 + rng.uniform(0.0, 1.0, (B, M))
    kind = rng.integers(0, 5, (B, M))
    lo[kind == 1] = -np.inf
    hi[kind == 2] = np.inf
    lo[kind == 3] = hi[kind == 3] = Ax0[kind == 3]
    lo[kind == 4], hi[kind == 4] = -np.inf, np.inf
    q = 3.0 * rng.normal(size=(B, N))
    return QPBatch(sp.csc_matrix(P), sp.csc_matrix(A), q, lo, hi)


def _assert_matches(batch: QPBatch, sol, ref) -> None:
    assert np.all(sol.status == Status.SOLVED), sol.status_counts()
    # (ipm stops at eps 1e-9 on the objective: on these QPs x is then ~2e-5 from the reference)
    np.testing.assert_allclose(sol.x, ref.x, atol=1e-4)
    np.testing.assert_allclose(sol.objective, ref.objective, rtol=1e-7, atol=1e-7)
    assert np.max(batch.constraint_violation(sol.x)) <= 1e-8


@pytest.mark.slow
@pytest.mark.parametrize("shuffle", [False, True], ids=["ordered", "shuffled columns"])
def test_band_assembly_from_slots_matches_dense_and_clarabel(shuffle):
    batch = _banded_batch(1, shuffle)
    setup = ipm_setup(*batch.dense(), IPMSettings())
    assert setup.kind == "banded" and "slot_VV" in setup.arrays  # the path under test
    ref = solve_batch(batch, "clarabel", **REFERENCE_SETTINGS)
    assert np.all(ref.solved)
    banded = solve_batch(batch, "ipm")
    dense = solve_batch(batch, "ipm", linear_solver="dense")
    _assert_matches(batch, banded, ref)
    _assert_matches(batch, dense, ref)
    np.testing.assert_allclose(banded.x, dense.x, atol=1e-9)


def test_slot_and_gather_assemblies_factor_the_same_matrix():
    """The two band assemblies of ``M = P̄ + ρI + Āᵀ diag(d) Ā`` give the same Cholesky factor."""
    batch = _banded_batch(2, shuffle=True)
    st = ipm_setup(*batch.dense(), IPMSettings())
    Pp, Ap = st.arrays["P"], st.arrays["A"]
    Pb, coef, rows = _band_tables(Pp, Ap, st.width)
    base = {k: v for k, v in st.arrays.items() if k not in ("slot_VV", "row_of_slot")}
    gather = {**base, "band_P": Pb, "band_coef": coef, "band_rows": rows}
    d = np.random.default_rng(0).uniform(0.0, 10.0, M)
    d[::7] = 0.0  # rows that do not enter M
    with jax.enable_x64(True):
        factors = []
        for arrays in (st.arrays, gather):
            s = IPMSetup(
                {k: jnp.asarray(v) for k, v in arrays.items()}, "banded", st.width, N, M, 1
            )
            factors.append(np.asarray(_linear_algebra(s, 1e-10).factor(jnp.asarray(d))))
    np.testing.assert_allclose(factors[0], factors[1], rtol=1e-12, atol=1e-12)


def test_rows_free_in_every_qp_leave_the_iteration():
    """Rows free in every QP of the batch: the same ``x`` as the QP without them, ``y = 0``; a
    dense row among them does not make the condensed matrix dense."""
    batch = _banded_batch(3)
    free = np.zeros(M, bool)
    free[::5] = True
    A = batch.A.toarray()
    A[0] = 1.0  # a dense row (free in every QP): kept, it would couple every variable
    batch = QPBatch(batch.P, sp.csc_matrix(A), batch.q, batch.l, batch.u)
    lo, hi = batch.l.copy(), batch.u.copy()
    lo[:, free], hi[:, free] = -np.inf, np.inf
    with_free = QPBatch(batch.P, batch.A, batch.q, lo, hi)
    without = QPBatch(batch.P, batch.A[~free], batch.q, lo[:, ~free], hi[:, ~free])
    sol = solve_batch(with_free, "ipm")
    assert sol.extras["linear_solver"] == "banded"
    ref = solve_batch(without, "clarabel", **REFERENCE_SETTINGS)
    _assert_matches(with_free, sol, ref)
    assert np.all(sol.y[:, free] == 0.0)
    np.testing.assert_allclose(sol.y[:, ~free], ref.y, atol=1e-5)
    assert np.max(with_free.dual_residual(sol.x, sol.y)) <= 1e-7
