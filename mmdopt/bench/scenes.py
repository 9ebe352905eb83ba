"""Synthetic multi-modal driving scenes (paper §IV-A, "Benchmarks and Metrics").

One obstacle ahead of the ego on a straight road (Frenet frame = Cartesian frame).  Its future is
multi-modal: every sample draws a discrete **lateral intent** (a lane offset ``y_d``, e.g. "stay
in / cut into the ego lane" at 0 m vs "go to the left lane" at 3.5 m, with probabilities ``p`` and
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

Ego: origin, 10 m/s along +x, desired speed 10 m/s.  Any generator parameter can be overridden
(``SceneParams.from_dict`` / the CLI's ``--scene-params FILE.json``); unknown keys are an error.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import json
from collections.abc import Mapping
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

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        if self.layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {LAYOUTS}, got {self.layout!r}")
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
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in out.items()}

    @property
    def n_scenes_layout(self) -> int | None:
        """Scenes in a "grid" layout (None for "random": unlimited)."""
        if self.layout == "grid":
            return len(self.x0_grid) * len(self.y0_choices) * len(self.p_grid)
        return None


def _check_keys(d: Mapping[str, Any]) -> None:
    known = set(SceneParams.keys())
    bad = sorted(set(d) - known)
    if bad:
        raise ValueError(
            f"unknown scene parameter(s) {bad}; valid keys: {', '.join(sorted(known))}"
        )


PRESETS: dict[str, SceneParams] = {
    "paper100": SceneParams(),
    "reference36": SceneParams(layout="grid", num_scenes=36),
    "lanechange": SceneParams(ego_y_lb=-0.3, ego_y_ub=3.8),
}


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
    x0, y0 : obstacle start (m);  p : the first intent's probability in this scene
    intent_probs : (I,) probabilities of ``params.intent_offsets``
    obstacles : (1, n, K, 2) planning samples, Cartesian = Frenet (s, d) on the straight road
    validation : (1, N, K, 2) validation samples (independent of the planning samples)
    intents, validation_intents : (n,), (N,) intent index of every sample
    speed_setpoints, validation_speed_setpoints : (n,), (N,) the samples' ``v_d`` (m/s)
    planner_seed : integer seed of the planner's PRNG key (its own stream)
    params : the generator's :class:`SceneParams`
    t : (K,) time grid (s)
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

    @property
    def name(self) -> str:
        return f"scene_{self.index:04d}"

    def describe(self) -> dict[str, Any]:
        """The scene's drawn parameters (for result rows)."""
        return dict(scene=self.index, x0=self.x0, y0=self.y0, p=self.p)

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
        """The scene's generative model of the obstacle as a predictor (:class:`ScenePredictor`)."""
        return ScenePredictor(self.params, self.x0, self.y0, self.intent_probs)

    def forecast(self, min_samples: int = 100, max_samples: int = 5000):
        """The obstacle as a :class:`mmdopt.predict.Forecast` of :meth:`predictor`: a plan with a
        risk level ε draws n(ε) = :func:`mmdopt.risk.samples_for_risk` (ε, 1) futures, within
        ``min_samples`` … ``max_samples`` (the history: ``HISTORY_ROWS`` positions at
        ``obstacle_speed`` along the road, ``HISTORY_DT`` s apart; the context: the scene's
        straight road on the planner's grid)."""
        from mmdopt.predict import Forecast, PredictionContext

        p = self.params
        back = HISTORY_DT * np.arange(HISTORY_ROWS - 1, -1, -1)
        hist = np.stack([self.x0 - p.obstacle_speed * back, np.full(HISTORY_ROWS, self.y0)], -1)
        line = np.array([[self.x0 - 100.0, 0.0], [self.x0 + 2000.0, 0.0]])
        ctx = PredictionContext(
            times=self.t,
            dt_history=HISTORY_DT,
            centerline=line[None],
            lane_width=np.array([3.5]),
            has_left=np.array([len(p.intent_offsets) > 1]),
            has_right=np.array([False]),
            gaps=np.full((1, 6), 100.0),
            rel_speed=np.zeros((1, 6)),
        )
        return Forecast(self.predictor(), hist[None], ctx, min_samples, max_samples)


