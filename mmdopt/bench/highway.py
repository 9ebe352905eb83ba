"""Closed-loop benchmark: receding-horizon MMD-Opt driving in highway-env (issue 13).

Everything that knows highway-env lives in this module (the optional extra ``[highway]``):

* :class:`HighwaySource` — the scene source of :func:`mmdopt.receding.run_receding`.  Headless
  (``render_mode=None``; ``"rgb_array"`` for videos).  The Frenet frame is a straight
  :class:`frenet.ReferencePath` along highway-env's lanes (+x at ``y = 0``, the centre of lane 0;
  highway-env's y axis points to the right of travel on screen, which is only a mirror image for
  the planner); the ego's lateral bounds ``y_lb, y_ub`` are the centres of the outermost lanes of
  its road, so the planner may change lanes.
* **The ego follows the plan exactly**: it is a :class:`PlanFollower` vehicle whose pose and speed
  are set along the planned trajectory (linear interpolation of the plan's grid) at every
  simulator step; no tracking controller.  The plan is kinematically feasible within the
  :class:`mmdopt.Road` limits, so this isolates the planner from a controller's tracking error.
  The other vehicles are highway-env's own IDM/MOBIL drivers, they see the ego as an ordinary
  vehicle, and highway-env's own collision checker (rotated rectangles, ``Road.step``) decides
  crashes.
* Frequencies are explicit: ``simulation_frequency`` (default 10 Hz) and ``policy_frequency`` =
  1/δ (default 2 Hz: replan every δ = 0.5 s, five simulator steps per plan).
* Predictors (each returns ``(O, n, K, 2)`` Cartesian samples on the planner's grid and is timed
  per call): :class:`SimulatorPredictor` clones the simulator (the nearby vehicles, with a fresh
  road sharing the lane network) and rolls out highway-env's own IDM/MOBIL models with
  randomised driver parameters and random forced lane changes — multi-modal by construction;
  :class:`ConstantVelocityPredictor` extrapolates each car's velocity with Gaussian velocity
  noise.
* Methods: ``mmd`` (MMD-Opt), ``degroot`` (the scenario baseline), ``cv`` (Algorithm 1 with the
  scenario cost against the single noise-free constant-velocity prediction of each car: a planner
  that ignores uncertainty) and ``idm`` (highway-env's own IDM/MOBIL driver as the ego: the
  reference for speed).
* :func:`run_highway` — the resumable benchmark behind ``mmdopt bench highway`` (one JSON per
  finished episode, ``episodes.csv`` rebuilt from them), :func:`write_video` for one episode.
"""

from __future__ import annotations

import copy
import csv
import json
import math
import os
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import frenet
import mmdopt
from mmdopt.receding import (
    Observation,
    RecedingConfig,
    StepOutcome,
    pad_obstacles,
    run_receding,
)

__all__ = [
    "HIGHWAY_PLANNER",
    "METHODS",
    "PREDICTORS",
    "CSV_COLUMNS",
    "HighwaySettings",
    "HighwaySource",
    "PlanFollower",
    "SimulatorPredictor",
    "ConstantVelocityPredictor",
    "vehicle_to_frenet",
    "frenet_to_pose",
    "classify_crash",
    "highway_config",
    "run_episode",
    "run_highway",
    "write_video",
    "add_highway_parser",
    "cmd_highway",
    "highway_available",
    "main",
]

METHODS = ("mmd", "degroot", "cv", "idm")
PREDICTORS = ("sim", "cv")
CSV_COLUMNS = (
    "episode",
    "seed",
    "env",
    "method",
    "predictor",
    "crashed",
    "mean_speed",
    "distance_m",
    "duration_s",
    "mean_plan_s",
    "max_plan_s",
    "median_plan_s",
    "over_budget",
    "steps",
    "mean_predict_s",
    "max_predict_s",
    "first_plan_s",
    "fallbacks",
    "crash_kind",
)

#: planner settings for highway driving (overridable with ``--config``): a 5 s horizon on a 0.1 s
#: grid (51 points), sizes cut to fit the 0.5 s replan budget on a 2-core CPU, the speed limit as
#: the desired speed, and the lateral collision semi-axis of highway-env's 2 m wide cars (2 m
#: between centres + 0.6 m) instead of the paper's 3.5 m, which would not fit two cars in
#: neighbouring 4 m lanes.
HIGHWAY_PLANNER: dict[str, Any] = {
    "horizon": 5.0,
    "num_steps": 51,
    "n_samples": 400,
    "n_cem": 100,
    "n_elite": 30,
    "iterations": 12,
    "reduced_set_size": 10,
    "v_des": 30.0,
    "b": 2.6,
    "margin_lat": 0.4,
    "margin_long": 2.5,
    "margin_rate": 1.0,
}


def highway_available() -> bool:
    """Whether highway-env and gymnasium import."""
    try:
        import gymnasium  # noqa: F401
        import highway_env  # noqa: F401
    except ImportError:
        return False
    return True


def _require_highway():
    try:
        import gymnasium as gym
        import highway_env  # noqa: F401  (registers the environments)
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError(
            f"the highway benchmark needs highway-env and gymnasium ({e}); "
            'install them with: pip install -e ".[highway]"'
        ) from None
    return gym


def highway_config(overrides: dict | None = None) -> mmdopt.MMDOptConfig:
    """:data:`HIGHWAY_PLANNER` on top of ``MMDOptConfig()``, then ``overrides`` (field names)."""
    kw = dict(HIGHWAY_PLANNER)
    kw.update(overrides or {})
    return mmdopt.MMDOptConfig().replace(**kw)


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
    predictor : "sim" | "cv"
    v_max, ax_max, ay_max, vy_max : the planner's kinematic limits (:class:`mmdopt.Road`)
    env_config : extra highway-env configuration keys
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
    predictor: str = "sim"
    v_max: float = 30.0
    ax_max: float = 5.0
    ay_max: float = 3.0
    vy_max: float = 3.0
    env_config: dict = field(default_factory=dict)

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


# ------------------------------------------------------------------------------ state conversion
def vehicle_to_frenet(path: frenet.ReferencePath, vehicle, accel: float = 0.0) -> frenet.EgoState:
    """The Frenet :class:`frenet.EgoState` of a highway-env vehicle (position, heading, speed)."""
    x, y = (float(v) for v in vehicle.position)
    return path.ego_state(x, y, float(vehicle.speed), float(vehicle.heading), accel=accel)


def frenet_to_pose(path: frenet.ReferencePath, ego: frenet.EgoState):
    """``(x, y, heading, speed)`` of a Frenet state (the inverse of :func:`vehicle_to_frenet`)."""
    x, y, h, v = path.trajectory_to_cartesian(
        np.array([ego.s]), np.array([ego.d]), np.array([ego.vs]), np.array([ego.vd])
    )
    return float(x[0]), float(y[0]), float(h[0]), float(v[0])


