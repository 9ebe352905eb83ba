"""MMD-Opt: kernels, reduced-set selection, the MMD collision surrogate (and, later, Algorithm 1).

Importing this package enables float64 in JAX (``jax_enable_x64``): reduced-set weights and the
MMD surrogate are compared at magnitudes far below float32 resolution.
"""

import jax

jax.config.update("jax_enable_x64", True)

from .geometry import EGO_FOOTPRINT, OBSTACLE_FOOTPRINT, CircleFootprint, circle_centres, headings  # noqa: E402
from .kernels import (  # noqa: E402
    gaussian_gram,
    median_heuristic,
    mmd2_to_dirac,
    mmd2_weighted,
    one_minus_gaussian_gram,
    sq_distances,
)
from .reduced_set import (  # noqa: E402
    METHODS,
    ReducedSet,
    ReducedSetConfig,
    project_simplex,
    reduced_set_objective,
    refine_weights,
    select_reduced_set,
    select_reduced_set_unchecked,
    select_reduced_sets,
)
from .surrogate import (  # noqa: E402
    CollisionCounts,
    ReducedObstacles,
    SurrogateConfig,
    collision_free_count,
    ellipse_f,
    f_bar,
    mmd_surrogate,
    mmd_surrogate_terms,
    reduced_obstacles,
)

__all__ = [
    "CircleFootprint",
    "EGO_FOOTPRINT",
    "OBSTACLE_FOOTPRINT",
    "circle_centres",
    "headings",
    "gaussian_gram",
    "median_heuristic",
    "mmd2_to_dirac",
    "mmd2_weighted",
    "one_minus_gaussian_gram",
    "sq_distances",
    "METHODS",
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
]

# Algorithm 1, the baselines and the public planning API (issue 6)
from .algorithm import MMDOptConfig  # noqa: E402
from .api import Plan, Road, plan, plan_frenet  # noqa: E402
from .baselines import METHODS as PLAN_METHODS  # noqa: E402

__all__ += ["MMDOptConfig", "Road", "Plan", "plan", "plan_frenet", "PLAN_METHODS"]
