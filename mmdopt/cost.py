"""The collision term of Algorithm 1's cost, eq. (c_aug): the planning ellipse (time-linear or
sample-driven margins, the responsibility rules, the yaw widening) and the method's collision
term against an :class:`~mmdopt.problem.ObstacleSet` (eq. l_dist, the scenario cost, SAA's chance
term).  :mod:`mmdopt.algorithm` scores every candidate with :func:`obstacle_cost`."""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

from .collision import (
    circle_max,
    collision_cost,
    cvar_cost,
    lane_lateral,
    mmd_cost,
    rear_exempt,
    saa_cost,
    scenario_cost,
)
from .config import MMDOptConfig
from .problem import ObstacleSet

__all__ = [
    "YAW_SPEED_FLOOR",
    "yaw_widening",
    "obstacle_cost",
    "planning_semi_axis",
    "headway_semi_axis",
    "margin_ellipse_values",
]

#: ego speed (m/s) under which the heading relative to the path is ill-defined: the floor in
#: the yaw widening's ``|ḋ| / sqrt(ṡ² + ḋ² + v²)`` (the heading hold of
#: :meth:`frenet.ReferencePath.trajectory_to_cartesian` uses the same speed)
YAW_SPEED_FLOOR = 0.05


def yaw_widening(cfg: MMDOptConfig, vs, vd):
    """Growth of the lateral semi-axis from the ego's heading relative to the path, (B, K):
    ``yaw_extent·|ḋ| / sqrt(ṡ² + ḋ² + v_f²)`` = ``yaw_extent·|sin Δθ|`` (:class:`MMDOptConfig`,
    yaw-aware footprint); ``vs``, ``vd`` (B, K) the samples' ṡ and ḋ."""
    vs, vd = jnp.asarray(vs), jnp.asarray(vd)
    if vs.ndim != 2 or vs.shape != vd.shape:
        raise ValueError(f"vs and vd must both be (B, K), got {vs.shape} and {vd.shape}")
    floor = jnp.asarray(YAW_SPEED_FLOOR * YAW_SPEED_FLOOR, vs.dtype)
    return cfg.safety.footprint.yaw_extent * jnp.abs(vd) / jnp.sqrt(vs * vs + vd * vd + floor)


def obstacle_cost(cfg: MMDOptConfig, ws: Any, s, dd, obstacles: ObstacleSet, dt, vs=None, vd=None):
    """The method's collision term and its weight (eq. c_aug), per ego sample (B,), on the
    :class:`~mmdopt.algorithm.Workspace` ``ws``; ``vs``,
    ``vd`` (B, K) the samples' ṡ and ḋ (needed when ``cfg.safety.rules.asymmetric`` /
    ``cfg.safety.footprint.yaw_aware``)."""
    mode = obstacles.mode
    if cfg.safety.rules.asymmetric and vs is None:
        raise ValueError("config.safety.rules.asymmetric needs the ego samples' speeds vs")
    if cfg.safety.footprint.yaw_aware and (vs is None or vd is None):
        raise ValueError(
            "config.safety.footprint.yaw_aware needs the ego samples' velocities vs, vd"
        )
    # the yaw-aware footprint: lateral semi-axis per sample and step (B, K), else none
    wide = yaw_widening(cfg, vs, vd).astype(dt) if cfg.safety.footprint.yaw_aware else None
    if obstacles.margins is not None:
        # sample-driven coverage margins (mmdopt.risk): per-point ellipses
        f = circle_max(margin_ellipse_values(
            cfg, s, dd, obstacles.centres.astype(dt), obstacles.margins, vs=vs, widen=wide
        ))  # fmt: skip
        if mode == "embedding":
            coll = mmd_cost(
                f,
                obstacles.weights.astype(dt),
                cfg.cost.bandwidth,
                cfg.cost.f_scale,
                obstacles.n_terms,
            )
            # coverage term: every penetration of a point's coverage ellipse costs
            # w_cover·f̄ whatever the point's weight ᾱ (the 1 − ε coverage holds only if no
            # ellipse is entered); returned weighted (the term's weight is then 1)
            cover = scenario_cost(f, obstacles.mask)
            return cfg.cost.w_mmd * coll + cfg.cost.w_cover * cover, jnp.asarray(1.0, dt)
        if mode == "scenario":
            return scenario_cost(f, obstacles.mask), cfg.baselines.w_coll
        if mode == "tail":
            return cvar_cost(f, obstacles.mask, cfg.cvar_level), cfg.baselines.w_cvar
        coll, _ = saa_cost(f, obstacles.mask, cfg.saa_level, cfg.baselines.saa_temperature)
        return coll, cfg.baselines.w_saa
    scale = 1.0 if mode == "embedding" else cfg.baselines.baseline_margin_scale
    a_plan = planning_semi_axis(cfg, ws.t(), dt, scale)
    a_behind = rear_w = None
    if cfg.safety.rules.asymmetric:
        a_behind = headway_semi_axis(cfg, a_plan, vs)
        a_plan = planning_semi_axis(cfg, ws.t(), dt, scale * cfg.safety.rules.margin_ahead_scale)
        rear_w = cfg.safety.rules.rear_exempt_width
    coll = collision_cost(
        mode,
        s,
        dd,
        obstacles.centres.astype(dt),
        obstacles.weights.astype(dt),
        obstacles.mask,
        a_plan,
        cfg.safety.footprint.b
        + scale * cfg.safety.margins.margin_lat
        + (0.0 if wide is None else wide),
        a_behind=a_behind,
        rear_exempt_width=rear_w,
        headway_lane=cfg.safety.rules.headway_lane,
        bandwidth=cfg.cost.bandwidth,
        f_scale=cfg.cost.f_scale,
        n_terms=obstacles.n_terms,
        saa_eps=cfg.saa_level,
        saa_temperature=cfg.baselines.saa_temperature,
        cvar_alpha=cfg.cvar_level,
    )
    w = {"embedding": cfg.cost.w_mmd, "scenario": cfg.baselines.w_coll,
         "chance": cfg.baselines.w_saa, "tail": cfg.baselines.w_cvar}[mode]  # fmt: skip
    return coll, w


