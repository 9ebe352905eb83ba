"""What users coming from qpsolvers or OSQP expect of the QP layer: statuses that print their
names, ``is_optimal``/``duality_gap``, a batch built from qpsolvers' arguments, one-line reprs,
``solver=`` for ``backend=``, and errors that name the argument the user wrote."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import solvers
from solvers import (
    QP,
    BatchSolution,
    QPBatch,
    Solution,
    Status,
    available_backends,
    solve,
    solve_batch,
    solve_qp,
)

REPO = Path(__file__).resolve().parents[2]
TIGHT = {"eps_abs": 1e-10, "eps_rel": 1e-10}


def _form():
    """min ½‖x‖² + [1, −1, 0.5]·x  s.t.  x0 + x1 ≤ 0.25, x0 − x2 = −0.5, −2 ≤ x ≤ 2."""
    P = np.diag([1.0, 2.0, 1.0])
    q = np.array([1.0, -1.0, 0.5])
    G, h = np.array([[1.0, 1.0, 0.0]]), np.array([0.25])
    A, b = np.array([[1.0, 0.0, -1.0]]), np.array([-0.5])
    lb, ub = np.full(3, -2.0), np.full(3, 2.0)
    return P, q, G, h, A, b, lb, ub


def _infeasible_batch() -> QPBatch:
    """Two QPs: the first feasible, the second asks x0 + x1 ≤ −5 inside the box [−1, 1]²."""
    return QPBatch.from_qpsolvers(
        np.eye(2), [1.0, -1.0], G=[[1.0, 1.0]], h=[[0.0], [-5.0]], lb=[-1.0, -1.0], ub=[1.0, 1.0]
    )


# ------------------------------------------------------------------------------------- status
def test_status_prints_its_name_and_still_compares_as_an_integer():
    s = Status.SOLVED
    assert str(s) == "SOLVED" and f"{s}" == "SOLVED" and f"{s:>8}" == "  SOLVED"
    assert f"{Status.MAX_ITER:d}" == "3" and int(Status.MAX_ITER) == 3
    assert s == 1 and Status(4) is Status.PRIMAL_INFEASIBLE
    assert np.array([s, Status.ERROR]).tolist() == [1, 6]
    sol = solve_qp(*_form())
    assert str(sol.status) == "SOLVED" and sol.ok


def test_a_batch_result_gives_each_status_by_name_and_an_ok_array():
    sols = solve_batch(_infeasible_batch(), "clarabel")
    assert sols.status_names == ("SOLVED", "PRIMAL_INFEASIBLE")
    assert sols.ok.dtype == bool and sols.ok.tolist() == [True, False]
    assert sols.status.tolist() == [1, 4]  # still integer codes


# ------------------------------------------------------------------- is_optimal, duality_gap
def test_duality_gap_and_is_optimal_agree_with_qpsolvers():
    qpsolvers = pytest.importorskip("qpsolvers")
    P, q, G, h, A, b, lb, ub = _form()
    csc = sp.csc_matrix
    problem = qpsolvers.Problem(csc(P), q, csc(G), h, csc(A), b, lb, ub)
    ref = qpsolvers.solve_problem(problem, solver="clarabel", tol_gap_abs=1e-10)
    # the same point in this package's form: y over the rows [G; A; I], OSQP's signs (= qpsolvers')
    qp = QP.from_qpsolvers(P, q, G, h, A, b, lb, ub)
    ours = Solution(
        x=ref.x,
        y=np.concatenate([ref.z, ref.y, ref.z_box]),
        status=Status.SOLVED,
        objective=qp.objective(ref.x),
        iterations=0,
        solve_time=0.0,
        primal_residual=qp.constraint_violation(ref.x),
        dual_residual=float("nan"),
        backend="qpsolvers:clarabel",
        problem=qp,
    )
    assert ours.duality_gap() == pytest.approx(ref.duality_gap(), rel=1e-9, abs=1e-14)
    for eps in (1e-4, 1e-7, 1e-12):
        assert ours.is_optimal(eps) == ref.is_optimal(eps), eps


def test_solutions_carry_their_problem_and_check_their_own_point():
    sol = solve_qp(*_form(), **TIGHT)
    assert isinstance(sol.problem, QP) and sol.problem.m == 5
    assert sol.duality_gap() < 1e-8 and sol.is_optimal(1e-6)
    off = Solution(**{**sol.__dict__, "x": sol.x + 1e-3})  # the same duals, a moved point
    assert not off.is_optimal(1e-6) and off.duality_gap() > 1e-6
    nan = Solution(**{**sol.__dict__, "y": np.full(sol.y.shape, np.nan)})
    assert not nan.is_optimal(1.0) and np.isnan(nan.duality_gap())
    bare = Solution(**{**sol.__dict__, "problem": None})
    with pytest.raises(ValueError, match="qp is required"):
        bare.duality_gap()
    assert bare.is_optimal(1e-6, qp=sol.problem)
    for bad in (-1.0, float("nan"), "1e-6", True):
        with pytest.raises(ValueError, match="eps_abs"):
            sol.is_optimal(bad)  # type: ignore[arg-type]


def test_batch_is_optimal_and_gap_per_problem_match_the_members():
    sols = solve_batch(_infeasible_batch(), "clarabel", **TIGHT)
    assert sols.is_optimal(1e-6).tolist() == [True, False]  # the infeasible one has NaN x
    gap = sols.duality_gap()
    assert gap.shape == (2,) and gap[0] == pytest.approx(sols[0].duality_gap(), abs=1e-15)
    assert sols[0].problem is not None and sols[0].is_optimal(1e-6)


# ----------------------------------------------------------------------- QPBatch.from_qpsolvers
@pytest.mark.parametrize("sparse", [False, True], ids=["dense", "sparse"])
def test_each_member_of_a_qpsolvers_batch_solves_as_the_single_qp(sparse):
    P, q, G, h, A, b, lb, ub = _form()
    if sparse:
        P, G, A = sp.csc_matrix(P), sp.csc_matrix(G), sp.csc_matrix(A)
    rng = np.random.default_rng(0)
    B = 4
    qs = q + 0.3 * rng.standard_normal((B, 3))  # per QP
    hs = h + np.linspace(-0.2, 0.2, B)[:, None]  # per QP, shape (B, 1)
    ubs = np.stack([ub] * B) - 0.1 * np.arange(B)[:, None]  # per QP
    batch = QPBatch.from_qpsolvers(P, qs, G, hs, A, b, lb, ubs)  # b, lb shared
    assert batch.batch_size == B and batch.m == 5 and sp.issparse(batch.A) == sparse
    sols = solve_batch(batch, "clarabel", **TIGHT)
    for i in range(B):
        single = QP.from_qpsolvers(P, qs[i], G, hs[i], A, b, lb, ubs[i])
        np.testing.assert_array_equal(batch[i].l, single.l)
        np.testing.assert_array_equal(batch[i].u, single.u)
        np.testing.assert_array_equal(batch[i].q, single.q)
        ref = solve(single, "clarabel", **TIGHT)
        assert sols[i].status is ref.status is Status.SOLVED
        np.testing.assert_allclose(sols[i].x, ref.x, atol=1e-12)
        np.testing.assert_allclose(sols[i].y, ref.y, atol=1e-10)


def test_batch_size_is_inferred_from_any_per_qp_argument():
    P, q, G, h, A, b, lb, ub = _form()
    for kw in (
        {"q": np.stack([q] * 3)},
        {"b": np.full((3, 1), -0.5)},
        {"lb": np.full((3, 3), -1.0)},
    ):
        args = {"P": P, "q": q, "G": G, "h": h, "A": A, "b": b, "lb": lb, "ub": ub} | kw
        assert QPBatch.from_qpsolvers(**args).batch_size == 3, kw
    one = QPBatch.from_qpsolvers(P, q, G, h, batch_size=2)  # everything shared: say how many
    assert one.batch_size == 2 and np.array_equal(one.q[0], one.q[1])
    with pytest.raises(ValueError, match="batch_size=B"):
        QPBatch.from_qpsolvers(P, q, G, h)


@pytest.mark.parametrize(
    "kw, msg",
    [
        ({"h": np.zeros((2, 1))}, r"h has 2 rows \(one per QP\) but q has 3"),
        ({"lb": np.zeros((4, 3))}, r"lb has 4 rows \(one per QP\) but q has 3"),
        ({"b": np.zeros((3, 2))}, r"b has shape \(3, 2\), expected \(1,\) .* or \(B, 1\)"),
        ({"ub": np.zeros(2)}, r"ub has shape \(2,\), expected \(3,\)"),
        ({"G": np.zeros((3, 1, 3))}, "G must be one 2-D matrix shared by every QP"),
        ({"h": np.array([[-np.inf]] * 3)}, r"h is -inf at \(QP, index\) \[\(0, 0\), \(1, 0\)"),
        ({"lb": np.full((3, 3), 3.0)}, r"lb > ub at \(QP, index\) \[\(0, 0\), \(0, 1\)"),
        ({"batch_size": 2}, "q has 3 rows .* but batch_size has 2"),
    ],
)
def test_bad_batch_arguments_raise_naming_the_users_argument(kw, msg):
    P, q, G, h, A, b, lb, ub = _form()
    args = {"P": P, "q": np.stack([q] * 3), "G": G, "h": h, "A": A, "b": b, "lb": lb, "ub": ub}
    with pytest.raises(ValueError, match=msg):
        QPBatch.from_qpsolvers(**(args | kw))


@pytest.mark.parametrize(
    "kw, msg",
    [
        ({"h": [-np.inf]}, r"h is -inf at index 0: G x ≤ -inf can never be met"),
        ({"lb": [np.inf, 0.0, 0.0], "ub": None}, r"lb is \+inf at index 0:"),
        ({"ub": [1.0, -np.inf, 1.0], "lb": None}, r"ub is -inf at index 1:"),
        ({"lb": [3.0, 0.0, 0.0]}, r"lb > ub at index 0 \(lb = 3, ub = "),
        ({"b": [np.inf]}, "b contains inf"),
        ({"h": [np.nan]}, "h contains NaN"),
    ],
)
def test_solve_qp_errors_name_h_lb_ub_not_the_internal_bounds(kw, msg):
    P, q, G, h, A, b, lb, ub = _form()
    args = {"P": P, "q": q, "G": G, "h": h, "A": A, "b": b, "lb": lb, "ub": ub} | kw
    with pytest.raises(ValueError, match=msg) as e:
        solve_qp(**args)
    text = str(e.value)
    assert not text.startswith(("l ", "u ")) and "l == u" not in text
    if "b" not in kw:
        assert "equality at infinity" not in text


# ------------------------------------------------------------------------------------- reprs
def test_reprs_are_one_short_line():
    sol = solve_qp(*_form())
    r = repr(sol)
    assert r.startswith("Solution(SOLVED, objective=") and "\n" not in r and len(r) < 160
    for part in ("n=3", "m=5", "backend='clarabel'", "solve_time="):
        assert part in r, part
    assert "tol_gap_abs" not in r and "settings" not in r  # not the backend's ~50 settings
    sols = solve_batch(_infeasible_batch(), "clarabel")
    rb = repr(sols)
    assert rb.startswith("BatchSolution(SOLVED 1, PRIMAL_INFEASIBLE 1; B=2") and "\n" not in rb
    assert "backend='clarabel'" in rb and "total_time=" in rb and len(rb) < 200
    assert repr(sol.problem) == "QP(n=3, m=5 (1 equalities), dense)"
    assert repr(_infeasible_batch()) == "QPBatch(B=2, n=2, m=3, dense)"
    assert isinstance(sols, BatchSolution) and str(sols) == rb


# -------------------------------------------------------------------------- solver= alias
def test_solver_is_an_alias_of_backend():
    args = _form()
    assert solve_qp(*args, solver="osqp").backend == "osqp"
    assert solve_qp(*args, backend="osqp", solver="osqp").backend == "osqp"
    assert solve(QP.from_qpsolvers(*args), solver="clarabel").backend == "clarabel"
    assert solve_batch(_infeasible_batch(), solver="clarabel").backend == "clarabel"
    with pytest.raises(ValueError, match="backend='clarabel' and solver='osqp'"):
        solve_qp(*args, backend="clarabel", solver="osqp")
    with pytest.raises(ValueError, match="backend='admm' and solver='clarabel'"):
        solve_batch(_infeasible_batch(), backend="admm", solver="clarabel")
    with pytest.raises(TypeError, match="solver must be a backend name"):
        solve_qp(*args, solver=3)  # type: ignore[arg-type]


def test_a_qpsolvers_solver_name_means_that_qpsolvers_backend():
    if "qpsolvers:piqp" not in available_backends():
        pytest.skip("qpsolvers with piqp not installed")
    sol = solve_qp(*_form(), solver="piqp")
    assert sol.backend == "qpsolvers:piqp" and sol.ok
    assert solve_qp(*_form(), backend="qpsolvers:piqp", solver="piqp").ok


def test_cvxpy_keeps_its_own_solver_setting():
    if "cvxpy" not in available_backends():
        pytest.skip("cvxpy not installed")
    sol = solve_qp(*_form(), backend="cvxpy", solver="CLARABEL")
    assert sol.backend == "cvxpy" and sol.settings["solver"] == "CLARABEL" and sol.ok


# -------------------------------------------------------------------- ipm listed everywhere
def test_ipm_is_listed_wherever_backends_are_listed():
    assert "``ipm``" in solvers.__doc__ and "``ipm``" in solvers.registry.__doc__
    readme = (REPO / "README.md").read_text()
    assert "| `ipm` | jax (core) |" in readme
    index = REPO / "docs" / "index.md"
    if index.exists():
        assert "interior-point" in index.read_text()
