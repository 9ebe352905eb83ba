"""The batched JAX ADMM backend (``admm``): agreement with Clarabel, statuses, batching, jit, dtypes
and the functional core.  Each test states its tolerance.

(``tests/solvers/test_backends.py`` runs the generic backend tests, and the Maros–Meszaros set,
over ``admm`` too, with the ``admm`` row of ``tolerances.py``.)  Shapes and settings are kept few,
because each distinct ``(batch, n, m, settings)`` costs one XLA compile of ~1–2 s.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

import solvers.admm.backend as admm_backend
import solvers.admm.core as admm_core
from solvers import QP, QPBatch, Status, solve, solve_batch
from solvers.admm import ADMMSettings, admm_factor, admm_iterate, rows_from_bounds
from solvers.examples import projection_like_batch, random_feasible_qp

from .tolerances import REFERENCE_SETTINGS

#: settings for projection-like QPs (explicit: no Ruiz scaling suits this shape, see the docs)
PROJ = {"scaling_iter": 0, "max_iter": 4000}


def _ref(qp: QP):
    r = solve(qp, "clarabel", **REFERENCE_SETTINGS)
    assert r.ok
    return r


def _agree(sol, ref, qp, *, x_rtol, f_rtol, feas):
    xs = max(1.0, float(np.max(np.abs(ref.x))))
    assert sol.status is Status.SOLVED, sol.status
    assert np.max(np.abs(sol.x - ref.x)) <= x_rtol * xs
    assert abs(sol.objective - ref.objective) <= f_rtol * max(1.0, abs(ref.objective))
    assert qp.constraint_violation(sol.x) <= feas * xs


# ----------------------------------------------------------------------------- settings


def test_unknown_setting_is_rejected_by_name():
    b = projection_like_batch(2, horizon=8)
    with pytest.raises(ValueError, match="rho_typo"):
        solve_batch(b, "admm", rho_typo=1.0)
    with pytest.raises(ValueError, match="dtype"):
        ADMMSettings(dtype="float16")


def test_settings_used_are_recorded_and_defaults_kept():
    b = projection_like_batch(2, horizon=8)
    sol = solve_batch(b, "admm", eps_abs=1e-6)
    want = ADMMSettings(eps_abs=1e-6).as_dict()
    assert sol.settings == want
    assert sol.settings["eps_rel"] == ADMMSettings().eps_rel  # untouched default
    assert sol.extras["fallback_count"] == 0 and "polish_accepted" in sol.extras


def test_large_n_warns(monkeypatch):
    monkeypatch.setattr(admm_backend, "DENSE_N_WARN", 4)
    b = projection_like_batch(1, horizon=8)
    with pytest.warns(UserWarning, match="densifies"):
        solve_batch(b, "admm", max_iter=25)


# ------------------------------------------------------------------ agreement with Clarabel


@pytest.mark.parametrize("seed", range(6))
def test_random_feasible_qps_match_clarabel(seed):
    """Random QPs with equality rows and infinite bounds: x to 1e-6, f to 1e-8 (polished)."""
    qp = random_feasible_qp(8, 10, 2, seed=seed, sparse=bool(seed % 2))
    assert np.isinf(qp.l).any() or np.isinf(qp.u).any()
    sol = solve(qp, "admm")
    _agree(sol, _ref(qp), qp, x_rtol=1e-6, f_rtol=1e-8, feas=1e-7)


def test_projection_like_batch_matches_clarabel():
    """Every QP of a projection-like batch: SOLVED, x to 1e-6, f to 1e-8, violation ≤ 1e-7."""
    batch = projection_like_batch(8, horizon=30, seed=1)
    sol = solve_batch(batch, "admm", **PROJ)
    assert sol.extras["polish_accepted"] == len(batch)
    for i, qp in enumerate(batch):
        _agree(sol[i], _ref(qp), qp, x_rtol=1e-6, f_rtol=1e-8, feas=1e-7)


def test_defaults_solve_a_projection_batch_exactly():
    """At its defaults (a fixed step, stages of 200 iterations, the polish between them) every QP
    of a projection batch is SOLVED at Clarabel's point: x to 1e-6, violation ≤ 1e-7."""
    batch = projection_like_batch(12, horizon=40, seed=3)
    sol = solve_batch(batch, "admm")
    assert sol.settings["stage_iter"] == 200 and not sol.settings["adaptive_rho"]
    for i, qp in enumerate(batch):
        _agree(sol[i], _ref(qp), qp, x_rtol=1e-6, f_rtol=1e-8, feas=1e-7)


