"""Algorithm 1 (paper): sampling-based MMD-augmented trajectory optimisation in the Frenet frame.

One CEM/MPPI iteration ``l`` (paper Alg. 1 lines 4–14, SPEC §g, with the reference's bugs fixed)::

    d_r ~ N(μ_l, Σ_l), r = 1 … n̄_cem           behavioural inputs (speed, lateral set-points)
        rows: the n_e elites of iteration l−1, n_brake "brake in lane" rows, fresh draws
    c̄_r   = Frenet planner(d_r)                 closed form (one matrix product)
    c_r   = projection(c̄_r)                     kinematic + lane constraints (batched ADMM)
    res_r = constraint residual of c_r          max violation on the time grid (m, m/s, m/s²)
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

**What is returned: the lowest-cost elite over all iterations** (best-so-far, tracked in the scan
carry), not the lowest-residual sample (the reference's bug, SPEC §g).  Best-so-far rather than
"best of the last iteration" because the cost of a given behavioural input is deterministic, so the
best sample ever evaluated is a valid plan and never worse; elites are carried to the next batch,
so the two coincide unless the distribution drifts away from a good sample.  The cost trace is
the best-so-far cost per iteration (non-increasing); the per-iteration minimum is in the
diagnostics.

Fixes of the reference (SPEC §8): a fresh PRNG key every iteration; lateral set-points sampled
with a spread matched to the lane bounds (not σ ≈ 4.8 m against ±0.3 m); "brake in lane" rows
as a ladder of constant speed set-points from ``v_min`` (not below it) to the current speed;
multipliers are not carried across iterations with misaligned rows (each projection is
warm-started from its own planner output ``c̄_r`` with zero duals); every constant in
:class:`MMDOptConfig`.

The ``admm`` backend runs the whole loop as one ``jit`` (``lax.scan`` over the iterations, the
projection by :meth:`frenet.ProjectionProblem.jax_projector`, a fixed ADMM iteration budget); any
other :mod:`solvers` backend runs the projection on the host per iteration via
:meth:`frenet.ProjectionProblem.project` (a Python loop over iterations, not samples), with the
sampling and the cost evaluation still jitted.  The public entry point is :func:`mmdopt.plan`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

import frenet

from .baselines import (
    COST_MODE,
    ellipse_values,
    mmd_cost,
    saa_cost,
    scenario_cost,
    taylor_terms,
)
from .reduced_set import ReducedSetConfig

__all__ = ["MMDOptConfig", "CEMResult", "CEMProblem", "build_problem", "run_cem"]


def _static(default):
    return field(default=default, metadata=dict(static=True))


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class MMDOptConfig:
    """Every constant of Algorithm 1 (a pytree: sizes/modes static, tunable scalars are leaves).

    Sizes (static; the paper's values): ``n_samples`` = n̄_cem = 1000 behavioural samples per
    iteration, ``n_cem`` = 150 (ConstraintEliteSet), ``n_elite`` = n_e = 50 (EliteSet),
    ``iterations`` = N = 20, ``reduced_set_size`` = m = 20 (the paper's Table II range is
    10 … 50; 20 instead of the reference's 10 because a 5–30 % intent has on average only
    0.5–3 samples in a 10-sample set: measured on the tuning scenes, docs/benchmarks.md).
    ``n_brake`` "brake in lane" rows per batch (reference 10, all at v_d = 0): here constant
    speed set-points evenly spaced from
    ``v_min`` to the ego's speed at the current lateral offset, so that following a slower
    obstacle at any speed is always among the candidates.  Trajectories: ``num_segments`` (4)
    speed/offset set-point pairs, ``horizon`` 15 s on ``num_steps`` = K = 100 grid points, a
    Bernstein basis of ``degree`` 10.
    Projection: ``constraint_points`` ("hull": bounds on Bernstein control points, sufficient
    for the bounds at every instant; "grid": at the grid steps), ``admm_iters`` fixed ADMM
    iterations per CEM iteration (10: the projection is warm-started at the planner output, and
    the boundary rows are corrected exactly afterwards; 10, 15 and 25 gave the same tuning-scene
    results, docs/benchmarks.md), ``admm_rho`` fixed step size (``None``: the projector's
    defaults, rho = 62.5 then adaptive), ``dtype`` of the jitted loop.

    Scalars (leaves): ``gamma`` γ = 0.9 (temperature), ``eta`` η = 0.6 (learning rate),
    ``cov_reg`` ε = 0.01; initial sampling distribution ``speed_std0`` (m/s) around the ego's
    speed and ``lateral_std_scale`` × half the lane width around its offset; cost weights and
    kernel (see :mod:`mmdopt.algorithm` and ``docs/benchmarks.md`` for how they were chosen);
    ``a``, ``b`` collision ellipse (m) plus the planning margins ``margin_long``, ``margin_lat``
    (m) and ``margin_rate`` (m/s: the longitudinal margin grows by this much per second) —
    part of MMD-Opt's surrogate design (they stand for the prediction spread a reduced set
    cannot represent); the scenario baselines (``degroot``, ``scenario_all``, ``saa``) use
    ``baseline_margin_scale`` × these margins, by default 0: the nominal ellipse, as de Groot et
    al. and the reference code plan (their worst-case sample set is their safety mechanism; see
    docs/benchmarks.md for both settings at matched progress);
    ``res_tol`` feasibility tolerance of the residual; ``saa_eps``, ``saa_temperature`` for the
    SAA baseline.  ``reduced_set`` configures the reduced-set selection; ``rs_lateral_scale``
    multiplies the samples' lateral offsets in the selection's kernel features (an anisotropic
    kernel: lateral intents count more than longitudinal spread).
    """

    # static: sizes and modes
    n_samples: int = _static(1000)
    n_cem: int = _static(150)
    n_elite: int = _static(50)
    iterations: int = _static(20)
    n_brake: int = _static(10)
    reduced_set_size: int = _static(20)
    num_segments: int = _static(4)
    horizon: float = _static(15.0)
    num_steps: int = _static(100)
    degree: int = _static(10)
    constraint_points: str = _static("hull")
    admm_iters: int = _static(10)
    admm_check_every: int = _static(25)
    dtype: str = _static("float32")
    admm_rho: float | None = _static(None)
    # leaves: optimiser
    gamma: float = 0.9
    eta: float = 0.6
    cov_reg: float = 0.01
    speed_std0: float = 4.0
    lateral_std_scale: float = 0.5
    # leaves: cost (eq. c_aug)
    v_des: float = 10.0
    w_speed: float = 1.0
    w_accel: float = 0.1
    w_res: float = 10.0
    w_mmd: float = 1.0e5
    w_coll: float = 100.0
    w_saa: float = 100.0
    bandwidth: float = 0.5
    f_scale: float = 1.0
    a: float = 4.5
    b: float = 3.5
    margin_long: float = 2.5
    margin_rate: float = 1.9
    rs_lateral_scale: float = 10.0
    margin_lat: float = 0.4
    baseline_margin_scale: float = 0.0
    res_tol: float = 0.05
    saa_eps: float = 0.02
    saa_temperature: float = 0.05
    reduced_set: ReducedSetConfig = field(default_factory=ReducedSetConfig)

    def replace(self, **kw) -> MMDOptConfig:
        return dataclasses.replace(self, **kw)

    def __post_init__(self) -> None:
        ints = (
            "n_samples",
            "n_cem",
            "n_elite",
            "iterations",
            "n_brake",
            "reduced_set_size",
            "num_segments",
            "num_steps",
            "degree",
            "admm_iters",
            "admm_check_every",
        )
        for name in ints:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer):
                raise ValueError(f"MMDOptConfig.{name} must be an int, got {v!r}")
        if not (2 <= self.n_elite <= self.n_cem <= self.n_samples):
            raise ValueError(
                "MMDOptConfig needs 2 <= n_elite <= n_cem <= n_samples, got "
                f"n_elite={self.n_elite}, n_cem={self.n_cem}, n_samples={self.n_samples}"
            )
        if self.n_brake < 0 or self.n_samples - self.n_elite - self.n_brake < 1:
            raise ValueError(
                "MMDOptConfig.n_brake must be >= 0 and leave room for fresh samples "
                f"(n_samples - n_elite - n_brake >= 1), got n_brake={self.n_brake}"
            )
        if self.iterations < 1 or self.reduced_set_size < 1 or self.num_segments < 1:
            raise ValueError("iterations, reduced_set_size and num_segments must be >= 1")
        if self.constraint_points not in ("hull", "grid"):
            raise ValueError(
                f"constraint_points must be 'hull' or 'grid', got {self.constraint_points!r}"
            )
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"dtype must be 'float32' or 'float64', got {self.dtype!r}")
        for name in (
            "gamma",
            "bandwidth",
            "a",
            "b",
            "res_tol",
            "saa_eps",
            "saa_temperature",
            "speed_std0",
        ):
            v = getattr(self, name)
            if _concrete(v) and not float(v) > 0:
                raise ValueError(f"MMDOptConfig.{name} must be > 0, got {v}")
        v = self.baseline_margin_scale
        if _concrete(v) and not float(v) >= 0:
            raise ValueError(f"MMDOptConfig.baseline_margin_scale must be >= 0, got {v}")
        if _concrete(self.eta) and not 0 < float(self.eta) <= 1:
            raise ValueError(f"MMDOptConfig.eta must be in (0, 1], got {self.eta}")

    @property
    def d_dim(self) -> int:
        return 2 * self.num_segments


def _concrete(v) -> bool:
    # only plain numbers are validated: pytree unflattening (jit, lower) passes other objects
    return isinstance(v, int | float | np.number) and not isinstance(v, bool)


# ---------------------------------------------------------------------------------- problem set-up
class CEMProblem:
    """Host-side constants of one (config statics, road bounds) pair: basis, planner, projection.

    Built once and cached by :func:`build_problem`; holds the jitted solvers.
    """

    def __init__(self, cfg: MMDOptConfig, bounds: frenet.ProjectionBounds):
        grid = frenet.TimeGrid(cfg.horizon, cfg.num_steps)
        self.basis = frenet.BernsteinBasis(grid, degree=cfg.degree)
        self.planner = frenet.BehaviouralPlanner(
            self.basis, frenet.PlannerConfig(num_segments=cfg.num_segments)
        )
        self.bounds = bounds
        self.problem = frenet.ProjectionProblem(
            self.basis, bounds, constraint_points=cfg.constraint_points
        )
        # residuals are always reported on the full grid
        self.grid_problem = (
            self.problem
            if cfg.constraint_points == "grid"
            else frenet.ProjectionProblem(self.basis, bounds, constraint_points="grid")
        )
        self.projector = self.problem.jax_projector(
            num_iters=cfg.admm_iters,
            dtype=cfg.dtype,
            check_every=min(cfg.admm_check_every, cfg.admm_iters),
            # None: the projector's measured defaults (start at rho = 62.5, adaptive)
            **({} if cfg.admm_rho is None else dict(rho=float(cfg.admm_rho), adaptive_rho=False)),
        )
        self.nvar = self.basis.nvar
        self.W = np.asarray(self.planner.W)
        self.P = np.asarray(self.basis.P)
        self.Pdot = np.asarray(self.basis.Pdot)
        self.Pddot = np.asarray(self.basis.Pddot)
        self._jit: dict[Any, Any] = {}

    def t(self) -> np.ndarray:
        return self.basis.grid.t


def _statics(cfg: MMDOptConfig) -> tuple:
    return tuple(getattr(cfg, f.name) for f in dataclasses.fields(cfg) if f.metadata.get("static"))


def build_problem(cfg: MMDOptConfig, bounds: frenet.ProjectionBounds) -> CEMProblem:
    """The cached :class:`CEMProblem` for ``cfg``'s static fields and the projection ``bounds``."""
    key = (_statics(cfg), _bounds_key(bounds))
    return _build_problem_cached(key, cfg, bounds)


