"""Problem model: validation and format converters."""

import numpy as np
import pytest
import scipy.sparse as sp

from solvers import QP, QPBatch, solve


def _qp():
    P = np.array([[2.0, 0.5], [0.5, 1.0]])
    A = np.array([[1.0, 1.0], [1.0, 0.0], [0.0, 1.0]])
    return QP(P, np.array([1.0, 1.0]), A, np.array([1.0, 0.0, 0.0]), np.array([1.0, 0.7, 0.7]))


@pytest.mark.parametrize(
    "kw, msg",
    [
        ({"q": np.array([1.0, np.nan])}, "q contains NaN"),
        ({"P": np.ones((2, 3))}, r"^P has shape \(2, 3\), expected a square \(n, n\) matrix"),
        ({"P": np.eye(3)}, r"^q has shape \(2,\), expected \(3,\): n = 3 is the size of P"),
        ({"l": np.array([2.0, 0.0, 0.0])}, "infeasible bounds"),
        ({"A": np.ones((3, 3))}, "A has shape"),
        ({"P": np.array([[1.0, 2.0], [0.0, 1.0]])}, "symmetric"),
        ({"u": np.array([1.0, np.nan, 1.0])}, "u contains NaN"),
    ],
)
def test_bad_input_raises_value_error_naming_argument(kw, msg):
    base = _qp()
    args = {"P": base.P, "q": base.q, "A": base.A, "l": base.l, "u": base.u} | kw
    with pytest.raises(ValueError, match=msg):
        QP(**args)


# The size n comes from P and the other arguments are checked against it; indices in messages are
# plain ints.  Each message is stated in full: the argument it names is the one that is wrong.
_I2 = np.eye(2)
BLAME = [
    (
        lambda: QP(_I2, np.ones(3), A=_I2, l=[-1, -1], u=[1, 1]),
        "q has shape (3,), expected (2,): n = 2 is the size of P",
    ),
    (
        lambda: QP(_I2, np.ones(2), A=_I2, l=[1, -1], u=[0, 1]),
        "infeasible bounds: l > u at index 0 (l = 1, u = 0)",
    ),
    (
        lambda: QP(_I2, np.ones(2), A=_I2, l=[1, 2], u=[0, 1]),
        "infeasible bounds: l > u at indices [0, 1]",
    ),
    (
        lambda: QP(np.eye(7), np.ones(7), A=np.eye(7), l=np.ones(7), u=np.zeros(7)),
        "infeasible bounds: l > u at indices [0, 1, 2, 3, 4] (first 5 of 7)",
    ),
    (
        lambda: QP(np.ones((2, 3)), np.ones(2), A=_I2, l=[-1, -1], u=[1, 1]),
        "P has shape (2, 3), expected a square (n, n) matrix",
    ),
    (
        lambda: QP(_I2, np.ones(2), A=np.ones((2, 3)), l=[-1, -1], u=[1, 1]),
        "A has shape (2, 3), expected (2, 2)",
    ),
    (
        lambda: QP(_I2, np.ones(2), A=_I2, l=[np.inf, -1], u=[np.inf, 1]),
        "l is +inf at index 0: a lower bound of +inf can never be met (l == u == ±inf: an "
        "equality at infinity)",
    ),
    (
        lambda: QPBatch(_I2, _I2, np.ones((4, 3)), -np.ones((4, 2)), np.ones((4, 2))),
        "q has shape (4, 3), expected (4, 2): n = 2 is the size of P",
    ),
    (
        lambda: QPBatch(
            _I2, _I2, np.ones((4, 2)), np.diag([2.0, 0.0])[[1, 0, 1, 1]], np.ones((4, 2))
        ),
        "infeasible bounds: l > u at index 0 of QP 1 (l = 2, u = 1)",
    ),
    (
        lambda: QPBatch(_I2, _I2, np.ones((2, 2)), np.full((2, 2), 2.0), np.ones((2, 2))),
        "infeasible bounds: l > u at (QP, index) [(0, 0), (0, 1), (1, 0), (1, 1)]",
    ),
    (
        lambda: QP.from_qpsolvers(_I2, np.ones(3), G=[[1.0, 1.0]], h=[1.0]),
        "q has shape (3,), expected (2,): n = 2 is the size of P",
    ),
    (
        lambda: QP.from_qpsolvers(_I2, np.ones(2), G=[[1.0, 1.0, 1.0]], h=[1.0]),
        "G has shape (1, 3), expected (1, 2)",
    ),
    (
        lambda: QP.from_qpsolvers(_I2, np.ones(2), A=[[1.0, 1.0, 1.0]], b=[1.0]),
        "A has shape (1, 3), expected (1, 2)",
    ),
    (
        lambda: QP.from_qpsolvers(_I2, np.ones(2), A=[[1.0, 1.0]], b=[1.0, 2.0]),
        "b has shape (2,), expected (1,)",
    ),
    (
        lambda: QP.from_qpsolvers(_I2, np.ones(2), lb=[1.0, 0.0], ub=[0.0, 1.0]),
        "lb > ub at index 0 (lb = 1, ub = 0)",
    ),
    (
        lambda: QP.from_qpsolvers(_I2, np.ones(2), G=[[1.0, 1.0]], h=[-np.inf]),
        "h is -inf at index 0: G x ≤ -inf can never be met",
    ),
    (
        lambda: QP.from_qpsolvers(_I2, np.ones(2), ub=[1.0, -np.inf]),
        "ub is -inf at index 1: x ≤ -inf can never be met",
    ),
    (
        lambda: QPBatch.from_qpsolvers(_I2, np.ones((3, 3)), G=[[1.0, 1.0]], h=[1.0]),
        "q has shape (3, 3), expected (2,) (shared by every QP) or (B, 2) (one row per QP): "
        "n = 2 is the size of P",
    ),
    (
        lambda: QPBatch.from_qpsolvers(
            _I2, np.ones((3, 2)), lb=np.array([[0, 0], [1, 0], [0, 0]]), ub=[0.5, 1.0]
        ),
        "lb > ub at index 0 of QP 1 (lb = 1, ub = 0.5)",
    ),
    (
        lambda: QPBatch.from_qpsolvers(
            _I2, np.ones((3, 2)), G=[[1.0, 1.0]], h=np.array([[1.0], [-np.inf], [1.0]])
        ),
        "h is -inf at index 0 of QP 1: G x ≤ -inf can never be met",
    ),
]