def test_the_polish_never_moves_a_point_further_outside_its_bounds():
    """A polished point replaces the ADMM iterate only if it is no further outside the bounds
    (unless exact to 1e-3 of the tolerance).  The QP here (two axes in blocks, rows of tens of
    metres, a near-degenerate corner: seven rows within 1 mm of a bound at the optimum) once came
    back SOLVED from a polished point 1.9e-4 outside, inside the relative tolerance, where the
    iterate it replaced was 3e-5 outside.  Now it ends inside 1e-4, SOLVED or MAX_ITER."""
    qp_families = pytest.importorskip("benchmarks.qp_families")
    batch = qp_families.blocks_batch(100, seed=0)
    one = QPBatch(P=batch.P, A=batch.A, q=batch.q[86:87], l=batch.l[86:87], u=batch.u[86:87])
    sol = solve_batch(one, "admm")
    A = batch.A.toarray() if hasattr(batch.A, "toarray") else np.asarray(batch.A)
    ax = np.asarray(sol.x) @ A.T
    viol = np.max(np.maximum(np.maximum(one.l - ax, ax - one.u), 0.0))
    assert int(sol.status[0]) in (Status.SOLVED, Status.MAX_ITER)
    if int(sol.status[0]) == Status.SOLVED:
        assert viol <= 1e-4
    assert viol <= 1e-4  # the last iterate too, here


