"""Behavioural planner: closed form == QP on every backend, set-point tracking, bad inputs."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from frenet import BehaviouralPlanner, EgoState, PlannerConfig

from .conftest import (
    BACKENDS,
    SLOW,
    backend_settings,
    backend_tol,
    make_basis,
    make_planner,
    sample_d,
)


@pytest.mark.parametrize("backend", BACKENDS)
def test_closed_form_equals_qp_on_each_backend(backend, ego):
    planner = make_planner("bernstein")
    d = sample_d(2 if backend in SLOW else 4, seed=1)
    cx_qp, cy_qp = planner.solve(d, ego, backend=backend, **backend_settings(backend))
    cx, cy = planner.closed_form(d, ego)
    tol = backend_tol(backend)
    scale = max(1.0, float(np.abs(cx).max()))
    np.testing.assert_allclose(cx_qp, np.asarray(cx), atol=tol * scale)
    np.testing.assert_allclose(cy_qp, np.asarray(cy), atol=tol * max(1.0, float(np.abs(cy).max())))


@pytest.mark.parametrize("backend", ["clarabel", "osqp"])
def test_closed_form_equals_qp_for_triple_integrator(backend, ego):
    if backend not in BACKENDS:
        pytest.skip(f"{backend} not installed")
    planner = make_planner("triple")
    d = sample_d(3, seed=2)
    cx_qp, cy_qp = planner.solve(d, ego, backend=backend, **backend_settings(backend))
    cx, cy = planner.closed_form(d, ego)
    tr_qp, tr = planner.trajectories(cx_qp, cy_qp), planner.trajectories(cx, cy)
    np.testing.assert_allclose(tr_qp.x, tr.x, atol=1e-4)
    np.testing.assert_allclose(tr_qp.y, tr.y, atol=1e-4)


@pytest.mark.parametrize("kind", ["bernstein", "triple"])
def test_plans_meet_boundary_conditions_and_track_set_points(kind):
    planner = make_planner(kind)
    state = EgoState(s=3.0, d=0.2, vs=10.0, vd=0.1, as_=0.5, ad=-0.1)
    d = np.array([[6.0, 6.0, 6.0, 6.0, 1.0, 1.0, 1.0, 1.0]])
    tr = planner.trajectories(*planner.closed_form(d, state))
    np.testing.assert_allclose(
        [tr.x[0, 0], tr.vx[0, 0], tr.ax[0, 0], tr.y[0, 0], tr.vy[0, 0], tr.ay[0, 0], tr.vy[0, -1]],
        [3.0, 10.0, 0.5, 0.2, 0.1, -0.1, 0.0],
        atol=1e-8,
    )
    assert abs(tr.vx[0, -1] - 6.0) < 0.5
    assert abs(tr.y[0, -1] - 1.0) < 0.2


def test_float32_closed_form_matches_float64(ego):
    planner = make_planner("bernstein")
    d = sample_d(100, seed=3)
    cx64, cy64 = planner.closed_form(d, ego)
    cx32, cy32 = planner.closed_form(d, ego, dtype=np.float32)
    assert cx64.dtype == jnp.float64 and cx32.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(cx32), np.asarray(cx64), rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(np.asarray(cy32), np.asarray(cy64), rtol=1e-4, atol=1e-3)


def test_closed_form_fn_works_inside_outer_jit(ego):
    planner = make_planner("bernstein")
    plan = planner.closed_form_fn(np.float32)

    @jax.jit
    def mean_final_speed(d, state):
        cx, _ = plan(d, state)
        return jnp.mean(cx @ jnp.asarray(planner.basis.Pdot[-1], jnp.float32))

    d = sample_d(16, seed=4).astype(np.float32)
    v = float(mean_final_speed(d, ego.as_array().astype(np.float32)))
    cx, _ = planner.closed_form(d, ego)
    assert v == pytest.approx(float(np.mean(np.asarray(cx) @ planner.basis.Pdot[-1])), rel=1e-4)


def test_per_sample_states_are_supported():
    planner = make_planner("bernstein")
    d = sample_d(3, seed=5)
    states = np.array([[0, 0, 10, 0, 0, 0], [5, 0.1, 8, 0, 0, 0], [1, -0.1, 12, 0, 0, 0]], float)
    cx, _ = planner.closed_form(d, states)
    for i in range(3):
        cxi, _ = planner.closed_form(d[i], states[i])
        np.testing.assert_allclose(np.asarray(cx[i]), np.asarray(cxi[0]), atol=1e-10)


def test_segment_count_is_configurable(ego):
    planner = BehaviouralPlanner(make_basis("bernstein"), PlannerConfig(num_segments=2))
    assert planner.config.d_dim == 4
    cx, cy = planner.closed_form(np.array([[5.0, 5.0, 0.0, 0.0]]), ego)
    assert cx.shape == (1, planner.basis.nvar)


@pytest.mark.parametrize(
    "d, state, msg",
    [
        (np.zeros((2, 6)), EgoState(), "shape"),
        (np.full((1, 8), np.nan), EgoState(), "NaN"),
        (np.zeros((2, 8)), np.zeros((3, 6)), "batch size"),
        (np.zeros((1, 8)), np.array([0, 0, np.inf, 0, 0, 0]), "NaN or inf"),
    ],
)
def test_bad_inputs_raise(d, state, msg):
    planner = make_planner("bernstein")
    with pytest.raises(ValueError, match=msg):
        planner.closed_form(d, state)


def test_ego_state_rejects_nan_and_config_rejects_bad_values():
    with pytest.raises(ValueError, match="finite"):
        EgoState(vs=float("nan"))
    with pytest.raises(ValueError):
        PlannerConfig(num_segments=0)
    with pytest.raises(ValueError):
        BehaviouralPlanner(make_basis("bernstein", num_steps=5), PlannerConfig(num_segments=8))
