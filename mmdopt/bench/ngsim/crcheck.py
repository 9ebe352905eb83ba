"""CommonRoad's own checkers on the benchmark's plans (``commonroad-drivability-checker``).

A second opinion on every plan of ``mmdopt bench ngsim``, from the tools the CommonRoad
benchmark suite scores solutions with, on the same recorded scene:

* ``cr_collision_free``: the plan's footprint (the removed car's length × width, centred on the
  planned position and turned to the planned heading: the footprint of :mod:`.metric`) against
  every *other* recorded obstacle of the scene (``pycrcc`` time-variant collision objects of the
  recorded trajectories; the ego's own recording is left out);
* ``cr_road_compliant``: the same footprint against the road boundary obstacle of the lanelet
  network (``commonroad_dc.boundary``, method "obb_rectangles": oriented rectangles along
  the outer lanelet boundaries: a footprint that touches an outer edge is not compliant; recorded
  drivers do that too, e.g. car 571 of USA_US101-10_1_T-1 in 7 of the 51 steps after t = 1 s);
* ``cr_feasible``: the trajectory is reproducible by the kinematic single-track model (KS) of
  :data:`VEHICLE_TYPE` (``commonroad_dc.feasibility.feasibility_checker.trajectory_feasibility``:
  for each 0.1 s step an input within the model's steering-rate and acceleration bounds that
  reaches the next planned position and orientation within the checker's default tolerance).
  A plan is the path of the car's centre; the KS model's rear axle follows it
  (:func:`body_heading`), which gives each state's body orientation, rear-axle speed and
  steering angle ``δ = atan(l_wb · ψ̇ / v)`` (the planner outputs none of the three).

:func:`solution` / :func:`write_solution` give a plan as a CommonRoad solution file
(``commonroad.common.solution``: one ``PlanningProblemSolution`` of the KS model, the ego's
recorded obstacle id as the planning problem id, its trajectory of KS states).

Needs ``commonroad-io`` < 2026 (2024.3 checked) and ``commonroad-drivability-checker`` 2025.4
(``pip install 'mmdopt[commonroad]'``); :func:`available` says whether they import.
"""

from __future__ import annotations

import atexit
import math
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "CR_COLUMNS",
    "VEHICLE_MODEL",
    "VEHICLE_TYPE",
    "available",
    "body_heading",
    "plan_trajectory",
    "check_plan",
    "solution",
    "write_solution",
    "disagreements",
]

#: results.csv columns written by :func:`check_plan` (booleans)
CR_COLUMNS = ("cr_collision_free", "cr_road_compliant", "cr_feasible")
#: the vehicle model of the feasibility check and of exported solutions
VEHICLE_MODEL = "KS"
#: the vehicle parameters of the KS model (CommonRoad vehicle type 2)
VEHICLE_TYPE = "BMW_320i"


def available() -> str | None:
    """None if the checker and a compatible commonroad-io import, else why not."""
    try:
        import commonroad_dc.boundary.boundary  # noqa: F401
        import commonroad_dc.feasibility.feasibility_checker  # noqa: F401
        from commonroad.common.solution import CommonRoadSolutionWriter  # noqa: F401
        from commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch import (  # noqa: F401
            create_collision_object,
        )
    except Exception as exc:  # ImportError, or a checker built against another commonroad-io
        return (
            f"CommonRoad's checkers do not import ({type(exc).__name__}: {exc}); "
            "pip install 'mmdopt[commonroad]' (commonroad-io<2026, "
            "commonroad-drivability-checker)"
        )
    return None


@lru_cache(maxsize=4)
def _scenario(path: str):
    """(scenario, obstacle collision objects by id, road boundary collision object) of a file."""
    from commonroad.common.file_reader import CommonRoadFileReader
    from commonroad_dc.boundary.boundary import create_road_boundary_obstacle
    from commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch import (
        create_collision_object,
    )

    scenario, _ = CommonRoadFileReader(str(path)).open()
    objs = {int(o.obstacle_id): create_collision_object(o) for o in scenario.obstacles}
    _, boundary = create_road_boundary_obstacle(scenario, method="obb_rectangles")
    return scenario, objs, boundary


# the cached collision objects go before the interpreter tears the extension down (else
# nanobind reports them as leaked at exit)
atexit.register(_scenario.cache_clear)


def _vehicle():
    from commonroad.common.solution import VehicleModel, VehicleType
    from commonroad_dc.feasibility.vehicle_dynamics import VehicleDynamics

    return VehicleDynamics.from_model(VehicleModel[VEHICLE_MODEL], VehicleType[VEHICLE_TYPE])