def test_active_guess_is_osqps_rule():
    """The polish's guess: at the lower bound where z − l < −y, at the upper where u − z < y,
    equalities always at the lower; nothing where both bounds are infinite."""
    from solvers.admm.polish import PolishData, active_guess

    pd = PolishData(*(np.eye(1),) * 5, E=np.ones(5), c=1.0)
    l = np.array([[0.0, 0.0, 0.0, 1.0, -np.inf]])
    u = np.array([[1.0, 1.0, 1.0, 1.0, np.inf]])
    z = np.array([[0.01, 0.99, 0.5, 1.0, 3.0]])
    y = np.array([[-0.1, 0.1, 0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(active_guess(pd, l, u, z, y), [[-1, 1, 0, -1, 0]])


def test_new_settings_are_checked_by_name():
    with pytest.raises(ValueError, match="rho_patience"):
        ADMMSettings.from_kwargs(rho_patience=0)
    s = ADMMSettings.from_kwargs(polish_stage_passes=2, polish_settle_rows=0, rho_patience=None)
    assert (s.polish_stage_passes, s.polish_settle_rows, s.rho_patience) == (2, 0, None)
    assert s.as_dict()["rho_patience"] is None


def test_patient_rho_tries_both_neighbours_of_the_start():
    """A QP still unsolved after every ``rho_patience`` iterations tries the rungs around its
    start: first the side the residual-balancing rule points to, then the other, then further."""
    batch = projection_like_batch(1, horizon=12, seed=0)
    P, A = (np.asarray(m) for m in batch.dense())
    s = ADMMSettings.from_kwargs(rho_patience=100)
    run = admm_backend._Run.start(batch, None, s)
    lad = np.asarray(s.rho_ladder)
    start = int(np.argmin(np.abs(np.log(lad) - np.log(s.rho))))
    seen = []
    for stage in range(1, 9):
        run.iters[:] = 50 * stage  # stages of 50 iterations: a move every second stage
        admm_backend._patient_rho(run, P, A, batch.q, batch.l, batch.u, np.array([0]), 50, s)
        seen.append(int(np.argmin(np.abs(np.log(lad) - np.log(run.rho[0])))) - start)
    side = seen[1]
    assert side in (1, -1)
    assert seen == [0, side, side, -side, -side, 2 * side, 2 * side, -2 * side]


def test_no_polish_still_within_admm_tolerance():
    """Without polish: SOLVED means the OSQP test holds; f to 1e-3 relative of Clarabel."""
    batch = projection_like_batch(8, horizon=30, seed=1)
    sol = solve_batch(batch, "admm", polish=False, **PROJ)
    for i, qp in enumerate(batch):
        if sol.status[i] == Status.SOLVED:
            ref = _ref(qp)
            assert abs(sol.objective[i] - ref.objective) <= 1e-3 * max(1, abs(ref.objective))
            assert sol.primal_residual[i] <= 1e-5 + 1e-5 * np.max(np.abs(batch.A @ sol.x[i]))


# ------------------------------------------------------------------------- infeasibility


def test_infeasible_problems_get_their_certificate_in_a_batch():
    batch = projection_like_batch(3, horizon=12, seed=5)
    l, u = batch.l.copy(), batch.u.copy()
    l[1, 0], u[1, 0] = 5.0, 6.0  # x0 ∈ [5, 6] contradicts the boundary row x0 = 0
    sol = solve_batch(QPBatch(batch.P, batch.A, batch.q, l, u), "admm", **PROJ)
    assert Status(int(sol.status[1])) is Status.PRIMAL_INFEASIBLE
    assert sol.status[0] == Status.SOLVED and sol.status[2] == Status.SOLVED


def test_dual_infeasible_is_detected():
    # min −x2 + ½x1² with x2 unbounded above: unbounded
    qp = QP(
        np.diag([1.0, 0.0]),
        np.array([0.0, -1.0]),
        np.eye(2),
        np.array([-1.0, 0.0]),
        np.array([1.0, np.inf]),
    )
    assert solve(qp, "admm").status is Status.DUAL_INFEASIBLE


def test_nan_guard_reports_error_not_solved():
    qp = QP(np.eye(2), np.array([3e38, -3e38]), np.eye(2), -np.ones(2), np.ones(2))
    sol = solve(qp, "admm", polish=False, scaling_iter=0, max_iter=50)
    assert sol.status is Status.ERROR


# -------------------------------------------------------------- batching, jit, warm start


def test_solve_batch_equals_loop_of_solve():
    """Same statuses; x equal to 1e-9 relative (the factor and the per-QP iteration are shared)."""
    batch = projection_like_batch(3, horizon=12, seed=2)
    bs = solve_batch(batch, "admm", **PROJ)
    for i, qp in enumerate(batch):
        one = solve(qp, "admm", **PROJ)
        assert int(bs.status[i]) == int(one.status)
        np.testing.assert_allclose(bs.x[i], one.x, atol=1e-9 * max(1, np.abs(one.x).max()))


def test_no_recompile_for_new_data_of_the_same_shape():
    b1 = projection_like_batch(3, horizon=12, seed=3)
    b2 = projection_like_batch(3, horizon=12, seed=4)
    solve_batch(b1, "admm", **PROJ)
    n0 = admm_core.admm_iterate_jit._cache_size()
    solve_batch(b2, "admm", **PROJ)
    assert admm_core.admm_iterate_jit._cache_size() == n0


def test_warm_start_from_previous_batch_needs_no_more_iterations():
    batch = projection_like_batch(3, horizon=12, seed=3)
    first = solve_batch(batch, "admm", **PROJ)
    again = solve_batch(batch, "admm", warm_start=first, **PROJ)
    assert again.all_solved
    assert again.iterations.max() <= first.iterations.max()
    np.testing.assert_allclose(again.x, first.x, atol=1e-7 * max(1, np.abs(first.x).max()))


def _tiny():
    P = np.array([[2.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]])
    A = np.vstack([np.eye(3), [[1.0, 1.0, 1.0]]])
    rng = np.random.default_rng(0)
    q = rng.normal(size=(4, 3))
    l = np.tile([-1.0, -1.0, -np.inf, 0.5], (4, 1))
    u = np.tile([1.0, 1.0, 0.2, 0.5], (4, 1))  # last row an equality
    return P, A, q, l, u


@pytest.mark.parametrize("dtype, atol", [("float64", 1e-10), ("float32", 1e-4)])
def test_jitted_equals_eager_on_a_tiny_batch(dtype, atol):
    """The functional core, jitted vs ``jax.disable_jit()``: x equal to 1e-10 in float64; 1e-4 in
    float32 (XLA fuses differently; 20 ADMM steps amplify float32 rounding to ~3e-5)."""
    P, A, q, l, u = _tiny()
    eq, free = rows_from_bounds(l, u)
    with jax.enable_x64(dtype == "float64"):
        f = admm_factor(P, A, ADMMSettings(check_every=5, dtype=dtype), eq_rows=eq, free_rows=free)
        jitted = jax.jit(lambda q, l, u: admm_iterate(f, q, l, u, iters=20))(q, l, u)
        with jax.disable_jit():
            eager = admm_iterate(f, q, l, u, iters=20)
        assert jitted.x.dtype == np.dtype(dtype)
        np.testing.assert_allclose(np.asarray(jitted.x), np.asarray(eager.x), atol=atol)
        np.testing.assert_array_equal(np.asarray(jitted.status), np.asarray(eager.status))


def test_core_vmaps_over_single_problems_like_the_batch():
    """``vmap`` of the core over 1-D problems equals the batched call (x to 1e-5, float32).
    The core alone has no polish: OSQP's adaptive rho from 0.1 suits these general small QPs."""
    P, A, q, l, u = _tiny()
    eq, free = rows_from_bounds(l, u)
    s = ADMMSettings(rho=0.1, adaptive_rho=True)
    f = admm_factor(P, A, s, eq_rows=eq, free_rows=free)
    batched = admm_iterate(f, q, l, u, iters=300)
    vm = jax.jit(jax.vmap(lambda q, l, u: admm_iterate(f, q, l, u, iters=300)))(q, l, u)
    assert vm.x.shape == (4, 3)
    np.testing.assert_allclose(np.asarray(vm.x), np.asarray(batched.x), atol=1e-5)
    assert np.all(np.asarray(batched.status) == Status.SOLVED)
    # the answers are right: Clarabel to the ADMM tolerance (1e-5 abs + rel)
    for i in range(4):
        r = _ref(QP(P, q[i], A, l[i], u[i]))
        assert np.max(np.abs(np.asarray(batched.x[i]) - r.x)) <= 1e-3


def test_float32_and_float64_agree():
    """Polished float32 and float64 runs agree to 1e-7 in x (both polish in float64)."""
    batch = projection_like_batch(3, horizon=12, seed=6)
    s32 = solve_batch(batch, "admm", **PROJ)
    s64 = solve_batch(batch, "admm", dtype="float64", **PROJ)
    assert s32.all_solved and s64.all_solved
    np.testing.assert_allclose(s32.x, s64.x, atol=1e-7 * max(1, np.abs(s64.x).max()))


def test_fallback_is_visible_and_counted():
    batch = projection_like_batch(3, horizon=12, seed=7)
    sol = solve_batch(
        batch,
        "admm",
        max_iter=25,
        polish=False,
        fallback="clarabel",
        **{k: v for k, v in PROJ.items() if k != "max_iter"},
    )
    assert sol.settings["fallback"] == "clarabel"
    assert sol.extras["fallback_count"] == sol.extras["fallback_attempted"] > 0
    assert sol.all_solved


def test_fixed_rung_fast_path_equals_the_ladder_dispatch():
    """One check chunk (no rho update can happen before the end) runs K⁻¹ as one fixed matrix;
    forcing the general per-QP rung dispatch (an explicit ``rho0`` on the same rung) gives the
    same iterate to 1e-10 (float64), and the same status."""
    P, A, q, l, u = _tiny()
    eq, free = rows_from_bounds(l, u)
    with jax.enable_x64(True):
        s = ADMMSettings(check_every=30, dtype="float64", rho=0.5)
        f = admm_factor(P, A, s, eq_rows=eq, free_rows=free)
        fast = admm_iterate(f, q, l, u, iters=30)
        ladder = admm_iterate(f, q, l, u, iters=30, rho0=np.full(4, 0.5))
        np.testing.assert_allclose(np.asarray(fast.x), np.asarray(ladder.x), atol=1e-10)
        np.testing.assert_allclose(np.asarray(fast.y), np.asarray(ladder.y), atol=1e-10)
        np.testing.assert_array_equal(np.asarray(fast.status), np.asarray(ladder.status))


# ------------------------------------------------------------------- products over the nonzeros
def _banded_batch(B: int = 4, N: int = 40, seed: int = 0) -> QPBatch:
    """Positions ``x_0..x_{N-1}`` tracking a target under bounds on ``x_k``, ``Δx_k`` and
    ``Δ²x_k`` (three nonzeros a row at most: ``auto`` picks the sparse products)."""
    rng = np.random.default_rng(seed)
    D1 = np.diff(np.eye(N), axis=0)
    D2 = np.diff(np.eye(N), 2, axis=0)
    A = np.vstack([np.eye(N), D1, D2])
    P = np.eye(N) + 10.0 * D2.T @ D2
    ref = np.cumsum(np.full(N, 0.5))
    ub = np.concatenate([ref + 1.0, np.full(N - 1, 0.8), np.full(N - 2, 0.05)])
    lb = np.concatenate([ref - 1.0, np.full(N - 1, 0.2), np.full(N - 2, -0.05)])
    q = -(ref + rng.normal(0, 2.0, (B, N)))
    return QPBatch(P, A, q, np.tile(lb, (B, 1)), np.tile(ub, (B, 1)))


def test_sparse_pattern_products_equal_the_matrix():
    """``Āx`` and ``Āᵀw`` over the padded nonzero lists equal the dense products (float64),
    rows and columns of different lengths and an all-zero row included."""
    rng = np.random.default_rng(3)
    A = rng.normal(size=(7, 5)) * (rng.random((7, 5)) < 0.4)
    A[2] = 0.0
    pat = admm_core.sparse_pattern(A)
    x, w = rng.normal(size=5), rng.normal(size=7)
    np.testing.assert_allclose(np.sum(pat.rvals * x[pat.rows], axis=1), A @ x, atol=1e-14)
    np.testing.assert_allclose(np.sum(pat.cvals * w[pat.cols], axis=1), A.T @ w, atol=1e-14)
    assert pat.rows.shape[1] == max(1, int((A != 0).sum(axis=1).max()))
    with pytest.raises(ValueError, match="A must be 2-D"):
        admm_core.sparse_pattern(np.ones(3))


def test_products_setting_is_checked_and_auto_picks_by_density():
    with pytest.raises(ValueError, match="products must be"):
        ADMMSettings(products="csr")
    b = _banded_batch()
    assert admm_factor(b.P, b.A).sparse is not None  # ≤ 3 nonzeros a row of 40 columns
    assert admm_factor(b.P, b.A, ADMMSettings(products="dense")).sparse is None
    P, A, *_ = _tiny()  # 3 columns: every row is dense
    assert admm_factor(P, A).sparse is None
    assert admm_factor(P, A, ADMMSettings(products="sparse")).sparse is not None


def test_sparse_products_give_the_dense_iterates_and_the_same_answer():
    """The same ADMM on a banded family with products over the nonzeros and as matmuls: the
    iterates agree to 1e-9 (float64, 300 iterations, per-QP rungs), and the backend's answers
    agree with Clarabel to 1e-6 both ways (polished)."""
    b = _banded_batch()
    eq, free = rows_from_bounds(b.l, b.u)
    with jax.enable_x64(True):
        out = {}
        for products in ("dense", "sparse"):
            s = ADMMSettings(dtype="float64", products=products, check_every=25)
            f = admm_factor(b.P, b.A, s, eq_rows=eq, free_rows=free)
            out[products] = admm_iterate(f, b.q, b.l, b.u, iters=300)
        scale = max(1.0, float(np.abs(np.asarray(out["dense"].x)).max()))
        np.testing.assert_allclose(
            np.asarray(out["sparse"].x), np.asarray(out["dense"].x), atol=1e-9 * scale
        )
        np.testing.assert_array_equal(np.asarray(out["sparse"].rho), np.asarray(out["dense"].rho))
    for products in ("dense", "sparse"):
        sol = solve_batch(b, "admm", products=products, max_iter=4000)
        assert sol.all_solved
        for i in range(len(b)):
            r = _ref(b[i])
            assert np.max(np.abs(sol.x[i] - r.x)) <= 1e-6 * max(1.0, np.abs(r.x).max())