def _bounds_key(b: frenet.ProjectionBounds) -> tuple:
    return tuple(
        (
            f.name,
            tuple(np.atleast_1d(np.asarray(getattr(b, f.name), float)).tolist())
            if getattr(b, f.name) is not None
            else None,
        )
        for f in dataclasses.fields(b)
    )


_PROBLEMS: dict[tuple, CEMProblem] = {}


def _build_problem_cached(key, cfg, bounds) -> CEMProblem:
    hit = _PROBLEMS.get(key)
    if hit is None:
        hit = CEMProblem(cfg, bounds)
        if len(_PROBLEMS) >= 16:
            _PROBLEMS.pop(next(iter(_PROBLEMS)))
        _PROBLEMS[key] = hit
    return hit


# ------------------------------------------------------------------------------------- the loop
class Best(NamedTuple):
    """Best-so-far sample (lowest cost), tracked in the carry."""

    cost: Any  # ()
    d: Any  # (D,)
    cx: Any  # (nvar,)
    cy: Any  # (nvar,)
    res: Any  # ()
    coll: Any  # () collision term (unweighted)
    iteration: Any  # () int


class CEMResult(NamedTuple):
    """Output of :func:`run_cem` (JAX or NumPy arrays)."""

    best: Best  # lowest cost over all iterations
    least_violating: Best  # lowest residual over all iterations (fallback)
    cost_trace: Any  # (N,) best-so-far cost after each iteration
    iter_min_cost: Any  # (N,) lowest cost of each iteration's ConstraintEliteSet
    iter_mean_elite_cost: Any  # (N,)
    n_feasible: Any  # (N,) samples with residual ≤ res_tol per iteration
    mu: Any  # (D,) final sampling mean
    cov: Any  # (D, D) final sampling covariance


