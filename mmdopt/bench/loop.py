"""The journal version's receding-horizon runs: the ego drives through a synthetic scene family in
the loop (MMD-OPT, arXiv 2412.09121, ``main_mpc_dynamic.py``; ``mmdopt bench receding``).

A :class:`SceneLoop` is a :class:`mmdopt.receding.SceneSource` made of one scene of a family
(:mod:`mmdopt.bench.scenes`):

- **the real traffic** is one joint future of the scene's obstacles, drawn from the scene's own
  generator with a stream of its own (``role`` 5, independent of the planning, validation and
  forecast streams): each obstacle drives to the intent and speed set-point it drew at t = 0, or,
  in a static family, stands at the position it drew;
- **the predictions** at each replan are the scene's model applied from the obstacles' *current*
  states (position, velocity and acceleration of the real traffic at that time, by central
  differences on the scene's grid): every future draws its intent and set-point afresh, as the
  journal's MPC regenerates its obstacle samples at each step.  A static family's predictions
  are its position noise around the nominal start, at every step.  They are a
  :class:`mmdopt.predict.Forecast`, so a plan at risk level ε draws the n(ε) futures it needs;
- **the ego** executes the first δ seconds of each plan exactly (:meth:`mmdopt.Plan.ego_at`);
- **a collision** is the metric's (:func:`mmdopt.collision.collision_free_count`: the family's
  ellipse around the real obstacles' circles) at any planner grid point of the executed part.

One episode lasts ``duration_s`` (≤ the scenes' 15 s horizon, where the real traffic is known).
Its row (:func:`run_episode`) has the metrics of ``bench highway``: ``crashed``, ``crash_time_s``,
``progress_m``, ``mean_speed``, ``steps``, ``median_plan_s``, ``max_plan_s``, ``over_budget``,
plus the share of replans whose status is ``ok`` and their largest ``risk_bound``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .scenes import (
    HORIZON_S,
    NUM_STEPS,
    STREAMS_PER_OBSTACLE,
    Scene,
    ScenePredictor,
    forecast_inputs,
    sample_obstacles,
    scene_rngs,
)

__all__ = ["ROLE_TRUTH", "SceneLoop", "LOOP_COLUMNS", "run_episode", "summarise_episodes"]

#: the random stream of the real traffic (after the scenes' roles 0–4)
ROLE_TRUTH = 5
#: the columns of ``receding.csv``, in order
LOOP_COLUMNS = (
    "scene", "method", "risk", "obstacles", "crashed", "crash_time_s", "progress_m", "mean_speed",
    "steps", "ok_share", "max_risk_bound", "median_plan_s", "max_plan_s", "over_budget",
    "compile_s", "seed", "preset",
)  # fmt: skip


def _states(xy: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(O, K, 6) states ``(x, y, vx, vy, ax, ay)`` of trajectories ``xy`` (O, K, 2) on grid ``t``
    (second-order central differences, one-sided at the ends)."""
    v = np.gradient(xy, t, axis=1)
    a = np.gradient(v, t, axis=1)
    return np.concatenate([xy, v, a], axis=-1)


@dataclass
class SceneLoop:
    """One synthetic scene as a receding-horizon world (see the module docstring).

    scene : the scene (any family, any number of obstacles)
    duration_s : the episode's length (s, ≤ 15: the real traffic is known over the horizon)
    min_samples, max_samples : the Forecast's range of futures per obstacle
    """

    scene: Scene
    duration_s: float = 10.0
    min_samples: int = 100
    max_samples: int = 5000
    time: float = field(default=0.0, init=False)
    ego: Any = field(default=None, init=False)
    crashed: bool = field(default=False, init=False)
    crash_time: float = field(default=math.nan, init=False)
    speeds: list = field(default_factory=list, init=False)

    def __post_init__(self) -> None:
        if not (isinstance(self.duration_s, int | float) and 0 < self.duration_s <= HORIZON_S):
            raise ValueError(f"duration_s must be in (0, {HORIZON_S:g}] s, got {self.duration_s!r}")
        sc = self.scene
        self.ego = sc.ego()
        self.t = np.linspace(0.0, HORIZON_S, NUM_STEPS)
        lay, probs = sc.layout, sc.obstacle_intent_probs
        rngs = scene_rngs(sc.seed, sc.index, ROLE_TRUTH, STREAMS_PER_OBSTACLE * len(lay.x0))
        truth, _, _ = sample_obstacles(rngs, sc.params, lay, probs, 1)
        self.truth = truth[:, 0]  # (O, K, 2)
        self.truth_states = _states(self.truth, self.t)

    # ------------------------------------------------------------------ the SceneSource protocol
    def observe(self):
        from mmdopt.predict import Forecast
        from mmdopt.receding import Observation

        sc = self.scene
        O = self.truth.shape[0]
        now = np.stack([[np.interp(self.time, self.t, self.truth_states[o, :, i])
                         for i in range(6)] for o in range(O)])  # fmt: skip
        static = sc.params.motion == "static"
        pred = ScenePredictor(
            sc.params, sc.x0, sc.y0, sc.intent_probs, layout=sc.layout,
            obstacle_probs=sc.obstacle_intent_probs, states=None if static else now,
        )  # fmt: skip
        hist, ctx = forecast_inputs(now[:, :2], now[:, 2:4], self.t,
                                    len(sc.params.intent_offsets) > 1)  # fmt: skip
        fc = Forecast(pred, hist, ctx, self.min_samples, self.max_samples)
        return Observation(ego=self.ego, road=sc.road(), obstacles=fc, time=self.time)

    def step(self, trajectory, dt: float):
        from mmdopt.collision import ELLIPSE_A, ELLIPSE_B, OBSTACLE_FOOTPRINT, collision_free_count
        from mmdopt.receding import StepOutcome

        dt = min(float(dt), self.duration_s - self.time)
        # the executed part on the plan's grid, at the real traffic's positions then
        tp = np.asarray(trajectory.t, dtype=np.float64)
        k = tp <= dt + 1e-9
        ego_xy = np.stack([np.asarray(trajectory.x)[k], np.asarray(trajectory.y)[k]], -1)
        when = self.time + tp[k]
        real = np.stack([np.stack([np.interp(when, self.t, self.truth[o, :, i]) for i in (0, 1)],
                                  -1) for o in range(self.truth.shape[0])])  # fmt: skip
        a, b = self.scene.params.footprint or (ELLIPSE_A, ELLIPSE_B)
        hit = collision_free_count(ego_xy, real[:, None], OBSTACLE_FOOTPRINT, a=a, b=b).joint == 0
        self.speeds.extend(np.asarray(trajectory.speed)[k][:-1].tolist() or [self.ego.vs])
        if hit and not self.crashed:
            self.crashed, self.crash_time = True, float(self.time)
        self.ego = trajectory.ego_at(dt)
        self.time += dt
        done = self.crashed or self.time >= self.duration_s - 1e-9
        return StepOutcome(done=done, crashed=bool(hit))


