"""The one-call API, the common settings vocabulary, warm starts as arrays, convexity refusal,
lazy backend discovery and one meaning for ``backend="admm"``."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import solvers
from solvers import (
    COMMON_SETTINGS,
    QP,
    Backend,
    InvalidSettingError,
    NonConvexError,
    QPBatch,
    Solution,
    Status,
    available_backends,
    get_backend,
    solve,
    solve_batch,
    solve_qp,
)
from solvers.examples import projection_like_batch, random_feasible_qp

from .conftest import reference
from .tolerances import tol_for

REPO = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------- solve_qp / from_qpsolvers
def _qpsolvers_form():
    """min ½‖x‖² + [1, −1]·x  s.t.  x0 + x1 ≤ 0.25, x0 − x1 = −1, −2 ≤ x ≤ 2."""
    P = np.eye(2)
    q = np.array([1.0, -1.0])
    G, h = np.array([[1.0, 1.0]]), np.array([0.25])
    A, b = np.array([[1.0, -1.0]]), np.array([-1.0])
    lb, ub = np.full(2, -2.0), np.full(2, 2.0)
    return P, q, G, h, A, b, lb, ub


def test_solve_qp_is_from_qpsolvers_then_solve(backend, tol):
    args = _qpsolvers_form()
    sol = solve_qp(*args, backend=backend, **tol.settings)
    qp = QP.from_qpsolvers(*args)
    ref = reference(qp)
    assert sol.status is Status.SOLVED and sol.backend == backend
    np.testing.assert_allclose(sol.x, ref.x, atol=max(tol.x_atol, 1e-6) * 2)
    # rows are [G; A; I]: the inequality, the equality, then the two bounds
    assert qp.m == 4 and qp.u[0] == 0.25 and qp.l[1] == qp.u[1] == -1.0
    assert sol.y.shape == (4,)


def test_solve_qp_docstring_example():
    sol = solve_qp(np.eye(2), [1.0, -1.0], G=[[1.0, 1.0]], h=[0.0], lb=[-0.5, -0.5], ub=[1, 1])
    assert sol.status is Status.SOLVED
    np.testing.assert_allclose(sol.x, [-0.5, 0.5], atol=1e-7)


def test_from_qpsolvers_keeps_dense_or_sparse():
    import scipy.sparse as sp

    P, q, G, h, A, b, lb, ub = _qpsolvers_form()
    assert isinstance(QP.from_qpsolvers(P, q, G, h, A, b, lb, ub).A, np.ndarray)
    assert sp.issparse(QP.from_qpsolvers(sp.csc_matrix(P), q, G, h, A, b, lb, ub).A)
    assert QP.from_qpsolvers(P, q).m == 0  # unconstrained


# ----------------------------------------------------------------------------- common settings
def test_unknown_setting_is_the_same_error_on_every_backend(backend):
    qp = random_feasible_qp(3, 2, 1, seed=0)
    with pytest.raises(InvalidSettingError, match="unknown setting 'eps_typo'.*valid names: ") as e:
        solve(qp, backend, eps_typo=1.0)
    assert "eps_abs" in str(e.value) and isinstance(e.value, ValueError)
    batch = projection_like_batch(2, horizon=6)
    with pytest.raises(InvalidSettingError, match="'eps_typo'"):
        solve_batch(batch, backend, eps_typo=1.0)


def test_common_settings_are_recorded_on_every_backend(backend, tol):
    """Each common name given is recorded (its value, or "ignored"), and the answer is right."""
    qp = random_feasible_qp(4, 3, 1, seed=1)
    common = {"eps_abs": 1e-7, "eps_rel": 1e-7, "max_iter": 5000, "time_limit": 30.0}
    sol = solve(qp, backend, verbose=False, warm_start=(np.zeros(4), None), **common)
    for k in (*common, "verbose", "warm_start"):
        assert k in sol.settings, k
    assert sol.settings["warm_start"] == (
        "used" if get_backend(backend).honours_warm_start else "ignored"
    )
    for k, v in common.items():
        assert sol.settings[k] in (v, "ignored"), (k, sol.settings[k])
    assert sol.status in (Status.SOLVED, Status.SOLVED_INACCURATE), sol.status
    assert set(COMMON_SETTINGS) == {*common, "verbose", "warm_start"}


@pytest.mark.parametrize(
    "backend_name, common, native",
    [
        ("clarabel", {"eps_abs": 1e-6}, {"tol_gap_abs": 1e-6, "tol_feas": 1e-6}),
        ("clarabel", {"eps_rel": 1e-6, "max_iter": 7}, {"tol_gap_rel": 1e-6, "max_iter": 7}),
        ("clarabel", {"time_limit": 5.0}, {"time_limit": 5.0}),
        ("osqp", {"eps_abs": 1e-6, "time_limit": 5.0}, {"eps_abs": 1e-6, "time_limit": 5.0}),
        (
            "qpsolvers:scs",
            {"max_iter": 123, "time_limit": 5.0},
            {"max_iters": 123, "time_limit_secs": 5.0},
        ),
        (
            "qpsolvers:daqp",
            {"eps_abs": 1e-7, "max_iter": 99},
            {"primal_tol": 1e-7, "iter_limit": 99},
        ),
        ("qpsolvers:piqp", {"eps_abs": 1e-7, "time_limit": 5.0}, {"eps_abs": 1e-7}),
        ("qpsolvers:quadprog", {"eps_abs": 1e-7, "max_iter": 5}, {}),
        ("admm", {"eps_abs": 1e-6, "max_iter": 50}, {"eps_abs": 1e-6, "max_iter": 50}),
    ],
)
def test_common_names_map_to_native_names(backend_name, common, native):
    if backend_name not in available_backends():
        pytest.skip(f"{backend_name} not installed")
    n, rec = get_backend(backend_name).native_settings(common)
    assert n == native
    for k, v in common.items():
        mapped = k in ("eps_abs", "eps_rel", "max_iter", "time_limit") and any(
            val == v for val in native.values()
        )
        assert rec[k] == (v if mapped else "ignored"), (k, rec)


def test_native_name_wins_over_the_common_one():
    n, rec = get_backend("clarabel").native_settings({"eps_abs": 1e-6, "tol_feas": 1e-9})
    assert n == {"tol_gap_abs": 1e-6, "tol_feas": 1e-9} and rec == {"eps_abs": 1e-6}
    sol = solve(random_feasible_qp(3, 2, 0, seed=2), "clarabel", eps_abs=1e-6, tol_feas=1e-9)
    assert sol.settings["tol_feas"] == 1e-9 and sol.settings["tol_gap_abs"] == 1e-6


def test_warm_start_as_arrays_equals_warm_start_from_a_solution():
    pytest.importorskip("osqp")
    batch = projection_like_batch(4, horizon=30, seed=5)
    kw = dict(eps_abs=1e-6, eps_rel=1e-6, max_iter=50_000)
    cold = solve_batch(batch, "osqp", **kw)
    warm_sol = solve_batch(batch, "osqp", warm_start=cold, **kw)
    warm_arr = solve_batch(batch, "osqp", warm_start=(cold.x, cold.y), **kw)
    np.testing.assert_array_equal(warm_sol.iterations, warm_arr.iterations)
    np.testing.assert_array_equal(warm_sol.x, warm_arr.x)
    assert warm_arr.iterations.sum() < cold.iterations.sum()
    assert warm_arr.settings["warm_start"] == "used"
    one = solve(batch[0], "osqp", warm_start=(cold.x[0], cold.y[0]), **kw)
    assert one.ok and one.iterations <= cold.iterations[0]


# ---------------------------------------------------------------------------------- convexity
def test_non_convex_p_is_refused_never_solved(backend):
    """The issue's reproducer: x = 0 is a saddle; no backend may return it as SOLVED."""
    P = np.diag([1.0, -1.0])
    with pytest.raises(NonConvexError, match="P is not positive semidefinite"):
        QP(P, [0.0, 0.0], np.eye(2), [-1.0, -1.0], [1.0, 1.0])
    with pytest.raises(NonConvexError, match="check_convex=False"):
        solve_qp(P, [0.0, 0.0], lb=[-1.0, -1.0], ub=[1.0, 1.0], backend=backend)
    unchecked = QP(P, [0.0, 0.0], np.eye(2), [-1.0, -1.0], [1.0, 1.0], check_convex=False)
    with pytest.raises(NonConvexError):
        solve(unchecked, backend, check_convex=True)
    if backend == "admm":
        with pytest.raises(NonConvexError):
            solve(unchecked, backend, check_convex=True, fallback="clarabel")


