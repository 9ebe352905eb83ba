"""Projection QP: feasibility on each backend, fixed points, user rows, batched ADMM, bad inputs."""

import numpy as np
import pytest

import solvers
from frenet import EgoState, LinearConstraints, ProjectionBounds, ProjectionProblem

from .conftest import (
    BACKENDS,
    SLOW,
    backend_settings,
    backend_tol,
    make_basis,
    make_planner,
    sample_d,
)


def _samples(num, kind="bernstein", seed=0, state=None):
    planner = make_planner(kind)
    state = state or EgoState()
    cx, cy = planner.closed_form(sample_d(num, seed=seed), state)
    return planner, np.asarray(cx), np.asarray(cy), state


@pytest.mark.parametrize("backend", BACKENDS)
def test_projected_trajectories_satisfy_every_constraint(backend):
    # control-point ("hull") rows keep this cheap and non-degenerate for first-order backends;
    # the grid rows are exercised below and in test_user_constraints_are_honoured
    planner, cx, cy, st = _samples(2 if backend in SLOW else 6, seed=1)
    prob = ProjectionProblem(planner.basis, constraint_points="hull")
    before, _ = prob.residuals(cx, cy, st)
    assert before.max() > 0.5  # the samples do violate the lane / speed bounds
    res = prob.project(cx, cy, st, backend=backend, **backend_settings(backend))
    ok = np.isin(res.status, [int(solvers.Status.SOLVED), int(solvers.Status.SOLVED_INACCURATE)])
    assert ok.all(), res.solution.status_counts()
    tol = 10 * backend_tol(backend)
    assert res.residual.max() <= tol, {k: float(v.max()) for k, v in res.residual_groups.items()}
    # and it is the projection: no farther than Clarabel's optimum (up to tolerance)
    ref = prob.project(cx, cy, st, backend="clarabel")
    np.testing.assert_allclose(res.distance, ref.distance, rtol=1e-3, atol=1e-3)


@pytest.mark.parametrize("backend", ["clarabel", "osqp"])
def test_grid_rows_projection_is_feasible(backend):
    if backend not in BACKENDS:
        pytest.skip(f"{backend} not installed")
    planner, cx, cy, st = _samples(4, seed=11)
    prob = ProjectionProblem(planner.basis)
    res = prob.project(cx, cy, st, backend=backend, **backend_settings(backend))
    assert res.residual.max() <= 10 * backend_tol(backend)


def test_triple_integrator_projection_is_feasible():
    planner, cx, cy, st = _samples(2, kind="triple", seed=2)
    prob = ProjectionProblem(planner.basis, metric="coefficient")
    res = prob.project(cx, cy, st, backend="clarabel")
    assert res.solved.all() and res.residual.max() <= 1e-6


def test_residual_groups_name_each_constraint_and_total_is_their_max():
    planner, cx, cy, st = _samples(5, seed=3)
    prob = ProjectionProblem(planner.basis, ProjectionBounds(a_max=6.0))
    total, groups = prob.residuals(cx, cy, st)
    assert set(groups) == {
        "boundary",
        "lane",
        "speed",
        "lateral_velocity",
        "accel_x",
        "accel_y",
        "accel_norm",
    }
    np.testing.assert_allclose(total, np.max(np.stack(list(groups.values())), axis=0))
    assert groups["boundary"].max() < 1e-9  # plans meet the boundary conditions already


@pytest.mark.parametrize("metric", ["waypoint", "coefficient"])
def test_feasible_trajectory_is_returned_unchanged(metric):
    planner = make_planner("bernstein")
    st = EgoState(vs=10.0)
    d = np.array(
        [[10.0, 9.0, 8.0, 8.0, 0.1, 0.1, 0.0, 0.0], [10.0, 10.0, 10.0, 10.0, 0.0, 0.0, 0.0, 0.0]]
    )
    cx, cy = map(np.asarray, planner.closed_form(d, st))
    prob = ProjectionProblem(planner.basis, metric=metric)
    assert prob.residuals(cx, cy, st)[0].max() < 1e-9
    tight = {"tol_gap_abs": 1e-12, "tol_gap_rel": 1e-12, "tol_feas": 1e-12, "tol_ktratio": 1e-10}
    res = prob.project(cx, cy, st, backend="clarabel", **tight)
    tr, tr0 = planner.trajectories(res.cx, res.cy), planner.trajectories(cx, cy)
    np.testing.assert_allclose(tr.x, tr0.x, atol=1e-5)
    np.testing.assert_allclose(tr.y, tr0.y, atol=1e-6)
    np.testing.assert_allclose(tr.vx, tr0.vx, atol=1e-5)
    assert res.distance.max() < 1e-8


