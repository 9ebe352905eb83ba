"""A peer on the recorded-traffic tasks: CommonRoad's sampling-based Frenet planner.

``commonroad-reactive-planner`` (Werling et al., ICRA 2010: quartic/quintic polynomials in a
Frenet frame, sampled over end time, end speed and end lateral offset, checked for kinematic
feasibility, then for collisions with CommonRoad's own checker, the cheapest collision-free one
kept) plans the same task as :func:`mmdopt.plan` (:func:`~.runner.run_task`):

* the same start: the removed car's recorded state at t0 (centre → rear axle, as the planner
  wants it), its length × width;
* the same reference path: the ego's route (:func:`~.scene.ego_road_geometry`) as a polyline
  of 1 m steps (the planner's own CLCS preprocessing on top), lateral samples within the same
  road bounds ``[y_lb, y_ub]``;
* the same desired speed (the task config's ``v_des``) and horizon (the benchmark's time grid);
* the same information about the others: each obstacle's first ``reactive_futures``
  (:class:`~.inputs.NgsimParams`) predictor samples (of the ones MMD-Opt plans with), every
  one a CommonRoad dynamic obstacle of the car's recorded size with the heading of its motion,
  plus the road boundary of the lanelet network.  It never sees the recorded futures it is
  scored against.

``plan_time_s`` is the collision checker built from those futures plus ``planner.plan()``: what
a user pays per planning cycle (the road boundary, built once per scene, is not in it).  When
the planner finds no trajectory (every sample collides or is infeasible) the peer brakes
along the path at :data:`FALLBACK_DECEL` (``fallback`` True, ``feasible`` False).

Install: ``commonroad-reactive-planner`` 2025.1 with ``commonroad-route-planner`` 2025.1.0 and
``commonroad-clcs`` 2025.2.0 without their dependencies (``pip install --no-deps -r
requirements-peer.txt``; the ``peer`` extra brings the rest): ``commonroad-clcs`` declares
``osqp~=0.6.5``, which cvxpy ≥ 1.6 (``osqp>=1.0``) excludes, though the paths the planner uses
do not call OSQP.  :func:`available` says whether it imports.
"""

from __future__ import annotations

import atexit
import time
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, ClassVar

import numpy as np

__all__ = [
    "REACTIVE",
    "PEERS",
    "FALLBACK_DECEL",
    "INSTALL",
    "available",
    "PeerPlan",
    "plan_reactive",
]

#: the method name of the peer in ``results.csv`` and ``--methods``
REACTIVE = "reactive"
#: the bench-side peers (not :mod:`mmdopt.methods`: they plan on CommonRoad scenes only)
PEERS = (REACTIVE,)
#: deceleration (m/s²) of the peer's braking fallback when it finds no trajectory
FALLBACK_DECEL = 6.0
#: how to install the peer
INSTALL = (
    "pip install -e '.[peer]' && pip install --no-deps -r requirements-peer.txt "
    "(commonroad-reactive-planner 2025.1, commonroad-route-planner 2025.1.0, "
    "commonroad-clcs 2025.2.0)"
)


def available() -> str | None:
    """None if the reactive planner imports, else why not and how to install it."""
    try:
        from commonroad_rp.reactive_planner import ReactivePlanner  # noqa: F401
        from commonroad_rp.utility.utils_coordinate_system import CoordinateSystem  # noqa: F401
    except Exception as exc:  # ImportError, or a build against other CommonRoad packages
        return f"the reactive planner does not import ({type(exc).__name__}: {exc}); {INSTALL}"
    return None


@dataclass(frozen=True)
class PeerPlan:
    """A peer's plan on the benchmark's time grid, with the fields the scores read
    (:class:`mmdopt.Plan`'s names): centre positions ``x, y``, ``heading``, ``speed``,
    longitudinal acceleration ``as_``, Frenet ``s, d`` on the task's reference path.  Its
    ``heading`` is the car's body orientation and ``speed`` the rear axle's (the reactive
    planner's KS states, positions shifted to the centre): :attr:`heading_is_body`."""

    #: the heading is the body's, not the centre's direction of motion (read by
    #: :func:`~mmdopt.bench.ngsim.crcheck.plan_trajectory`)
    heading_is_body: ClassVar[bool] = True

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    as_: np.ndarray
    s: np.ndarray
    d: np.ndarray
    plan_time_s: float
    feasible: bool
    fallback: bool
    message: str = ""
    cost: float = float("nan")
    risk_bound: float = float("nan")
    diagnostics: dict[str, Any] = field(default_factory=dict)

    @property
    def xy(self) -> np.ndarray:
        """(K, 2) Cartesian waypoints."""
        return np.stack([self.x, self.y], axis=-1)

    @property
    def progress(self) -> float:
        """Arc length travelled along the reference path over the horizon (m)."""
        return float(self.s[-1] - self.s[0])

    @property
    def status_text(self) -> str:
        """``"ok"`` or ``"fallback: why"``."""
        return "ok" if not self.fallback else f"fallback: {self.message}"