def classify_crash(ego_pose, other_pose) -> str:
    """Where the other car hit the ego (nuPlan's classes): ``"rear"`` (it came from behind),
    ``"front"`` (the ego ran into it) or ``"side"``.  Poses are ``(x, y, heading)``."""
    ex, ey, eh = ego_pose
    ox, oy = other_pose[0], other_pose[1]
    dx, dy = ox - ex, oy - ey
    lon = dx * math.cos(eh) + dy * math.sin(eh)
    lat = -dx * math.sin(eh) + dy * math.cos(eh)
    if abs(lat) < 1.5:
        return "front" if lon > 0 else "rear"
    return "side"


# --------------------------------------------------------------------------------- the ego vehicle
def _follower_class():
    from highway_env.vehicle.kinematics import Vehicle

    class PlanFollower(Vehicle):
        """A highway-env vehicle that drives exactly along a planned trajectory.

        ``set_plan(t, x, y, heading, speed, frenet)`` (grid arrays) restarts the plan clock; each
        ``step(dt)`` advances it and sets the pose and speed by linear interpolation (constant
        speed along the last heading past the plan's end).  Its ``act`` ignores actions.  After a
        crash it brakes like any highway-env vehicle.
        """

        def __init__(self, road, position, heading=0.0, speed=0.0):
            super().__init__(road, position, heading, speed)
            self.plan_clock = 0.0
            self._plan = None

        def set_plan(self, t, x, y, heading, speed, frenet_arrays=None):
            self._plan = (
                np.asarray(t, float),
                np.asarray(x, float),
                np.asarray(y, float),
                np.unwrap(np.asarray(heading, float)),
                np.asarray(speed, float),
                None
                if frenet_arrays is None
                else {k: np.asarray(v, float) for k, v in frenet_arrays.items()},
            )
            self.plan_clock = 0.0

        def frenet_now(self):
            """Frenet arrays of the plan interpolated at the plan clock (``None`` without plan)."""
            if self._plan is None or self._plan[5] is None:
                return None
            t = self._plan[0]
            return {k: float(np.interp(self.plan_clock, t, v)) for k, v in self._plan[5].items()}

        def act(self, action=None):
            pass

        def step(self, dt):
            if self.crashed or self._plan is None:
                self.action = {
                    "steering": 0.0,
                    "acceleration": -self.speed if self.crashed else 0.0,
                }
                Vehicle.step(self, dt)
                return
            self.plan_clock += dt
            t, x, y, h, v, _ = self._plan
            tc = self.plan_clock
            if tc <= t[-1]:
                px, py = np.interp(tc, t, x), np.interp(tc, t, y)
                heading, speed = np.interp(tc, t, h), np.interp(tc, t, v)
            else:
                heading, speed = h[-1], v[-1]
                px = x[-1] + speed * (tc - t[-1]) * math.cos(heading)
                py = y[-1] + speed * (tc - t[-1]) * math.sin(heading)
            self.position = np.array([px, py], dtype=float)
            self.heading = float((heading + math.pi) % (2 * math.pi) - math.pi)
            self.speed = float(speed)
            if self.impact is not None:
                self.position += self.impact
                self.crashed = True
                self.impact = None
            self.on_state_update()

    return PlanFollower


def PlanFollower(road, position, heading=0.0, speed=0.0):
    """A plan-following highway-env vehicle (the class is built on first use: highway-env is an
    optional dependency)."""
    global _PLAN_FOLLOWER
    if _PLAN_FOLLOWER is None:
        _PLAN_FOLLOWER = _follower_class()
    return _PLAN_FOLLOWER(road, position, heading, speed)


_PLAN_FOLLOWER = None


# ----------------------------------------------------------------------------------- predictors
def _clone_road(road, vehicles, seed: int):
    """A new highway-env ``Road`` sharing the (immutable) lane network, with deep copies of
    ``vehicles`` whose ``road`` points at the clone; its own random state."""
    from highway_env.road.road import Road as HRoad

    clone = HRoad(network=road.network, np_random=np.random.RandomState(seed), record_history=False)
    memo = {id(road): clone, id(road.network): road.network}
    for lane in road.network.lanes_list():
        memo[id(lane)] = lane
    clone.vehicles = copy.deepcopy(list(vehicles), memo)
    clone.objects = copy.deepcopy(list(road.objects), memo)
    return clone


