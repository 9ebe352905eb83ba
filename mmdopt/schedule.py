"""The risk passes around Algorithm 1: a named, typed schedule.

One :func:`mmdopt.plan` call runs Algorithm 1 once (the *first* pass) and then, in the
"samples" margin mode (the risk dial), the optional passes its method's record names
(:attr:`mmdopt.methods.PlanMethod.passes`), in this order:

==============  ==========================================================================
pass            what it does
==============  ==========================================================================
``reselect``    the reduced set plus the ``reselect`` samples in deepest conflict with the
                first plan, after the ⌊ε·n⌋ deepest (sampling and discarding), warm-started
``nearest``     against the ``nearest_futures`` futures nearest to the plan so far, with
                SAA's chance term at the hits the 95 % bound allows; repeated with one hit
                fewer while its plan's bound exceeds ε (``schedule.nearest_repeats``)
``ladder``      one pass per rung of ``schedule.margin_ladder`` (looser coverage margins),
                then one refining tail pass
``tail``        while no candidate's bound is ≤ ε: the samples the best-bounded candidate
                meets join the reduced set (at most ``schedule.tail_passes``)
==============  ==========================================================================

Every pass reads one immutable :class:`PassContext` and returns a :class:`Candidate` (its
Algorithm 1 state, the obstacle set it planned against, the samples it added); the **final
check** (:func:`final_check`) scores every candidate against all n planning samples and picks
one (:class:`ScheduleResult`).  Its random keys come from one :class:`KeyStream`; its constants
are the fields of :class:`mmdopt.config.ScheduleConfig`; its diagnostics are written into a
dict that no pass reads.  A change to the passes is a change to this module and that section.
"""

from __future__ import annotations

import enum
import functools
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from . import algorithm as alg
from .collision import OBSTACLE_FOOTPRINT, circle_centres, ellipse_values
from .config import MMDOptConfig
from .counting import (
    FutureIndex,
    Futures,
    SampleGeometry,
    plan_bound,
    risk_counts,
    sample_geometry,
    samples_met,
    smallest,
)
from .methods import PlanMethod
from .risk import CoverageData, coverage_margins, hits_for_risk, risk_floor
from .samples import ReducedSet

__all__ = [
    "PassName",
    "KeyStream",
    "PassContext",
    "Candidate",
    "ScheduleResult",
    "run_schedule",
    "runs_nearest",
    "first_config",
    "final_check",
    "plan_bound",
    "risk_counts",
    "obstacle_centres",
    "SampleGeometry",
    "sample_geometry",
    "samples_met",
    "coverage",
    "coverage_rows",
]


class PassName(enum.StrEnum):
    """The passes of the schedule (the final check's candidates are named by them)."""

    FIRST = "first"
    RESELECT = "reselect"
    NEAREST = "nearest"
    LADDER = "ladder"
    REFINE = "refine"
    TAIL = "tail"


#: the folds of the plan's key: every random stream of one plan, named (:class:`KeyStream`)
KEY_FOLDS: Mapping[str, int] = MappingProxyType(
    {
        "forecast": 0x5EED,
        "pool": 0x9001,
        "reselect": 1,
        "nearest": 0x501,
        "ladder": 0x1AD,
        "refine": 0x2EF,
        "tail": 2,
    }
)


class KeyStream:
    """The one key stream of a plan: the plan's key split into the selection's and Algorithm
    1's, and every pass's key a named fold of those (:data:`KEY_FOLDS`), so the same key gives
    the same plan and no two passes share a stream by accident."""

    def __init__(self, key: Any) -> None:
        self.key = key
        self.selection, self.cem = jax.random.split(key)

    def forecast(self) -> Any:
        """The key of a forecast's draw of the futures."""
        return jax.random.fold_in(self.key, KEY_FOLDS["forecast"])

    def pool(self) -> Any:
        """The key of the selection pool's permutation."""
        return jax.random.fold_in(self.selection, KEY_FOLDS["pool"])

    def reselect(self) -> Any:
        return jax.random.fold_in(self.cem, KEY_FOLDS["reselect"])

    def nearest(self, repeat: int) -> Any:
        base = self.cem if repeat == 0 else jax.random.fold_in(self.cem, repeat)
        return jax.random.fold_in(base, KEY_FOLDS["nearest"])

    def ladder(self, rung: int) -> Any:
        return jax.random.fold_in(self.cem, KEY_FOLDS["ladder"] + rung)

    def refine(self) -> Any:
        return jax.random.fold_in(self.cem, KEY_FOLDS["refine"])

    def tail(self, i: int) -> Any:
        return jax.random.fold_in(self.cem, KEY_FOLDS["tail"] + i)