def body_heading(
    t: np.ndarray, heading: np.ndarray, speed: np.ndarray, l_r: float, substeps: int = 10
) -> tuple[np.ndarray, np.ndarray]:
    """The body heading ``ψ`` and its rate of a kinematic single-track car whose centre moves in
    the direction ``heading`` (φ, unwrapped) at ``speed`` (v) at times ``t`` (each (n,)).

    The KS model's states are the car's centre, but its rear axle is what moves along the body
    (CommonRoad's KS converts a state's position to the rear axle, ``b`` = ``l_r`` behind the
    centre along ψ).  With the rear axle dragged by the centre (a tractrix), ``ψ̇ = v·sin(φ − ψ)
    / l_r``; integrated here with RK4 (``substeps`` per interval, φ and v linear in between) from
    the steady turn of the starting curvature κ₀ = φ̇₀ / v₀: ``sin(φ₀ − ψ₀) = l_r κ₀``.  A plan
    whose heading is its direction of motion is the centre's path, and ``ψ`` differs from it by
    the slip angle (≈ 5° in a 15 m turn); giving the checker ``φ`` instead puts the rear axle
    off the path it must follow.  Returns ``(ψ, ψ̇)``, each (n,)."""
    t, phi, v = (np.asarray(a, np.float64) for a in (t, heading, speed))
    if not (t.shape == phi.shape == v.shape and t.ndim == 1 and t.size >= 1):
        raise ValueError(
            f"t, heading, speed must be 1-D of one length, got {t.shape}, {phi.shape}, {v.shape}"
        )
    if not (np.isfinite(l_r) and l_r > 0):
        raise ValueError(f"l_r must be a finite number > 0, got {l_r!r}")

    k0 = 0.0
    if t.size > 1 and v[0] > 0.5:
        k0 = (phi[1] - phi[0]) / (t[1] - t[0]) / v[0]
    psi = np.empty_like(phi)
    psi[0] = phi[0] - np.arcsin(np.clip(l_r * k0, -0.5, 0.5))
    # φ and v / l_r at every RK4 stage time (start, middle, end of each substep), interpolated
    # at once; only the ODE itself is sequential (≤ 51 intervals × ``substeps``)
    h = np.diff(t)[:, None, None] / substeps
    tq = t[:-1, None, None] + h * (np.arange(substeps)[None, :, None] + [[[0.0, 0.5, 1.0]]])
    pq, wq = np.interp(tq, t, phi).tolist(), (np.interp(tq, t, v) / l_r).tolist()
    for i in range(t.size - 1):
        p, hi = psi[i], float(h[i, 0, 0])
        for (p0, pm, p1), (w0, wm, w1) in zip(pq[i], wq[i], strict=True):
            k1 = w0 * math.sin(p0 - p)
            k2 = wm * math.sin(pm - p - hi / 2 * k1)
            k3 = wm * math.sin(pm - p - hi / 2 * k2)
            k4 = w1 * math.sin(p1 - p - hi * k3)
            p += hi / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        psi[i + 1] = p
    return psi, v * np.sin(phi - psi) / l_r


def plan_trajectory(plan: Any, k0: int, dt: float):
    """The plan as a CommonRoad ``Trajectory`` of KS states from time step ``k0`` (the task's
    planning step), resampled onto the scene's grid of ``dt`` seconds.

    ``plan``: anything with ``t, x, y, heading, speed`` arrays (an :class:`mmdopt.Plan`): the
    car's centre and its direction of motion.  The states keep the centre's positions; their
    orientation is the body heading of :func:`body_heading`, their velocity the rear axle's
    (``v·cos(φ − ψ)``) and their steering angle the KS model's ``δ = atan(l_wb·ψ̇ / v)``.  A
    plan with ``heading_is_body`` (a KS planner's states, the peer's) keeps its heading and
    speed."""
    from commonroad.scenario.state import KSState
    from commonroad.scenario.trajectory import Trajectory

    if not (isinstance(dt, int | float) and dt > 0):
        raise ValueError(f"dt must be > 0, got {dt!r}")
    if not (isinstance(k0, int | np.integer) and k0 >= 0):
        raise ValueError(f"k0 must be an integer >= 0, got {k0!r}")
    t = np.asarray(plan.t, float) - float(np.asarray(plan.t)[0])
    n = int(np.floor(t[-1] / dt + 1e-9)) + 1
    tg = np.arange(n) * dt
    x, y, v = (np.interp(tg, t, np.asarray(a, float)) for a in (plan.x, plan.y, plan.speed))
    phi = np.interp(tg, t, np.unwrap(np.asarray(plan.heading, float)))
    par = _vehicle().parameters
    if getattr(plan, "heading_is_body", False):  # a KS planner's own states (the peer's)
        th, v_rear = phi, v
        dth = np.gradient(th, dt) if n > 1 else np.zeros(n)
    else:
        th, dth = body_heading(tg, phi, v, float(par.b))
        v_rear = v * np.cos(phi - th)
    delta = np.arctan(float(par.a + par.b) * dth / np.maximum(v_rear, 0.1))
    states = [
        KSState(
            time_step=int(k0 + i),
            position=np.array([x[i], y[i]]),
            steering_angle=float(delta[i]),
            velocity=float(v_rear[i]),
            orientation=float(th[i]),
        )
        for i in range(n)
    ]
    return Trajectory(initial_time_step=int(k0), state_list=states)