def test_admm_batch_equals_loop_over_clarabel_on_200_projections():
    if "admm" not in solvers.available_backends():
        pytest.skip("the 'admm' backend is not available yet (solvers/admm.py)")
    planner, cx, cy, st = _samples(200, seed=4)
    # control-point rows: non-degenerate, so ADMM converges on every sample (see docs)
    prob = ProjectionProblem(planner.basis, constraint_points="hull")
    batch = prob.batch(cx, cy, st)
    ref = np.stack([solvers.solve(qp, backend="clarabel").x for qp in batch])
    res = prob.project(cx, cy, st, backend="admm", **backend_settings("admm"))
    assert res.solved.all(), res.solution.status_counts()
    n, P = planner.basis.nvar, planner.basis.P
    np.testing.assert_allclose(res.cx @ P.T, ref[:, :n] @ P.T, atol=5e-2)
    np.testing.assert_allclose(res.cy @ P.T, ref[:, n:] @ P.T, atol=1e-2)
    assert res.residual.max() <= 1e-4


def test_user_constraints_are_honoured_including_per_sample_bounds():
    planner, cx, cy, st = _samples(4, seed=5)
    K = planner.basis.num_steps
    zone = LinearConstraints.at_steps(
        range(50, K), nx=1.0, ny=0.0, upper=6.0, num_steps=K, quantity="velocity", name="speed_zone"
    )
    # per-sample "stay behind" half-plane at step 80: x_80 ≤ h_b
    h = np.array([[40.0], [45.0], [50.0], [55.0]])
    behind = LinearConstraints.at_steps(
        [80], nx=1.0, ny=0.0, lower=-np.inf, upper=h, num_steps=K, name="behind"
    )
    prob = ProjectionProblem(planner.basis, extra=[zone, behind])
    res = prob.project(cx, cy, st, backend="clarabel")
    assert res.solved.all()
    tr = planner.trajectories(res.cx, res.cy)
    assert tr.vx[:, 50:].max() <= 6.0 + 1e-6
    assert np.all(tr.x[:, 80] <= h[:, 0] + 1e-6)
    assert (
        res.residual_groups["speed_zone"].max() <= 1e-6
        and res.residual_groups["behind"].max() <= 1e-6
    )
    # the bounds can be swapped per call without rebuilding the problem
    res2 = prob.project(
        cx, cy, st, backend="clarabel", extra_bounds=[(-np.inf, 6.0), (-np.inf, h - 5.0)]
    )
    assert np.all(planner.trajectories(res2.cx, res2.cy).x[:, 80] <= h[:, 0] - 5.0 + 1e-6)


def test_acceleration_norm_polygon_is_conservative():
    planner, cx, cy, st = _samples(4, seed=6)
    prob = ProjectionProblem(
        planner.basis, ProjectionBounds(a_max=1.0, ax_max=np.inf, ay_max=np.inf)
    )
    res = prob.project(cx, cy, st, backend="clarabel")
    tr = planner.trajectories(res.cx, res.cy)
    assert np.hypot(tr.ax, tr.ay).max() <= 1.0 + 1e-6


@pytest.mark.parametrize(
    "call, msg",
    [
        (
            lambda p, cx, cy: p.project(cx, cy, EgoState(vs=35.0), backend="clarabel"),
            "initial speed",
        ),
        (
            lambda p, cx, cy: p.project(cx, cy, EgoState(d=1.0), backend="clarabel"),
            "lateral offset",
        ),
        (lambda p, cx, cy: p.batch(cx[:, :5], cy[:, :5], EgoState()), "shape"),
        (lambda p, cx, cy: p.batch(cx * np.nan, cy, EgoState()), "NaN"),
        (lambda p, cx, cy: p.batch(cx, cy, np.tile(EgoState().as_array(), (3, 1))), "batch size"),
    ],
)
def test_bad_inputs_raise(call, msg):
    planner, cx, cy, _ = _samples(2, seed=7)
    prob = ProjectionProblem(planner.basis)
    with pytest.raises(ValueError, match=msg):
        call(prob, cx, cy)


