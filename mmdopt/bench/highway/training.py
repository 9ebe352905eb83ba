"""Training and evaluation data of the learned highway predictor: highway-env rollouts.

Each rollout resets a highway-env environment (the benchmark's environment settings:
``simulation_frequency`` 10 Hz, so a simulator frame is 0.1 s, the MDN's history spacing) and
replaces the ego by highway-env's own IDM/MOBIL driver (:class:`~highway_env.vehicle.behavior
.IDMVehicle`, desired speed its initial speed), then steps the road frame by frame and records every
vehicle's position, speed and lane.  Every ``stride`` frames, the vehicles recorded over the
whole history (``history`` rows) and the horizon (the planner's 5 s, 51 points at 0.1 s) make a
:class:`~mmdopt.predict.train.Window`, with a :class:`~mmdopt.predict.PredictionContext` built
from the lane network (:func:`~.context.scene_context`: each vehicle's lane centre line, followed
along the network while it continues the lane, is its centerline).

Seeds.  Training rollouts use seeds ``TRAIN_SEED0 + i`` (100000, 100001, ...); the benchmark's
episodes (``mmdopt bench highway --seed S --episodes N``) and the held-out evaluation use seeds
below 100000 (the evaluation: 0 … 9), so no training episode is an evaluation episode.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mmdopt.predict.train import Window

from .context import lane_centerline, scene_context
from .predictors import TRACK_FRAMES, ConstantVelocityPredictor, LearnedPredictor, tracked_velocity
from .settings import require_highway

__all__ = [
    "TRAIN_SEED0",
    "TRAINING_ENVS",
    "Rollout",
    "calibrate_cv_lateral",
    "cv_lateral_errors",
    "coverage",
    "evaluate_heldout",
    "evaluate_live",
    "highway_windows",
    "lane_centerline",
    "rollout",
    "rollout_windows",
    "scene_context",
]

#: the first training seed; the benchmark's episodes and the evaluation use seeds below it
TRAIN_SEED0 = 100_000
#: (highway-env id, extra configuration, episodes per requested episode) of the training and
#: evaluation traffic: highway-v0 at its default density and at ``vehicles_density`` 2 (50 cars
#: each), and merge-v0 (5 cars, so four times as many episodes)
TRAINING_ENVS: tuple[tuple[str, dict, int], ...] = (
    ("highway-v0", {}, 1),
    ("highway-v0", {"vehicles_density": 2}, 1),
    ("merge-v0", {}, 4),
)


# ------------------------------------------------------------------------------ rollouts
@dataclass(frozen=True, eq=False)
class Rollout:
    """One recorded highway-env episode: ``xy`` (N, T, 2) positions, ``speed`` (N, T), ``lane``
    (T lists of N lane indices) at the frames ``t = k·dt``; ``ego`` the ego's row; ``network``
    the road's lanes."""

    env: str
    seed: int
    ego: int
    dt: float
    xy: np.ndarray
    speed: np.ndarray
    lane: list
    network: object


def rollout(
    env: str,
    seed: int,
    duration: float = 30.0,
    env_config: dict | None = None,
    simulation_frequency: int = 10,
    on_frame=None,
) -> Rollout:
    """Reset ``env`` with ``seed`` (the benchmark's configuration plus ``env_config``), make
    the ego an IDM/MOBIL driver and record ``duration`` s of traffic at every simulator frame;
    ``on_frame(k, road, ego, cars)``, if given, is called after frame ``k`` is recorded
    (``cars``: the vehicles in the order of the recorded rows)."""
    if not (isinstance(duration, int | float) and duration > 0):
        raise ValueError(f"duration must be > 0 s, got {duration!r}")
    if isinstance(simulation_frequency, bool) or not isinstance(simulation_frequency, int):
        raise ValueError(f"simulation_frequency must be an int (Hz), got {simulation_frequency!r}")
    gym = require_highway()
    from highway_env.vehicle.behavior import IDMVehicle

    e = gym.make(env).unwrapped
    cfg = {"simulation_frequency": simulation_frequency, "policy_frequency": 2}
    cfg["duration"] = float(duration)
    cfg.update(env_config or {})
    e.configure(cfg)
    e.reset(seed=int(seed))
    road, old = e.road, e.vehicle
    ego = IDMVehicle(road, old.position.copy(), old.heading, old.speed)
    road.vehicles[road.vehicles.index(old)] = ego
    cars = list(road.vehicles)
    dt = 1.0 / simulation_frequency
    T = int(round(duration / dt)) + 1
    xy, speed, lanes = np.empty((len(cars), T, 2)), np.empty((len(cars), T)), []
    for k in range(T):
        if k:
            road.act()
            road.step(dt)
        xy[:, k] = [c.position for c in cars]
        speed[:, k] = [c.speed for c in cars]
        lanes.append([c.lane_index for c in cars])
        if on_frame is not None:
            on_frame(k, road, ego, cars)
    e.close()
    return Rollout(env, int(seed), cars.index(ego), dt, xy, speed, lanes, road.network)


