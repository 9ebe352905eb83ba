"""Shared factories and the one per-backend tolerance/settings table of the Frenet tests."""

from __future__ import annotations

import numpy as np
import pytest

import solvers
from frenet import BehaviouralPlanner, BernsteinBasis, EgoState, TimeGrid, TripleIntegratorBasis

#: backend -> (settings for tight solves, absolute tolerance on coefficients / constraint rows)
BACKEND_TABLE: dict[str, tuple[dict, float]] = {
    "clarabel": ({}, 1e-6),
    "osqp": ({"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 200000, "polishing": True}, 1e-5),
    "admm": ({"max_iter": 4000}, 1e-4),
    "cvxpy": ({}, 1e-4),
    "qpsolvers:osqp": ({"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 200000}, 1e-5),
    "qpsolvers:scs": ({"eps_abs": 1e-9, "eps_rel": 1e-9}, 1e-3),
}
DEFAULT_ENTRY: tuple[dict, float] = ({}, 1e-5)

#: backends too slow to run more than a handful of problems in a test
SLOW = {"cvxpy"}


def backend_settings(name: str) -> dict:
    return dict(BACKEND_TABLE.get(name, DEFAULT_ENTRY)[0])


def backend_tol(name: str) -> float:
    return BACKEND_TABLE.get(name, DEFAULT_ENTRY)[1]


BACKENDS = solvers.available_backends()


def make_basis(kind: str = "bernstein", num_steps: int = 100, horizon: float = 15.0, **kw):
    grid = TimeGrid(horizon, num_steps)
    return BernsteinBasis(grid, **kw) if kind == "bernstein" else TripleIntegratorBasis(grid)


def sample_d(num: int, segments: int = 4, seed: int = 0) -> np.ndarray:
    """Behavioural inputs like the reference sampler's (speeds clipped to [0.1, 30])."""
    rng = np.random.default_rng(seed)
    v = np.clip(rng.normal(8.0, 4.0, (num, segments)), 0.1, 30.0)
    y = rng.normal(0.0, 1.5, (num, segments))
    return np.concatenate([v, y], axis=1)


@pytest.fixture
def ego() -> EgoState:
    return EgoState(s=0.0, d=0.0, vs=10.0, vd=0.0, as_=0.0, ad=0.0)


def make_planner(kind: str = "bernstein", **kw) -> BehaviouralPlanner:
    return BehaviouralPlanner(make_basis(kind), **kw)
