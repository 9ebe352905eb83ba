"""Algorithm 1 (paper): sampling-based MMD-augmented trajectory optimisation in the Frenet frame.

A pure step API in the optax/jaxopt manner; a :class:`mmdopt.Planner` holds the
:class:`Workspace` (what is compiled and factorised) and the config, and the state holds arrays
only::

    planner = mmdopt.Planner(config)
    problem = planner.problem(ego, road)                     # ego state, sampling prior, bounds
    obstacles = alg.ObstacleSet.create(config, centres, weights, "mmd")
    state = planner.init(problem, key)                       # CEMState (a pytree of arrays)
    for _ in range(config.cem.iterations):
        state = planner.update(problem, state, obstacles)    # one CEM iteration
    state = planner.run(problem, obstacles, key)             # the same, one jitted scan
    state.best, state.least_violating, state.cost_trace
    warm = planner.shift(state, dt=0.1)                      # receding horizon: shifted in time
    state = planner.run(problem_next, obstacles_next, key, warm_start=warm)

The functions below take the workspace and the config explicitly
(``alg.run(planner.workspace(road.bounds()), config, problem, obstacles, key)``).

One CEM/MPPI iteration ``l`` (paper Alg. 1 lines 4–14, with the reference code's bugs fixed)::

    d_r ~ N(μ_l, Σ_l), r = 1 … n̄_cem           behavioural inputs (speed, lateral set-points)
        rows: the n_e elites of iteration l−1, n_brake "brake in lane" rows, fresh draws
    c̄_r   = Frenet planner(d_r)                 closed form (one matrix product)
    c_r   = projection(c̄_r)                     kinematic + lane constraints (batched ADMM)
    res_r = constraint residual of c_r          max violation on the time grid (m, m/s, m/s²)
        (planned and projected chunk by chunk until n_cem rows are feasible: no later row can
         enter the ConstraintEliteSet below, so the rest are not computed; project_rows)
    ConstraintEliteSet = n_cem lowest res_r     (residuals below ``res_tol`` count as 0; ties go
                                                 to elites, then brake rows, then fresh draws)
    cost_r = w_speed·mean_k (ṡ_k − v_des)²                      progress (m²/s²)
           + w_accel·mean_k (s̈_k² + d̈_k²)                      comfort ((m/s²)²)
           + collision term (w_mmd·l_dist for MMD-Opt)          eq. (c_aug)
           + w_res·res_r                                        c(·) of eq. (s_formula)
    EliteSet = n_e lowest cost_r
    s_r = exp(−(cost_r − min cost)/γ)                                 eq. (s_formula)
    μ ← (1−η)μ + η Σ s_r d_r/Σ s_r                                    eq. (mean_update)
    Σ ← (1−η)Σ + η Σ s_r (d_r − μ)(d_r − μ)ᵀ/Σ s_r + ε I              eq. (cov_update)

**What is returned: the lowest-cost elite over all iterations** (best-so-far, tracked in the
state), not the lowest-residual sample (the reference code's bug).  The cost trace is the
best-so-far cost per iteration (non-increasing); the per-iteration minimum is kept too.

Fixes of the reference code: a fresh PRNG key every iteration; lateral set-points sampled
with a spread matched to the lane bounds; "brake in lane" rows as a ladder of constant speed
set-points from ``v_min`` to the current speed; each projection warm-started from its own planner
output with zero duals; every constant in :class:`MMDOptConfig`.

**Projectors.**  :data:`PLANNER_PROJECTOR` = ``"admm-fixed"`` (default): the projection
is :meth:`frenet.ProjectionProblem.jax_projector` (a fixed ADMM iteration budget, warm-started,
boundary rows corrected exactly) inside the jitted step, so :func:`run` is one ``jit``
(``lax.scan`` over the iterations).  Any :mod:`solvers` backend name (``"admm"``, ``"clarabel"``,
``"osqp"``, ...) projects on the host each iteration through the registry
(:meth:`frenet.ProjectionProblem.project`), with sampling and cost still jitted.
"""

from __future__ import annotations

import math
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

import frenet

from ._x64 import x64
from .collision import compact_order
from .config import SAA_EPS_LINEAR, W_COVER, MMDOptConfig  # noqa: F401 (re-exported)
from .cost import (  # noqa: F401 (re-exported)
    YAW_SPEED_FLOOR,
    headway_semi_axis,
    margin_ellipse_values,
    obstacle_cost,
    planning_semi_axis,
    yaw_widening,
)
from .problem import (  # noqa: F401 (re-exported)
    ObstacleSet,
    Problem,
    bounds_from_key,
    bounds_key,
    n_taylor_terms,
    statics,
)

__all__ = [
    "PLANNER_PROJECTOR",
    "PLANNER_BACKEND",
    "MMDOptConfig",
    "Problem",
    "ObstacleSet",
    "Best",
    "CEMState",
    "Workspace",
    "Workspace",
    "statics",
    "bounds_key",
    "bounds_from_key",
    "init",
    "update",
    "run",
    "shift",
    "planning_semi_axis",
    "margin_ellipse_values",
    "headway_semi_axis",
    "slip_residual",
    "INFEASIBLE_COST",
    "n_taylor_terms",
    "check_backend",
    "project_rows",
    "project_chunk_size",
    "cost_chunk_size",
]

#: the planner's own projection: the jitted fixed-budget ADMM projector inside the CEM step
PLANNER_PROJECTOR = "admm-fixed"
#: the former name of :data:`PLANNER_PROJECTOR` (the CLI's ``--backend`` default)
PLANNER_BACKEND = PLANNER_PROJECTOR


#: added to the cost of a row beyond ``res_tol`` when the slip limit is on
#: (``safety.rules.slip_ratio`` > 0)
INFEASIBLE_COST = 1.0e12


