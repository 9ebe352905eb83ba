"""The differentiable projection (``ProjectionProblem.differentiable_projector``): the same
optimum as the host projection, gradients that agree with finite differences, batches, and the
NaN-with-status convention for a QP that is not solved."""

from __future__ import annotations

import numpy as np
import pytest

jax = pytest.importorskip("jax")

import jax.numpy as jnp  # noqa: E402

import solvers  # noqa: E402
from frenet import (  # noqa: E402
    BernsteinBasis,
    EgoState,
    LinearConstraints,
    ProjectionBounds,
    ProjectionProblem,
    TimeGrid,
)

STATE = EgoState(vs=11.0)
TIGHT = {"eps_abs": 1e-11, "eps_rel": 1e-11}
SETTINGS = {"ipm": TIGHT, "admm": {**TIGHT, "max_iter": 20000}}  # admm: polished
CLARABEL_TIGHT = {"tol_gap_abs": 1e-12, "tol_gap_rel": 1e-12, "tol_feas": 1e-12}


def _problem() -> ProjectionProblem:
    basis = BernsteinBasis(TimeGrid(5.0, 20), degree=6)
    return ProjectionProblem(basis, ProjectionBounds(y_lb=-0.5, y_ub=0.5, vx_max=12.0))


def _samples(prob: ProjectionProblem, num: int = 1, seed: int = 0):
    """Least-squares fits of trajectories that leave the lane and exceed the speed limit (so the
    lane and speed rows are active at the projection, strictly: nonzero multipliers)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 5.0, prob.basis.num_steps)
    cxs, cys = [], []
    for _ in range(num):
        a, w = rng.uniform(0.3, 0.5), rng.uniform(0.8, 1.0)
        x = 11.0 * t + a * t**2
        y = w * np.sin(t)
        cxs.append(np.linalg.lstsq(prob.basis.P, x, rcond=None)[0])
        cys.append(np.linalg.lstsq(prob.basis.P, y, rcond=None)[0])
    return np.array(cxs), np.array(cys)


@pytest.mark.slow
def test_projection_matches_clarabel():
    prob = _problem()
    cx, cy = _samples(prob, 3)
    # Clarabel's default tolerances leave ~5e-5 in these coefficients (OSQP polished agrees
    # with the tight solve to 1e-8): compare with a tight solve
    ref = prob.project(cx, cy, STATE, backend="clarabel", **CLARABEL_TIGHT)
    assert np.all(ref.solved)
    with jax.enable_x64(True):  # x64 only inside this block
        proj = jax.jit(prob.differentiable_projector(**TIGHT))
        out = proj(cx, cy, STATE.as_array())
        assert np.all(np.asarray(out.status) == int(solvers.Status.SOLVED))
        np.testing.assert_allclose(out.cx, ref.cx, atol=1e-6)
        np.testing.assert_allclose(out.cy, ref.cy, atol=1e-6)
        one = prob.differentiable_projector(**TIGHT)(cx[1], cy[1], STATE)  # one sample
        np.testing.assert_allclose(one.cy, ref.cy[1], atol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["ipm", "admm"])
def test_gradients_agree_with_finite_differences(method):
    prob = _problem()
    cx, cy = _samples(prob)
    cx, cy = cx[0], cy[0]
    K = prob.basis.num_steps
    Pm = prob.basis.P
    with jax.enable_x64(True):  # x64 only inside this block
        proj = prob.differentiable_projector(method, **SETTINGS[method])

        def loss(cx_bar, y_ub, vx_max, w):
            out = proj(cx_bar, cy, STATE.as_array(), {"y_ub": y_ub, "vx_max": vx_max}, w)
            px, py = Pm @ out.cx, Pm @ out.cy
            return jnp.sum(px**2) / K + jnp.sum(py**2)

        args = (jnp.asarray(cx), jnp.asarray(0.5), jnp.asarray(12.0), jnp.ones((2, K)))
        f = jax.jit(loss)
        grads = jax.jit(jax.grad(loss, argnums=(0, 1, 2, 3)))(*args)
        assert all(np.all(np.isfinite(g)) for g in grads)
        assert abs(float(grads[1])) > 1e-3 and abs(float(grads[2])) > 1e-3  # active bounds

        h = 1e-4

        def fd(i, direction):
            plus = list(args)
            minus = list(args)
            plus[i] = args[i] + h * direction
            minus[i] = args[i] - h * direction
            return (float(f(*plus)) - float(f(*minus))) / (2 * h)

        e = np.zeros(prob.nvar)
        for j in (0, 3, prob.nvar - 1):
            e[:] = 0.0
            e[j] = 1.0
            assert fd(0, jnp.asarray(e)) == pytest.approx(float(grads[0][j]), rel=1e-5, abs=1e-8)
        assert fd(1, 1.0) == pytest.approx(float(grads[1]), rel=1e-5)
        assert fd(2, 1.0) == pytest.approx(float(grads[2]), rel=1e-5)
        ew = np.zeros((2, K))
        for axis, k in ((0, 10), (1, 7), (1, 15)):
            ew[:] = 0.0
            ew[axis, k] = 1.0
            g = float(grads[3][axis, k])
            assert fd(3, jnp.asarray(ew)) == pytest.approx(g, rel=1e-5, abs=1e-8)


@pytest.mark.slow
def test_vmap_over_a_batch_equals_one_by_one():
    prob = _problem()
    cx, cy = _samples(prob, 4, seed=1)
    with jax.enable_x64(True):  # x64 only inside this block
        proj = prob.differentiable_projector(**TIGHT)
        batched = jax.jit(jax.vmap(proj, in_axes=(0, 0, None)))(cx, cy, STATE.as_array())
        singles = [proj(cx[b], cy[b], STATE.as_array()) for b in range(4)]
        np.testing.assert_allclose(batched.cx, np.stack([s.cx for s in singles]), atol=1e-9)
        np.testing.assert_allclose(batched.cy, np.stack([s.cy for s in singles]), atol=1e-9)

        def loss(cy_bar):  # a batched call (the projector vmaps (B, nvar) inputs itself)
            return jnp.sum(proj(cx, cy_bar, STATE.as_array()).cy ** 2)

        g = jax.grad(loss)(jnp.asarray(cy))
        assert g.shape == cy.shape and np.all(np.isfinite(g))


def test_infeasible_input_gives_status_and_nan_gradient():
    prob = _problem()
    cx, cy = _samples(prob)
    with jax.enable_x64(True):  # x64 only inside this block
        proj = prob.differentiable_projector()
        fast = EgoState(vs=15.0).as_array()  # initial speed above vx_max = 12: no feasible point

        def loss(cx_bar):
            return jnp.sum(proj(cx_bar, cy[0], fast).cx ** 2)

        out = proj(cx[0], cy[0], fast)
        assert int(out.status) != int(solvers.Status.SOLVED)
        g = jax.grad(loss)(jnp.asarray(cx[0]))
        assert np.all(np.isnan(g))


def test_arguments_are_validated():
    prob = _problem()
    cx, cy = _samples(prob)
    with pytest.raises(ValueError, match="method"):
        prob.differentiable_projector(method="newton")
    with jax.enable_x64(True):  # x64 only inside this block
        proj = prob.differentiable_projector()
        with pytest.raises(ValueError, match="bounds"):
            proj(cx[0], cy[0], STATE, bounds={"speed": 3.0})
        with pytest.raises(ValueError, match="weights"):
            proj(cx[0], cy[0], STATE, weights=np.ones(3))
        with pytest.raises(ValueError, match="cx_bar"):
            proj(cx[0, :3], cy[0], STATE)


@pytest.mark.parametrize("variant", ["hull", "extra", "polygon"])
def test_other_problem_forms_match_clarabel(variant):
    basis = BernsteinBasis(TimeGrid(5.0, 20), degree=6)
    bounds = ProjectionBounds(y_lb=-0.5, y_ub=0.5, vx_max=12.0)
    if variant == "hull":
        prob = ProjectionProblem(basis, bounds, constraint_points="hull")
    elif variant == "extra":
        zone = LinearConstraints.at_steps(
            range(10, 20), nx=1.0, ny=0.0, upper=10.5, num_steps=20, quantity="velocity"
        )
        prob = ProjectionProblem(basis, bounds, extra=zone)
    else:
        prob = ProjectionProblem(basis, ProjectionBounds(y_lb=-0.5, y_ub=0.5, a_max=4.0))
    cx, cy = _samples(prob, 2)
    ref = prob.project(cx, cy, STATE, backend="clarabel", **CLARABEL_TIGHT)
    assert np.all(ref.solved)
    with jax.enable_x64(True):  # x64 only inside this block
        out = prob.differentiable_projector(**TIGHT)(cx, cy, STATE)
    np.testing.assert_allclose(out.cx, ref.cx, atol=1e-6)
    np.testing.assert_allclose(out.cy, ref.cy, atol=1e-6)
