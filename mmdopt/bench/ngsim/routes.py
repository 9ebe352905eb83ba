"""Routes in the predictor: one mode per route a car can still take, with learned weights.

At a junction a car may go straight, turn left or turn right; a lane predictor given one centre
line (the straightest, :func:`.scene.vehicle_centerline`) predicts one of them.  Here every
route of a car (:func:`.scene.candidate_routes`: the successor branches of its lanelet, known at
t0 without its future) is a mode:

* :func:`route_probabilities`: P(route) = softmax(−θ · f) over the car's routes, with features
  ``f`` of its history against each route (:data:`FEATURES`): how far the route's heading 1 s
  and 3 s ahead is from where the car's heading and yaw rate point, the car's lateral offset
  from the route, and how much the route turns;
* θ is fitted by maximum likelihood (:func:`fit_route_weights`) on the training recordings'
  windows where a car has more than one route, the label being the route nearest its recorded
  future; ``mmdopt predictor train`` writes them beside the MDN's weights
  (``<weights>_routes.json``); the shipped ones (:data:`ROUTE_WEIGHTS`) were fitted with the
  urban MDN (``mmdopt.predict.learned.URBAN_WEIGHTS``);
* :class:`RouteMixture`: any predictor (the learned MDN, constant velocity, ...) run once per
  route with that route as the car's centre line, ``n`` futures split over the routes by their
  probabilities (largest remainder) and shuffled.

:func:`evaluate_routes`: minADE/minFDE@k, coverage (share of cars with minFDE@k ≤
:data:`COVERAGE_M`) and route accuracy of cv, the lane-only learned predictor and both through
the routes, on windows of held-out files.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from .scene import (
    CHAIN_SPACING,
    candidate_routes,
    distance_to_polyline,
    future_at,
    load_scenario,
    present,
)

__all__ = [
    "FEATURES",
    "COVERAGE_M",
    "ROW_BUCKET",
    "ROUTE_WEIGHTS",
    "RouteWeights",
    "route_features",
    "route_probabilities",
    "taken_route",
    "save_route_weights",
    "load_route_weights",
    "shipped_route_weights",
    "route_windows",
    "fit_route_weights",
    "RouteMixture",
    "evaluate_routes",
]

#: the features of a (car, route) pair, in θ's order
FEATURES = ("heading_gap_1s", "heading_gap_3s", "offset_m", "route_turn")
#: :class:`RouteMixture` hands its inner predictor a multiple of this many rows
ROW_BUCKET = 8
#: a car is covered when one of its k futures ends within this distance (m) of where it went
COVERAGE_M = 2.0
#: the shipped route weights (fitted with the urban MDN: ``<weights>_routes.json``)
ROUTE_WEIGHTS = Path(__file__).parents[2] / "predict" / "weights" / "mdn_ngsim_urban_routes.json"


@dataclass(frozen=True)
class RouteWeights:
    """θ of :func:`route_probabilities` (one per :data:`FEATURES`) and how it was fitted."""

    theta: tuple[float, ...]
    info: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        th = np.asarray(self.theta, np.float64)
        if th.shape != (len(FEATURES),) or not np.all(np.isfinite(th)):
            raise ValueError(f"theta must be {len(FEATURES)} finite numbers, got {self.theta!r}")


def _wrap(a):
    return np.angle(np.exp(1j * np.asarray(a, np.float64)))


def route_features(history: np.ndarray, route: np.ndarray, dt: float) -> np.ndarray:
    """(F,) features (:data:`FEATURES`) of a car's ``history`` (H, 2), last row now, ``dt`` s
    apart, against a ``route`` (P, 2) polyline :data:`~.scene.CHAIN_SPACING` m apart."""
    h = np.asarray(history, np.float64)
    if h.ndim != 2 or h.shape[1] != 2 or len(h) < 3:
        raise ValueError(f"history must be (H, 2), H >= 3, got {h.shape}")
    r = np.asarray(route, np.float64)
    if r.ndim != 2 or r.shape[1] != 2 or len(r) < 3:
        raise ValueError(f"route must be (P, 2), P >= 3, got {r.shape}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be > 0, got {dt!r}")
    vel = (h[-1] - h[-3]) / (2 * dt)
    v = float(np.hypot(*vel))
    back = min(len(h) - 1, 6)
    vel0 = (h[-1 - back + 2] - h[-1 - back]) / (2 * dt)
    hd = float(np.arctan2(vel[1], vel[0]))
    moving = v > 1.0 and np.hypot(*vel0) > 1.0
    w = float(_wrap(hd - np.arctan2(vel0[1], vel0[0]))) / ((back - 1) * dt) if moving else 0.0
    w = float(np.clip(w, -0.5, 0.5))
    seg = np.diff(r, axis=0)
    rh = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
    i0 = int(np.argmin(np.linalg.norm(r - h[-1], axis=-1)))
    i0 = min(i0, len(seg) - 1)

    def ahead(L: float) -> float:
        return float(rh[min(len(rh) - 1, i0 + int(round(L / CHAIN_SPACING)))])

    if not moving:
        hd = rh[i0]
    g1 = abs(float(_wrap(ahead(max(v * 1.0, 3.0)) - (hd + w * 1.0))))
    g3 = abs(float(_wrap(ahead(max(v * 3.0, 8.0)) - (hd + w * 3.0))))
    off = float(np.min(np.linalg.norm(r - h[-1], axis=-1)))
    turn = abs(float(ahead(max(v * 3.0, 8.0)) - rh[i0]))
    return np.array([g1, g3, off, turn])


def route_probabilities(
    history: np.ndarray, routes, dt: float, weights: RouteWeights
) -> list[np.ndarray]:
    """P(route) of each car: ``history`` (O, H, 2), ``routes`` one (R_i, P, 2) array (or list)
    per car; softmax(−θ · f) over its routes (one route: probability 1)."""
    th = np.asarray(weights.theta, np.float64)
    history = np.asarray(history, np.float64)
    if history.ndim != 3 or len(history) != len(routes):
        raise ValueError(f"history (O, H, 2) needs one route set per car, got {history.shape}")
    out = []
    for h, rs in zip(history, routes, strict=True):
        if len(rs) == 0:
            raise ValueError("every car needs at least one route")
        z = -np.array([th @ route_features(h, r, dt) for r in rs])
        p = np.exp(z - z.max())
        out.append(p / p.sum())
    return out


def taken_route(routes, future: np.ndarray) -> int:
    """Index of the route nearest (mean point-to-polyline distance) a car's recorded future."""
    f = np.asarray(future, np.float64)
    f = f[np.all(np.isfinite(f), -1)]
    return int(np.argmin([np.mean(distance_to_polyline(np.asarray(r), f)) for r in routes]))