class Workspace:
    """What Algorithm 1 builds once for one (static config, road bounds) pair: the Bernstein
    basis, the Frenet planner's closed form, the projection QP with its factorisation and
    jitted projector, and the jitted steps of Algorithm 1 (``init``, ``step``, ``run``, and
    the sampling and scoring halves of a host-projected step).

    :class:`mmdopt.Planner` owns its workspaces; nothing here is global.
    """

    def __init__(self, cfg: MMDOptConfig, bounds: frenet.ProjectionBounds):
        grid = frenet.TimeGrid(cfg.trajectory.horizon, cfg.trajectory.num_steps)
        self.basis = frenet.BernsteinBasis(grid, degree=cfg.trajectory.degree)
        self.planner = frenet.BehaviouralPlanner(
            self.basis,
            frenet.PlannerConfig(
                num_segments=cfg.trajectory.num_segments, k_p=cfg.trajectory.lateral_gain
            ),
        )
        self.bounds = bounds
        self.bounds_key = bounds_key(bounds)
        self.projection = frenet.ProjectionProblem(
            self.basis, bounds, constraint_points=cfg.projection.constraint_points
        )
        # residuals are always reported on the full grid
        self.grid_projection = (
            self.projection
            if cfg.projection.constraint_points == "grid"
            else frenet.ProjectionProblem(self.basis, bounds, constraint_points="grid")
        )
        self.projector = self.projection.jax_projector(
            num_iters=cfg.projection.admm_iters,
            dtype=cfg.cem.dtype,
            check_every=min(cfg.projection.admm_check_every, cfg.projection.admm_iters),
            # None: the projector's measured defaults (start at rho = 62.5, adaptive)
            **(
                {}
                if cfg.projection.admm_rho is None
                else dict(rho=float(cfg.projection.admm_rho), adaptive_rho=False)
            ),
        )
        self.nvar = self.basis.nvar
        self.W = np.asarray(self.planner.W)
        self.P = np.asarray(self.basis.P)
        self.Pdot = np.asarray(self.basis.Pdot)
        self.Pddot = np.asarray(self.basis.Pddot)
        # Algorithm 1's jitted steps, with this workspace's constants closed over
        self.init = jax.jit(partial(_init, self))
        self.step = jax.jit(partial(_step, self))
        self.run = jax.jit(partial(_run_fixed, self))
        self.sample = jax.jit(partial(_sample_plan, self))
        self.evaluate = jax.jit(partial(_evaluate_host, self))

    def t(self) -> np.ndarray:
        return self.basis.grid.t


class Best(NamedTuple):
    """One evaluated sample: the best-so-far (lowest cost) or the least violating."""

    cost: Any  # ()
    d: Any  # (D,) behavioural input
    cx: Any  # (nvar,) projected coefficients, longitudinal
    cy: Any  # (nvar,) lateral
    res: Any  # () constraint residual
    coll: Any  # () collision term (unweighted)
    iteration: Any  # () int, the iteration it was found in (-1: none yet)


class CEMState(NamedTuple):
    """The state of Algorithm 1 between iterations: arrays only (a pytree; see :func:`init`).
    The config and the :class:`Problem` it was made for are passed beside it."""

    mu: Any  # (D,) sampling mean
    cov: Any  # (D, D) sampling covariance
    elites: Any  # (n_elite, D) elites carried into the next batch
    best: Best  # lowest cost so far
    least_violating: Best  # lowest residual so far (fallback)
    iteration: Any  # () int32, iterations done
    keys: Any  # (N, ...) one PRNG key per iteration
    cost_trace: Any  # (N,) best-so-far cost after each iteration
    iter_min_cost: Any  # (N,) lowest cost of each iteration's ConstraintEliteSet
    iter_mean_elite_cost: Any  # (N,)
    n_feasible: Any  # (N,) projected samples with residual ≤ res_tol per iteration
    n_projected: (
        Any  # (N,) samples planned and projected per iteration (config.projection.project_chunk)
    )


def _empty_best(D, n, dt) -> Best:
    return Best(
        cost=jnp.asarray(jnp.inf, dt),
        d=jnp.zeros((D,), dt),
        cx=jnp.zeros((n,), dt),
        cy=jnp.zeros((n,), dt),
        res=jnp.asarray(jnp.inf, dt),
        coll=jnp.asarray(0.0, dt),
        iteration=jnp.asarray(-1, jnp.int32),
    )


def _cast(tree, dt):
    return jax.tree_util.tree_map(
        lambda x: x.astype(dt) if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating) else x, tree
    )


# ------------------------------------------------------------------------------------ one step
def _n_fresh(cfg: MMDOptConfig) -> int:
    return cfg.cem.n_samples - cfg.cem.n_elite - cfg.cem.n_brake


def _normals(cfg: MMDOptConfig, key, dt):
    """The standard normal draws of one iteration, (n_samples − n_elite − n_brake, D)."""
    return jax.random.normal(key, (_n_fresh(cfg), cfg.d_dim), dt)


def _sample(cfg: MMDOptConfig, key, mu, cov, elites, problem: Problem, z=None):
    """Batch of behavioural inputs: [elites; brake rows; fresh draws], clipped to the bounds
    (``z``: this iteration's :func:`_normals` when drawn beforehand)."""
    D = mu.shape[0]
    L = jnp.linalg.cholesky(cov)
    if z is None:
        z = _normals(cfg, key, mu.dtype)
    new = mu + z @ L.T
    # order matters: residuals within res_tol tie and ties go to the lower index, so the previous
    # elites and the brake rows always reach the ConstraintEliteSet when feasible, and the fresh
    # draws fill it in (random) draw order
    d = jnp.concatenate([elites, problem.brake.reshape(cfg.cem.n_brake, D), new], axis=0)
    return jnp.clip(d, problem.lo, problem.hi)


