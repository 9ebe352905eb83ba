"""Receding-horizon loop (mmdopt.receding) against a small synthetic scene source.

The source is a straight two-lane road with one slower car ahead in the ego lane whose future is
bimodal (stays / moves to the left lane); the ego is moved exactly along each plan for δ seconds.
One small planner configuration is shared so the jitted planner compiles once.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import jax
import numpy as np
import pytest

import frenet
import mmdopt
from mmdopt.receding import (
    Observation,
    PlansLike,
    RecedingConfig,
    SceneSource,
    StepOutcome,
    pad_obstacles,
    run_receding,
    warm_up,
)

CFG = mmdopt.MMDOptConfig().replace(
    n_samples=80,
    n_cem=30,
    n_elite=10,
    iterations=4,
    n_brake=5,
    horizon=5.0,
    num_steps=26,
    reduced_set_size=5,
    v_des=15.0,
)
T = frenet.TimeGrid(CFG.trajectory.horizon, CFG.trajectory.num_steps).t


class TwoLaneScene:
    """Ego at 15 m/s behind a 8 m/s car; the car stays (70 %) or changes to y = 3.5 (30 %)."""

    def __init__(self, seed=0, duration=3.0, gap=35.0, crash_at=None):
        self.road = mmdopt.Road(y_lb=-0.3, y_ub=3.8, v_max=20.0)
        self.ego = frenet.EgoState(s=0.0, d=0.0, vs=15.0)
        self.obs_x, self.obs_v = gap, 8.0
        self.t = 0.0
        self.duration = duration
        self.rng = np.random.default_rng(seed)
        self.crash_at = crash_at
        self.min_gap = np.inf
        self.steps = 0

    def observe(self) -> Observation:
        n = 10
        change = self.rng.random(n) < 0.3
        y_end = np.where(change, 3.5, 0.0)
        v = self.obs_v + 0.3 * self.rng.standard_normal(n)
        x = self.obs_x + v[:, None] * T[None]
        y = y_end[:, None] * np.clip(T[None] / 3.0, 0.0, 1.0)
        obs = np.stack([x, y], axis=-1)[None]
        return Observation(ego=self.ego, road=self.road, obstacles=obs, time=self.t)

    def step(self, trajectory, dt) -> StepOutcome:
        f = {k: np.interp(dt, trajectory.t, getattr(trajectory, k)) for k in ("s", "d", "vs", "vd")}
        f.update(as_=np.interp(dt, trajectory.t, trajectory.as_))
        f.update(ad=np.interp(dt, trajectory.t, trajectory.ad))
        self.ego = frenet.EgoState(**{k: float(v) for k, v in f.items()})
        self.obs_x += self.obs_v * dt
        self.t += dt
        self.steps += 1
        gap = np.hypot(self.obs_x - self.ego.s, 0.0 - self.ego.d)
        self.min_gap = min(self.min_gap, gap)
        crashed = self.crash_at is not None and self.steps >= self.crash_at
        return StepOutcome(done=self.t >= self.duration - 1e-9, crashed=crashed)


@pytest.fixture(scope="module")
def run():
    # compile the cold and the warm-started planner first: the timed loop then sees plan times
    warm_up(TwoLaneScene().observe(), RecedingConfig(), CFG)
    src = TwoLaneScene()
    res = run_receding(
        src, RecedingConfig(dt=0.5, budget_s=60.0), config=CFG, key=jax.random.PRNGKey(3)
    )
    return src, res


def test_scene_source_satisfies_the_protocol():
    assert isinstance(TwoLaneScene(), SceneSource)


@pytest.mark.slow
def test_loop_replans_every_delta_until_the_source_is_done(run):
    src, res = run
    assert res.done and not res.crashed
    assert len(res.steps) == 6  # 3 s at δ = 0.5 s
    assert [r.time for r in res.steps] == pytest.approx(np.arange(6) * 0.5)
    assert src.ego.s > 6 * 0.5 * 5.0  # it kept moving (at least 5 m/s on average)
    # executed states are the plans' states: each record starts where the previous plan was at δ
    assert all(r.n_obstacles == 1 for r in res.steps)


def test_every_replan_after_the_first_is_warm_started(run):
    _, res = run
    assert [r.warm_started for r in res.steps] == [False] + [True] * 5
    cold = run_receding(TwoLaneScene(duration=1.0), RecedingConfig(warm_start=False), config=CFG)
    assert not any(r.warm_started for r in cold.steps)


class NewFrameAtStep2(TwoLaneScene):
    """Reports a new Frenet frame at the third observation (as a source that rebuilt its path)."""

    def observe(self) -> Observation:
        obs = super().observe()
        return dataclasses.replace(obs, frame_changed=self.steps == 2)


def test_a_new_frame_is_planned_cold():
    res = run_receding(NewFrameAtStep2(duration=2.0), RecedingConfig(), config=CFG)
    # the previous plan's warm start is in the old frame: the loop does not use it
    assert [r.warm_started for r in res.steps] == [False, True, False, True]


def test_plan_times_and_budget_are_reported(run):
    _, res = run
    pt = res.plan_times
    assert pt.shape == (6,) and np.all(pt > 0)
    assert res.n_over_budget == 0  # a 60 s budget
    s = res.summary()
    assert s["steps"] == 6 and s["over_budget"] == 0
    assert s["max_plan_s"] >= s["median_plan_s"] > 0


def test_warm_up_compiles_without_touching_the_source(run):
    src = TwoLaneScene()
    secs = warm_up(src.observe(), RecedingConfig(), CFG, jax.random.PRNGKey(0))
    assert secs > 0 and src.steps == 0 and src.t == 0.0


def test_tiny_budget_counts_every_step_over_budget():
    res = run_receding(
        TwoLaneScene(duration=1.0),
        RecedingConfig(dt=0.5, budget_s=1e-6),
        config=CFG,
        key=jax.random.PRNGKey(0),
    )
    assert res.n_over_budget == len(res.steps) == 2


def test_closed_loop_keeps_clear_of_the_slower_car(run):
    src, _ = run
    # the car ahead is 8 m/s, the ego starts at 15 m/s, 35 m behind: it must not close in
    assert src.min_gap > 8.0


def test_the_rss_shield_brakes_behind_a_close_slower_car_and_records_it(run):
    from mmdopt.safety import RSSConfig

    _, plain = run
    assert not any(r.intervened or r.shield for r in plain.steps)  # no shield: nothing checked
    assert plain.summary()["interventions"] == 0
    # 20 m behind a car 7 m/s slower: no plan that keeps driving for δ passes RSS's rule
    src = TwoLaneScene(duration=1.5, gap=20.0)
    res = run_receding(
        src,
        RecedingConfig(dt=0.5, budget_s=60.0, shield=RSSConfig()),
        config=CFG,
        key=jax.random.PRNGKey(3),
    )
    first = res.steps[0]
    assert first.intervened and "obstacle 0" in first.shield
    assert res.summary()["interventions"] >= 1
    assert src.min_gap > RSSConfig().contact  # the fallback kept it off the car


def test_same_key_same_run():
    a = run_receding(TwoLaneScene(duration=1.5), config=CFG, key=jax.random.PRNGKey(7))
    b = run_receding(TwoLaneScene(duration=1.5), config=CFG, key=jax.random.PRNGKey(7))
    for ra, rb in zip(a.steps, b.steps, strict=True):
        assert (ra.cost, ra.s, ra.d, ra.speed, ra.status) == (
            rb.cost,
            rb.s,
            rb.d,
            rb.speed,
            rb.status,
        )


class CountingPlanner:
    """A policy of the user's own (a :class:`mmdopt.receding.PlansLike`): it logs each call and
    plans with an :class:`mmdopt.Planner` underneath."""

    def __init__(self, config):
        self.config = config
        self.inner = mmdopt.Planner(config)
        self.calls: list[dict] = []

    def plan(self, ego, road, obstacles, **kw):
        self.calls.append(kw)
        return self.inner.plan(ego, road, obstacles, **kw)


def test_the_loop_drives_a_users_planner_and_plans_as_the_default_one():
    pl = CountingPlanner(CFG)
    assert isinstance(pl, PlansLike) and isinstance(mmdopt.Planner(CFG), PlansLike)
    own = run_receding(TwoLaneScene(duration=1.5), planner=pl, key=jax.random.PRNGKey(7))
    ref = run_receding(TwoLaneScene(duration=1.5), config=CFG, key=jax.random.PRNGKey(7))
    assert len(pl.calls) == len(own.steps) == len(ref.steps)
    assert all(c["method"] == "mmd" for c in pl.calls) and "warm_start" in pl.calls[-1]
    for ra, rb in zip(own.steps, ref.steps, strict=True):
        assert (ra.cost, ra.s, ra.d, ra.speed, ra.status) == (rb.cost, rb.s, rb.d, rb.speed,
                                                              rb.status)  # fmt: skip
    with pytest.raises(ValueError, match="planner"):
        run_receding(TwoLaneScene(duration=1.0), planner=object())
    with pytest.raises(ValueError, match="differs from planner.config"):
        run_receding(TwoLaneScene(duration=1.0), planner=pl, config=CFG.replace(v_des=3.0))


def test_loop_stops_when_the_source_reports_a_crash():
    res = run_receding(
        TwoLaneScene(duration=10.0, crash_at=2), config=CFG, key=jax.random.PRNGKey(0)
    )
    assert res.crashed and len(res.steps) == 2


def test_empty_road_plans_against_a_phantom():
    class Empty(TwoLaneScene):
        def observe(self):
            o = super().observe()
            return Observation(ego=o.ego, road=o.road, obstacles=np.zeros((0, 10, len(T), 2)))

    res = run_receding(Empty(duration=1.0), config=CFG, key=jax.random.PRNGKey(0))
    assert res.done and len(res.steps) == 2 and all(r.n_obstacles == 0 for r in res.steps)
    # nothing in the way: it holds v_des (15 m/s) and the phantom adds no collision cost
    assert res.steps[-1].speed == pytest.approx(15.0, abs=0.5)
    assert all(r.cost < 1.0 for r in res.steps)


def test_on_the_risk_dial_an_empty_road_reaches_the_planner_empty():
    """The loop never pads with phantoms on the risk dial (they would count in the plan's bound,
    and their few samples support no ε: every plan said ``risk floor``); an empty road is then
    the planner's own case, ``ok`` with a bound of 0.  With the time-linear margins it still
    pads to ``max_obstacles``, so the shapes stay fixed."""

    class Empty(TwoLaneScene):
        def observe(self):
            o = super().observe()
            return Observation(ego=o.ego, road=o.road, obstacles=np.zeros((0, 10, len(T), 2)))

    class Seen(CountingPlanner):
        def plan(self, ego, road, obstacles, **kw):
            self.calls.append(dict(kw, shape=np.shape(obstacles)))
            return self.inner.plan(ego, road, obstacles, **kw)

    for mode, given in (("samples", 0), ("linear", 1)):
        pl = Seen(CFG.replace(margin_mode=mode, risk=0.01))
        seen: list = []
        res = run_receding(
            Empty(duration=1.0), RecedingConfig(max_obstacles=1), planner=pl,
            key=jax.random.PRNGKey(0), callback=lambda i, obs, p, out, seen=seen: seen.append(p),
        )  # fmt: skip
        assert [c["shape"][0] for c in pl.calls] == [given, given]
        assert res.done and all(r.n_obstacles == 0 for r in res.steps)
        if mode == "samples":
            assert all(r.status == "ok" for r in res.steps), [r.status for r in res.steps]
            assert all(p.risk_bound == 0.0 for p in seen)


def test_warm_up_plans_at_each_number_of_cars_it_is_given():
    """``warm_up(..., counts=)`` compiles the shapes the loop meets on the risk dial (no phantoms:
    one shape per number of cars): it plans cold and warm at every count, the scene's cars
    repeated or cut; ``counts`` must be ints >= 1."""

    class Seen(CountingPlanner):
        def plan(self, ego, road, obstacles, **kw):
            self.calls.append(dict(kw, shape=np.shape(obstacles)))
            return self.inner.plan(ego, road, obstacles, **kw)

    pl = Seen(CFG.replace(margin_mode="samples", risk=0.05))
    warm_up(TwoLaneScene().observe(), RecedingConfig(), planner=pl, counts=range(1, 3))
    got = [(c["shape"][0], "warm_start" in c) for c in pl.calls]
    assert got == [(1, False), (1, True), (2, False), (2, True)]
    assert pl.calls[2]["shape"][1:] == pl.calls[0]["shape"][1:]  # the same futures per car
    for bad in ([0], [1.5], [True], 3):
        with pytest.raises(ValueError, match="counts"):
            warm_up(TwoLaneScene().observe(), RecedingConfig(), planner=pl, counts=bad)


def test_pad_obstacles_shapes_and_phantoms_far_behind():
    road = mmdopt.Road()
    ego = frenet.EgoState(s=100.0, d=0.0, vs=10.0)
    obs = np.zeros((2, 4, len(T), 2))
    assert pad_obstacles(obs, 5, ego, road, T).shape == (5, 4, len(T), 2)
    assert pad_obstacles(obs, 1, ego, road, T).shape == (1, 4, len(T), 2)
    ph = pad_obstacles(np.zeros((0, 4, len(T), 2)), None, ego, road, T)
    assert ph.shape == (1, 4, len(T), 2)
    assert np.all(ph[..., 0] < ego.s - 400.0 + ego.vs * T)  # stays ≥ 400 m behind
    assert len(np.unique(ph[0, :, 0, 0])) == 4  # distinct samples (positive kernel bandwidth)
    with pytest.raises(ValueError, match="obstacles must have shape"):
        pad_obstacles(np.zeros((1, 4, 3, 2)), 2, ego, road, T)


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"dt": 0.0}, "dt"),
        ({"dt": float("nan")}, "dt"),
        ({"max_steps": 0}, "max_steps"),
        ({"budget_s": -1.0}, "budget_s"),
        ({"method": "nope"}, "method"),
        ({"max_obstacles": 0}, "max_obstacles"),
    ],
)
def test_bad_receding_config_is_rejected(kw, match):
    with pytest.raises(ValueError, match=match):
        RecedingConfig(**kw)


def test_bad_arguments_are_rejected():
    with pytest.raises(ValueError, match="horizon"):
        run_receding(TwoLaneScene(), RecedingConfig(dt=6.0), config=CFG)
    with pytest.raises(ValueError, match="SceneSource"):
        run_receding(object(), config=CFG)
    with pytest.raises(ValueError, match="MMDOptConfig"):
        run_receding(TwoLaneScene(), config={"horizon": 5.0})


def test_receding_does_not_import_the_benchmarks():
    code = (
        "import sys, mmdopt.receding; print(any(m.startswith('mmdopt.bench') for m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


class ForecastScene(TwoLaneScene):
    """The same scene with the car given as a forecast of a constant-velocity predictor."""

    def __init__(self, min_samples=12, **kw):
        super().__init__(**kw)
        self.min_samples = min_samples

    def observe(self) -> Observation:
        from mmdopt.predict import GAP_NONE, ConstantVelocity, Forecast, PredictionContext

        past = np.array([-0.1, 0.0])
        history = np.stack([self.obs_x + self.obs_v * past, 0.0 * past], axis=-1)[None]
        lane = np.stack([np.linspace(-100.0, 400.0, 51), np.zeros(51)], axis=-1)[None]
        context = PredictionContext(
            times=T, dt_history=0.1, centerline=lane, lane_width=np.array([3.5]),
            has_left=np.array([True]), has_right=np.array([False]),
            gaps=np.full((1, 6), GAP_NONE), rel_speed=np.zeros((1, 6)),
        )  # fmt: skip
        fc = Forecast(ConstantVelocity(), history, context, min_samples=self.min_samples)
        return Observation(ego=self.ego, road=self.road, obstacles=fc, time=self.t)


@pytest.mark.slow
def test_a_forecast_is_drawn_as_plan_draws_it_and_the_callback_sees_the_futures():
    seen = []
    key = jax.random.PRNGKey(5)
    cfg = CFG.replace(margin_mode="linear")
    res = run_receding(
        ForecastScene(duration=1.0), RecedingConfig(dt=0.5, max_obstacles=2), config=cfg,
        key=key, callback=lambda i, obs, p, out: seen.append((obs, p)),
    )  # fmt: skip
    assert len(res.steps) == 2 and all(r.n_obstacles == 1 for r in res.steps)
    obs, p = seen[0]
    # the time-linear margins draw min_samples futures of the real car (phantoms are padded on)
    assert np.asarray(obs.obstacles).shape == (1, 12, T.shape[0], 2)
    assert p.diagnostics["forecast_samples"] == 12 and "predict_s" in obs.info
    # the loop's first plan is plan() on the forecast with the loop's key for that step (one
    # car: no phantom to pad with)
    fc = ForecastScene(duration=1.0).observe().obstacles
    alone = run_receding(
        ForecastScene(duration=0.5), RecedingConfig(dt=0.5), config=cfg, key=key,
        callback=lambda i, obs, p, out: seen.append((obs, p)),
    )  # fmt: skip
    p = seen[-1][1]
    direct = mmdopt.plan(
        obs.ego, obs.road, fc, config=cfg, key=jax.random.fold_in(key, 0),
        method=RecedingConfig().method,
    )  # fmt: skip
    assert alone.steps[0].n_obstacles == 1 and direct.diagnostics["forecast_samples"] == 12
    np.testing.assert_allclose(p.s, direct.s, atol=1e-6)
    np.testing.assert_allclose(p.d, direct.d, atol=1e-6)


@pytest.mark.slow
def test_a_forecast_in_the_samples_mode_draws_what_the_risk_level_needs():
    from mmdopt.risk import samples_for_risk

    cfg = CFG.replace(margin_mode="samples", risk=0.05)
    seen = []
    res = run_receding(
        ForecastScene(duration=0.5), RecedingConfig(dt=0.5, max_obstacles=3), config=cfg,
        key=jax.random.PRNGKey(1), callback=lambda i, obs, p, out: seen.append((obs, p)),
    )  # fmt: skip
    obs, p = seen[0]
    n = samples_for_risk(0.05, 1, hits=mmdopt.methods.get(RecedingConfig().method).risk_hits(cfg))
    assert np.asarray(obs.obstacles).shape[:2] == (1, n) and p.diagnostics["forecast_samples"] == n
    # no phantoms under the risk dial: the plan's bound is over the one real car's n futures
    assert res.steps[0].n_obstacles == 1 and p.diagnostics["n_planning_samples"] == n
    assert p.risk_bound <= 0.05 or p.status != "ok", p.status_text
    assert np.asarray(p.reduced_set.indices).shape[0] == 1  # planned against one obstacle


class TurnedCarAtRest(TwoLaneScene):
    """A car at rest 40 m ahead in the lane to the right, turned 45° towards the ego's lane:
    its nose reaches within 2.4 m of the ego's path, its centre is 4.2 m away."""

    def __init__(self, headings=True, **kw):
        super().__init__(**kw)
        self.headings = headings

    def observe(self) -> Observation:
        obs = np.broadcast_to(np.array([40.0, -4.2]), (1, 10, len(T), 2)).copy()
        heads = np.array([np.pi / 4]) if self.headings is True else self.headings
        return Observation(
            ego=self.ego, road=self.road, obstacles=obs, time=self.t, obstacle_headings=heads
        )


def test_the_loop_plans_against_the_observed_body_headings():
    body = np.full((1, 10, len(T)), np.pi / 4)
    a, b = CFG.safety.footprint.a, CFG.safety.footprint.b

    def meets(headings):
        met = []

        def record(i, obs, plan, outcome):
            cnt = mmdopt.collision.collision_free_count(
                np.stack([plan.s, plan.d], -1), obs.obstacles, a=a, b=b, obstacle_heading=body
            )
            met.append(int(np.asarray(cnt.colliding).sum()))

        run_receding(
            TurnedCarAtRest(headings=headings, duration=1.0),
            config=CFG,
            key=jax.random.PRNGKey(0),
            callback=record,
        )
        return met

    assert meets(True) == [0, 0]  # clear of the turned body in every sample, every replan
    assert max(meets(None)) == 10  # along the path (no heading of its own) it looks clear
    with pytest.raises(ValueError, match="obstacle_headings"):
        run_receding(TurnedCarAtRest(headings=np.zeros(2), duration=0.5), config=CFG)
