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
        ({"P": np.ones((3, 3))}, "P has shape"),
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
