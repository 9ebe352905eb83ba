"""The planning problem's set-up: the :class:`Problem` of one ego state and the
:class:`ObstacleSet` the collision term plans against, and the keys a workspace is cached by.
:mod:`mmdopt.algorithm` runs Algorithm 1 on them (and re-exports every name here)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import frenet

from .collision import collision_term, taylor_terms
from .config import MMDOptConfig

__all__ = [
    "statics",
    "bounds_key",
    "bounds_from_key",
    "Problem",
    "ObstacleSet",
    "n_taylor_terms",
]


# ---------------------------------------------------------------------------------- problem set-up
def statics(cfg: MMDOptConfig):
    """The static part of ``cfg`` that Algorithm 1 reads (sizes, modes, rules): the pytree
    structure of :meth:`~mmdopt.MMDOptConfig.program`, hashable; two configs with equal statics
    share a :class:`Workspace` and its compiled steps."""
    return jax.tree_util.tree_structure(cfg.program())


def bounds_key(b: frenet.ProjectionBounds) -> tuple:
    """A hashable description of projection bounds (static data of :class:`Problem`)."""
    return tuple(
        (
            f.name,
            tuple(np.atleast_1d(np.asarray(getattr(b, f.name), float)).tolist())
            if getattr(b, f.name) is not None
            else None,
        )
        for f in dataclasses.fields(b)
    )


def bounds_from_key(bkey: tuple) -> frenet.ProjectionBounds:
    """The :class:`frenet.ProjectionBounds` that :func:`bounds_key` describes."""
    kw = {
        name: None if v is None else (float(v[0]) if len(v) == 1 else np.asarray(v, float))
        for name, v in bkey
    }
    defaults = {f.name: f.default for f in dataclasses.fields(frenet.ProjectionBounds)}
    for name, v in kw.items():
        if isinstance(defaults.get(name), int) and isinstance(v, float):
            kw[name] = int(v)
    return frenet.ProjectionBounds(**kw)


# ------------------------------------------------------------------------------ inputs and state
@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Problem:
    """One planning problem: the ego state, the sampling prior and the bounds (a pytree).

    state : (6,) Frenet ego state ``(s, d, ṡ, ḋ, s̈, d̈)``;  mu0, cov0 : (D,), (D, D) initial
    sampling distribution of the behavioural input ``d`` (speed set-points, then lateral
    set-points);  lo, hi : (D,) clip bounds of ``d``;  brake : (n_brake, D) "brake in lane"
    inputs (constant speed set-points ``v_min … v₀``);  bounds : static, the projection bounds
    (:func:`bounds_key` of a :class:`frenet.ProjectionBounds`).
    """

    state: Any
    mu0: Any
    cov0: Any
    lo: Any
    hi: Any
    brake: Any
    bounds: tuple = field(metadata=dict(static=True))
    lanes: Any = None

    @staticmethod
    def create(
        cfg: MMDOptConfig,
        ego: frenet.EgoState,
        bounds: frenet.ProjectionBounds,
        lanes: tuple[float, ...] = (),
    ) -> Problem:
        """The problem of planning from ``ego`` (Frenet) within ``bounds``: the sampling prior is
        centred on the ego's speed and lateral offset (clipped to the bounds), with spreads
        ``speed_std0`` and ``lateral_std_scale`` × half the lane width.  ``lanes``: the road's
        lane-centre offsets, kept (for :func:`lane_cost`) when ``cfg.cost.w_lane > 0``."""
        S = cfg.trajectory.num_segments
        b = bounds.per_step(1)
        v_min, v_max = float(b["vx_min"][0]), float(b["vx_max"][0])
        y_lb, y_ub = float(b["y_lb"][0]), float(b["y_ub"][0])
        v0 = float(np.clip(ego.vs, v_min, v_max))
        y0 = float(np.clip(ego.d, y_lb, y_ub))
        half = 0.5 * (y_ub - y_lb)
        lat_std = float(cfg.cem.lateral_std_scale) * (half if np.isfinite(half) else 1.75)
        lat_std = max(lat_std, 1e-3)
        mu0 = np.array([v0] * S + [y0] * S)
        cov0 = np.diag([float(cfg.cem.speed_std0) ** 2] * S + [lat_std**2] * S)
        lo = np.array([v_min] * S + [y_lb] * S)
        hi = np.array([v_max] * S + [y_ub] * S)
        vlo = v_min if np.isfinite(v_min) else 0.0
        ladder = np.linspace(vlo, max(v0, vlo), cfg.cem.n_brake)
        brake = np.concatenate(
            [np.repeat(ladder[:, None], S, 1), np.full((cfg.cem.n_brake, S), y0)], 1
        )
        bkey = bounds_key(bounds)
        with jax.enable_x64(True):
            arr = lambda x: jnp.asarray(np.asarray(x, np.float64))  # noqa: E731
            lane_arr = None
            if (float(cfg.cost.w_lane) > 0.0 or cfg.trajectory.lane_setpoints) and len(lanes) > 0:
                lane_arr = arr(np.sort(np.asarray(lanes, np.float64)))
            return Problem(
                arr(ego.as_array()),
                arr(mu0),
                arr(cov0),
                arr(lo),
                arr(hi),
                arr(brake),
                bkey,
                lane_arr,
            )


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ObstacleSet:
    """What the collision term plans against (a pytree).

    centres : (O, J, C, K, 2) obstacle circle centres in the planning (Frenet) frame, J samples
    per obstacle (a reduced set, or all samples);  weights : (O, J) ᾱ;  mask : (O, J) bool;
    mode : static, the collision term — "embedding" (eq. l_dist), "scenario" (deterministic
    scenario cost), "chance" (sample-average chance constraint) or "tail" (CVaR),
    :mod:`mmdopt.collision`
    (:data:`~mmdopt.collision.COLLISION_TERMS`; the method names "mmd", "saa" and "cvar" are
    accepted);  n_terms : static, Taylor features of the MMD cost (:func:`n_taylor_terms`).
    """

    centres: Any
    weights: Any
    mask: Any
    mode: str = field(metadata=dict(static=True))
    n_terms: int = field(default=0, metadata=dict(static=True))
    margins: Any = None

    @staticmethod
    def create(
        cfg: MMDOptConfig, centres, weights, mode: str, mask=None, margins=None
    ) -> ObstacleSet:
        """Build (and validate) an obstacle set for ``cfg``; ``mode`` as above.

        ``margins`` : optional (3, O, J, K) sample-driven planning margins (m): longitudinal
        behind and ahead of each point, lateral (:func:`mmdopt.risk.coverage_margins`); when
        given they replace the time-linear margins of every method.
        """
        mode = collision_term(mode)
        c = np.asarray(centres, np.float64)
        w = np.asarray(weights, np.float64)
        if c.ndim != 5 or c.shape[-1] != 2 or c.shape[-2] != cfg.trajectory.num_steps:
            raise ValueError(
                "centres must have shape (O, J, C, K, 2) with K = "
                f"{cfg.trajectory.num_steps}, got {c.shape}"
            )
        if w.shape != c.shape[:2]:
            raise ValueError(f"weights must have shape {c.shape[:2]}, got {w.shape}")
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(w))):
            raise ValueError("centres and weights must be finite")
        if np.any(w < 0):
            raise ValueError("weights must be >= 0")
        m = np.ones(w.shape, bool) if mask is None else np.asarray(mask, bool)
        if m.shape != w.shape:
            raise ValueError(f"mask must have shape {w.shape}, got {m.shape}")
        n_terms = n_taylor_terms(cfg) if mode == "embedding" else 0
        mg = None
        if margins is not None:
            mg = np.asarray(margins, np.float64)
            want = (3, *w.shape, cfg.trajectory.num_steps)
            if mg.shape != want:
                raise ValueError(f"margins must have shape {want}, got {mg.shape}")
            if not np.all(np.isfinite(mg)) or np.any(mg < 0):
                raise ValueError("margins must be finite and >= 0")
        with jax.enable_x64(True):
            return ObstacleSet(
                jnp.asarray(c),
                jnp.asarray(w),
                jnp.asarray(m),
                mode,
                n_terms,
                None if mg is None else jnp.asarray(mg),
            )


def n_taylor_terms(cfg: MMDOptConfig) -> int:
    """Static number of Taylor features for the MMD cost (f̄ ≤ 1, so ``t ≤ f_scale/bandwidth``):
    truncation below the loop's float resolution (relative 1e-7 in float32: 18 terms at the
    defaults instead of 21 for 1e-9; 1e-12 in float64)."""
    rel = 1e-7 if cfg.cem.dtype == "float32" else 1e-12
    return taylor_terms(float(cfg.cost.f_scale) / float(cfg.cost.bandwidth), rel)