@dataclass
class SimulatorPredictor:
    """Samples of each car's future from the simulator's own driver models.

    For each of ``n`` rollouts the nearby traffic (cars within ``radius`` m of the ego) is cloned
    and every IDM/MOBIL car gets randomised driver parameters: desired speed
    ± ``speed_spread`` (Gaussian), time gap U[1, 2] s, comfortable acceleration U[2, 4] m/s²,
    comfortable deceleration U[4, 6] m/s², IDM exponent U[3.5, 4.5], MOBIL politeness U[0, 0.5],
    gain threshold U[0, 0.4] m/s², lane-change timer phase; with probability
    ``lane_change_prob`` a car is also sent to a random neighbouring lane at a random time in the
    first half of the horizon (the modes).  The ego keeps following its current plan.

    ``mode="auto"`` (default) picks ``"vectorised"`` on roads made only of straight lanes along
    +x (highway-v0) and ``"clone"`` otherwise (merge-v0's ramp).  ``mode="vectorised"`` steps
    all rollouts at once with a NumPy replica of highway-env's ``IDMVehicle`` (IDM acceleration
    with its centre-to-centre gap, MOBIL with its own conventions: neighbours found with
    ``on_lane``'s 1 m margin, the deciding car's parameters, the minimum over the current and the
    target lane during a change, the 1 s decision timer) and a first-order lateral response fitted
    to highway-env's steering controller (time constant 0.55 s, |ḋ| ≤ 5 m/s).
    ``mode="clone"`` deep-copies the vehicles onto a fresh highway-env ``Road`` and steps its own
    ``act``/``step`` rollout by rollout (exact, any road geometry, ~100× slower).  Positions are
    interpolated onto the planner's grid; ``last_time_s`` is the wall time of the last call.
    """

    radius: float = 150.0
    rollout_frequency: float = 10.0
    lane_change_prob: float = 0.25
    speed_spread: float = 2.0
    randomise: bool = True
    mode: str = "auto"
    name: str = "sim"
    last_time_s: float = 0.0

    def __post_init__(self) -> None:
        if self.mode not in ("auto", "vectorised", "clone"):
            raise ValueError(f"mode must be 'auto', 'vectorised' or 'clone', got {self.mode!r}")

    def __call__(self, road, ego_vehicle, targets, t_grid: np.ndarray, n: int, rng) -> np.ndarray:
        t0 = time.perf_counter()
        t_grid = np.asarray(t_grid, dtype=np.float64)
        O, K = len(targets), t_grid.shape[0]
        if O == 0:
            self.last_time_s = time.perf_counter() - t0
            return np.zeros((0, n, K, 2))
        near = [
            v
            for v in road.vehicles
            if np.linalg.norm(v.position - ego_vehicle.position) < self.radius
        ]
        for v in targets:
            if not any(v is u for u in near):
                near.append(v)
        idx = [next(i for i, u in enumerate(near) if u is v) for v in targets]
        dt = 1.0 / self.rollout_frequency
        steps = int(math.ceil(t_grid[-1] / dt - 1e-9))
        t_roll = np.arange(steps + 1) * dt
        mode = self.mode
        if mode == "auto":
            mode = "vectorised" if _straight_parallel(road.network) else "clone"
        if mode == "vectorised":
            traj = self._vectorised(road, near, idx, ego_vehicle, steps, dt, n, rng)
        else:
            traj = self._clone(road, near, idx, steps, dt, n, rng)
        # traj (n, O, steps+1, 2) -> (O, n, K, 2) on the planner's grid
        out = np.empty((O, n, K, 2))
        for o in range(O):
            for j in range(n):
                out[o, j, :, 0] = np.interp(t_grid, t_roll, traj[j, o, :, 0])
                out[o, j, :, 1] = np.interp(t_grid, t_roll, traj[j, o, :, 1])
        self.last_time_s = time.perf_counter() - t0
        return out

    # -- the randomised parameters, shared by both modes: (n, N) arrays
    def _params(self, near, idx, horizon, n, rng):
        from highway_env.vehicle.behavior import IDMVehicle

        N = len(near)
        idm = np.array([isinstance(v, IDMVehicle) and not v.crashed for v in near])
        base = {
            "target_speed": np.array([float(getattr(v, "target_speed", v.speed)) for v in near]),
            "TIME_WANTED": np.array([getattr(v, "TIME_WANTED", 1.5) for v in near], float),
            "COMFORT_ACC_MAX": np.array([getattr(v, "COMFORT_ACC_MAX", 3.0) for v in near], float),
            "COMFORT_ACC_MIN": np.array([getattr(v, "COMFORT_ACC_MIN", -5.0) for v in near], float),
            "DELTA": np.array([getattr(v, "DELTA", 4.0) for v in near], float),
            "POLITENESS": np.array([getattr(v, "POLITENESS", 0.0) for v in near], float),
            "LANE_CHANGE_MIN_ACC_GAIN": np.array(
                [getattr(v, "LANE_CHANGE_MIN_ACC_GAIN", 0.2) for v in near], float
            ),
            "timer": np.array([float(getattr(v, "timer", 0.0)) for v in near]),
        }
        p = {k: np.broadcast_to(v, (n, N)).copy() for k, v in base.items()}
        lc_time = np.full((n, N), np.inf)
        lc_side = np.zeros((n, N), dtype=np.int64)
        if self.randomise:
            r = rng.random
            p["target_speed"] = np.maximum(
                0.0, p["target_speed"] + rng.normal(0.0, self.speed_spread, (n, N))
            )
            p["TIME_WANTED"] = 1.0 + r((n, N))
            p["COMFORT_ACC_MAX"] = 2.0 + 2.0 * r((n, N))
            p["COMFORT_ACC_MIN"] = -6.0 + 2.0 * r((n, N))
            p["DELTA"] = 3.5 + r((n, N))
            p["POLITENESS"] = 0.5 * r((n, N))
            p["LANE_CHANGE_MIN_ACC_GAIN"] = 0.4 * r((n, N))
            p["timer"] = r((n, N))
            is_target = np.zeros(N, bool)
            is_target[idx] = True
            force = (r((n, N)) < self.lane_change_prob) & is_target[None, :] & idm[None, :]
            when = 0.5 * horizon * r((n, N))
            lc_time = np.where(force, when, np.inf)
            lc_side = np.where(force, rng.integers(0, 2, (n, N)) * 2 - 1, 0)
        for k in p:
            p[k] = np.where(idm[None, :], p[k], base[k][None, :])
        return idm, p, lc_time, lc_side

    def _clone(self, road, near, idx, steps, dt, n, rng):
        from highway_env.vehicle.behavior import IDMVehicle

        def side_lane(v, side):
            # the neighbouring lane on `side` (-1 / +1 lane id), else the other one, else None
            if not v.lane_index:
                return None
            ids = {s[2]: s for s in road.network.side_lanes(v.lane_index)}
            k = v.lane_index[2]
            return ids.get(k + side, ids.get(k - side))

        idm, p, lc_time, lc_side = self._params(near, idx, steps * dt, n, rng)
        O = len(idx)
        traj = np.zeros((n, O, steps + 1, 2))
        for j in range(n):
            clone = _clone_road(road, near, int(rng.integers(2**31 - 1)))
            cars = clone.vehicles
            forced = {}
            for i, car in enumerate(cars):
                if not (isinstance(car, IDMVehicle) and idm[i]):
                    continue
                for k in p:
                    setattr(car, k, float(p[k][j, i]))
                if np.isfinite(lc_time[j, i]):
                    lane = side_lane(car, int(lc_side[j, i]))
                    if lane is not None:
                        forced[i] = (lc_time[j, i], lane)
            traj[j, :, 0] = [cars[i].position for i in idx]
            for k in range(steps):
                tk = k * dt
                for i, (t_lc, lane) in list(forced.items()):
                    if tk >= t_lc:
                        cars[i].target_lane_index = lane
                        del forced[i]
                clone.act()
                clone.step(dt)
                traj[j, :, k + 1] = [cars[i].position for i in idx]
        return traj

    def _vectorised(self, road, near, idx, ego_vehicle, steps, dt, n, rng):
        from highway_env.vehicle.behavior import IDMVehicle

        lanes = road.network.all_side_lanes(ego_vehicle.lane_index)
        yc = np.array([float(road.network.get_lane(li).position(0.0, 0.0)[1]) for li in lanes])
        order = np.argsort(yc)
        yc = yc[order]
        L = len(yc)
        half_w = 0.5 * float(road.network.get_lane(lanes[0]).width)
        speed_limit = road.network.get_lane(lanes[0]).speed_limit

        def lane_no(y):
            return np.argmin(np.abs(np.asarray(y)[..., None] - yc), axis=-1)

        idm, p, lc_time, lc_side = self._params(near, idx, steps * dt, n, rng)
        N = len(near)
        pos = np.array([v.position for v in near], float)
        lane0 = lane_no(pos[:, 1])[None, :]
        lc_lane = lane0 + lc_side
        lc_lane = np.where((lc_lane < 0) | (lc_lane >= L), lane0 - lc_side, lc_lane)
        lc_lane = np.where((lc_side == 0) | (lc_lane < 0) | (lc_lane >= L), -1, lc_lane)
        x = np.broadcast_to(pos[:, 0], (n, N)).copy()
        y = np.broadcast_to(pos[:, 1], (n, N)).copy()
        spd = np.array([float(v.speed) for v in near])
        hd = np.array([float(v.heading) for v in near])
        v = np.broadcast_to(spd, (n, N)).copy()
        vy0 = spd * np.sin(hd)
        tgt = np.empty((n, N), np.int64)
        for i, car in enumerate(near):
            ti = getattr(car, "target_lane_index", None)
            yt = (
                float(road.network.get_lane(ti).position(car.position[0], 0.0)[1])
                if ti is not None and isinstance(car, IDMVehicle)
                else car.position[1]
            )
            tgt[:, i] = int(lane_no(yt))
        v0 = p["target_speed"]
        if speed_limit is not None:
            v0 = np.clip(v0, 0.0, speed_limit)
        T, amax, bmin = p["TIME_WANTED"], p["COMFORT_ACC_MAX"], p["COMFORT_ACC_MIN"]
        delta, pol, gain, timer = (
            p["DELTA"],
            p["POLITENESS"],
            p["LANE_CHANGE_MIN_ACC_GAIN"],
            p["timer"],
        )
        d0 = IDMVehicle.DISTANCE_WANTED
        acc_max, delay = IDMVehicle.ACC_MAX, IDMVehicle.LANE_CHANGE_DELAY
        brake_imposed = IDMVehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED
        ego_i = next((i for i, c in enumerate(near) if c is ego_vehicle), None)
        ego_fn = _ego_motion(ego_vehicle) if ego_i is not None else None
        passive = ~idm  # constant velocity (the ego is overwritten along its plan)
        vx_passive = spd * np.cos(hd)
        O = len(idx)
        traj = np.zeros((n, O, steps + 1, 2))
        traj[:, :, 0, 0], traj[:, :, 0, 1] = x[:, idx], y[:, idx]
        rows = np.arange(n)[:, None]
        eye = np.eye(N, dtype=bool)[None]
        crashed = np.broadcast_to(np.array([bool(c.crashed) for c in near]), (n, N)).copy()
        length, width = IDMVehicle.LENGTH, IDMVehicle.WIDTH

        def idm_acc(vi, v0i, Ti, ai, bi, di, gap, vf, has):
            # IDMVehicle.acceleration: free road term minus the interaction term (centre gap)
            free = ai * (1.0 - np.power(np.maximum(vi, 0.0) / np.maximum(np.abs(v0i), 1e-6), di))
            ab = -ai * bi
            dstar = d0 + vi * Ti + vi * (vi - vf) / (2.0 * np.sqrt(ab))
            inter = ai * (dstar / np.where(np.abs(gap) > 1e-6, gap, 1e-6)) ** 2
            return free - np.where(has, inter, 0.0)

        def neighbours(lane_idx):
            # front / rear of every car i in lane lane_idx[:, i] (on_lane with a 1 m margin)
            on = np.abs(y[:, None, :] - yc[lane_idx][:, :, None]) <= half_w + 1.0  # (n, i, j)
            on &= ~eye
            dx = x[:, None, :] - x[:, :, None]  # x_j - x_i
            fr = np.where(on & (dx >= 0), dx, np.inf)
            re = np.where(on & (dx < 0), -dx, np.inf)
            jf, jr = np.argmin(fr, axis=2), np.argmin(re, axis=2)
            hf = np.isfinite(np.take_along_axis(fr, jf[..., None], 2)[..., 0])
            hr = np.isfinite(np.take_along_axis(re, jr[..., None], 2)[..., 0])
            return jf, hf, jr, hr

        def acc_of(who, front, has_front, exists, params_of):
            # acceleration of car `who` (n, N indices) behind car `front`, with the parameters of
            # the deciding car (params_of = identity index: highway-env's MOBIL convention)
            vi = v[rows, who]
            gap = x[rows, front] - x[rows, who]
            vf = v[rows, front]
            a = idm_acc(vi, v0[rows, who], T, amax, bmin, delta, gap, vf, has_front)
            return np.where(exists, a, 0.0)

        t = 0.0
        for k in range(steps):
            lane = lane_no(y)
            # forced lane changes (the random modes)
            fire = (t >= lc_time) & (lc_lane >= 0)
            tgt = np.where(fire, lc_lane, tgt)
            lc_time = np.where(fire, np.inf, lc_time)
            # longitudinal: IDM in the current lane, min with the target lane while changing
            jf, hf, jr, hr = neighbours(lane)
            a = idm_acc(v, v0, T, amax, bmin, delta, x[rows, jf] - x, v[rows, jf], hf)
            changing = lane != tgt
            jft, hft, _, _ = neighbours(tgt)
            a_t = idm_acc(v, v0, T, amax, bmin, delta, x[rows, jft] - x, v[rows, jft], hft)
            a = np.where(changing, np.minimum(a, a_t), a)
            a = np.clip(a, -acc_max, acc_max)
            # lateral decision: MOBIL every LANE_CHANGE_DELAY seconds when not changing
            decide = (~changing) & (timer > delay) & idm[None, :]
            timer = np.where(decide, 0.0, timer)
            if decide.any():
                self_a = idm_acc(v, v0, T, amax, bmin, delta, x[rows, jf] - x, v[rows, jf], hf)
                # old follower: behind me (jr) now, and with my front as its front
                old_fol_a = np.where(
                    hr,
                    idm_acc(
                        v[rows, jr], v0[rows, jr], T, amax, bmin, delta, x - x[rows, jr], v, True
                    ),
                    0.0,
                )
                old_fol_pred_a = np.where(
                    hr,
                    idm_acc(
                        v[rows, jr],
                        v0[rows, jr],
                        T,
                        amax,
                        bmin,
                        delta,
                        x[rows, jf] - x[rows, jr],
                        v[rows, jf],
                        hf,
                    ),
                    0.0,
                )
                for side in (-1, 1):
                    cand = lane + side
                    valid = decide & (cand >= 0) & (cand < L) & (np.abs(v) >= 1.0)
                    if not valid.any():
                        continue
                    cand_c = np.clip(cand, 0, L - 1)
                    nf, hnf, nr, hnr = neighbours(cand_c)
                    new_fol_a = np.where(
                        hnr,
                        idm_acc(
                            v[rows, nr],
                            v0[rows, nr],
                            T,
                            amax,
                            bmin,
                            delta,
                            x[rows, nf] - x[rows, nr],
                            v[rows, nf],
                            hnf,
                        ),
                        0.0,
                    )
                    new_fol_pred_a = np.where(
                        hnr,
                        idm_acc(
                            v[rows, nr],
                            v0[rows, nr],
                            T,
                            amax,
                            bmin,
                            delta,
                            x - x[rows, nr],
                            v,
                            True,
                        ),
                        0.0,
                    )
                    self_pred_a = idm_acc(
                        v, v0, T, amax, bmin, delta, x[rows, nf] - x, v[rows, nf], hnf
                    )
                    jerk = (
                        self_pred_a
                        - self_a
                        + pol * (new_fol_pred_a - new_fol_a + old_fol_pred_a - old_fol_a)
                    )
                    ok = valid & (new_fol_pred_a >= -brake_imposed) & (jerk >= gain)
                    tgt = np.where(ok, cand_c, tgt)
            # crashed cars brake to a stop (highway-env: acceleration −speed, no steering); a
            # crash is an overlap of the 5 m × 2 m boxes (axis-aligned: lanes run along +x)
            a = np.where(crashed, -v, a)
            # lateral motion: first-order response to the target lane centre
            vy = np.clip((yc[tgt] - y) / 0.55, -5.0, 5.0)
            vy = np.where(crashed, 0.0, vy)
            vy = np.where(passive[None, :], vy0[None, :], vy)
            vx = np.where(passive[None, :], vx_passive[None, :], v)
            x = x + vx * dt
            y = y + vy * dt
            v = np.where(passive[None, :], v, np.maximum(v + a * dt, 0.0))
            timer = timer + dt
            t += dt
            if ego_fn is not None:
                ex, ey, ev = ego_fn(t)
                x[:, ego_i], y[:, ego_i], v[:, ego_i] = ex, ey, ev
            hit = (np.abs(x[:, None, :] - x[:, :, None]) < length) & (
                np.abs(y[:, None, :] - y[:, :, None]) < width
            )
            crashed |= np.any(hit & ~eye, axis=2)
            traj[:, :, k + 1, 0], traj[:, :, k + 1, 1] = x[:, idx], y[:, idx]
        return traj