class _CostCache(NamedTuple):
    """What carries over between the iterations of :func:`run` (obstacles fixed): rows
    ``0 … n_elite + n_brake − 1`` of the next batch are the elites and the brake rows, whose
    behavioural inputs, projections and hence costs do not change from one iteration to the
    next."""

    cost: Any  # (n_elite + n_brake,) total cost of those rows
    coll: Any  # (n_elite + n_brake,) their collision term
    valid: Any  # (n_elite + n_brake,) bool: the row has been scored against these obstacles
    cx: Any  # (n_elite + n_brake, nvar) their projections
    cy: Any  # (n_elite + n_brake, nvar)
    res: Any  # (n_elite + n_brake,) their residuals
    known: Any  # () int32: rows 0 … known − 1 have the projections above (a prefix)


def _empty_cache(cfg: MMDOptConfig, n: int, dt) -> _CostCache:
    nc = cfg.cem.n_elite + cfg.cem.n_brake
    z = jnp.zeros((nc,), dt)
    zx = jnp.zeros((nc, n), dt)
    return _CostCache(z, z, jnp.zeros((nc,), bool), zx, zx, z, jnp.asarray(0, jnp.int32))


def cost_chunk_size(cfg: MMDOptConfig) -> int:
    """Rows scored per chunk in :func:`run`: the rows of the ConstraintEliteSet that are
    neither elites nor brake rows (at least a quarter of ``n_cem``)."""
    return max(cfg.cem.n_cem - cfg.cem.n_elite - cfg.cem.n_brake, -(-cfg.cem.n_cem // 4))


def lane_inputs(cfg: MMDOptConfig, d, lanes, state=None):
    """The behavioural inputs the Frenet planner follows: ``d`` (B, D) itself, or with
    ``cfg.trajectory.lane_setpoints`` and lane centres ``lanes`` (L,) each lateral set-point
    moved to the nearest lane centre (lane discipline, not in the paper).  With
    ``cfg.trajectory.lane_commit > 0`` and the ego ``state`` (6,) more than that far from every
    lane centre (between lanes), every lateral set-point is the first one: each candidate
    finishes the lane change or gives it up at once."""
    if lanes is None or not cfg.trajectory.lane_setpoints:
        return d
    S = cfg.trajectory.num_segments
    lat = d[:, S:]
    near = jnp.argmin(jnp.abs(lat[..., None] - lanes), axis=-1)
    centres = lanes[near].astype(d.dtype)
    commit = float(cfg.trajectory.lane_commit)
    if state is not None and commit > 0.0:
        between = jnp.min(jnp.abs(state[1] - lanes)) > commit
        centres = jnp.where(between, jnp.broadcast_to(centres[:, :1], centres.shape), centres)
    return jnp.concatenate([d[:, :S], centres], axis=1)


def lane_cost(dd, lanes, start: float = 0.5):
    """Lane discipline (not in the paper): the mean, from ``start`` × the horizon on, of the
    squared distance of the lateral offsets ``dd`` (R, K) to the nearest lane centre of
    ``lanes`` (L,), (R,) in m².  With ``start`` = 0.5 a plan must have settled at a lane centre
    by mid-horizon: a lane change inside the first half is free, one that holds an offset
    between two lanes pays; with 0 every lane change pays for the time it spends between
    lanes."""
    K = dd.shape[-1]
    k0 = min(int(start * K), K - 1)
    dev = jnp.min(jnp.abs(dd[..., k0:, None] - lanes), axis=-1)
    return jnp.mean(dev * dev, axis=-1)


def _row_costs(cfg: MMDOptConfig, ws: Workspace, obstacles: ObstacleSet, cx, cy, res, lanes=None):
    """eq. (c_aug) + residual (+ :func:`lane_cost` when ``lanes`` is given) for coefficient rows
    (R, nvar): ``(cost, collision term)``."""
    dt = cx.dtype
    P, Pd, Pdd = (jnp.asarray(M, dt) for M in (ws.P, ws.Pdot, ws.Pddot))
    s, vs, as_ = cx @ P.T, cx @ Pd.T, cx @ Pdd.T
    dd, ad = cy @ P.T, cy @ Pdd.T
    j_speed = jnp.mean((vs - cfg.cost.v_des) ** 2, axis=1)
    j_acc = jnp.mean(as_ * as_ + ad * ad, axis=1)
    vd = cy @ Pd.T if cfg.safety.footprint.yaw_aware else None
    coll, w = obstacle_cost(cfg, ws, s, dd, obstacles, dt, vs=vs, vd=vd)
    cost = cfg.cost.w_speed * j_speed + cfg.cost.w_accel * j_acc + w * coll + cfg.cost.w_res * res
    if lanes is not None:
        cost = cost + cfg.cost.w_lane * lane_cost(dd, lanes, cfg.cost.lane_from)
    if cfg.safety.rules.kinematic:
        # feasibility first (a hard slip limit; the collision term may reach 10⁶): a row whose
        # residual, slip included, exceeds res_tol ranks after every row within it
        cost = cost + jnp.where(res > cfg.projection.res_tol, jnp.asarray(INFEASIBLE_COST, dt), 0.0)
    return jnp.where(jnp.isfinite(cost), cost, jnp.asarray(1e30, dt)), coll


def _cached_costs(cfg, ws, obstacles, ces, cx_c, cy_c, res_c, cache: _CostCache, lanes=None):
    """:func:`_row_costs` of the ConstraintEliteSet ``ces`` (n_cem,), reusing the cached costs of
    elites and brake rows; the other rows are scored in chunks of :func:`cost_chunk_size`
    (one chunk once the cache is filled, as many as needed before: a while loop)."""
    nc = cfg.cem.n_elite + cfg.cem.n_brake
    nces = ces.shape[0]
    U = cost_chunk_size(cfg)
    nq = -(-nces // U)
    slot = jnp.minimum(ces, nc - 1)
    hit = (ces < nc) & cache.valid[slot]
    miss = ~hit
    n_miss = jnp.sum(miss.astype(jnp.int32))
    order = compact_order(miss, nq * U, -1)  # the CES positions to score; −1: an empty slot
    cost0 = jnp.where(hit, cache.cost[slot], 0.0)
    coll0 = jnp.where(hit, cache.coll[slot], 0.0)

    def more(c):
        return c[0] * U < n_miss

    def chunk(c):
        q, cost, coll = c
        sl = lax.dynamic_slice_in_dim(order, q * U, U)
        i = jnp.maximum(sl, 0)
        cq, kq = _row_costs(cfg, ws, obstacles, cx_c[i], cy_c[i], res_c[i], lanes)
        tgt = jnp.where(sl >= 0, i, nces)  # empty slots are dropped
        cost = cost.at[tgt].set(cq, mode="drop")
        coll = coll.at[tgt].set(kq.astype(coll.dtype), mode="drop")
        return q + 1, cost, coll

    _, cost, coll = lax.while_loop(more, chunk, (jnp.asarray(0, jnp.int32), cost0, coll0))
    return cost, coll


def _next_cache(
    cfg: MMDOptConfig, ces, cost, coll, el, cx, cy, res, end, cache: _CostCache
) -> _CostCache:
    """The cache for the next batch: the new elites (rows 0 … n_elite − 1, in EliteSet order;
    their projections are known, as every CES row's) and the brake rows scored so far (in this
    CES or before) and projected so far (rows below ``end`` of this batch)."""
    ne, nb = cfg.cem.n_elite, cfg.cem.n_brake
    i = ces[el]
    inces = ces[None, :] == (ne + jnp.arange(nb, dtype=ces.dtype))[:, None]  # (nb, n_cem)
    seen = jnp.any(inces, axis=1)
    bc = jnp.where(seen, jnp.sum(jnp.where(inces, cost[None], 0.0), 1), cache.cost[ne:])
    bk = jnp.where(seen, jnp.sum(jnp.where(inces, coll[None], 0.0), 1), cache.coll[ne:])
    rows = slice(ne, ne + nb)
    return _CostCache(
        jnp.concatenate([cost[el], bc]),
        jnp.concatenate([coll[el], bk]),
        jnp.concatenate([jnp.ones((ne,), bool), seen | cache.valid[ne:]]),
        jnp.concatenate([cx[i], cx[rows]]),
        jnp.concatenate([cy[i], cy[rows]]),
        jnp.concatenate([res[i], res[rows]]),
        (ne + jnp.clip(end - ne, 0, nb)).astype(jnp.int32),
    )


def _evaluate(
    cfg: MMDOptConfig,
    state: CEMState,
    ws: Workspace,
    obstacles: ObstacleSet,
    d,
    cx,
    cy,
    res,
    n_projected=None,
    cache: _CostCache | None = None,
    end=None,
    lanes=None,
):
    """ConstraintEliteSet, cost, EliteSet, distribution update, best-so-far (one iteration);
    rows not projected (:func:`project_rows`) carry ``res = inf``.  With ``cache`` (inside
    :func:`run` only, where the obstacles are fixed) the elites' and brake rows' costs are
    reused and ``(state, next cache)`` is returned."""
    it = state.iteration
    mu, cov, best, lv = state.mu, state.cov, state.best, state.least_violating
    dt = cx.dtype
    res = jnp.where(jnp.isfinite(res), res, jnp.asarray(1e30, dt))
    n_feas = jnp.sum(res <= cfg.projection.res_tol)
    # --- ConstraintEliteSet: n_cem lowest residuals (within res_tol all count as 0: index order)
    rank = jnp.maximum(res - cfg.projection.res_tol, 0.0)
    _, ces = lax.top_k(-rank, cfg.cem.n_cem)
    d_c, cx_c, cy_c, res_c = d[ces], cx[ces], cy[ces], res[ces]
    # --- cost, eq. (c_aug) + residual
    if cache is None:
        cost, coll = _row_costs(cfg, ws, obstacles, cx_c, cy_c, res_c, lanes)
    else:
        cost, coll = _cached_costs(cfg, ws, obstacles, ces, cx_c, cy_c, res_c, cache, lanes)
    # --- EliteSet and the MPPI-weighted update, eqs. (mean_update), (cov_update), (s_formula)
    neg, el = lax.top_k(-cost, cfg.cem.n_elite)
    cost_e = -neg
    d_e = d_c[el]
    sw = jnp.exp(-(cost_e - cost_e[0]) / cfg.cem.gamma)
    sw = sw / jnp.sum(sw)
    mu_new = (1.0 - cfg.cem.eta) * mu + cfg.cem.eta * (sw @ d_e)
    diff = d_e - mu_new
    cov_new = (1.0 - cfg.cem.eta) * cov + cfg.cem.eta * (diff.T * sw) @ diff
    cov_new = 0.5 * (cov_new + cov_new.T) + cfg.cem.cov_reg * jnp.eye(cov.shape[0], dtype=dt)
    # --- best so far (lowest cost) and least violating (lowest residual)
    i0 = ces[el[0]]
    cand = Best(cost_e[0], d[i0], cx[i0], cy[i0], res[i0], coll[el[0]], it.astype(jnp.int32))
    take = cand.cost < best.cost
    best = jax.tree_util.tree_map(lambda a, b: jnp.where(take, a, b), cand, best)
    j = jnp.argmin(res)
    jc = jnp.argmin(jnp.where(ces == j, 0, 1))  # position of j in the CES if present
    in_ces = ces[jc] == j
    lv_cand = Best(
        jnp.where(in_ces, cost[jc], jnp.asarray(jnp.inf, dt)),
        d[j],
        cx[j],
        cy[j],
        res[j],
        jnp.where(in_ces, coll[jc], 0.0),
        it.astype(jnp.int32),
    )
    take_lv = lv_cand.res < lv.res
    lv = jax.tree_util.tree_map(lambda a, b: jnp.where(take_lv, a, b), lv_cand, lv)
    new = state._replace(
        mu=mu_new,
        cov=cov_new,
        elites=d_e,
        best=best,
        least_violating=lv,
        iteration=it + 1,
        cost_trace=state.cost_trace.at[it].set(best.cost),
        iter_min_cost=state.iter_min_cost.at[it].set(cost_e[0]),
        iter_mean_elite_cost=state.iter_mean_elite_cost.at[it].set(jnp.mean(cost_e)),
        n_feasible=state.n_feasible.at[it].set(n_feas.astype(state.n_feasible.dtype)),
        n_projected=state.n_projected.at[it].set(
            d.shape[0] if n_projected is None else n_projected
        ),
    )
    if cache is None:
        return new
    return new, _next_cache(cfg, ces, cost, coll, el, cx, cy, res, end, cache)


def slip_residual(cfg: MMDOptConfig, ws: Workspace, ego_state, cx, cy):
    """Kinematic slip limit (:class:`MMDOptConfig`, not in the paper): per row (B,) the largest
    excess ``max_k max(0, |ḋ_k| − r·max(ṡ_k, 0) − v₀)`` (m/s) of the lateral speed over
    ``r = slip_ratio`` times the longitudinal speed, ``v₀`` that of the initial state
    ``ego_state`` (6,) = (s, d, ṡ, ḋ, s̈, d̈), in residual units (× ``res_tol / slip_tol``)."""
    cx, cy = jnp.asarray(cx), jnp.asarray(cy)
    if cx.ndim != 2 or cy.shape != cx.shape or cx.shape[1] != ws.Pdot.shape[1]:
        raise ValueError(
            f"cx and cy must both have shape (B, {ws.Pdot.shape[1]}), got {cx.shape} and {cy.shape}"
        )
    if jnp.shape(ego_state) != (6,):
        raise ValueError(f"ego_state must have shape (6,), got {jnp.shape(ego_state)}")
    dt = cx.dtype
    Pd = jnp.asarray(ws.Pdot, dt)
    vs, vd = cx @ Pd.T, cy @ Pd.T
    r = jnp.asarray(cfg.safety.rules.slip_ratio, dt)
    st = ego_state.astype(dt)
    v0 = jnp.maximum(jnp.abs(st[3]) - r * jnp.maximum(st[2], 0.0), 0.0)
    ex = jnp.abs(vd) - r * jnp.maximum(vs, 0.0) - v0
    return jnp.max(jnp.maximum(ex, 0.0), axis=1) * (
        cfg.projection.res_tol / cfg.safety.rules.slip_tol
    )


def planner_output(ws: Workspace, d, state, dt):
    """Frenet planner, closed form: behavioural inputs (B, D) -> coefficients c̄x, c̄y (B, nvar)."""
    W = jnp.asarray(ws.W, dt)
    n = ws.nvar
    st = jnp.broadcast_to(state[None], (d.shape[0], 6))
    z = jnp.concatenate([d, st], axis=1) @ W
    return z[:, :n], z[:, n:]


class _WarmStart(NamedTuple):
    x: Any
    y: Any


def project_fixed(ws: Workspace, cx_bar, cy_bar, state):
    """The ``admm-fixed`` projection, warm-started from the planner output with zero duals:
    ``(cx, cy, residual)``."""
    m = ws.projection.num_rows
    start = _WarmStart(
        jnp.concatenate([cx_bar, cy_bar], axis=1), jnp.zeros((cx_bar.shape[0], m), cx_bar.dtype)
    )
    out = ws.projector(cx_bar, cy_bar, state, warm_start=start)
    return out.cx, out.cy, out.residual


def project_chunk_size(cfg: MMDOptConfig) -> int:
    """Rows per chunk of :func:`project_rows` (``project_chunk``; ``None``: ``n_cem + n_elite``)."""
    c = cfg.projection.project_chunk
    if c is None:
        c = cfg.cem.n_cem + cfg.cem.n_elite
    return min(c, cfg.cem.n_samples)


def project_rows(cfg: MMDOptConfig, ws: Workspace, d, ego, dt):
    """Planner + ``admm-fixed`` projection of the batch ``d`` (B, D), chunk by chunk, until the
    projected rows hold ``n_cem`` feasible ones: ``(cx, cy, res, n_projected)``, ``res = inf``
    on the rows not projected.

    Exact: the ConstraintEliteSet is the ``n_cem`` lowest ``max(res − res_tol, 0)`` with ties
    to the lower index, so once ``n_cem`` rows with ``res ≤ res_tol`` are known, no later row
    can enter it (the rows are independent QPs: same warm start, same fixed ADMM budget, no
    batch-wide test before the last iteration).  The later fresh draws would be planned and
    projected only to be discarded; on the tuning scenes ≥ 99 % of all rows are feasible, so
    one chunk of ``n_cem + n_elite`` rows almost always suffices (docs/experiments/synthetic.md)."""
    cx, cy, res, n_proj, _ = _project_rows(cfg, ws, d, ego, dt)
    return cx, cy, res, n_proj


def _project_fixed_slip(cfg: MMDOptConfig, ws: Workspace, cx_bar, cy_bar, ego):
    """:func:`project_fixed`, its residual with the slip limit's added when
    ``cfg.safety.rules.kinematic``
    (once, where the residual is made: cached rows carry it already)."""
    cx, cy, res = project_fixed(ws, cx_bar, cy_bar, ego)
    if cfg.safety.rules.kinematic:
        res = res + slip_residual(cfg, ws, ego, cx, cy).astype(res.dtype)
    return cx, cy, res


def _project_rows(cfg: MMDOptConfig, ws: Workspace, d, ego, dt, cache=None):
    """:func:`project_rows`; with ``cache`` (:func:`run`) the first ``cache.known`` rows (the
    elites and brake rows, projected in an earlier iteration) are taken from it and the chunks,
    ``n_elite + n_brake`` rows shorter, start after them.  Also returns the end of the known
    prefix of rows."""
    B, D = d.shape
    C = min(project_chunk_size(cfg), B)
    if C >= B:
        cx_bar, cy_bar = planner_output(ws, d, ego, dt)
        cx, cy, res = _project_fixed_slip(cfg, ws, cx_bar, cy_bar, ego)
        n = jnp.asarray(B, jnp.int32)
        return cx, cy, res.astype(dt), n, n
    n = ws.nvar
    inf = jnp.asarray(jnp.inf, dt)
    L = -(-B // C) * C  # rows of the padded batch
    zero, i0 = jnp.zeros((L, n), dt), jnp.asarray(0, jnp.int32)
    cx0, cy0, res0, nf0, base = zero, zero, jnp.full((L,), inf), i0, i0
    if cache is not None:
        nk = cache.res.shape[0]
        C = max(C - nk, -(-C // 2))
        L = B + C
        base = cache.known
        kn = jnp.arange(nk) < base
        pad = ((0, L - nk), (0, 0))
        cx0 = jnp.pad(jnp.where(kn[:, None], cache.cx, 0.0), pad)
        cy0 = jnp.pad(jnp.where(kn[:, None], cache.cy, 0.0), pad)
        res0 = jnp.pad(jnp.where(kn, cache.res, inf), (0, L - nk), constant_values=inf)
        nf0 = jnp.sum(kn & (cache.res <= cfg.projection.res_tol)).astype(jnp.int32)
    dp = jnp.concatenate([d, jnp.broadcast_to(d[-1:], (L - B, D))], axis=0) if L > B else d

    def more(c):
        return (base + c[0] * C < B) & (c[1] < cfg.cem.n_cem)

    def chunk(c):
        i, nf, cx, cy, res = c
        start = base + i * C
        cx_bar, cy_bar = planner_output(ws, lax.dynamic_slice_in_dim(dp, start, C), ego, dt)
        cxi, cyi, ri = _project_fixed_slip(cfg, ws, cx_bar, cy_bar, ego)
        ri = jnp.where(start + jnp.arange(C) < B, ri.astype(dt), inf)  # padding: never chosen
        nf = nf + jnp.sum(ri <= cfg.projection.res_tol).astype(jnp.int32)
        cx = lax.dynamic_update_slice_in_dim(cx, cxi, start, 0)
        cy = lax.dynamic_update_slice_in_dim(cy, cyi, start, 0)
        res = lax.dynamic_update_slice_in_dim(res, ri, start, 0)
        return i + 1, nf, cx, cy, res

    i, _, cx, cy, res = lax.while_loop(more, chunk, (i0, nf0, cx0, cy0, res0))
    end = jnp.minimum(base + i * C, B)
    return cx[:B], cy[:B], res[:B], end - base, end


def _step(
    ws: Workspace,
    cfg: MMDOptConfig,
    problem: Problem,
    state: CEMState,
    obstacles: ObstacleSet,
    z=None,
    cache: _CostCache | None = None,
):
    """One iteration with the ``admm-fixed`` projection (traceable); ``z`` optionally this
    iteration's normal draws (the same numbers as drawn from its key here); with ``cache``
    (:func:`run`) returns ``(state, next cache)``."""
    dt = jnp.dtype(cfg.cem.dtype)
    problem = _cast(problem, dt)
    k = state.keys[state.iteration]
    d = _sample(cfg, k, state.mu, state.cov, state.elites, problem, z)
    d_plan = lane_inputs(cfg, d, problem.lanes, problem.state)
    cx, cy, res, n_proj, end = _project_rows(cfg, ws, d_plan, problem.state, dt, cache)
    return _evaluate(cfg, state, ws, obstacles, d, cx, cy, res, n_proj, cache, end, problem.lanes)


def _init(
    ws: Workspace,
    cfg: MMDOptConfig,
    problem: Problem,
    key,
    warm_start: CEMState | None,
    z0=None,
) -> CEMState:
    """``z0``: the first rows of a larger standard-normal draw from the init key, when that is
    bit-identical to drawing (n_elite, D) from it (partitionable threefry)."""
    dt = jnp.dtype(cfg.cem.dtype)
    problem = _cast(problem, dt)
    D = cfg.d_dim
    k_init, k_loop = jax.random.split(key)
    if warm_start is None:
        L0 = jnp.linalg.cholesky(problem.cov0)
        z = jax.random.normal(k_init, (cfg.cem.n_elite, D), dt) if z0 is None else z0
        elites = jnp.clip(problem.mu0 + z @ L0.T, problem.lo, problem.hi)
        mu, cov = problem.mu0, problem.cov0
    else:
        mu = jnp.clip(warm_start.mu.astype(dt), problem.lo, problem.hi)
        cov = warm_start.cov.astype(dt)
        elites = jnp.clip(warm_start.elites.astype(dt), problem.lo, problem.hi)
    keys = jax.random.split(k_loop, cfg.cem.iterations)
    empty = _empty_best(D, ws.nvar, dt)
    N = cfg.cem.iterations
    return CEMState(
        mu=mu,
        cov=cov,
        elites=elites,
        best=empty,
        least_violating=empty,
        iteration=jnp.asarray(0, jnp.int32),
        keys=keys,
        cost_trace=jnp.full((N,), jnp.inf, dt),
        iter_min_cost=jnp.full((N,), jnp.inf, dt),
        iter_mean_elite_cost=jnp.full((N,), jnp.inf, dt),
        n_feasible=jnp.zeros((N,), jnp.int32),
        n_projected=jnp.zeros((N,), jnp.int32),
    )


class _Warm(NamedTuple):
    """The part of a warm start :func:`run` reads, and whether there is one: a cold start
    passes zeros with ``cold = True``, so that one compiled program serves both."""

    mu: Any
    cov: Any
    elites: Any
    cold: Any  # () bool


def _as_warm(cfg: MMDOptConfig, warm_start: CEMState | None) -> _Warm:
    D, ne = cfg.d_dim, cfg.cem.n_elite
    dt = jnp.dtype(cfg.cem.dtype)
    if warm_start is None:
        return _Warm(
            jnp.zeros((D,), dt), jnp.zeros((D, D), dt), jnp.zeros((ne, D), dt), jnp.asarray(True)
        )
    return _Warm(
        jnp.asarray(warm_start.mu, dt),
        jnp.asarray(warm_start.cov, dt),
        jnp.asarray(warm_start.elites, dt),
        jnp.asarray(False),
    )


def _run_fixed(
    ws: Workspace, cfg: MMDOptConfig, problem: Problem, obstacles: ObstacleSet, key, warm: _Warm
):
    """The whole of Algorithm 1 as one jitted function (``lax.scan`` over the iterations); a
    cold start and a warm start are one program (the state is selected by ``warm.cold``)."""
    dt = jnp.dtype(cfg.cem.dtype)
    problem = _cast(problem, dt)
    # every iteration's normal draws in one vmapped call (bit-identical to drawing them from
    # each iteration's key inside the loop, ≈ 2.4× cheaper: threefry on CPU is dispatch-bound
    # at 940 × 8 values)
    prefix = bool(jax.config.jax_threefry_partitionable) and cfg.cem.n_elite <= _n_fresh(cfg)
    if not prefix:
        state = _init(ws, cfg, problem, key, None)
        z_all = jax.vmap(lambda k: _normals(cfg, k, dt))(state.keys)
    else:
        # the initial elites' draws are the first rows of a draw of the iterations' shape from
        # the init key (partitionable threefry: the same counters, a prefix), so every normal
        # comes from one vmapped threefry: one instance to compile instead of two (≈ 0.25 s)
        k_init, k_loop = jax.random.split(key)
        keys = jnp.concatenate([k_init[None], jax.random.split(k_loop, cfg.cem.iterations)])
        z = jax.vmap(lambda k: _normals(cfg, k, dt))(keys)
        state = _init(ws, cfg, problem, key, None, z[0, : cfg.cem.n_elite])
        z_all = z[1:]
    # a warm start: its distribution and elites (clipped to the bounds), the same keys
    warmed = state._replace(
        mu=jnp.clip(warm.mu, problem.lo, problem.hi),
        cov=warm.cov,
        elites=jnp.clip(warm.elites, problem.lo, problem.hi),
    )
    state = jax.tree_util.tree_map(lambda c, w: jnp.where(warm.cold, c, w), state, warmed)
    # the obstacles are the same in every iteration: the elites' and brake rows' costs carry
    # over (_CostCache) and only the new rows of each ConstraintEliteSet are scored
    (state, _), _ = lax.scan(
        lambda c, z: (_step(ws, cfg, problem, c[0], obstacles, z, c[1]), None),
        (state, _empty_cache(cfg, ws.nvar, dt)),
        z_all,
    )
    return state


def _sample_plan(ws: Workspace, cfg: MMDOptConfig, problem: Problem, state: CEMState):
    dt = jnp.dtype(cfg.cem.dtype)
    problem = _cast(problem, dt)
    d = _sample(cfg, state.keys[state.iteration], state.mu, state.cov, state.elites, problem)
    cx_bar, cy_bar = planner_output(
        ws, lane_inputs(cfg, d, problem.lanes, problem.state), problem.state, dt
    )
    return d, cx_bar, cy_bar


def _evaluate_host(
    ws: Workspace,
    cfg: MMDOptConfig,
    problem: Problem,
    state: CEMState,
    obstacles: ObstacleSet,
    d,
    cx,
    cy,
    res,
):
    dt = jnp.dtype(cfg.cem.dtype)
    problem = _cast(problem, dt)
    cx, cy, res = cx.astype(dt), cy.astype(dt), res.astype(dt)
    if cfg.safety.rules.kinematic:  # the slip limit joins the backend's residual
        res = res + slip_residual(cfg, ws, problem.state, cx, cy)
    return _evaluate(cfg, state, ws, obstacles, d, cx, cy, res, lanes=problem.lanes)


# ------------------------------------------------------------------------------------ public API
def check_backend(projector: str, settings: dict) -> None:
    """Raise ``ValueError`` for a non-string projector or settings given to ``admm-fixed``."""
    if not isinstance(projector, str):
        raise ValueError(f"projector must be a string, got {type(projector).__name__}")
    if projector == PLANNER_PROJECTOR and settings:
        raise ValueError(
            f"projector {PLANNER_PROJECTOR!r} takes no solver settings (got {sorted(settings)}): "
            "its budget and step size are MMDOptConfig.projection.admm_iters / admm_rho; pass "
            "projector='admm' for the registry's ADMM with settings"
        )


def _check_step_inputs(ws, config, problem, state=None, obstacles=None) -> None:
    if not isinstance(ws, Workspace):
        raise ValueError(f"ws must be an algorithm.Workspace, got {type(ws).__name__}")
    if not isinstance(config, MMDOptConfig):
        raise ValueError(f"config must be an MMDOptConfig, got {type(config).__name__}")
    if not isinstance(problem, Problem):
        raise ValueError(f"problem must be an algorithm.Problem, got {type(problem).__name__}")
    if problem.bounds != ws.bounds_key:
        raise ValueError("problem was made for other road bounds than the workspace's")
    if state is not None and not isinstance(state, CEMState):
        raise ValueError(f"state must be a CEMState, got {type(state).__name__}")
    if obstacles is not None and not isinstance(obstacles, ObstacleSet):
        raise ValueError(f"obstacles must be an ObstacleSet, got {type(obstacles).__name__}")


@x64
def init(
    ws: Workspace,
    config: MMDOptConfig,
    problem: Problem,
    key: Any,
    warm_start: CEMState | None = None,
) -> CEMState:
    """Initial state: the sampling prior of ``problem`` (or ``warm_start``'s distribution and
    elites, e.g. from :func:`shift`), ``config.cem.iterations`` PRNG keys, empty best-so-far.
    ``ws``: the :class:`Workspace` of ``config``'s statics and ``problem``'s bounds
    (:meth:`mmdopt.Planner.workspace`)."""
    _check_step_inputs(ws, config, problem)
    if warm_start is not None and not isinstance(warm_start, CEMState):
        raise ValueError(f"warm_start must be a CEMState, got {type(warm_start).__name__}")
    return ws.init(config.program(), problem, key, warm_start)


@x64
def update(
    ws: Workspace,
    config: MMDOptConfig,
    problem: Problem,
    state: CEMState,
    obstacles: ObstacleSet,
    projector: str = PLANNER_PROJECTOR,
    **projector_settings: Any,
) -> CEMState:
    """One CEM iteration (sample, plan, project, score, update); every row of the
    ConstraintEliteSet is scored (``obstacles`` may differ from the previous call's).  Raises
    ``ValueError`` once the state has done ``config.cem.iterations`` iterations (its keys are
    used up: :func:`shift` or :func:`init` a new state)."""
    check_backend(projector, projector_settings)
    _check_step_inputs(ws, config, problem, state, obstacles)
    if int(state.iteration) >= config.cem.iterations:
        raise ValueError(
            f"state has done all config.iterations = {config.cem.iterations} iterations"
        )
    config = config.program()  # one compiled program per statics Algorithm 1 reads
    if projector == PLANNER_PROJECTOR:
        return ws.step(config, problem, state, obstacles)
    d, cx_bar, cy_bar = ws.sample(config, problem, state)
    pr = ws.projection.project(
        np.asarray(cx_bar, np.float64),
        np.asarray(cy_bar, np.float64),
        np.asarray(problem.state, np.float64),
        backend=projector,
        **projector_settings,
    )
    return ws.evaluate(config, problem, state, obstacles, d, pr.cx, pr.cy, pr.residual)


@x64
def run(
    ws: Workspace,
    config: MMDOptConfig,
    problem: Problem,
    obstacles: ObstacleSet,
    key: Any,
    projector: str = PLANNER_PROJECTOR,
    warm_start: CEMState | None = None,
    **projector_settings: Any,
) -> CEMState:
    """:func:`init` then ``config.cem.iterations`` × :func:`update`; with ``admm-fixed`` one
    jitted ``lax.scan``, in which the obstacles are fixed, so the costs of the elites and brake
    rows carried into the next batch are reused instead of recomputed (the same plan as the
    :func:`update` loop, to float rounding).  Returns the final :class:`CEMState` (``best``,
    ``least_violating``, traces)."""
    check_backend(projector, projector_settings)
    _check_step_inputs(ws, config, problem, None, obstacles)
    if projector == PLANNER_PROJECTOR:
        if warm_start is not None and not isinstance(warm_start, CEMState):
            raise ValueError(f"warm_start must be a CEMState, got {type(warm_start).__name__}")
        cfg = config.program()  # one compiled program per statics Algorithm 1 reads
        return ws.run(cfg, problem, obstacles, key, _as_warm(cfg, warm_start))
    state = init(ws, config, problem, key, warm_start)
    for _ in range(config.cem.iterations):
        state = update(ws, config, problem, state, obstacles, projector, **projector_settings)
    return state


def _shift_setpoints(v, frac):
    """Piecewise-constant set-points (…, S) moved ``frac`` segments earlier, last one held."""
    S = v.shape[-1]
    pos = jnp.arange(S, dtype=v.dtype) + frac
    i0 = jnp.clip(jnp.floor(pos).astype(jnp.int32), 0, S - 1)
    i1 = jnp.clip(i0 + 1, 0, S - 1)
    w = jnp.clip(pos - jnp.floor(pos), 0.0, 1.0)
    return jnp.take(v, i0, axis=-1) * (1 - w) + jnp.take(v, i1, axis=-1) * w


@x64
def shift(config: MMDOptConfig, state: CEMState, dt: float) -> CEMState:
    """Warm start for receding horizon: the sampling distribution and the elites moved ``dt``
    seconds forward in time (each of the ``S`` speed and lateral set-point sequences is
    re-sampled at ``t + dt``, the last set-point held), the covariance kept (plus ``cov_reg``);
    best-so-far, traces and iteration count reset, fresh keys derived from the old ones.  Pass
    it as ``warm_start`` to :func:`init` / :func:`run` with the new :class:`Problem`
    (``config``: the one the state was made with)."""
    if not isinstance(config, MMDOptConfig):
        raise ValueError(f"config must be an MMDOptConfig, got {type(config).__name__}")
    if not isinstance(state, CEMState):
        raise ValueError(f"state must be a CEMState, got {type(state).__name__}")
    dt = float(dt)
    if not (math.isfinite(dt) and dt >= 0):
        raise ValueError(f"dt must be finite and >= 0, got {dt}")
    cfg = config
    if tuple(np.shape(state.mu)) != (cfg.d_dim,):
        raise ValueError(
            f"state.mu has shape {tuple(np.shape(state.mu))}, but config needs ({cfg.d_dim},): "
            "shift a state with the config it was made with"
        )
    frac = dt / (cfg.trajectory.horizon / cfg.trajectory.num_segments)
    return _shift(cfg.program(), state, frac)


@jax.jit
def _shift(cfg: MMDOptConfig, state: CEMState, frac) -> CEMState:
    # one compiled program per config (eagerly, each op would compile for every new shape)
    S = cfg.trajectory.num_segments

    def sh(x):
        return jnp.concatenate(
            [_shift_setpoints(x[..., :S], frac), _shift_setpoints(x[..., S:], frac)], axis=-1
        )

    D = cfg.d_dim
    dtype = state.mu.dtype
    empty = _empty_best(D, state.best.cx.shape[-1], dtype)
    key = jax.random.fold_in(state.keys[-1], 0x5F17)
    N = cfg.cem.iterations
    return state._replace(
        mu=sh(state.mu),
        cov=state.cov + cfg.cem.cov_reg * jnp.eye(D, dtype=dtype),
        elites=sh(state.elites),
        best=empty,
        least_violating=empty,
        iteration=jnp.asarray(0, jnp.int32),
        keys=jax.random.split(key, N),
        cost_trace=jnp.full((N,), jnp.inf, dtype),
        iter_min_cost=jnp.full((N,), jnp.inf, dtype),
        iter_mean_elite_cost=jnp.full((N,), jnp.inf, dtype),
        n_feasible=jnp.zeros((N,), jnp.int32),
        n_projected=jnp.zeros((N,), jnp.int32),
    )
