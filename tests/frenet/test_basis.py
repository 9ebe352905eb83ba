"""Trajectory bases: derivative consistency, boundary rows, grid."""

import numpy as np
import pytest

from frenet import BernsteinBasis, TimeGrid, TripleIntegratorBasis, make_basis


def test_grid_spacing_is_horizon_over_k_minus_one():
    g = TimeGrid(15.0, 100)
    assert g.dt == pytest.approx(15.0 / 99)
    assert g.t[-1] == pytest.approx(15.0) and g.t.shape == (100,)


@pytest.mark.parametrize(
    "kw", [{"horizon": 0.0}, {"horizon": np.nan}, {"num_steps": 2}, {"num_steps": 10.5}]
)
def test_bad_grid_raises(kw):
    with pytest.raises(ValueError):
        TimeGrid(**kw)


def test_triple_integrator_follows_exact_zoh_recursion():
    b = TripleIntegratorBasis(TimeGrid(15.0, 100))
    assert b.nvar == 102
    c = np.random.default_rng(0).normal(size=b.nvar)
    p, v, a = b.trajectory(c)
    u, dt = b.Pdddot @ c, b.grid.dt
    np.testing.assert_allclose(
        p[1:], p[:-1] + dt * v[:-1] + dt**2 / 2 * a[:-1] + dt**3 / 6 * u[:-1], atol=1e-10
    )
    np.testing.assert_allclose(v[1:], v[:-1] + dt * a[:-1] + dt**2 / 2 * u[:-1], atol=1e-10)
    np.testing.assert_allclose(a[1:], a[:-1] + dt * u[:-1], atol=1e-10)
    # every jerk acts (the reference's dead last column is gone)
    assert np.all(np.abs(b.P[-1, 3:]) > 0)


@pytest.mark.parametrize(
    "basis", [TripleIntegratorBasis(TimeGrid(15.0, 60)), BernsteinBasis(degree=11)]
)
def test_derivative_matrices_are_time_derivatives(basis):
    """Central differences of the basis evaluated off-grid match the derivative rows."""
    c = np.random.default_rng(1).normal(size=basis.nvar)
    t = np.linspace(0.37, basis.grid.horizon - 0.41, 13)
    h = 1e-5
    lo, mid, hi = basis.evaluate(t - h), basis.evaluate(t), basis.evaluate(t + h)
    for order in (0, 1):
        fd = (hi[order] - lo[order]) @ c / (2 * h)
        np.testing.assert_allclose(fd, mid[order + 1] @ c, rtol=1e-6, atol=1e-6)
    # and the on-grid rows are the evaluation at the grid times
    P, Pd, Pdd = basis.evaluate(basis.grid.t)[:3]
    np.testing.assert_allclose(P, basis.P, atol=1e-12)
    np.testing.assert_allclose(Pd, basis.Pdot, atol=1e-12)
    np.testing.assert_allclose(Pdd, basis.Pddot, atol=1e-12)


def test_boundary_rows_pick_initial_state_and_final_lateral_velocity():
    b = BernsteinBasis(degree=10)
    Ax, Ay = b.boundary_rows()
    assert Ax.shape == (3, b.nvar) and Ay.shape == (4, b.nvar)
    c = np.random.default_rng(2).normal(size=b.nvar)
    p, v, a = b.trajectory(c)
    np.testing.assert_allclose(Ay @ c, [p[0], v[0], a[0], v[-1]])
    assert b.boundary_rows(final_lateral_velocity=False)[1].shape == (3, b.nvar)


def test_smoothness_is_sum_of_squared_jerk():
    b = TripleIntegratorBasis(TimeGrid(15.0, 30))
    c = np.random.default_rng(3).normal(size=b.nvar)
    assert c @ b.smoothness() @ c == pytest.approx(np.sum(c[3:] ** 2))


def test_make_basis_rejects_unknown_kind_and_bad_degree():
    with pytest.raises(ValueError, match="unknown basis"):
        make_basis("fourier")
    with pytest.raises(ValueError, match="degree"):
        BernsteinBasis(degree=2)
