"""Public planning API: :func:`plan` and :func:`plan_frenet`, thin wrappers over the cached
:class:`~mmdopt.Planner` of the config (:data:`mmdopt.planner.PLANNERS`).

::

    import jax, mmdopt, frenet
    road = mmdopt.Road(path=frenet.ReferencePath.straight(1000.0), y_lb=-0.3, y_ub=0.3)
    ego = frenet.EgoState(s=0.0, d=0.0, vs=10.0)
    p = mmdopt.plan(ego, road, obstacles, method="mmd", key=jax.random.PRNGKey(0))
    p.x, p.y, p.speed, p.cost, p.feasible, p.status

``obstacles`` are samples of the obstacles' future trajectories from any predictor, ``(O, n, K, 2)``
Cartesian ``(x, y)`` on the planner's time grid (``K = config.trajectory.num_steps``).

Where the rest lives: the types :class:`Road`, :class:`Plan`, :class:`PlanStatus` in
:mod:`mmdopt.plans`; the input checks in :mod:`mmdopt.validate`; the :class:`Planner` and its
cache in :mod:`mmdopt.planner`; the risk passes in :mod:`mmdopt.schedule`; the assembly of a
plan in :mod:`mmdopt.assemble`; the methods in :mod:`mmdopt.methods`.
"""

from __future__ import annotations

from typing import Any

from numpy.typing import ArrayLike

import frenet

from . import algorithm as alg
from ._x64 import x64
from .algorithm import PLANNER_PROJECTOR, MMDOptConfig
from .methods import PLAN_METHODS
from .planner import PLANNERS, Planner
from .plans import Plan, PlanStatus, Road
from .samples import ReducedSet
from .validate import resolve_projector

__all__ = [
    "Road",
    "Plan",
    "PlanStatus",
    "Planner",
    "plan",
    "plan_frenet",
    "PLAN_METHODS",
    "PLANNERS",
    "PLANNER_PROJECTOR",
]


@x64
def plan(
    ego: frenet.EgoState,
    road: Road,
    obstacles: ArrayLike,
    *,
    method: str = "mmd",
    config: MMDOptConfig | None = None,
    projector: str = PLANNER_PROJECTOR,
    key: ArrayLike | None = None,
    reduced_set: ReducedSet | None = None,
    warm_start: alg.CEMState | None = None,
    risk: float | None = None,
    obstacle_headings: ArrayLike | None = None,
    backend: str | None = None,
    **projector_settings: Any,
) -> Plan:
    """Plan with Algorithm 1 against Cartesian obstacle-trajectory samples.

    Parameters
    ----------
    ego : :class:`frenet.EgoState` in the Frenet frame of ``road.path``
    road : :class:`Road`
    obstacles : (O, n, K, 2) Cartesian ``(x, y)`` samples of each obstacle's future (m), or a
        :class:`mmdopt.predict.Forecast` (a predictor, the histories and the context): then
        ``plan`` draws as many futures as the risk level needs, n(ε) per obstacle
        (:func:`mmdopt.risk.samples_for_risk`, within the forecast's ``min_samples`` …
        ``max_samples``; ``diagnostics["forecast_samples"]``)
    method : "mmd" (MMD-Opt) | "degroot" | "random" | "saa" | "scenario_all", or any method
        registered in :mod:`mmdopt.methods`
    config : :class:`MMDOptConfig` (default: the paper's sizes, and the method's risk knob at
        ε = ``risk`` = 0.005 with sample-driven margins; ``MMDOptConfig().replace(margin_mode=
        "linear")`` plans with the time-linear tuned margins of the paper reproduction)
    projector : the projection of every CEM iteration: ``"admm-fixed"`` (default), the planner's
        own fixed-budget ADMM projector inside the one jit of the whole algorithm (its settings
        are ``config.projection``); or the name of any :mod:`solvers` backend (``"admm"``,
        ``"clarabel"``, ``"osqp"``, ...) projects on the host each iteration
        (``projector_settings`` go to it); ``backend=``, its former name, still works with a
        ``DeprecationWarning``
    key : jax PRNG key (default ``PRNGKey(0)``); the same key gives the same plan
    reduced_set : optional precomputed :class:`ReducedSet` with leading axis O (indices into the
        n samples, weights ᾱ ≥ 0 summing to 1 per obstacle) used instead of the method's own
        selection (methods whose cost uses a reduced set: "mmd", "random", "degroot")
    warm_start : optional :class:`mmdopt.algorithm.CEMState` (e.g. ``algorithm.shift`` of the
        previous plan's ``state``): the sampling distribution and elites start from it
    risk : optional target collision probability ε in (0, 0.5), the method's risk knob: the
        method's margins and chance level follow from it (:func:`mmdopt.risk.config_for_risk`,
        applied to ``config``); ``None``: ``config`` as given (whose default is the knob at
        0.005: ``plan(..., method=m)`` plans as ``plan(..., method=m, risk=0.005)``)
    obstacle_headings : optional (O,) body heading of each obstacle when observed (rad,
        Cartesian): its footprint circles follow it until a sample's own motion gives a heading
        (:func:`mmdopt.collision.headings`), so a car at rest turned across its lane is planned
        against along its real axis, with certainty, in every sample.  ``None``: headings from
        the samples' motion only (along the path for a sample at rest)

    Returns
    -------
    :class:`Plan`.  Never raises for an infeasible situation: if the initial state violates the
    bounds (e.g. speed above ``v_max``) or the cost is not finite, a braking profile is returned,
    and if no sample satisfies the constraints the least-violating one, all with
    ``fallback=True`` and a ``status`` that says why.

    Raises
    ------
    ValueError naming the argument for bad inputs (wrong shapes or horizon, NaN, zero obstacles,
    fewer samples than the reduced-set size, unknown method or backend, a malformed reduced set).
    """
    return PLANNERS.get(config).plan(
        ego, road, obstacles, method=method, projector=resolve_projector(projector, backend),
        key=key, reduced_set=reduced_set, warm_start=warm_start, risk=risk,
        obstacle_headings=obstacle_headings, **projector_settings,
    )  # fmt: skip


@x64
def plan_frenet(
    ego: frenet.EgoState,
    road: Road,
    obstacles_frenet: ArrayLike,
    *,
    method: str = "mmd",
    config: MMDOptConfig | None = None,
    projector: str = PLANNER_PROJECTOR,
    key: ArrayLike | None = None,
    reduced_set: ReducedSet | None = None,
    warm_start: alg.CEMState | None = None,
    risk: float | None = None,
    obstacle_headings: ArrayLike | None = None,
    backend: str | None = None,
    **projector_settings: Any,
) -> Plan:
    """:func:`plan` with obstacle samples already in the Frenet frame of ``road.path``:
    ``obstacles_frenet`` (O, n, K, 2) as ``(s, d)`` (and ``obstacle_headings``, if given,
    relative to the path's tangent).  On a straight path starting at the origin
    along +x (the default :class:`Road`) this is the same as Cartesian."""
    return PLANNERS.get(config).plan_frenet(
        ego, road, obstacles_frenet, method=method,
        projector=resolve_projector(projector, backend), key=key, reduced_set=reduced_set,
        warm_start=warm_start, risk=risk, obstacle_headings=obstacle_headings,
        **projector_settings,
    )  # fmt: skip