def test_bad_problem_definitions_raise():
    basis = make_basis("bernstein")
    with pytest.raises(ValueError, match="y_lb > y_ub"):
        ProjectionProblem(basis, ProjectionBounds(y_lb=1.0, y_ub=0.0))
    with pytest.raises(ValueError, match="shape"):
        ProjectionProblem(basis, ProjectionBounds(vx_max=np.ones(7)))
    wrong_k = LinearConstraints(np.zeros((1, 50)), np.zeros((1, 50)), upper=1.0)
    with pytest.raises(ValueError, match="K=100"):
        ProjectionProblem(basis, extra=wrong_k)
    with pytest.raises(ValueError, match="metric"):
        ProjectionProblem(basis, metric="l1")


def test_hull_mode_is_feasible_at_every_step_and_more_conservative():
    planner, cx, cy, st = _samples(6, seed=8)
    grid = ProjectionProblem(planner.basis)
    hull = ProjectionProblem(planner.basis, constraint_points="hull")
    assert hull.num_rows < grid.num_rows / 5
    rg = grid.project(cx, cy, st, backend="clarabel")
    rh = hull.project(cx, cy, st, backend="clarabel")
    assert rh.solved.all() and rh.residual.max() <= 1e-7  # residuals measured at the grid steps
    # feasible between grid steps too (convex-hull property)
    t = np.linspace(0, planner.basis.grid.horizon, 1001)
    Pf = planner.basis.evaluate(t)[0]
    assert np.abs(rh.cy @ Pf.T).max() <= 0.3 + 1e-7
    assert np.all(rh.distance >= rg.distance - 1e-6)


def _admm_core_available() -> bool:
    try:
        from solvers.admm import admm_factor, admm_iterate  # noqa: F401
    except ImportError:
        return False
    return True


@pytest.mark.skipif(not _admm_core_available(), reason="solvers.admm functional core not present")
def test_jax_projector_matches_clarabel_inside_jit_and_warm_starts():
    import jax

    planner, cx, cy, st = _samples(64, seed=9)
    K = planner.basis.num_steps
    zone = LinearConstraints.at_steps(
        range(60, K), nx=1.0, ny=0.0, upper=7.0, num_steps=K, quantity="velocity", name="zone"
    )
    prob = ProjectionProblem(planner.basis, extra=zone, constraint_points="hull")
    proj = jax.jit(prob.jax_projector(num_iters=500))
    out = proj(cx, cy, st.as_array())
    ref = prob.project(cx, cy, st, backend="clarabel")
    # ADMM at a fixed budget: most samples converge, a few are still ~1 cm off
    res = np.asarray(out.residual)
    assert np.median(res) <= 1e-3 and res.max() <= 5e-2
    np.testing.assert_allclose(
        res, prob.residuals(np.asarray(out.cx, float), np.asarray(out.cy, float), st)[0], atol=1e-4
    )
    # and it is (nearly) the projection: distance close to Clarabel's optimum for most samples
    gap = prob.distance(np.asarray(out.cx, float), np.asarray(out.cy, float), cx, cy) - ref.distance
    assert np.median(np.abs(gap)) < 0.1 and np.percentile(np.abs(gap), 90) < 1.0, gap
    # warm start from the previous state, bounds given per sample: stays near the solution
    again = proj(
        cx,
        cy,
        st.as_array(),
        extra_bounds=[(-np.inf, np.full((64, K - 60), 7.0))],
        warm_start=out.admm,
    )
    assert again.groups["zone"].shape == (64,)
    assert float(np.median(again.residual)) <= 2 * np.median(res) + 1e-4


