"""MMD-Opt's margin ladder in the risk dial's final check: candidates planned with the coverage
margins of larger levels than ε compete with the plan at ε, and one is returned only when its
bound against every planning sample still meets ε."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import frenet
import mmdopt
from mmdopt.risk import samples_for_risk

TINY = mmdopt.MMDOptConfig().replace(
    n_samples=60, n_cem=20, n_elite=8, iterations=3, n_brake=4, reduced_set_size=10
)
EPS = 0.05


def _slow_car_ahead(n: int) -> np.ndarray:
    """(1, n, K, 2) futures of one car 25 m ahead in the ego's lane at 6 ± 1 m/s (the ego wants
    more): how closely a plan may follow it is what the margins decide."""
    t = frenet.TimeGrid(TINY.trajectory.horizon, TINY.trajectory.num_steps).t
    v = 6.0 + np.random.default_rng(1).normal(0.0, 1.0, n)
    s = 25.0 + v[:, None] * t
    return np.stack([s, 0.0 * s], -1)[None]


LADDER = (4.0, 16.0)


def _plan(obs, config=TINY, **kw):
    return mmdopt.plan_frenet(frenet.EgoState(vs=10.0), mmdopt.Road(), obs, config=config,
                              key=jax.random.PRNGKey(5), risk=EPS, method="mmd", **kw)  # fmt: skip


@pytest.mark.slow
def test_the_ladder_only_adds_candidates_and_keeps_the_promise():
    obs = _slow_car_ahead(samples_for_risk(EPS, 1))
    assert TINY.schedule.margin_ladder == ()  # off by default
    without = _plan(obs)
    with_ladder = _plan(obs, TINY.replace(margin_ladder=LADDER))  # a config field: no recompile
    b1, b0 = (p.diagnostics["final_check_bounds"] for p in (with_ladder, without))
    # the same passes at ε, then one candidate per rung of the ladder
    assert len(b1) >= len(b0) + len(LADDER) - without.diagnostics["tail_passes"]
    assert with_ladder.diagnostics["final_check_passes"].count("ladder") == len(LADDER)
    np.testing.assert_allclose(b1[:2], b0[:2])
    for p in (with_ladder, without):
        if p.status == "ok":  # an ok plan meets ε against all its planning samples
            assert p.risk_bound <= EPS, p.status_text
    assert without.status == "ok", without.status_text
    # among candidates that meet ε the least task cost wins: never worse than the plan at ε
    t1 = with_ladder.diagnostics["final_check_task"][with_ladder.diagnostics["final_check_choice"]]
    t0 = without.diagnostics["final_check_task"][without.diagnostics["final_check_choice"]]
    assert with_ladder.status == "ok" and t1 <= t0 + 1e-9


def test_other_methods_plan_without_the_ladder():
    """With the ladder switched on, a method whose record does not run it gets no rung passes.
    Random reduced sets stand for every other method: planned like MMD-Opt (a reduced set, its
    weights and margins), only their record's ``passes`` keeps the ladder from them."""
    assert not mmdopt.methods.get("random").runs("ladder")
    obs = _slow_car_ahead(samples_for_risk(EPS, 1))
    cfg = TINY.replace(margin_ladder=LADDER)
    p = mmdopt.plan_frenet(frenet.EgoState(vs=10.0), mmdopt.Road(), obs, config=cfg,
                           key=jax.random.PRNGKey(5), risk=EPS, method="random")  # fmt: skip
    n_passes = 1 + p.diagnostics["tail_passes"]
    assert len(p.diagnostics["final_check_bounds"]) == n_passes
