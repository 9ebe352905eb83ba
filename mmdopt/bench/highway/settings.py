"""Settings of the highway benchmark: the agents that drive the ego, predictors, the planner
defaults, the environment/loop settings and the optional-dependency check."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import mmdopt
from mmdopt.safety import RSSConfig

#: drivers of the ego: the receding-horizon planner, or highway-env's own IDM/MOBIL driver
DRIVERS = ("planner", "idm")
#: the predictor an agent may bring instead of the settings' one: the noise-free
#: constant-velocity extrapolation, one sample per car (:func:`~.predictors.make_predictor`)
CV_MEAN = "cv-mean"


@dataclass(frozen=True)
class Agent:
    """What drives the ego in one column of the benchmark (a value of ``--methods``).

    name : the ``--methods`` value, the ``method`` column of ``episodes.csv`` and the episode
        files' name
    driver : "planner" (the receding-horizon planner, :func:`mmdopt.receding.run_receding`) or
        "idm" (highway-env's IDM/MOBIL driver as the ego: no planner, no predictor; the
        reference for speed)
    plan_method : the planner's method (:data:`mmdopt.PLAN_METHODS`); ``None`` for the IDM driver
    predictor : the predictions it plans on: ``None`` for those of the settings' predictor
        (:attr:`HighwaySettings.predictor`), or :data:`CV_MEAN` (its own noise-free
        constant-velocity prediction of each car, a planner that ignores uncertainty)
    """

    name: str
    driver: str
    plan_method: str | None
    predictor: str | None = None

    def __post_init__(self) -> None:
        if self.driver not in DRIVERS:
            raise ValueError(f"driver must be one of {DRIVERS}, got {self.driver!r}")
        if (self.driver == "planner") != (self.plan_method is not None):
            raise ValueError("a planner agent needs a plan_method, the IDM driver none")
        if self.driver == "idm" and self.predictor is not None:
            raise ValueError("the IDM driver uses no predictor")
        if self.predictor not in (None, CV_MEAN):
            raise ValueError(f"predictor must be None or {CV_MEAN!r}, got {self.predictor!r}")


#: the agents of ``mmdopt bench highway --methods``, by name
AGENTS = MappingProxyType(
    {
        "mmd": Agent("mmd", "planner", "mmd"),
        "degroot": Agent("degroot", "planner", "degroot"),
        # Algorithm 1 with the scenario cost against the single noise-free constant-velocity
        # prediction of each car
        "cv": Agent("cv", "planner", "scenario_all", CV_MEAN),
        "idm": Agent("idm", "idm", None),
    }
)
#: the agents' names (the choices of ``--methods``)
METHODS = tuple(AGENTS)
#: "sim": the simulator oracle (rollouts of highway-env's own driver models); "cv": constant
#: velocity; "learned": the MDN trained on highway-env rollouts of seeds >= 100000 (the
#: benchmark's episodes use seeds below 100000); "route": one mode per route a car can take
#: from its lane through the road network's junctions, uniform weights (:mod:`.junction`)
PREDICTORS = ("sim", "cv", "learned", "route")
#: highway-env ids whose ego drives a route through a junction (its configured destination)
JUNCTION_PREFIXES = ("intersection-", "roundabout-")


def default_predictor(env: str) -> str:
    """The predictor ``bench highway`` uses when ``--predictor`` is not given: ``"route"`` at a
    junction (:data:`JUNCTION_PREFIXES`; on held-out junction rollouts it has the smallest
    minADE/minFDE and the largest coverage of cv, route and learned, the learned MDN having been
    trained on straight roads and the merge), else ``"learned"``."""
    return "route" if str(env).startswith(JUNCTION_PREFIXES) else "learned"


#: planner settings for highway driving (overridable with ``--config``): a 5 s horizon on a 0.1 s
#: grid (51 points), sizes cut to fit the 0.5 s replan budget on a 2-core CPU, the speed limit as
#: the desired speed, and the lateral collision semi-axis of highway-env's 2 m wide cars (2 m
#: between centres + 0.6 m) instead of the paper's 3.5 m, which would not fit two cars in
#: neighbouring 4 m lanes.
#: the planner of this benchmark (:meth:`mmdopt.MMDOptConfig.highway`), in its nested JSON form
HIGHWAY_PLANNER: dict[str, Any] = mmdopt.MMDOptConfig.highway().to_dict()


#: how the ego executes a plan (:func:`~.adapter.PlanFollower`)
EGO_MODELS = ("bicycle", "exact")
#: the safety shield of the benchmark (:mod:`mmdopt.safety`): highway-env's IDM cars brake at
#: most 6 m/s² (``IDMVehicle.ACC_MAX``), the ego brakes at 6 m/s² after a replan period and at
#: up to 8 m/s² in an emergency, 5 m long cars, 1 m of margin for tracking errors, a corridor
#: of 2.5 m (2 m wide cars plus 0.5 m) either side of the ego's lateral offset
SHIELD = RSSConfig(
    response_time=0.5,
    a_max=5.0,
    b_min=6.0,
    b_max=6.0,
    b_emergency=8.0,
    contact=5.0,
    margin=1.0,
    lateral_overlap=2.5,
)

#: the shield at a junction (an ego with a route to a destination: ``intersection-v2``,
#: ``roundabout-v1``): :data:`SHIELD` with RSS's lateral safe distance checked beside the
#: longitudinal one; the crossing rule applies wherever the scene source reports conflict areas
JUNCTION_SHIELD = dataclasses.replace(SHIELD, lateral=True)


def highway_available() -> bool:
    """Whether highway-env and gymnasium import."""
    try:
        import gymnasium  # noqa: F401
        import highway_env  # noqa: F401
    except ImportError:
        return False
    return True


def require_highway():
    """The ``gymnasium`` module with highway-env's environments registered; ``ImportError``
    saying how to install them when either is missing."""
    try:
        import gymnasium as gym
        import highway_env  # noqa: F401  (registers the environments)
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError(
            f"the highway benchmark needs highway-env and gymnasium ({e}); "
            'install them with: pip install -e ".[highway]"'
        ) from None
    return gym


def check_env(env: str) -> None:
    """Raise ``ValueError`` unless ``env`` is a registered gymnasium id of highway-env (checked
    before a benchmark writes anything; the message lists highway-env's ids)."""
    gym = require_highway()
    if not isinstance(env, str) or not env:
        raise ValueError(f"env must be a highway-env id such as 'highway-v0', got {env!r}")
    try:
        gym.spec(env)
    except gym.error.Error as e:
        ids = sorted(
            k for k, v in gym.registry.items() if str(v.entry_point).startswith("highway_env")
        )
        raise ValueError(
            f"unknown environment {env!r} ({e}); highway-env's: {', '.join(ids)}"
        ) from None


#: highway-env keys the benchmark sets from its own options (refused in ``env_config``)
ENV_KEYS_SET_BY_OPTIONS = {
    "simulation_frequency": "HighwaySettings.simulation_frequency",
    "policy_frequency": "--dt",
    "duration": "--duration",
}


def check_env_config(env: str, env_config) -> None:
    """Raise ``ValueError`` unless ``env_config`` is a dict of keys of the environment's own
    ``default_config()`` (naming the unknown ones and the known ones) other than those the
    benchmark sets itself (:data:`ENV_KEYS_SET_BY_OPTIONS`)."""
    from gymnasium.envs.registration import load_env_creator

    check_env(env)
    if not isinstance(env_config, dict):
        raise ValueError(
            f"env_config must be a JSON object of {env}'s config keys, "
            f"got {type(env_config).__name__}"
        )
    known = load_env_creator(require_highway().spec(env).entry_point).default_config()
    unknown = sorted(str(k) for k in env_config if k not in known)
    if unknown:
        raise ValueError(
            f"unknown {env} config key(s) {', '.join(map(repr, unknown))}; {env}'s keys: "
            f"{', '.join(sorted(k for k in known if k not in ENV_KEYS_SET_BY_OPTIONS))}"
        )
    owned = sorted(k for k in env_config if k in ENV_KEYS_SET_BY_OPTIONS)
    if owned:
        raise ValueError(
            "env_config must not set "
            + ", ".join(f"{k!r} (set by {ENV_KEYS_SET_BY_OPTIONS[k]})" for k in owned)
        )


def highway_config(overrides: dict | None = None) -> mmdopt.MMDOptConfig:
    """The preset :meth:`mmdopt.MMDOptConfig.highway`, then ``overrides`` (field names)."""
    return mmdopt.MMDOptConfig.from_dict(overrides or {}, base=mmdopt.MMDOptConfig.highway())


@dataclass(frozen=True)
class HighwaySettings:
    """One benchmark's environment and loop settings (JSON-friendly).

    env : highway-env id (``highway-v0``, ``merge-v0``, ...), at its default traffic density
    duration : simulated seconds per episode
    simulation_frequency : highway-env's simulator rate (Hz)
    dt : δ, seconds of each plan executed before replanning (``policy_frequency = 1/dt``;
        ``simulation_frequency · dt`` must be an integer)
    n_samples : predictor samples per obstacle
    max_obstacles : obstacles given to the planner (nearest first, padded with phantoms)
    ahead, behind : perception range along the road (m) for the obstacles given to the planner
    budget_s : per-step plan-time budget (s)
    predictor : "sim" (the simulator oracle) | "cv" | "learned" (:data:`PREDICTORS`)
    v_max, ax_max, ay_max, vy_max : the planner's kinematic limits (:class:`mmdopt.Road`)
    env_config : extra highway-env configuration keys
    ego_model : how the ego executes plans: "bicycle" (highway-env's kinematic bicycle with a
        tracking controller, :func:`~.adapter.PlanFollower`) or "exact" (the pose set from the
        plan)
    shield : check every plan against RSS's longitudinal safe distance and brake when it fails
        (:mod:`mmdopt.safety`, :data:`SHIELD`)
    forecast : give the planner each replan's obstacles as an :class:`mmdopt.predict.Forecast`
        of the predictor (:class:`~.adapter.HighwayDraw`; the loop draws ``n_samples`` with the
        time-linear margins, n(ε) in the "samples" mode) instead of a drawn array; the same
        futures either way with the time-linear margins
    """

    env: str = "highway-v0"
    duration: float = 20.0
    simulation_frequency: int = 10
    dt: float = 0.5
    n_samples: int = 20
    max_obstacles: int = 6
    ahead: float = 80.0
    behind: float = 30.0
    budget_s: float = 0.5
    predictor: str = "learned"
    v_max: float = 30.0
    ax_max: float = 5.0
    ay_max: float = 3.0
    vy_max: float = 3.0
    env_config: dict = field(default_factory=dict)
    ego_model: str = "bicycle"
    shield: bool = True
    forecast: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"duration must be > 0 s, got {self.duration}")
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"dt must be > 0 s, got {self.dt}")
        if isinstance(self.simulation_frequency, bool) or not isinstance(
            self.simulation_frequency, int
        ):
            raise ValueError("simulation_frequency must be an int (Hz)")
        frames = self.simulation_frequency * self.dt
        if self.simulation_frequency < 1 or abs(frames - round(frames)) > 1e-9 or frames < 1:
            raise ValueError(
                f"simulation_frequency · dt must be a positive integer, got "
                f"{self.simulation_frequency} Hz · {self.dt} s"
            )
        if self.ego_model not in EGO_MODELS:
            raise ValueError(f"ego_model must be one of {EGO_MODELS}, got {self.ego_model!r}")
        for name in ("shield", "forecast"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be a bool, got {getattr(self, name)!r}")
        if self.predictor not in PREDICTORS:
            raise ValueError(f"predictor must be one of {PREDICTORS}, got {self.predictor!r}")
        for name in ("n_samples", "max_obstacles"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be an int >= 1, got {v!r}")
        for name in ("ahead", "behind", "budget_s", "v_max", "ax_max", "ay_max", "vy_max"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and v > 0):
                raise ValueError(f"{name} must be > 0, got {v!r}")

    @property
    def policy_frequency(self) -> float:
        return 1.0 / self.dt

    @property
    def frames_per_step(self) -> int:
        return int(round(self.simulation_frequency * self.dt))