@dataclass(frozen=True, eq=False)
class ScenePredictor:
    """The synthetic scene's own model of its obstacle as a predictor (the ``mmdopt.predict``
    protocol): every future draws an intent with the scene's probabilities and a Gaussian speed
    set-point, through :func:`sample_obstacle`, exactly as the planning and validation samples.

    ``sample(history, context, n, key)`` returns (1, n, K, 2) futures on the scene's grid
    (``context.times`` must be it); the history and context are checked but the model is the
    scene's, not learned from them.  The random stream is ``SeedSequence([*key_data,
    ROLE_FORECAST])``: deterministic for a given JAX key, and independent of the scene's planning
    (``role`` 1) and validation (``role`` 2) streams.
    """

    params: SceneParams
    x0: float
    y0: float
    probs: np.ndarray
    name: str = "scene model"

    def sample(self, history, context, n: int, key) -> np.ndarray:
        import jax

        from mmdopt.predict.base import check_history, check_key, check_n

        n = check_n(n)
        check_history(history, context)
        if context.num_obstacles != 1:
            raise ValueError(
                f"context must describe the scene's 1 obstacle, got {context.num_obstacles}"
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
        rngs = tuple(np.random.default_rng(c) for c in ss.spawn(2))
        xy, _, _ = sample_obstacle(rngs, self.params, self.x0, self.y0, self.probs, n)
        return xy[None]


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


def _rngs(seed: int, index: int, role: int, k: int) -> list[np.random.Generator]:
    """``k`` independent generators of one role (one per drawn quantity, so that the first
    ``n`` samples do not depend on how many are drawn)."""
    ss = np.random.SeedSequence([int(seed), int(index), int(role)])
    return [np.random.default_rng(s) for s in ss.spawn(k)]


def scene_settings(params: SceneParams, seed: int, index: int) -> tuple[float, float, float]:
    """``(x0, y0, p)`` of scene ``index`` (its own ``role = 0`` stream for the "random" layout)."""
    if params.layout == "grid":
        grid = list(itertools.product(params.x0_grid, params.y0_choices, params.p_grid))
        if not 0 <= index < len(grid):
            raise ValueError(f"scene index {index} outside the grid of {len(grid)} scenes")
        return grid[index]
    r = _rng(seed, index, ROLE_PARAMS)
    x0 = float(r.uniform(*params.x0_range))
    y0 = float(params.y0_choices[int(r.integers(len(params.y0_choices)))])
    p = float(r.uniform(*params.p_range))
    return x0, y0, p


def _intent_probs(params: SceneParams, p: float) -> np.ndarray:
    if params.intent_probs is not None:
        return np.asarray(params.intent_probs)
    I = len(params.intent_offsets)
    if I == 1:
        return np.ones(1)
    return np.concatenate([[p], np.full(I - 1, (1.0 - p) / (I - 1))])


def sample_obstacle(
    rngs: tuple[np.random.Generator, np.random.Generator],
    params: SceneParams,
    x0: float,
    y0: float,
    probs: np.ndarray,
    n: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` obstacle futures ``(n, K, 2)``, their intent indices ``(n,)`` and set-points ``(n,)``.

    ``rngs``: generators of the intents and of the speed set-points.
    """
    intents = rngs[0].choice(len(probs), size=n, p=probs)
    xi = rngs[1].standard_normal(n)
    vd = np.clip(
        params.speed_mean + np.sqrt(params.speed_var) * xi, params.speed_min, params.speed_max
    )
    yd = np.asarray(params.intent_offsets)[intents]
    planner = _obstacle_planner()
    state = np.array([x0, y0, params.obstacle_speed, 0.0, 0.0, 0.0])
    cx, cy = planner.closed_form(np.stack([vd, yd], axis=1), state)
    P = planner.basis.P
    xy = np.stack([np.asarray(cx) @ P.T, np.asarray(cy) @ P.T], axis=-1)
    return xy, intents, vd


def make_scene(index: int, seed: int = 0, params: SceneParams | str = "paper100") -> Scene:
    """Scene ``index`` of the sweep with ``seed`` (reproducible; see the module docstring)."""
    params = preset(params) if isinstance(params, str) else params
    x0, y0, p = scene_settings(params, seed, index)
    probs = _intent_probs(params, p)
    obs, intents, vd = sample_obstacle(
        _rngs(seed, index, ROLE_PLANNING, 2), params, x0, y0, probs, params.n_samples
    )
    val, vintents, vvd = sample_obstacle(
        _rngs(seed, index, ROLE_VALIDATION, 2), params, x0, y0, probs, params.n_validation
    )
    planner_seed = int(
        np.random.SeedSequence([int(seed), int(index), ROLE_PLANNER_KEY]).generate_state(1)[0]
    )
    return Scene(
        index=int(index),
        seed=int(seed),
        x0=float(x0),
        y0=float(y0),
        p=float(p),
        intent_probs=probs,
        obstacles=obs[None],
        validation=val[None],
        intents=intents,
        validation_intents=vintents,
        speed_setpoints=vd,
        validation_speed_setpoints=vvd,
        planner_seed=planner_seed,
        params=params,
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


def demo_scene() -> Scene:
    """The built-in demo scene (paper Fig. 3): the obstacle starts 45 m ahead in the right lane
    and cuts into the ego lane with probability 10 % or crosses to the left lane with 90 %."""
    params = PRESETS["reference36"]
    grid = list(itertools.product(params.x0_grid, params.y0_choices, params.p_grid))
    return make_scene(grid.index((45.0, -3.0, 0.10)), seed=0, params=params)
