"""Synthetic multi-modal driving scenes (paper §IV-A, "Benchmarks and Metrics", and the journal
version's static and dynamic families).

Obstacles ahead of the ego on a straight road (Frenet frame = Cartesian frame): one in the
conference paper's presets, 1–5 in the journal's (``num_obstacles``, the CLI's ``--obstacles``).
Each future is multi-modal: every sample draws a discrete **lateral intent** (a lane offset
``y_d``, e.g. "stay in / cut into the ego lane" at 0 m vs "go to the left lane" at 3.5 m, with
probabilities ``p`` and
``1 − p``) and a Gaussian **speed set-point** ``v_d ~ N(speed_mean, speed_var)`` clipped to
``[speed_min, speed_max]``; the pair ``(v_d, y_d)`` is passed through the Frenet planner
(:meth:`frenet.BehaviouralPlanner.closed_form`, one segment, from the obstacle's own initial state
``(x0, y0, obstacle_speed, 0, 0, 0)``), exactly as the reference's ``compute_obs_guess``
(``k_v = k_p = 2``, jerk smoothness, ``ẏ_{K−1} = 0``).

Each :class:`Scene` holds ``n_samples`` **planning samples** (what the planner sees) and a
separate **validation set** of ``n_validation`` fresh samples from the same distribution (what
the metric counts).  Every random quantity comes from its own stream,
``numpy.random.SeedSequence([seed, scene_index, role])`` with ``role`` 0 = scene parameters,
1 = planning samples, 2 = validation samples, 3 = the planner's PRNG key: scenes are reproducible,
independent of each other and of how many scenes are generated, and the validation samples are
independent of the planning samples (the reference re-used the same speed draws in every scene
and left the lateral draws unseeded).

Instead of the fixed planning samples, a planner may draw as many futures as its risk level needs
from the scene's own generative model: :meth:`Scene.forecast` is a :class:`mmdopt.predict.Forecast`
of a :class:`ScenePredictor` (the ``mmdopt.predict`` protocol; its random stream is derived from
the JAX key it is given and tagged with ``role`` 4, so it is independent of the validation
samples).

Presets (:data:`PRESETS`):

``paper100``     the paper's protocol: 100 scenes, ``x0 ~ U[45, 75]`` m, ``y0`` ∈ {−3, 0} m
                 (uniform), ``p ~ U[0.05, 0.30]``; ego lane bounds ±0.3 m (speed changes only).
``reference36``  the reference code's grid: ``x0 ∈ {45, 60, 75}`` × ``y0 ∈ {−3, 0}``
                 × ``p ∈ {5, 10, …, 30} %`` = 36 scenes (order: x0, then y0, then p).
``lanechange``   ``paper100`` with ego lane bounds spanning the ego lane and the left lane
                 (−0.3 … 3.8 m), so the ego may also change lanes (the reference's ±0.3 m bounds
                 only allow speed modulation).

The journal version's families (MMD-OPT, arXiv 2412.09121, ``obs_data_generate_static.py`` and
``obs_data_generate_dynamic.py``), on its two lanes shifted so that the ego lane's centre is 0 m
(its −1.75 / +1.75 m are 0 / 3.5 m here), the ego at 3 m/s wanting 10 m/s, 2 obstacles by
default (the count both of its command lines run):

``static-gaussian``, ``static-bimodal``, ``static-trimodal``
                 standing obstacles at distinct x ∈ {30, 37.8, …, 100} m in either lane, their
                 positions noisy: Gaussian (std 1 / 0.2 m), or the journal's two- and three-mode
                 mixtures (:data:`STATIC_NOISE`); the ego may use both lanes.
``cutin-low``, ``cutin-high``
                 moving obstacles at distinct x ∈ 30 … 60 m (30 values) in either lane, at
                 distinct speeds 0.5 … 7 m/s (15 values), each ending in the ego lane with
                 probability p, drawn without replacement from {0.05 … 0.3} (low) or
                 {0.7 … 0.95} (high), else in the other; speed set-points a three-mode mixture;
                 the ego keeps its lane (±0.5 m).

Ego: origin, 10 m/s along +x, desired speed 10 m/s.  Any generator parameter can be overridden
(``SceneParams.from_dict`` / the CLI's ``--scene-params FILE.json``); unknown keys are an error.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "SceneParams",
    "Scene",
    "PRESETS",
    "preset",
    "load_scene_params",
    "make_scene",
    "make_scenes",
    "num_scenes",
    "scene_settings",
    "scene_layout",
    "Layout",
    "sample_obstacle",
    "sample_obstacles",
    "scene_rngs",
    "forecast_inputs",
    "STREAMS_PER_OBSTACLE",
    "JOURNAL_FAMILIES",
    "STATIC_NOISE",
    "demo_scene",
    "ROLE_PARAMS",
    "ROLE_PLANNING",
    "ROLE_VALIDATION",
    "ROLE_PLANNER_KEY",
    "ROLE_FORECAST",
    "ScenePredictor",
]

ROLE_PARAMS, ROLE_PLANNING, ROLE_VALIDATION, ROLE_PLANNER_KEY, ROLE_FORECAST = 0, 1, 2, 3, 4
#: spacing (s) and rows of the constant-velocity history of :meth:`Scene.forecast`
HISTORY_DT, HISTORY_ROWS = 0.1, 10

HORIZON_S = 15.0
NUM_STEPS = 100


def _tuple(v) -> tuple:
    return tuple(float(x) for x in v)


#: how a family's scenes are laid out: drawn at random, or on a grid of its ranges
LAYOUTS = ("random", "grid")
#: how the obstacles' futures move: to an intent through the Frenet planner, or standing still
MOTIONS = ("intent", "static")


def _modes(name: str, rows, width: int) -> tuple[tuple[float, ...], ...]:
    """A Gaussian mixture's rows ``(probability, means…, stds…)``, checked: ``width`` numbers
    each, probabilities ≥ 0 summing to 1, standard deviations ≥ 0."""
    try:
        out = tuple(tuple(float(x) for x in r) for r in rows)
    except TypeError:
        raise ValueError(f"{name} must be rows of {width} numbers, got {rows!r}") from None
    if not out or any(len(r) != width for r in out):
        raise ValueError(f"{name} must be rows of {width} numbers, got {[list(r) for r in out]}")
    probs = np.array([r[0] for r in out])
    if not np.all(np.isfinite(np.array(out))):
        raise ValueError(f"{name} must be finite")
    if np.any(probs < 0) or abs(probs.sum() - 1.0) > 1e-9:
        raise ValueError(f"{name}: the probabilities (first column) must be >= 0 and sum to 1")
    nstd = (width - 1) // 2
    if any(x < 0 for r in out for x in r[-nstd:]):
        raise ValueError(f"{name}: the standard deviations (last {nstd} columns) must be >= 0")
    return out


@dataclass(frozen=True)
class SceneParams:
    """Parameters of the scene generator (SI units).  Field names are the ``--scene-params`` keys.

    layout : "random" (draw ``x0``, ``y0``, ``p`` per scene) or "grid" (the Cartesian product
        ``x0_grid × y0_choices × p_grid``, in that order)
    num_scenes : default number of scenes of the preset (the CLI's ``--scenes`` overrides it)
    x0_range : obstacle start ``x`` range (m) for "random"
    x0_grid : obstacle start ``x`` values (m) for "grid"
    y0_choices : obstacle start lateral offsets (m); "random" picks one uniformly
    p_range : probability of the first intent, drawn uniformly per scene ("random")
    p_grid : probabilities of the first intent ("grid")
    intent_offsets : lateral targets ``y_d`` of the intents (m, absolute offsets from the road
        centre line); at least one
    intent_probs : fixed probabilities of the intents (sum 1), or ``None``: the first intent
        gets the scene's ``p``, the others share ``1 − p`` equally
    obstacle_speed : obstacle initial speed (m/s), along +x, zero acceleration
    speed_mean, speed_var : mean (m/s) and variance (m²/s²) of the speed set-point
    speed_min, speed_max : clip range of the speed set-point (m/s)
    n_samples : planning samples per scene (the planner's input)
    n_validation : validation samples per scene (the metric)
    ego_y_lb, ego_y_ub : ego lateral (lane) bounds (m)
    ego_speed : ego initial speed (m/s); the ego starts at the origin heading +x
    desired_speed : the ego's desired speed (m/s)
    num_obstacles : obstacles per scene (1–5 in the journal's protocol; the CLI's
        ``--obstacles``); each draws its own start, speed, intent probability and futures
    x0_choices : ``None`` (``x0`` from ``x0_range``), or the start positions (m) the obstacles
        take *without replacement* (the journal's grid, so no two start on one spot)
    obstacle_speed_choices : ``None`` (every obstacle at ``obstacle_speed``), or initial speeds
        (m/s) drawn without replacement
    p_choices : ``None`` (``p`` from ``p_range``), or first-intent probabilities drawn without
        replacement (the journal's ``prob_arr``)
    speed_modes : ``None`` (the set-point is ``N(speed_mean, speed_var)``), or a Gaussian mixture
        of the speed set-point, rows ``(probability, mean m/s, std m/s)`` (the journal's
        trimodal 0.4 / 0.2 / 0.4), clipped to ``[speed_min, speed_max]`` as well
    motion : "intent" (every future drives to an intent through the Frenet planner) or
        "static" (the obstacle stands still at a noisy position: the journal's static scenes)
    position_modes : "static" motion's noise on the start, a Gaussian mixture of rows
        ``(probability, mean x, mean y, std x, std y)`` (m); one row is Gaussian noise
    footprint : ``None`` (the planner config's collision ellipse and the metric's nominal one),
        or the semi-axes ``(a, b)`` (m) the family was made for: the planner plans with them
        and the metric counts collisions with them (the journal's families: its 4.25 × 2.75 m,
        so that a car in the next lane, 3.5 m over, is clear of the ego lane)
    """

    layout: str = "random"
    num_scenes: int = 100
    x0_range: tuple[float, float] = (45.0, 75.0)
    x0_grid: tuple[float, ...] = (45.0, 60.0, 75.0)
    y0_choices: tuple[float, ...] = (-3.0, 0.0)
    p_range: tuple[float, float] = (0.05, 0.30)
    p_grid: tuple[float, ...] = (0.05, 0.10, 0.15, 0.20, 0.25, 0.30)
    intent_offsets: tuple[float, ...] = (0.0, 3.5)
    intent_probs: tuple[float, ...] | None = None
    obstacle_speed: float = 5.0
    speed_mean: float = 5.0
    speed_var: float = 2.0
    speed_min: float = 0.1
    speed_max: float = 30.0
    n_samples: int = 100
    n_validation: int = 1000
    ego_y_lb: float = -0.3
    ego_y_ub: float = 0.3
    ego_speed: float = 10.0
    desired_speed: float = 10.0
    num_obstacles: int = 1
    x0_choices: tuple[float, ...] | None = None
    obstacle_speed_choices: tuple[float, ...] | None = None
    p_choices: tuple[float, ...] | None = None
    speed_modes: tuple[tuple[float, float, float], ...] | None = None
    motion: str = "intent"
    position_modes: tuple[tuple[float, float, float, float, float], ...] = ((1.0, 0, 0, 0, 0),)
    footprint: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        if self.layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {LAYOUTS}, got {self.layout!r}")
        if self.motion not in MOTIONS:
            raise ValueError(f"motion must be one of {MOTIONS}, got {self.motion!r}")
        v = self.num_obstacles
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 5:
            raise ValueError(f"num_obstacles must be an integer in 1 … 5, got {v!r}")
        set_("num_obstacles", int(v))
        for name in ("x0_choices", "obstacle_speed_choices", "p_choices"):
            v = getattr(self, name)
            if v is None:
                continue
            v = _tuple(np.atleast_1d(v))
            if len(v) < self.num_obstacles:
                raise ValueError(
                    f"{name} has {len(v)} values, fewer than num_obstacles = "
                    f"{self.num_obstacles} (they are drawn without replacement)"
                )
            if not all(np.isfinite(v)):
                raise ValueError(f"{name} must be finite, got {list(v)}")
            set_(name, v)
        if self.p_choices is not None and not all(0 <= x <= 1 for x in self.p_choices):
            raise ValueError(f"p_choices must lie in [0, 1], got {list(self.p_choices)}")
        if self.obstacle_speed_choices is not None and min(self.obstacle_speed_choices) < 0:
            raise ValueError("obstacle_speed_choices must be >= 0")
        if self.speed_modes is not None:
            set_("speed_modes", _modes("speed_modes", self.speed_modes, 3))
        set_("position_modes", _modes("position_modes", self.position_modes, 5))
        if self.footprint is not None:
            fp = _tuple(np.atleast_1d(self.footprint))
            if len(fp) != 2 or not all(np.isfinite(fp)) or min(fp) <= 0:
                raise ValueError(f"footprint must be [a, b], two semi-axes > 0 (m), got {list(fp)}")
            set_("footprint", fp)
        for name in ("x0_range", "p_range"):
            v = _tuple(getattr(self, name))
            if len(v) != 2 or not v[0] <= v[1]:
                raise ValueError(f"{name} must be [low, high] with low <= high, got {list(v)}")
            set_(name, v)
        for name in ("x0_grid", "y0_choices", "p_grid", "intent_offsets"):
            v = _tuple(np.atleast_1d(getattr(self, name)))
            if len(v) == 0:
                raise ValueError(f"{name} must not be empty")
            set_(name, v)
        for name in ("p_range", "p_grid"):
            v = np.asarray(getattr(self, name))
            if np.any(v < 0) or np.any(v > 1):
                raise ValueError(f"{name} must lie in [0, 1], got {list(v)}")
        if self.intent_probs is not None:
            pr = _tuple(np.atleast_1d(self.intent_probs))
            if len(pr) != len(self.intent_offsets):
                raise ValueError(
                    f"intent_probs has {len(pr)} entries but intent_offsets has "
                    f"{len(self.intent_offsets)}"
                )
            if min(pr) < 0 or abs(sum(pr) - 1.0) > 1e-9:
                raise ValueError(f"intent_probs must be non-negative and sum to 1, got {list(pr)}")
            set_("intent_probs", pr)
        for name in ("num_scenes", "n_samples", "n_validation"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
            set_(name, int(v))
        for name in (
            "obstacle_speed",
            "speed_mean",
            "speed_var",
            "speed_min",
            "speed_max",
            "ego_y_lb",
            "ego_y_ub",
            "ego_speed",
            "desired_speed",
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
                raise ValueError(f"{name} must be a number, got {v!r}")
            if not np.isfinite(v):
                raise ValueError(f"{name} must be finite, got {v!r}")
            set_(name, float(v))
        if self.speed_var < 0:
            raise ValueError(f"speed_var must be >= 0, got {self.speed_var}")
        if self.speed_min > self.speed_max:
            raise ValueError("speed_min > speed_max")
        if self.ego_y_lb > self.ego_y_ub:
            raise ValueError("ego_y_lb > ego_y_ub")
        if not self.ego_y_lb <= 0.0 <= self.ego_y_ub:
            raise ValueError("the ego starts at y = 0, which must lie in [ego_y_lb, ego_y_ub]")

    # ------------------------------------------------------------------ (de)serialisation
    @classmethod
    def keys(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))

    def replace(self, **kw) -> SceneParams:
        _check_keys(kw)
        return dataclasses.replace(self, **kw)

    def update(self, overrides: Mapping[str, Any]) -> SceneParams:
        """A copy with ``overrides`` applied (unknown keys raise ``ValueError`` naming them)."""
        return self.replace(**dict(overrides))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], base: SceneParams | None = None) -> SceneParams:
        return (base or cls()).update(d)

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        return {k: _lists(v) for k, v in out.items()}

    @property
    def n_scenes_layout(self) -> int | None:
        """Scenes in a "grid" layout (None for "random": unlimited)."""
        if self.layout == "grid":
            return len(self.x0_grid) * len(self.y0_choices) * len(self.p_grid)
        return None


def _lists(v):
    return [_lists(x) for x in v] if isinstance(v, tuple) else v


def _check_keys(d: Mapping[str, Any]) -> None:
    known = set(SceneParams.keys())
    bad = sorted(set(d) - known)
    if bad:
        raise ValueError(
            f"unknown scene parameter(s) {bad}; valid keys: {', '.join(sorted(known))}"
        )


#: the journal version's two lanes (its y = ∓1.75 m), here with the ego lane's centre at 0 m
JOURNAL_LANES = (0.0, 3.5)
#: the journal's collision ellipse (``a_obs``, ``b_obs``: semi-axes, m)
JOURNAL_FOOTPRINT = (4.25, 2.75)
#: the journal's static scenes (``obs_data_generate_static.py``): standing obstacles 30–100 m
#: ahead on a grid of 10, in either lane, ego at 3 m/s wanting 10 m/s, both lanes drivable
#: (its −2.25 … 2.25 m)
_STATIC = dict(
    motion="static",
    footprint=JOURNAL_FOOTPRINT,
    num_obstacles=2,
    x0_choices=tuple(np.linspace(30.0, 100.0, 10)),
    y0_choices=JOURNAL_LANES,
    intent_offsets=(0.0,),
    obstacle_speed=0.0,
    ego_speed=3.0,
    desired_speed=10.0,
    ego_y_lb=-0.5,
    ego_y_ub=4.0,
)
#: its noise on the obstacles' positions, rows (probability, mean x, mean y, std x, std y)
STATIC_NOISE = {
    "gaussian": ((1.0, 0.0, 0.0, 1.0, 0.2),),
    "bimodal": ((0.8, -1.0, -0.3, 0.5, 0.1), (0.2, 1.0, 0.3, 0.1, 0.02)),
    "trimodal": (
        (0.4, -1.0, -0.3, 0.5, 0.1),
        (0.2, 1.0, 0.3, 0.1, 0.02),
        (0.4, -1.0, 0.2, 0.1, 0.02),
    ),
}
#: the journal's dynamic scenes (``obs_data_generate_dynamic.py``): obstacles 30–60 m ahead on a
#: grid of 30 in either lane, at 0.5–7 m/s on a grid of 15, each driving to the ego lane with
#: probability p or to the other lane, its speed set-point a mixture of three modes
#: (0.4 / 0.2 / 0.4 at 5 / 7 / 3 m/s, std 1.5 / 0.1 / 3); the ego at 3 m/s wanting 10 m/s
_DYNAMIC = dict(
    footprint=JOURNAL_FOOTPRINT,
    num_obstacles=2,
    x0_choices=tuple(np.linspace(30.0, 60.0, 30)),
    y0_choices=JOURNAL_LANES,
    obstacle_speed_choices=tuple(np.linspace(0.5, 7.0, 15)),
    intent_offsets=JOURNAL_LANES,
    speed_modes=((0.4, 5.0, 1.5), (0.2, 7.0, 0.1), (0.4, 3.0, 3.0)),
    ego_speed=3.0,
    desired_speed=10.0,
)

PRESETS: dict[str, SceneParams] = {
    "paper100": SceneParams(),
    "reference36": SceneParams(layout="grid", num_scenes=36),
    "lanechange": SceneParams(ego_y_lb=-0.3, ego_y_ub=3.8),
    "static-gaussian": SceneParams(**_STATIC, position_modes=STATIC_NOISE["gaussian"]),
    "static-bimodal": SceneParams(**_STATIC, position_modes=STATIC_NOISE["bimodal"]),
    "static-trimodal": SceneParams(**_STATIC, position_modes=STATIC_NOISE["trimodal"]),
    # in-lane cut-in: the ego keeps its lane (the journal's −2.25 … −1.25 m), p from prob_arr
    "cutin-low": SceneParams(
        **_DYNAMIC, p_choices=(0.05, 0.1, 0.15, 0.2, 0.25, 0.3), ego_y_lb=-0.5, ego_y_ub=0.5
    ),
    "cutin-high": SceneParams(
        **_DYNAMIC, p_choices=(0.95, 0.9, 0.85, 0.8, 0.75, 0.7), ego_y_lb=-0.5, ego_y_ub=0.5
    ),
}
#: the journal's families (the others are the conference paper's)
JOURNAL_FAMILIES = (
    "static-gaussian",
    "static-bimodal",
    "static-trimodal",
    "cutin-low",
    "cutin-high",
)


def preset(name: str) -> SceneParams:
    """The :class:`SceneParams` of a preset by name (see :data:`PRESETS`)."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; choose one of {sorted(PRESETS)}") from None


def load_scene_params(path: str | Path, base: SceneParams | str = "paper100") -> SceneParams:
    """Read a ``--scene-params`` JSON object and apply it to ``base`` (a preset name or params)."""
    base = preset(base) if isinstance(base, str) else base
    p = Path(path)
    try:
        d = json.loads(p.read_text())
    except FileNotFoundError:
        raise ValueError(f"scene-params file {str(p)!r} does not exist") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"scene-params file {str(p)!r} is not valid JSON: {e}") from None
    if not isinstance(d, dict):
        raise ValueError(f"scene-params file {str(p)!r} must hold a JSON object")
    return base.update(d)


# ---------------------------------------------------------------------------------------------
# scenes


@dataclass(frozen=True, eq=False)
class Scene:
    """One synthetic scene.

    Attributes
    ----------
    index, seed : the scene's position in its sweep and the sweep's seed
    x0, y0 : the first obstacle's start (m);  p : its first intent's probability
    intent_probs : (I,) its probabilities of ``params.intent_offsets``
    obstacles : (O, n, K, 2) planning samples, Cartesian = Frenet (s, d) on the straight road
    validation : (O, N, K, 2) validation samples (independent of the planning samples; sample
        ``j`` of every obstacle is one joint draw of the traffic)
    intents, validation_intents : (n,), (N,) the first obstacle's intent index of every sample
    speed_setpoints, validation_speed_setpoints : (n,), (N,) its samples' ``v_d`` (m/s)
    planner_seed : integer seed of the planner's PRNG key (its own stream)
    params : the generator's :class:`SceneParams`
    t : (K,) time grid (s)
    layout : every obstacle's drawn settings (:class:`Layout`: ``x0``, ``y0``, ``p``, speed)
    obstacle_intent_probs : (O, I) every obstacle's intent probabilities
    """

    index: int
    seed: int
    x0: float
    y0: float
    p: float
    intent_probs: np.ndarray
    obstacles: np.ndarray
    validation: np.ndarray
    intents: np.ndarray
    validation_intents: np.ndarray
    speed_setpoints: np.ndarray
    validation_speed_setpoints: np.ndarray
    planner_seed: int
    params: SceneParams
    t: np.ndarray = field(repr=False, default_factory=lambda: np.linspace(0, HORIZON_S, NUM_STEPS))
    layout: Layout | None = field(repr=False, default=None)
    obstacle_intent_probs: np.ndarray | None = field(repr=False, default=None)

    def __post_init__(self) -> None:
        if self.layout is None:  # a scene built by hand with one obstacle
            one = lambda v: np.array([float(v)])  # noqa: E731
            lay = Layout(one(self.x0), one(self.y0), one(self.p), one(self.params.obstacle_speed))
            object.__setattr__(self, "layout", lay)
        if self.obstacle_intent_probs is None:
            object.__setattr__(self, "obstacle_intent_probs", np.atleast_2d(self.intent_probs))

    @property
    def name(self) -> str:
        return f"scene_{self.index:04d}"

    @property
    def num_obstacles(self) -> int:
        return int(self.obstacles.shape[0])

    def describe(self) -> dict[str, Any]:
        """The scene's drawn parameters (for result rows): the first obstacle's ``x0``, ``y0``,
        ``p``, and the number of obstacles."""
        return dict(scene=self.index, x0=self.x0, y0=self.y0, p=self.p,
                    obstacles=self.num_obstacles)  # fmt: skip

    # ---- planning inputs (need Algorithm 1's API: imported lazily)
    def ego(self):
        """The ego's :class:`frenet.EgoState` (origin, ``ego_speed`` along the road)."""
        import frenet

        return frenet.EgoState(s=0.0, d=0.0, vs=self.params.ego_speed)

    def road(self, **kw):
        """The ``mmdopt.Road`` of the scene: straight path along +x, lane bounds from ``params``."""
        import mmdopt

        return mmdopt.Road(
            path=straight_path(), y_lb=self.params.ego_y_lb, y_ub=self.params.ego_y_ub, **kw
        )

    def key(self):
        """The planner's JAX PRNG key (its own stream, ``role = 3``)."""
        import jax

        return jax.random.PRNGKey(self.planner_seed)

    def predictor(self) -> ScenePredictor:
        """The scene's model of its obstacles as a predictor (:class:`ScenePredictor`)."""
        return ScenePredictor(
            self.params, self.x0, self.y0, self.intent_probs,
            layout=self.layout, obstacle_probs=self.obstacle_intent_probs,
        )  # fmt: skip

    def forecast(self, min_samples: int = 100, max_samples: int = 5000):
        """The obstacles as a :class:`mmdopt.predict.Forecast` of :meth:`predictor`: a plan with
        a risk level ε draws n(ε) = :func:`mmdopt.risk.samples_for_risk` (ε, …) futures, within
        ``min_samples`` … ``max_samples`` (the history: ``HISTORY_ROWS`` positions of each
        obstacle at its initial speed along the road, ``HISTORY_DT`` s apart; the context: the
        scene's straight road on the planner's grid)."""
        from mmdopt.predict import Forecast

        lay = self.layout
        pos = np.stack([lay.x0, lay.y0], -1)
        vel = np.stack([lay.speed, np.zeros_like(lay.speed)], -1)
        hist, ctx = forecast_inputs(pos, vel, self.t, len(self.params.intent_offsets) > 1)
        return Forecast(self.predictor(), hist, ctx, min_samples, max_samples)


@dataclass(frozen=True, eq=False)
class ScenePredictor:
    """The synthetic scene's own model of its obstacles as a predictor (the ``mmdopt.predict``
    protocol): every future draws what the scene's planning and validation samples draw (an
    intent with the scene's probabilities and a speed set-point, or a static obstacle's noisy
    position), through :func:`sample_obstacles`.

    ``sample(history, context, n, key)`` returns (O, n, K, 2) futures on the scene's grid
    (``context.times`` must be it); the history and context are checked but the model is the
    scene's, not learned from them.  The random stream is ``SeedSequence([*key_data,
    ROLE_FORECAST])``: deterministic for a given JAX key, and independent of the scene's planning
    (``role`` 1) and validation (``role`` 2) streams.  ``x0``, ``y0``, ``probs``: the first
    obstacle's (a one-obstacle scene needs nothing else); ``layout`` and ``obstacle_probs``:
    every obstacle's; ``states``: optional (O, 6) current states ``(x, y, vx, vy, ax, ay)`` the
    futures of moving obstacles start from (:mod:`mmdopt.bench.loop`).
    """

    params: SceneParams
    x0: float
    y0: float
    probs: np.ndarray
    name: str = "scene model"
    layout: Layout | None = None
    obstacle_probs: np.ndarray | None = None
    states: np.ndarray | None = None

    def _layout(self) -> tuple[Layout, np.ndarray]:
        if self.layout is not None:
            probs = self.obstacle_probs
            return self.layout, np.atleast_2d(self.probs if probs is None else probs)
        one = lambda v: np.array([float(v)])  # noqa: E731
        lay = Layout(one(self.x0), one(self.y0), one(np.nan), one(self.params.obstacle_speed))
        return lay, np.atleast_2d(self.probs)

    def sample(self, history, context, n: int, key) -> np.ndarray:
        import jax

        from mmdopt.predict.base import check_history, check_key, check_n

        n = check_n(n)
        check_history(history, context)
        lay, probs = self._layout()
        O = len(lay.x0)
        if context.num_obstacles != O:
            raise ValueError(
                f"context must describe the scene's {O} obstacle(s), got {context.num_obstacles}"
            )
        t = np.linspace(0, HORIZON_S, NUM_STEPS)
        if context.times.shape != t.shape or not np.allclose(context.times, t, atol=1e-9):
            raise ValueError(
                f"context.times must be the scene's grid ({NUM_STEPS} points over {HORIZON_S:g} s)"
            )
        k = check_key(key)
        if jax.dtypes.issubdtype(np.asarray(k).dtype if not hasattr(k, "dtype") else k.dtype,
                                 jax.dtypes.prng_key):  # fmt: skip
            k = jax.random.key_data(k)
        data = np.asarray(k, np.uint32).ravel()
        ss = np.random.SeedSequence([*data.tolist(), ROLE_FORECAST])
        rngs = tuple(np.random.default_rng(c) for c in ss.spawn(STREAMS_PER_OBSTACLE * O))
        xy, _, _ = sample_obstacles(rngs, self.params, lay, probs, n, self.states)
        return xy


def forecast_inputs(pos: np.ndarray, vel: np.ndarray, t: np.ndarray, has_left: bool):
    """The history and context of a :class:`mmdopt.predict.Forecast` of obstacles on the scenes'
    straight road: ``HISTORY_ROWS`` positions ``HISTORY_DT`` s apart ending at ``pos`` (O, 2)
    and moving at ``vel`` (O, 2) m/s, each on a centre line along +x through its start, on the
    planner's grid ``t``; ``has_left``: whether a lane change is possible."""
    from mmdopt.predict import PredictionContext

    O = pos.shape[0]
    back = HISTORY_DT * np.arange(HISTORY_ROWS - 1, -1, -1)
    hist = pos[:, None, :] - back[None, :, None] * vel[:, None, :]
    lines = np.stack([np.array([[x - 100.0, 0.0], [x + 2000.0, 0.0]]) for x in pos[:, 0]])
    ctx = PredictionContext(
        times=t,
        dt_history=HISTORY_DT,
        centerline=lines,
        lane_width=np.full(O, 3.5),
        has_left=np.full(O, bool(has_left)),
        has_right=np.zeros(O, bool),
        gaps=np.full((O, 6), 100.0),
        rel_speed=np.zeros((O, 6)),
    )
    return hist, ctx


@functools.lru_cache(maxsize=1)
def straight_path():
    """The scenes' road: a straight :class:`frenet.ReferencePath` from the origin along +x."""
    import frenet

    return frenet.ReferencePath.straight(2000.0)


@functools.lru_cache(maxsize=1)
def _obstacle_planner():
    import frenet

    basis = frenet.TripleIntegratorBasis(frenet.TimeGrid(HORIZON_S, NUM_STEPS))
    return frenet.BehaviouralPlanner(basis, frenet.PlannerConfig(num_segments=1))


def _rng(seed: int, index: int, role: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(index), int(role)]))


def scene_rngs(seed: int, index: int, role: int, k: int) -> list[np.random.Generator]:
    """``k`` independent generators of one role (one per drawn quantity, so that the first
    ``n`` samples do not depend on how many are drawn)."""
    ss = np.random.SeedSequence([int(seed), int(index), int(role)])
    return [np.random.default_rng(s) for s in ss.spawn(k)]


def scene_settings(params: SceneParams, seed: int, index: int) -> tuple[float, float, float]:
    """``(x0, y0, p)`` of scene ``index``'s first obstacle (:func:`scene_layout` has them all)."""
    lay = scene_layout(params, seed, index)
    return float(lay.x0[0]), float(lay.y0[0]), float(lay.p[0])


@dataclass(frozen=True, eq=False)
class Layout:
    """The drawn settings of one scene's ``N`` obstacles, each an (N,) array: start ``x0``,
    ``y0`` (m), first-intent probability ``p`` and initial speed (m/s)."""

    x0: np.ndarray
    y0: np.ndarray
    p: np.ndarray
    speed: np.ndarray


def scene_layout(params: SceneParams, seed: int, index: int) -> Layout:
    """The obstacles' settings of scene ``index`` (its own ``role = 0`` stream for the "random"
    layout; a "grid" scene has one obstacle per grid point and ``num_obstacles`` = 1).

    One obstacle with no ``*_choices`` draws exactly as it always did (``x0``, the lane, ``p``);
    otherwise each quantity is drawn for all obstacles at once, the ``*_choices`` without
    replacement (the journal's ``np.random.choice(..., replace=False)``)."""
    N = params.num_obstacles
    if params.layout == "grid":
        if N != 1:
            raise ValueError("the grid layout has one obstacle per scene (num_obstacles = 1)")
        grid = list(itertools.product(params.x0_grid, params.y0_choices, params.p_grid))
        if not 0 <= index < len(grid):
            raise ValueError(f"scene index {index} outside the grid of {len(grid)} scenes")
        x0, y0, p = grid[index]
        speed = params.obstacle_speed
        return Layout(np.array([x0]), np.array([y0]), np.array([p]), np.array([speed]))
    r = _rng(seed, index, ROLE_PARAMS)
    if N == 1 and params.x0_choices is None and params.p_choices is None:
        x0 = np.array([r.uniform(*params.x0_range)])
        y0 = np.array([params.y0_choices[int(r.integers(len(params.y0_choices)))]])
        p = np.array([r.uniform(*params.p_range)])
    else:
        if params.x0_choices is None:
            x0 = r.uniform(*params.x0_range, size=N)
        else:
            x0 = r.choice(np.asarray(params.x0_choices), size=N, replace=False)
        y0 = np.asarray(params.y0_choices)[r.integers(len(params.y0_choices), size=N)]
        if params.p_choices is None:
            p = r.uniform(*params.p_range, size=N)
        else:
            p = r.choice(np.asarray(params.p_choices), size=N, replace=False)
    if params.obstacle_speed_choices is None:
        speed = np.full(N, params.obstacle_speed)
    else:
        speed = r.choice(np.asarray(params.obstacle_speed_choices), size=N, replace=False)
    return Layout(x0.astype(float), y0.astype(float), p.astype(float), speed.astype(float))


def _intent_probs(params: SceneParams, p: float) -> np.ndarray:
    if params.intent_probs is not None:
        return np.asarray(params.intent_probs)
    I = len(params.intent_offsets)
    if I == 1:
        return np.ones(1)
    return np.concatenate([[p], np.full(I - 1, (1.0 - p) / (I - 1))])


#: independent generators per obstacle: its intents (or noise modes), its speed set-points (or
#: position noise), and the modes of a speed mixture
STREAMS_PER_OBSTACLE = 3


def _mixture(
    rng_mode, rng_value, rows, n: int, dims: int, offset=0.0
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` draws of a Gaussian mixture of ``rows`` ``(probability, means…, stds…)`` with
    ``dims`` coordinates, (n, dims), and their modes (n,): a mode per draw from ``rng_mode``, a
    standard normal per draw and coordinate from ``rng_value`` (so the first draws do not depend
    on ``n``); ``offset`` (dims,) is added to the means (a static obstacle's start)."""
    rows = np.asarray(rows, dtype=float)
    xi = rng_value.standard_normal((n, dims))
    mode = rng_mode.choice(len(rows), size=n, p=rows[:, 0]) if len(rows) > 1 else np.zeros(n, int)
    return offset + rows[mode, 1 : 1 + dims] + rows[mode, 1 + dims :] * xi, mode


def sample_obstacle(
    rngs: Sequence[np.random.Generator],
    params: SceneParams,
    x0: float,
    y0: float,
    probs: np.ndarray,
    n: int,
    speed: float | None = None,
    state: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` futures of one obstacle ``(n, K, 2)``, their intent indices ``(n,)`` and speed
    set-points ``(n,)`` (a static obstacle: its noise modes and 0).

    ``rngs``: generators of the intents and of the speed set-points (and of a speed mixture's
    modes, a third one, needed only with ``params.speed_modes``); ``speed``: the obstacle's
    initial speed (``None``: ``params.obstacle_speed``); ``state``: instead, its whole initial
    state ``(x, y, vx, vy, ax, ay)`` (a moving obstacle in the receding loop, from now on).
    """
    K = NUM_STEPS
    if params.motion == "static":  # the journal's static scenes: a noisy position, no motion
        pos, mode = _mixture(rngs[0], rngs[1], params.position_modes, n, 2, np.array([x0, y0]))
        return np.repeat(pos[:, None, :], K, axis=1), mode, np.zeros(n)
    intents = rngs[0].choice(len(probs), size=n, p=probs)
    if params.speed_modes is None:
        xi = rngs[1].standard_normal(n)
        vd = params.speed_mean + np.sqrt(params.speed_var) * xi
    else:
        vd = _mixture(rngs[2], rngs[1], params.speed_modes, n, 1)[0][:, 0]
    vd = np.clip(vd, params.speed_min, params.speed_max)
    yd = np.asarray(params.intent_offsets)[intents]
    planner = _obstacle_planner()
    if state is None:
        v0 = params.obstacle_speed if speed is None else float(speed)
        state = np.array([x0, y0, v0, 0.0, 0.0, 0.0])
    cx, cy = planner.closed_form(np.stack([vd, yd], axis=1), state)
    P = planner.basis.P
    xy = np.stack([np.asarray(cx) @ P.T, np.asarray(cy) @ P.T], axis=-1)
    return xy, intents, vd


def sample_obstacles(
    rngs: Sequence[np.random.Generator],
    params: SceneParams,
    lay: Layout,
    probs: np.ndarray,
    n: int,
    states: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` futures of every obstacle of a scene, (N, n, K, 2), with their intents and set-points
    (N, n): obstacle ``o`` draws from ``rngs[3o : 3o + 3]`` (:func:`sample_obstacle`), so the
    first obstacle's futures are those of a one-obstacle scene.  ``states``: optional (N, 6)
    current states ``(x, y, vx, vy, ax, ay)`` of moving obstacles (their futures start there)."""
    k = STREAMS_PER_OBSTACLE
    outs = [
        sample_obstacle(
            rngs[k * o : k * (o + 1)],
            params,
            float(lay.x0[o]),
            float(lay.y0[o]),
            probs[o],
            n,
            float(lay.speed[o]),
            None if states is None else np.asarray(states[o], dtype=float),
        )
        for o in range(len(lay.x0))
    ]
    return tuple(np.stack(a) for a in zip(*outs, strict=True))


def make_scene(index: int, seed: int = 0, params: SceneParams | str = "paper100") -> Scene:
    """Scene ``index`` of the sweep with ``seed`` (reproducible; see the module docstring)."""
    params = preset(params) if isinstance(params, str) else params
    lay = scene_layout(params, seed, index)
    N = len(lay.x0)
    probs = np.stack([_intent_probs(params, float(p)) for p in lay.p])
    k = STREAMS_PER_OBSTACLE * N
    obs, intents, vd = sample_obstacles(
        scene_rngs(seed, index, ROLE_PLANNING, k), params, lay, probs, params.n_samples
    )
    val, vintents, vvd = sample_obstacles(
        scene_rngs(seed, index, ROLE_VALIDATION, k), params, lay, probs, params.n_validation
    )
    planner_seed = int(
        np.random.SeedSequence([int(seed), int(index), ROLE_PLANNER_KEY]).generate_state(1)[0]
    )
    return Scene(
        index=int(index),
        seed=int(seed),
        x0=float(lay.x0[0]),
        y0=float(lay.y0[0]),
        p=float(lay.p[0]),
        intent_probs=probs[0],
        obstacles=obs,
        validation=val,
        intents=intents[0],
        validation_intents=vintents[0],
        speed_setpoints=vd[0],
        validation_speed_setpoints=vvd[0],
        planner_seed=planner_seed,
        params=params,
        layout=lay,
        obstacle_intent_probs=probs,
    )


def num_scenes(params: SceneParams, requested: int | None = None) -> int:
    """Number of scenes of a sweep: ``requested`` or the preset's, capped by a grid's size."""
    n = params.num_scenes if requested is None else int(requested)
    if n < 1:
        raise ValueError(f"number of scenes must be >= 1, got {n}")
    cap = params.n_scenes_layout
    if cap is not None and n > cap:
        raise ValueError(f"the grid layout has only {cap} scenes, {n} requested")
    return n


def make_scenes(
    n: int | None = None, seed: int = 0, params: SceneParams | str = "paper100"
) -> list[Scene]:
    """Scenes ``0 … n−1`` of a sweep (``n`` defaults to the preset's count)."""
    params = preset(params) if isinstance(params, str) else params
    return [make_scene(i, seed, params) for i in range(num_scenes(params, n))]


def demo_scene(num_obstacles: int = 1) -> Scene:
    """The built-in demo scene (paper Fig. 3): the obstacle starts 45 m ahead in the right lane
    and cuts into the ego lane with probability 10 % or crosses to the left lane with 90 %.

    ``num_obstacles`` > 1 (at most 5): scene 0 of ``paper100``'s generator (seed 0) with that
    many cars, at distinct starts 45, 52.5, …, 105 m (the demo's ``--obstacles``)."""
    if num_obstacles == 1:
        params = PRESETS["reference36"]
        grid = list(itertools.product(params.x0_grid, params.y0_choices, params.p_grid))
        return make_scene(grid.index((45.0, -3.0, 0.10)), seed=0, params=params)
    params = PRESETS["paper100"].replace(
        num_obstacles=num_obstacles, x0_choices=tuple(np.linspace(45.0, 105.0, 9))
    )
    return make_scene(0, seed=0, params=params)