def _straight_parallel(network) -> bool:
    """Whether every lane of ``network`` is a straight lane along +x (the vectorised rollout's
    road model)."""
    from highway_env.road.lane import StraightLane

    for lane in network.lanes_list():
        if type(lane) is not StraightLane or abs(math.sin(lane.heading)) > 1e-9:
            return False
        if math.cos(lane.heading) < 0:
            return False
    return True


def _ego_motion(ego):
    """``t -> (x, y, speed)`` of the ego in a rollout: along its current plan (if it is a
    :class:`PlanFollower`), else at constant velocity."""
    plan = getattr(ego, "_plan", None)
    x0, y0 = (float(c) for c in ego.position)
    sp, h = float(ego.speed), float(ego.heading)
    if plan is None:
        return lambda t: (x0 + sp * math.cos(h) * t, y0 + sp * math.sin(h) * t, sp)
    tp, xp, yp, hp, vp, _ = plan
    clock = float(ego.plan_clock)

    def f(t):
        tc = clock + t
        if tc <= tp[-1]:
            return np.interp(tc, tp, xp), np.interp(tc, tp, yp), np.interp(tc, tp, vp)
        e = tc - tp[-1]
        return (
            xp[-1] + vp[-1] * math.cos(hp[-1]) * e,
            yp[-1] + vp[-1] * math.sin(hp[-1]) * e,
            vp[-1],
        )

    return f


