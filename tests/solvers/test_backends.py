"""Every available backend against a tight Clarabel reference: random QPs (hypothesis),
projection-like QPs, infeasible problems, and ``solve_batch`` against a loop of ``solve``.

One test body per behaviour; per-backend settings and tolerances come from ``tolerances.py``.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from solvers import QP, QPBatch, Status, get_backend, solve, solve_batch
from solvers.examples import projection_like_batch, random_feasible_qp

from .conftest import assert_agrees, reference

# ------------------------------------------------------------------ random QPs (hypothesis)


@st.composite
def feasible_qps(draw) -> QP:
    """Small feasible, bounded QPs with inequality rows (some bounds ±inf) and equality rows."""
    n = draw(st.integers(1, 6))
    m_ineq = draw(st.integers(0, 6))
    m_eq = draw(st.integers(0, min(n - 1, 3)) if n > 1 else st.just(0))
    seed = draw(st.integers(0, 2**31 - 1))
    sparse = draw(st.booleans())
    rank = draw(st.one_of(st.none(), st.integers(0, n)))
    return random_feasible_qp(n, m_ineq, m_eq, seed=seed, sparse=sparse, psd_rank=rank)


def test_random_feasible_qps_match_reference(backend, tol):
    @settings(
        max_examples=tol.examples,
        deadline=None,
        derandomize=True,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    )
    @given(feasible_qps())
    def check(qp):
        ref = reference(qp)
        sol = solve(qp, backend, **tol.settings)
        if tol.may_fail and sol.status is not Status.SOLVED:
            assert sol.status is not Status.SOLVED_INACCURATE
            return  # allowed, see tolerances.py; a SOLVED below must agree
        assert_agrees(sol, ref, qp, tol, f"{backend} n={qp.n} m={qp.m}")
        # duals in OSQP's convention: stationarity holds with the returned y
        ys = max(1.0, float(np.max(np.abs(ref.y), initial=0.0)))
        if np.all(np.isfinite(sol.y)):
            assert sol.dual_residual <= 10 * tol.x_atol * max(ys, float(np.max(np.abs(qp.q))))

    check()


# --------------------------------------------------------------- projection-like QPs


@pytest.fixture(scope="module")
def projection_batch() -> QPBatch:
    return projection_like_batch(6, horizon=100, seed=3)


@pytest.fixture(scope="module")
def projection_refs(projection_batch):
    return [reference(qp) for qp in projection_batch]


def test_projection_like_qps_match_reference(backend, tol, projection_batch, projection_refs):
    for i, (qp, ref) in enumerate(zip(projection_batch, projection_refs, strict=True)):
        sol = solve(qp, backend, **tol.settings)
        assert_agrees(sol, ref, qp, tol, f"{backend} projection problem {i}")


def test_solve_batch_equals_loop_of_solve(backend, tol):
    batch = projection_like_batch(4, horizon=40, seed=7)
    # one problem with a free row and a one-sided row: the infinite-bound pattern changes within
    # the batch (cvxpy rebuilds for it; OSQP takes inf through update())
    l, u = batch.l.copy(), batch.u.copy()
    l[1, 5], u[1, 5] = -np.inf, np.inf
    l[2, 45] = -np.inf
    batch = QPBatch(batch.P, batch.A, batch.q, l, u)
    bs = solve_batch(batch, backend, **tol.settings)
    assert len(bs) == len(batch) and bs.x.shape == (4, batch.n) and bs.y.shape == (4, batch.m)
    assert bs.backend == backend
    for i, qp in enumerate(batch):
        one = solve(qp, backend, **tol.settings)
        assert Status(int(bs.status[i])) is one.status, (i, bs.status, one.status)
        if i in (0, 3):  # the unmodified problems; see tolerances.py for HiGHS on problem 1
            assert one.status is Status.SOLVED, (i, one.status)
        if one.status is not Status.SOLVED:
            continue
        xs = max(1.0, float(np.max(np.abs(one.x))))
        np.testing.assert_allclose(bs.x[i], one.x, rtol=0, atol=2 * tol.x_atol * xs)
        assert abs(bs.objective[i] - one.objective) <= 2 * tol.obj_rtol * max(1, abs(one.objective))
        assert bs[i].primal_residual == pytest.approx(qp.constraint_violation(bs.x[i]), abs=1e-12)


def test_solve_batch_accepts_warm_start(backend, tol):
    batch = projection_like_batch(3, horizon=30, seed=11)
    first = solve_batch(batch, backend, **tol.settings)
    again = solve_batch(batch, backend, warm_start=first, **tol.settings)
    assert again.all_solved
    xs = max(1.0, float(np.max(np.abs(first.x))))
    np.testing.assert_allclose(again.x, first.x, rtol=0, atol=2 * tol.x_atol * xs)


# ------------------------------------------------------------------ edge problems


def test_unconstrained_qp(backend, tol):
    P = np.array([[2.0, 0.5], [0.5, 1.0]])
    q = np.array([1.0, -1.0])
    qp = QP(P, q, np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    sol = solve(qp, backend, **tol.settings)
    assert sol.status is Status.SOLVED
    np.testing.assert_allclose(sol.x, np.linalg.solve(P, -q), atol=10 * tol.x_atol)
    assert sol.y.shape == (0,)


def test_psd_only_objective(backend, tol):
    """P singular (an LP in one direction): solved, or a clean ERROR where P must be PD."""
    P = sp.csc_matrix(np.diag([1.0, 0.0]))
    qp = QP(P, np.array([0.0, 1.0]), np.eye(2), np.array([-1.0, -2.0]), np.array([1.0, 2.0]))
    sol = solve(qp, backend, **tol.settings)
    if tol.handles_psd:
        assert sol.status is Status.SOLVED
        np.testing.assert_allclose(sol.x, [0.0, -2.0], atol=10 * tol.x_atol * 2)
    else:
        assert sol.status is Status.ERROR and "positive definite" in sol.extras["message"]


# --------------------------------------------------------------------- infeasibility

_PRIMAL_INFEASIBLE = {
    # x ≥ 1 and x ≤ 0 on two rows
    "contradicting rows": QP(
        np.eye(1),
        np.zeros(1),
        np.array([[1.0], [1.0]]),
        np.array([1.0, -np.inf]),
        np.array([np.inf, 0.0]),
    ),
    # x1 + x2 = 1 and x1 + x2 = 2
    "inconsistent equalities": QP(
        np.eye(2),
        np.ones(2),
        np.array([[1.0, 1.0], [1.0, 1.0], [1.0, 0.0]]),
        np.array([1.0, 2.0, -5.0]),
        np.array([1.0, 2.0, 5.0]),
    ),
    # box [0, 1]² and x1 + x2 ≥ 3
    "box vs half-space": QP(
        np.diag([1.0, 2.0]),
        np.array([1.0, 0.0]),
        np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]),
        np.array([0.0, 0.0, 3.0]),
        np.array([1.0, 1.0, np.inf]),
    ),
}
_DUAL_INFEASIBLE = {
    # min −x s.t. x ≥ 0 (an unbounded LP)
    "unbounded LP": QP(
        np.zeros((1, 1)), -np.ones(1), np.ones((1, 1)), np.zeros(1), np.array([np.inf])
    ),
    # min ½x1² − x2 s.t. −1 ≤ x1 ≤ 1, x2 free above 0
    "unbounded along a null direction of P": QP(
        np.diag([1.0, 0.0]),
        np.array([0.0, -1.0]),
        np.eye(2),
        np.array([-1.0, 0.0]),
        np.array([1.0, np.inf]),
    ),
}


@pytest.mark.parametrize("case", sorted(_PRIMAL_INFEASIBLE))
def test_primal_infeasible_never_solved(backend, tol, case):
    qp = _PRIMAL_INFEASIBLE[case]
    sol = solve(qp, backend, **tol.settings)
    assert sol.status not in (Status.SOLVED, Status.SOLVED_INACCURATE), sol
    if get_backend(backend).detects_infeasibility:
        assert sol.status is Status.PRIMAL_INFEASIBLE, (case, sol.status)


@pytest.mark.parametrize("case", sorted(_DUAL_INFEASIBLE))
def test_dual_infeasible_never_solved(backend, tol, case):
    qp = _DUAL_INFEASIBLE[case]
    sol = solve(qp, backend, **tol.settings)
    assert sol.status not in (Status.SOLVED, Status.SOLVED_INACCURATE), sol
    if get_backend(backend).detects_infeasibility:
        assert sol.status is Status.DUAL_INFEASIBLE, (case, sol.status)


def test_infeasible_problem_in_a_batch_does_not_spoil_the_rest(backend, tol):
    batch = projection_like_batch(3, horizon=30, seed=5)
    l, u = batch.l.copy(), batch.u.copy()
    l[1, 0], u[1, 0] = 5.0, 6.0  # x0 ∈ [5, 6] but the boundary equality says x0 = 0
    bad = QPBatch(batch.P, batch.A, batch.q, l, u)
    bs = solve_batch(bad, backend, **tol.settings)
    assert Status(int(bs.status[1])) not in (Status.SOLVED, Status.SOLVED_INACCURATE)
    if get_backend(backend).detects_infeasibility:
        assert Status(int(bs.status[1])) is Status.PRIMAL_INFEASIBLE
    for i in (0, 2):
        assert_agrees(bs[i], reference(bad[i]), bad[i], tol, f"{backend} batch problem {i}")