@lru_cache(maxsize=4)
def _map(path: str):
    """(lanelet network, road boundary collision object) of a scenario file."""
    from commonroad.common.file_reader import CommonRoadFileReader
    from commonroad_dc.boundary.boundary import create_road_boundary_obstacle

    scenario, _ = CommonRoadFileReader(str(path)).open()
    _, boundary = create_road_boundary_obstacle(scenario)
    return scenario.lanelet_network, boundary, float(scenario.dt)


# the cached collision objects go before the interpreter tears the extension down
atexit.register(_map.cache_clear)


def _headings(pts: np.ndarray, h0: float) -> np.ndarray:
    """(K,) heading of the motion along ``pts`` (K, 2); ``h0`` while (nearly) standing."""
    d = np.gradient(pts, axis=0)
    moving = np.hypot(d[:, 0], d[:, 1]) > 0.02
    h = np.arctan2(d[:, 1], d[:, 0])
    # forward fill over the standing steps: the last moving step's heading, else h0
    last = np.maximum.accumulate(np.where(moving, np.arange(len(pts)), -1))
    return np.unwrap(np.where(last >= 0, h[np.maximum(last, 0)], h0))


def _checker(boundary, futures: np.ndarray, lengths, widths, h0s):
    """CommonRoad collision checker of the road boundary and every future (O, M, K, 2) as a
    time-variant obstacle from time step 0."""
    import commonroad_dc.pycrcc as pycrcc
    from commonroad.geometry.shape import Rectangle
    from commonroad.prediction.prediction import TrajectoryPrediction
    from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType
    from commonroad.scenario.state import CustomState, InitialState
    from commonroad.scenario.trajectory import Trajectory
    from commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch import (
        create_collision_object,
    )

    cc = pycrcc.CollisionChecker()
    cc.add_collision_object(boundary)
    oid = 1
    for i in range(futures.shape[0]):
        shape = Rectangle(float(lengths[i]), float(widths[i]))
        for j in range(futures.shape[1]):
            pts = futures[i, j]
            h = _headings(pts, float(h0s[i]))
            states = [
                CustomState(time_step=k, position=pts[k], orientation=float(h[k]))
                for k in range(1, len(pts))
            ]
            ob = DynamicObstacle(
                oid,
                ObstacleType.CAR,
                shape,
                InitialState(time_step=0, position=pts[0], orientation=float(h[0]), velocity=0.0),
                TrajectoryPrediction(Trajectory(1, states), shape),
            )
            cc.add_collision_object(create_collision_object(ob))
            oid += 1
    return cc


def _braking(path, ego, times: np.ndarray, decel: float):
    """(s, d, x, y, heading, speed, accel) of braking at ``decel`` along the path from ``ego``."""
    v0 = max(float(ego.vs), 0.0)
    t_stop = v0 / decel
    tt = np.minimum(times, t_stop)
    s = ego.s + v0 * tt - 0.5 * decel * tt**2
    d = np.full_like(s, float(ego.d))
    x, y = (np.asarray(a, np.float64) for a in path.to_cartesian(s, d))
    speed = np.maximum(v0 - decel * times, 0.0)
    acc = np.where(times < t_stop, -decel, 0.0)
    return s, d, x, y, np.asarray(path.heading(s), np.float64), speed, acc


