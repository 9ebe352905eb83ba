"""Frenet layer: trajectory bases, reference paths, the behavioural planner and the projection QP.

Layered on :mod:`solvers` (QPs and backends); nothing here knows about MMD or obstacles' statistics.
"""

from .basis import Basis, BernsteinBasis, TimeGrid, TripleIntegratorBasis, make_basis
from .path import ReferencePath, wrap_angle
from .planner import BehaviouralPlanner, EgoState, PlannerConfig, Trajectories, state_array
from .projection import (
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
    "JaxProjection",
]
