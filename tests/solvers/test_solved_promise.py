"""What ``SOLVED`` promises, in :meth:`solvers.Solution.is_optimal`'s terms.

A backend's ``eps_abs`` / ``eps_rel`` are its own termination test, ``residual ≤ eps_abs +
eps_rel·scale``; ``is_optimal(eps_abs)`` alone is the absolute test (qpsolvers' habit), which a
``SOLVED`` at ``eps_rel > 0`` need not meet.  Pinned here on 200 seeded random feasible QPs:

* every backend: every ``SOLVED`` at ``eps_abs = eps_rel = 1e-6`` passes ``is_optimal(1e-5)``.
  The data are of unit scale (rows of unit ∞-norm, ``q`` in ``[−1, 1]``, ``x*`` near the unit
  box), so the relative part ``eps_rel·scale`` is below ``9·eps_abs`` there: the relation follows
  from the backend's own test, it is not a guarantee on data of any scale;
* ``osqp`` (also through qpsolvers), ``admm`` and ``ipm``, whose test *is* ``is_optimal``'s: every
  ``SOLVED`` passes ``is_optimal(eps_abs, eps_rel)``, and with ``eps_rel = 0`` ``is_optimal
  (eps_abs)`` itself.

The QPs come in 20 groups of 10 sharing ``P`` and ``A`` (one batch each: the JAX backends compile
once), with two-sided, one-sided and equality rows, ``n = 4``, ``m = 6``.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from solvers import QP, BatchSolution, QPBatch, Solution, Status, available_backends, solve_batch

EPS = 1e-6
#: backends whose termination test is OSQP's, the one is_optimal(eps_abs, eps_rel) computes
OSQP_TEST = ("osqp", "qpsolvers:osqp", "admm", "ipm")
BACKENDS = available_backends()


@cache
def random_batches(seed: int = 0, groups: int = 20, per: int = 10) -> tuple[QPBatch, ...]:
    """200 feasible, bounded QPs of unit scale (``P ≻ 0``; bounds around a point ``x0``)."""
    rng = np.random.default_rng(seed)
    n, m = 4, 6
    out = []
    for _ in range(groups):
        M = rng.normal(size=(n, n - 1)) / np.sqrt(n)
        P = M @ M.T + 0.1 * np.eye(n)
        A = rng.normal(size=(m, n))
        A /= np.abs(A).max(axis=1, keepdims=True)
        x0 = rng.uniform(-0.5, 0.5, (per, n))
        Ax0 = x0 @ A.T
        lo = Ax0 - rng.uniform(0.0, 0.5, (per, m))
        hi = Ax0 + rng.uniform(0.0, 0.5, (per, m))
        lo[:, 0] = -np.inf  # upper-only row
        hi[:, 1] = np.inf  # lower-only row
        lo[:, 2] = hi[:, 2] = Ax0[:, 2]  # an equality
        out.append(QPBatch(P, A, rng.uniform(-1.0, 1.0, (per, n)), lo, hi))
    return tuple(out)


def _solve_all(name: str, eps_rel: float):
    sols = [solve_batch(b, name, eps_abs=EPS, eps_rel=eps_rel) for b in random_batches()]
    return sols, np.concatenate([s.status == int(Status.SOLVED) for s in sols])


def _failures(sols, solved, eps_abs: float, eps_rel: float = 0.0) -> list[int]:
    ok = np.concatenate([s.is_optimal(eps_abs, eps_rel) for s in sols])
    return np.flatnonzero(solved & ~ok).tolist()


@pytest.mark.parametrize("name", BACKENDS)
def test_solved_at_1e_6_passes_is_optimal_at_1e_5(name):
    sols, solved = _solve_all(name, EPS)
    assert solved.sum() >= 180, f"{name}: only {solved.sum()} of 200 SOLVED"
    bad = _failures(sols, solved, 10 * EPS)
    assert not bad, f"{name}: SOLVED but not is_optimal({10 * EPS:g}) at items {bad}"
    if name in OSQP_TEST:
        bad = _failures(sols, solved, EPS, EPS)
        assert not bad, f"{name}: SOLVED but not is_optimal({EPS:g}, {EPS:g}) at items {bad}"


@pytest.mark.parametrize("name", [b for b in OSQP_TEST if b in BACKENDS])
def test_solved_at_eps_rel_0_passes_is_optimal_eps_abs(name):
    sols, solved = _solve_all(name, 0.0)
    assert solved.sum() >= 180, f"{name}: only {solved.sum()} of 200 SOLVED"
    bad = _failures(sols, solved, EPS)
    assert not bad, f"{name}: SOLVED at eps_rel=0 but not is_optimal({EPS:g}) at items {bad}"


# ------------------------------------------------------------------------ is_optimal itself
def _point(gap: float) -> tuple[QP, Solution]:
    """``min ½x² − x`` on ``x ≤ 2``: the optimum ``x = 1``; ``y`` chosen for a duality gap of
    ``gap`` (dual residual ``gap/2``) with terms of size 1 and 2."""
    qp = QP(np.eye(1), [-1.0], np.eye(1), [-np.inf], [2.0])
    y = gap / 2.0  # S(y) = 2y, Px + q + y = y
    return qp, Solution(
        x=np.array([1.0]),
        y=np.array([y]),
        status=Status.SOLVED,
        objective=-0.5,
        iterations=0,
        solve_time=0.0,
        primal_residual=0.0,
        dual_residual=y,
        backend="made-up",
        problem=qp,
    )


def test_is_optimal_eps_rel_is_osqps_relative_part():
    qp, sol = _point(1.5e-6)  # gap 1.5e-6 = |xᵀPx + qᵀx + S(y)| = |1 − 1 + 1.5e-6|
    assert sol.duality_gap() == pytest.approx(1.5e-6)
    assert not sol.is_optimal(1e-6)  # the absolute test (eps_rel = 0, the default)
    assert sol.is_optimal(1e-6, 1e-6)  # 1.5e-6 ≤ 1e-6 + 1e-6·max(|xᵀPx|, |qᵀx|, |S(y)|) = 2e-6
    assert not sol.is_optimal(1e-7, 1e-7)
    assert sol.is_optimal(1e-6, 1e-6, qp=qp)
    batch = QPBatch(qp.P, qp.A, qp.q[None], qp.l[None], qp.u[None])
    bs = BatchSolution.stack([sol], "made-up", 0.0)
    assert bs.is_optimal(1e-6, batch=batch).tolist() == [False]
    assert bs.is_optimal(1e-6, 1e-6, batch=batch).tolist() == [True]


def test_is_optimal_refuses_a_problem_where_eps_rel_goes():
    qp, sol = _point(0.0)
    with pytest.raises(ValueError, match=r"eps_rel must be a number ≥ 0, got QP \(pass the "):
        sol.is_optimal(1e-6, qp)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="eps_rel must be a number"):
        sol.is_optimal(1e-6, -1.0)


def test_proxqp_common_tolerances_switch_its_gap_test_on():
    """ProxQP tests no duality gap by default; the common eps_abs / eps_rel set it (the
    native name given explicitly wins)."""
    if "qpsolvers:proxqp" not in BACKENDS:
        pytest.skip("qpsolvers:proxqp is not installed")
    from solvers import get_backend

    be = get_backend("qpsolvers:proxqp")
    native, _ = be.native_settings({"eps_abs": 1e-6, "eps_rel": 1e-7})
    assert native["check_duality_gap"] is True
    assert native["eps_duality_gap_abs"] == 1e-6 and native["eps_duality_gap_rel"] == 1e-7
    native, _ = be.native_settings({"eps_abs": 1e-6, "check_duality_gap": False})
    assert native["check_duality_gap"] is False
    assert be.native_settings({})[0] == {}  # ProxQP's own defaults untouched