def planning_semi_axis(cfg: MMDOptConfig, t, dt=None, scale=1.0):
    """Longitudinal semi-axis of the planning ellipse per step,
    ``a + scale·(margin_long + margin_rate·t)`` (m; the margin may grow with time like the spread
    of the predictions; ``scale`` is 1 for MMD-Opt, ``baseline_margin_scale`` for baselines)."""
    t = jnp.asarray(t, dt) if dt is not None else jnp.asarray(t)
    return cfg.safety.footprint.a + scale * (
        cfg.safety.margins.margin_long + cfg.safety.margins.margin_rate * t
    )


def headway_semi_axis(cfg: MMDOptConfig, a, vs):
    """Longitudinal semi-axis behind an obstacle point with the following distance:
    ``max(a_plan, a + d₀ + h·max(ṡ, 0))`` (m), ``a_plan`` the planning semi-axis ((K,) or
    scalar: ``a`` plus the margins), ``vs`` (B, K) the ego samples' speeds; returns (B, K).  The
    time-headway gap ≥ d₀ + h·v (ACC/RSS-style) is a floor under the prediction-spread margins,
    not added to them; not in the paper (:class:`MMDOptConfig`)."""
    vs = jnp.asarray(vs)
    floor = (
        cfg.safety.footprint.a
        + cfg.safety.rules.headway_gap
        + cfg.safety.rules.headway_time * jnp.maximum(vs, 0.0)
    )
    return jnp.maximum(a, floor)


def margin_ellipse_values(cfg: MMDOptConfig, s, d, centres, margins, vs=None, widen=None):
    """Collision function with per-point, per-step sample-driven margins (:mod:`mmdopt.risk`):
    ``f = 1 − Δs²/a_±² − Δd²/(b + m_lat)²`` with ``a_− = a + m_behind`` when the ego is behind
    the point (Δs < 0) and ``a_+ = a + m_ahead`` otherwise.  ``s, d`` (B, K); ``centres``
    (O, J, C, K, 2); ``margins`` (3, O, J, K); with ``cfg.safety.rules.asymmetric`` the
    following distance
    ``d₀ + h·ṡ`` of ``vs`` (B, K) is added to ``a_−``; ``widen`` (B, K) is added to the lateral
    semi-axis (:func:`yaw_widening`).  Returns (B, O, J, C, K)."""
    dt = centres.dtype
    mg = margins.astype(dt)[:, :, :, None, :]  # (3, O, J, 1, K)
    ds = s[:, None, None, None, :] - centres[None, ..., 0]
    dd = d[:, None, None, None, :] - centres[None, ..., 1]
    behind, ahead = mg[0][None], mg[1][None]
    if cfg.safety.rules.asymmetric:
        if vs is None:
            raise ValueError("config.safety.rules.asymmetric needs the ego samples' speeds vs")
        floor = (
            headway_semi_axis(cfg, cfg.safety.footprint.a, vs).astype(dt) - cfg.safety.footprint.a
        )  # (B, K)
        behind = jnp.maximum(behind, floor[:, None, None, None, :])
        ahead = cfg.safety.rules.margin_ahead_scale * ahead
    # reciprocals per (point, step) before broadcasting over the ego samples (one division
    # per step, not per value); with the headway floor (per ego sample) per value
    if cfg.safety.rules.asymmetric:
        a = cfg.safety.footprint.a + jnp.where(ds < 0, behind, ahead)
        ia = 1.0 / (a * a)
    else:
        ia_b, ia_a = (
            1.0 / ((cfg.safety.footprint.a + behind) ** 2),
            1.0 / ((cfg.safety.footprint.a + ahead) ** 2),
        )
        ia = jnp.where(ds < 0, ia_b, ia_a)
    b = cfg.safety.footprint.b + mg[2][None]
    if widen is not None:
        b = b + widen[:, None, None, None, :]
    lat = dd * dd * (1.0 / (b * b))
    if cfg.safety.rules.asymmetric:
        lat = lane_lateral(lat, ds, dd, cfg.safety.rules.headway_lane)
    f = 1.0 - ds * ds * ia - lat
    if cfg.safety.rules.asymmetric:
        f = rear_exempt(f, ds, dd, b, cfg.safety.rules.rear_exempt_width)
    return f