class Data(NamedTuple):
    """Per-call inputs of the loop (all arrays)."""

    state: Any  # (6,) Frenet ego state
    mu0: Any  # (D,)
    cov0: Any  # (D, D)
    lo: Any  # (D,) clip bounds of d
    hi: Any  # (D,)
    brake: Any  # (n_brake, D) "brake in lane" inputs (constant speed set-points v_min … v₀)
    centres: Any  # (O, J, C, K, 2) obstacle circles, Frenet
    weights: Any  # (O, J)
    mask: Any  # (O, J) bool


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


def _sample(cfg: MMDOptConfig, key, mu, cov, elites, data: Data):
    """Batch of behavioural inputs: [elites; brake rows; fresh draws], clipped to the bounds."""
    n_new = cfg.n_samples - cfg.n_elite - cfg.n_brake
    D = mu.shape[0]
    L = jnp.linalg.cholesky(cov)
    z = jax.random.normal(key, (n_new, D), mu.dtype)
    new = mu + z @ L.T
    # order matters: residuals within res_tol tie and ties go to the lower index, so the previous
    # elites and the brake rows always reach the ConstraintEliteSet when feasible, and the fresh
    # draws fill it in (random) draw order
    d = jnp.concatenate([elites, data.brake.reshape(cfg.n_brake, D), new], axis=0)
    return jnp.clip(d, data.lo, data.hi)