@pytest.mark.skipif(not _admm_core_available(), reason="solvers.admm functional core not present")
def test_jax_projector_starts_every_trajectory_at_the_ego_state_even_with_few_iterations():
    """A short fixed ADMM budget (Algorithm 1 uses 10 iterations) leaves the boundary rows ~1e-4
    off; the projector's final equality correction makes them exact: boundary residual ≤ 1e-5
    (float32) for every sample."""
    import jax

    planner, cx, cy, st = _samples(64, seed=3)
    prob = ProjectionProblem(planner.basis, constraint_points="hull")
    out = jax.jit(prob.jax_projector(num_iters=5))(cx, cy, st.as_array())
    _, groups = prob.residuals(np.asarray(out.cx, float), np.asarray(out.cy, float), st)
    assert groups["boundary"].max() <= 1e-5, groups["boundary"].max()


def test_per_sample_rows_such_as_linearised_half_planes_are_honoured():
    planner, cx, cy, st = _samples(3, seed=12)
    K = planner.basis.num_steps
    # one half-plane n_b·(x_k, y_k) ≤ h_b per sample at k = 70, with a different normal each
    normals = np.array([[1.0, 0.0], [0.8, 0.6], [0.6, -0.8]])
    Gx, Gy = np.zeros((3, 1, K)), np.zeros((3, 1, K))
    Gx[:, 0, 70], Gy[:, 0, 70] = normals[:, 0], normals[:, 1]
    h = np.array([[30.0], [35.0], [25.0]])
    hp = LinearConstraints(Gx, Gy, lower=-np.inf, upper=h, name="halfplane")
    prob = ProjectionProblem(planner.basis, extra=hp)
    res = prob.project(cx, cy, st, backend="clarabel")
    assert res.solved.all() and res.residual.max() <= 1e-6
    tr = planner.trajectories(res.cx, res.cy)
    assert np.all(normals[:, 0] * tr.x[:, 70] + normals[:, 1] * tr.y[:, 70] <= h[:, 0] + 1e-6)
    with pytest.raises(ValueError, match="per-sample rows"):
        prob.batch(cx, cy, st)
    with pytest.raises(ValueError, match="rows for 3 samples"):
        prob.project(cx[:2], cy[:2], st, backend="clarabel")


@pytest.mark.skipif(not _admm_core_available(), reason="solvers.admm functional core not present")
def test_jax_projector_split_by_axis_reaches_the_joint_projection():
    """Without coupling rows the projection splits into one QP per axis: at a converged budget
    both forms give Clarabel's projection (distance within 1e-3 relative for 90 % of the
    samples, float32), the
    per-group residuals agree, and the split's ADMM state (joint row order) warm-starts the
    joint projector."""
    import jax

    planner, cx, cy, st = _samples(64, seed=5)
    prob = ProjectionProblem(planner.basis, constraint_points="hull")
    split = jax.jit(prob.jax_projector(num_iters=500, split_axes=True))
    joint = jax.jit(prob.jax_projector(num_iters=500, split_axes=False))
    a, b = split(cx, cy, st.as_array()), joint(cx, cy, st.as_array())
    ref = prob.project(cx, cy, st, backend="clarabel")
    for out in (a, b):
        gap = prob.distance(np.asarray(out.cx, float), np.asarray(out.cy, float), cx, cy)
        rel = np.abs(gap - ref.distance) / np.maximum(ref.distance, 1.0)
        assert np.percentile(rel, 90) < 1e-3, np.percentile(rel, 90)
        assert np.median(np.asarray(out.residual)) <= 1e-3
    assert set(a.groups) == set(b.groups)
    for name in a.groups:
        np.testing.assert_allclose(a.groups[name], b.groups[name], atol=2e-3)
    assert a.admm.y.shape == b.admm.y.shape == (64, prob.num_rows)
    again = joint(cx, cy, st.as_array(), warm_start=a.admm)
    assert float(np.median(again.residual)) <= 2 * float(np.median(a.residual)) + 1e-4
    zone = LinearConstraints.at_steps(
        range(60, 100), nx=1.0, ny=0.0, upper=7.0, num_steps=100, quantity="velocity"
    )
    with pytest.raises(ValueError, match="split_axes"):
        ProjectionProblem(planner.basis, extra=zone).jax_projector(split_axes=True)
    with pytest.raises(ValueError, match="split_axes"):
        prob.jax_projector(split_axes="yes")