@dataclass
class ConstantVelocityPredictor:
    """Each car keeps its current velocity; sample ``j > 0`` adds Gaussian velocity noise
    (``sigma_long`` m/s along the road, ``sigma_lat`` m/s across), sample 0 is the noise-free
    extrapolation.  Unimodal."""

    sigma_long: float = 1.0
    sigma_lat: float = 0.3
    name: str = "cv"
    last_time_s: float = 0.0

    def __call__(self, road, ego_vehicle, targets, t_grid: np.ndarray, n: int, rng) -> np.ndarray:
        t0 = time.perf_counter()
        O = len(targets)
        if O == 0:
            self.last_time_s = time.perf_counter() - t0
            return np.zeros((0, n, t_grid.shape[0], 2))
        pos = np.array([v.position for v in targets], float)  # (O, 2)
        vel = np.array([v.velocity for v in targets], float)
        noise = rng.normal(size=(O, n, 2)) * np.array([self.sigma_long, self.sigma_lat])
        noise[:, 0] = 0.0
        v = vel[:, None, :] + noise  # (O, n, 2) — highway-v0 lanes run along +x
        out = pos[:, None, None, :] + v[:, :, None, :] * t_grid[None, None, :, None]
        self.last_time_s = time.perf_counter() - t0
        return out


def make_predictor(name: str):
    if name == "sim":
        return SimulatorPredictor()
    if name == "cv":
        return ConstantVelocityPredictor()
    raise ValueError(f"predictor must be one of {PREDICTORS}, got {name!r}")


