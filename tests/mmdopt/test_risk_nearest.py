"""MMD-Opt's nearest-futures pass in the risk dial's final check: a last pass against the
planning futures nearest to the plan, at the chance level the plan's bound allows, whose plan
competes with the earlier passes' and is returned only when its bound against every future still
meets ε."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import frenet
import mmdopt
from mmdopt.risk import hits_for_risk, risk_bound, samples_for_risk

TINY = mmdopt.MMDOptConfig().replace(
    n_samples=60, n_cem=20, n_elite=8, iterations=3, n_brake=4, reduced_set_size=10
)
EPS = 0.05


def _slow_car_ahead(n: int, gap: float = 25.0) -> np.ndarray:
    """(1, n, K, 2) futures of one car 25 m ahead in the ego's lane at 6 ± 1 m/s (the ego wants
    more): how closely a plan may follow it is what the margins and that pass decide."""
    t = frenet.TimeGrid(TINY.trajectory.horizon, TINY.trajectory.num_steps).t
    v = 6.0 + np.random.default_rng(1).normal(0.0, 1.0, n)
    s = gap + v[:, None] * t
    return np.stack([s, 0.0 * s], -1)[None]


def _plan(obs, config=TINY, method="mmd"):
    return mmdopt.plan_frenet(frenet.EgoState(vs=10.0), mmdopt.Road(), obs, config=config,
                              key=jax.random.PRNGKey(5), risk=EPS, method=method)  # fmt: skip


@pytest.fixture(scope="module")
def pair():
    obs = _slow_car_ahead(3 * samples_for_risk(EPS, 1))  # 177 futures
    cfg = TINY.replace(nearest_futures=40)
    return obs, _plan(obs, cfg), _plan(obs, cfg.replace(nearest_futures=0))


def test_the_nearest_pass_adds_candidates_and_the_least_costly_plan_within_eps_wins(pair):
    _, nearer, plain = pair
    b1, b0 = (p.diagnostics["final_check_bounds"] for p in (nearer, plain))
    assert "nearest_s" in nearer.diagnostics and "nearest_s" not in plain.diagnostics
    # the first pass, then the nearest-futures pass (and its repeats); without it the first
    # pass alone, with all of Algorithm 1's iterations (the two passes share them)
    passes = nearer.diagnostics["final_check_passes"]
    assert passes[0] == "first" and set(passes[1:]) == {"nearest"} and len(b1) >= 2
    assert plain.diagnostics["final_check_passes"] == ["first"] and len(b0) == 1
    N = TINY.cem.iterations
    first, near = nearer.diagnostics["pass_iterations"]
    assert first + near == N and near == max(1, round(TINY.schedule.nearest_share * N))
    for p in (nearer, plain):
        assert p.status == "ok", p.status_text
        assert p.risk_bound <= EPS
    # among the candidates meeting ε the least task cost wins
    task, choice = nearer.diagnostics["final_check_task"], nearer.diagnostics["final_check_choice"]
    assert b1[choice] <= EPS
    assert task[choice] == min(t for t, b in zip(task, b1, strict=True) if b <= EPS)


def test_the_nearest_pass_plans_against_the_futures_nearest_the_plan_at_the_allowed_level(pair):
    obs, nearer, _ = pair
    n = obs.shape[1]
    idx = nearer.diagnostics["nearest_futures"]
    assert idx.shape == (1, 40) and len(np.unique(idx)) == 40 and idx.max() < n
    k = hits_for_risk(EPS, n)
    assert k >= 1  # 177 futures leave room for a few hits at ε = 0.05
    assert nearer.diagnostics["nearest_level"] == pytest.approx((k + 0.5) / 40)
    # the chosen futures are the closest ones: none of the others is nearer the car's mean path
    s0 = obs[0, :, -1, 0]
    chosen = np.zeros(n, bool)
    chosen[idx[0]] = True
    # the ego follows behind the car, so the slowest futures come nearest
    assert s0[chosen].max() <= np.sort(s0)[60]


def test_other_methods_have_no_nearest_pass():
    obs = _slow_car_ahead(samples_for_risk(EPS, 1))
    p = _plan(obs, method="random")
    assert "nearest_s" not in p.diagnostics


def test_hits_for_risk_is_the_most_the_bound_allows():
    for eps, n, O in [(0.005, 598, 1), (0.005, 3000, 1), (0.02, 1000, 2), (0.1, 100, 1)]:
        k = hits_for_risk(eps, n, O)
        assert k >= 0
        assert risk_bound([k] * O, [n] * O) <= eps < risk_bound([k + 1] * O, [n] * O)
    assert hits_for_risk(0.005, 598) == 0 and hits_for_risk(0.005, 597) == -1
    for bad, match in [((0.005, 0), "n"), ((0.7, 10), "eps"), ((0.01, 10, 0), "obstacles")]:
        with pytest.raises(ValueError, match=match):
            hits_for_risk(*bad)


def test_nearest_futures_is_checked():
    with pytest.raises(ValueError, match="nearest_futures"):
        mmdopt.MMDOptConfig().replace(nearest_futures=-1)


def test_with_fewer_futures_than_the_pass_takes_it_plans_against_all_of_them():
    """Fewer futures than ``nearest_futures``: all of them, the program padded to its size (the
    copies masked out of the chance term), so one compiled program serves every n."""
    n = samples_for_risk(EPS, 1)
    p = _plan(_slow_car_ahead(n), TINY.replace(nearest_futures=100))
    idx = p.diagnostics["nearest_futures"]
    np.testing.assert_array_equal(idx, np.arange(n)[None])
    assert p.diagnostics["nearest_level"] == pytest.approx(0.5 / n)  # k = 0 at n(ε)
    assert p.status == "ok" and p.risk_bound <= EPS, p.status_text


def test_no_nearest_pass_below_the_floor_of_the_futures():
    """ε below what the futures can confirm (60 futures support 0.049 at best, ε = 0.01): no
    allowance for the pass to use, the margins alone keep the plan off the unseen tail."""
    obs = _slow_car_ahead(60)
    p = mmdopt.plan_frenet(frenet.EgoState(vs=10.0), mmdopt.Road(), obs, config=TINY,
                           key=jax.random.PRNGKey(5), risk=0.01, method="mmd")  # fmt: skip
    assert "nearest_s" not in p.diagnostics
    assert p.status == "risk floor", p.status_text


def test_the_pass_repeats_while_its_plan_breaks_the_bound_and_the_promise_holds(monkeypatch):
    """A nearest-futures pass that allows 20 hits more than the bound does (its count made too
    generous), behind a slow car 12 m ahead, gives plans that meet too many futures: the pass
    repeats around each such plan, one allowed hit fewer each time, at most
    ``schedule.nearest_repeats`` times, and the plan's status says whether its bound meets ε."""
    import mmdopt.risk
    import mmdopt.schedule

    NEAREST_REPEATS = mmdopt.MMDOptConfig().schedule.nearest_repeats
    true_hits = mmdopt.risk.hits_for_risk
    monkeypatch.setattr(mmdopt.schedule, "hits_for_risk", lambda *a, **k: true_hits(*a, **k) + 20)
    obs = _slow_car_ahead(3 * samples_for_risk(EPS, 1), gap=12.0)  # close: clearing costs
    p = _plan(obs, TINY.replace(nearest_futures=40))
    d = p.diagnostics
    k = true_hits(EPS, obs.shape[1]) + 20
    levels, bounds = d["nearest_levels"], d["final_check_bounds"]
    reps = len(levels) - 1
    assert levels == pytest.approx([(k - i + 0.5) / 40 for i in range(reps + 1)])
    nearest = bounds[2 : 3 + reps]  # after the first pass and the re-selection pass
    assert all(b > EPS for b in nearest[:-1])  # a repeat follows only a broken bound
    assert reps == NEAREST_REPEATS or nearest[-1] <= EPS
    assert reps >= 1
    # the status says whether the promise holds; with none kept, the least bound is returned
    assert (p.status == "ok") == (p.risk_bound <= EPS), p.status_text
    if not np.any(np.asarray(bounds) <= EPS):
        assert p.status == "risk exceeded" and p.risk_bound == pytest.approx(min(bounds))