def test_psd_singular_and_rounding_level_matrices_are_accepted():
    rng = np.random.default_rng(0)
    M = rng.standard_normal((6, 3))
    QP(M @ M.T, np.zeros(6), np.zeros((0, 6)), np.zeros(0), np.zeros(0))  # rank 3, PSD
    QP(np.zeros((3, 3)), np.ones(3), np.eye(3), -np.ones(3), np.ones(3))  # an LP
    Pn = M @ M.T - 1e-9 * np.eye(6)  # rounding-level negative eigenvalues
    QP(Pn, np.zeros(6), np.zeros((0, 6)), np.zeros(0), np.zeros(0))


def test_batch_checks_p_once_not_per_problem():
    b = projection_like_batch(3, horizon=6)
    assert b[0]._convex_checked and not b[0].check_convex  # inherited, not recomputed


# ------------------------------------------------------------------------------ admm: one meaning
def test_backend_admm_without_settings_is_the_registry_backend():
    from solvers.admm import ADMMBackend, ADMMSettings

    be = get_backend("admm")
    assert type(be) is ADMMBackend
    batch = projection_like_batch(2, horizon=8)
    plain = solve_batch(batch, "admm")
    explicit = solve_batch(batch, "admm", **ADMMSettings().as_dict())
    assert plain.settings == ADMMSettings().as_dict()
    np.testing.assert_array_equal(plain.x, explicit.x)
    np.testing.assert_array_equal(plain.status, explicit.status)


