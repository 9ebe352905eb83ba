"""The batched interior-point backend ``ipm``: agreement with Clarabel, row kinds, batches,
infeasibility, Maros–Meszaros, determinism, input validation, the jittable core.

Every JAX shape compiles once (seconds), so the cases are grouped on a few shapes: random QPs
with n = 8 and m = 10 rows of every kind, a (2, 2) pair for the infeasible cases, a projection
batch (banded path), and two Maros–Meszaros problems of one shape.
"""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
import scipy.io as sio
import scipy.sparse as sp

from solvers import QP, InvalidSettingError, QPBatch, Status, solve, solve_batch
from solvers.examples import projection_like_batch
from solvers.ipm import IPMSettings, ipm_iterate, ipm_setup, ipm_solve

from .conftest import MM_DIR
from .tolerances import REFERENCE_SETTINGS

#: agreement with tight Clarabel (ipm at its defaults, eps 1e-9)
OBJ_RTOL = 1e-8
X_ATOL = 1e-6
FEAS_ATOL = 1e-8


def _random_qp(seed: int, n: int = 8) -> QP:
    """Feasible, bounded QP with rows of every kind: two-sided, lower-only, upper-only,
    equality and free (both bounds infinite); P positive semidefinite of rank n − 2 plus a
    small ridge (so the QP is bounded whatever the rows)."""
    rng = np.random.default_rng(seed)
    M = rng.normal(size=(n, n - 2))
    P = M @ M.T + 1e-3 * np.eye(n)
    q = rng.normal(size=n)
    x0 = rng.normal(size=n)
    G = rng.normal(size=(7, n))
    gx = G @ x0
    sl = rng.uniform(0.1, 1.0, 7)
    lo = gx - sl
    hi = gx + sl[::-1]
    lo[[2, 3]] = -np.inf  # upper-only rows
    hi[[4, 5]] = np.inf  # lower-only rows
    lo[6], hi[6] = -np.inf, np.inf  # a free row
    Ae = rng.normal(size=(2, n))
    box = np.eye(n)[:1]  # |x_0| ≤ 5
    A = np.vstack([G, Ae, box])
    l = np.concatenate([lo, Ae @ x0, [-5.0]])
    u = np.concatenate([hi, Ae @ x0, [5.0]])
    return QP(P, q, A, l, u)


def _reference(qp: QP):
    ref = solve(qp, "clarabel", **REFERENCE_SETTINGS)
    assert ref.ok, ref.status
    return ref


@pytest.fixture(scope="module")
def random_qps() -> list[QP]:
    return [_random_qp(seed) for seed in range(6)]


def test_random_qps_agree_with_clarabel(random_qps):
    for qp in random_qps:
        ref = _reference(qp)
        sol = solve(qp, backend="ipm")
        assert sol.status is Status.SOLVED, sol.status
        fs = max(1.0, abs(ref.objective))
        assert abs(sol.objective - ref.objective) <= OBJ_RTOL * fs
        assert qp.constraint_violation(sol.x) <= FEAS_ATOL
        xs = max(1.0, float(np.max(np.abs(ref.x))))
        assert np.max(np.abs(sol.x - ref.x)) <= X_ATOL * xs
        # duals in OSQP's convention, as Clarabel's mapped ones: Px + q + Aᵀy = 0
        assert sol.dual_residual <= 1e-7 * max(1.0, float(np.max(np.abs(ref.y))))
        ys = max(1.0, float(np.max(np.abs(ref.y))))
        assert np.max(np.abs(sol.y - ref.y)) <= 1e-5 * ys
        assert sol.x.dtype == np.float64 and sol.y.dtype == np.float64