def rollout_windows(
    rec: Rollout, times, *, history: int = 10, stride: int = 5, max_obstacles: int | None = None
) -> list[Window]:
    """Windows every ``stride`` frames of ``rec``: the vehicles (all, the ego included, or the
    ``max_obstacles`` nearest to the ego, the ego excluded) with ``history`` rows before and the
    recorded future at ``times`` (s, on the frame grid)."""
    times = np.asarray(times, np.float64)
    K = int(round(times[-1] / rec.dt))
    frames = np.rint(times / rec.dt).astype(int)
    if np.any(np.abs(frames * rec.dt - times) > 1e-6):
        raise ValueError("times must lie on the rollout's frame grid")
    N, T = rec.xy.shape[:2]
    out = []
    for k in range(history - 1, T - K, stride):
        idx = np.arange(N)
        if max_obstacles is not None:
            dist = np.linalg.norm(rec.xy[:, k] - rec.xy[rec.ego, k], axis=-1)
            dist[rec.ego] = np.inf
            idx = np.argsort(dist)[:max_obstacles]
            idx = idx[np.isfinite(dist[idx])]
        ctx = scene_context(
            rec.network, rec.lane[k], rec.xy[:, k], rec.speed[:, k], idx, times, rec.dt
        )
        out.append(
            Window(
                history=rec.xy[idx, k - history + 1 : k + 1],
                context=ctx,
                future=rec.xy[idx][:, k + frames],
                scene=f"{rec.env}/{rec.seed}",
                t0=k * rec.dt,
            )
        )
    return out


def highway_windows(
    episodes: int,
    times,
    *,
    envs=TRAINING_ENVS,
    duration: float = 30.0,
    history: int = 10,
    stride: int = 5,
    max_obstacles: int | None = None,
    seed0: int = TRAIN_SEED0,
) -> list[Window]:
    """:func:`rollout_windows` of ``episodes`` × (the environment's factor) rollouts of every
    environment of ``envs``, seeds ``seed0, seed0 + 1, ...`` (the training seeds by default)."""
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be an int >= 1, got {episodes!r}")
    out: list[Window] = []
    for env, extra, factor in envs:
        for seed in range(seed0, seed0 + episodes * factor):
            rec = rollout(env, seed, duration, extra)
            out += rollout_windows(
                rec, times, history=history, stride=stride, max_obstacles=max_obstacles
            )
    return out


# ------------------------------------------------------------------------------ cv calibration
#: the lateral deviation (m) at which a highway-env car's body crosses its lane's marking:
#: (lane width 4 m − car width 2 m) / 2
MARKING_DEVIATION = 1.0


def _check_times(times) -> np.ndarray:
    """``times`` as a non-empty 1-D float array of finite times > 0 s, else ``ValueError``."""
    t = np.asarray(times, np.float64)
    if t.ndim != 1 or t.size == 0 or not np.all(np.isfinite(t)) or t.min() <= 0:
        raise ValueError(f"times must be a non-empty 1-D array of times > 0 s, got {times!r}")
    return t