# ------------------------------------------------------------------------------ the scene source
class HighwaySource:
    """A highway-env episode as a :class:`mmdopt.receding.SceneSource`.

    ``method`` is the planning method ("mmd", "degroot", "cv") or "idm" (the ego is highway-env's
    own IDM/MOBIL driver with desired speed ``v_des``; drive it with :meth:`run_idm`).
    """

    def __init__(
        self,
        settings: HighwaySettings,
        seed: int,
        config: mmdopt.MMDOptConfig,
        *,
        method: str = "mmd",
        render: bool = False,
    ):
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        gym = _require_highway()
        self.settings, self.seed, self.config, self.method = settings, int(seed), config, method
        env_cfg = {
            "simulation_frequency": settings.simulation_frequency,
            "policy_frequency": settings.policy_frequency,
            "duration": settings.duration,
        }
        env_cfg.update(settings.env_config)
        self.env = gym.make(settings.env, render_mode="rgb_array" if render else None).unwrapped
        self.env.configure(env_cfg)
        self.env.reset(seed=self.seed)
        self.frames: list[np.ndarray] = []
        self.render = render
        road = self.env.road
        old = self.env.vehicle
        ego_lane = road.network.get_lane(old.lane_index)
        side = road.network.all_side_lanes(old.lane_index)
        s_lane = ego_lane.local_coordinates(old.position)[0]
        ys = [float(road.network.get_lane(i).position(s_lane, 0.0)[1]) for i in side]
        self.path = frenet.ReferencePath.straight(20_000.0, start=(-5000.0, 0.0))
        self.road = mmdopt.Road(
            path=self.path,
            y_lb=min(ys),
            y_ub=max(ys),
            v_min=0.0,
            v_max=settings.v_max,
            vy_max=settings.vy_max,
            ax_max=settings.ax_max,
            ay_max=settings.ay_max,
        )
        if method == "idm":
            from highway_env.vehicle.behavior import IDMVehicle

            ego = IDMVehicle(
                road, old.position.copy(), old.heading, old.speed, target_speed=config.v_des
            )
        else:
            ego = PlanFollower(road, old.position.copy(), old.heading, old.speed)
        ego.color = (50, 200, 0)  # highway-env's ego green in videos
        road.vehicles[road.vehicles.index(old)] = ego
        self.env.controlled_vehicles = [ego]
        self.ego = ego
        self.t_grid = frenet.TimeGrid(config.horizon, config.num_steps).t
        self.predictor = make_predictor(settings.predictor)
        self.cv_mean = ConstantVelocityPredictor(sigma_long=0.0, sigma_lat=0.0)
        self.step_index = 0
        self.x0 = float(ego.position[0])
        self.speeds: list[float] = [float(ego.speed)]
        self.predict_times: list[float] = []
        self.crash_kind = ""
        if render:
            self.frames.append(self.env.render())

    # -- observation
    def _targets(self):
        ex = self.ego.position[0]
        cands = [
            v
            for v in self.env.road.vehicles
            if v is not self.ego
            and -self.settings.behind <= v.position[0] - ex <= self.settings.ahead
        ]
        cands.sort(key=lambda v: float(np.linalg.norm(v.position - self.ego.position)))
        return cands[: self.settings.max_obstacles]

    def ego_state(self) -> frenet.EgoState:
        fr = self.ego.frenet_now() if hasattr(self.ego, "frenet_now") else None
        if fr is not None and not self.ego.crashed:
            return frenet.EgoState(**fr)
        return vehicle_to_frenet(self.path, self.ego)

    def observe(self) -> Observation:
        targets = self._targets()
        rng = np.random.default_rng([self.seed, self.step_index])
        if self.method == "cv":
            obstacles = self.cv_mean(self.env.road, self.ego, targets, self.t_grid, 1, rng)
            pred_s = self.cv_mean.last_time_s
        else:
            obstacles = self.predictor(
                self.env.road, self.ego, targets, self.t_grid, self.settings.n_samples, rng
            )
            pred_s = self.predictor.last_time_s
        self.predict_times.append(pred_s)
        return Observation(
            ego=self.ego_state(),
            road=self.road,
            obstacles=obstacles,
            time=float(self.env.time),
            info={"predict_s": pred_s, "n_targets": len(targets)},
        )

    # -- execution
    def _advance(self) -> StepOutcome:
        env = self.env
        for _ in range(self.settings.frames_per_step):
            env.road.act()
            env.road.step(1.0 / self.settings.simulation_frequency)
            env.steps += 1
            self.speeds.append(float(self.ego.speed))
            if self.render:
                self.frames.append(env.render())
            if self.ego.crashed:
                break
        env.time += self.settings.dt
        self.step_index += 1
        crashed = bool(self.ego.crashed)
        if crashed and not self.crash_kind:
            self.crash_kind = self._crash_kind()
        done = crashed or env.time >= self.settings.duration - 1e-9
        return StepOutcome(done=done, crashed=crashed, info={"time": float(env.time)})

    def step(self, trajectory: mmdopt.Plan, dt: float) -> StepOutcome:
        if abs(dt - self.settings.dt) > 1e-9:
            raise ValueError(f"dt = {dt} differs from the source's δ = {self.settings.dt}")
        fr = {
            "s": trajectory.s,
            "d": trajectory.d,
            "vs": trajectory.vs,
            "vd": trajectory.vd,
            "as_": trajectory.as_,
            "ad": trajectory.ad,
        }
        self.ego.set_plan(
            trajectory.t, trajectory.x, trajectory.y, trajectory.heading, trajectory.speed, fr
        )
        return self._advance()

    def run_idm(self) -> StepOutcome:
        """Drive the whole episode with the IDM ego (``method="idm"``)."""
        out = StepOutcome(done=False, crashed=False)
        while not out.done:
            out = self._advance()
        return out

    def _crash_kind(self) -> str:
        ego = self.ego
        others = [
            v
            for v in self.env.road.vehicles + self.env.road.objects
            if v is not ego and getattr(v, "crashed", False)
        ]
        if not others:
            return "unknown"
        o = min(others, key=lambda v: float(np.linalg.norm(v.position - ego.position)))
        return classify_crash((*ego.position, ego.heading), tuple(o.position))

    def distance(self) -> float:
        return float(self.ego.position[0] - self.x0)

    def close(self) -> None:
        self.env.close()


# ------------------------------------------------------------------------------------ one episode
def run_episode(
    episode: int,
    seed: int,
    method: str,
    settings: HighwaySettings,
    config: mmdopt.MMDOptConfig,
    *,
    render: bool = False,
) -> dict[str, Any]:
    """Drive one episode with ``method``; the episode record (a JSON-friendly dict with the CSV
    columns, per-step plan and predictor times, and the frames when ``render``)."""
    import jax

    src = HighwaySource(settings, seed, config, method=method, render=render)
    t_start = time.perf_counter()
    rec: dict[str, Any] = {
        "episode": int(episode),
        "seed": int(seed),
        "env": settings.env,
        "method": method,
        "predictor": "-"
        if method == "idm"
        else ("cv-mean" if method == "cv" else settings.predictor),
    }
    plan_times: list[float] = []
    first_plan = float("nan")
    fallbacks = 0
    steps_status: list[str] = []
    if method == "idm":
        out = src.run_idm()
        crashed = out.crashed
    else:
        planner_method = "scenario_all" if method == "cv" else method
        rc = RecedingConfig(
            dt=settings.dt,
            budget_s=settings.budget_s,
            method=planner_method,
            max_obstacles=settings.max_obstacles,
            max_steps=int(math.ceil(settings.duration / settings.dt)) + 1,
        )
        # compile once on the first scene (shapes are fixed by max_obstacles), untimed by the loop
        obs0 = src.observe()
        src.predict_times.clear()
        src.step_index = 0
        t0 = time.perf_counter()
        mmdopt.plan(
            obs0.ego,
            obs0.road,
            pad_obstacles(obs0.obstacles, settings.max_obstacles, obs0.ego, obs0.road, src.t_grid),
            method=planner_method,
            config=config,
            key=jax.random.PRNGKey(seed),
        )
        first_plan = time.perf_counter() - t0
        res = run_receding(src, rc, config=config, key=jax.random.PRNGKey(seed))
        crashed = res.crashed
        plan_times = [float(x) for x in res.plan_times]
        fallbacks = sum(r.fallback for r in res.steps)
        steps_status = [r.status for r in res.steps if r.status != "ok"]
        rec["plan_d"] = [r.d for r in res.steps]  # lateral offset at each replan (m)
        for name in ("reduced_set_s", "cem_s"):
            rec[name] = [r.timings.get(name, float("nan")) for r in res.steps]
    pt = np.array(plan_times) if plan_times else np.array([np.nan])
    pr = np.array(src.predict_times) if src.predict_times else np.array([np.nan])
    speeds = np.array(src.speeds)
    rec.update(
        crashed=bool(crashed),
        mean_speed=float(speeds.mean()),
        distance_m=src.distance(),
        duration_s=float(src.env.time),
        mean_plan_s=float(pt.mean()),
        max_plan_s=float(pt.max()),
        median_plan_s=float(np.median(pt)),
        over_budget=int(np.sum(pt > settings.budget_s)),
        steps=len(plan_times),
        mean_predict_s=float(pr.mean()),
        max_predict_s=float(pr.max()),
        first_plan_s=first_plan,
        fallbacks=int(fallbacks),
        crash_kind=src.crash_kind,
        plan_times=plan_times,
        predict_times=[float(x) for x in src.predict_times],
        speeds=[float(x) for x in speeds],
        statuses=steps_status[:20],
        wall_s=time.perf_counter() - t_start,
    )
    if render:
        rec["frames"] = src.frames
    src.close()
    return rec


