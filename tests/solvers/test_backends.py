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

from solvers import (
    QP,
    InvalidSettingError,
    QPBatch,
    Status,
    available_backends,
    get_backend,
    solve,
    solve_batch,
)
from solvers.examples import projection_like_batch, random_feasible_qp

from .conftest import assert_agrees, reference
from .tolerances import tol_for

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
    return projection_like_batch(4, horizon=100, seed=3)


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


# ------------------------------------------------------- backend-specific behaviour


def test_osqp_records_its_defaults_and_changes_only_verbose():
    pytest.importorskip("osqp")
    sol = solve(random_feasible_qp(4, 3, 1, seed=0), "osqp")
    s = sol.settings
    assert s["verbose"] in (0, False)
    assert s["eps_abs"] == 1e-3 and s["eps_rel"] == 1e-3 and s["max_iter"] == 4000  # OSQP's own
    sol = solve(random_feasible_qp(4, 3, 1, seed=0), "osqp", eps_abs=1e-6, polishing=True)
    assert sol.settings["eps_abs"] == 1e-6 and sol.settings["polishing"] in (1, True)
    with pytest.raises(InvalidSettingError, match="unknown setting 'eps_typo'"):
        solve(random_feasible_qp(4, 3, 1, seed=0), "osqp", eps_typo=1.0)


def test_osqp_batch_sets_up_once_and_warm_starts():
    osqp = pytest.importorskip("osqp")
    batch = projection_like_batch(8, horizon=60, seed=2)
    calls = {"setup": 0}
    orig = osqp.OSQP.setup

    def counting_setup(self, *a, **k):
        calls["setup"] += 1
        return orig(self, *a, **k)

    mp = pytest.MonkeyPatch()
    mp.setattr(osqp.OSQP, "setup", counting_setup)
    try:
        cold = solve_batch(batch, "osqp", eps_abs=1e-5, eps_rel=1e-5, max_iter=50_000)
        assert calls["setup"] == 1
        warm = solve_batch(
            batch, "osqp", warm_start=cold, eps_abs=1e-5, eps_rel=1e-5, max_iter=50_000
        )
    finally:
        mp.undo()
    assert cold.all_solved and warm.all_solved
    # started at the answer, every problem stops at its first termination check
    assert warm.iterations.sum() < cold.iterations.sum()
    assert cold.settings["eps_abs"] == 1e-5


def test_osqp_non_convex_objective_is_an_error_status():
    """With the convexity check skipped by the caller, OSQP's own NON_CVX is still an ERROR."""
    pytest.importorskip("osqp")
    qp = QP(
        np.diag([1.0, -1.0]), np.zeros(2), np.eye(2), -np.ones(2), np.ones(2), check_convex=False
    )
    assert solve(qp, "osqp").status is Status.ERROR


def test_cvxpy_builds_once_per_pattern_of_finite_bounds():
    pytest.importorskip("cvxpy")
    from solvers import cvxpy_

    be = cvxpy_.CvxpyBackend()
    batch = projection_like_batch(3, horizon=20, seed=1)
    for qp in batch:
        assert be.solve(qp).ok
    assert len(be._cache) == 1  # same P, A and bound pattern: one built problem re-solved
    l = batch.l[0].copy()
    l[3] = -np.inf
    qp = QP(batch.P, batch.q[0], batch.A, l, batch.u[0])
    sol = be.solve(qp)
    assert len(be._cache) == 2
    assert_agrees(sol, reference(qp), qp, tol_for("cvxpy"), "cvxpy new pattern")
    with pytest.raises(ValueError, match="not installed"):
        be.solve(qp, solver="NO_SUCH_SOLVER")


def test_qpsolvers_lists_only_offered_solvers():
    pytest.importorskip("qpsolvers")
    from solvers import UnknownBackendError, qpsolvers_

    offered = qpsolvers_.installed_solvers()
    assert offered and not set(offered) & set(qpsolvers_._EXCLUDED)
    for name in set(qpsolvers_._EXCLUDED) & set(__import__("qpsolvers").available_solvers):
        with pytest.raises(UnknownBackendError, match="not offered"):
            get_backend(f"qpsolvers:{name}")


def test_qpsolvers_never_reports_solved_at_a_grossly_infeasible_point():
    """A solver that says "found" at a point violating the rows gets ERROR, not SOLVED."""
    pytest.importorskip("qpsolvers")
    if "qpsolvers:daqp" not in available_backends():
        pytest.skip("daqp not installed")
    sol = solve(_PRIMAL_INFEASIBLE["inconsistent equalities"], "qpsolvers:daqp")
    assert sol.status is Status.ERROR and "infeasible point" in sol.extras["message"]
