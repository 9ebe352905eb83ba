"""Frenet layer: trajectory bases, reference paths, the behavioural planner and the projection QP.

Layered on :mod:`solvers` (QPs and backends); nothing here knows about MMD or obstacle statistics.

Typical use (Algorithm 1's lines 6 and 8)::

    import jax, numpy as np
    from frenet import (BehaviouralPlanner, EgoState, ProjectionBounds, ProjectionProblem,
                        ReferencePath, make_basis)

    basis = make_basis()                         # Bernstein, degree 10, T = 15 s, K = 100
    planner = BehaviouralPlanner(basis)          # reference constants, 4 segments
    state = EgoState(s=0.0, d=0.0, vs=10.0)      # or ReferencePath.ego_state(x, y, v, heading)
    cx, cy = planner.closed_form(d_batch, state) # (B, 8) behavioural inputs -> (B, 11) each
    prob = ProjectionProblem(basis, ProjectionBounds(y_lb=-0.3, y_ub=0.3),
                             constraint_points="hull")
    res = prob.project(cx, cy, state, backend="clarabel")       # exact, any solvers backend
    project = jax.jit(prob.jax_projector(num_iters=25))         # inside a jitted CEM loop
    out = project(cx, cy, state.as_array())      # out.cx, out.cy, out.residual, out.admm

    tr = planner.trajectories(res.cx, res.cy)    # x, y, vx, vy, ax, ay (B, K), Frenet frame
    path = ReferencePath.from_waypoints(xy)      # Cartesian <-> Frenet for trajectories/obstacles
    X, Y = path.to_cartesian(tr.x, tr.y)
"""

from .basis import Basis, BernsteinBasis, TimeGrid, TripleIntegratorBasis, make_basis
from .path import FLOAT32_TOL, ReferencePath, wrap_angle
from .planner import BehaviouralPlanner, EgoState, PlannerConfig, Trajectories, state_array
from .projection import (
    DiffProjection,
    JaxProjection,
    LinearConstraints,
    ProjectionBounds,
    ProjectionProblem,
    ProjectionResult,
)

__all__ = [
    "TimeGrid",
    "Basis",
    "TripleIntegratorBasis",
    "BernsteinBasis",
    "make_basis",
    "ReferencePath",
    "FLOAT32_TOL",
    "wrap_angle",
    "EgoState",
    "PlannerConfig",
    "BehaviouralPlanner",
    "Trajectories",
    "state_array",
    "ProjectionBounds",
    "LinearConstraints",
    "ProjectionProblem",
    "ProjectionResult",
    "DiffProjection",
    "JaxProjection",
]