def _evaluate(
    cfg: MMDOptConfig,
    prob: CEMProblem,
    mode: str,
    n_terms: int,
    it,
    d,
    cx,
    cy,
    res,
    data: Data,
    mu,
    cov,
    best: Best,
    lv: Best,
):
    """ConstraintEliteSet, cost, EliteSet, distribution update, best-so-far (one iteration)."""
    dt = cx.dtype
    res = jnp.where(jnp.isfinite(res), res, jnp.asarray(1e30, dt))
    n_feas = jnp.sum(res <= cfg.res_tol)
    # --- ConstraintEliteSet: n_cem lowest residuals (within res_tol all count as 0: index order)
    rank = jnp.maximum(res - cfg.res_tol, 0.0)
    _, ces = lax.top_k(-rank, cfg.n_cem)
    d_c, cx_c, cy_c, res_c = d[ces], cx[ces], cy[ces], res[ces]
    P, Pd, Pdd = (jnp.asarray(M, dt) for M in (prob.P, prob.Pdot, prob.Pddot))
    s, vs, as_ = cx_c @ P.T, cx_c @ Pd.T, cx_c @ Pdd.T
    dd, ad = cy_c @ P.T, cy_c @ Pdd.T
    # --- cost, eq. (c_aug) + residual
    j_speed = jnp.mean((vs - cfg.v_des) ** 2, axis=1)
    j_acc = jnp.mean(as_ * as_ + ad * ad, axis=1)
    scale = 1.0 if mode == "mmd" else cfg.baseline_margin_scale
    f = ellipse_values(
        s,
        dd,
        data.centres.astype(dt),
        planning_semi_axis(cfg, prob.t(), dt, scale),
        cfg.b + scale * cfg.margin_lat,
    )
    if mode == "mmd":
        coll = mmd_cost(f, data.weights.astype(dt), cfg.bandwidth, cfg.f_scale, n_terms)
        w = cfg.w_mmd
    elif mode == "scenario":
        coll = scenario_cost(f, data.mask)
        w = cfg.w_coll
    elif mode == "saa":
        coll, _ = saa_cost(f, data.mask, cfg.saa_eps, cfg.saa_temperature)
        w = cfg.w_saa
    else:  # pragma: no cover
        raise ValueError(mode)
    cost = cfg.w_speed * j_speed + cfg.w_accel * j_acc + w * coll + cfg.w_res * res_c
    cost = jnp.where(jnp.isfinite(cost), cost, jnp.asarray(1e30, dt))
    # --- EliteSet and the MPPI-weighted update, eqs. (mean_update), (cov_update), (s_formula)
    neg, el = lax.top_k(-cost, cfg.n_elite)
    cost_e = -neg
    d_e = d_c[el]
    sw = jnp.exp(-(cost_e - cost_e[0]) / cfg.gamma)
    sw = sw / jnp.sum(sw)
    mu_new = (1.0 - cfg.eta) * mu + cfg.eta * (sw @ d_e)
    diff = d_e - mu_new
    cov_new = (1.0 - cfg.eta) * cov + cfg.eta * (diff.T * sw) @ diff
    cov_new = 0.5 * (cov_new + cov_new.T) + cfg.cov_reg * jnp.eye(cov.shape[0], dtype=dt)
    # --- best so far (lowest cost) and least violating (lowest residual)
    i0 = ces[el[0]]
    cand = Best(cost_e[0], d[i0], cx[i0], cy[i0], res[i0], coll[el[0]], jnp.asarray(it, jnp.int32))
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
        jnp.asarray(it, jnp.int32),
    )
    take_lv = lv_cand.res < lv.res
    lv = jax.tree_util.tree_map(lambda a, b: jnp.where(take_lv, a, b), lv_cand, lv)
    info = (best.cost, cost_e[0], jnp.mean(cost_e), n_feas)
    return mu_new, cov_new, d_e, best, lv, info