def plan_reactive(
    scenario_path: str,
    road,
    ego,
    start: tuple[float, float, float, float],
    size: tuple[float, float],
    times: np.ndarray,
    futures: np.ndarray,
    obstacle_sizes: np.ndarray,
    obstacle_headings: np.ndarray,
    v_des: float,
    full_horizon: bool = False,
) -> PeerPlan:
    """The reactive planner's plan of one task.

    ``road``: the task's :class:`mmdopt.Road` (reference path, lateral bounds); ``ego``: its
    Frenet start state on it; ``start``: the recorded centre ``(x, y, heading, speed)`` at t0;
    ``size``: the ego's (length, width); ``times``: the (K,) time grid from 0 (uniform);
    ``futures``: (O, M, K, 2) predicted positions of the obstacles (M futures each),
    ``obstacle_sizes`` (O, 2) their (length, width), ``obstacle_headings`` (O,) their headings
    at t0; ``v_des``: the desired speed (m/s); ``full_horizon``: sample end times at the horizon
    only (the planner's default samples them from 0.4 s on and extends a short sample straight
    to the horizon)."""
    reason = available()
    if reason is not None:
        raise ValueError(f"method {REACTIVE!r}: {reason}")
    times = np.asarray(times, np.float64)
    if times.ndim != 1 or len(times) < 2 or not np.allclose(np.diff(times), times[1] - times[0]):
        raise ValueError(f"times must be a uniform (K,) grid, K >= 2, got {times!r}")
    futures = np.asarray(futures, np.float64)
    if futures.ndim != 4 or futures.shape[2:] != (len(times), 2):
        raise ValueError(f"futures must be (O, M, {len(times)}, 2), got {futures.shape}")
    obstacle_sizes = np.asarray(obstacle_sizes, np.float64).reshape(-1, 2)
    if len(obstacle_sizes) != futures.shape[0] or len(obstacle_headings) != futures.shape[0]:
        raise ValueError("obstacle_sizes and obstacle_headings need one row per obstacle")
    if not (np.isfinite(v_des) and v_des >= 0):
        raise ValueError(f"v_des must be a finite speed >= 0, got {v_des!r}")
    from commonroad.scenario.scenario import Scenario
    from commonroad.scenario.state import InitialState
    from commonroad_clcs.config import CLCSParams
    from commonroad_rp.reactive_planner import ReactivePlanner
    from commonroad_rp.state import ReactivePlannerState
    from commonroad_rp.utility.config import ReactivePlannerConfiguration
    from commonroad_rp.utility.utils_coordinate_system import CoordinateSystem

    network, boundary, _ = _map(str(scenario_path))
    dt = float(times[1] - times[0])
    rc = ReactivePlannerConfiguration()
    rc.planning.dt = dt
    rc.planning.time_steps_computation = len(times) - 1
    rc.planning.planning_horizon = dt * (len(times) - 1)
    rc.debug.multiproc = False
    rc.debug.logging_level = "ERROR"
    rc.debug.show_plots = rc.debug.save_plots = False
    rc.vehicle.length, rc.vehicle.width = (float(a) for a in size)
    rc.sampling.d_min, rc.sampling.d_max = float(road.y_lb), float(road.y_ub)
    if full_horizon:
        # end times at the horizon only: a sample ending earlier is extended along a straight
        # line in Cartesian space (``TrajectorySample.enlarge``), which leaves the route in a turn
        rc.sampling.t_min = rc.planning.planning_horizon
    rc.scenario = Scenario(dt=dt)
    rc.scenario.add_objects(network)
    path = road.path
    ss = np.arange(0.0, float(path.length), 1.0)
    ref = np.stack([np.asarray(a, np.float64) for a in path.to_cartesian(ss, 0.0 * ss)], -1)
    x0, y0, h0, v0 = (float(a) for a in start)
    init = InitialState(
        time_step=0, position=np.array([x0, y0]), orientation=h0, velocity=max(v0, 0.0),
        acceleration=0.0, yaw_rate=0.0, slip_angle=0.0,
    )  # fmt: skip
    t1 = time.perf_counter()
    planner = ReactivePlanner(rc)
    planner.set_reference_path(coordinate_system=CoordinateSystem(ref, clcs_params=CLCSParams()))
    x0_rear = ReactivePlannerState.create_from_initial_state(
        init, rc.vehicle.wheelbase, rc.vehicle.wb_rear_axle
    )
    setup_s = time.perf_counter() - t1
    t2 = time.perf_counter()
    cc = _checker(boundary, futures, obstacle_sizes[:, 0], obstacle_sizes[:, 1], obstacle_headings)
    message = ""
    try:
        planner.reset(
            initial_state_cart=x0_rear, collision_checker=cc,
            coordinate_system=planner.coordinate_system,
        )  # fmt: skip
        # at rest the planner reads the desired speed off a planning problem we do not have
        # (current_speed == 0): the sampling range starts from 1 cm/s instead
        v_now = max(float(x0_rear.velocity), 0.01)
        planner.set_desired_velocity(desired_velocity=float(v_des), current_speed=v_now)
        out = planner.plan()
    except Exception as exc:  # the planner's asserts / CLCS projection errors: report, brake
        out, message = None, f"reactive planner failed ({type(exc).__name__}: {exc})"
    plan_s = time.perf_counter() - t2
    diag = dict(setup_s=setup_s, n_futures=int(futures.shape[0] * futures.shape[1]))
    if out is None or len(out[0].state_list) < len(times):
        s, d, x, y, hd, sp, acc = _braking(path, ego, times, FALLBACK_DECEL)
        return PeerPlan(
            times, x, y, hd, sp, acc, s, d, plan_s, feasible=False, fallback=True,
            message=message or "no collision-free, feasible sample; braking along the path",
            diagnostics=diag,
        )  # fmt: skip
    states = [
        ReactivePlannerState.shift_state_to_center(st, rc.vehicle.wb_rear_axle)
        for st in out[0].state_list[: len(times)]
    ]
    x = np.array([st.position[0] for st in states], np.float64)
    y = np.array([st.position[1] for st in states], np.float64)
    hd = np.unwrap(np.array([st.orientation for st in states], np.float64))
    sp = np.array([st.velocity for st in states], np.float64)
    acc = np.array([st.acceleration for st in states], np.float64)
    s, d = (np.asarray(a, np.float64) for a in path.to_frenet(x, y))
    return PeerPlan(
        times, x, y, hd, sp, acc, s, d, plan_s, feasible=True, fallback=False,
        cost=float(planner.optimal_cost), diagnostics=diag,
    )  # fmt: skip