# ------------------------------------------------------------------------------------ the sweep
def _episode_path(out: Path, episode: int, method: str) -> Path:
    return out / "episodes" / f"episode_{episode:04d}__{method}.json"


def _manifest(settings: HighwaySettings, config_overrides: dict, seed: int) -> dict:
    return {"settings": asdict(settings), "config": config_overrides, "seed": int(seed)}


def _task(args) -> dict:
    episode, seed, method, settings_d, overrides, out = args
    settings = HighwaySettings(**settings_d)
    config = highway_config(overrides)
    rec = run_episode(episode, seed, method, settings, config)
    path = _episode_path(Path(out), episode, method)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(rec))
    os.replace(tmp, path)
    return rec


def _worker_init() -> None:  # pragma: no cover - runs in worker processes
    os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false")


def write_csv(rows: Sequence[dict], path: Path) -> None:
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(CSV_COLUMNS), extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, "") for k in CSV_COLUMNS})


def summarize(rows: Sequence[dict]) -> list[dict]:
    """Per method: episodes, crashes, mean speed, mean distance, median/mean/max plan time."""
    out = []
    for m in dict.fromkeys(r["method"] for r in rows):
        rs = [r for r in rows if r["method"] == m]
        pts = np.concatenate([np.asarray(r.get("plan_times") or [np.nan]) for r in rs])
        pts = pts[np.isfinite(pts)]
        prs = np.concatenate([np.asarray(r.get("predict_times") or [np.nan]) for r in rs])
        prs = prs[np.isfinite(prs)]
        out.append(
            {
                "method": m,
                "episodes": len(rs),
                "crashes": int(sum(bool(r["crashed"]) for r in rs)),
                "mean_speed": float(np.mean([r["mean_speed"] for r in rs])),
                "distance_m": float(np.mean([r["distance_m"] for r in rs])),
                "median_plan_s": float(np.median(pts)) if pts.size else float("nan"),
                "mean_plan_s": float(np.mean(pts)) if pts.size else float("nan"),
                "max_plan_s": float(np.max(pts)) if pts.size else float("nan"),
                "median_predict_s": float(np.median(prs)) if prs.size else float("nan"),
            }
        )
    return out


def run_highway(
    out: str | Path,
    *,
    episodes: int,
    seed: int = 0,
    methods: Sequence[str] = ("mmd", "idm"),
    settings: HighwaySettings | None = None,
    config_overrides: dict | None = None,
    executor: str = "local",
    jobs: int = 1,
    progress: bool = True,
) -> list[dict]:
    """Resumable benchmark: episode ``i`` uses seed ``seed + i``; each finished (episode, method)
    is ``OUT/episodes/episode_XXXX__METHOD.json`` and never recomputed; ``OUT/episodes.csv`` is
    rebuilt from them.  Reusing ``out`` with other settings is refused (``ValueError``)."""
    settings = HighwaySettings() if settings is None else settings
    overrides = dict(config_overrides or {})
    highway_config(overrides)  # validate before starting
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be an int >= 1, got {episodes!r}")
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise ValueError(f"methods must be among {METHODS}, got {list(methods)}")
    if executor not in ("local", "ray"):
        raise ValueError(f"executor must be 'local' or 'ray', got {executor!r}")
    out = Path(out)
    (out / "episodes").mkdir(parents=True, exist_ok=True)
    man = _manifest(settings, overrides, seed)
    mpath = out / "manifest.json"
    if mpath.exists():
        old = json.loads(mpath.read_text())
        if old != json.loads(json.dumps(man)):
            raise ValueError(
                f"{out} holds results with other settings ({mpath}); use another --out folder"
            )
    else:
        mpath.write_text(json.dumps(man, indent=1))
    todo = [
        (i, seed + i, m, asdict(settings), overrides, str(out))
        for i in range(episodes)
        for m in methods
        if not _episode_path(out, i, m).exists()
    ]
    if todo:
        if executor == "ray":
            import ray

            if not ray.is_initialized():
                ray.init(num_cpus=jobs, include_dashboard=False, log_to_driver=False)
            remote = ray.remote(_task)
            pending = [remote.remote(a) for a in todo]
            for k, ref in enumerate(pending):
                ray.get(ref)
                if progress:
                    print(f"  [{k + 1}/{len(todo)}] done", flush=True)
        elif jobs > 1:
            import concurrent.futures as cf
            import multiprocessing as mp

            with cf.ProcessPoolExecutor(
                max_workers=jobs, mp_context=mp.get_context("spawn"), initializer=_worker_init
            ) as ex:
                futs = {ex.submit(_task, a): a for a in todo}
                for k, f in enumerate(cf.as_completed(futs)):
                    r = f.result()
                    if progress:
                        print(_progress_line(k, len(todo), r), flush=True)
        else:
            for k, a in enumerate(todo):
                r = _task(a)
                if progress:
                    print(_progress_line(k, len(todo), r), flush=True)
    rows = []
    for i in range(episodes):
        for m in methods:
            p = _episode_path(out, i, m)
            if p.exists():
                rows.append(json.loads(p.read_text()))
    write_csv(rows, out / "episodes.csv")
    (out / "summary.json").write_text(json.dumps(summarize(rows), indent=1))
    return rows