@dataclass(frozen=True, eq=False)
class PassContext:
    """What every pass of one plan reads (never written): the workspace, config (after the risk
    mapping), the method's record, the planning problem, the planning samples in the planning
    frame, the reduced set, the projector and the key stream.  ``workspace_for(cfg)`` gives the
    workspace of another config with the same road (the nearest pass's chance level)."""

    workspace: alg.Workspace
    config: MMDOptConfig
    method: PlanMethod
    problem: alg.Problem
    obs_fr: np.ndarray
    obs_h: np.ndarray | None
    rs: ReducedSet
    projector: str
    projector_settings: Mapping[str, Any]
    keys: KeyStream
    workspace_for: Callable[[MMDOptConfig], alg.Workspace]
    #: the planning samples' :class:`~mmdopt.risk.CoverageData` (built once by the planner in
    #: the "samples" margin mode; every coverage margin of the plan reads it)
    coverage_data: CoverageData | None = None
    #: the planning samples as the counts read them (:class:`mmdopt.counting.Futures`; formed
    #: from ``obs_fr`` and ``obs_h`` when not given)
    samples: Futures | None = None

    @functools.cached_property
    def scores(self) -> dict[Candidate, tuple[float, float, np.ndarray]]:
        """The final check's score (bound, task cost, samples met) of each candidate scored so
        far in this plan (filled by the schedule)."""
        return {}

    @functools.cached_property
    def geometry(self) -> SampleGeometry:
        """The planning samples' :class:`SampleGeometry`, formed once per plan: the conflict
        depth with the config's rules of the road reads it."""
        return sample_geometry(self.obs_fr, self.obs_h)

    @functools.cached_property
    def futures(self) -> Futures:
        """The planning samples as the counts read them (:class:`mmdopt.counting.Futures`)."""
        return Futures.of(self.obs_fr, self.obs_h) if self.samples is None else self.samples

    @functools.cached_property
    def indices(self) -> list[FutureIndex]:
        """The plan's :class:`~mmdopt.counting.FutureIndex` (at most one: the first exact pass
        over every sample, against the plan the nearest-futures pass starts from or the first
        candidate of the final check); every later count and search reads it."""
        return []

    def index(self, s, d, q: np.ndarray | None = None) -> FutureIndex:
        """The plan's index, made against the plan ``s, d`` (K,) when there is none yet
        (``q``: that plan's windowed count, when already made)."""
        if not self.indices:
            a, b = float(self.config.safety.footprint.a), float(self.config.safety.footprint.b)
            self.indices.append(FutureIndex(self.futures, s, d, a, b, q))
        return self.indices[0]

    def trajectory(self, best) -> tuple[np.ndarray, np.ndarray]:
        """The positions ``s, d`` (K,) of a state's plan (:class:`mmdopt.algorithm.Best`)."""
        B = self.workspace.basis
        return B.P @ np.asarray(best.cx, np.float64), B.P @ np.asarray(best.cy, np.float64)

    def centres(self, idx: np.ndarray) -> jax.Array:
        """Footprint circle centres (O, J, C, K, 2) of the samples ``idx`` (O, J)."""
        return obstacle_centres(self.obs_fr, self.obs_h, idx)

    def run(self, obstacles: alg.ObstacleSet, key: Any, warm: alg.CEMState | None,
            config: MMDOptConfig | None = None) -> alg.CEMState:  # fmt: skip
        """Algorithm 1 against ``obstacles`` (:func:`mmdopt.algorithm.run`), to completion."""
        cfg = self.config if config is None else config
        ws = self.workspace if config is None else self.workspace_for(cfg)
        out = alg.run(ws, cfg, self.problem, obstacles, key, self.projector, warm_start=warm,
                      **self.projector_settings)  # fmt: skip
        return jax.block_until_ready(out)

    def warm(self, state: alg.CEMState) -> alg.CEMState:
        """``state`` as the warm start of the next pass (re-timed by 0 s)."""
        return alg.shift(self.config, state, 0.0)


@dataclass(frozen=True, eq=False)
class Candidate:
    """One pass's outcome: its name, Algorithm 1 state, the obstacle set it planned against,
    that set's sample indices (O, J; the nearest pass's pooled set: (1, P) positions, their
    obstacles in ``diagnostics["nearest_pairs"]``), the indices it added to the reduced set
    (``None``: none) and the coverage level of its margins (``None``: ε)."""

    name: PassName
    state: alg.CEMState
    obstacles: alg.ObstacleSet
    indices: np.ndarray
    extra: np.ndarray | None = None
    level: float | None = None


