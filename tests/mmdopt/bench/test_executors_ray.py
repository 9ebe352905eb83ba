"""The Ray executor: refused by name when unknown.  Its rows equal the local executor's on a
``ray start`` cluster (``test_executors_ray_cluster.py``: one cluster start-up for the sweep and
the frontier)."""

from __future__ import annotations

import pytest

from mmdopt.bench.executors import run_tasks


def _square(x):
    return x * x


def test_an_unknown_executor_is_refused_by_name():
    with pytest.raises(ValueError, match="executor"):
        run_tasks(_square, [1], executor="dask")