def cv_lateral_errors(
    env: str = "highway-v0",
    seeds=range(TRAIN_SEED0, TRAIN_SEED0 + 8),
    *,
    env_config: dict | None = None,
    duration: float = 40.0,
    max_obstacles: int = 6,
    stride: int = 10,
    times=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Lateral errors of constant-velocity extrapolation in highway-env rollouts
    (:func:`rollout`, the ego an IDM/MOBIL driver; training seeds by default): every ``stride``
    frames, for the ``max_obstacles`` cars nearest to the ego, the recorded position at each of
    ``times`` (s, default every 0.5 s up to the planner's 5 s) minus the position its observed
    velocity extrapolates (:func:`~.predictors.tracked_velocity` of the recorded frames, as
    :class:`~.predictors.ConstantVelocityPredictor` observes it), across its lane's direction
    at the start.  Returns ``(times (K,), errors (M, K))``, one row per car and start."""
    if times is None:
        times = np.arange(1, 11) * 0.5
    times = _check_times(times)
    if isinstance(max_obstacles, bool) or not isinstance(max_obstacles, int) or max_obstacles < 1:
        raise ValueError(f"max_obstacles must be an int >= 1, got {max_obstacles!r}")
    if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
        raise ValueError(f"stride must be an int >= 1, got {stride!r}")
    rows = []
    for seed in seeds:
        starts = []  # (frame, rows, position, velocity, lane normal)

        def on_frame(k, road, ego, cars, starts=starts):
            if k % stride:
                return
            d = np.array([np.linalg.norm(c.position - ego.position) for c in cars])
            d[cars.index(ego)] = np.inf
            idx = [int(r) for r in np.argsort(d)[:max_obstacles] if np.isfinite(d[r])]
            normal = []
            for r in idx:
                lane = road.network.get_lane(cars[r].lane_index)
                h = lane.heading_at(float(lane.local_coordinates(cars[r].position)[0]))
                normal.append((-math.sin(h), math.cos(h)))
            starts.append(
                (
                    k,
                    idx,
                    np.array([cars[r].position for r in idx]),
                    np.array([cars[r].velocity for r in idx]),
                    np.array(normal),
                )
            )

        rec = rollout(env, int(seed), duration, env_config, on_frame=on_frame)
        steps = np.rint(times / rec.dt).astype(int)
        for k, idx, pos, vel, normal in starts:
            if k + steps[-1] >= rec.xy.shape[1] or not idx:
                continue
            if k >= 1:  # the velocity the predictor observes: the recorded motion
                f0 = max(k - TRACK_FRAMES, 0)
                vel = tracked_velocity(rec.dt * np.arange(f0, k + 1), rec.xy[idx][:, f0 : k + 1])
            err = rec.xy[idx][:, k + steps] - (pos[:, None] + vel[:, None] * times[None, :, None])
            rows.append(np.einsum("mkc,mc->mk", err, normal))
    errors = np.concatenate(rows) if rows else np.zeros((0, times.size))
    return times, errors


def calibrate_cv_lateral(
    times, errors, deviation: float = MARKING_DEVIATION
) -> tuple[float, float]:
    """The lateral velocity noise σ (m/s) of a constant-velocity predictor (lateral offset
    ``N(0, (σ·t)²)`` at time ``t``) calibrated on the event that matters to a car beside it:
    the probability that the car has moved more than ``deviation`` m sideways (default: its body
    crosses its lane's marking), averaged over ``times``, equals the rate measured in
    ``errors`` (M, K) (:func:`cv_lateral_errors`).  Returns ``(σ, measured rate)``.

    Lateral errors of highway traffic are not Gaussian: most cars stay exactly on their lane's
    centre and a few change lanes, so a Gaussian fitted by its moments (dominated by the lane
    changes) spreads every car over the next lane, and one fitted by a robust or proper score
    (median, CRPS) shrinks to zero; matching the probability of the event the planner acts on
    keeps that probability right."""
    from scipy.optimize import brentq
    from scipy.stats import norm

    times = _check_times(times)
    errors = np.asarray(errors, np.float64)
    if errors.ndim != 2 or errors.shape[1] != times.size or errors.shape[0] == 0:
        raise ValueError(
            f"errors must have shape (M >= 1, {times.size}) to match times, got {errors.shape}"
        )
    if not np.all(np.isfinite(errors)):
        raise ValueError("errors must be finite")
    if not (math.isfinite(deviation) and deviation > 0):
        raise ValueError(f"deviation must be > 0 m, got {deviation!r}")
    rate = float((np.abs(errors) > deviation).mean())
    if not 0.0 < rate < 1.0:
        raise ValueError(
            f"the measured rate of deviations beyond {deviation} m is {rate}: no σ matches it "
            "(too few errors, or a deviation outside their range)"
        )

    def excess(sigma: float) -> float:
        return float(np.mean(2.0 * norm.sf(deviation / (sigma * times)))) - rate

    return float(brentq(excess, 1e-6, 1e3)), rate


# ------------------------------------------------------------------------------ evaluation
def coverage(samples, future, radius: float = 2.0) -> np.ndarray:
    """Per-vehicle coverage (O,): the fraction of future steps ``t > 0`` at which some sample
    lies within ``radius`` m of the recorded position."""
    s, f = np.asarray(samples, np.float64), np.asarray(future, np.float64)
    if s.ndim != 4 or f.shape != (s.shape[0], s.shape[2], 2):
        raise ValueError(
            f"samples (O, n, K, 2) and future (O, K, 2) expected, got {s.shape}, {f.shape}"
        )
    if not radius > 0:
        raise ValueError(f"radius must be > 0 m, got {radius}")
    err = np.linalg.norm(s[:, :, 1:] - f[:, None, 1:], axis=-1)  # (O, n, K-1)
    return (err.min(axis=1) <= radius).mean(axis=-1)


# ------------------------------------------------------------------------------ train / evaluate
#: held-out evaluation: seeds 0 … N−1 (merge-v0: its factor times more), the six cars nearest to
#: the ego (the benchmark's ``max_obstacles``) every second, 20 samples, coverage within 2 m
EVAL_MAX_OBSTACLES, EVAL_STRIDE, EVAL_SAMPLES = 6, 10, 20


def _planner_times() -> np.ndarray:
    import mmdopt

    tr = mmdopt.MMDOptConfig.highway().trajectory
    return np.linspace(0.0, tr.horizon, tr.num_steps)


def _scores(samples, future, k: int, radius: float) -> np.ndarray:
    """(O, 4) minADE@k, minFDE@k, coverage (first ``k`` samples) and KDE NLL (all samples)."""
    from mmdopt.predict.metrics import kde_nll, min_ade_fde

    a, f = min_ade_fde(samples[:, :k], future)
    c = coverage(samples[:, :k], future, radius)
    return np.stack([a, f, c, kde_nll(samples, future)], axis=-1)


def evaluate_live(
    predictors: dict,
    env: str,
    seeds,
    *,
    env_config: dict | None = None,
    duration: float = 20.0,
    k: int = EVAL_SAMPLES,
    n_nll: int = 200,
    radius: float = 2.0,
) -> dict:
    """The benchmark's predictors in live highway-env rollouts (the ego an IDM/MOBIL driver):
    ``predictors`` maps a name to a factory of a fresh predictor per rollout, fed every frame
    through ``record`` and called every ``EVAL_STRIDE`` frames (from the first with a full
    1 s history) on the ``EVAL_MAX_OBSTACLES`` cars nearest to the ego, with ``n_nll``
    samples on the planner's grid; scored against the recorded futures: minADE/minFDE@``k``
    (m), coverage within ``radius`` m (:func:`coverage`) of the first ``k`` samples, and the
    KDE NLL (:func:`mmdopt.predict.metrics.kde_nll`, nats per step) of all of them.  Returns
    ``{name: {n_vehicles, min_ade, min_fde, coverage, kde_nll}}``."""
    times = _planner_times()
    K = int(round(times[-1] * 10))
    scores: dict = {name: [] for name in predictors}
    for seed in seeds:
        live = {name: make() for name, make in predictors.items()}
        asked = []  # (k, rows, {name: samples})

        def on_frame(f, road, ego, cars, live=live, asked=asked, seed=seed):
            for p in live.values():
                p.record(road, 0.1)  # rollout's frames: 10 Hz (the clock's origin is moot)
            if f < 9 or (f - 9) % EVAL_STRIDE or f + K > int(round(duration * 10)):
                return
            d = np.array([np.linalg.norm(c.position - ego.position) for c in cars])
            d[cars.index(ego)] = np.inf
            rows = [r for r in np.argsort(d)[:EVAL_MAX_OBSTACLES] if np.isfinite(d[r])]
            rng = np.random.default_rng([seed, f])
            out = {
                n: p(road, ego, [cars[r] for r in rows], times, n_nll, rng) for n, p in live.items()
            }
            asked.append((f, rows, out))

        rec = rollout(env, int(seed), duration, env_config, on_frame=on_frame)
        for f, rows, out in asked:
            future = rec.xy[rows][:, f + np.rint(times / rec.dt).astype(int)]
            for name, samples in out.items():
                scores[name].append(_scores(samples, future, k, radius))
    result = {}
    for name, sc in scores.items():
        a = np.concatenate(sc) if sc else np.zeros((0, 4))
        result[name] = dict(
            n_vehicles=int(a.shape[0]),
            **{
                m: float(a[:, i].mean())
                for i, m in enumerate(("min_ade", "min_fde", "coverage", "kde_nll"))
            },
        )
    return result


def evaluate_heldout(weights=None, *, episodes: int = 10, duration: float = 20.0) -> list[dict]:
    """:func:`evaluate_live` of the benchmark's ``cv`` predictor and the learned one
    (``weights``, default: the shipped highway weights) on the held-out seeds ``0 …
    episodes−1`` of every environment of :data:`TRAINING_ENVS` (its factor times more for
    merge-v0), one row per environment and predictor."""
    preds = {"cv": ConstantVelocityPredictor, "learned": lambda: LearnedPredictor(weights=weights)}
    rows = []
    for env, extra, factor in TRAINING_ENVS:
        n_seeds = episodes * factor
        res = evaluate_live(preds, env, range(n_seeds), env_config=extra, duration=duration)
        label = env + "".join(f" {k}={v}" for k, v in extra.items())
        for name, r in res.items():
            rows.append(
                dict(env=label, predictor=name, seeds=f"0-{n_seeds - 1}", k=EVAL_SAMPLES, **r)
            )
            if name == "learned":
                rows[-1]["spread"] = LearnedPredictor.spread
    return rows


def train_highway(
    out,
    *,
    episodes: int = 8,
    duration: float = 30.0,
    steps: int = 2000,
    seed: int = 0,
    evaluate: bool = True,
    eval_episodes: int = 10,
    verbose: bool = True,
):
    """Collect the training windows (:func:`highway_windows`, training seeds), fit the MDN
    (:func:`mmdopt.predict.train.fit_mdn`), write ``out.eqx`` / ``out.json`` with the command,
    the seeds and (``evaluate``) the held-out table in the json's ``info``; returns the base
    path and the info."""
    import time

    from mmdopt.predict.learned import MDNConfig, save_weights
    from mmdopt.predict.train import fit_mdn

    from ..ngsim.data import TRAIN_WEIGHT_DECAY

    t0 = time.perf_counter()
    W = highway_windows(episodes, _planner_times(), duration=duration)
    if verbose:
        print(
            f"{len(W)} windows, {sum(len(w.future) for w in W)} vehicle futures from "
            f"{sum(episodes * e[2] for e in TRAINING_ENVS)} rollouts "
            f"({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )
    pred, info = fit_mdn(
        W, MDNConfig(), steps=steps, seed=seed, weight_decay=TRAIN_WEIGHT_DECAY, verbose=verbose
    )
    info.update(
        source="highway-env rollouts, the ego an IDM/MOBIL driver, every car a sample",
        envs=[
            dict(env=e, config=c, seeds=f"{TRAIN_SEED0}-{TRAIN_SEED0 + episodes * f - 1}")
            for e, c, f in TRAINING_ENVS
        ],
        duration_s=duration,
        command=(
            f"mmdopt predictor train --source highway --episodes {episodes} "
            f"--duration {duration:g} --steps {steps} --seed {seed}"
        ),
    )
    info["collect_and_train_s"] = time.perf_counter() - t0
    base = save_weights(out, pred.model, pred.config, pred.norm, info)
    if evaluate:
        info["heldout"] = evaluate_heldout(base, episodes=eval_episodes)
        base = save_weights(out, pred.model, pred.config, pred.norm, info)
    return base, info