@pytest.mark.parametrize("make, message", BLAME, ids=[m[:24] for _, m in BLAME])
def test_messages_name_the_argument_that_is_wrong_with_plain_indices(make, message):
    with pytest.raises(ValueError) as e:
        make()
    assert str(e.value) == message


def test_solve_qp_messages_match_from_qpsolvers():
    from solvers import solve_qp

    with pytest.raises(ValueError, match=r"^q has shape \(3,\), expected \(2,\): n = 2"):
        solve_qp(_I2, np.ones(3), lb=[0.0, 0.0], ub=[1.0, 1.0], solver="clarabel")
    with pytest.raises(ValueError, match=r"^lb > ub at index 0 \(lb = 1, ub = 0\)$"):
        solve_qp(_I2, np.ones(2), lb=[1.0, 0.0], ub=[0.0, 1.0], solver="clarabel")


def test_qpsolvers_round_trip_preserves_optimum():
    qp = _qp()
    back = QP.from_qpsolvers(**qp.to_qpsolvers())
    a, b = solve(qp, "clarabel"), solve(back, "clarabel")
    np.testing.assert_allclose(a.x, b.x, atol=1e-7)
    assert abs(a.objective - b.objective) < 1e-8


def test_sparse_and_dense_give_same_solution():
    qp = _qp()
    qs = QP(sp.csc_matrix(qp.P), qp.q, sp.csc_matrix(qp.A), qp.l, qp.u)
    np.testing.assert_allclose(solve(qp, "clarabel").x, solve(qs, "clarabel").x, atol=1e-8)


def test_batch_validates_leading_axis_and_indexes_to_qps():
    qp = _qp()
    with pytest.raises(ValueError, match="leading batch axis"):
        QPBatch(qp.P, qp.A, qp.q, qp.l, qp.u)
    batch = QPBatch(qp.P, qp.A, np.stack([qp.q, -qp.q]), np.stack([qp.l] * 2), np.stack([qp.u] * 2))
    assert len(batch) == 2 and batch[1].q[0] == -1.0
    with pytest.raises(ValueError, match="empty batch"):
        QPBatch(qp.P, qp.A, np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 3)))


def test_clarabel_duals_follow_osqp_convention():
    sol = solve(_qp(), "clarabel")
    assert sol.dual_residual < 1e-7 and sol.primal_residual < 1e-7