def _progress_line(k, n, r) -> str:
    return (
        f"  [{k + 1}/{n}] episode {r['episode']} seed {r['seed']} {r['method']}: "
        f"crashed={r['crashed']} mean_speed={r['mean_speed']:.2f} m/s "
        f"median_plan={r['median_plan_s']:.3f} s predict={r['mean_predict_s']:.3f} s"
    )


def write_video(
    path: str | Path,
    episode: int,
    seed: int,
    method: str,
    settings: HighwaySettings,
    config: mmdopt.MMDOptConfig,
) -> Path:
    """Render one episode (highway-env's ``rgb_array``) to ``path``: MP4 when imageio's ffmpeg
    plugin is installed and ``path`` ends in ``.mp4``, otherwise a GIF (suffix replaced)."""
    import imageio.v2 as imageio

    rec = run_episode(episode, seed, method, settings, config, render=True)
    frames = [np.asarray(f) for f in rec["frames"] if f is not None]
    if not frames:
        raise RuntimeError("highway-env rendered no frames")
    path = Path(path)
    fps = settings.simulation_frequency
    if path.suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401

            imageio.mimsave(path, frames, fps=fps)
            return path
        except ImportError:
            path = path.with_suffix(".gif")
    path = path.with_suffix(".gif")
    imageio.mimsave(path, frames, duration=1000.0 / fps, loop=0)
    return path


# ------------------------------------------------------------------------------------------ CLI
def _pos_int(s: str) -> int:
    import argparse

    try:
        v = int(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {s!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def _nonneg_int(s: str) -> int:
    import argparse

    try:
        v = int(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {s!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {v}")
    return v


def _pos_float(s: str) -> float:
    import argparse

    try:
        v = float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {s!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {s!r}")
    return v


def _method_list(s: str) -> list[str]:
    import argparse

    ms = [m.strip() for m in s.split(",") if m.strip()]
    bad = [m for m in ms if m not in METHODS]
    if not ms or bad:
        raise argparse.ArgumentTypeError(
            f"unknown method(s) {', '.join(bad) or '(none)'}; choose from {', '.join(METHODS)}"
        )
    return list(dict.fromkeys(ms))


def add_highway_parser(bench_subparsers):
    """Add ``highway`` to the ``mmdopt bench`` sub-commands; returns the parser."""
    h = bench_subparsers.add_parser(
        "highway",
        help="closed-loop receding-horizon driving in highway-env (issue 13)",
        description="Receding-horizon MMD-Opt and baselines driving in highway-env; "
        "resumable, one JSON per episode, DIR/episodes.csv.",
    )
    h.add_argument("--episodes", type=_pos_int, default=20, help="episodes (default 20)")
    h.add_argument("--seed", type=_nonneg_int, default=0, help="episode i uses seed S + i")
    h.add_argument("--duration", type=_pos_float, default=20.0, help="seconds per episode")
    h.add_argument("--out", required=True, help="output folder (resumable)")
    h.add_argument("--env", default="highway-v0", help="highway-env id (default highway-v0)")
    h.add_argument(
        "--methods",
        type=_method_list,
        default=["mmd", "degroot", "cv", "idm"],
        help="comma-separated: mmd,degroot,cv,idm (default all)",
    )
    h.add_argument("--predictor", choices=PREDICTORS, default="sim", help="sim | cv (default sim)")
    h.add_argument(
        "--config",
        default=None,
        metavar="FILE.json",
        help="JSON object of MMDOptConfig fields on top of the highway defaults",
    )
    h.add_argument("--dt", type=_pos_float, default=0.5, help="replan period δ (s, default 0.5)")
    h.add_argument("--samples", type=_pos_int, default=20, help="predictor samples per car")
    h.add_argument("--executor", choices=("local", "ray"), default="local")
    h.add_argument("--jobs", type=_pos_int, default=1, help="parallel episodes (default 1)")
    h.add_argument(
        "--video",
        type=_nonneg_int,
        default=None,
        metavar="EPISODE",
        help="also write DIR/video_EPISODE_METHOD.gif (or .mp4) of this episode",
    )
    h.add_argument("--no-progress", action="store_true")
    h.set_defaults(func=cmd_highway)
    return h


def _load_overrides(path) -> dict:
    if path is None:
        return {}
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"argument --config: file {str(path)!r} does not exist")
    try:
        raw = json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"argument --config: {path} is not valid JSON: {e}") from None
    if not isinstance(raw, dict):
        raise ValueError(
            "argument --config: the config must be a JSON object of MMDOptConfig fields"
        )
    try:
        highway_config(raw)
    except (TypeError, ValueError) as e:
        raise ValueError(f"argument --config: {e}") from None
    return raw


def cmd_highway(args) -> int:
    """Run ``mmdopt bench highway``; prints a per-method table; returns the exit status."""
    import sys

    if not highway_available():
        print(
            'mmdopt bench highway: highway-env is not installed; pip install -e ".[highway]"',
            file=sys.stderr,
        )
        return 2
    try:
        overrides = _load_overrides(args.config)
        settings = HighwaySettings(
            env=args.env,
            duration=float(args.duration),
            dt=float(args.dt),
            n_samples=int(args.samples),
            predictor=args.predictor,
        )
    except ValueError as e:
        print(f"mmdopt bench highway: {e}", file=sys.stderr)
        return 2
    try:
        rows = run_highway(
            args.out,
            episodes=args.episodes,
            seed=args.seed,
            methods=args.methods,
            settings=settings,
            config_overrides=overrides,
            executor=args.executor,
            jobs=args.jobs,
            progress=not args.no_progress,
        )
    except ValueError as e:
        print(f"mmdopt bench highway: {e}", file=sys.stderr)
        return 2
    summ = summarize(rows)
    cols = [
        "method",
        "episodes",
        "crashes",
        "mean_speed",
        "distance_m",
        "median_plan_s",
        "max_plan_s",
        "median_predict_s",
    ]
    print("  ".join(f"{c:>14}" for c in cols))
    for s in summ:
        print(
            "  ".join(
                f"{s[c]:>14.3f}" if isinstance(s[c], float) else f"{s[c]!s:>14}" for c in cols
            )
        )
    print(f"wrote {Path(args.out) / 'episodes.csv'}")
    if args.video is not None:
        for m in args.methods:
            p = write_video(
                Path(args.out) / f"video_{args.video:04d}_{m}.mp4",
                args.video,
                args.seed + args.video,
                m,
                settings,
                highway_config(overrides),
            )
            print(f"wrote {p}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m mmdopt.bench.highway [OPTIONS]``: the options of ``mmdopt bench highway``."""
    import argparse
    import sys

    p = argparse.ArgumentParser(prog="python -m mmdopt.bench")
    add_highway_parser(p.add_subparsers(dest="experiment", required=True))
    args = p.parse_args(["highway", *(sys.argv[1:] if argv is None else argv)])
    return cmd_highway(args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