def test_admm_final_check_refuses_a_diverged_or_floor_failing_point():
    """The float64 last word: a SOLVED point with ‖x‖ blown up is ERROR; one whose residual is
    within OSQP's relative test but not the absolute floor is SOLVED_INACCURATE."""
    from solvers.admm import ADMMSettings
    from solvers.admm.backend import _final_check

    b = QPBatch(np.eye(2), np.eye(2), np.zeros((3, 2)), -np.ones((3, 2)), np.ones((3, 2)))
    x = np.array([[0.5, 0.5], [3e10, 0.0], [1.0 + 1e-3, 0.0]])
    prim = b.constraint_violation(x)
    status = np.full(3, int(Status.SOLVED), np.int32)
    out, diverged, floor = _final_check(b, x, prim, status, ADMMSettings(eps_abs=1e-5))
    assert [Status(int(s)) for s in out] == [Status.SOLVED, Status.ERROR, Status.SOLVED_INACCURATE]
    assert diverged.tolist() == [False, True, False] and floor.tolist() == [False, True, True]


def test_admm_infeasibility_claims_are_rechecked_in_float64():
    """A certificate that does not hold on the unscaled data in float64 is no claim: MAX_ITER."""
    from solvers.admm import ADMMSettings
    from solvers.admm.backend import _recheck_certificates

    A = np.array([[1.0, 0.0], [1.0, 0.0]])  # x0 ≥ 1 and x0 ≤ 0: primal infeasible
    l = np.array([[1.0, -np.inf], [1.0, -np.inf]])
    u = np.array([[np.inf, 0.0], [np.inf, 0.0]])
    b = QPBatch(np.eye(2), A, np.zeros((2, 2)), l, u)
    status = np.full(2, int(Status.PRIMAL_INFEASIBLE), np.int32)
    dy = np.array([[-1.0, 1.0], [1.0, 1.0]])  # a true certificate, and one that is not
    out = _recheck_certificates(b, np.eye(2), A, status, np.zeros((2, 2)), dy, ADMMSettings())
    assert out.tolist() == [False, True]
    sol = solve(b[0], "admm")
    assert sol.status is Status.PRIMAL_INFEASIBLE and not sol.extras["certificate_rejected"][0]


# -------------------------------------------------------------------------------- residual flag
class _IgnoresConstraints(Backend):
    """A real but sloppy solver: returns the unconstrained minimiser and calls it SOLVED."""

    name = "ignores-constraints"

    def solve(self, qp, *, warm_start=None, **settings):
        P = qp.P if isinstance(qp.P, np.ndarray) else qp.P.toarray()
        x = np.linalg.solve(P, -qp.q)
        y = np.zeros(qp.m)
        return Solution(
            x,
            y,
            Status.SOLVED,
            qp.objective(x),
            1,
            0.0,
            qp.constraint_violation(x),
            qp.dual_residual(x, y),
            self.name,
        )