def test_the_closed_loop_schedule_runs_one_nearest_pass_and_still_tells_the_truth(monkeypatch):
    """The schedule of the closed-loop preset (``MMDOptConfig.highway()``: ``nearest_repeats`` =
    ``tail_passes`` = 0): a plan that breaks its bound gets one nearest-futures pass and no pass
    after it (the next replan comes δ later), and its status still says whether ε holds."""
    import mmdopt.risk
    import mmdopt.schedule

    preset = mmdopt.MMDOptConfig.highway().schedule
    assert (preset.nearest_repeats, preset.tail_passes) == (0, 0)
    true_hits = mmdopt.risk.hits_for_risk
    monkeypatch.setattr(mmdopt.schedule, "hits_for_risk", lambda *a, **k: true_hits(*a, **k) + 20)
    obs = _slow_car_ahead(3 * samples_for_risk(EPS, 1), gap=12.0)
    p = _plan(obs, TINY.replace(nearest_futures=40, nearest_repeats=0, tail_passes=0))
    d = p.diagnostics
    assert len(d["nearest_levels"]) == 1 and d.get("tail_passes", 0) == 0
    assert d["final_check_passes"].count("nearest") == 1
    assert "tail" not in d["final_check_passes"]
    assert (p.status == "ok") == (p.risk_bound <= EPS), p.status_text


def test_an_allowance_above_the_futures_seen_keeps_a_chance_level_below_one():
    """ε = 0.05 over 177 futures allows 3 hits; a pass that sees 2 futures may meet both
    (level 1.5/2), not an invalid level of 3.5/2."""
    obs = _slow_car_ahead(3 * samples_for_risk(EPS, 1))
    p = _plan(obs, TINY.replace(nearest_futures=2))
    assert p.diagnostics["nearest_level"] == pytest.approx(1.5 / 2)
    assert p.status == "ok" and p.risk_bound <= EPS, p.status_text


def test_with_several_obstacles_the_pass_takes_the_deepest_samples_of_all_together():
    """The nearest pass pools the samples of every obstacle: a car far behind in the next lane
    gives none of its samples to the pass while the slow car ahead has samples in deeper
    conflict, and no sample is taken twice."""
    n = 3 * samples_for_risk(EPS, 1)
    ahead = _slow_car_ahead(n)
    t = frenet.TimeGrid(TINY.trajectory.horizon, TINY.trajectory.num_steps).t
    s = -150.0 + 5.0 * t + np.random.default_rng(2).normal(0.0, 0.5, (n, 1))
    behind = np.stack([s, np.full_like(s, 3.5)], -1)[None]
    p = _plan(np.concatenate([behind, ahead]), TINY.replace(nearest_futures=40))
    pairs = p.diagnostics["nearest_pairs"]
    assert pairs.shape == (40, 2)
    assert set(pairs[:, 0].tolist()) == {1}  # all from the car ahead
    assert len({tuple(r) for r in pairs.tolist()}) == 40
    assert (p.status == "ok") == (p.risk_bound <= EPS), p.status_text