def check_plan(
    plan: Any, scenario_path: str | Path, ego_id: int, k0: int, length: float, width: float
) -> dict[str, bool]:
    """:data:`CR_COLUMNS` of one plan of the ego ``ego_id`` planned at step ``k0`` of the scene
    ``scenario_path`` (its footprint ``length`` × ``width`` m)."""
    from commonroad.geometry.shape import Rectangle
    from commonroad.prediction.prediction import TrajectoryPrediction
    from commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch import (
        create_collision_object,
    )
    from commonroad_dc.feasibility.feasibility_checker import trajectory_feasibility

    for name, val in (("length", length), ("width", width)):
        if not (np.isfinite(val) and val > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {val!r}")
    scenario, objs, boundary = _scenario(str(scenario_path))
    if int(ego_id) not in objs:
        raise ValueError(f"ego_id {ego_id} is not an obstacle of {scenario_path}")
    traj = plan_trajectory(plan, k0, float(scenario.dt))
    ego = create_collision_object(
        TrajectoryPrediction(traj, Rectangle(float(length), float(width)))
    )
    hit = any(o.collide(ego) for i, o in objs.items() if i != int(ego_id))
    try:
        feasible, _ = trajectory_feasibility(traj, _vehicle(), float(scenario.dt))
    except Exception:  # the checker's input reconstruction failed: not reproducible
        feasible = False
    return dict(
        cr_collision_free=not hit,
        cr_road_compliant=not boundary.collide(ego),
        cr_feasible=bool(feasible),
    )


def solution(plan: Any, scenario_path: str | Path, ego_id: int, k0: int):
    """A CommonRoad ``Solution`` of one plan (KS model, :data:`VEHICLE_TYPE`, planning problem
    id = the ego's recorded obstacle id)."""
    from commonroad.common.solution import (
        CostFunction,
        PlanningProblemSolution,
        Solution,
        VehicleModel,
        VehicleType,
    )

    scenario, _, _ = _scenario(str(scenario_path))
    pps = PlanningProblemSolution(
        planning_problem_id=int(ego_id),
        vehicle_model=VehicleModel[VEHICLE_MODEL],
        vehicle_type=VehicleType[VEHICLE_TYPE],
        cost_function=CostFunction.SM1,
        trajectory=plan_trajectory(plan, k0, float(scenario.dt)),
    )
    return Solution(scenario.scenario_id, [pps], computation_time=float(plan.plan_time_s))


def write_solution(
    plan: Any, scenario_path: str | Path, ego_id: int, k0: int, out_dir: str | Path, name: str
) -> Path:
    """Write :func:`solution` to ``out_dir/name.xml`` (CommonRoadSolutionWriter); the path."""
    from commonroad.common.solution import CommonRoadSolutionWriter

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    CommonRoadSolutionWriter(solution(plan, scenario_path, ego_id, k0)).write_to_file(
        output_path=str(out_dir), filename=f"{name}.xml", overwrite=True
    )
    return out_dir / f"{name}.xml"


def _is_bool(v: Any) -> bool:
    return isinstance(v, bool | np.bool_)


def disagreements(rows: list[dict]) -> str:
    """Where CommonRoad's checkers and the benchmark's own scores differ, as report lines.

    Compared: ``cr_collision_free`` with ``not any_collision`` (the same footprint against the
    same recorded vehicles, so they should agree up to the collision checkers' geometry), and
    ``cr_feasible`` with ``feasible`` (the planner's constraints vs the KS model: these may
    differ by design).  ``cr_road_compliant`` has no counterpart and is counted.  Rows without
    the checker's columns (checker absent, failed tasks) are left out."""
    rr = [r for r in rows if all(_is_bool(r.get(c)) for c in CR_COLUMNS)]
    if not rr:
        return "CommonRoad checkers: no verdicts (" + (available() or "no planned rows") + ")"

    def name(r: dict) -> str:
        return f"{r['scenario']}/ego {r['ego_id']}/t0 {r['t0']}/{r['method']}"

    coll = [r for r in rr if r["cr_collision_free"] == bool(r.get("any_collision"))]
    feas = [r for r in rr if r["cr_feasible"] != bool(r.get("feasible"))]
    off = [r for r in rr if not r["cr_road_compliant"]]
    lines = [
        f"CommonRoad checkers on {len(rr)} plans: {sum(r['cr_collision_free'] for r in rr)} "
        f"collision-free, {len(rr) - len(off)} road-compliant, "
        f"{sum(r['cr_feasible'] for r in rr)} feasible ({VEHICLE_MODEL}, {VEHICLE_TYPE})",
        f"  collision (checker vs our any_collision): {len(coll)} disagree"
        + "".join(
            f"\n    {name(r)}: checker "
            f"{'collision-free' if r['cr_collision_free'] else 'collision'}, ours "
            f"{'collision' if r.get('any_collision') else 'collision-free'}"
            for r in coll
        ),
        f"  feasibility (checker's KS model vs our 'feasible'): {len(feas)} disagree"
        + "".join(
            f"\n    {name(r)}: checker {r['cr_feasible']}, ours {r.get('feasible')}" for r in feas
        ),
        f"  off the road (checker): {len(off)}" + "".join(f"\n    {name(r)}" for r in off),
    ]
    return "\n".join(lines)
