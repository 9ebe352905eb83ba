"""The registry of planning methods: a new method is one record, defined here and nowhere else,
and every part of the toolkit (``plan``, the risk mapping, the receding loop, ``bench
frontier`` and its CSV) takes it by name."""

from __future__ import annotations

import csv
import json

import jax
import numpy as np
import pytest

import frenet
import mmdopt
from mmdopt.methods import PlanMethod


def _toy_settings(eps: float) -> dict:
    # module-level, so that the record pickles into the benchmarks' worker processes
    return {"baseline_margin_scale": 0.5}


#: a method the package does not ship: the scenario cost on a uniformly random reduced set, with
#: its own default risk level and risk rule (a looser scenario margin scale)
TOY = PlanMethod(
    name="toy_scenario_uniform",
    label="scenario cost, random set (toy)",
    selector="uniform",
    collision="scenario",
    default_risk=0.02,
    risk_settings=_toy_settings,
    passes=("tail",),
    colour="tab:red",
)
TINY = {"cem": {"n_samples": 60, "n_cem": 30, "n_elite": 10, "iterations": 3, "n_brake": 2},
        "selection": {"reduced_set_size": 5}}  # fmt: skip


@pytest.fixture
def toy():
    mmdopt.methods.register(TOY)
    try:
        yield TOY
    finally:
        mmdopt.methods.unregister(TOY.name)


def _car_ahead(cfg, n=40):
    t = frenet.TimeGrid(cfg.trajectory.horizon, cfg.trajectory.num_steps).t
    v = 6.0 + np.random.default_rng(2).normal(0.0, 0.5, n)
    s = 30.0 + v[:, None] * t
    return np.stack([s, 0.0 * s], -1)[None]


def test_a_toy_method_runs_through_plan_with_its_own_record(toy):
    cfg = mmdopt.MMDOptConfig.from_dict(TINY)
    obs = _car_ahead(cfg)
    p = mmdopt.plan(frenet.EgoState(vs=10.0), mmdopt.Road(), obs, method=toy.name, config=cfg,
                    key=jax.random.PRNGKey(1), risk=0.05)  # fmt: skip
    assert p.method == toy.name and p.reduced_set.method == "uniform"
    assert p.reduced_set.indices.shape == (1, 5)
    # its risk rule reached the config the plan was made with, and its default is its own
    assert p.config.safety.risk == 0.05 and p.config.baselines.baseline_margin_scale == 0.5
    assert mmdopt.config_for_risk(toy.name).safety.risk == 0.02
    assert p.status in ("ok", "risk floor", "risk exceeded"), p.status_text
    assert np.isfinite(p.risk_bound)
    assert "toy_scenario_uniform" in mmdopt.methods.names()
    again = mmdopt.plan(frenet.EgoState(vs=10.0), mmdopt.Road(), obs, method=toy.name,
                        config=cfg, key=jax.random.PRNGKey(1), risk=0.05)  # fmt: skip
    np.testing.assert_array_equal(p.x, again.x)  # the same seed, the same plan


@pytest.mark.slow
def test_a_toy_method_runs_through_bench_frontier_and_its_csv(toy, tmp_path):
    from mmdopt.bench import cli

    tiny = tmp_path / "cfg.json"
    tiny.write_text(json.dumps(TINY))
    out = tmp_path / "f"
    argv = ["bench", "frontier", "--scenes", "1", "--seed", "3", "--out", str(out),
            "--methods", toy.name, "--risks", "0.05", "--jobs", "1", "--config", str(tiny),
            "--n-samples", "40", "--n-validation", "100", "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    with open(out / "frontier.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows and {r["method"] for r in rows} == {toy.name}
    assert {float(r["risk"]) for r in rows} == {0.05}


def test_an_unknown_or_malformed_method_is_refused_by_name():
    with pytest.raises(ValueError, match="method must be one of"):
        mmdopt.methods.get("nope")
    with pytest.raises(ValueError, match="selector"):
        PlanMethod(name="x", label="x", selector="nope", collision="scenario")
    with pytest.raises(ValueError, match="collision"):
        PlanMethod(name="x", label="x", selector=None, collision="mmd-ish")
    with pytest.raises(ValueError, match="need a selector"):
        PlanMethod(name="x", label="x", selector=None, collision="scenario", passes=("tail",))
    with pytest.raises(ValueError, match="already registered"):
        mmdopt.methods.register(mmdopt.methods.get("mmd"))
    with pytest.raises(ValueError, match="built-in"):
        mmdopt.methods.unregister("mmd")


def test_the_built_ins_are_records_that_say_what_differs():
    get = mmdopt.methods.get
    assert mmdopt.methods.names()[: len(mmdopt.PLAN_METHODS)] == mmdopt.PLAN_METHODS
    assert get("mmd").selector == "kernel-cem" and get("mmd").collision == "embedding"
    assert get("saa").all_samples and get("saa").collision == "chance"
    assert get("degroot").ego_guess and not get("degroot").lateral_features
    assert get("mmd").runs("nearest") and not get("random").runs("nearest")