def run_episode(
    scene: Scene,
    method: str,
    risk: float,
    *,
    config=None,
    dt: float = 0.5,
    duration_s: float = 10.0,
    budget_s: float = 0.1,
    backend: str | None = None,
) -> dict[str, Any]:
    """Drive one scene with ``method`` at risk level ``risk`` in the receding loop; its row
    (:data:`LOOP_COLUMNS`).  ``config``: the planner's base config (default ``MMDOptConfig()``),
    with the scene's desired speed and footprint (:func:`~mmdopt.bench.synthetic.scene_config`)
    and the method's settings for ``risk``; plan time is reported beside every figure, the
    compile apart (a first plan of the first step before the loop)."""
    import jax

    import mmdopt
    from mmdopt.receding import RecedingConfig, run_receding

    from .synthetic import forecast_cap, scene_config

    cfg = mmdopt.config_for_risk(method, risk, scene_config(scene, config))
    loop = SceneLoop(scene, duration_s=duration_s, max_samples=forecast_cap(method))
    kw = {} if backend is None else {"projector": backend}
    rc = RecedingConfig(dt=dt, budget_s=budget_s, method=method, **kw)
    # the compile, apart: one plan of the first observation (same shapes as the loop's)
    first = mmdopt.plan(loop.ego, scene.road(), loop.observe().obstacles, method=method,
                        config=cfg, key=jax.random.PRNGKey(1), **kw)  # fmt: skip
    statuses: list[str] = []
    bounds: list[float] = []

    def record(i, obs, plan, outcome):
        statuses.append(str(plan.status))
        bounds.append(float(plan.risk_bound))

    res = run_receding(loop, rc, config=cfg, key=scene.key(), callback=record)
    times = res.plan_times
    return dict(
        scene=scene.index,
        method=method,
        risk=float(risk),
        obstacles=scene.num_obstacles,
        crashed=bool(loop.crashed),
        crash_time_s=loop.crash_time,
        progress_m=float(loop.ego.s - scene.ego().s),
        mean_speed=float(np.mean(loop.speeds)) if loop.speeds else math.nan,
        steps=len(res.steps),
        ok_share=float(np.mean([s == "ok" for s in statuses])) if statuses else math.nan,
        max_risk_bound=float(np.nanmax(bounds)) if np.isfinite(bounds).any() else math.nan,
        median_plan_s=float(np.median(times)) if times.size else math.nan,
        max_plan_s=float(times.max()) if times.size else math.nan,
        over_budget=res.n_over_budget,
        compile_s=max(
            0.0, float(first.plan_time_s) - (float(np.median(times)) if times.size else 0.0)
        ),  # fmt: skip
        seed=scene.seed,
        preset="",
    )


def summarise_episodes(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (method, ε): episodes, crashes, mean progress and speed, median plan time, the share
    of ``ok`` replans."""
    out = []
    keys = sorted({(r["method"], r["risk"]) for r in rows}, key=lambda k: (k[0], -k[1]))
    for m, eps in keys:
        rs = [r for r in rows if r["method"] == m and r["risk"] == eps]
        out.append(dict(
            method=m, risk=eps, episodes=len(rs), crashes=sum(bool(r["crashed"]) for r in rs),
            progress_m=float(np.mean([r["progress_m"] for r in rs])),
            mean_speed=float(np.mean([r["mean_speed"] for r in rs])),
            median_plan_s=float(np.median([r["median_plan_s"] for r in rs])),
            ok_share=float(np.mean([r["ok_share"] for r in rs])),
        ))  # fmt: skip
    return out
