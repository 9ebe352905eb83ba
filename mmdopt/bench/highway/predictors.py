"""Predictors of the highway benchmark: the simulator oracle (rollouts of highway-env's own
IDM/MOBIL driver models: a vectorised replica or exact clones), constant velocity, and a learned
mixture-density network trained on highway-env rollouts of other seeds (no access to the
simulator's models).  Each returns ``(O, n, K, 2)`` samples on the planner's grid and records its
wall time per call in ``last_time_s``; ``record(road, dt)`` is called after every simulator frame
(the learned predictor keeps the positions as histories, the others ignore it)."""

from __future__ import annotations

import copy
import math
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .context import scene_context
from .roads import LaneChain, follow_lanes, routes_from
from .settings import CV_MEAN, PREDICTORS


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
    """The simulator oracle: samples of each car's future from the simulator's own driver models
    (the very models that drive the traffic, so an upper bound on what a predictor can know).

    For each of ``n`` rollouts the nearby traffic (cars within ``radius`` m of the ego) is cloned
    and every IDM/MOBIL car gets randomised driver parameters: desired speed
    ± ``speed_spread`` (Gaussian), time gap U[1, 2] s, comfortable acceleration U[2, 4] m/s²,
    comfortable deceleration U[4, 6] m/s², IDM exponent U[3.5, 4.5], gain threshold
    U[0, 0.4] m/s², lane-change timer phase; the MOBIL politeness stays each car's own
    (highway-env's ``IDMVehicle.POLITENESS`` = 0): a polite car in a rollout makes way for a fast
    ego behind it (MOBIL's politeness term counts the braking the ego would need), which
    highway-env's cars never do, so the predictions would promise a gap that does not open.
    With probability ``lane_change_prob`` a car is also sent to a random neighbouring lane at a
    random time in the first half of the horizon (the modes).  The ego keeps following its
    current plan.

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

    def record(self, road, dt: float) -> None:
        """Nothing: the rollouts start from the current state."""

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
            mode = "vectorised" if straight_parallel(road.network) else "clone"
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
        params = self._params(near, idx, steps * dt, n, rng)
        sim = _VectorisedTraffic(road, near, ego_vehicle, params, n)
        traj = np.zeros((n, len(idx), steps + 1, 2))
        traj[:, :, 0, 0], traj[:, :, 0, 1] = sim.x[:, idx], sim.y[:, idx]
        t = 0.0
        for k in range(steps):
            t = sim.step(t, dt)
            traj[:, :, k + 1, 0], traj[:, :, k + 1, 1] = sim.x[:, idx], sim.y[:, idx]
        return traj


class _VectorisedTraffic:
    """``n`` rollouts of the ``N`` nearby cars stepped at once, as ``(n, N)`` arrays, on a road of
    straight lanes along +x: the NumPy replica of highway-env's ``IDMVehicle`` described in
    :class:`SimulatorPredictor` (``params`` from :meth:`SimulatorPredictor._params`)."""

    def __init__(self, road, near, ego_vehicle, params, n: int) -> None:
        from highway_env.vehicle.behavior import IDMVehicle

        lanes = road.network.all_side_lanes(ego_vehicle.lane_index)
        yc = np.array([float(road.network.get_lane(li).position(0.0, 0.0)[1]) for li in lanes])
        self.yc = yc[np.argsort(yc)]  # lane centres (m), bottom to top
        self.L = len(self.yc)
        self.half_w = 0.5 * float(road.network.get_lane(lanes[0]).width)
        speed_limit = road.network.get_lane(lanes[0]).speed_limit
        self.idm, p, self.lc_time, lc_side = params
        N = len(near)
        pos = np.array([v.position for v in near], float)
        lane0 = self.lane_no(pos[:, 1])[None, :]
        lc_lane = lane0 + lc_side
        lc_lane = np.where((lc_lane < 0) | (lc_lane >= self.L), lane0 - lc_side, lc_lane)
        self.lc_lane = np.where((lc_side == 0) | (lc_lane < 0) | (lc_lane >= self.L), -1, lc_lane)
        self.x = np.broadcast_to(pos[:, 0], (n, N)).copy()
        self.y = np.broadcast_to(pos[:, 1], (n, N)).copy()
        spd = np.array([float(v.speed) for v in near])
        hd = np.array([float(v.heading) for v in near])
        self.v = np.broadcast_to(spd, (n, N)).copy()
        self.tgt = np.empty((n, N), np.int64)
        for i, car in enumerate(near):
            ti = getattr(car, "target_lane_index", None)
            yt = (
                float(road.network.get_lane(ti).position(car.position[0], 0.0)[1])
                if ti is not None and isinstance(car, IDMVehicle)
                else car.position[1]
            )
            self.tgt[:, i] = int(self.lane_no(yt))
        v0 = p["target_speed"]
        self.v0 = np.clip(v0, 0.0, speed_limit) if speed_limit is not None else v0
        self.T, self.amax, self.bmin = p["TIME_WANTED"], p["COMFORT_ACC_MAX"], p["COMFORT_ACC_MIN"]
        self.delta, self.pol = p["DELTA"], p["POLITENESS"]
        self.gain, self.timer = p["LANE_CHANGE_MIN_ACC_GAIN"], p["timer"]
        self.d0 = IDMVehicle.DISTANCE_WANTED
        self.acc_max, self.delay = IDMVehicle.ACC_MAX, IDMVehicle.LANE_CHANGE_DELAY
        self.brake_imposed = IDMVehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED
        self.length, self.width = IDMVehicle.LENGTH, IDMVehicle.WIDTH
        self.ego_i = next((i for i, c in enumerate(near) if c is ego_vehicle), None)
        self.ego_fn = _ego_motion(ego_vehicle) if self.ego_i is not None else None
        self.passive = ~self.idm  # constant velocity (the ego is overwritten along its plan)
        self.vx_passive, self.vy0 = spd * np.cos(hd), spd * np.sin(hd)
        self.rows = np.arange(n)[:, None]
        self.eye = np.eye(N, dtype=bool)[None]
        self.crashed = np.broadcast_to(np.array([bool(c.crashed) for c in near]), (n, N)).copy()

    def lane_no(self, y):
        """Index of the lane whose centre is nearest to ``y``."""
        return np.argmin(np.abs(np.asarray(y)[..., None] - self.yc), axis=-1)

    def idm_acc(self, vi, v0i, gap, vf, has):
        """``IDMVehicle.acceleration``: free-road term minus the interaction term (centre gap),
        with the deciding car's parameters (highway-env's MOBIL convention)."""
        ai, bi, di, Ti = self.amax, self.bmin, self.delta, self.T
        free = ai * (1.0 - np.power(np.maximum(vi, 0.0) / np.maximum(np.abs(v0i), 1e-6), di))
        ab = -ai * bi
        dstar = self.d0 + vi * Ti + vi * (vi - vf) / (2.0 * np.sqrt(ab))
        inter = ai * (dstar / np.where(np.abs(gap) > 1e-6, gap, 1e-6)) ** 2
        return free - np.where(has, inter, 0.0)

    def neighbours(self, lane_idx):
        """Front / rear car of every car i in lane ``lane_idx[:, i]`` (``on_lane`` with its 1 m
        margin): indices and whether there is one, each (n, N)."""
        x, y = self.x, self.y
        on = np.abs(y[:, None, :] - self.yc[lane_idx][:, :, None]) <= self.half_w + 1.0
        on &= ~self.eye  # (n, i, j)
        dx = x[:, None, :] - x[:, :, None]  # x_j - x_i
        fr = np.where(on & (dx >= 0), dx, np.inf)
        re = np.where(on & (dx < 0), -dx, np.inf)
        jf, jr = np.argmin(fr, axis=2), np.argmin(re, axis=2)
        hf = np.isfinite(np.take_along_axis(fr, jf[..., None], 2)[..., 0])
        hr = np.isfinite(np.take_along_axis(re, jr[..., None], 2)[..., 0])
        return jf, hf, jr, hr

    def _behind(self, who, front, has_front):
        """IDM acceleration of car ``who`` behind car ``front`` (index arrays (n, N))."""
        x, v, rows = self.x, self.v, self.rows
        vf, gap = v[rows, front], x[rows, front] - x[rows, who]
        return self.idm_acc(v[rows, who], self.v0[rows, who], gap, vf, has_front)

    def _mobil(self, lane, decide, jf, hf, jr, hr) -> None:
        """MOBIL lane-change decisions of the cars in ``decide``: a side lane becomes the target
        where the new follower brakes less than ``LANE_CHANGE_MAX_BRAKING_IMPOSED`` and the
        politeness-weighted acceleration gain exceeds ``LANE_CHANGE_MIN_ACC_GAIN``."""
        x, v, v0, rows = self.x, self.v, self.v0, self.rows
        self_a = self.idm_acc(v, v0, x[rows, jf] - x, v[rows, jf], hf)
        # old follower: behind me (jr) now, and with my front as its front
        old_fol_a = np.where(
            hr, self.idm_acc(v[rows, jr], v0[rows, jr], x - x[rows, jr], v, True), 0.0
        )
        old_fol_pred_a = np.where(hr, self._behind(jr, jf, hf), 0.0)
        for side in (-1, 1):
            cand = lane + side
            valid = decide & (cand >= 0) & (cand < self.L) & (np.abs(v) >= 1.0)
            if not valid.any():
                continue
            cand_c = np.clip(cand, 0, self.L - 1)
            nf, hnf, nr, hnr = self.neighbours(cand_c)
            new_fol_a = np.where(hnr, self._behind(nr, nf, hnf), 0.0)
            new_fol_pred_a = np.where(
                hnr, self.idm_acc(v[rows, nr], v0[rows, nr], x - x[rows, nr], v, True), 0.0
            )
            self_pred_a = self.idm_acc(v, v0, x[rows, nf] - x, v[rows, nf], hnf)
            jerk = (
                self_pred_a
                - self_a
                + self.pol * (new_fol_pred_a - new_fol_a + old_fol_pred_a - old_fol_a)
            )
            ok = valid & (new_fol_pred_a >= -self.brake_imposed) & (jerk >= self.gain)
            self.tgt = np.where(ok, cand_c, self.tgt)

    def _accelerations(self, t: float):
        """Longitudinal accelerations (n, N) at time ``t`` (s); updates the target lanes (the
        forced changes that are due, then MOBIL) and the decision timers."""
        x, v, rows = self.x, self.v, self.rows
        lane = self.lane_no(self.y)
        # forced lane changes (the random modes)
        fire = (t >= self.lc_time) & (self.lc_lane >= 0)
        self.tgt = np.where(fire, self.lc_lane, self.tgt)
        self.lc_time = np.where(fire, np.inf, self.lc_time)
        # longitudinal: IDM in the current lane, min with the target lane while changing
        jf, hf, jr, hr = self.neighbours(lane)
        a = self.idm_acc(v, self.v0, x[rows, jf] - x, v[rows, jf], hf)
        changing = lane != self.tgt
        jft, hft, _, _ = self.neighbours(self.tgt)
        a_t = self.idm_acc(v, self.v0, x[rows, jft] - x, v[rows, jft], hft)
        a = np.where(changing, np.minimum(a, a_t), a)
        a = np.clip(a, -self.acc_max, self.acc_max)
        # lateral decision: MOBIL every LANE_CHANGE_DELAY seconds when not changing
        decide = (~changing) & (self.timer > self.delay) & self.idm[None, :]
        self.timer = np.where(decide, 0.0, self.timer)
        if decide.any():
            self._mobil(lane, decide, jf, hf, jr, hr)
        return a

    def step(self, t: float, dt: float) -> float:
        """Advance every rollout from ``t`` by ``dt`` (s); returns the new time."""
        a = self._accelerations(t)
        crashed, passive = self.crashed, self.passive[None, :]
        # crashed cars brake to a stop (highway-env: acceleration −speed, no steering); a
        # crash is an overlap of the 5 m × 2 m boxes (axis-aligned: lanes run along +x)
        a = np.where(crashed, -self.v, a)
        # lateral motion: first-order response to the target lane centre
        vy = np.clip((self.yc[self.tgt] - self.y) / 0.55, -5.0, 5.0)
        vy = np.where(crashed, 0.0, vy)
        vy = np.where(passive, self.vy0[None, :], vy)
        vx = np.where(passive, self.vx_passive[None, :], self.v)
        self.x = self.x + vx * dt
        self.y = self.y + vy * dt
        self.v = np.where(passive, self.v, np.maximum(self.v + a * dt, 0.0))
        self.timer = self.timer + dt
        t += dt
        x, y = self.x, self.y
        if self.ego_fn is not None:
            ex, ey, ev = self.ego_fn(t)
            x[:, self.ego_i], y[:, self.ego_i], self.v[:, self.ego_i] = ex, ey, ev
        hit = (np.abs(x[:, None, :] - x[:, :, None]) < self.length) & (
            np.abs(y[:, None, :] - y[:, :, None]) < self.width
        )
        self.crashed |= np.any(hit & ~self.eye, axis=2)
        return t


def straight_parallel(network) -> bool:
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


#: the shipped weights of the learned highway predictor (``.eqx`` + ``.json``; trained with
#: ``mmdopt predictor train --source highway``, docs/experiments/highway.md)
HIGHWAY_WEIGHTS = Path(__file__).resolve().parents[2] / "predict" / "weights" / "mdn_highway"


@dataclass
class LearnedPredictor:
    """The mixture-density network of :class:`mmdopt.predict.Learned` with the weights trained on
    highway-env rollouts of the training seeds (:mod:`.training`; ``weights`` overrides the
    path), sampled in each car's lane frame.

    Histories: :meth:`record` keeps every car's positions after each simulator frame (the
    source calls it); a call interpolates the model's ``history_len`` rows at its
    ``dt_history`` spacing back from now, and where a car has been seen for less than that
    (the first replans) continues its oldest position backwards at its current velocity.  The
    context (lane centre line, lane width, side lanes, neighbour gaps) comes from the road's
    lane network (:func:`.context.scene_context`).  ``spread`` scales the mixture's standard
    deviations when sampling.  On roads whose lanes all run along +x (highway-v0, merge-v0)
    every sample stays on the road: its lateral position is clipped to the road's extent at its
    x (:func:`_road_extent`; highway-env's cars never leave the lanes), which the mixture's wide
    components for cars in mid lane change would otherwise overshoot by up to ~10 m.  The
    default ``spread`` 1.5 was chosen on validation rollouts (seeds 100–102, merge-v0 100–111:
    neither training nor held-out seeds) among 1, 1.5 and 2: the lowest or within 0.1 m of the
    lowest minFDE@20 on all three traffic settings, and the lowest KDE NLL on two of them."""

    weights: str | Path | None = None
    spread: float = 1.5
    name: str = "learned"
    last_time_s: float = 0.0
    _model: object = field(default=None, init=False, repr=False)
    _tracks: dict = field(default_factory=dict, init=False, repr=False)
    _clock: float = field(default=0.0, init=False, repr=False)
    _keep: int = field(default=0, init=False, repr=False)

    def __post_init__(self) -> None:
        from mmdopt.predict.learned import Learned

        self._model = Learned(
            HIGHWAY_WEIGHTS if self.weights is None else self.weights, self.spread
        )
        cfg = self._model.config
        self._keep = int(math.ceil(cfg.history_len * cfg.dt_history / 0.02)) + 2

    def record(self, road, dt: float) -> None:
        """Advance the predictor's clock by ``dt`` (s) and store every car's position."""
        if not (isinstance(dt, int | float) and dt >= 0):
            raise ValueError(f"dt must be a time step >= 0 s, got {dt!r}")
        self._clock += float(dt)
        for v in road.vehicles:
            entry = self._tracks.get(id(v))
            if entry is None or entry[0] is not v:  # a new car (or a reused id)
                entry = (v, deque(maxlen=self._keep))
                self._tracks[id(v)] = entry
            hist = entry[1]
            if hist and self._clock - hist[-1][0] < 1e-9:
                hist.pop()
            hist.append((self._clock, np.array(v.position, dtype=float)))

    def _history(self, v) -> np.ndarray:
        """(H, 2) positions of ``v`` at ``now − (H−1)·dt_history, …, now``."""
        cfg = self._model.config
        t = self._clock - cfg.dt_history * np.arange(cfg.history_len - 1, -1, -1)
        ts = np.array([r[0] for r in self._tracks[id(v)][1]])
        ps = np.array([r[1] for r in self._tracks[id(v)][1]])
        out = np.stack([np.interp(t, ts, ps[:, 0]), np.interp(t, ts, ps[:, 1])], axis=-1)
        early = t < ts[0] - 1e-9  # not seen yet: constant velocity backwards
        vel = np.asarray(v.velocity, dtype=float)
        out[early] = ps[0] + (t[early] - ts[0])[:, None] * vel
        return out

    def __call__(self, road, ego_vehicle, targets, t_grid: np.ndarray, n: int, rng) -> np.ndarray:
        import jax

        t0 = time.perf_counter()
        t_grid = np.asarray(t_grid, dtype=np.float64)
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
            raise ValueError(f"n must be a positive int, got {n!r}")
        O, K = len(targets), t_grid.shape[0]
        if O == 0:
            self.last_time_s = time.perf_counter() - t0
            return np.zeros((0, n, K, 2))
        self.record(road, 0.0)  # now (a no-op when the source recorded this frame)
        cars = list(road.vehicles)
        idx = []
        for v in targets:
            i = next((i for i, u in enumerate(cars) if u is v), None)
            if i is None:
                cars.append(v)
                i = len(cars) - 1
            idx.append(i)
        for v in cars[len(road.vehicles) :]:  # targets not on the road's list
            self._tracks.setdefault(id(v), (v, deque([(self._clock, np.array(v.position))])))
        history = np.stack([self._history(v) for v in targets])
        ctx = scene_context(
            road.network,
            [v.lane_index for v in cars],
            np.array([v.position for v in cars], float),
            np.array([v.speed for v in cars], float),
            idx,
            t_grid,
            self._model.config.dt_history,
        )
        key = jax.random.PRNGKey(int(rng.integers(2**31 - 1)))
        out = self._model.sample(history, ctx, int(n), key)
        extent = _road_extent(road.network, out[..., 0].min(), out[..., 0].max())
        if extent is not None:
            through = np.array(
                [(*u.position, u.velocity[0]) for u in road.vehicles], float
            ).reshape(-1, 3)
            for o, v in enumerate(targets):
                others = through[[u is not v for u in road.vehicles]]
                _merge_before_lane_end(
                    road.network, v.lane_index, out[o], rng, t_grid=t_grid, through=others
                )
            xs, lo, hi = extent
            half = 0.5 * float(getattr(targets[0], "WIDTH", 2.0))
            y_lo, y_hi = (
                np.interp(out[..., 0], xs, lo) + half,
                np.interp(out[..., 0], xs, hi) - half,
            )
            out[..., 1] = np.clip(out[..., 1], y_lo, np.maximum(y_hi, y_lo))
        self.last_time_s = time.perf_counter() - t0
        return out


#: the distance over which a car's sample moves into the neighbouring lane when its own lane
#: ends (m; about 1.5 s at merge-v0's 20 m/s, highway-env's lane-change time)
MERGE_ZONE_M = 30.0


def _ending_lane(network, lane_index, hops: int = 2):
    """The first lane without a continuation (the road goes on after its end node, but with no
    lane of its index) on the
    car's way from ``lane_index`` through at most ``hops`` geometric successors (highway-env's
    ``next_lane`` at the lane's end: merge-v0's ramp leads into the acceleration lane), else
    ``None``."""
    for _ in range(hops + 1):
        _, to, i = lane_index
        following = network.graph.get(to, {})
        if not following:  # the end of the road, not of a lane
            return None
        if not any(len(lanes) > i for lanes in following.values()):
            return lane_index
        lane = network.get_lane(lane_index)
        nxt = tuple(network.next_lane(lane_index, position=lane.position(lane.length, 0.0)))
        if nxt == tuple(lane_index):
            return None
        lane_index = nxt
    return None


#: a car entering from a lane that ends yields to the traffic in the lane it enters (the rule of
#: the road): it enters only where every car of that lane keeps, from the car ahead of it, a
#: distance of MERGE_SPACING_M (two 5 m car lengths, centre to centre) plus MERGE_TIME_GAP_S
#: seconds at its own speed
MERGE_SPACING_M = 10.0
MERGE_TIME_GAP_S = 1.0


def _merge_before_lane_end(
    network, lane_index, samples: np.ndarray, rng, t_grid=None, through=None
) -> None:
    """Map knowledge the network does not learn: a car on a lane that ends (no lane of its index
    continues it: ``merge-v0``'s acceleration lane, also ahead on the car's way,
    :func:`_ending_lane`) must leave it before the lane's end, and may
    do so anywhere before.  Each of its samples (n, K, 2), on a road along +x, moves laterally
    into the neighbouring lane over :data:`MERGE_ZONE_M` metres from a start drawn uniformly
    between the car's position and the last point that still completes the move by the end
    (``rng``: a NumPy generator), in place.  A car on a lane that continues is left as
    predicted.

    It yields to the lane it enters: with ``t_grid`` (K,) and ``through`` ((C, 3): ``x, y, vx``
    of the cars now in the road's other lanes, the ego among them), a sample's move starts at
    the first grid time from its drawn start at which the cars of the lane it enters, at
    constant speed, leave the gap of :data:`MERGE_SPACING_M` and :data:`MERGE_TIME_GAP_S`
    around it; a sample that finds no such gap before the lane's end stays in its lane and
    stops at the end.  A car already moving across (more than 1 m off its lane's centre) is not
    held."""
    lane_index = _ending_lane(network, lane_index)
    if lane_index is None:
        return
    _, to, i = lane_index
    lane = network.get_lane(lane_index)
    frm = lane_index[0]
    sides = [j for j in (i - 1, i + 1) if 0 <= j < len(network.graph[frm][to])]
    if not sides:
        return
    end = lane.position(lane.length, 0.0)
    centres = [float(network.get_lane((frm, to, j)).position(lane.length, 0.0)[1]) for j in sides]
    y_to = min(centres, key=lambda c: abs(c - float(end[1])))
    x_now = float(samples[:, 0, 0].mean())
    last = max(float(end[0]) - MERGE_ZONE_M, x_now)
    start = rng.uniform(x_now, last, size=(samples.shape[0], 1))
    if t_grid is not None and through is not None and len(through):
        if abs(float(samples[:, 0, 1].mean()) - float(end[1])) <= 1.0:
            start = _yielding_start(samples, start, np.asarray(t_grid, float), through, y_to, end)
    w = np.clip((samples[..., 0] - start) / MERGE_ZONE_M, 0.0, 1.0)
    samples[..., 1] = (1.0 - w) * samples[..., 1] + w * y_to


def _yielding_start(samples, start, t, through, y_to, end) -> np.ndarray:
    """The merge starts (n, 1) of :func:`_merge_before_lane_end` once the merging car yields to
    the cars of the lane it enters; samples that find no gap are held at the lane's end (in
    place) and get an infinite start."""
    through = np.asarray(through, float).reshape(-1, 3)
    lane_cars = through[np.abs(through[:, 1] - y_to) < 2.0]
    x = samples[..., 0]  # (n, K)
    if not len(lane_cars):
        return start
    cx = lane_cars[:, 0, None] + lane_cars[:, 2, None] * t[None, :]  # (C, K)
    vx = np.gradient(x, t, axis=1) if t.shape[0] > 1 else np.zeros_like(x)
    gap = x[None] - cx[:, None]  # (C, n, K): the merging car ahead of the lane's car by gap
    ahead_ok = gap >= MERGE_SPACING_M + MERGE_TIME_GAP_S * lane_cars[:, 2, None, None]
    behind_ok = -gap >= MERGE_SPACING_M + MERGE_TIME_GAP_S * np.maximum(vx, 0.0)[None]
    ok = np.where(gap >= 0.0, ahead_ok, behind_ok).all(0)
    cand = (x >= start) & ok & (x <= float(end[0]) - 0.5 * MERGE_ZONE_M)
    found = cand.any(1)
    first = np.argmax(cand, axis=1)
    new = np.where(found, x[np.arange(x.shape[0]), first], np.inf)[:, None]
    samples[~found, :, 0] = np.minimum(samples[~found, :, 0], float(end[0]))
    return new


def _road_extent(network, x_min: float, x_max: float, step: float = 2.0):
    """``(xs, y_lo, y_hi)``: the road's lateral extent (outer lane edges) on a grid ``xs`` of
    ``[x_min, x_max]`` when every lane runs along +x (heading within 60° of +x), else ``None``;
    beyond the lanes' ends the extent at the nearest covered ``x``."""
    xs = np.arange(float(x_min) - step, float(x_max) + 2 * step, step)
    lo, hi = np.full(xs.shape, np.inf), np.full(xs.shape, -np.inf)
    for lane in network.lanes_list():
        s = np.linspace(0.0, float(lane.length), max(2, int(lane.length // step) + 2))
        if s[-1] > 5000.0:  # highway-v0's 10 km lanes: only the stretch around [x_min, x_max]
            x0 = float(lane.local_coordinates(np.array([x_min, 0.0]))[0])
            s = np.clip(np.arange(x0 - 2 * step, x0 + (x_max - x_min) + 3 * step, step), 0, s[-1])
        pts = np.array([lane.position(si, 0.0) for si in s])
        if np.any(np.cos([lane.heading_at(si) for si in s]) < 0.5):
            return None
        w = 0.5 * float(lane.width_at(0.0))
        inside = (xs >= pts[0, 0]) & (xs <= pts[-1, 0])
        y = np.interp(xs[inside], pts[:, 0], pts[:, 1])
        lo[inside] = np.minimum(lo[inside], y - w)
        hi[inside] = np.maximum(hi[inside], y + w)
    ok = np.isfinite(lo)
    if not ok.any():
        return None
    return xs[ok], lo[ok], hi[ok]


#: speed (m/s) from which the constant-velocity predictor's lateral noise is at full strength
LATERAL_FULL_SPEED = 10.0
#: the constant-velocity predictor's lateral velocity noise (m/s), calibrated on highway-env
#: rollouts of the training seeds (:func:`~.training.calibrate_cv_lateral`: highway-v0 at its
#: default density and at ``vehicles_density`` 2, seeds 100000–100007, 40 s each, the six cars
#: nearest to the ego every second, 3456 futures): with it the probability that a car's body has
#: crossed its lane's marking (moved more than 1 m sideways), averaged over the 5 s horizon, is
#: the measured 4.1 % (σ = 0.140).  The former 0.3 m/s put it at 23 % (50 % at 5 s against the
#: measured 5.6 %), so a car in the next lane blocked passing as if it were changing lanes.
#: Extrapolating the observed velocity (:func:`tracked_velocity`) instead of
#: ``Vehicle.velocity`` gives 4.2 % and σ = 0.141 on the same futures: kept.
CV_SIGMA_LAT = 0.14
#: the longitudinal velocity noise (m/s): the same rule with a car's length (5 m) gives
#: 0.66 m/s at the horizon; 1.0 is kept, the cautious side along the road, where the following
#: distance and the safety shield act
CV_SIGMA_LONG = 1.0
#: frames over which the constant-velocity predictor's observed velocity is taken (the median
#: of this many frame-to-frame velocities: 0.3 s at the benchmark's 10 Hz)
TRACK_FRAMES = 3


def tracked_velocity(ts, ps) -> np.ndarray:
    """A car's velocity (..., 2) m/s from its last positions ``ps`` (..., F, 2) at the times
    ``ts`` (F,) s, F >= 2: the component-wise median of the last :data:`TRACK_FRAMES`
    frame-to-frame velocities (robust to a one-frame jump, such as a collision's impact)."""
    ts, ps = np.asarray(ts, dtype=float), np.asarray(ps, dtype=float)
    if ts.ndim != 1 or ts.shape[0] < 2 or ps.shape[-2:] != (ts.shape[0], 2):
        raise ValueError(
            f"ts must be (F >= 2,) times and ps (..., F, 2) positions, got {ts.shape}, {ps.shape}"
        )
    dt = np.diff(ts)[-TRACK_FRAMES:]
    if not np.all(dt > 0):
        raise ValueError("ts must increase")
    vel = np.diff(ps, axis=-2)[..., -TRACK_FRAMES:, :] / dt[:, None]
    return np.median(vel, axis=-2)


#: a car closer than this (m) to a lane centre is at it: its next centre in the direction of
#: its sideways motion is the one beyond (:func:`stop_at_next_centre`)
LANE_STOP_TOL = 0.25


def stop_at_next_centre(y0, vy, y, road) -> np.ndarray:
    """Lateral positions ``y`` (O, n, K) of cars that started at ``y0`` (O,) moving sideways at
    ``vy`` (O, n), stopped at the next lane centre of ``road`` (straight lanes along +x) in
    the direction of their motion: more than :data:`LANE_STOP_TOL` beyond ``y0``; a car
    beyond the outermost centre moving outwards stays where it is."""
    centres = np.unique(np.round([ln.position(0.0, 0.0)[1] for ln in road.network.lanes_list()], 6))
    y0 = np.asarray(y0, dtype=float)
    above = np.array(
        [centres[centres > c + LANE_STOP_TOL].min() if np.any(centres > c + LANE_STOP_TOL)
         else max(c, centres.max()) for c in y0]
    )  # fmt: skip
    below = np.array(
        [centres[centres < c - LANE_STOP_TOL].max() if np.any(centres < c - LANE_STOP_TOL)
         else min(c, centres.min()) for c in y0]
    )  # fmt: skip
    target = np.where(np.asarray(vy) > 0, above[:, None], below[:, None])  # (O, n)
    lo = np.minimum(y0[:, None], target)[..., None]
    hi = np.maximum(y0[:, None], target)[..., None]
    return np.clip(y, lo, hi)


def _check_nonnegative(obj, names, unit: str) -> None:
    """A ``ValueError`` naming the first of the fields ``names`` of ``obj`` that is not a finite
    number >= 0 (in ``unit``)."""
    for f in names:
        v = getattr(obj, f)
        if isinstance(v, bool) or not isinstance(v, int | float) or not (0 <= v < math.inf):
            raise ValueError(f"{f} must be a finite number >= 0 ({unit}), got {v!r}")


@dataclass
class ConstantVelocityPredictor:
    """Each car keeps its current velocity; sample ``j > 0`` adds Gaussian velocity noise
    (``sigma_long`` m/s along the road, ``sigma_lat`` m/s across: :data:`CV_SIGMA_LONG`,
    :data:`CV_SIGMA_LAT`, calibrated on rollouts of the training seeds), sample 0 is the
    noise-free extrapolation. Unimodal.

    The velocity is the one *observed*: the motion of the car's position over the last frames
    passed to :meth:`record` (the component-wise median of the last :data:`TRACK_FRAMES`
    frame-to-frame velocities, so the one-frame jump of a collision's impact is ignored), as a
    tracker would estimate it.  highway-env's ``Vehicle.velocity`` is the speed along the body's
    heading, without the slip angle of its kinematic bicycle: a car that steers hard (a lane
    change, or a car reversing behind a wreck, whose steering controller turns it across the
    road) moves sideways at up to several m/s more than it says, possibly the other way.  A car
    with no recorded frames yet (or when :meth:`record` is not called) uses ``velocity``.

    The noise does not make a car reverse faster than it is seen to (the speed along the road
    is clipped at ``min(0, observed)``), and a car moves sideways only as it moves: below
    :data:`LATERAL_FULL_SPEED` the lateral noise shrinks in proportion to its observed speed (a
    car at rest stays where it is, or drives off along the road; its body's heading reaches the
    planner with the observation, :attr:`mmdopt.receding.Observation.obstacle_headings`).  On
    roads of straight lanes, with ``lane_stop`` (default), a car's sideways motion stops at the
    next lane centre in its direction (:func:`stop_at_next_centre`): highway traffic changes
    one lane at a time, and a car carried on across every lane would leave the lane it enters
    looking free.  On a road with curved lanes the velocity is kept in each car's lane frame
    (speed along the lane's centre line, through its successors, and across it:
    :func:`~.roads.follow_lanes`), so the futures follow the curves instead of leaving the road
    in a straight line."""

    sigma_long: float = CV_SIGMA_LONG
    sigma_lat: float = CV_SIGMA_LAT
    lane_stop: bool = True
    name: str = "cv"
    last_time_s: float = 0.0
    _clock: float = field(default=0.0, init=False, repr=False)
    _tracks: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        _check_nonnegative(self, ("sigma_long", "sigma_lat"), "m/s")
        if not isinstance(self.lane_stop, bool):
            raise ValueError(f"lane_stop must be True or False, got {self.lane_stop!r}")

    def record(self, road, dt: float) -> None:
        """Advance the predictor's clock by ``dt`` (s) and store every car's position (the last
        :data:`TRACK_FRAMES` + 1 frames of each; cars that left the road are forgotten)."""
        if isinstance(dt, bool) or not (isinstance(dt, int | float) and 0 < dt < math.inf):
            raise ValueError(f"dt must be a time step > 0 s, got {dt!r}")
        self._clock += float(dt)
        tracks = {}
        for v in road.vehicles:
            entry = self._tracks.get(id(v))
            if entry is None or entry[0] is not v:  # a new car (or a reused id)
                entry = (v, deque(maxlen=TRACK_FRAMES + 1))
            entry[1].append((self._clock, np.array(v.position, dtype=float)))
            tracks[id(v)] = entry
        self._tracks = tracks

    def observed_velocity(self, v) -> np.ndarray:
        """The velocity (2,) m/s of car ``v`` as observed: the component-wise median of its last
        frame-to-frame velocities (up to :data:`TRACK_FRAMES`), when its last recorded position
        is where it is now; else highway-env's ``v.velocity``."""
        entry = self._tracks.get(id(v))
        pos = np.asarray(v.position, dtype=float)
        if entry is None or entry[0] is not v or len(entry[1]) < 2:
            return np.asarray(v.velocity, dtype=float)
        ts = np.array([r[0] for r in entry[1]])
        ps = np.array([r[1] for r in entry[1]])
        if not np.allclose(ps[-1], pos, rtol=0.0, atol=1e-9):
            return np.asarray(v.velocity, dtype=float)
        return tracked_velocity(ts, ps)

    def __call__(self, road, ego_vehicle, targets, t_grid: np.ndarray, n: int, rng) -> np.ndarray:
        t0 = time.perf_counter()
        O = len(targets)
        if O == 0:
            self.last_time_s = time.perf_counter() - t0
            return np.zeros((0, n, t_grid.shape[0], 2))
        pos = np.array([v.position for v in targets], float)  # (O, 2)
        vel = np.array([self.observed_velocity(v) for v in targets], float).reshape(O, 2)
        noise = rng.normal(size=(O, n, 2)) * np.array([self.sigma_long, self.sigma_lat])
        noise[:, 0] = 0.0
        speed = np.hypot(vel[:, 0], vel[:, 1])
        noise[..., 1] *= np.clip(speed / LATERAL_FULL_SPEED, 0.0, 1.0)[:, None]
        if not straight_parallel(road.network):
            # curved lanes: constant velocity in each car's lane frame, along the lane's centre
            lanes = [road.network.get_lane(v.lane_index) for v in targets]
            hl = np.array(
                [ln.heading_at(ln.local_coordinates(v.position)[0])
                 for v, ln in zip(targets, lanes, strict=True)]
            )  # fmt: skip
            mean_long = vel[:, 0] * np.cos(hl) + vel[:, 1] * np.sin(hl)
            mean_lat = -vel[:, 0] * np.sin(hl) + vel[:, 1] * np.cos(hl)
            v_long = np.maximum(
                mean_long[:, None] + noise[..., 0], np.minimum(mean_long, 0.0)[:, None]
            )
            v_lat = mean_lat[:, None] + noise[..., 1]
            out = follow_lanes(road.network, targets, t_grid, v_long, v_lat)
        else:
            v = vel[:, None, :] + noise  # (O, n, 2) — highway-v0 lanes run along +x
            v[..., 0] = np.maximum(v[..., 0], np.minimum(vel[:, 0], 0.0)[:, None])
            out = pos[:, None, None, :] + v[:, :, None, :] * t_grid[None, None, :, None]
            if self.lane_stop:
                out[..., 1] = stop_at_next_centre(pos[:, 1], v[..., 1], out[..., 1], road)
        self.last_time_s = time.perf_counter() - t0
        return out


#: metres of route beyond the farthest a car can go in the horizon (:class:`RoutePredictor`)
ROUTE_SLACK = 20.0


@dataclass
class RoutePredictor:
    """A multi-modal predictor that is not the simulator: one mode per route a car can take from
    its lane (:func:`routes_from` over the horizon's reach), with the stated weights ``weights``
    ("uniform": each route equally likely; the samples split among the modes as evenly as
    whole samples allow, mode ``j % M`` for sample ``j``).  In each mode the car moves along
    the route's centre line (:class:`~.roads.LaneChain`, through the junction) at its observed
    speed along its lane with a constant acceleration drawn from N(0, ``sigma_accel``²) (the
    first sample of each mode noise-free), clipped to ``[-accel_limit, accel_limit / 2]``, its
    speed kept within ``[0, lane speed limit + 2 m/s]``, and keeps its lateral offset from the
    centre line.  A car's speed is the one observed (its tracked motion, as the cv predictor's).
    After each call ``last_modes`` (O, n) gives each sample's mode and ``last_routes`` each car's
    routes (for videos and the shield's crossing rule)."""

    sigma_accel: float = 1.5
    accel_limit: float = 6.0
    weights: str = "uniform"
    name: str = "route"
    last_time_s: float = 0.0
    last_modes: np.ndarray | None = None
    last_routes: list = field(default_factory=list)
    _tracker: object = field(default=None, init=False, repr=False)
    _chains: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        _check_nonnegative(self, ("sigma_accel", "accel_limit"), "m/s²")
        if self.weights != "uniform":
            raise ValueError(f"weights must be 'uniform', got {self.weights!r}")
        self._tracker = ConstantVelocityPredictor()

    def record(self, road, dt: float) -> None:
        """Track every car's position (the observed velocities, as the cv predictor does)."""
        self._tracker.record(road, dt)

    def chain(self, network, route: tuple) -> LaneChain:
        """The centre line of ``route`` (cached: the network does not change in an episode)."""
        key = (id(network), route)
        ch = self._chains.get(key)
        if ch is None:
            total = sum(float(network.get_lane(li).length) for li in route)
            ch = LaneChain.follow(network, route[0], total, route=list(route))
            self._chains[key] = ch
        return ch

    def modes(
        self, road, vehicle, horizon: float
    ) -> tuple[list[tuple], float, float, float, float]:
        """``(routes, s0, d0, v0, v_top)`` of ``vehicle``: its routes over the horizon's reach,
        its lane coordinates, its observed speed along its lane and the top speed it may reach
        (the lane's speed limit + 2 m/s)."""
        net = road.network
        lane = net.get_lane(vehicle.lane_index)
        s0, d0 = (float(c) for c in lane.local_coordinates(np.asarray(vehicle.position, float)))
        h = float(lane.heading_at(max(s0, 0.0)))
        vel = self._tracker.observed_velocity(vehicle)
        v0 = max(float(vel[0] * math.cos(h) + vel[1] * math.sin(h)), 0.0)
        v_top = float(lane.speed_limit or 20.0) + 2.0
        reach = max(v0, v_top) * horizon + ROUTE_SLACK
        routes = routes_from(net, vehicle.lane_index, reach, start_s=max(s0, 0.0))
        return routes, s0, d0, v0, v_top

    def __call__(self, road, ego_vehicle, targets, t_grid: np.ndarray, n: int, rng) -> np.ndarray:
        t0 = time.perf_counter()
        t = np.asarray(t_grid, dtype=float)
        O, K = len(targets), t.shape[0]
        out = np.zeros((O, n, K, 2))
        modes = np.zeros((O, n), dtype=np.int64)
        self.last_routes = []
        for o, v in enumerate(targets):
            routes, s0, d0, v0, v_top = self.modes(road, v, float(t[-1]))
            self.last_routes.append(routes)
            m = np.arange(n) % len(routes)
            first = np.zeros(n, bool)
            first[: len(routes)] = True
            a = rng.normal(size=n) * self.sigma_accel
            a[first] = 0.0
            a = np.clip(a, -self.accel_limit, 0.5 * self.accel_limit)
            vt = np.clip(v0 + a[:, None] * t[None, :], 0.0, max(v_top, v0))  # (n, K)
            dt = np.diff(t, prepend=t[0])
            s = s0 + np.cumsum(0.5 * (vt + np.concatenate([vt[:, :1], vt[:, :-1]], 1)) * dt, 1)
            for j, route in enumerate(routes):
                sel = m == j
                if sel.any():
                    out[o, sel] = self.chain(road.network, route).position(s[sel], d0)
            modes[o] = m
        self.last_modes = modes
        self.last_time_s = time.perf_counter() - t0
        return out


def make_predictor(name: str, weights: str | Path | None = None):
    """The predictor ``name`` (:data:`~.settings.PREDICTORS`): ``"sim"`` (the simulator oracle),
    ``"cv"``, ``"route"`` (one mode per route through a junction, :mod:`.junction`) or
    ``"learned"`` (``weights``: a path other than the shipped highway weights); or
    :data:`~.settings.CV_MEAN`, the noise-free constant-velocity extrapolation of the ``cv``
    agent (:data:`~.settings.AGENTS`)."""
    if name == "sim":
        return SimulatorPredictor()
    if name == "cv":
        return ConstantVelocityPredictor()
    if name == "learned":
        return LearnedPredictor(weights=weights)
    if name == "route":
        return RoutePredictor()
    if name == CV_MEAN:
        return ConstantVelocityPredictor(sigma_long=0.0, sigma_lat=0.0, name=CV_MEAN)
    raise ValueError(f"predictor must be one of {(*PREDICTORS, CV_MEAN)}, got {name!r}")