def test_equality_and_free_rows(random_qps):
    qp = random_qps[0]
    sol = solve(qp, backend="ipm")
    eq = qp.l == qp.u
    free = np.isinf(qp.l) & np.isinf(qp.u)
    assert eq.sum() == 2 and free.sum() == 1
    Ax = qp.A @ sol.x
    np.testing.assert_allclose(Ax[eq], qp.l[eq], atol=1e-9)
    assert np.all(sol.y[free] == 0.0)  # a free row carries no multiplier
    # upper-only rows: y ≥ 0; lower-only rows: y ≤ 0 (OSQP sign convention)
    up_only = np.isinf(qp.l) & np.isfinite(qp.u)
    lo_only = np.isfinite(qp.l) & np.isinf(qp.u)
    assert np.all(sol.y[up_only] >= -1e-9) and np.all(sol.y[lo_only] <= 1e-9)


def test_batch_shares_p_and_a_and_matches_clarabel():
    batch = projection_like_batch(8, horizon=40, seed=1)
    sol = solve_batch(batch, backend="ipm")
    ref = solve_batch(batch, backend="clarabel", **REFERENCE_SETTINGS)
    assert ref.all_solved
    assert sol.all_solved, sol.status_counts()
    assert sol.extras["linear_solver"] == "banded"  # RCM leaves M banded (half-bandwidth 2)
    rel = np.abs(sol.objective - ref.objective) / np.maximum(1.0, np.abs(ref.objective))
    assert rel.max() <= OBJ_RTOL
    assert batch.constraint_violation(sol.x).max() <= FEAS_ATOL * np.abs(sol.x).max()
    assert sol.x.shape == (8, batch.n) and sol.y.shape == (8, batch.m)


def test_infeasible_problems_get_their_status():
    # each batch: one infeasible QP beside a feasible one with the same P and A (the feasible
    # one must still be solved: an infeasible QP does not spoil the batch)
    # primal infeasible: x₀ ≥ 1 and x₀ ≤ 0; its neighbour: x₀ ≥ −1, x₀ ≤ 2
    A = np.array([[1.0, 0.0], [1.0, 0.0]])
    q = np.array([[1.0, 1.0], [1.0, -1.0]])
    l = np.array([[1.0, -np.inf], [-1.0, -np.inf]])
    u = np.array([[np.inf, 0.0], [np.inf, 2.0]])
    sol = solve_batch(QPBatch(np.eye(2), A, q, l, u), backend="ipm")
    assert sol.status.tolist() == [int(Status.PRIMAL_INFEASIBLE), int(Status.SOLVED)]
    # the neighbour is degenerate (its unconstrained minimiser −1 lies on the bound x₀ ≥ −1, with
    # a zero multiplier): the duality gap is met to 1e-9, and x₀ converges as its square root
    np.testing.assert_allclose(sol.x[1], [-1.0, 1.0], atol=1e-4)
    assert sol[1].is_optimal(1e-8)
    # dual infeasible (unbounded below): min −x₀ s.t. x₀ ≥ 0 with P = diag(0, 1); its
    # neighbour has x₀ ≤ 3
    q = np.array([[-1.0, 0.0], [-1.0, 0.0]])
    l = np.array([[0.0, -1.0], [0.0, -1.0]])
    u = np.array([[np.inf, 1.0], [3.0, 1.0]])
    sol = solve_batch(QPBatch(np.diag([0.0, 1.0]), np.eye(2), q, l, u), backend="ipm")
    assert sol.status.tolist() == [int(Status.DUAL_INFEASIBLE), int(Status.SOLVED)]
    np.testing.assert_allclose(sol.x[1], [3.0, 0.0], atol=1e-8)


def test_max_iter_is_reported():
    qp = _random_qp(0)
    sol = solve(qp, backend="ipm", max_iter=2)
    assert sol.status is Status.MAX_ITER and sol.iterations == 2


def _load_mm(name: str) -> tuple[QP, float, float]:
    m = sio.loadmat(MM_DIR / f"{name}.mat")
    P = sp.csc_matrix(m["P"], dtype=np.float64)
    P = (P + P.T) / 2

    def vec(k):
        return np.asarray(m[k], dtype=np.float64).reshape(-1)

    r = float(vec("r")[0]) if "r" in m else 0.0
    qp = QP(P, vec("q"), sp.csc_matrix(m["A"], dtype=np.float64), vec("l"), vec("u"))
    f_star = json.loads((MM_DIR / "optimal_objectives.json").read_text())[name]
    return qp, r, f_star


