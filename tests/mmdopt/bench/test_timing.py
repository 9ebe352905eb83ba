"""The timing measurement shared by ``mmdopt bench timing`` and ``benchmarks/planner_timing.py``."""

from __future__ import annotations

import pytest

import mmdopt
from mmdopt.bench.scenes import demo_scene
from mmdopt.bench.timing import time_plan, time_reduced_set


def test_time_plan_reports_first_and_median_times_with_algorithm1_inside_plan():
    cfg = mmdopt.MMDOptConfig().replace(
        n_samples=200, n_cem=40, n_elite=15, iterations=3, n_brake=5
    )
    t = time_plan(demo_scene(), cfg, repeats=2)
    assert 0 < t["algorithm1_s"] <= t["plan_s"] and 0 < t["algorithm1_first_s"] <= t["plan_first_s"]
    assert t["plan_first_cpu_s"] > 0 and t["plan_cpu_s"] > 0
    assert t["plan"].x.ndim == 1


def test_time_reduced_set_times_the_selection_and_checks_its_arguments():
    samples = demo_scene().obstacles[0]
    first, median = time_reduced_set(samples, 5, repeats=2)
    assert first > 0 and median > 0
    for kw, name in ((dict(m=0), "m"), (dict(m=5, repeats=0), "repeats")):
        with pytest.raises(ValueError, match=name):
            time_reduced_set(samples, **kw)
    with pytest.raises(ValueError, match="samples"):
        time_reduced_set(samples[0], 5)
    with pytest.raises(ValueError, match="repeats"):
        time_plan(demo_scene(), repeats=0)
