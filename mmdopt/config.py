"""The planner's configuration: small frozen sections, each of which checks its own fields.

::

    cfg = mmdopt.MMDOptConfig()                                  # the defaults (paper sizes)
    cfg = mmdopt.MMDOptConfig(cost=mmdopt.CostConfig(w_mmd=1e4))  # one section replaced
    cfg = cfg.replace(n_samples=300, risk=0.001)                # any field, by its name
    cfg = mmdopt.MMDOptConfig.from_dict({"cem": {"iterations": 10}})   # --config JSON
    cfg = mmdopt.MMDOptConfig.ngsim()                            # a named preset

=====================  =======================================================================
section                what it holds
=====================  =======================================================================
``CEMConfig``          Algorithm 1's sampler: batch sizes, iterations, γ, η, initial spread
``TrajectoryConfig``   the time grid and the Bernstein basis of the Frenet planner
``ProjectionConfig``   the projection QP's fixed ADMM budget and feasibility tolerance
``CostConfig``         eq. (c_aug): speed tracking, comfort, residual and MMD weights
``SafetyConfig``       the risk level and the safety model: ``Footprint`` (the one collision
                       ellipse, in ``mmdopt.geometry``), ``MarginConfig``, ``RoadRules``
``SelectionConfig``    the reduced set: its size m and the selector's CEM
``BaselineConfig``     fields only the baselines read (de Groot, SAA, CVaR, all samples)
``ScheduleConfig``     the constants of the risk passes around Algorithm 1 (``mmdopt.schedule``)
=====================  =======================================================================

Sizes and modes are static (changing them recompiles); tunable scalars are pytree leaves.
The static fields that only the host-side steps of :func:`mmdopt.plan` read (``margin_mode``,
``coverage_knn``, ``reselect``, ``risk_hits``, ``nearest_futures``, ``joint_futures``,
``unsafe_brake``, ``reduced_set_size`` and the selector's ``reduced_set``) do not recompile
Algorithm 1: its programs see :meth:`MMDOptConfig.program`, with those fields at their defaults.
Every field name is unique across the sections, so ``replace(name=value)`` reaches any of them.
"Automatic" is spelled ``None`` everywhere (``reselect``, ``coverage_knn``, ``project_chunk``,
``admm_rho``, ``saa_eps``, ``cvar_alpha``).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import jax
import numpy as np

from .geometry import Footprint
from .reduced_set import ReducedSetConfig

__all__ = [
    "CEMConfig",
    "TrajectoryConfig",
    "ProjectionConfig",
    "CostConfig",
    "MarginConfig",
    "RoadRules",
    "SafetyConfig",
    "SelectionConfig",
    "BaselineConfig",
    "ScheduleConfig",
    "MMDOptConfig",
    "SAA_EPS_LINEAR",
    "W_COVER",
    "MMD_RISK_HITS",
]

#: SAA's chance level in the "linear" margin mode when ``BaselineConfig.saa_eps`` is ``None``
SAA_EPS_LINEAR = 0.02
#: CVaR's level α in the "linear" margin mode when ``BaselineConfig.cvar_alpha`` is ``None``
#: (the journal version's ``alpha_quant``)
CVAR_ALPHA_LINEAR = 0.98
#: weight of the coverage term of the MMD cost in the "samples" margin mode (the default)
W_COVER = 100.0
#: the planning futures (joint draws of every obstacle, ``SafetyConfig.joint_futures``) an
#: MMD-Opt plan drawn from a predictor may meet with its 95 % bound ≤ ε ("samples" margin mode,
#: ``SafetyConfig.risk_hits = None``): it draws n(ε) ≈ 52/ε futures instead of ≈ 3/ε, so that
#: its plans may come as close to ε as the bound allows (docs/experiments/frontier.md)
MMD_RISK_HITS = 40


def _static(default):
    return field(default=default, metadata=dict(static=True))


def _host(default):
    """A static field only the host-side steps of :func:`mmdopt.plan` read, never Algorithm 1's
    programs: configs differing only in such fields share them (:meth:`MMDOptConfig.program`)."""
    return field(default=default, metadata=dict(static=True, host=True))


def _plain(v) -> bool:
    # only plain numbers are validated: pytree unflattening (jit, vmap) passes other objects
    return isinstance(v, int | float | np.number) and not isinstance(v, bool)


class _Section:
    """Shared checks of a config section (a frozen dataclass): the subclasses list their
    integer, positive and non-negative fields; every numeric leaf must be finite."""

    _ints: tuple[str, ...] = ()
    _positive: tuple[str, ...] = ()
    _nonneg: tuple[str, ...] = ()
    _choices: dict[str, tuple] = {}

    def _check(self) -> None:
        name = type(self).__name__
        for f in self._ints:
            v = getattr(self, f)
            if v is None and f in _AUTO:
                continue
            if isinstance(v, bool) or not isinstance(v, int | np.integer):
                raise ValueError(f"{name}.{f} must be an int, got {v!r}")
        for f, options in self._choices.items():
            v = getattr(self, f)
            if v not in options:
                raise ValueError(f"{name}.{f} must be one of {options}, got {v!r}")
        for fld in dataclasses.fields(self):
            v = getattr(self, fld.name)
            if isinstance(v, str | bytes | complex) and fld.name not in self._choices:
                raise ValueError(f"{name}.{fld.name} must be a real number, got {v!r}")
            if not _plain(v):
                continue
            x = float(v)
            if not math.isfinite(x):
                raise ValueError(f"{name}.{fld.name} must be finite, got {v!r}")
            if fld.name in self._positive and not x > 0:
                raise ValueError(f"{name}.{fld.name} must be > 0, got {v!r}")
            if fld.name in self._nonneg and not x >= 0:
                raise ValueError(f"{name}.{fld.name} must be >= 0, got {v!r}")

    def replace(self, **kw):
        return dataclasses.replace(self, **kw)


#: fields whose ``None`` means "automatic"
_AUTO = ("reselect", "coverage_knn", "project_chunk", "risk_hits")


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class CEMConfig(_Section):
    """Algorithm 1's sampler (paper Alg. 1; the paper's sizes).

    n_samples : n̄_cem, behavioural samples per iteration (1000)
    n_cem : the ConstraintEliteSet's size (150);  n_elite : n_e, the EliteSet's size (50)
    iterations : N (20)
    n_brake : "brake in lane" rows per batch: constant speed set-points from ``v_min`` to the
        ego's speed at its offset, so following a slower obstacle is always a candidate (10)
    dtype : float type of the jitted loop ("float32")
    gamma : γ, the temperature of eq. (s_formula) (0.9);  eta : η, the learning rate of
        eqs. (mean_update), (cov_update) (0.6);  cov_reg : ε I added to Σ (0.01)
    speed_std0 : initial spread of the speed set-points around the ego's speed (m/s)
    lateral_std_scale : initial spread of the lateral set-points, × half the lane width
    """

    n_samples: int = _static(1000)
    n_cem: int = _static(150)
    n_elite: int = _static(50)
    iterations: int = _static(20)
    n_brake: int = _static(10)
    dtype: str = _static("float32")
    gamma: float = 0.9
    eta: float = 0.6
    cov_reg: float = 0.01
    speed_std0: float = 4.0
    lateral_std_scale: float = 0.5

    _ints = ("n_samples", "n_cem", "n_elite", "iterations", "n_brake")
    _positive = ("gamma", "speed_std0")
    _choices = {"dtype": ("float32", "float64")}

    def __post_init__(self) -> None:
        self._check()
        if not (2 <= self.n_elite <= self.n_cem <= self.n_samples):
            raise ValueError(
                "CEMConfig needs 2 <= n_elite <= n_cem <= n_samples, got "
                f"n_elite={self.n_elite}, n_cem={self.n_cem}, n_samples={self.n_samples}"
            )
        if self.n_brake < 0 or self.n_samples - self.n_elite - self.n_brake < 1:
            raise ValueError(
                "CEMConfig.n_brake must be >= 0 and leave room for fresh samples "
                f"(n_samples - n_elite - n_brake >= 1), got n_brake={self.n_brake}"
            )
        if self.iterations < 1:
            raise ValueError(f"CEMConfig.iterations must be >= 1, got {self.iterations}")
        if _plain(self.eta) and not 0 < float(self.eta) <= 1:
            raise ValueError(f"CEMConfig.eta must be in (0, 1], got {self.eta}")


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class TrajectoryConfig(_Section):
    """The Frenet planner's trajectories: ``num_segments`` speed/offset set-point pairs over
    ``horizon`` seconds on ``num_steps`` grid points, a Bernstein basis of ``degree``.

    lane_setpoints : lane discipline (not in the paper; off by default): each sampled lateral
        set-point is moved to the nearest lane centre of the road (``Road.lane_centres``) before
        the Frenet planner, so every candidate drives at lane centres and leaves one only to
        change lanes; the sampling distribution stays continuous (its update sees the sampled
        inputs), so lane changes stay explored.
    lateral_gain : k_p, the Frenet planner's lateral-offset tracking gain (1/s²; the reference
        code's 2): a larger gain reaches a new lateral set-point sooner (4: a 4 m lane change
        spends 1.0 s instead of 1.4 s more than 1 m from both lane centres)
    lane_commit : with ``lane_setpoints``, a lane change once begun is finished or given up at
        once (m; 0 = off, the default): when the ego is more than ``lane_commit`` from every lane
        centre, each candidate holds its first lateral set-point over the whole horizon, so no
        candidate postpones the rest of the change.  Without it, a receding-horizon planner can
        creep between two lanes for seconds: each plan finishes the change a little later than
        the one before, and only its first replan period is driven.
    """

    num_segments: int = _static(4)
    horizon: float = _static(15.0)
    num_steps: int = _static(100)
    degree: int = _static(10)
    lane_setpoints: bool = _static(False)
    lateral_gain: float = _static(2.0)
    lane_commit: float = _static(0.0)

    _ints = ("num_segments", "num_steps", "degree")
    _positive = ("horizon", "lateral_gain")
    _nonneg = ("lane_commit",)

    def __post_init__(self) -> None:
        self._check()
        for f in ("num_segments", "num_steps", "degree"):
            if getattr(self, f) < 1:
                raise ValueError(f"TrajectoryConfig.{f} must be >= 1, got {getattr(self, f)}")


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ProjectionConfig(_Section):
    """The projection QP inside Algorithm 1 (lane, speed and acceleration bounds).

    constraint_points : "hull" (bounds on the Bernstein control points: sufficient for every
        instant) or "grid" (at the grid steps)
    admm_iters : fixed ADMM iterations per CEM iteration, warm-started at the planner output,
        boundary rows corrected exactly afterwards (10);  admm_check_every : residual checks
    admm_rho : fixed ADMM step size (``None``: automatic, ρ = 62.5 then adaptive)
    project_chunk : rows planned and projected per chunk until ``n_cem`` rows are feasible
        (``None``: automatic, ``n_cem + n_elite``); the ConstraintEliteSet is the same as when
        every row is projected
    res_tol : feasibility tolerance of the residual (m, m/s, m/s²)
    """

    constraint_points: str = _static("hull")
    admm_iters: int = _static(10)
    admm_check_every: int = _static(25)
    admm_rho: float | None = _static(None)
    project_chunk: int | None = _static(None)
    res_tol: float = 0.05

    _ints = ("admm_iters", "admm_check_every", "project_chunk")
    _positive = ("res_tol",)
    _choices = {"constraint_points": ("hull", "grid")}

    def __post_init__(self) -> None:
        self._check()
        if self.admm_iters < 1 or self.admm_check_every < 1:
            raise ValueError("ProjectionConfig.admm_iters and admm_check_every must be >= 1")
        if self.project_chunk is not None and self.project_chunk < 1:
            raise ValueError(
                "ProjectionConfig.project_chunk must be >= 1 (or None: automatic), got "
                f"{self.project_chunk}"
            )
        r = self.admm_rho
        if r is not None and not (_plain(r) and math.isfinite(float(r)) and float(r) > 0):
            raise ValueError(f"ProjectionConfig.admm_rho must be None or > 0, got {r!r}")


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class CostConfig(_Section):
    """Algorithm 1's cost, eq. (c_aug) plus the residual term of eq. (s_formula).

    v_des : desired speed (m/s);  w_speed, w_accel : speed-tracking and comfort weights;
    w_res : weight of the constraint residual;  w_mmd : w, the weight of l_dist (eq. l_dist);
    w_cover : weight of the coverage term in the "samples" margin mode (:mod:`mmdopt.risk`);
    bandwidth : the Gaussian kernel σ of the MMD on f̄;  f_scale : f̄ is scaled by it first;
    w_lane : lane discipline (not in the paper; 0 = off): weight of the mean squared distance of
    the lateral trajectory to the nearest lane centre of the road (``Road.lane_centres``), m²,
    from ``lane_from`` × the horizon on (:func:`mmdopt.algorithm.lane_cost`);
    lane_from : where the lane cost starts, a fraction of the horizon in [0, 1): 0.5 (the
        default) makes a lane change inside the first half free, 0 charges every lane change
        the time it spends between lanes.
    """

    v_des: float = 10.0
    w_speed: float = 1.0
    w_accel: float = 0.1
    w_res: float = 10.0
    w_mmd: float = 1.0e5
    w_cover: float = W_COVER
    bandwidth: float = 0.5
    f_scale: float = 1.0
    w_lane: float = 0.0
    lane_from: float = _static(0.5)

    _positive = ("bandwidth",)
    _nonneg = ("w_speed", "w_accel", "w_res", "w_mmd", "w_cover", "w_lane", "lane_from")

    def __post_init__(self) -> None:
        self._check()
        if not self.lane_from < 1.0:
            raise ValueError(f"CostConfig.lane_from must be in [0, 1), got {self.lane_from!r}")


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class MarginConfig(_Section):
    """Planning margins around every obstacle point (they stand for the spread a reduced set
    cannot show).

    margin_mode : "samples" (default; :mod:`mmdopt.risk`): each point's ellipse is inflated per
        step by the spread of the planning samples of its cluster, to contain them with
        probability ``1 − risk`` under a per-step Gaussian fit;  "linear": the time-linear
        constants ``margin_long + margin_rate·t`` (m) and ``margin_lat`` (m)
    coverage_knn : the neighbourhood standing for a sample's cluster when a method plans on all
        samples (``None``: automatic, ``n // reduced_set_size``)
    coverage_prior : pseudo-count of the pooled spread a small cluster is shrunk towards
    coverage_bandwidth : kernel-density bandwidth factor added in quadrature to the
        longitudinal spread (0: off)
    """

    margin_mode: str = _host("samples")
    coverage_knn: int | None = _host(None)
    margin_long: float = 2.5
    margin_lat: float = 0.4
    margin_rate: float = 1.9
    coverage_prior: float = 2.0
    coverage_bandwidth: float = 0.0

    _ints = ("coverage_knn",)
    _nonneg = ("coverage_prior", "coverage_bandwidth")
    _choices = {"margin_mode": ("linear", "samples")}

    def __post_init__(self) -> None:
        self._check()
        if self.coverage_knn is not None and self.coverage_knn < 1:
            raise ValueError(
                "MarginConfig.coverage_knn must be >= 1 (or None: automatic), got "
                f"{self.coverage_knn}"
            )


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class RoadRules(_Section):
    """Rules of the road the ego is responsible for (not in the paper; all off by default, and
    static: the default compiles the program without them).

    headway_time h (s), headway_gap d₀ (m): behind every obstacle point the longitudinal
        semi-axis is at least ``a + d₀ + h·ṡ_ego`` (a time-headway following distance, as in
        ACC and RSS) — a floor under the planning margins, not added to them
    margin_ahead_scale : scales the planning margins on the other side (the ego ahead)
    rear_exempt_width w (m): a follower costs nothing — a point in line with the ego
        (|Δd| < w) that has stayed in line since it was behind the ego
        (:func:`mmdopt.collision.rear_exempt`)
    slip_ratio r : kinematic slip limit ``|ḋ| ≤ r·max(ṡ, 0)`` (a heading within atan(r) of the
        path) in the projection's residual; feasibility then comes first in the cost
    slip_tol : the excess lateral speed (m/s) that alone uses up ``res_tol``
    headway_lane w_h (m): the following distance is a rule for the lane (0 = off, the default):
        behind a point and less than w_h to its side (a corridor, as the RSS shield's
        ``lateral_overlap``), ``f`` measures the longitudinal gap only
        (:func:`mmdopt.collision.ellipse_values`), so a plan part of the way into the next lane
        still keeps the whole following distance.  Off, the following-distance ellipse gives a
        plan credit for every metre it moves sideways, and a planner too close behind a car
        prefers a swerve that ends between two lanes.
    """

    headway_time: float = _static(0.0)
    headway_gap: float = _static(0.0)
    margin_ahead_scale: float = _static(1.0)
    rear_exempt_width: float = _static(0.0)
    slip_ratio: float = _static(0.0)
    slip_tol: float = _static(0.01)
    headway_lane: float = _static(0.0)

    _nonneg = (
        "headway_time",
        "headway_gap",
        "margin_ahead_scale",
        "rear_exempt_width",
        "slip_ratio",
        "headway_lane",
    )
    _positive = ("slip_tol",)

    def __post_init__(self) -> None:
        for fld in dataclasses.fields(self):
            v = getattr(self, fld.name)
            if not _plain(v):
                raise ValueError(f"RoadRules.{fld.name} must be a real number, got {v!r}")
        self._check()

    @property
    def asymmetric(self) -> bool:
        """Whether the responsibility-aware longitudinal model is on (any of its rules set)."""
        return (
            self.headway_time != 0.0
            or self.headway_gap != 0.0
            or self.margin_ahead_scale != 1.0
            or self.rear_exempt_width != 0.0
        )

    @property
    def kinematic(self) -> bool:
        """Whether the slip limit is on (``slip_ratio > 0``)."""
        return self.slip_ratio > 0


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SafetyConfig(_Section):
    """The safety model: the risk level, the footprint, the margins and the rules of the road.

    risk : ε, the target probability that the plan's footprint meets an obstacle, under the
        predictor's distribution of futures (:mod:`mmdopt.risk`; 0.005)
    reselect : samples in deepest conflict with the first plan added to the reduced set for a
        second, warm-started pass (``None``: automatic — 0 for every built-in method: MMD-Opt's
        nearest-futures pass does its work at a fraction of the cost; 0: off;
        :meth:`mmdopt.methods.PlanMethod.reselect`)
    footprint : the collision ellipse (:class:`mmdopt.Footprint`), the one every user reads
    margins : :class:`MarginConfig`;  rules : :class:`RoadRules`
    risk_hits : when ``plan`` draws its futures from a predictor, n(ε) is the fewest futures per
        obstacle for which a plan meeting ``risk_hits`` of them still has a 95 % bound ≤ ε
        (:func:`mmdopt.risk.samples_for_risk`; 0: the fewest that can confirm ε at all, so a
        plan must clear every one; ``None``: automatic — :data:`MMD_RISK_HITS` for MMD-Opt in
        the "samples" margin mode, else 0; :meth:`mmdopt.methods.PlanMethod.risk_hits`)
    nearest_futures : MMD-Opt's nearest-futures pass in the "samples" margin mode: Algorithm 1,
        warm-started from the plan so far, against the ``nearest_futures`` planning futures per
        obstacle nearest to that plan (all of them when there are fewer), with the sample-average
        chance term at the number of futures the plan may meet while its 95 % bound stays ≤ ε
        and loose coverage margins (100; 0: off; skipped when ε is below what the futures can
        confirm; repeated around its plan with one hit fewer, at most twice, while that plan's
        bound exceeds ε).  Each of its plans is one more candidate of the final check
    joint_futures : whether sample i of every obstacle is one joint draw of the scene's future
        (True, the default: a predictor's draw, and how the benchmarks' metric counts): the
        plan's 95 % bound is then Clopper–Pearson on the number of joint futures it meets (those
        it meets with any obstacle), and n(ε) does not grow with the number of obstacles.
        False: each obstacle's samples are separate draws, paired in no particular order; the
        bound is the union over obstacles (Bonferroni), valid whatever their dependence, and
        n(ε) grows about linearly with O (:func:`mmdopt.risk.risk_bound`)
    unsafe_brake : where the plan meets every planning future of some obstacle (``unsafe``)
        and a stop at this deceleration (m/s²) meets fewer, brake (``fallback``; not from a car
        behind).  ``None``: return the plan flagged (NGSIM: 6; :func:`mmdopt.safety.braking_plan`)
    """

    risk: float = 0.005
    reselect: int | None = _host(None)
    risk_hits: int | None = _host(None)
    nearest_futures: int = _host(100)
    joint_futures: bool = _host(True)
    unsafe_brake: float | None = _host(None)
    footprint: Footprint = field(default_factory=Footprint)
    margins: MarginConfig = field(default_factory=MarginConfig)
    rules: RoadRules = field(default_factory=RoadRules)

    _ints = ("reselect", "risk_hits", "nearest_futures")
    _nonneg = _ints  # (None: automatic)
    _positive = ("unsafe_brake",)

    def __post_init__(self) -> None:
        self._check()
        if not isinstance(self.joint_futures, bool | np.bool_):
            raise ValueError(
                f"SafetyConfig.joint_futures must be a bool, got {self.joint_futures!r}"
            )
        if isinstance(self.unsafe_brake, bool):  # (a str is refused by _check)
            raise ValueError(
                f"SafetyConfig.unsafe_brake must be None or m/s² > 0, got {self.unsafe_brake!r}"
            )
        if _plain(self.risk) and not 0 < float(self.risk) < 0.5:
            raise ValueError(f"SafetyConfig.risk must be in (0, 0.5), got {self.risk!r}")
        subsections = (("footprint", Footprint), ("margins", MarginConfig), ("rules", RoadRules))
        for name, cls in subsections:
            if not isinstance(getattr(self, name), cls):
                raise ValueError(
                    f"SafetyConfig.{name} must be a {cls.__name__}, got "
                    f"{type(getattr(self, name)).__name__}"
                )


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SelectionConfig(_Section):
    """The reduced set: ``reduced_set_size`` m (20; the paper's Table II range is 10 … 50),
    ``rs_lateral_scale`` (the samples' lateral offsets × this in the selector's kernel
    features: lateral intents count more than longitudinal spread) and the selector's
    :class:`~mmdopt.ReducedSetConfig` ``reduced_set``."""

    reduced_set_size: int = _host(20)
    rs_lateral_scale: float = 10.0
    reduced_set: ReducedSetConfig = field(
        default_factory=ReducedSetConfig, metadata=dict(host=True)
    )

    _ints = ("reduced_set_size",)
    _positive = ("rs_lateral_scale",)

    def __post_init__(self) -> None:
        self._check()
        if self.reduced_set_size < 1:
            raise ValueError(
                f"SelectionConfig.reduced_set_size must be >= 1, got {self.reduced_set_size}"
            )
        if not isinstance(self.reduced_set, ReducedSetConfig):
            raise ValueError(
                "SelectionConfig.reduced_set must be a ReducedSetConfig, got "
                f"{type(self.reduced_set).__name__}"
            )


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class BaselineConfig(_Section):
    """Fields only the baselines read.

    w_coll : weight of the deterministic scenario cost (de Groot, random, all samples)
    w_saa : weight of the sample-average chance constraint (SAA)
    saa_eps : SAA's chance level (``None``: automatic — the risk level in the "samples" margin
        mode, :data:`SAA_EPS_LINEAR` in the "linear" one);  saa_temperature : its smoothing
    baseline_margin_scale : the scenario baselines plan with this × the linear margins (0: the
        nominal ellipse, as de Groot et al. and the reference code plan)
    w_cvar : weight of the CVaR cost (``cvar``)
    cvar_alpha : its level α (``None``: automatic — ``1 − ε`` in the "samples" margin mode, so
        that the CVaR averages the worst ε-fraction of the futures, the tail the risk level
        speaks of; :data:`CVAR_ALPHA_LINEAR` in the "linear" one)
    """

    w_coll: float = 100.0
    w_saa: float = 100.0
    saa_eps: float | None = None
    saa_temperature: float = 0.05
    baseline_margin_scale: float = 0.0
    w_cvar: float = 100.0
    cvar_alpha: float | None = None

    _positive = ("saa_temperature",)
    _nonneg = ("w_coll", "w_saa", "baseline_margin_scale", "w_cvar")

    def __post_init__(self) -> None:
        self._check()
        v = self.saa_eps
        if v is not None and _plain(v) and not 0 < float(v) < 1:
            raise ValueError(f"BaselineConfig.saa_eps must be in (0, 1) or None, got {v!r}")
        v = self.cvar_alpha
        if v is not None and _plain(v) and not 0 <= float(v) < 1:
            raise ValueError(f"BaselineConfig.cvar_alpha must be in [0, 1) or None, got {v!r}")


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ScheduleConfig(_Section):
    """The constants of the risk passes around Algorithm 1 in the "samples" margin mode
    (:mod:`mmdopt.schedule`); host-side only, so changing them recompiles nothing.

    nearest_repeats : the most repeats of the nearest-futures pass while its plan's bound
        exceeds ε, each around the last plan with one allowed hit fewer (2)
    nearest_margin_factor : the nearest-futures pass's coverage margins are at level
        min(this · ε, ``level_cap``): it plans against the futures that matter themselves, and
        the final check's bound covers the rest (10)
    tail_passes : the most tail passes of the final check, each adding the planning samples the
        best plan so far meets to the reduced set (3; 0: off)
    margin_ladder : MMD-Opt's margin ladder: one more pass per rung with coverage margins at
        level rung · ε (capped at ``level_cap``), each warm-started from the one before, then a
        refining tail pass (``()``: off, the default; docs/experiments/frontier.md)
    level_cap : the loosest coverage level of a pass (0.45: z = Φ⁻¹(0.55) ≈ 0.13 σ)
    selection_pool : beyond this many samples a method with a selection pool chooses its
        reduced set among a random pool of this size ("samples" mode; 100)
    coverage_pool : beyond this many futures every coverage margin is estimated from this many
        of them, evenly spaced (k-NN clusters with k scaled by the share), 5000
    futures_budget : the most obstacle-futures (O · n) a plan drawn from a predictor draws
        for the hits it may meet (``risk_hits``): with O obstacles at most this / O each, never
        fewer than the n(ε) that can confirm ε (50 000)
    nearest_share : when the nearest-futures pass follows, it and the first pass share
        Algorithm 1's N iterations: it (each repeat too) runs this share (≥ 1), the first pass
        the rest (0.4: 12 + 8 of the paper's 20)
    """

    nearest_repeats: int = _host(2)
    nearest_margin_factor: float = _host(10.0)
    tail_passes: int = _host(3)
    margin_ladder: tuple[float, ...] = _host(())
    level_cap: float = _host(0.45)
    selection_pool: int = _host(100)
    coverage_pool: int = _host(5000)
    nearest_share: float = _host(0.4)
    futures_budget: int = _host(50_000)

    _ints = ("nearest_repeats", "tail_passes", "selection_pool", "coverage_pool",
             "futures_budget")  # fmt: skip
    _nonneg = ("nearest_repeats", "tail_passes")
    _positive = ("nearest_margin_factor", "level_cap", "selection_pool", "coverage_pool",
                 "futures_budget")  # fmt: skip

    def __post_init__(self) -> None:
        try:
            ladder = tuple(float(r) for r in self.margin_ladder)
        except (TypeError, ValueError):
            raise ValueError(
                f"ScheduleConfig.margin_ladder must be a sequence of numbers, got "
                f"{self.margin_ladder!r}"
            ) from None
        if any(not (r > 0) for r in ladder):
            raise ValueError(f"ScheduleConfig.margin_ladder rungs must be > 0, got {ladder}")
        object.__setattr__(self, "margin_ladder", ladder)
        self._check()
        if not 0 < float(self.nearest_share) < 1:
            raise ValueError(
                f"ScheduleConfig.nearest_share must be in (0, 1), got {self.nearest_share}"
            )
        if not 0 < float(self.level_cap) < 0.5:
            raise ValueError(f"ScheduleConfig.level_cap must be in (0, 0.5), got {self.level_cap}")


_SECTIONS: tuple[tuple[str, type], ...] = (
    ("cem", CEMConfig),
    ("trajectory", TrajectoryConfig),
    ("projection", ProjectionConfig),
    ("cost", CostConfig),
    ("safety", SafetyConfig),
    ("selection", SelectionConfig),
    ("baselines", BaselineConfig),
    ("schedule", ScheduleConfig),
)
_SUBSECTIONS: tuple[tuple[str, type], ...] = (
    ("footprint", Footprint),
    ("margins", MarginConfig),
    ("rules", RoadRules),
)


def _field_paths() -> dict[str, tuple[str, ...]]:
    """Every leaf field's name -> its path (section, [subsection,] field)."""
    out: dict[str, tuple[str, ...]] = {}
    sub = dict(_SUBSECTIONS)
    for sec, cls in _SECTIONS:
        for f in dataclasses.fields(cls):
            if f.name in sub:
                for g in dataclasses.fields(sub[f.name]):
                    out[g.name] = (sec, f.name, g.name)
            out[f.name] = (sec, f.name)  # a subsection by its name too (footprint=Footprint(...))
    return out


#: leaf field name -> path in the nested config (the names are unique)
FIELD_PATHS: Mapping[str, tuple[str, ...]] = MappingProxyType(_field_paths())
#: former names -> the field that replaces them
RENAMED: Mapping[str, str] = MappingProxyType({"risk_eps": "risk"})
#: former "automatic" sentinels of fields now spelled ``None``
_OLD_AUTO: Mapping[str, Any] = MappingProxyType(
    {"reselect": -1, "coverage_knn": 0, "project_chunk": 0}
)


def _program(obj):
    """``obj`` (a config section) with every field marked ``host`` at its default, recursively
    (the same object where no field changes; a host section, such as the selector's config, is
    always replaced by its default, so its section is always rebuilt — once per config object,
    as :meth:`MMDOptConfig.program` caches it)."""
    kw = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if f.metadata.get("host"):
            d = f.default_factory() if f.default is dataclasses.MISSING else f.default
            # a section (the selector's config) is replaced without comparing: its leaves may
            # be traced values, which have no truth value
            if dataclasses.is_dataclass(d) or v != d:
                kw[f.name] = d
        elif dataclasses.is_dataclass(v) and not isinstance(v, type):
            nv = _program(v)
            if nv is not v:
                kw[f.name] = nv
    return dataclasses.replace(obj, **kw) if kw else obj


def _apply(obj, changes: dict):
    """``obj`` with the nested ``changes`` applied, each (sub)section rebuilt once (its checks
    then see the new values together)."""
    if not changes:
        return obj
    known = {f.name for f in dataclasses.fields(obj)}
    bad = [k for k in changes if k not in known]
    if bad:
        raise ValueError(
            f"{type(obj).__name__} has no field {bad[0]!r}; its fields: {', '.join(sorted(known))}"
        )
    kw = {
        k: _apply(getattr(obj, k), v) if isinstance(v, dict) and dataclasses.is_dataclass(
            getattr(obj, k)) else v
        for k, v in changes.items()
    }  # fmt: skip
    return dataclasses.replace(obj, **kw)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class MMDOptConfig:
    """Every constant of Algorithm 1, in sections (a pytree; see :mod:`mmdopt.config`)."""

    cem: CEMConfig = field(default_factory=CEMConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    projection: ProjectionConfig = field(default_factory=ProjectionConfig)
    cost: CostConfig = field(default_factory=CostConfig)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    selection: SelectionConfig = field(default_factory=SelectionConfig)
    baselines: BaselineConfig = field(default_factory=BaselineConfig)
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)

    def __post_init__(self) -> None:
        for name, cls in _SECTIONS:
            v = getattr(self, name)
            if not isinstance(v, cls):
                raise ValueError(
                    f"MMDOptConfig.{name} must be a {cls.__name__}, got {type(v).__name__}"
                )

    # ------------------------------------------------------------------------- construction
    def replace(self, **kw: Any) -> MMDOptConfig:
        """A copy with sections (``cem=CEMConfig(...)``) or fields by name (``w_mmd=1e4``,
        ``risk=0.001``, ``a=3.0``; every field name is unique) replaced.  Unknown names raise
        ``ValueError`` naming them (a renamed field names its new name)."""
        sections = dict(_SECTIONS)
        changes: dict = {}  # nested {section: {field: value | {...}}}, applied section-wise
        for k, v in kw.items():
            if k in sections:
                if k in changes:
                    raise ValueError(f"section {k!r} given together with one of its fields")
                changes[k] = v
            elif k in FIELD_PATHS:
                node = changes
                *head, last = FIELD_PATHS[k]
                for p in head:
                    node = node.setdefault(p, {})
                    if not isinstance(node, dict):
                        raise ValueError(f"field {k!r} given together with its section {p!r}")
                node[last] = v
            elif k in RENAMED:
                new = RENAMED[k]
                raise ValueError(
                    f"MMDOptConfig has no field {k!r}: it is now {new!r} "
                    f"({'.'.join(FIELD_PATHS[new])})"
                )
            elif k in ("asymmetric", "kinematic", "yaw_aware"):
                raise ValueError(
                    f"{k!r} is not a field: it follows from the rules' values "
                    "(safety.rules / safety.footprint.yaw_extent)"
                )
            else:
                raise ValueError(_unknown_field(k))
        return _apply(self, changes)

    @classmethod
    def from_dict(cls, raw: Any, base: MMDOptConfig | None = None) -> MMDOptConfig:
        """A config from JSON-like data: the nested form (``{"cem": {"iterations": 10}}``,
        ``{"safety": {"footprint": {"a": 3.0}}}``, ``{"selection": {"reduced_set": {...}}}``)
        or, for older files, flat field names (``{"iterations": 10}``).  Values are checked by
        type; unknown keys, a renamed key and NaN/Infinity raise ``ValueError`` naming the key
        (the new name for a renamed one)."""
        if not isinstance(raw, dict):
            raise ValueError("the config must be a JSON object (nested sections or field names)")
        flat: dict[str, Any] = {}
        _flatten(raw, cls, "", flat)
        cfg = cls() if base is None else base
        try:
            return cfg.replace(**flat)
        except (TypeError, ValueError) as e:
            raise ValueError(str(e)) from None

    def to_dict(self) -> dict[str, Any]:
        """The nested JSON-able form that :meth:`from_dict` reads back."""
        return _to_dict(self)

    def program(self) -> MMDOptConfig:
        """This config as Algorithm 1's jitted programs see it: the host-only fields (the
        margin mode, ``coverage_knn``, ``reselect``, ``risk_hits``, ``nearest_futures``,
        ``joint_futures``, ``reduced_set_size`` and the selector's ``reduced_set``) at their
        defaults.  :func:`mmdopt.plan` reads those fields around Algorithm 1, which receives
        their effect as arrays (the reduced set, its margins, the futures), so configs with the
        same program share a :class:`~mmdopt.Planner`'s workspaces and compiled steps."""
        return self._program

    @functools.cached_property
    def _program(self) -> MMDOptConfig:  # computed once per config object (it is frozen)
        return _program(self)

    # ------------------------------------------------------------------------------ presets
    @classmethod
    def paper(cls, **overrides: Any) -> MMDOptConfig:
        """The paper's Algorithm 1 as Table II times it: the paper's sizes with the time-linear
        planning margins and no re-selection pass (the defaults are the risk-driven margins)."""
        return cls().replace(margin_mode="linear", reselect=0, **overrides)

    @classmethod
    def ngsim(cls, **overrides: Any) -> MMDOptConfig:
        """The recorded-traffic (NGSIM US-101) planner: 5 s on 51 points (the recordings' step),
        a 3.0 × 2.2 m ellipse (the ego point against a car's three circles: half a length
        + 0.5 m along, two half widths + 0.2 m across), time-linear margins 1.5 + 0.5·t m and
        0.2 m, a follower rule of 2 m, a slip limit of 0.5 and a yaw-aware footprint of 2.5 m
        (chosen on the training recordings), braking at 6 m/s² where no plan is clear
        (``unsafe_brake``), and sizes for 10–15 obstacles in real time on two cores (300
        samples, n_cem 60, n_e 20, 10 iterations, m = 10, selector 50/10/20)."""
        base = cls(
            cem=CEMConfig(n_samples=300, n_cem=60, n_elite=20, iterations=10),
            trajectory=TrajectoryConfig(horizon=5.0, num_steps=51),
            safety=SafetyConfig(
                reselect=0,
                unsafe_brake=6.0,
                footprint=Footprint(a=3.0, b=2.2, yaw_extent=2.5),
                margins=MarginConfig(
                    margin_mode="linear", margin_long=1.5, margin_lat=0.2, margin_rate=0.5
                ),
                rules=RoadRules(rear_exempt_width=2.0, slip_ratio=0.5),
            ),
            selection=SelectionConfig(
                reduced_set_size=10,
                reduced_set=ReducedSetConfig(iterations=20, population=50, n_elite=10),
            ),
        )
        return base.replace(**overrides)

    @classmethod
    def highway(cls, **overrides: Any) -> MMDOptConfig:
        """The closed-loop highway-env planner: 5 s on 51 points (re-planned every step), a
        lateral semi-axis of 2.6 m, time-linear margins 2.5 + 1.0·t m and 0.4 m, a desired speed
        of 30 m/s, sizes for a real-time budget (400 samples, n_cem 100, n_e 30, 12 iterations,
        m = 10), lane discipline (set-points at lane centres, ``w_lane`` = 6, lateral gain 4), a
        following distance of 6 m + 1.0 s·ṡ behind every obstacle point, kept in full within
        2.5 m to its side (``headway_lane``, the RSS shield's corridor), and on the risk dial one
        nearest-futures pass and no tail passes (the next replan comes δ later; the repeats cost
        time, not driving: docs/experiments/highway.md)."""
        base = cls().replace(
            horizon=5.0, num_steps=51, n_samples=400, n_cem=100, n_elite=30, iterations=12,
            reduced_set_size=10, v_des=30.0, b=2.6, margin_lat=0.4, margin_long=2.5,
            margin_rate=1.0, margin_mode="linear", reselect=0, lane_setpoints=True,
            lateral_gain=4.0, lane_commit=0.5, w_lane=6.0, headway_time=1.0, headway_gap=6.0,
            headway_lane=2.5, nearest_repeats=0, tail_passes=0,
        )  # fmt: skip
        return base.replace(**overrides)

    # ---------------------------------------------------------------------------- derived
    @property
    def d_dim(self) -> int:
        """Dimension of the behavioural input d: speed then lateral set-points."""
        return 2 * self.trajectory.num_segments

    @property
    def saa_level(self):
        """SAA's chance level: ``baselines.saa_eps``, or when that is ``None`` the risk level in
        the "samples" margin mode and :data:`SAA_EPS_LINEAR` in the "linear" one."""
        if self.baselines.saa_eps is not None:
            return self.baselines.saa_eps
        if self.safety.margins.margin_mode == "samples":
            return self.safety.risk
        return SAA_EPS_LINEAR

    @property
    def cvar_level(self):
        """CVaR's level α: ``baselines.cvar_alpha``, or when that is ``None`` ``1 − ε`` in the
        "samples" margin mode and :data:`CVAR_ALPHA_LINEAR` in the "linear" one."""
        if self.baselines.cvar_alpha is not None:
            return self.baselines.cvar_alpha
        if self.safety.margins.margin_mode == "samples":
            return 1.0 - self.safety.risk
        return CVAR_ALPHA_LINEAR

    def bound_groups(self, obstacles: int) -> int:
        """How many counts the plan's risk bound sums over (:func:`mmdopt.risk.risk_bound`,
        :func:`~mmdopt.risk.samples_for_risk`): 1 (the joint futures met) when
        ``safety.joint_futures``, else one per obstacle."""
        return 1 if self.safety.joint_futures else int(obstacles)


def _unknown_field(name: str) -> str:
    """The message for an unknown field ``name``: the nearest known names, and where to find
    them all (the full list is long)."""
    import difflib

    near = difflib.get_close_matches(name, list(FIELD_PATHS) + [s for s, _ in _SECTIONS], n=3)
    hint = f"; did you mean {' or '.join(repr(n) for n in near)}?" if near else ""
    return (
        f"MMDOptConfig has no field {name!r}{hint} (every field: mmdopt.config.FIELD_PATHS; "
        "sections: " + ", ".join(s for s, _ in _SECTIONS) + ")"
    )


def _type_check(name: str, value: Any, default: Any) -> Any:
    """``value`` checked against the type of the field's default (JSON has no tuples)."""
    number = isinstance(value, int | float) and not isinstance(value, bool)
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ValueError(f"{name} must be true or false, got {value!r}")
        return value
    if default is None or name.split(".")[-1] in _AUTO:
        if value is None:
            return None
        if name.split(".")[-1] in _AUTO:
            if not (isinstance(value, int) and not isinstance(value, bool)):
                raise ValueError(f"{name} must be an integer or null (automatic), got {value!r}")
            return value
        if not number:
            raise ValueError(f"{name} must be a number or null, got {value!r}")
        return float(value)
    if isinstance(default, int):
        if not (isinstance(value, int) and not isinstance(value, bool)):
            raise ValueError(f"{name} must be an integer, got {value!r}")
        return value
    if isinstance(default, float):
        if not number:
            raise ValueError(f"{name} must be a number, got {value!r}")
        return float(value)
    if isinstance(default, str) and not isinstance(value, str):
        raise ValueError(f"{name} must be a string, got {value!r}")
    return value


def _reduced_set_from(raw: Any, prefix: str) -> ReducedSetConfig:
    if not isinstance(raw, dict):
        raise ValueError(f"{prefix} must be a JSON object of ReducedSetConfig fields")
    names = {f.name: f for f in dataclasses.fields(ReducedSetConfig)}
    base = ReducedSetConfig()
    kw = {}
    for k, v in raw.items():
        if k not in names:
            raise ValueError(
                f"unknown ReducedSetConfig field {prefix}.{k}; known: {', '.join(sorted(names))}"
            )
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(
                f"{prefix}.{k} is NaN or Infinity; every value must be a finite number"
            )
        kw[k] = _type_check(f"{prefix}.{k}", v, getattr(base, k))
    try:
        return ReducedSetConfig(**kw)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{prefix}: {e}") from None


def _flatten(raw: dict, cls: type, prefix: str, out: dict[str, Any]) -> None:
    """Collect ``{field name: checked value}`` from nested sections or flat names."""
    sections = dict(_SECTIONS) | dict(_SUBSECTIONS)
    for k, v in raw.items():
        name = f"{prefix}{k}"
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"{name} is NaN or Infinity; every value must be a finite number")
        if k == "reduced_set":
            out[k] = _reduced_set_from(v, name)
        elif k in sections:
            if not isinstance(v, dict):
                raise ValueError(f"{name} must be a JSON object of {sections[k].__name__} fields")
            known = {f.name for f in dataclasses.fields(sections[k])}
            for sub in v:
                if sub not in known:
                    raise ValueError(
                        f"unknown {sections[k].__name__} field {name}.{sub}; known: "
                        f"{', '.join(sorted(known))}"
                    )
            _flatten(v, sections[k], f"{name}.", out)
        elif k in FIELD_PATHS:
            if k in _OLD_AUTO and v == _OLD_AUTO[k] and v is not None:
                raise ValueError(
                    f"{name} = {v} (automatic) is now spelled null "
                    f"({'.'.join(FIELD_PATHS[k])}: null)"
                )
            default = _default_at(FIELD_PATHS[k])
            out[k] = _type_check(name, v, default)
            if not prefix and len(FIELD_PATHS[k]) > 1:
                warnings.warn(
                    f"flat config key {k!r} is read as {'.'.join(FIELD_PATHS[k])}; "
                    "write the nested form",
                    DeprecationWarning,
                    stacklevel=4,
                )
        elif k in RENAMED:
            new = RENAMED[k]
            raise ValueError(f"{name} is now {'.'.join(FIELD_PATHS[new])}")
        else:
            known = sorted(set(dict(_SECTIONS)) | set(FIELD_PATHS))
            raise ValueError(f"unknown config key {name}; known: {', '.join(known)}")


def _default_at(path: tuple[str, ...]) -> Any:
    obj: Any = MMDOptConfig()
    for p in path:
        obj = getattr(obj, p)
    return obj


def _to_dict(obj: Any) -> Any:
    if dataclasses.is_dataclass(obj):
        return {f.name: _to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, tuple):  # JSON has lists (margin_ladder): equal after a round trip
        return [_to_dict(v) for v in obj]
    return obj