def planning_semi_axis(cfg: MMDOptConfig, t, dt=None, scale=1.0):
    """Longitudinal semi-axis of the planning ellipse per step,
    ``a + scale·(margin_long + margin_rate·t)`` (m; the margin may grow with time like the spread
    of the predictions; ``scale`` is 1 for MMD-Opt, ``baseline_margin_scale`` for baselines)."""
    t = jnp.asarray(t, dt) if dt is not None else jnp.asarray(t)
    return cfg.a + scale * (cfg.margin_long + cfg.margin_rate * t)


def _plan(prob: CEMProblem, d, state, dt):
    W = jnp.asarray(prob.W, dt)
    n = prob.nvar
    st = jnp.broadcast_to(state[None], (d.shape[0], 6))
    z = jnp.concatenate([d, st], axis=1) @ W
    return z[:, :n], z[:, n:]


class _WarmStart(NamedTuple):
    x: Any
    y: Any


def _project_jax(prob: CEMProblem, cx_bar, cy_bar, state):
    """The jitted projection, warm-started from the planner output with zero duals."""
    m = prob.problem.num_rows
    ws = _WarmStart(
        jnp.concatenate([cx_bar, cy_bar], axis=1), jnp.zeros((cx_bar.shape[0], m), cx_bar.dtype)
    )
    out = prob.projector(cx_bar, cy_bar, state, warm_start=ws)
    return out.cx, out.cy, out.residual


def _init(cfg: MMDOptConfig, prob: CEMProblem, key, data: Data, dt):
    D = cfg.d_dim
    k_init, k_loop = jax.random.split(key)
    L0 = jnp.linalg.cholesky(data.cov0)
    z = jax.random.normal(k_init, (cfg.n_elite, D), dt)
    elites = jnp.clip(data.mu0 + z @ L0.T, data.lo, data.hi)
    keys = jax.random.split(k_loop, cfg.iterations)
    empty = _empty_best(D, prob.nvar, dt)
    return elites, keys, empty


def _cast(data: Data, dt) -> Data:
    return Data(*(x.astype(dt) if jnp.issubdtype(x.dtype, jnp.floating) else x for x in data))


