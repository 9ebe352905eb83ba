"""The :class:`Planner`: Algorithm 1 for one configuration, owning its workspaces and running one
plan from the samples to the assembled :class:`~mmdopt.Plan`.

One plan (:meth:`Planner.plan`), in order: the input checks (:mod:`mmdopt.validate`); the risk
mapping of the method's record (:func:`apply_risk`); the futures of a forecast
(:func:`draw_forecast`); the conversion to the road's Frenet frame; the method's selection of
the samples it plans against (:func:`mmdopt.baselines.select_for_method`); the coverage margins;
Algorithm 1 (the first pass); the risk passes (:mod:`mmdopt.schedule`); and the assembly
(:mod:`mmdopt.assemble`).  :data:`PLANNERS` is the one bounded cache of workspaces behind
:func:`mmdopt.plan`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import jax
import numpy as np
from numpy.typing import ArrayLike

import frenet
from solvers.cache import BoundedCache

from . import algorithm as alg
from . import methods as registry
from ._x64 import x64
from .algorithm import PLANNER_PROJECTOR, MMDOptConfig
from .assemble import PlanFrame, assemble, braking_fallback
from .baselines import select_for_method
from .collision import headings
from .counting import Futures, to_planes
from .padding import pad_obstacles
from .plans import Plan, PlanStatus, Road
from .predict.base import Forecast
from .risk import config_for_risk, coverage_data, samples_for_risk
from .safety import braking_plan
from .samples import ReducedSet
from .schedule import (
    Candidate,
    KeyStream,
    PassContext,
    PassName,
    coverage,
    coverage_rows,
    first_config,
    obstacle_centres,
    plan_bound,
    risk_counts,
    run_schedule,
    samples_met,
)
from .validate import (
    check_obstacle_headings,
    check_obstacles,
    check_plan_inputs,
    check_reduced_set_for,
    check_warm_start,
    resolve_projector,
)

__all__ = ["Planner", "PlannerCache", "PLANNERS", "apply_risk", "draw_forecast"]


def apply_risk(method: Any, risk: Any, config: MMDOptConfig) -> MMDOptConfig:
    """``config`` with ``method``'s mapping of the risk level ``risk`` (none when ``None``) and
    its automatic re-selection size resolved (:meth:`mmdopt.methods.PlanMethod.reselect`)."""
    rec = registry.get(method)
    if risk is not None:
        config = config_for_risk(rec, risk, config)
    if config.safety.reselect is None:  # automatic: the method's re-selection pass size
        config = config.replace(reselect=rec.reselect(config))
    return config


def draw_forecast(fc: Forecast, config: MMDOptConfig, method: Any, key) -> tuple:
    """Draw the futures of a :class:`mmdopt.predict.Forecast`: n(ε) per obstacle for the risk
    level of ``config`` (the "samples" margin mode), clipped to the forecast's bounds; returns
    the samples and the draw's diagnostics (``forecast_samples``, ``forecast_samples_needed``,
    ``forecast_s``).  ``key`` is the plan's: the draw uses its forecast stream."""
    rec = registry.get(method)
    O = fc.num_obstacles
    grid = frenet.TimeGrid(config.trajectory.horizon, config.trajectory.num_steps).t
    times = fc.context.times
    if times.shape != grid.shape or not np.allclose(times, grid, atol=1e-9):
        raise ValueError(
            f"obstacles.context.times must be the planner's grid ({config.trajectory.num_steps} "
            f"points over {config.trajectory.horizon} s), got {times.shape[0]} points over "
            f"{times[-1]:g} s"
        )
    lo = fc.min_samples
    if rec.selector is not None:
        lo = max(lo, config.selection.reduced_set_size)
    needed = None
    if config.safety.margins.margin_mode == "samples":
        eps, G, hits = float(config.safety.risk), config.bound_groups(O), rec.risk_hits(config)
        needed = samples_for_risk(eps, G, hits=hits)
        if hits > 0:  # the budget limits the futures drawn for allowed hits, never below n(ε)
            fewest = samples_for_risk(eps, G)
            needed = min(needed, max(fewest, int(config.schedule.futures_budget) // O))
    n = int(min(max(lo, needed or lo), max(fc.max_samples, lo)))
    t0 = time.perf_counter()
    k_pred = KeyStream(key).forecast()
    samples = np.asarray(fc.predictor.sample(fc.history, fc.context, n, k_pred), np.float64)
    want = (O, n, grid.shape[0], 2)
    if samples.shape != want:
        raise ValueError(
            f"obstacles.predictor.sample returned shape {samples.shape}, expected {want}"
        )
    return samples, dict(
        forecast_samples=n,
        forecast_samples_needed=needed,
        forecast_s=time.perf_counter() - t0,
    )


def _phantom(arr: np.ndarray, ego, road: Road, config: MMDOptConfig) -> np.ndarray:
    """One phantom obstacle (1, n, K, 2) for an empty road (:func:`mmdopt.padding.pad_obstacles`:
    500 m behind the ego, never met), with at least the reduced-set size of samples."""
    t = frenet.TimeGrid(config.trajectory.horizon, config.trajectory.num_steps).t
    n = max(arr.shape[1], config.selection.reduced_set_size)
    return pad_obstacles(np.zeros((0, n, t.shape[0], 2)), 1, ego, road, t)


def _selection_pool(rec, config: MMDOptConfig, n: int, keys: KeyStream) -> np.ndarray | None:
    """Sorted positions of the ``schedule.selection_pool`` samples a method with a selection
    pool selects from (the same for every obstacle; from the key stream), or ``None``: all of
    them (fewer samples, a method without a pool, or the time-linear margins)."""
    pool = int(config.schedule.selection_pool)
    if not rec.selection_pool or n <= pool or config.safety.margins.margin_mode != "samples":
        return None
    # a uniform draw without replacement, seeded by the pool's key: O(pool), not a permutation
    # of all n (at 50 000 futures that costs more than the selection itself)
    key = keys.pool()
    bits = np.asarray(jax.random.key_data(key) if jax.dtypes.issubdtype(
        key.dtype, jax.dtypes.prng_key) else key, np.uint32).ravel()  # fmt: skip
    rng = np.random.default_rng([int(b) for b in bits])
    return np.sort(rng.choice(n, pool, replace=False))


def _select(rec, config, obs_fr, ego, workspace, keys: KeyStream) -> ReducedSet:
    """The method's own selection of the samples its cost plans against (with de Groot's
    constant-velocity ego guess and the selection pool where its record asks for them)."""
    O, n, K, _ = obs_fr.shape
    ego_guess = None
    if rec.ego_guess:
        t = workspace.t()
        ego_guess = np.stack([ego.s + ego.vs * t, np.full(K, ego.d)], axis=-1)
    pool = _selection_pool(rec, config, n, keys)
    rs = select_for_method(
        rec,
        keys.selection,
        np.asarray(obs_fr if pool is None else obs_fr[:, pool], np.float64),
        config.selection.reduced_set_size,
        config.selection.reduced_set,
        lateral_scale=float(config.selection.rs_lateral_scale),
        ego_guess=ego_guess,
        footprint=config.safety.footprint,
    )
    if pool is not None:  # back to positions among all n samples
        alpha = np.zeros((O, n))
        alpha[:, pool] = np.asarray(rs.alpha)
        rs = dataclasses.replace(
            rs, indices=jax.numpy.asarray(pool[np.asarray(rs.indices)]),
            alpha=jax.numpy.asarray(alpha),
        )  # fmt: skip
    return rs


class Planner:
    """Algorithm 1 for one configuration, owning what it compiles and factorises.

    A planner keeps one :class:`mmdopt.algorithm.Workspace` (basis, planner matrix, projection
    factorisation, jitted steps) per road's bounds and static configuration it has planned
    with, at most :attr:`max_workspaces` of them (the oldest dropped first; ``workspaces``: a
    :class:`solvers.cache.BoundedCache` shared with other planners of the same static
    configuration, as :data:`PLANNERS` does).  Reuse one planner to plan many times without
    compiling again::

        planner = mmdopt.Planner(config)
        p = planner.plan(ego, road, obstacles, method="mmd", key=jax.random.PRNGKey(0))

    The same steps one at a time (the step API of :mod:`mmdopt.algorithm`; the state holds
    arrays only)::

        problem = planner.problem(ego, road)
        obstacles = mmdopt.algorithm.ObstacleSet.create(config, centres, weights, "embedding")
        state = planner.init(problem, key)
        state = planner.update(problem, state, obstacles)      # one CEM iteration
        state = planner.run(problem, obstacles, key)           # all of them, one jitted scan
        warm = planner.shift(state, dt)                        # receding horizon

    Anything with this :meth:`plan` signature drives the receding loop
    (:class:`mmdopt.receding.PlansLike`).
    """

    max_workspaces = 8

    def __init__(
        self, config: MMDOptConfig | None = None, *, workspaces: BoundedCache | None = None
    ) -> None:
        config = MMDOptConfig() if config is None else config
        if not isinstance(config, MMDOptConfig):
            raise ValueError(f"config must be an mmdopt.MMDOptConfig, got {type(config).__name__}")
        if workspaces is not None and not isinstance(workspaces, BoundedCache):
            raise ValueError(
                f"workspaces must be a solvers.cache.BoundedCache, got {type(workspaces).__name__}"
            )
        self.config = config
        self._workspaces = BoundedCache(self.max_workspaces) if workspaces is None else workspaces

    def __repr__(self) -> str:
        return f"Planner({len(self._workspaces)} workspace(s))"

    def workspace(
        self, bounds: frenet.ProjectionBounds | tuple, config: MMDOptConfig | None = None
    ) -> alg.Workspace:
        """The workspace of ``config`` (default: the planner's) and the projection ``bounds``
        (a :class:`frenet.ProjectionBounds` or its :func:`mmdopt.algorithm.bounds_key`), built
        on first use."""
        cfg = self.config if config is None else config
        bkey = bounds if isinstance(bounds, tuple) else alg.bounds_key(bounds)

        def build() -> alg.Workspace:
            b = alg.bounds_from_key(bkey) if isinstance(bounds, tuple) else bounds
            return alg.Workspace(cfg, b)

        return self._workspaces.get_or_create((alg.statics(cfg), bkey), build)

    # ------------------------------------------------------------------------------ step API
    def problem(self, ego: frenet.EgoState, road: Road) -> alg.Problem:
        """The planning problem of ``ego`` on ``road`` (:meth:`mmdopt.algorithm.Problem.create`)."""
        if not isinstance(road, Road):
            raise ValueError(f"road must be an mmdopt.Road, got {type(road).__name__}")
        return alg.Problem.create(self.config, ego, road.bounds(), lanes=road.lane_centres)

    def _ws(self, problem: Any) -> alg.Workspace:
        if not isinstance(problem, alg.Problem):
            raise ValueError(f"problem must be an algorithm.Problem, got {type(problem).__name__}")
        return self.workspace(problem.bounds)

    def init(
        self, problem: alg.Problem, key: Any, warm_start: alg.CEMState | None = None
    ) -> alg.CEMState:
        """:func:`mmdopt.algorithm.init` with this planner's config and workspace."""
        return alg.init(self._ws(problem), self.config, problem, key, warm_start)

    def update(
        self,
        problem: alg.Problem,
        state: alg.CEMState,
        obstacles: alg.ObstacleSet,
        projector: str = PLANNER_PROJECTOR,
        **projector_settings: Any,
    ) -> alg.CEMState:
        """One CEM iteration (:func:`mmdopt.algorithm.update`)."""
        ws = self._ws(problem)
        return alg.update(
            ws, self.config, problem, state, obstacles, projector, **projector_settings
        )

    def run(
        self,
        problem: alg.Problem,
        obstacles: alg.ObstacleSet,
        key: Any,
        projector: str = PLANNER_PROJECTOR,
        warm_start: alg.CEMState | None = None,
        **projector_settings: Any,
    ) -> alg.CEMState:
        """Every iteration (:func:`mmdopt.algorithm.run`)."""
        ws = self._ws(problem)
        return alg.run(
            ws, self.config, problem, obstacles, key, projector, warm_start, **projector_settings
        )

    def shift(self, state: alg.CEMState, dt: float) -> alg.CEMState:
        """The warm start ``dt`` seconds later (:func:`mmdopt.algorithm.shift`)."""
        return alg.shift(self.config, state, dt)

    # ---------------------------------------------------------------------------------- plan
    @x64
    def plan(
        self,
        ego: frenet.EgoState,
        road: Road,
        obstacles: ArrayLike,
        *,
        method: str = "mmd",
        projector: str = PLANNER_PROJECTOR,
        key: ArrayLike | None = None,
        reduced_set: ReducedSet | None = None,
        warm_start: alg.CEMState | None = None,
        risk: float | None = None,
        obstacle_headings: ArrayLike | None = None,
        backend: str | None = None,
        **projector_settings: Any,
    ) -> Plan:
        """:func:`mmdopt.plan` with this planner's config."""
        return self._plan(
            ego, road, obstacles, method, resolve_projector(projector, backend), key,
            reduced_set, warm_start, risk, projector_settings, False, obstacle_headings,
        )  # fmt: skip

    @x64
    def plan_frenet(
        self,
        ego: frenet.EgoState,
        road: Road,
        obstacles_frenet: ArrayLike,
        *,
        method: str = "mmd",
        projector: str = PLANNER_PROJECTOR,
        key: ArrayLike | None = None,
        reduced_set: ReducedSet | None = None,
        warm_start: alg.CEMState | None = None,
        risk: float | None = None,
        obstacle_headings: ArrayLike | None = None,
        backend: str | None = None,
        **projector_settings: Any,
    ) -> Plan:
        """:func:`mmdopt.plan_frenet` with this planner's config."""
        return self._plan(
            ego, road, obstacles_frenet, method, resolve_projector(projector, backend), key,
            reduced_set, warm_start, risk, projector_settings, True, obstacle_headings,
        )  # fmt: skip

    def _plan(
        self, ego, road, obstacles, method, projector, key, reduced_set, warm_start, risk,
        projector_settings, frenet_frame: bool, obstacle_headings=None,
    ) -> Plan:  # fmt: skip
        t0 = time.perf_counter()
        key = jax.random.PRNGKey(0) if key is None else key
        config = self.config
        rec = check_plan_inputs(ego, road, method, config, projector, key)
        config = apply_risk(rec, risk, config)
        alg.check_backend(projector, projector_settings)
        forecast_diag: dict[str, Any] = {}
        if isinstance(obstacles, Forecast):
            obstacles, forecast_diag = draw_forecast(obstacles, config, rec, key)
            # the predictor's draw is timed apart (Plan.predict_time_s): plan_time_s is the
            # planner's own part
            t0 += forecast_diag["forecast_s"]
        name = "obstacles_frenet" if frenet_frame else "obstacles"
        arr = check_obstacles(obstacles, config, rec, name, allow_empty=True)
        empty = arr.shape[0] == 0
        if empty:  # an empty road: one phantom far behind keeps Algorithm 1's shapes
            if reduced_set is not None or obstacle_headings is not None:
                raise ValueError(
                    "reduced_set and obstacle_headings need obstacles: the road is empty (O = 0)"
                )
            arr = _phantom(arr, ego, road, config)
            frenet_frame = False
        # plan in arc length relative to the ego (float32 keeps ~1e-6 relative precision:
        # absolute arc lengths of kilometres would cost millimetres); shifted back in assembly.
        # The samples are stored once, as the planes every count reads in place (float32,
        # mmdopt.counting); the rest reads small gathers of them in float64
        s_off = float(ego.s)
        t1 = time.perf_counter()
        if frenet_frame:
            planes = to_planes(arr, lambda b: (b[..., 0] - s_off, b[..., 1]))
        else:
            affine = road.path.frenet_affine(s_off)  # a straight road: one product per block
            if affine is not None:
                planes = to_planes(arr, affine=affine)
            else:
                planes = to_planes(
                    arr, lambda b: road.path.to_frenet_points(b, s_off, tol=frenet.FLOAT32_TOL)
                )
            if not math.isfinite(float(planes.max())) or not math.isfinite(float(planes.min())):
                raise ValueError(
                    "obstacles could not be converted to the road's Frenet frame (non-finite)"
                )
        obs_fr = planes.transpose(0, 3, 2, 1)  # (O, n, K, 2): a view of the count's layout
        diag: dict[str, Any] = {
            "frenet_conversion_s": 0.0 if frenet_frame else time.perf_counter() - t1
        }
        diag.update(forecast_diag, empty_road=empty)
        h0 = None
        if obstacle_headings is not None:
            h0 = check_obstacle_headings(obstacle_headings, obs_fr.shape[0])
            if not frenet_frame:  # relative to the path's tangent where each obstacle starts
                h0 = h0 - np.asarray(road.path.heading(obs_fr[:, 0, 0, 0] + s_off), np.float64)
        return self._plan_samples(
            ego, road, planes, s_off, rec, config, projector, key, projector_settings, t0,
            diag, reduced_set, warm_start, h0,
        )  # fmt: skip

    def _plan_samples(
        self, ego, road, planes, s_off, rec, config, projector, key, projector_settings, t0,
        diag, rs, warm_start, h0=None,
    ) -> Plan:  # fmt: skip
        """The plan from checked Frenet samples, the planes ``planes`` (O, 2, K, n) float32 in
        the planning frame (arc length relative to the ego at ``s_off``): selection, margins,
        Algorithm 1, the risk passes and the assembly."""
        ego = dataclasses.replace(ego, s=0.0)
        obs_fr = planes.transpose(0, 3, 2, 1)  # (O, n, K, 2), a view
        O, n, K, _ = obs_fr.shape
        # a body heading given for each obstacle holds before (and without) motion of its own
        obs_h = None if h0 is None else np.asarray(headings(obs_fr, h0[:, None]), np.float64)
        futures = Futures(planes, obs_h)
        if warm_start is not None:
            check_warm_start(warm_start, config)
        ws = self.workspace(road.bounds(), config)
        keys = KeyStream(key)
        t1 = time.perf_counter()
        if rs is not None:
            rs = check_reduced_set_for(rs, O, n, rec)
        else:
            rs = _select(rec, config, obs_fr, ego, ws, keys)
        diag["reduced_set_s"] = time.perf_counter() - t1
        idx0 = np.asarray(rs.indices)
        margins = cdata = None
        if config.safety.margins.margin_mode == "samples":
            t3 = time.perf_counter()
            cdata = coverage_data(obs_fr, float(config.selection.rs_lateral_scale),
                                  coverage_rows(config, n))  # fmt: skip
            knn = 0
            if rec.all_samples:
                knn = config.safety.margins.coverage_knn
                if knn is None:  # automatic: the samples a reduced-set point stands for
                    knn = max(2, n // config.selection.reduced_set_size)
            margins = coverage(config, obs_fr, idx0, knn=knn, data=cdata)
            diag["margins_s"] = time.perf_counter() - t3
        obstacles = alg.ObstacleSet.create(
            config, obstacle_centres(obs_fr, obs_h, rs.indices), np.asarray(rs.weights, np.float64),
            rec.collision, margins=margins,
        )  # fmt: skip
        frame = PlanFrame(ego, road, config, ws, rec, projector, rs, t0, s_off, obs_fr, obs_h,
                          empty=bool(diag.get("empty_road", False)), futures=futures)  # fmt: skip
        try:  # an infeasible initial state: braking profile, flagged
            ws.projection.check_state(ego)
        except ValueError as exc:
            return braking_fallback(frame, str(exc), obstacles, diag)
        t2 = time.perf_counter()
        problem = alg.Problem.create(config, ego, road.bounds(), lanes=road.lane_centres)
        ctx = PassContext(
            ws, config, rec, problem, obs_fr, obs_h, rs, projector, projector_settings, keys,
            lambda cfg: self.workspace(road.bounds(), cfg), cdata, futures,
        )  # fmt: skip
        cfg1 = first_config(config, rec, n, O)  # with the nearest pass: the iterations split
        state1 = ctx.run(obstacles, keys.cem, warm_start, config=None if cfg1 is config else cfg1)
        first = Candidate(PassName.FIRST, state1, obstacles, idx0)
        result = run_schedule(ctx, first, diag)
        diag["cem_s"] = time.perf_counter() - t2
        state = result.chosen.state
        best, lv = state.best, state.least_violating
        if not math.isfinite(float(best.cost)) or float(best.cost) >= 1e29:
            why = (
                f"the cost is not finite (best {float(best.cost):.3g}: NaN/inf in the cost "
                "terms); braking plan returned"
            )
            return braking_fallback(frame, why, result.reduced, diag, state)
        status, chosen = (PlanStatus.OK, ""), best
        if not float(lv.res) <= float(config.projection.res_tol):
            chosen = lv
            status = (PlanStatus.FALLBACK, (
                f"no sample met the constraints (least residual {float(lv.res):.3g} > res_tol "
                f"{float(config.projection.res_tol):g}); least-violating plan returned"
            ))  # fmt: skip
        plan = assemble(
            frame,
            np.asarray(chosen.cx, np.float64),
            np.asarray(chosen.cy, np.float64),
            # the set-points the Frenet planner followed (lane centres with lane_setpoints)
            np.asarray(alg.lane_inputs(config, chosen.d[None], problem.lanes, problem.state)[0]),
            float(chosen.cost),
            int(chosen.iteration),
            status,
            state,
            result.reduced,
            diag,
            result.met,
        )
        if plan.status is PlanStatus.UNSAFE and config.safety.unsafe_brake is not None:
            return _brake_if_safer(plan, frame)
        return plan


def _brake_if_safer(plan: Plan, frame: PlanFrame) -> Plan:
    """``plan`` (status UNSAFE) or, where the planning futures give it the lower risk bound
    (:func:`mmdopt.schedule.plan_bound`: the joint futures met, or each obstacle's samples with
    ``joint_futures = False``), the stop at ``safety.unsafe_brake`` m/s²
    (:func:`mmdopt.safety.braking_plan`, status FALLBACK): braking is the way out of a car
    ahead, not of one that runs into the ego from behind."""
    config = frame.config
    brake = float(config.safety.unsafe_brake)
    why = f"{plan.message}; braking at {brake:g} m/s² to a stop returned (unsafe_brake)"
    stop = braking_plan(plan, frame.road.path, brake, reason=why)
    s = np.stack([plan.s, stop.s]) - frame.s_offset  # the planning frame: the ego at s = 0
    met = samples_met(config, frame.obs_fr, frame.obs_h, s, np.stack([plan.d, stop.d]),
                      futures=frame.futures)  # fmt: skip
    diag = {"unsafe_brake_met": tuple(int(risk_counts(config, m).sum()) for m in met)}
    if plan_bound(config, met[1]) < plan_bound(config, met[0]):
        return dataclasses.replace(stop, diagnostics={**stop.diagnostics, **diag})
    return dataclasses.replace(plan, diagnostics={**plan.diagnostics, **diag})


class PlannerCache:
    """The one cache behind :func:`mmdopt.plan` and :func:`mmdopt.plan_frenet`: one pool of
    workspaces (a :class:`solvers.cache.BoundedCache`, the policy every cache of the toolkit
    follows) per static configuration (sizes, modes, rules: what changes the compiled program),
    at most :attr:`maxsize` pools, the oldest dropped first.  :meth:`get` returns a
    :class:`Planner` that owns the caller's config and shares that pool, so configs that differ
    only in their tunable scalars do not compile again.  Use your own :class:`Planner` to control
    what stays alive; :meth:`clear` frees the cached pools."""

    maxsize = 8

    def __init__(self) -> None:
        self._pools: BoundedCache = BoundedCache(self.maxsize)

    def get(self, config: MMDOptConfig | None) -> Planner:
        """A :class:`Planner` of ``config`` (default ``MMDOptConfig()``) on its shared pool."""
        config = MMDOptConfig() if config is None else config
        if not isinstance(config, MMDOptConfig):
            raise ValueError(f"config must be an mmdopt.MMDOptConfig, got {type(config).__name__}")
        pool = self._pools.get_or_create(
            alg.statics(config), lambda: BoundedCache(Planner.max_workspaces)
        )
        return Planner(config, workspaces=pool)

    def __len__(self) -> int:
        return len(self._pools)

    def clear(self) -> None:
        self._pools.clear()


#: the workspaces of :func:`mmdopt.plan` (:class:`PlannerCache`; with the method registry, the
#: method's only mutable module state)
PLANNERS = PlannerCache()