@dataclass(frozen=True, eq=False)
class ScheduleResult:
    """The schedule's choice: the chosen candidate; the obstacle set of the last pass that
    changed the reduced set (what :attr:`mmdopt.Plan.mmd` is measured against); ``met``: the
    chosen plan's ``(cx, cy)`` and the (O, n) planning samples it meets, when the final check
    counted them (``None`` otherwise)."""

    chosen: Candidate
    reduced: alg.ObstacleSet
    met: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None


# ------------------------------------------------------------------------------ shared tools
def obstacle_centres(obs_fr, obs_h, idx=None) -> jax.Array:
    """Footprint circle centres (O, J, C, K, 2) of the samples ``idx`` (O, J) of ``obs_fr``
    (all when None), along ``obs_h`` (O, n, K) where given, else along each sample's motion."""
    sel, h = obs_fr, obs_h
    if idx is not None:
        idx = np.asarray(idx)
        sel = np.take_along_axis(obs_fr, idx[:, :, None, None], axis=1)
        h = None if obs_h is None else np.take_along_axis(obs_h, idx[:, :, None], axis=1)
    hj = None if h is None else jnp.asarray(h)
    return circle_centres(jnp.asarray(sel), OBSTACLE_FOOTPRINT, hj)


def coverage_rows(config: MMDOptConfig, n: int) -> np.ndarray | None:
    """The samples every coverage margin of a plan is estimated from: all n (``None``), or
    beyond ``schedule.coverage_pool`` that many evenly spaced draws (i.i.d. futures: the same
    clusters' spread from a fraction of the work; the points themselves always join)."""
    R = int(config.schedule.coverage_pool)
    return None if n <= R else np.linspace(0, n - 1, R).round().astype(np.int64)


def coverage(
    config: MMDOptConfig, obs_fr, idx, level=None, knn: int = 0, data: CoverageData | None = None,
    pool: np.ndarray | None = None,
) -> np.ndarray:  # fmt: skip
    """:func:`mmdopt.risk.coverage_margins` of the points ``idx`` among ``obs_fr`` at ``level``
    (default: the risk level ε) with ``config``'s coverage settings (every pass plans with
    these); ``data``: the samples' :class:`~mmdopt.risk.CoverageData` (the pass context's);
    ``pool``: the samples the k-NN clusters are formed among (``None``: all)."""
    return coverage_margins(
        obs_fr,
        idx,
        float(config.safety.risk) if level is None else float(level),
        lateral_scale=float(config.selection.rs_lateral_scale),
        prior=float(config.safety.margins.coverage_prior),
        knn=knn,
        bandwidth=float(config.safety.margins.coverage_bandwidth),
        data=data,
        pool=pool,
    )


def _plain_depth(config: MMDOptConfig) -> bool:
    """Whether the conflict depth is the count's own measure (no rule of the road widens or
    exempts: the nominal ellipse, ``1 − q``), so that the index serves it."""
    return not (config.safety.rules.asymmetric or config.safety.footprint.yaw_aware)


def _conflict_depth(ctx: PassContext, best) -> np.ndarray:
    """(O, n) deepest conflict over time of the plan ``best`` with every planning sample: the
    nominal ellipse ``a, b`` with the geometry and responsibility rules of the config (yaw
    widening, rear exemption); > 0 where the plan enters a sample's ellipse.  Without rules it
    is ``1 − q`` of the count (:mod:`mmdopt.counting`), and that pass makes the plan's index."""
    s1, d1 = ctx.trajectory(best)
    if _plain_depth(ctx.config):
        if not ctx.indices:  # the first pass over every sample: it makes the plan's index
            return 1.0 - ctx.index(s1, d1).q_ref
        ref = ctx.indices[0]
        if np.array_equal(ref.ref_s, s1) and np.array_equal(ref.ref_d, d1):
            return 1.0 - ref.q_ref
        return _depth_full(ctx, s1, d1)
    Bs = ctx.workspace.basis
    vs1 = (Bs.Pdot @ np.asarray(best.cx, np.float64))[None]
    vd1 = (Bs.Pdot @ np.asarray(best.cy, np.float64))[None]
    return np.asarray(
        _depth_values(ctx.config.program(), s1[None], d1[None], vs1, vd1, ctx.geometry)
    )


def _depth_full(ctx: PassContext, s, d) -> np.ndarray:
    a, b = float(ctx.config.safety.footprint.a), float(ctx.config.safety.footprint.b)
    return 1.0 - ctx.futures.q(s[None], d[None], a, b)[0, ..., 0].astype(np.float64)


