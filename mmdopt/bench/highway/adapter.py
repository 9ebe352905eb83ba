"""highway-env ↔ planner: state conversion, the plan-following ego vehicle, crash classes and the
scene source :class:`HighwaySource` of :func:`mmdopt.receding.run_receding`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

import frenet
import mmdopt
from mmdopt.receding import Observation, StepOutcome

from .context import scene_context
from .junction import crossings
from .predictors import RoutePredictor, make_predictor
from .roads import arrived, build_road, on_road, reanchor, route_of
from .settings import AGENTS, EGO_MODELS, METHODS, HighwaySettings, require_highway


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
def bicycle_limits(length: float = 5.0, max_steer: float = math.pi / 3) -> float:
    """The largest path curvature (1/m) of highway-env's kinematic bicycle: its centre turns
    with slip angle ``β = atan(½ tan δ)`` and heading rate ``v sin β / (L/2)``, so
    ``κ_max = sin(atan(½ tan δ_max)) / (L/2)``; the yaw-rate limit at speed ``v`` is
    ``v κ_max``."""
    if not (length > 0 and 0 < max_steer < math.pi / 2):
        raise ValueError(f"length must be > 0 and max_steer in (0, π/2), got {length}, {max_steer}")
    return math.sin(math.atan(0.5 * math.tan(max_steer))) / (length / 2.0)


def plan_curvature(plan) -> tuple[float, float]:
    """``(max |κ|, max |ψ̇|)`` of a plan's Cartesian path: the yaw rate from its heading
    (unwrapped) on the time grid, the curvature ``ψ̇ / v`` where it moves at ≥ 1 m/s (below, the
    heading is held and the curvature is undefined)."""
    t = np.asarray(plan.t, float)
    rate = np.gradient(np.unwrap(np.asarray(plan.heading, float)), t)
    v = np.asarray(plan.speed, float)
    moving = v >= 1.0
    kappa = np.abs(rate[moving] / v[moving]) if moving.any() else np.zeros(1)
    return float(np.max(kappa)), float(np.max(np.abs(rate)))


def _reference(plan, ff, tc: float) -> tuple[float, ...]:
    """``(x, y, heading, speed, acceleration, curvature)`` of a follower's plan at ``tc`` s
    (constant speed along the last heading past its end)."""
    t, x, y, h, v, _ = plan
    a, k = ff
    if tc <= t[-1]:
        return tuple(float(np.interp(tc, t, arr)) for arr in (x, y, h, v, a, k))
    sp, dt = float(v[-1]), tc - t[-1]
    return (
        float(x[-1] + sp * dt * math.cos(h[-1])),
        float(y[-1] + sp * dt * math.sin(h[-1])),
        float(h[-1]),
        sp,
        0.0,
        0.0,
    )


def _tracking_errors(vehicle, ref) -> tuple[float, float, float]:
    """Lateral error (m, left of the reference positive), along-track error (m, ahead positive)
    and velocity-direction error (rad: the heading plus the bicycle's slip angle) of a vehicle
    against a reference ``(x, y, heading, ...)``."""
    xr, yr, hr = ref[0], ref[1], ref[2]
    dx, dy = vehicle.position[0] - xr, vehicle.position[1] - yr
    lat = -math.sin(hr) * dx + math.cos(hr) * dy
    lon = math.cos(hr) * dx + math.sin(hr) * dy
    beta = math.atan(0.5 * math.tan(float(vehicle.action.get("steering", 0.0))))
    eh = math.remainder(vehicle.heading + beta - hr, 2 * math.pi)
    return lat, lon, eh


def _tracking_command(v, ref) -> dict:
    """The tracking controller of :class:`PlanFollower` ``v`` at the plan's reference ``ref``
    (its docstring): highway-env's ``{"steering", "acceleration"}``."""
    lat, lon, eh = _tracking_errors(v, ref)
    speed = max(float(v.speed), v.V_FLOOR)
    w, z = v.OMEGA, v.ZETA
    kappa = ref[5] - (w * w / (speed * speed)) * lat - (2.0 * z * w / speed) * eh
    sin_beta = float(np.clip(kappa * v.LENGTH / 2.0, -0.99, 0.99))
    steer = math.atan(2.0 * math.tan(math.asin(sin_beta)))
    steer = float(np.clip(steer, -v.MAX_STEERING_ANGLE, v.MAX_STEERING_ANGLE))
    acc = ref[4] + v.K_V * (ref[3] - v.speed) - v.K_S * lon
    return {"steering": steer, "acceleration": float(np.clip(acc, v.ACC_MIN, v.ACC_MAX))}


def _follower_class():
    from highway_env.vehicle.controller import ControlledVehicle
    from highway_env.vehicle.kinematics import Vehicle

    class PlanFollower(Vehicle):
        """A highway-env vehicle that executes planned trajectories.

        ``set_plan(t, x, y, heading, speed, frenet)`` (grid arrays) restarts the plan clock;
        each ``step(dt)`` advances it.  ``model="bicycle"``: ``act`` computes highway-env's
        ``{"steering", "acceleration"}`` from the plan at the plan clock and ``step`` integrates
        highway-env's kinematic bicycle.  The steering is a curvature command: the plan's
        curvature (feed-forward) plus state feedback on the lateral and heading errors with
        speed-scheduled gains (closed-loop lateral error ``ë + 2ζω ė + ω² e = 0``, ω = 1.5 rad/s,
        ζ = 0.8, for the linearised bicycle; gains held at their 5 m/s values below 5 m/s),
        turned into a steering angle and clipped at highway-env's ±60°; the acceleration is the
        plan's plus a speed and along-track position loop (``k_v = 2/s, k_s = 1/s²``), clipped
        to ``[−8, 6]`` m/s² and never reversing.
        ``model="exact"``: the pose and speed are set by linear interpolation of the plan (no
        vehicle model; constant speed along the last heading past the plan's end).  After a
        crash it brakes like any highway-env vehicle.  ``tracking_errors``: the lateral distance
        from the plan's path at the plan clock after every step (m).
        """

        MAX_STEERING_ANGLE = ControlledVehicle.MAX_STEERING_ANGLE
        ACC_MIN, ACC_MAX = -8.0, 6.0
        OMEGA, ZETA, K_V, K_S = 1.5, 0.8, 2.0, 1.0
        #: the speed (m/s) below which the lateral gains stop growing: the feedback curvature
        #: scales as 1/v², and below a walking pace a few decimetres of error would saturate the
        #: steering and make it chatter (the velocity's slip angle then swings with it)
        V_FLOOR = 5.0

        def __init__(
            self, road, position, heading=0.0, speed=0.0, model="exact", target_speed=30.0
        ):
            super().__init__(road, position, heading, speed)
            if model not in EGO_MODELS:
                raise ValueError(f"model must be one of {EGO_MODELS}, got {model!r}")
            self.model = model
            # highway-env's drivers judge a lane change by the IDM acceleration it would impose
            # on the car behind (MOBIL), reading that car's ``target_speed`` (0 when absent: any
            # moving car without one looks as if it would brake without limit, so no driver
            # would ever merge in front of the ego).  The ego's is the planner's desired speed,
            # as highway-env's own controlled vehicles have one.
            self.target_speed = float(target_speed)
            self.plan_clock = 0.0
            self._plan = None
            self._plan_ff = None
            self.tracking_errors: list[float] = []
            self.action = {"steering": 0.0, "acceleration": 0.0}

        def set_plan(self, t, x, y, heading, speed, frenet_arrays=None):
            t = np.asarray(t, float)
            h = np.unwrap(np.asarray(heading, float))
            v = np.asarray(speed, float)
            ds = np.maximum(v, 1.0)  # curvature = yaw rate / speed (finite at a stop)
            self._plan = (
                t,
                np.asarray(x, float),
                np.asarray(y, float),
                h,
                v,
                None
                if frenet_arrays is None
                else {k: np.asarray(val, float) for k, val in frenet_arrays.items()},
            )
            # the plan's acceleration and curvature, for the tracking controller's feed-forward
            self._plan_ff = (np.gradient(v, t), np.gradient(h, t) / ds)
            self.plan_clock = 0.0

        def frenet_now(self):
            """Frenet arrays of the plan interpolated at the plan clock (``None`` without plan)."""
            if self._plan is None or self._plan[5] is None:
                return None
            t = self._plan[0]
            return {k: float(np.interp(self.plan_clock, t, v)) for k, v in self._plan[5].items()}

        def reference(self, tc):
            """``(x, y, heading, speed, acceleration, curvature)`` of the plan at ``tc`` s."""
            return _reference(self._plan, self._plan_ff, tc)

        def _errors(self, ref):
            return _tracking_errors(self, ref)

        def act(self, action=None):
            if self.model != "bicycle" or self._plan is None or self.crashed:
                return
            self.action = _tracking_command(self, self.reference(self.plan_clock))

        def step(self, dt):
            if self.crashed or self._plan is None:
                brake = -float(self.speed) if self.crashed else 0.0
                self.action = {"steering": 0.0, "acceleration": brake}
                Vehicle.step(self, dt)
                return
            self.plan_clock += dt
            if self.model == "bicycle":
                # brake to a stop, never reverse
                acc = max(float(self.action["acceleration"]), -max(float(self.speed), 0.0) / dt)
                self.action = dict(self.action, acceleration=acc)
                Vehicle.step(self, dt)
            else:
                self._set_pose(dt)
            lat = self._errors(self.reference(self.plan_clock))[0]
            self.tracking_errors.append(abs(lat))

        def _set_pose(self, dt):
            xr, yr, heading, speed, _, _ = self.reference(self.plan_clock)
            self.position = np.array([xr, yr], dtype=float)
            self.heading = float((heading + math.pi) % (2 * math.pi) - math.pi)
            self.speed = float(speed)
            if self.impact is not None:
                self.position += self.impact
                self.crashed = True
                self.impact = None
            self.on_state_update()

    return PlanFollower


def PlanFollower(
    road, position, heading=0.0, speed=0.0, model: str = "exact", target_speed: float = 30.0
):
    """A plan-executing highway-env vehicle, ``model`` of :data:`EGO_MODELS` (the class is built
    on first use: highway-env is an optional dependency)."""
    global _PLAN_FOLLOWER
    if model not in EGO_MODELS:
        raise ValueError(f"model must be one of {EGO_MODELS}, got {model!r}")
    if _PLAN_FOLLOWER is None:
        _PLAN_FOLLOWER = _follower_class()
    return _PLAN_FOLLOWER(road, position, heading, speed, model, target_speed)


_PLAN_FOLLOWER = None


#: how far a measured state may lie outside the planner's bounds and still be moved onto them
#: (m, m/s): tracking noise of the bicycle ego (e.g. 10.05 m/s at a 10 m/s limit, or a lateral
#: offset a few cm past the outer lane centre), which would otherwise make every candidate
#: infeasible from its first point and the plan a braking fallback.  A larger excess is kept, so
#: the planner reports it (a braking fallback) instead of a silently moved start.
MEASURED_SLACK = {"d": 0.3, "vs": 0.5, "vd": 0.3}


def _settle(v: float, lo: float, hi: float, slack: float) -> float:
    """``v`` moved onto ``[lo, hi]`` when it lies outside by at most ``slack``, else ``v``."""
    if lo - slack <= v < lo:
        return float(lo)
    if hi < v <= hi + slack:
        return float(hi)
    return float(v)


def _note_modes(predictor, info: dict | None) -> None:
    """Record in ``info`` the route (mode) of each sample the route predictor just drew
    (``modes``, for the videos' colours by route)."""
    modes = getattr(predictor, "last_modes", None)
    if info is not None and modes is not None:
        info["modes"] = np.array(modes)


# ------------------------------------------------------------------------------ the scene source
#: the most futures per obstacle a forecast gives the planner (n(ε) beyond it: ``risk floor``)
MAX_FORECAST_SAMPLES = 5000


@dataclass(frozen=True, eq=False)
class HighwayDraw:
    """One replan's highway predictor as an :mod:`mmdopt.predict` predictor: ``sample`` calls
    ``predictor(road, ego, targets, t_grid, n, rng)`` on the scene as observed, ``rng`` the
    episode's random stream of this replan (``np.random.default_rng(seed)``, ``seed`` =
    (episode seed, replan index), fresh at every call), so the planner draws the futures the
    array path drew and a run is the same through either path; the key of the protocol is not
    used (the stream is already the replan's own).  Each call's prediction time is appended to
    ``times``.  ``history`` and ``context`` are checked against the targets, not read: the
    benchmark's predictors read the simulator's scene."""

    predictor: Any
    road: Any
    ego: Any
    targets: tuple
    t_grid: np.ndarray
    seed: tuple
    times: list
    info: dict | None = None

    def sample(self, history, context, n, key) -> np.ndarray:
        if np.shape(history)[0] != len(self.targets):
            raise ValueError(
                f"history has {np.shape(history)[0]} obstacles, the scene {len(self.targets)}"
            )
        rng = np.random.default_rng(list(self.seed))
        out = self.predictor(self.road, self.ego, list(self.targets), self.t_grid, int(n), rng)
        self.times.append(float(self.predictor.last_time_s))
        _note_modes(self.predictor, self.info)
        return out


class HighwaySource:
    """A highway-env episode as a :class:`mmdopt.receding.SceneSource`.

    ``method`` names the agent that drives the ego (:data:`~.settings.AGENTS`, kept as
    :attr:`agent`): a planner agent ("mmd", "degroot", "cv") is driven by
    :func:`mmdopt.receding.run_receding` and observes the predictions of the settings' predictor
    or of its own (:attr:`own_predictor`, "cv": the noise-free constant-velocity mean, one sample
    per car); the IDM agent ("idm") makes the ego highway-env's own IDM/MOBIL driver with desired
    speed ``v_des`` (drive it with :meth:`run_idm`).
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
        gym = require_highway()
        self.settings, self.seed, self.config, self.method = settings, int(seed), config, method
        self.agent = AGENTS[method]
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
        self.frame_views: list[tuple[np.ndarray, float]] = []
        self.render = render
        road = self.env.road
        old = self.env.vehicle
        #: the ego's route to its destination (highway-env's list of lane indices, from the
        #: env's configured destination: intersection-v2, roundabout-v1), None on roads without
        #: one (highway-v0, merge-v0, racetrack-v0: the ego drives on)
        self.route = route_of(old)
        # the Frenet path and lane bounds from the lane network at the ego (roads.build_road)
        self.road_model = self._build_road(old.lane_index, old.position)
        self._frame_changed = False  # the path was rebuilt on another lane since the last plan
        self._s_shift = 0.0  # path arc length moved by the last re-anchoring of a loop's window
        self._s_travelled = 0.0  # arc length of the windows left behind (m)
        self.off_road = False
        if self.agent.driver == "idm":
            from highway_env.vehicle.behavior import IDMVehicle

            v_des = float(config.cost.v_des)
            if self.route is not None:  # at a junction: the lane's speed limit, as the env's own
                v_des = min(v_des, float(road.network.get_lane(old.lane_index).speed_limit))
            ego = IDMVehicle(
                road,
                old.position.copy(),
                old.heading,
                old.speed,
                target_speed=v_des,
                route=None if self.route is None else list(self.route),
            )
        else:
            ego = PlanFollower(
                road,
                old.position.copy(),
                old.heading,
                old.speed,
                model=settings.ego_model,
                target_speed=config.cost.v_des,
            )
        ego.color = (50, 200, 0)  # highway-env's ego green in videos
        road.vehicles[road.vehicles.index(old)] = ego
        self.env.controlled_vehicles = [ego]
        self.ego = ego
        self.t_grid = frenet.TimeGrid(config.trajectory.horizon, config.trajectory.num_steps).t
        self.predictor = make_predictor(settings.predictor)
        #: the routes of the cars at a junction (the route predictor's, whatever the planner
        #: predicts with), for the shield's crossing rule
        self._routes = (
            self.predictor if isinstance(self.predictor, RoutePredictor) else RoutePredictor()
        )
        #: the agent's own predictor (planned on with one sample per car), else None
        self.own_predictor = (
            None if self.agent.predictor is None else make_predictor(self.agent.predictor)
        )
        self.step_index = 0
        self.s0 = float(self.path.to_frenet(*ego.position)[0])
        self.speeds: list[float] = [float(ego.speed)]
        self.predict_times: list[float] = []
        self.crash_kind = ""
        self.between_lanes_s = 0.0  # time the ego's centre is > 1 m from every lane centre
        self.plan_limits: list[tuple[float, float]] = []  # (max |κ|, max |ψ̇|) of each plan
        #: the ego reached its destination (:func:`~.roads.arrived`); None without a route
        self.arrived: bool | None = None if self.route is None else False
        # the env's own traffic between steps (intersection-v2 spawns cars at its entries and
        # removes those that have left, once per step of its default policy period)
        self._spawn_period = 1.0 / float(type(self.env).default_config()["policy_frequency"])
        self._spawned = 0
        if render:
            self._render()

    def _render(self) -> None:
        """Append highway-env's ``rgb_array`` frame to ``frames`` and its view (the world
        position of the frame's top-left pixel and the pixels per metre) to ``frame_views``, for
        drawing on the frame afterwards (:mod:`.video`)."""
        self.frames.append(self.env.render())
        surf = self.env.viewer.sim_surface
        self.frame_views.append((np.array(surf.origin, dtype=float), float(surf.scaling)))

    # -- the road
    def _route_from(self, lane_index):
        """The rest of the ego's route from the road of ``lane_index`` (None: no route, or that
        road is not on it)."""
        if self.route is None:
            return None
        roads = [tuple(r[:2]) for r in self.route]
        if tuple(lane_index[:2]) not in roads:
            return None
        return self.route[roads.index(tuple(lane_index[:2])) :]

    def _build_road(self, lane_index, position):
        st = self.settings
        return build_road(
            self.env.road.network,
            lane_index,
            position,
            limits=dict(
                v_min=0.0, v_max=st.v_max, vy_max=st.vy_max, ax_max=st.ax_max, ay_max=st.ay_max
            ),
            back=st.behind + 10.0,
            ahead=st.ahead,
            horizon=self.config.trajectory.horizon,
            route=self._route_from(lane_index),
        )

    @property
    def path(self) -> frenet.ReferencePath:
        """The Frenet reference path (:func:`~.roads.build_road`; on a loop it moves with the
        ego, see :meth:`observe`)."""
        return self.road_model.road.path

    @property
    def road(self) -> mmdopt.Road:
        """The planner's :class:`mmdopt.Road` (path, lane bounds, lane centres, limits)."""
        return self.road_model.road

    def _note_off_road(self) -> None:
        """Record whether the ego's centre has left every lane (``roads.on_road``)."""
        if not self.off_road and not on_road(self.env.road.network, self.ego.position):
            self.off_road = True

    # -- observation
    def _targets(self):
        """The ``max_obstacles`` cars nearest the ego among those from ``behind`` m behind to
        ``ahead`` m ahead of it along the path (Frenet ``s``) and at most 20 m beside the
        outermost lane centres; at a junction (an ego with a route), the nearest within
        ``ahead`` m in any direction, cars behind it in its own lane last."""
        others = [v for v in self.env.road.vehicles if v is not self.ego]
        if not others:
            return []
        pos = np.array([v.position for v in others], dtype=float)
        s, d = self.path.to_frenet(pos[:, 0], pos[:, 1])
        s_ego = float(self.path.to_frenet(*self.ego.position)[0])
        rel = s - s_ego
        keep = (rel >= -self.settings.behind) & (rel <= self.settings.ahead)
        keep &= (d >= self.road.y_lb - 20.0) & (d <= self.road.y_ub + 20.0)
        dist = np.linalg.norm(pos - np.asarray(self.ego.position, float), axis=1)
        if self.route is not None:
            # at a junction the cars that matter come from every side, not along the path: those
            # within ``ahead`` metres, the ones behind the ego in its own lane last
            behind = (rel < -2.0) & (np.abs(d) < 3.0)
            keep = dist <= self.settings.ahead
            dist = dist + np.where(behind, self.settings.ahead, 0.0)
        order = sorted(np.flatnonzero(keep), key=lambda i: float(dist[i]))
        return [others[i] for i in order][: self.settings.max_obstacles]

    def ego_state(self) -> frenet.EgoState:
        fr = self.ego.frenet_now() if hasattr(self.ego, "frenet_now") else None
        if fr is not None and not self.ego.crashed and self.ego.model == "bicycle":
            return self._measured_state(fr)
        if fr is not None and not self.ego.crashed and not self._frame_changed:
            # a plan made before the loop's window moved: its arc lengths shift with it
            return frenet.EgoState(**dict(fr, s=fr["s"] - self._s_shift))
        return vehicle_to_frenet(self.path, self.ego)

    def _measured_state(self, fr: dict) -> frenet.EgoState:
        """The bicycle ego's state for the next plan: position and velocity measured (the
        velocity's direction is the heading plus the slip angle), the accelerations of the plan
        being tracked, clipped to the planner's bounds."""
        ego = self.ego
        beta = math.atan(0.5 * math.tan(float(ego.action.get("steering", 0.0))))
        x, y = (float(v) for v in ego.position)
        st = self.path.ego_state(x, y, max(float(ego.speed), 0.0), float(ego.heading) + beta)
        ax, ay = self.road.ax_max, self.road.ay_max
        r = self.road
        return frenet.EgoState(
            s=st.s,
            d=_settle(st.d, r.y_lb, r.y_ub, MEASURED_SLACK["d"]),
            vs=_settle(st.vs, r.v_min, r.v_max, MEASURED_SLACK["vs"]),
            vd=_settle(st.vd, -r.vy_max, r.vy_max, MEASURED_SLACK["vd"]),
            as_=float(np.clip(fr["as_"], -ax, ax)),
            ad=float(np.clip(fr["ad"], -ay, ay)),
        )

    def _obstacle_states(self) -> np.ndarray:
        """``(M, 4)`` = ``(x, y, vx, vy)`` of every other car and road object within 200 m of
        the ego (what the safety shield checks; more than the planner's targets)."""
        road, ego = self.env.road, self.ego
        rows = [
            (*v.position, *v.velocity)
            for v in road.vehicles + road.objects
            if v is not ego and float(np.linalg.norm(v.position - ego.position)) < 200.0
        ]
        return np.array(rows, dtype=float).reshape(-1, 4)

    def _between_lanes(self) -> bool:
        """Whether the ego's centre is more than 1 m from the centre of every lane beside its
        own (highway-env's lanes, ``all_side_lanes``, lateral offsets by
        ``lane.local_coordinates``)."""
        net, pos = self.env.road.network, self.ego.position
        lanes = [net.get_lane(i) for i in net.all_side_lanes(self.ego.lane_index)]
        return min(abs(float(lane.local_coordinates(pos)[1])) for lane in lanes) > 1.0

    def _reanchor(self) -> None:
        """On a loop, move the path's window forward when the ego nears its end
        (:func:`~.roads.reanchor`); the distance driven is kept across windows."""
        s = float(self.path.to_frenet(*self.ego.position)[0])
        self.road_model, shift = reanchor(self.road_model, s, back=self.settings.behind + 10.0)
        self._s_shift = shift
        self._s_travelled += shift

    def _rebase(self) -> None:
        """On a curved road, once the ego has moved into another lane (its centre within 1 m of
        that lane's centre line and more than 1.5 m from the path), rebuild the path on the
        centre line of that lane (:func:`~.roads.build_road`).  In a bend, a path one lane away
        makes arc length and distance driven differ by the factor 1 − κ·d (up to ±35 % on
        ``racetrack-v0``), and a plan at a steady Frenet speed would ask for a jump in speed
        where the curvature changes sign.  The distance driven is kept across paths; the
        observation says the frame changed, so the next plan starts cold."""
        self._frame_changed = False
        if self.road_model.chain is None or self.ego.crashed:
            return
        net, pos = self.env.road.network, self.ego.position
        s_old, d_old = (float(v) for v in self.path.to_frenet(*pos))
        lane_index = net.get_closest_lane_index(pos, self.ego.heading)
        lat = float(net.get_lane(lane_index).local_coordinates(pos)[1])
        if abs(d_old) <= 1.5 or abs(lat) >= 1.0:
            return
        try:
            self.road_model = self._build_road(lane_index, pos)
        except ValueError:  # that lane gives no usable path (too short a loop): keep this one
            return
        s_new = float(self.path.to_frenet(*pos)[0])
        self._s_travelled += s_old - s_new
        self._s_shift = 0.0
        self._frame_changed = True

    def observe(self) -> Observation:
        self._rebase()
        if not self._frame_changed:
            self._reanchor()
        self._note_off_road()
        targets = self._targets()
        rng = np.random.default_rng([self.seed, self.step_index])
        info: dict = {"n_targets": len(targets)}
        if self.own_predictor is not None:
            own = self.own_predictor
            obstacles = own(self.env.road, self.ego, targets, self.t_grid, 1, rng)
            pred_s = own.last_time_s
        elif self.settings.forecast and targets:
            obstacles, pred_s = self._forecast(targets, info), None
        else:
            obstacles = self.predictor(
                self.env.road, self.ego, targets, self.t_grid, self.settings.n_samples, rng
            )
            pred_s = self.predictor.last_time_s
            _note_modes(self.predictor, info)
        if self.route is not None and self.render:
            s_ego = float(self.path.to_frenet(*self.ego.position)[0])
            ss = np.arange(max(s_ego - 10.0, 0.0), min(s_ego + 100.0, self.path.length), 1.0)
            rx, ry = self.path.to_cartesian(ss, np.zeros_like(ss))
            info["route_xy"] = np.column_stack([rx, ry])
        if pred_s is not None:  # a forecast's draw records its own time
            self.predict_times.append(pred_s)
            info["predict_s"] = pred_s
        extra = {}
        if self.route is not None and self.settings.shield:
            extra["crossings"] = self._crossings()
            info["n_crossings"] = int(extra["crossings"].shape[0])
        return Observation(
            ego=self.ego_state(),
            road=self.road,
            obstacles=obstacles,
            time=float(self.env.time),
            info=info,
            obstacle_states=self._obstacle_states(),
            frame_changed=self._frame_changed,
            obstacle_headings=np.array([float(v.heading) for v in targets], float),
            **extra,
        )

    def _crossings(self) -> np.ndarray:
        """At a junction, the conflict areas ``(C, 3)`` of the cars within ``ahead`` m of the
        ego whose routes cross its path (:func:`~.junction.crossings`), for the shield's
        crossing rule (:func:`mmdopt.safety.check_crossings`)."""
        ego = self.ego
        cars = [
            v
            for v in self.env.road.vehicles
            if v is not ego
            and float(np.linalg.norm(v.position - ego.position)) < self.settings.ahead
        ]
        s_ego = float(self.path.to_frenet(*ego.position)[0])
        return crossings(
            self._routes, self.env.road, self.path, s_ego, cars,
            ahead=self.settings.ahead, horizon=self.config.trajectory.horizon,
        )  # fmt: skip

    def _forecast(self, targets, info: dict | None = None) -> mmdopt.predict.Forecast:
        """The targets as a :class:`mmdopt.predict.Forecast` of this replan's
        :class:`HighwayDraw`: histories of two rows (0.1 s ago at the current velocity, now),
        the lane context of :func:`~.context.scene_context`, ``n_samples`` futures with the
        time-linear margins (n(ε) in the "samples" mode, at most :data:`MAX_FORECAST_SAMPLES`)."""
        road = self.env.road
        cars = list(road.vehicles)
        idx = [next(i for i, u in enumerate(cars) if u is v) for v in targets]
        pos = np.array([v.position for v in cars], float)
        vel = np.array([v.velocity for v in targets], float)
        history = np.stack([pos[idx] - 0.1 * vel, pos[idx]], axis=1)
        ctx = scene_context(
            road.network,
            [v.lane_index for v in cars],
            pos,
            np.array([v.speed for v in cars], float),
            idx,
            self.t_grid,
            0.1,
        )
        draw = HighwayDraw(
            self.predictor, road, self.ego, tuple(targets), self.t_grid,
            (self.seed, self.step_index), self.predict_times, info,
        )  # fmt: skip
        n = self.settings.n_samples
        return mmdopt.predict.Forecast(
            draw, history, ctx, min_samples=n, max_samples=max(n, MAX_FORECAST_SAMPLES)
        )

    # -- execution
    def _advance(self) -> StepOutcome:
        env = self.env
        for _ in range(self.settings.frames_per_step):
            env.road.act()
            env.road.step(1.0 / self.settings.simulation_frequency)
            self.predictor.record(env.road, 1.0 / self.settings.simulation_frequency)
            if self.route is not None and self._routes is not self.predictor:
                self._routes.record(env.road, 1.0 / self.settings.simulation_frequency)
            if self.own_predictor is not None:
                self.own_predictor.record(env.road, 1.0 / self.settings.simulation_frequency)
            env.steps += 1
            self.speeds.append(float(self.ego.speed))
            if self._between_lanes():
                self.between_lanes_s += 1.0 / self.settings.simulation_frequency
            self._note_off_road()
            if self.render:
                self._render()
            if self.arrived is False and arrived(env, self.ego, self.route):
                self.arrived = True
            if self.ego.crashed:
                break
        env.time += self.settings.dt
        self.step_index += 1
        self._env_traffic()
        crashed = bool(self.ego.crashed)
        if crashed and not self.crash_kind:
            self.crash_kind = self._crash_kind()
        done = crashed or bool(self.arrived) or env.time >= self.settings.duration - 1e-9
        return StepOutcome(done=done, crashed=crashed, info={"time": float(env.time)})

    def _env_traffic(self) -> None:
        """The env's own traffic rules between its steps, which ``env.step`` would run and the
        benchmark's own stepping does not: cars that have left removed (``_clear_vehicles``)
        and new ones spawned at the entries (``_spawn_vehicle`` at the env's
        ``spawn_probability``) once per step of the env's default policy period, so the traffic
        is the env's whatever the replan period."""
        env = self.env
        if hasattr(env, "_clear_vehicles"):
            env._clear_vehicles()
        if "spawn_probability" in env.config and hasattr(env, "_spawn_vehicle"):
            due = int(math.floor(env.time / self._spawn_period + 1e-9))
            while self._spawned < due:
                env._spawn_vehicle(spawn_probability=env.config["spawn_probability"])
                self._spawned += 1

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
        self.plan_limits.append(plan_curvature(trajectory))
        return self._advance()

    def run_idm(self) -> StepOutcome:
        """Drive the whole episode with the IDM ego (the agent whose driver is "idm")."""
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

    def others_crashed(self) -> int:
        """How many cars other than the ego have crashed (into each other or the ego)."""
        return sum(1 for v in self.env.road.vehicles if v is not self.ego and v.crashed)

    def distance(self) -> float:
        """Metres driven along the path (Frenet ``s``; Δx on a straight road along +x)."""
        s = float(self.path.to_frenet(*self.ego.position)[0])
        return s + self._s_travelled - self.s0

    def close(self) -> None:
        self.env.close()
