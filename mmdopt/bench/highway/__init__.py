"""Closed-loop benchmark: receding-horizon MMD-Opt driving in highway-env.

Everything that knows highway-env lives in this package (the optional extra ``[highway]``):
``settings`` (methods, planner defaults, :class:`HighwaySettings`), ``adapter`` (state
conversion, the plan-following ego, :class:`HighwaySource`), ``predictors``, ``runner`` (one
episode, the resumable sweep, videos) and ``cli``.

* :class:`HighwaySource` — the scene source of :func:`mmdopt.receding.run_receding`.  Headless
  (``render_mode=None``; ``"rgb_array"`` for videos).  The Frenet frame and the lane bounds come
  from the env's lane network (:mod:`.roads`): on roads of straight lanes along +x a straight
  :class:`frenet.ReferencePath` (+x at ``y = 0``, the centre of lane 0; highway-env's y axis
  points to the right of travel on screen, which is only a mirror image for the planner), on
  curved roads (``racetrack-v0``) the centre line of the ego's lane; the ego's lateral bounds
  ``y_lb, y_ub`` are the centres of the outermost lanes of its road, so the planner may change
  lanes.
* **The ego drives through its vehicle model** (``ego_model="bicycle"``, the default): a
  :class:`PlanFollower` whose tracking controller (curvature feed-forward and lateral/heading
  feedback, a speed and along-track loop) sends highway-env's ``{"steering", "acceleration"}``
  every simulator step and highway-env's kinematic bicycle integrates them; the lateral tracking
  error is recorded.  ``ego_model="exact"`` sets the pose and speed along the plan (linear
  interpolation), which isolates the planner from tracking error.  Every plan is checked against
  RSS's longitudinal safe distance before it runs (:mod:`mmdopt.safety`, :data:`SHIELD`); a plan
  that fails is replaced by a checked braking fallback.  The other vehicles are highway-env's own
  IDM/MOBIL drivers, they see the ego as an ordinary vehicle, and highway-env's own collision
  checker (rotated rectangles, ``Road.step``) decides crashes.
* Frequencies are explicit: ``simulation_frequency`` (default 10 Hz) and ``policy_frequency`` =
  1/δ (default 2 Hz: replan every δ = 0.5 s, five simulator steps per plan).
* Predictors (each returns ``(O, n, K, 2)`` Cartesian samples on the planner's grid and is timed
  per call): :class:`SimulatorPredictor`, the simulator oracle (``--predictor sim``), clones the
  simulator (the nearby vehicles, with a fresh road sharing the lane network) and rolls out
  highway-env's own IDM/MOBIL models with randomised driver parameters and random forced lane
  changes — multi-modal by construction; :class:`ConstantVelocityPredictor` extrapolates each
  car's velocity with Gaussian velocity noise; :class:`LearnedPredictor` samples the
  mixture-density network trained on highway-env rollouts of other seeds (``training``).
* Agents (``--methods``, :data:`AGENTS` of :class:`Agent` records: a driver, a plan method, a
  predictor): ``mmd`` (MMD-Opt), ``degroot`` (the scenario baseline), ``cv`` (Algorithm 1 with
  the scenario cost against the single noise-free constant-velocity prediction of each car: a
  planner that ignores uncertainty) and ``idm`` (highway-env's own IDM/MOBIL driver as the ego,
  no planner: the reference for speed).
* :func:`run_highway` — the resumable benchmark behind ``mmdopt bench highway`` (one JSON per
  finished episode, ``episodes.csv`` rebuilt from them), :func:`write_video` for one episode with
  the planner drawn on it (:mod:`.video`).
"""

from .adapter import (
    HighwaySource,
    PlanFollower,
    bicycle_limits,
    classify_crash,
    frenet_to_pose,
    plan_curvature,
    vehicle_to_frenet,
)
from .cli import add_highway_parser, cmd_highway, main
from .predictors import (
    ConstantVelocityPredictor,
    LearnedPredictor,
    SimulatorPredictor,
    make_predictor,
    straight_parallel,
)
from .runner import (
    CSV_COLUMNS,
    config_for_method,
    risk_overrides,
    run_episode,
    run_highway,
    summarize,
    write_csv,
    write_video,
)
from .settings import (
    AGENTS,
    EGO_MODELS,
    HIGHWAY_PLANNER,
    JUNCTION_SHIELD,
    METHODS,
    PREDICTORS,
    SHIELD,
    Agent,
    HighwaySettings,
    highway_available,
    highway_config,
)

__all__ = [
    "HIGHWAY_PLANNER",
    "AGENTS",
    "Agent",
    "METHODS",
    "PREDICTORS",
    "CSV_COLUMNS",
    "HighwaySettings",
    "HighwaySource",
    "PlanFollower",
    "EGO_MODELS",
    "JUNCTION_SHIELD",
    "SHIELD",
    "bicycle_limits",
    "plan_curvature",
    "SimulatorPredictor",
    "ConstantVelocityPredictor",
    "LearnedPredictor",
    "make_predictor",
    "vehicle_to_frenet",
    "frenet_to_pose",
    "classify_crash",
    "highway_config",
    "highway_available",
    "run_episode",
    "run_highway",
    "risk_overrides",
    "config_for_method",
    "summarize",
    "write_csv",
    "write_video",
    "add_highway_parser",
    "cmd_highway",
    "main",
    "straight_parallel",
]
