"""highway-env ↔ planner: state conversion, the plan-following ego vehicle, crash classes and the
scene source :class:`HighwaySource` of :func:`mmdopt.receding.run_receding`."""

from __future__ import annotations

import math

import numpy as np

import frenet
import mmdopt
from mmdopt.receding import Observation, StepOutcome

from .predictors import ConstantVelocityPredictor, make_predictor
from .settings import METHODS, HighwaySettings, _require_highway


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
                road, old.position.copy(), old.heading, old.speed, target_speed=config.cost.v_des
            )
        else:
            ego = PlanFollower(road, old.position.copy(), old.heading, old.speed)
        ego.color = (50, 200, 0)  # highway-env's ego green in videos
        road.vehicles[road.vehicles.index(old)] = ego
        self.env.controlled_vehicles = [ego]
        self.ego = ego
        self.t_grid = frenet.TimeGrid(config.trajectory.horizon, config.trajectory.num_steps).t
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