def test_a_wrong_solved_is_flagged_not_hidden(monkeypatch):
    from solvers import registry as reg

    monkeypatch.setattr(reg, "_USER", dict(reg._USER))
    monkeypatch.setattr(reg, "_CACHE", dict(reg._CACHE))
    solvers.register_backend("ignores-constraints", _IgnoresConstraints)
    qp = QP(np.eye(2), [-5.0, 0.0], np.eye(2), [-1.0, -1.0], [1.0, 1.0])
    sol = solve(qp, "ignores-constraints")
    rc = sol.extras["residual_check"]
    assert rc["result"] == "failed" and rc["primal_residual"] == pytest.approx(4.0)  # flagged ...
    # ... and not SOLVED: x = (5, 0) violates x0 ≤ 1 by 80 % of the row's scale, far beyond any
    # tolerance, so the answer check calls it an unconverged iterate (kept for inspection)
    assert sol.status is Status.MAX_ITER
    assert sol.extras["check"]["status_before"] == "SOLVED" and sol.extras["check"]["reason"]
    np.testing.assert_array_equal(sol.x, [5.0, 0.0])
    good = solve(qp, "clarabel")
    assert good.extras["residual_check"]["result"] == "passed"


# --------------------------------------------------------------------------------- osqp NaN
@pytest.mark.parametrize("kind", ["primal", "dual"])
def test_osqp_nan_placeholder_is_never_read_as_a_point(kind):
    pytest.importorskip("osqp")
    if kind == "primal":
        A = np.array([[1.0, 0.0], [1.0, 0.0]])
        qp = QP(np.eye(2), np.ones(2), A, [1.0, -np.inf], [np.inf, 0.0])
        want, cert = Status.PRIMAL_INFEASIBLE, "prim_inf_cert"
    else:
        qp = QP(np.zeros((2, 2)), -np.ones(2), np.eye(2), [-1.0, -1.0], [np.inf, 1.0])
        want, cert = Status.DUAL_INFEASIBLE, "dual_inf_cert"
    sol = solve(qp, "osqp")
    assert sol.status is want and cert in sol.extras
    assert np.all(np.isnan(sol.x)) and np.all(np.isnan(sol.y))
    assert np.isnan(sol.objective) and np.isnan(sol.primal_residual)
    assert not np.any(sol.x == 2143289344.0)


# ---------------------------------------------------------------------------- import isolation
def _fresh(code: str) -> dict:
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_available_backends_imports_no_solver_package():
    out = _fresh(
        "import json, sys, solvers\n"
        "names = solvers.available_backends()\n"
        "print(json.dumps({'names': names, 'loaded': [m for m in ('cvxpy', 'osqp', 'qpsolvers',"
        " 'jax', 'mmdopt', 'frenet') if m in sys.modules]}))"
    )
    assert out["loaded"] == []
    assert set(out["names"]) == set(available_backends())


def test_import_frenet_does_not_import_mmdopt_or_cvxpy():
    out = _fresh(
        "import json, sys, frenet\n"
        "mods = ('mmdopt', 'cvxpy', 'qpsolvers', 'osqp')\n"
        "print(json.dumps([m for m in mods if m in sys.modules]))"
    )
    assert out == []


def test_errors_module_has_no_package_imports():
    """solvers.errors is the leaf every module imports (no circle through the registry)."""
    src = (REPO / "solvers" / "errors.py").read_text()
    assert "from ." not in src and "import solvers" not in src
    src_q = (REPO / "solvers" / "qpsolvers_.py").read_text()
    assert "registry" not in src_q
    assert tol_for("clarabel").settings  # the tolerance table still imports


def test_readme_qp_backends_example_runs_unchanged():
    """The README's "QP backends" code block, executed as written, on every available backend."""
    text = (REPO / "README.md").read_text()
    section = text[text.index("## QP backends") :]
    block = section.split("```python", 1)[1].split("```", 1)[0]
    ns: dict = {}
    exec(compile(block, "README.md", "exec"), ns)  # noqa: S102
    assert ns["sol"].ok and ns["sols"].all_solved and ns["sols"].settings["warm_start"] == "used"
    for name in available_backends():
        sol = solve(ns["qp"], name, eps_abs=1e-6, eps_rel=1e-6)
        assert sol.status in (Status.SOLVED, Status.SOLVED_INACCURATE), (name, sol.status)
        np.testing.assert_allclose(sol.x, [-0.5, 1.0], atol=1e-2)
