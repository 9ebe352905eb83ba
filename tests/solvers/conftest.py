"""Backend parametrisation (style: osqp-python's ``pytest_generate_tests``).

Any test that takes a ``backend`` argument runs once per backend that imports on this machine
(``solvers.available_backends()``): a backend whose package or module is missing (for instance
``admm`` before its module lands) is simply not parametrised.  ``tol`` is that backend's row of
:mod:`tests.solvers.tolerances`.  ``mm_problem`` runs over the Maros–Meszaros problems in the
shared data, when present.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from solvers import QP, Solution, available_backends, solve
from tests.conftest import SHARED_DATA

from .tolerances import REFERENCE_FALLBACK, REFERENCE_SETTINGS, BackendTol, tol_for

MM_DIR = SHARED_DATA / "maros_meszaros"
#: backends whose every case is marked slow (run them alone with `-m slow`)
SLOW = frozenset({"admm"})


def _mm_names() -> list[str]:
    try:
        return sorted(json.loads((MM_DIR / "optimal_objectives.json").read_text()))
    except (OSError, ValueError):
        return ["<maros_meszaros data absent>"]


#: backends left out of the generic per-backend suites: ``ipm`` compiles one JAX program per
#: problem shape (10–30 s each on a 2-core CPU), so its properties (agreement with Clarabel,
#: equality and free rows, infeasibility, Maros–Meszaros, batches) are tested on a few shapes in
#: test_ipm.py
GENERIC_EXCLUDED = frozenset({"ipm"})


def _backends() -> list[str]:
    return [b for b in available_backends() if b not in GENERIC_EXCLUDED]


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "backend" in metafunc.fixturenames:
        # admm compiles with JAX per problem shape: seconds per case, so its cases are `slow`
        metafunc.parametrize(
            "backend",
            [pytest.param(b, marks=pytest.mark.slow) if b in SLOW else b for b in _backends()],
        )
    if "mm_problem" in metafunc.fixturenames:
        metafunc.parametrize("mm_problem", _mm_names())


@pytest.fixture
def tol(backend: str) -> BackendTol:
    return tol_for(backend)


def reference(qp: QP) -> Solution:
    """Clarabel at tight tolerances: the reference every backend is compared with."""
    ref = solve(qp, "clarabel", **REFERENCE_SETTINGS)
    if not ref.ok:
        ref = solve(qp, "clarabel", **REFERENCE_FALLBACK)
    assert ref.ok, f"reference failed: {ref.status}"
    return ref


def assert_agrees(sol: Solution, ref: Solution, qp: QP, tol: BackendTol, what: str = "") -> None:
    """``sol`` is SOLVED and agrees with ``ref`` in x, objective and feasibility per ``tol``."""
    assert sol.status.name == "SOLVED", f"{what}: status {sol.status.name} {sol.extras}"
    xs = max(1.0, float(np.max(np.abs(ref.x))))
    dx = float(np.max(np.abs(sol.x - ref.x)))
    assert dx <= tol.x_atol * xs, f"{what}: ‖x − x_ref‖∞ = {dx:.3g} > {tol.x_atol:g}·{xs:.3g}"
    df = abs(sol.objective - ref.objective)
    fs = max(1.0, abs(ref.objective))
    assert df <= tol.obj_rtol * fs, f"{what}: |f − f_ref| = {df:.3g} > {tol.obj_rtol:g}·{fs:.3g}"
    viol = qp.constraint_violation(sol.x)
    assert viol <= tol.feas_atol * xs, f"{what}: violation {viol:.3g}"
    assert sol.x.shape == (qp.n,) and sol.y.shape == (qp.m,)