def _deepest(ctx: PassContext, best, M: int) -> np.ndarray:
    """(O, M) the positions, ascending, of the M planning samples in deepest conflict with the
    plan ``best`` (:func:`_conflict_depth`; ties to the lower position); with the plain depth the
    plan's index finds them from a few candidates when it can."""
    if _plain_depth(ctx.config) and ctx.indices:
        s1, d1 = ctx.trajectory(best)
        near = ctx.indices[0].nearest(s1, d1, M)
        if near is not None:
            return np.sort(near, axis=1)
    return smallest(-_conflict_depth(ctx, best), M)


@jax.jit
def _depth_values(config: MMDOptConfig, s1, d1, vs1, vd1, geo: SampleGeometry):
    # one compiled program per shape for _conflict_depth (eagerly: a program per op and shape);
    # the circles are formed here, so XLA fuses them into the reduction: the (O, n, C, K)
    # centres of all n samples are never stored (at n = 50 000 they were 240 MB)
    b = jnp.asarray(config.safety.footprint.b)
    if config.safety.footprint.yaw_aware:
        b = b + alg.yaw_widening(config, vs1, vd1)  # (1, K)
    rear = float(config.safety.rules.rear_exempt_width) if config.safety.rules.asymmetric else None
    depth = None
    for c in range(geo.r.shape[0]):  # one circle at a time: each a fused loop over the samples
        cs, cd = geo.circle(c)
        f = ellipse_values(s1, d1, (cs[:, :, None], cd[:, :, None]), config.safety.footprint.a,
                           b, rear_exempt_width=rear)  # fmt: skip
        m = jnp.max(f[0, :, :, 0], axis=-1)  # (O, n)
        depth = m if depth is None else jnp.maximum(depth, m)
    return depth


