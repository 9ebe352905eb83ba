"""MMD-Opt: motion planning under multi-modal obstacle predictions (IROS 2023), the method only.

Modules, bottom up: :mod:`~mmdopt.kernels` (Gaussian kernels, MMD²), :mod:`~mmdopt.geometry`
(the collision ellipse and circle footprints), :mod:`~mmdopt.samples` (the reduced-set type),
:mod:`~mmdopt.reduced_set` (reduced-set selection), :mod:`~mmdopt.collision` (f̄, the MMD and
scenario costs, the collision-free count), :mod:`~mmdopt.config` (the planner's configuration
sections and presets), :mod:`~mmdopt.algorithm` (Algorithm 1: state, init/update/run/shift),
:mod:`~mmdopt.methods` (the registry of planning methods), :mod:`~mmdopt.baselines` (each
method's selection of samples), :mod:`~mmdopt.schedule` (the risk passes),
:mod:`~mmdopt.plans` (:class:`Road`, :class:`Plan`, :class:`PlanStatus`), :mod:`~mmdopt.validate`
(the input checks), :mod:`~mmdopt.planner` (:class:`Planner`), :mod:`~mmdopt.api`
(:func:`plan`), :mod:`~mmdopt.predict` (predictors).  Experiments live in
:mod:`mmdopt.bench`, which this package never imports.

``import mmdopt`` does not change JAX's global configuration: the public functions that need
float64 ask for it locally (``jax.enable_x64`` inside the call).
"""

from __future__ import annotations

import importlib
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

__version__ = "0.2.0"

#: every public name of the package and the module it comes from, imported on first use
#: (PEP 562): ``import mmdopt`` itself imports neither JAX nor SciPy, so the CLI's ``--help``
#: and ``--version`` answer at once; ``mmdopt.plan`` imports the method the first time
_LAZY = MappingProxyType(
    {
        "algorithm": ".algorithm",
        "methods": ".methods",
        "risk": ".risk",
        "schedule": ".schedule",
        "plan": ".api",
        "plan_frenet": ".api",
        "enable_compile_cache": ".compile_cache",
        "CollisionCounts": ".collision",
        "ReducedObstacles": ".collision",
        "SurrogateConfig": ".collision",
        "circle_centres": ".collision",
        "collision_free_count": ".collision",
        "ellipse_f": ".collision",
        "f_bar": ".collision",
        "headings": ".collision",
        "mmd_surrogate": ".collision",
        "mmd_surrogate_terms": ".collision",
        "reduced_obstacles": ".collision",
        "BaselineConfig": ".config",
        "CEMConfig": ".config",
        "CostConfig": ".config",
        "MarginConfig": ".config",
        "MMDOptConfig": ".config",
        "ProjectionConfig": ".config",
        "RoadRules": ".config",
        "SafetyConfig": ".config",
        "ScheduleConfig": ".config",
        "SelectionConfig": ".config",
        "TrajectoryConfig": ".config",
        "EGO_FOOTPRINT": ".geometry",
        "ELLIPSE_A": ".geometry",
        "ELLIPSE_B": ".geometry",
        "OBSTACLE_FOOTPRINT": ".geometry",
        "CircleFootprint": ".geometry",
        "Footprint": ".geometry",
        "gaussian_gram": ".kernels",
        "median_heuristic": ".kernels",
        "mmd2_to_dirac": ".kernels",
        "mmd2_weighted": ".kernels",
        "one_minus_gaussian_gram": ".kernels",
        "sq_distances": ".kernels",
        "PLAN_METHODS": ".methods",
        "PlanMethod": ".methods",
        "Planner": ".planner",
        "Plan": ".plans",
        "PlanStatus": ".plans",
        "Road": ".plans",
        "SELECTORS": ".reduced_set",
        "ReducedSetConfig": ".reduced_set",
        "project_simplex": ".reduced_set",
        "reduced_set_objective": ".reduced_set",
        "refine_weights": ".reduced_set",
        "select_reduced_set": ".reduced_set",
        "select_reduced_set_unchecked": ".reduced_set",
        "select_reduced_sets": ".reduced_set",
        "config_for_risk": ".risk",
        "ReducedSet": ".samples",
    }
)

if TYPE_CHECKING:  # the same names for type checkers and the API reference
    from . import algorithm, methods, risk, schedule
    from .api import plan, plan_frenet
    from .collision import (
        CollisionCounts,
        ReducedObstacles,
        SurrogateConfig,
        circle_centres,
        collision_free_count,
        ellipse_f,
        f_bar,
        headings,
        mmd_surrogate,
        mmd_surrogate_terms,
        reduced_obstacles,
    )
    from .config import (
        BaselineConfig,
        CEMConfig,
        CostConfig,
        MarginConfig,
        MMDOptConfig,
        ProjectionConfig,
        RoadRules,
        SafetyConfig,
        ScheduleConfig,
        SelectionConfig,
        TrajectoryConfig,
    )
    from .geometry import (
        EGO_FOOTPRINT,
        ELLIPSE_A,
        ELLIPSE_B,
        OBSTACLE_FOOTPRINT,
        CircleFootprint,
        Footprint,
    )
    from .kernels import (
        gaussian_gram,
        median_heuristic,
        mmd2_to_dirac,
        mmd2_weighted,
        one_minus_gaussian_gram,
        sq_distances,
    )
    from .methods import PLAN_METHODS, PlanMethod
    from .planner import Planner
    from .plans import Plan, PlanStatus, Road
    from .reduced_set import (
        SELECTORS,
        ReducedSetConfig,
        project_simplex,
        reduced_set_objective,
        refine_weights,
        select_reduced_set,
        select_reduced_set_unchecked,
        select_reduced_sets,
    )
    from .risk import config_for_risk
    from .samples import ReducedSet


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'mmdopt' has no attribute {name!r}")
    mod = importlib.import_module(module, __name__)
    value = mod if module == "." + name else getattr(mod, name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


__all__ = [
    "__version__",
    "algorithm",
    "methods",
    "risk",
    "schedule",
    "PlanMethod",
    "config_for_risk",
    "CircleFootprint",
    "EGO_FOOTPRINT",
    "OBSTACLE_FOOTPRINT",
    "ELLIPSE_A",
    "ELLIPSE_B",
    "circle_centres",
    "headings",
    "gaussian_gram",
    "median_heuristic",
    "mmd2_to_dirac",
    "mmd2_weighted",
    "one_minus_gaussian_gram",
    "sq_distances",
    "SELECTORS",
    "Footprint",
    "ReducedSet",
    "ReducedSetConfig",
    "project_simplex",
    "reduced_set_objective",
    "refine_weights",
    "select_reduced_set",
    "select_reduced_set_unchecked",
    "select_reduced_sets",
    "CollisionCounts",
    "ReducedObstacles",
    "SurrogateConfig",
    "collision_free_count",
    "ellipse_f",
    "f_bar",
    "mmd_surrogate",
    "mmd_surrogate_terms",
    "reduced_obstacles",
    "MMDOptConfig",
    "CEMConfig",
    "TrajectoryConfig",
    "ProjectionConfig",
    "CostConfig",
    "SafetyConfig",
    "MarginConfig",
    "RoadRules",
    "SelectionConfig",
    "BaselineConfig",
    "ScheduleConfig",
    "Road",
    "Plan",
    "Planner",
    "PlanStatus",
    "plan",
    "plan_frenet",
    "PLAN_METHODS",
    "enable_compile_cache",
]