def _make_scan_solver(prob: CEMProblem, mode: str, n_terms: int):
    """The whole of Algorithm 1 as one jitted function (``lax.scan`` over the iterations)."""

    def solve(cfg: MMDOptConfig, key, data: Data) -> CEMResult:
        dt = jnp.dtype(cfg.dtype)
        data = _cast(data, dt)
        elites, keys, empty = _init(cfg, prob, key, data, dt)

        def body(carry, xs):
            mu, cov, elites, best, lv = carry
            it, k = xs
            d = _sample(cfg, k, mu, cov, elites, data)
            cx_bar, cy_bar = _plan(prob, d, data.state, dt)
            cx, cy, res = _project_jax(prob, cx_bar, cy_bar, data.state)
            mu, cov, elites, best, lv, info = _evaluate(
                cfg, prob, mode, n_terms, it, d, cx, cy, res.astype(dt), data, mu, cov, best, lv
            )
            return (mu, cov, elites, best, lv), info

        carry0 = (data.mu0, data.cov0, elites, empty, empty)
        xs = (jnp.arange(cfg.iterations), keys)
        (mu, cov, _, best, lv), (trace, it_min, it_mean, n_feas) = lax.scan(body, carry0, xs)
        return CEMResult(best, lv, trace, it_min, it_mean, n_feas, mu, cov)

    return jax.jit(solve)


def _make_host_parts(prob: CEMProblem, mode: str, n_terms: int):
    @jax.jit
    def sample_plan(cfg, k, mu, cov, elites, data):
        dt = jnp.dtype(cfg.dtype)
        d = _sample(cfg, k, mu, cov, elites, data)
        cx_bar, cy_bar = _plan(prob, d, data.state, dt)
        return d, cx_bar, cy_bar

    @jax.jit
    def evaluate(cfg, it, d, cx, cy, res, data, mu, cov, best, lv):
        dt = jnp.dtype(cfg.dtype)
        return _evaluate(
            cfg,
            prob,
            mode,
            n_terms,
            it,
            d,
            cx.astype(dt),
            cy.astype(dt),
            res.astype(dt),
            data,
            mu,
            cov,
            best,
            lv,
        )

    @jax.jit
    def init(cfg, key, data):
        dt = jnp.dtype(cfg.dtype)
        return _init(cfg, prob, key, _cast(data, dt), dt)

    return sample_plan, evaluate, init


def n_taylor_terms(cfg: MMDOptConfig) -> int:
    """Static number of Taylor features for the MMD cost (f̄ ≤ 1, so ``t ≤ f_scale/bandwidth``):
    truncation below the loop's float resolution (relative 1e-7 in float32: 18 terms at the
    defaults instead of 21 for 1e-9; 1e-12 in float64)."""
    rel = 1e-7 if cfg.dtype == "float32" else 1e-12
    return taylor_terms(float(cfg.f_scale) / float(cfg.bandwidth), rel)


def run_cem(
    cfg: MMDOptConfig,
    prob: CEMProblem,
    key,
    data: Data,
    method: str,
    backend: str = "admm",
    **backend_settings,
) -> CEMResult:
    """Run Algorithm 1 for ``method`` with the projection on ``backend`` (see module docstring)."""
    mode = COST_MODE[method]
    n_terms = n_taylor_terms(cfg) if mode == "mmd" else 0
    if backend == "admm" and not backend_settings:
        jk = ("scan", mode, n_terms)
        fn = prob._jit.get(jk)
        if fn is None:
            fn = prob._jit[jk] = _make_scan_solver(prob, mode, n_terms)
        return fn(cfg, key, data)
    jk = ("host", mode, n_terms)
    parts = prob._jit.get(jk)
    if parts is None:
        parts = prob._jit[jk] = _make_host_parts(prob, mode, n_terms)
    sample_plan, evaluate, init = parts
    dt = np.dtype(cfg.dtype)
    data = _cast(data, dt)
    elites, keys, empty = init(cfg, key, data)
    mu, cov, best, lv = data.mu0, data.cov0, empty, empty
    state = np.asarray(data.state, np.float64)
    infos = []
    for it in range(cfg.iterations):
        d, cx_bar, cy_bar = sample_plan(cfg, keys[it], mu, cov, elites, data)
        pr = prob.problem.project(
            np.asarray(cx_bar, np.float64),
            np.asarray(cy_bar, np.float64),
            state,
            backend=backend,
            **backend_settings,
        )
        mu, cov, elites, best, lv, info = evaluate(
            cfg, it, d, pr.cx, pr.cy, pr.residual, data, mu, cov, best, lv
        )
        infos.append(info)
    trace, it_min, it_mean, n_feas = (jnp.stack(v) for v in zip(*infos, strict=True))
    return CEMResult(best, lv, trace, it_min, it_mean, n_feas, mu, cov)
