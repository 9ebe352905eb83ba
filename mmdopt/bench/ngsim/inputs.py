"""Inputs of the recorded-traffic benchmark: scenario files, the benchmark's settings and the
``--config`` of ``bench ngsim``.

The lowest module of :mod:`mmdopt.bench.ngsim` (the scene reader and the runner build on it):

* :func:`check_scenario_file`: a CommonRoad scenario file is non-empty, well-formed XML with a
  ``<commonRoad>`` root, lanelets and dynamic obstacles (cheap: no CommonRoad objects are built);
  :func:`~mmdopt.bench.ngsim.scene.load_scenario` runs it first and turns every error of the
  CommonRoad reader into :class:`ScenarioError` too, so a bad file is one error naming the file
  and the reason, whichever command reads it;
* :class:`NgsimParams` (the benchmark's settings) and :func:`ngsim_config` (its planner
  configuration), re-exported by :mod:`~mmdopt.bench.ngsim.runner`;
* :func:`load_ngsim_config`: ``--config FILE.json`` of ``bench ngsim`` (planner fields over
  :meth:`mmdopt.MMDOptConfig.ngsim` and an optional ``"bench"`` object of :class:`NgsimParams`
  fields), ``ValueError`` naming the key.

Why a set of scenes gives no task is :func:`~mmdopt.bench.ngsim.runner.explain_no_tasks` (it
reads the scenes).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.parsers import expat

import numpy as np

import mmdopt

from .metric import BRAKE_THRESHOLD

__all__ = [
    "ScenarioError",
    "check_scenario_file",
    "NgsimParams",
    "ngsim_config",
    "load_ngsim_config",
]


class ScenarioError(ValueError):
    """A scenario path that cannot be used; the message names the file (or folder) and why."""


def check_scenario_file(path: str | Path) -> None:
    """Raise :class:`ScenarioError` (``"<path>: <reason>"``) unless ``path`` is a readable,
    non-empty, well-formed XML file with a ``<commonRoad>`` root holding at least one
    ``<lanelet>`` and one ``<dynamicObstacle>``."""
    p = Path(path)

    def bad(reason: str) -> ScenarioError:
        return ScenarioError(f"{p}: {reason}")

    if not p.is_file():
        raise bad("does not exist or is not a file")
    seen: dict[str, bool] = {}
    root: list[str] = []

    def start(name, attrs):  # noqa: ARG001
        if not root:
            root.append(name)
        if name in ("lanelet", "dynamicObstacle"):
            seen[name] = True

    # expat without building a tree: every byte is parsed (a truncated file is found) at a
    # tenth of ElementTree's cost
    parser = expat.ParserCreate()
    parser.StartElementHandler = start
    try:
        if p.stat().st_size == 0:
            raise bad("is empty (0 bytes)")
        with open(p, "rb") as f:
            parser.ParseFile(f)
    except expat.ExpatError as e:
        raise bad(f"is not well-formed XML (truncated or not XML: {e})") from None
    except OSError as e:
        raise bad(f"cannot be read ({e})") from None
    if root[0] != "commonRoad":
        raise bad(f"is not a CommonRoad scenario (root element <{root[0]}>, not <commonRoad>)")
    if "lanelet" not in seen:
        raise bad("has no lanelets (the lane network the ego plans on)")
    if "dynamicObstacle" not in seen:
        raise bad("has no dynamic obstacles (no recorded vehicles)")


@dataclass(frozen=True)
class NgsimParams:
    """Benchmark settings (not the planner's; those are an :class:`mmdopt.MMDOptConfig`).

    history : history rows given to the predictor (0.1 s apart)
    first_t0, every : planning times t0 = first_t0, first_t0 + every, … (s) while the ego is
        recorded over the whole horizon
    min_task_speed : egos at least this fast (m/s) at t0 are chosen before slower ones (a car
        waiting at a red light through the whole horizon is no planning task)
    egos_per_time : egos per (scene, t0): the candidates (recorded over history and horizon,
        on the lane map, ≤ ``max_ego_length`` m, ≥ 1 vehicle within range), those at least
        ``min_task_speed`` fast first, then the most vehicles within ``range_m``, ties by id
    range_m, max_obstacles : vehicles planned against (Euclidean distance at t0)
    n_samples, n_validation : predictor samples per obstacle for planning / for the metric
    forecast : plan through the predictor (an :class:`mmdopt.predict.Forecast`): ``plan`` draws
        n(ε) futures per obstacle for the risk level of a "samples"-margin config, at least
        ``n_samples`` (exactly ``n_samples`` with the time-linear margins of the NGSIM preset)
        and at most :data:`MAX_FORECAST_SAMPLES`; ``False``: ``n_samples`` drawn here, a fixed
        array
    routes : predict every car along each route it can still take
        (:class:`~mmdopt.bench.ngsim.routes.RouteMixture` of the predictor over
        :func:`~mmdopt.bench.ngsim.scene.candidate_routes`, learned route weights); ``False``:
        along the straightest route only
    speed_limits : the desired speed is capped at the lowest speed-limit sign of the ego's route
        lanelets it reaches within 2 s (at least 20 m; Lankershim: 3.6–13.4 m/s, the US-101
        scenes have none)
    curve_accel, curve_steer_rate : the desired speed is also capped at the speed at which
        the ego can drive its route's curves within the horizon's reach (``max(20, v0 · T)`` m):
        lateral acceleration at most ``curve_accel`` (m/s²) and the steering rate of the
        curvature's change at most ``curve_steer_rate`` (rad/s: the KS model's limit of the
        drivability checker is 0.4) (:func:`~mmdopt.bench.ngsim.scene.curve_speed`); ``None``:
        that bound is not applied
    reactive_futures : predictor samples per car the ``reactive`` peer avoids, each one a
        CommonRoad obstacle (the first of the planning samples, which mix the routes).  One,
        the planner's design (one prediction per car), chosen on the Lankershim training
        scenes 2_1–2_4 and 2_6 (16 tasks): 1 / 5 / 20 futures gave 0 / 0 / 2 at-fault, 1 / 4 / 7
        contacts, 0.98 / 0.92 / 0.73 of the human's progress, 0.18 / 0.23 / 3.4 s median plan
    warm_up : before each task's timed plan of a JAX method, plan it once with another key,
        untimed, so ``plan_time_s`` is the planner's time on compiled programs, as in a loop at
        10 Hz; the first call's extra time is ``compile_s`` (``False``: one plan, whose time
        includes any compile and ``compile_s`` is empty)
    reactive_full_horizon : the peer samples end times at the horizon only (its default, False:
        from 0.4 s on, a short sample extended straight to the horizon, which leaves the route
        in turns); measured on the Lankershim scenes: True gave it more at-fault collisions
        (6 against 3 of 44) and less progress (0.74 against 0.85)
    lane_keep_margin : lateral freedom (m) on a side without a same-direction lane
    v_des : desired speed (m/s) of the cost (None: the config's)
    v_des_flow : if set (m/s), the desired speed respects the traffic: ``min(v_des, v_flow +
        v_des_flow)`` with ``v_flow`` the median speed at t0 (observed, not the future) of the
        planned vehicles ahead of the ego within ``range_m`` in the lanes it may use (lateral
        offset within the lane bounds ± half a lane width: its lane and the neighbours);
        ``v_des`` alone when nobody is ahead (:func:`~mmdopt.bench.ngsim.runner.traffic_v_des`)
    flow_leader : with ``v_des_flow``, the traffic speed is that of the ego lane's leader (the
        nearest vehicle ahead within half a lane width of the ego's offset) when there is one
    min_change_speed : below this speed (m/s) at t0 the ego keeps its lane (bounds
        ±``lane_keep_margin`` around the lane centre, widened to its offset): the planner's
        Frenet model has no turning-radius limit, so a lateral move while crawling is a sideways
        slide, and lane changes in stop-and-go traffic are where cut-in contacts happen
    bound_step : lane bounds are rounded to this step (m) so few projection problems compile
    obstacle_bucket : obstacle counts are padded with phantoms
        (:func:`mmdopt.padding.pad_obstacles`) to a multiple of this (default:
        ``max_obstacles``, i.e. every plan sees the same O and Algorithm 1 compiles once per
        lane-bound pair; plan times in ``results.csv`` are then for O = max_obstacles — the
        timing against the real count is
        :func:`~mmdopt.bench.ngsim.runner.timing_vs_obstacles`); :attr:`bucket` is the one in
        effect
    """

    history: int = 10
    first_t0: float = 1.0
    every: float = 2.0
    egos_per_time: int = 2
    min_task_speed: float = 1.0
    range_m: float = 50.0
    max_obstacles: int = 15
    max_ego_length: float = 7.0
    n_samples: int = 100
    n_validation: int = 1000
    lane_keep_margin: float = 0.5
    v_des: float | None = 25.0
    v_des_flow: float | None = 2.0
    flow_leader: bool = False
    min_change_speed: float = 5.0
    bound_step: float = 0.5
    obstacle_bucket: int | None = None
    brake_threshold: float = BRAKE_THRESHOLD
    seed: int = 0
    forecast: bool = True
    routes: bool = True
    speed_limits: bool = True
    curve_accel: float | None = 3.0
    curve_steer_rate: float | None = 0.4
    reactive_futures: int = 1
    reactive_full_horizon: bool = False
    warm_up: bool = True

    def __post_init__(self) -> None:
        for name in ("v_des", "v_des_flow"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, int | float) and np.isfinite(v) and v >= 0):
                raise ValueError(
                    f"NgsimParams.{name} must be None or a finite number >= 0, got {v!r}"
                )
        if not (np.isfinite(self.min_task_speed) and self.min_task_speed >= 0):
            raise ValueError(
                f"NgsimParams.min_task_speed must be finite and >= 0, got {self.min_task_speed}"
            )
        if not (np.isfinite(self.min_change_speed) and self.min_change_speed >= 0):
            raise ValueError(
                f"NgsimParams.min_change_speed must be finite and >= 0, got {self.min_change_speed}"
            )
        for name in (
            "forecast",
            "routes",
            "speed_limits",
            "reactive_full_horizon",
            "warm_up",
        ):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"NgsimParams.{name} must be a bool, got {getattr(self, name)!r}")
        for name in ("curve_accel", "curve_steer_rate"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, int | float) and np.isfinite(v) and v > 0):
                raise ValueError(
                    f"NgsimParams.{name} must be None or a finite number > 0, got {v!r}"
                )
        if self.v_des_flow is not None and self.v_des is None:
            raise ValueError("NgsimParams.v_des_flow needs v_des (the cap without traffic)")
        for name in (
            "history",
            "egos_per_time",
            "max_obstacles",
            "n_samples",
            "n_validation",
            "reactive_futures",
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
                raise ValueError(f"NgsimParams.{name} must be an int >= 1, got {v!r}")
        if self.obstacle_bucket is not None and not (
            isinstance(self.obstacle_bucket, int | np.integer) and self.obstacle_bucket >= 1
        ):
            raise ValueError(
                f"NgsimParams.obstacle_bucket must be None or an int >= 1, got "
                f"{self.obstacle_bucket!r}"
            )
        for name in ("every", "range_m", "max_ego_length", "bound_step"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"NgsimParams.{name} must be finite and > 0, got {v!r}")
        for name in ("first_t0", "lane_keep_margin"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"NgsimParams.{name} must be finite and >= 0, got {v!r}")

    @property
    def bucket(self) -> int:
        """The obstacle bucket in effect: ``obstacle_bucket``, else ``max_obstacles``."""
        return self.max_obstacles if self.obstacle_bucket is None else int(self.obstacle_bucket)

    @classmethod
    def from_dict(cls, d: dict) -> NgsimParams:
        """From JSON-like data: unknown keys and values of the wrong type (a string for a
        number, a float for a count, NaN) raise ``ValueError`` naming the key."""
        if not isinstance(d, dict):
            raise ValueError(f"NgsimParams needs a dict of fields, got {type(d).__name__}")
        fields = {f.name: f for f in dataclasses.fields(cls)}
        bad = set(d) - set(fields)
        if bad:
            raise ValueError(f"unknown NgsimParams keys {sorted(bad)}; known: {sorted(fields)}")
        for k, v in d.items():
            kind = str(fields[k].type)
            if v is None and "None" in kind:
                continue
            if kind.startswith("bool"):
                ok = isinstance(v, bool)
            elif kind.startswith("int"):
                ok = isinstance(v, int) and not isinstance(v, bool)
            else:
                ok = isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v)
            if not ok:
                raise ValueError(f"NgsimParams.{k} must be of type {kind}, got {v!r}")
        return cls(**d)


def ngsim_config(**overrides) -> mmdopt.MMDOptConfig:
    """The planner configuration of this benchmark: 5 s on 51 points (the recordings' step).

    Collision ellipse from the footprints: the obstacle's three circles at 0, ±2.5 m already
    cover its length, so the ego point must keep ``a = 3.0`` m (its half length + 0.5 m)
    along and ``b = 2.2`` m (two half widths + 0.2 m) across — the synthetic benchmark's
    4.5 × 3.5 m would make every car in the next lane (3.3–3.7 m away) and every close follower a
    collision.  Planning margins: ``margin_long = 1.5`` m, ``margin_rate = 0.5`` m/s,
    ``margin_lat = 0.2`` m (with the follower rule below: 1.5 + 0.5·t m; the synthetic
    defaults 2.5 + 1.9·t, and an earlier 2.5 + 1.0·t, made every plan in stop-and-go
    traffic enter some margin, docs/experiments/ngsim.md).  The metric
    (``collision_free``) uses the same ``a``, ``b``.

    Sizes for 10–15 obstacles in real time on 2 cores: 300 behavioural samples, n_cem 60,
    n_e 20, 10 iterations, reduced sets of m = 10 (selection CEM: population 50, 10 elites,
    20 iterations) — with the paper's sizes (1000/150/50, 20 iterations, m = 20, selection
    100/20/75) one plan against 10 obstacles took 7.5 s vs 1.1 s here on a loaded 2-core CPU
    (docs/experiments/ngsim.md).  Pass the paper's sizes through ``overrides`` (or ``--config``).

    Responsibility (no at-fault collision; :class:`mmdopt.MMDOptConfig`, responsibility-aware
    longitudinal model): ``rear_exempt_width = 2.0`` m — obstacle points behind the ego and
    within 2 m of its offset (a follower in its lane) cost nothing, also once a predicted
    follower runs through the ego, so the plan neither dodges a closing follower sideways into
    the next lane nor races ahead of it.  The time-headway
    floor (``headway_time``, ``headway_gap``) is available but off: on the training scenes it
    cost progress without removing an at-fault contact (docs/experiments/ngsim.md, "Tuning").
    Chosen on the training recordings only (``benchmarks/ngsim_safety_tuning.py``).

    Kinematic slip limit ``slip_ratio = 0.5`` (:class:`mmdopt.MMDOptConfig`): ``|ḋ| ≤ 0.5·ṡ``,
    so a crawling plan cannot stop and then slide sideways (a footprint turned by 90° in the
    metric); on the training recordings it removed one of the three at-fault contacts
    (docs/experiments/ngsim.md).

    Yaw-aware footprint ``yaw_extent = 2.5`` m (half a car's length, as ``a`` assumes): the
    lateral semi-axis grows by ``2.5·|sin Δθ|`` where the plan turns from the path, so a
    crawling plan does not swing a corner into the next lane (docs/experiments/ngsim.md)."""
    return mmdopt.MMDOptConfig.ngsim(**overrides)


def load_ngsim_config(source: Any = None):
    """``(MMDOptConfig, NgsimParams)`` of ``bench ngsim --config``: ``source`` is ``None``
    (the defaults), a JSON file path or an already parsed dict.  Planner fields, nested or flat
    (:meth:`mmdopt.MMDOptConfig.from_dict`), apply over :meth:`mmdopt.MMDOptConfig.ngsim`; a
    ``"bench"`` object sets :class:`NgsimParams` fields.  Raises
    ``ValueError`` naming the file or the key."""
    if source is None:
        return ngsim_config(), NgsimParams()
    from ..inputs import read_json

    raw = read_json(source) if isinstance(source, str | Path) else source
    if not isinstance(raw, dict):
        raise ValueError(
            "the config must be a JSON object of planner fields (and an optional 'bench' object)"
        )
    d = dict(raw)
    bench = d.pop("bench", {})
    if not isinstance(bench, dict):
        raise ValueError(
            f"'bench' must be a JSON object of NgsimParams fields, got {type(bench).__name__}"
        )
    try:
        params = NgsimParams.from_dict(bench)
    except (TypeError, ValueError) as e:
        raise ValueError(f"'bench' section: {e}") from None
    return mmdopt.MMDOptConfig.from_dict(d, base=ngsim_config()), params