@pytest.mark.parametrize("name", ["HS51", "HS52"])  # one shape (n = 5, m = 8): one compile
def test_maros_meszaros_published_optimum(name):
    if not (MM_DIR / f"{name}.mat").is_file():
        pytest.skip(f"Maros–Meszaros data absent at {MM_DIR} (see its README)")
    qp, r, f_star = _load_mm(name)
    sol = solve(qp, backend="ipm")
    assert sol.status is Status.SOLVED
    assert abs(sol.objective + r - f_star) <= 1e-6 * max(1.0, abs(f_star))
    assert qp.constraint_violation(sol.x) <= 1e-8


def test_deterministic(random_qps):
    a = solve(random_qps[1], backend="ipm")
    b = solve(random_qps[1], backend="ipm")
    assert np.array_equal(a.x, b.x) and np.array_equal(a.y, b.y)
    assert a.iterations == b.iterations


def test_functional_core_is_jittable_and_leaves_x64_alone(random_qps):
    x64_before = bool(jax.config.jax_enable_x64)
    qp = random_qps[2]
    P, A = qp.dense()
    setup = ipm_setup(P, A, IPMSettings())
    with jax.enable_x64(True):

        @jax.jit
        def user_fn(q, l, u):  # e.g. a planner's inner loop
            res = ipm_iterate(setup, q, l, u)
            return res.x, res.status

        x, status = user_fn(qp.q, qp.l, qp.u)
        assert x.dtype == np.float64 and int(status) == int(Status.SOLVED)
    res = ipm_solve(P, A, qp.q, qp.l, qp.u)
    np.testing.assert_allclose(np.asarray(x), np.asarray(res.x), atol=1e-12)
    np.testing.assert_allclose(np.asarray(res.x), solve(qp, backend="ipm").x, atol=1e-12)
    assert bool(jax.config.jax_enable_x64) == x64_before


def test_input_validation(random_qps):
    qp = random_qps[0]
    with pytest.raises(InvalidSettingError, match="unknown setting 'rho'"):
        solve(qp, backend="ipm", rho=1.0)
    with pytest.raises(ValueError, match="max_iter"):
        IPMSettings(max_iter=0)
    with pytest.raises(ValueError, match="step_fraction"):
        IPMSettings(step_fraction=1.0)
    with pytest.raises(ValueError, match="linear_solver"):
        IPMSettings(linear_solver="sparse")
    with pytest.raises(ValueError, match="eps_abs"):
        IPMSettings(eps_abs=float("nan"))
    with pytest.raises(ValueError, match="P and A must be finite"):
        ipm_setup(np.eye(2), np.array([[np.nan, 0.0]]))
    with pytest.raises(ValueError, match="symmetric"):
        ipm_setup(np.array([[1.0, 1.0], [0.0, 1.0]]), np.eye(2))
    with pytest.raises(ValueError, match=r"A must have shape"):
        ipm_setup(np.eye(2), np.eye(3))
    setup = ipm_setup(*qp.dense())
    with jax.enable_x64(True), pytest.raises(ValueError, match="last dimensions"):
        ipm_iterate(setup, np.zeros(3), qp.l, qp.u)
    if not jax.config.jax_enable_x64:
        with pytest.raises(RuntimeError, match="enable_x64"):
            ipm_iterate(setup, qp.q, qp.l, qp.u)


@pytest.mark.parametrize(
    "key, value",
    [("step_fraction", "x"), ("reg_primal", None), ("eps_abs", [1e-9]), ("band_ratio", True)],
)
def test_ipm_setting_of_the_wrong_type_is_refused_naming_it(key, value):
    qp = QP(np.eye(2), np.ones(2), np.eye(2), -np.ones(2), np.ones(2))
    with pytest.raises(ValueError, match=key):
        solve(qp, backend="ipm", **{key: value})