def _bounds_of(ctx: PassContext, cands) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The 95 % risk bound (C,), task cost (C,) and planning samples met (C, O, n) of the
    candidates' best plans against every planning sample; a candidate scored before in this
    plan (the nearest pass's check, then the final check) is read from
    :attr:`PassContext.scores`, not counted again."""
    new = [c for c in dict.fromkeys(cands) if c not in ctx.scores]
    if new:
        for c, score in zip(new, zip(*_score(ctx, new), strict=True), strict=True):
            ctx.scores[c] = score
    bound, task, hits = zip(*(ctx.scores[c] for c in cands), strict=True)
    return np.array(bound), np.array(task), np.stack(hits)


def _score(ctx: PassContext, cands) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    config, B = ctx.config, ctx.workspace.basis
    bests = [c.state.best for c in cands]
    cx = np.stack([np.asarray(b.cx, np.float64) for b in bests])
    cy = np.stack([np.asarray(b.cy, np.float64) for b in bests])
    s, d = cx @ B.P.T, cy @ B.P.T
    hits = ctx.index(s[0], d[0]).met(s, d)  # the first exact pass makes the index
    bound = np.array([plan_bound(config, h) for h in hits])
    vs, as_, ad = cx @ B.Pdot.T, cx @ B.Pddot.T, cy @ B.Pddot.T
    c = config.cost
    task = c.w_speed * np.mean((vs - c.v_des) ** 2, -1) + c.w_accel * np.mean(as_**2 + ad**2, -1)
    ok = np.array([math.isfinite(float(b.cost)) and float(b.res) <= config.projection.res_tol
                   for b in bests])  # fmt: skip
    return np.where(ok, bound, np.inf), task, hits


def _extended(ctx: PassContext, idx: np.ndarray, extra: np.ndarray, level=None):
    """The obstacle set of the reduced set ``idx`` plus ``extra`` (O, r) samples of weight 1/n
    each (the reduced set's weights scaled by 1 − r/n), with coverage margins at ``level``
    ("samples" mode) or the time-linear ones."""
    config = ctx.config
    n = ctx.obs_fr.shape[1]
    r = extra.shape[1]
    full = np.concatenate([idx, extra], axis=1)
    w = np.concatenate(
        [np.asarray(ctx.rs.weights, np.float64) * (1.0 - r / n),
         np.full((idx.shape[0], r), 1.0 / n)], 1
    )  # fmt: skip
    margins = None
    if config.safety.margins.margin_mode == "samples":
        margins = coverage(config, ctx.obs_fr, full, level, data=ctx.coverage_data)
    obstacles = alg.ObstacleSet.create(
        config, ctx.centres(full), w, ctx.method.collision, margins=margins
    )
    return obstacles, full


# ------------------------------------------------------------------------------------ passes
def _nearest_iterations(config: MMDOptConfig) -> int:
    """Algorithm 1's iterations in a nearest-futures pass: ``schedule.nearest_share`` of the
    config's N (at least 1); the first pass runs the rest (:func:`first_config`)."""
    N = int(config.cem.iterations)
    return max(1, min(N - 1, round(float(config.schedule.nearest_share) * N))) if N > 1 else 1


def runs_nearest(config: MMDOptConfig, method: PlanMethod, n: int, obstacles: int) -> bool:
    """Whether a plan of ``method`` on ``n`` planning futures of ``obstacles`` obstacles runs the
    nearest-futures pass: its record names it, ``safety.nearest_futures`` > 0, the "samples"
    margin mode, and ε at or above what the n futures can confirm (below it there is no
    allowance for the pass to use: the margins alone extrapolate the tail the futures do not
    show)."""
    return (
        method.runs("nearest")
        and config.safety.nearest_futures > 0
        and config.safety.margins.margin_mode == "samples"
        and risk_floor([n] * config.bound_groups(obstacles)) <= float(config.safety.risk)
    )


def first_config(config: MMDOptConfig, method: PlanMethod, n: int, obstacles: int):
    """The config of the first pass: when the nearest-futures pass follows
    (:func:`runs_nearest`), the two share Algorithm 1's N iterations
    (``schedule.nearest_share``) and the first runs N minus the nearest pass's; else
    ``config`` itself."""
    N = int(config.cem.iterations)
    if N < 2 or not runs_nearest(config, method, n, obstacles):
        return config
    return config.replace(iterations=N - _nearest_iterations(config))


def reselect_pass(ctx: PassContext, first: Candidate, diag: dict) -> Candidate | None:
    """The re-selection pass (``safety.reselect`` = r > 0): the reduced set plus the r samples
    in deepest conflict with the first plan (weight 1/n each) after the ⌊ε·n⌋ deepest (the
    conflicts a chance constraint at level ε may leave, as in sampling-and-discarding, Campi &
    Garatti 2011), warm-started from the first pass; ``None`` when no sample is left to add.
    Conflict is measured on the nominal ellipse with the config's geometry and rules; the
    margins of the config's margin mode then apply to the added samples."""
    config = ctx.config
    O, n = ctx.obs_fr.shape[:2]
    depth = _conflict_depth(ctx, first.state.best)  # (O, n)
    idx0 = np.asarray(ctx.rs.indices)
    k = int(math.floor(float(config.safety.risk) * n))
    r = min(int(config.safety.reselect), n - idx0.shape[1] - k)
    if r <= 0:
        return None
    d = depth.copy()
    np.put_along_axis(d, idx0, -np.inf, axis=1)  # already in the reduced set
    order = np.argsort(-d, axis=1, kind="stable").astype(idx0.dtype)
    extra = order[:, k : k + r]
    obstacles, full = _extended(ctx, idx0, extra)
    diag.update(reselected=extra, discarded=order[:, :k], conflict_depth=depth)
    state = ctx.run(obstacles, ctx.keys.reselect(), ctx.warm(first.state))
    return Candidate(PassName.RESELECT, state, obstacles, full, extra)


def _nearest_pairs(ctx: PassContext, best, M: int) -> np.ndarray:
    """(M, 2) the (obstacle, position) pairs, in ascending order, of the M planning samples of
    all obstacles in deepest conflict with the plan ``best`` (ties to the lower obstacle, then
    position).  With the plain depth, per obstacle its M deepest through the plan's index
    (:func:`_deepest`), then the M deepest of those; with the rules' depth, the M deepest of
    the one full pass of :func:`_conflict_depth`."""
    O, n = ctx.obs_fr.shape[:2]
    if not _plain_depth(ctx.config):
        flat = smallest(-_conflict_depth(ctx, best).reshape(1, -1), M)[0]
        return np.stack(np.divmod(flat, n), -1)
    per = _deepest(ctx, best, min(M, n))  # (O, min(M, n))
    if O == 1:
        return np.stack([np.zeros(per.shape[1], np.int64), per[0]], -1)
    s1, d1 = ctx.trajectory(best)
    a, b = float(ctx.config.safety.footprint.a), float(ctx.config.safety.footprint.b)
    q = ctx.futures.subset(per).q(s1[None], d1[None], a, b)[0, ..., 0]  # (O, m): 1 − depth
    flat = smallest(q.astype(np.float64).reshape(1, -1), M)[0]
    o, i = np.divmod(flat, per.shape[1])
    return np.stack([o, per[o, i]], -1)


def _nearest_pass(
    ctx: PassContext, start: Candidate, fewer: int
) -> tuple[Candidate, float, np.ndarray]:
    """One nearest-futures pass from ``start``: Algorithm 1 against the M = min(O·n,
    ``nearest_futures``) planning samples of all obstacles together in deepest conflict with its
    plan (one set, padded to ``nearest_futures``, padding masked out: the pass costs the same
    for any number of obstacles), weight 1/M each, k-NN coverage margins among each sample's own
    obstacle at the loose level min(``nearest_margin_factor`` · ε, ``level_cap``), and SAA's
    chance term at level (k + ½)/M, k = :func:`mmdopt.risk.hits_for_risk` (ε, n, G) − ``fewer``
    (≥ 0): a joint future met through two obstacles counts twice, so the term is conservative;
    returns the candidate (its ``indices`` (1, P): the positions of the pooled samples), its
    chance level and the M (obstacle, position) pairs it planned against."""
    config, obs_fr, sched = ctx.config, ctx.obs_fr, ctx.config.schedule
    O, n = obs_fr.shape[:2]
    P = int(config.safety.nearest_futures)  # one compiled program for every n and O: pad to P
    M = min(O * n, P)
    if M < O * n:
        pairs = _nearest_pairs(ctx, start.state.best, M)
    else:
        pairs = np.stack(np.divmod(np.arange(O * n), n), -1)
    pairs = np.concatenate([pairs, np.repeat(pairs[:1], P - M, axis=0)])  # (P, 2)
    mask = (np.arange(P) < M)[None]
    G = config.bound_groups(O)
    k = max(hits_for_risk(float(config.safety.risk), int(n), G) - int(fewer), 0)
    k = min(k, M - 1)  # a level below 1 (with as many hits as futures seen, all may be met)
    cfg = config.replace(saa_eps=(k + 0.5) / M, iterations=_nearest_iterations(config))
    level = min(float(sched.nearest_margin_factor) * float(config.safety.risk),
                float(sched.level_cap))  # fmt: skip
    knn = max(2, n // config.selection.reduced_set_size)
    R = int(sched.coverage_pool)
    data = ctx.coverage_data
    if n > R:  # the clusters among R evenly spaced draws: the same neighbourhoods, R/n the work
        knn = max(2, round(knn * R / n))
    margins = np.empty((3, 1, P, obs_fr.shape[2]))
    for o in np.unique(pairs[:, 0]):  # each sample's margins among its own obstacle's samples
        at = np.flatnonzero(pairs[:, 0] == o)
        data_o = None if data is None else data.obstacle(int(o))
        pool = None
        if n > R and (data_o is None or data_o.rows is None):
            pool = coverage_rows(config, n)[None]
        margins[:, 0, at] = coverage(config, obs_fr[o : o + 1], pairs[at, 1][None], level, knn,
                                     data_o, pool)[:, 0]  # fmt: skip
    sel = obs_fr[pairs[:, 0], pairs[:, 1]][None]  # (1, P, K, 2)
    h = None if ctx.obs_h is None else ctx.obs_h[pairs[:, 0], pairs[:, 1]][None]
    obstacles = alg.ObstacleSet.create(
        cfg, obstacle_centres(np.asarray(sel, np.float64), h), np.where(mask, 1.0 / M, 0.0),
        "chance", mask=mask, margins=margins,
    )  # fmt: skip
    state = ctx.run(obstacles, ctx.keys.nearest(fewer), ctx.warm(start.state), config=cfg)
    cand = Candidate(PassName.NEAREST, state, obstacles, pairs[None, :, 1], level=level)
    return cand, (k + 0.5) / M, pairs[:M]


def nearest_passes(ctx: PassContext, start: Candidate, diag: dict) -> list[Candidate]:
    """MMD-Opt's nearest-futures pass (:func:`_nearest_pass`) from ``start``, then while the last
    one's plan has a bound against all n futures above ε up to ``schedule.nearest_repeats``
    more around that plan, each allowing one hit fewer.  The reduced set decides where the plan
    goes; these passes let it pass as close to the futures that matter as the bound allows."""
    t0 = time.perf_counter()
    eps = float(ctx.config.safety.risk)
    first, level, pairs = _nearest_pass(ctx, start, 0)
    out, levels = [first], [level]
    for rep in range(1, int(ctx.config.schedule.nearest_repeats) + 1):
        if _bounds_of(ctx, [out[-1]])[0][0] <= eps:
            break
        nxt, level, _ = _nearest_pass(ctx, out[-1], rep)
        out.append(nxt)
        levels.append(level)
    if ctx.obs_fr.shape[0] == 1:  # the positions among the one obstacle's samples
        diag["nearest_futures"] = np.sort(pairs[:, 1])[None]
    diag.update(
        nearest_pairs=pairs,
        nearest_level=levels[0],
        nearest_levels=levels,
        nearest_s=time.perf_counter() - t0,
        # Algorithm 1's iterations in the first pass and in each nearest-futures pass
        pass_iterations=(
            int(ctx.config.cem.iterations) - _nearest_iterations(ctx.config),
            _nearest_iterations(ctx.config),
        ),
    )
    return out


def _rung_level(eps: float, factor: float, cap: float) -> float:
    return min(factor * eps, cap)


def ladder_passes(ctx: PassContext, start: Candidate, base: Candidate) -> list[Candidate]:
    """The passes of ``schedule.margin_ladder``: Algorithm 1 on ``base``'s obstacle set (the
    last reduced set) with coverage margins at each rung's level (a rung no looser than the one
    before is skipped), the first warm-started from ``start``, each next from the one before."""
    config = ctx.config
    ladder = config.schedule.margin_ladder
    if not ladder or base.obstacles.margins is None:
        return []
    if base.indices.shape != tuple(base.obstacles.weights.shape):
        return []
    eps, cap = float(config.safety.risk), float(config.schedule.level_cap)
    out: list[Candidate] = []
    levels = [eps]
    state = start.state
    for i, factor in enumerate(ladder):
        level = _rung_level(eps, factor, cap)
        if level <= levels[-1]:
            continue
        levels.append(level)
        ob = base.obstacles
        obstacles = alg.ObstacleSet.create(
            config, ob.centres, ob.weights, ob.mode, mask=ob.mask,
            margins=coverage(config, ctx.obs_fr, base.indices, level, data=ctx.coverage_data),
        )  # fmt: skip
        state = ctx.run(obstacles, ctx.keys.ladder(i), ctx.warm(state))
        out.append(Candidate(PassName.LADDER, state, obstacles, base.indices, level=level))
    return out


def tail_pass(
    ctx: PassContext, start: Candidate, hits, prev_extra, key, name: PassName, level=None
) -> Candidate | None:
    """One more pass, warm-started from ``start``, on the reduced set plus r extra points (r =
    the re-selection size, m/2 where that is off: one compiled program for every such pass):
    first the planning samples ``hits`` (O, n) that ``start``'s plan meets, then the extra
    points of the previous pass (``prev_extra``), weight 1/n each; coverage margins at ε, or at
    ``level``; ``None`` when it meets no sample outside the reduced set."""
    config = ctx.config
    O, n = ctx.obs_fr.shape[:2]
    m = config.selection.reduced_set_size
    r = ctx.method.reselect(config) or max(1, m // 2)
    idx0 = np.asarray(ctx.rs.indices)
    h = np.asarray(hits, bool).copy()
    np.put_along_axis(h, idx0, False, axis=1)
    if not h.any():
        return None
    extra = np.empty((O, r), idx0.dtype)
    for o in range(O):  # a handful of obstacles
        cand = list(np.flatnonzero(h[o]))
        if prev_extra is not None:
            cand += [int(i) for i in np.asarray(prev_extra)[o] if not h[o, i]]
        cand = list(dict.fromkeys(cand)) or [int(idx0[o, 0])]
        extra[o] = (cand * r)[:r]  # repeats pad an obstacle with fewer (weight split below)
    obstacles, full = _extended(ctx, idx0, extra, level)  # tails run in the "samples" mode
    state = ctx.run(obstacles, key, ctx.warm(start.state))
    return Candidate(name, state, obstacles, full, extra, level)


# ----------------------------------------------------------------------------- final check
class _Scored:
    """The final check's candidates and their bound, task cost and samples met (appended as
    passes are added)."""

    def __init__(self, ctx: PassContext, cands: list[Candidate]) -> None:
        self.ctx, self.cands = ctx, list(cands)
        self.bound, self.task, self.hits = _bounds_of(ctx, self.cands)

    def add(self, cand: Candidate) -> None:
        b, t, h = _bounds_of(self.ctx, [cand])
        self.cands.append(cand)
        self.bound = np.concatenate([self.bound, b])
        self.task = np.concatenate([self.task, t])
        self.hits = np.concatenate([self.hits, h])


def _refine(ctx: PassContext, sc: _Scored, first_rung: int, eps: float, prev_extra):
    """One tail pass from the cheapest ladder candidate that meets planning samples (bound > ε)
    while costing less than every candidate whose bound is ≤ ε: the samples it meets join the
    reduced set, the margins at its rung's level; returns the added candidate or ``None``."""
    good = sc.bound <= eps
    best_good = np.min(sc.task[good]) if good.any() else np.inf
    cand = [
        i
        for i in range(first_rung, len(sc.cands))
        if np.isfinite(sc.bound[i]) and not good[i] and sc.task[i] < best_good and sc.hits[i].any()
    ]
    if not cand:
        return None
    j = min(cand, key=lambda i: sc.task[i])
    nxt = tail_pass(ctx, sc.cands[j], sc.hits[j], prev_extra, ctx.keys.refine(), PassName.REFINE,
                    level=sc.cands[j].level)  # fmt: skip
    if nxt is not None:
        sc.add(nxt)
    return nxt


def final_check(ctx: PassContext, passes: list[Candidate], base: Candidate,
                diag: dict) -> ScheduleResult:  # fmt: skip
    """The risk dial's final check ("samples" margin mode): every candidate's best plan is
    scored against **all** n planning samples and its :func:`mmdopt.risk.risk_bound` computed
    (with the ladder's candidates, for a method that runs it); while no candidate's bound is ≤ ε
    (and the method runs tail passes) up to ``schedule.tail_passes`` more passes
    (:func:`tail_pass`).  ε here is at least the floor of the n samples
    (:func:`mmdopt.risk.risk_floor`).  The choice: among candidates with bound ≤ ε the one of
    least task cost (speed tracking and comfort, the terms every pass shares), else the one of
    least bound (its status then says "risk exceeded").  ``base`` is the last candidate that
    changed the reduced set (the first or the re-selection pass)."""
    config, method = ctx.config, ctx.method
    n = ctx.obs_fr.shape[1]
    G = config.bound_groups(ctx.obs_fr.shape[0])
    eps = max(float(config.safety.risk), risk_floor([n] * G) * (1 + 1e-9))
    ladder = ladder_passes(ctx, passes[-1], base) if method.runs("ladder") else []
    sc = _Scored(ctx, list(passes) + ladder)
    reduced, prev_extra = base, base.extra
    if ladder:
        nxt = _refine(ctx, sc, len(passes), eps, prev_extra)
        if nxt is not None:
            reduced, prev_extra = nxt, nxt.extra
    tails = 0
    limit = int(config.schedule.tail_passes) if method.runs("tail") else 0
    while not np.any(sc.bound <= eps) and tails < limit:
        j = int(np.argmin(sc.bound))
        if not np.isfinite(sc.bound[j]) or not sc.hits[j].any():
            break
        nxt = tail_pass(ctx, sc.cands[j], sc.hits[j], prev_extra, ctx.keys.tail(tails),
                        PassName.TAIL)  # fmt: skip
        if nxt is None:
            break
        sc.add(nxt)
        reduced, prev_extra = nxt, nxt.extra
        tails += 1
    good = np.flatnonzero(sc.bound <= eps)
    j = int(good[np.argmin(sc.task[good])]) if good.size else int(np.argmin(sc.bound))
    if not np.isfinite(sc.bound[j]):
        j = len(passes) - 1
    diag.update(
        final_check_bounds=sc.bound,
        final_check_task=sc.task,
        final_check_choice=j,
        final_check_passes=[str(c.name) for c in sc.cands],
        tail_passes=tails,
    )
    if prev_extra is not None and reduced.name in (PassName.TAIL, PassName.REFINE):
        diag["tail_extra"] = prev_extra
    best = sc.cands[j].state.best
    met = (np.asarray(best.cx, np.float64), np.asarray(best.cy, np.float64), sc.hits[j])
    return ScheduleResult(sc.cands[j], reduced.obstacles, met)


def run_schedule(ctx: PassContext, first: Candidate, diag: dict) -> ScheduleResult:
    """The passes after the first (``first``: Algorithm 1 on the method's own selection) that
    the method's record and the config ask for, then, in the "samples" margin mode, the final
    check; diagnostics of every pass are written into ``diag``."""
    config, method = ctx.config, ctx.method
    passes, base = [first], first
    if config.safety.reselect > 0 and method.runs("reselect"):
        nxt = reselect_pass(ctx, first, diag)
        if nxt is not None:
            passes.append(nxt)
            base = nxt
    if config.safety.margins.margin_mode != "samples":
        return ScheduleResult(passes[-1], base.obstacles)
    if runs_nearest(config, method, ctx.obs_fr.shape[1], ctx.obs_fr.shape[0]):
        passes += nearest_passes(ctx, passes[-1], diag)
    return final_check(ctx, passes, base, diag)