def save_route_weights(path: str | Path, weights: RouteWeights, extra: dict | None = None) -> Path:
    """Write ``weights`` (θ, its fit's info and ``extra``) as JSON to ``path``."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    info = dict(weights.info, **(extra or {}), features=list(FEATURES))
    p.write_text(json.dumps(dict(theta=list(weights.theta), info=info), indent=1))
    return p


def load_route_weights(path: str | Path | None = None) -> RouteWeights:
    """The route weights of a JSON file (default: the shipped :data:`ROUTE_WEIGHTS`)."""
    p = Path(ROUTE_WEIGHTS if path is None else path)
    if not p.is_file():
        raise ValueError(f"route weights {p} not found")
    d = json.loads(p.read_text())
    return RouteWeights(tuple(float(x) for x in d["theta"]), d.get("info", {}))


@lru_cache(maxsize=1)
def shipped_route_weights() -> RouteWeights:
    """:func:`load_route_weights` of the shipped file, read once per process."""
    return load_route_weights()


# --------------------------------------------------------------------------- training data
def route_windows(files, *, horizon: float = 5.0, history: int = 10, stride: int = 5) -> list:
    """Every ``stride`` steps of each file, per vehicle recorded over history and horizon:
    ``(scene name, t0, history (H, 2), routes (R, P, 2), future (K+1, 2), dt)``."""
    out = []
    for f in files:
        sc = load_scenario(str(f))
        K = int(round(horizon / sc.dt))
        times = np.arange(K + 1) * sc.dt
        for k in range(history - 1, sc.num_steps - K, stride):
            idx = np.flatnonzero(present(sc, k - history + 1, k + K) & (sc.lane_of[:, k] >= 0))
            if len(idx) == 0:
                continue
            fut = future_at(sc, idx, k, times)
            for j, v in enumerate(idx):
                rs = np.stack(candidate_routes(sc, int(v), k))
                hist = sc.xy[v, k - history + 1 : k + 1]
                out.append((sc.name, round(k * sc.dt, 3), hist, rs, fut[j], sc.dt))
    return out


def fit_route_weights(files, *, stride: int = 5, l2: float = 1e-3) -> RouteWeights:
    """θ by maximum likelihood of the taken route (:func:`taken_route`) over the cars of
    :func:`route_windows` (``files``) that have more than one route, with an L2 penalty."""
    from scipy.optimize import minimize

    rows = [r for r in route_windows(files, stride=stride) if len(r[3]) > 1]
    if not rows:
        raise ValueError("no car with more than one route in these files")
    feats = [np.stack([route_features(h, r, dt) for r in rs]) for _, _, h, rs, _, dt in rows]
    labels = [taken_route(rs, fut) for _, _, _, rs, fut, _ in rows]

    def nll(th):
        total, grad = 0.0, np.zeros_like(th)
        for F, y in zip(feats, labels, strict=True):
            z = -F @ th
            m = z.max()
            p = np.exp(z - m)
            p /= p.sum()
            total -= z[y] - m - np.log(np.sum(np.exp(z - m)))
            grad += F[y] - p @ F
        n = len(feats)
        return total / n + l2 * th @ th, grad / n + 2 * l2 * th

    res = minimize(nll, np.ones(len(FEATURES)), jac=True, method="L-BFGS-B")
    th = res.x
    acc = np.mean([int(np.argmin(F @ th)) == y for F, y in zip(feats, labels, strict=True)])
    info = dict(
        n_cars=len(rows),
        nll=float(res.fun),
        train_accuracy=float(acc),
        files=[Path(f).name for f in files],
        stride=stride,
        l2=l2,
    )
    return RouteWeights(tuple(float(x) for x in th), info)


# --------------------------------------------------------------------------- the predictor
def _split(n: int, p: np.ndarray) -> np.ndarray:
    """``n`` draws over modes of probability ``p`` (largest remainder)."""
    c = np.floor(n * p).astype(int)
    rest = n - int(c.sum())
    if rest:
        c[np.argsort(-(n * p - c), kind="stable")[:rest]] += 1
    return c


@dataclass(frozen=True)
class RouteMixture:
    """``inner`` once per route of each car (that route as its context's centre line), ``n``
    futures split over a car's routes by ``probabilities`` and shuffled (so any prefix of the
    draws mixes the routes).  ``routes``: one (R_i, P, 2) array per car, P the context's;
    ``probabilities``: one (R_i,) array per car."""

    inner: Any
    routes: tuple
    probabilities: tuple
    name: str = "routes"

    def __post_init__(self) -> None:
        if len(self.routes) != len(self.probabilities):
            raise ValueError("routes and probabilities need one entry per car")
        for i, (r, p) in enumerate(zip(self.routes, self.probabilities, strict=True)):
            r, p = np.asarray(r), np.asarray(p)
            if r.ndim != 3 or r.shape[-1] != 2 or len(r) != len(p) or len(r) == 0:
                raise ValueError(f"car {i}: routes must be (R, P, 2) with R probabilities")
            if not (np.all(p >= 0) and abs(p.sum() - 1) < 1e-6):
                raise ValueError(f"car {i}: probabilities must be >= 0 and sum to 1")

    def sample(self, history, context, n, key) -> np.ndarray:
        import jax

        O = len(self.routes)
        if np.asarray(history).shape[0] != O:
            raise ValueError(f"history has {np.asarray(history).shape[0]} cars, routes {O}")
        rows = np.concatenate([np.full(len(r), i) for i, r in enumerate(self.routes)])
        cl = np.concatenate([np.asarray(r, np.float64) for r in self.routes])
        if cl.shape[1] != np.asarray(context.centerline).shape[1]:
            raise ValueError(
                f"routes have {cl.shape[1]} points, the context's centre lines "
                f"{np.asarray(context.centerline).shape[1]}"
            )
        # the inner predictor sees a multiple of ROW_BUCKET rows (the last repeated): a jitted
        # predictor compiles once per bucket, not once per count of routes
        pad = -len(rows) % ROW_BUCKET
        rows = np.concatenate([rows, np.full(pad, rows[-1])])
        cl = np.concatenate([cl, np.repeat(cl[-1:], pad, axis=0)])
        ctx = replace(context.subset(rows), centerline=cl)
        k_draw, k_mix = jax.random.split(key)
        draws = np.asarray(self.inner.sample(np.asarray(history)[rows], ctx, n, k_draw))
        out = np.empty((O, n) + draws.shape[2:], draws.dtype)
        start = 0
        for i, p in enumerate(self.probabilities):
            c = _split(n, np.asarray(p, np.float64))
            parts = [draws[start + r, : c[r]] for r in range(len(c))]
            perm = np.asarray(jax.random.permutation(jax.random.fold_in(k_mix, i), n))
            out[i] = np.concatenate(parts)[perm]
            start += len(c)
        return out


# --------------------------------------------------------------------------- evaluation
def evaluate_routes(
    files,
    weights: RouteWeights | None = None,
    *,
    k: int = 20,
    stride: int = 20,
    seed: int = 1,
    weights_mdn=None,
) -> list[dict]:
    """minADE/minFDE@k and coverage (minFDE@k ≤ :data:`COVERAGE_M`) on windows of ``files``,
    over every car and over the cars with more than one route (``*_multi``), of cv, the
    lane-only predictor (``lane``), the learned MDN (``weights_mdn``; default shipped) and the
    urban one (``learned_urban``) on the straightest route, and each through
    :class:`RouteMixture` (``*_routes``: every route, ``weights``; default shipped); and the
    route accuracy of argmax P(route)."""
    import jax

    from mmdopt.predict import ConstantVelocity, LaneAware
    from mmdopt.predict.learned import Learned
    from mmdopt.predict.metrics import min_ade_fde

    from .data import windows

    weights = load_route_weights() if weights is None else weights
    W = windows(files, stride=stride)
    R = route_windows(files, stride=stride)
    from mmdopt.predict.learned import URBAN_WEIGHTS

    preds = dict(
        cv=ConstantVelocity(),
        lane=LaneAware(),
        learned=Learned(weights_mdn),
        learned_urban=Learned(URBAN_WEIGHTS),
    )
    acc: dict[str, list] = {}
    hits, multi = [], []
    pos = 0
    key = jax.random.PRNGKey(seed)
    for wi, w in enumerate(W):
        O = w.history.shape[0]
        rr = R[pos : pos + O]
        pos += O
        if any(r[0] != w.scene or abs(r[1] - w.t0) > 1e-6 for r in rr):
            raise RuntimeError("route windows out of step with the prediction windows")
        routes = tuple(r[3] for r in rr)
        probs = tuple(route_probabilities(w.history, routes, rr[0][5], weights))
        for i, r in enumerate(rr):
            multi.append(len(r[3]) > 1)
            if len(r[3]) > 1:
                hits.append(int(np.argmax(probs[i])) == taken_route(r[3], r[4]))
        kk = jax.random.fold_in(key, wi)
        for name, p in preds.items():
            for tag, pred in ((name, p), (name + "_routes", RouteMixture(p, routes, probs))):
                draws = pred.sample(w.history, w.context, k, kk)
                acc.setdefault(tag, []).append(min_ade_fde(draws, w.future))
    multi = np.asarray(multi, bool)
    out = []
    for tag, v in acc.items():
        ade = np.concatenate([a for a, _ in v])
        fde = np.concatenate([f for _, f in v])
        row = dict(predictor=tag, k=k, n_vehicles=int(ade.size), n_windows=len(W))
        for sfx, m in (("", np.ones_like(multi)), ("_multi", multi)):
            row.update(
                {
                    f"min_ade{sfx}": float(ade[m].mean()) if m.any() else float("nan"),
                    f"min_fde{sfx}": float(fde[m].mean()) if m.any() else float("nan"),
                    f"coverage{sfx}": float(np.mean(fde[m] <= COVERAGE_M)) if m.any() else 0.0,
                }
            )
        row["n_multi_route"] = int(multi.sum())
        row["route_accuracy"] = float(np.mean(hits)) if hits else float("nan")
        out.append(row)
    return out
