"""A table-driven bad-input corpus for :mod:`solvers`: every public entry point
(``QP``, ``QPBatch``, ``QP.from_qpsolvers``, ``solve``, ``solve_batch``, ``solve_qp``) on every
available backend.  Each case states its exact outcome: the error type and the argument the
message names, or the set of statuses allowed.  Over the corpus no answer is a wrong ``SOLVED``.

Problems are tiny (n ≤ 3), so the corpus runs in seconds; ``admm`` compiles once per shape.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
import scipy.sparse as sp

from solvers import (
    QP,
    BatchSolution,
    InvalidSettingError,
    NonConvexError,
    QPBatch,
    Solution,
    Status,
    UnknownBackendError,
    available_backends,
    get_backend,
    solve,
    solve_batch,
    solve_qp,
)

BACKENDS = available_backends()
I2 = np.eye(2)


@dataclass(frozen=True)
class Case:
    """``call()`` must raise ``error`` with a message matching ``names``, or return a solution
    whose status is in ``statuses``."""

    id: str
    call: Callable[[], Any]
    error: type[BaseException] | None = None
    names: str = ""
    statuses: frozenset[Status] = frozenset()
    #: further property of the returned object (a QP, Solution or BatchSolution)
    check: Callable[[Any], None] | None = None


def raises(id_: str, call: Callable[[], Any], error: type[BaseException], names: str) -> Case:
    return Case(id_, call, error=error, names=names)


def _qp(**kw: Any) -> QP:
    """A small valid QP (optimum x = (−0.5, 1)) with any argument replaced."""
    args = dict(P=I2, q=np.array([1.0, -1.0]), A=I2, l=np.array([-0.5, -0.5]), u=np.ones(2))
    args.update(kw)
    return QP(**args)


def _batch(**kw: Any) -> QPBatch:
    args = dict(
        P=I2,
        A=I2,
        q=np.array([[1.0, -1.0], [-1.0, 1.0]]),
        l=np.full((2, 2), -0.5),
        u=np.ones((2, 2)),
    )
    args.update(kw)
    return QPBatch(**args)


INDEFINITE = np.diag([1.0, -1.0])  # a saddle: x = 0 is stationary, x = (0, ±1) better

# ---------------------------------------------------------------- problem construction (QP)
QP_CASES = [
    raises("q-strings", lambda: _qp(q=["a", "b"]), ValueError, r"^q must be numeric"),
    raises("q-complex", lambda: _qp(q=np.array([1 + 1j, 0])), ValueError, r"^q is complex"),
    raises("P-complex", lambda: _qp(P=I2 * (1 + 0j)), ValueError, r"^P is complex"),
    raises("P-complex-sparse", lambda: _qp(P=sp.csc_matrix(I2 * 1j)), ValueError, r"^P is complex"),
    raises("A-complex", lambda: _qp(A=I2 + 1j), ValueError, r"^A is complex"),
    raises("l-complex", lambda: _qp(l=np.array([-1j, 0])), ValueError, r"^l is complex"),
    raises("u-complex", lambda: _qp(u=np.array([1j, 1])), ValueError, r"^u is complex"),
    raises("P-strings", lambda: _qp(P=[["a", "b"], ["c", "d"]]), ValueError, r"^P must be numeric"),
    raises("A-strings", lambda: _qp(A=[["a", "b"], ["c", "d"]]), ValueError, r"^A must be numeric"),
    raises("l-strings", lambda: _qp(l=["x", "y"]), ValueError, r"^l must be numeric"),
    raises("u-object", lambda: _qp(u=[object(), 1.0]), ValueError, r"^u must be numeric"),
    raises("q-nan", lambda: _qp(q=np.array([np.nan, 0.0])), ValueError, r"^q contains NaN"),
    raises("q-inf", lambda: _qp(q=np.array([np.inf, 0.0])), ValueError, r"^q contains inf"),
    raises("P-nan", lambda: _qp(P=np.diag([np.nan, 1.0])), ValueError, r"^P contains NaN"),
    raises("P-inf", lambda: _qp(P=np.diag([np.inf, 1.0])), ValueError, r"^P contains NaN or inf"),
    raises("A-nan", lambda: _qp(A=np.diag([np.nan, 1.0])), ValueError, r"^A contains NaN"),
    raises("A-inf-sparse", lambda: _qp(A=sp.diags([np.inf, 1.0])), ValueError, r"^A contains"),
    raises("l-nan", lambda: _qp(l=np.array([np.nan, 0.0])), ValueError, r"^l contains NaN"),
    raises("u-nan", lambda: _qp(u=np.array([1.0, np.nan])), ValueError, r"^u contains NaN"),
    raises("P-shape", lambda: _qp(P=np.ones((2, 3))), ValueError, r"^P has shape \(2, 3\), expec"),
    # n comes from P: a q that disagrees with P is the q's fault, not P's
    raises(
        "q-length", lambda: _qp(q=np.ones(3)), ValueError, r"^q has shape \(3,\), expected \(2,\)"
    ),
    raises(
        "P-3x3-q-2", lambda: _qp(P=np.eye(3)), ValueError, r"^q has shape \(2,\), expected \(3,"
    ),
    raises("P-scalar", lambda: _qp(P=1.0), ValueError, r"^P has shape \(\)"),
    raises("A-shape", lambda: _qp(A=np.ones((2, 3))), ValueError, r"^A has shape \(2, 3\)"),
    raises("A-3d", lambda: _qp(A=np.ones((2, 2, 1))), ValueError, r"^A must be 2-D"),
    raises("l-length", lambda: _qp(l=np.zeros(3)), ValueError, r"^l has shape \(3,\)"),
    raises("u-length", lambda: _qp(u=np.ones(1)), ValueError, r"^u has shape \(1,\)"),
    raises("q-2d", lambda: _qp(q=np.ones((2, 1))), ValueError, r"^q must be 1-D"),
    raises("q-empty", lambda: _qp(q=np.zeros(0)), ValueError, r"^q is empty"),
    raises("P-none", lambda: _qp(P=None), ValueError, r"^P is required"),
    raises("q-none", lambda: _qp(q=None), ValueError, r"^q is required"),
    raises("A-none", lambda: _qp(A=None), ValueError, r"^A is required"),
    raises("l-none", lambda: _qp(l=None), ValueError, r"^l is required"),
    raises("u-none", lambda: _qp(u=None), ValueError, r"^u is required"),
    raises(
        "P-asymmetric", lambda: _qp(P=np.array([[1.0, 1.0], [0, 1]])), ValueError, "^P must be sym"
    ),
    raises(
        "l>u",
        lambda: _qp(l=np.array([2.0, 0.0])),
        ValueError,
        r"^infeasible bounds: l > u at index 0 \(",
    ),
    raises(
        "eq-at-+inf",
        lambda: _qp(l=np.array([np.inf, 0.0]), u=np.array([np.inf, 1.0])),
        ValueError,
        r"^l is \+inf .*equality at infinity",
    ),
    raises(
        "eq-at--inf",
        lambda: _qp(l=np.array([-np.inf, 0.0]), u=np.array([-np.inf, 1.0])),
        ValueError,
        r"^u is -inf .*equality at infinity",
    ),
    raises(
        "l-+inf-alone",
        lambda: _qp(l=np.array([np.inf, 0.0]), u=np.array([np.inf, 1.0])),
        ValueError,
        r"^l is \+inf",
    ),
    raises(
        "u--inf-alone",
        lambda: _qp(u=np.array([-np.inf, 1.0]), l=np.array([-np.inf, 0.0])),
        ValueError,
        r"^u is -inf",
    ),
    raises("P-indefinite", lambda: _qp(P=INDEFINITE), NonConvexError, r"^P is not positive semi"),
    raises("P-negdef", lambda: _qp(P=-I2), NonConvexError, r"^P is not positive semidefinite"),
    raises(
        "P-indefinite-sparse", lambda: _qp(P=sp.csc_matrix(INDEFINITE)), NonConvexError, r"^P is"
    ),
    raises(
        "P-slightly-indefinite",
        lambda: _qp(P=np.array([[1.0, 1.001], [1.001, 1.0]])),
        NonConvexError,
        r"smallest eigenvalue -0.001",
    ),
    raises("check_convex-str", lambda: _qp(check_convex="yes"), ValueError, r"^check_convex"),
]


def _equality_stays_finite(qp: QP) -> None:
    assert qp.l[0] == qp.u[0] == 1e25  # never read as an infinite bound


def _one_sided_rule(qp: QP) -> None:
    assert qp.l[0] == -np.inf and qp.u[0] == 1.0 and qp.l[1] == 1e21 and qp.u[1] == np.inf


QP_CASES += [
    Case(
        "eq-1e25-stays-finite",
        lambda: _qp(l=np.array([1e25, 0.0]), u=np.array([1e25, 1.0])),
        check=_equality_stays_finite,
    ),
    Case(
        "1e20-rule-one-sided",
        lambda: _qp(l=np.array([-1e20, 1e21]), u=np.array([1.0, 1e22])),
        check=_one_sided_rule,
    ),
]

# ---------------------------------------------------------------------- QPBatch
BATCH_CASES = [
    raises(
        "n=0",
        lambda: _batch(q=np.zeros((2, 0)), A=np.zeros((2, 0)), P=np.zeros((0, 0))),
        ValueError,
        r"^q has shape \(B, 0\)",
    ),
    raises("q-1d", lambda: _batch(q=np.ones(2)), ValueError, r"^q must have shape \(B, n\)"),
    raises("B=0", lambda: _batch(q=np.zeros((0, 2))), ValueError, r"^q has an empty batch axis"),
    raises("q-strings", lambda: _batch(q=[["a", "b"]]), ValueError, r"^q must be numeric"),
    raises("q-complex", lambda: _batch(q=np.ones((2, 2)) * 1j), ValueError, r"^q is complex"),
    raises("P-complex", lambda: _batch(P=I2 + 0j), ValueError, r"^P is complex"),
    raises("A-complex", lambda: _batch(A=I2 * 1j), ValueError, r"^A is complex"),
    raises("l-complex", lambda: _batch(l=np.zeros((2, 2)) * 1j), ValueError, r"^l is complex"),
    raises("q-nan", lambda: _batch(q=np.full((2, 2), np.nan)), ValueError, r"^q contains NaN"),
    raises("l-batch", lambda: _batch(l=np.zeros((3, 2))), ValueError, r"^l has shape \(3, 2\)"),
    raises("u-batch", lambda: _batch(u=np.ones(2)), ValueError, r"^u has shape \(2,\)"),
    raises("l-nan", lambda: _batch(l=np.full((2, 2), np.nan)), ValueError, r"^l contains NaN"),
    raises("u-nan", lambda: _batch(u=np.full((2, 2), np.nan)), ValueError, r"^u contains NaN"),
    raises("l>u", lambda: _batch(l=np.full((2, 2), 2.0)), ValueError, r"^infeasible bounds"),
    raises(
        "eq-at-inf",
        lambda: _batch(l=np.full((2, 2), np.inf), u=np.full((2, 2), np.inf)),
        ValueError,
        r"^l is \+inf",
    ),
    raises("P-indefinite", lambda: _batch(P=INDEFINITE), NonConvexError, r"^P is not positive"),
    raises("P-asymmetric", lambda: _batch(P=np.triu(np.ones((2, 2)))), ValueError, r"^P must be"),
    raises("P-shape", lambda: _batch(P=np.ones((2, 3))), ValueError, r"^P has shape \(2, 3\)"),
    raises(
        "q-length",
        lambda: _batch(P=np.eye(3)),
        ValueError,
        r"^q has shape \(2, 2\), expected \(2, 3",
    ),
    raises("A-shape", lambda: _batch(A=np.eye(3)), ValueError, r"^A has shape"),
    raises("A-none", lambda: _batch(A=None), ValueError, r"^A is required"),
]

# ------------------------------------------------------------ QP.from_qpsolvers / solve_qp
FROM_QPSOLVERS = [
    ("G-without-h", dict(G=[[1.0, 1.0]]), ValueError, r"^h is required when G is given"),
    ("h-without-G", dict(h=[1.0]), ValueError, r"^G is required when h is given"),
    ("A-without-b", dict(A=[[1.0, 1.0]]), ValueError, r"^b is required when A is given"),
    ("b-without-A", dict(b=[1.0]), ValueError, r"^A is required when b is given"),
    ("G-cols", dict(G=[[1.0, 1.0, 1.0]], h=[1.0]), ValueError, r"^G has shape \(1, 3\)"),
    ("h-length", dict(G=[[1.0, 1.0]], h=[1.0, 2.0]), ValueError, r"^h has shape \(2,\)"),
    ("b-length", dict(A=[[1.0, 1.0]], b=[1.0, 2.0]), ValueError, r"^b has shape \(2,\)"),
    ("b-inf", dict(A=[[1.0, 1.0]], b=[np.inf]), ValueError, r"^b contains inf"),
    ("b-nan", dict(A=[[1.0, 1.0]], b=[np.nan]), ValueError, r"^b contains NaN"),
    ("h-nan", dict(G=[[1.0, 1.0]], h=[np.nan]), ValueError, r"^h contains NaN"),
    ("G-complex", dict(G=[[1j, 1.0]], h=[1.0]), ValueError, r"^G is complex"),
    ("lb-length", dict(lb=[0.0]), ValueError, r"^lb has shape \(1,\)"),
    ("ub-strings", dict(ub=["a", "b"]), ValueError, r"^ub must be numeric"),
    ("lb>ub", dict(lb=[1.0, 1.0], ub=[0.0, 0.0]), ValueError, r"^lb > ub at indices \[0, 1\]$"),
    (
        "lb>ub-one",
        dict(lb=[1.0, 0.0], ub=[0.0, 1.0]),
        ValueError,
        r"^lb > ub at index 0 \(lb = 1, ub",
    ),
    (
        "q-length",
        dict(q=[1.0, 1.0, 1.0]),
        ValueError,
        r"^q has shape \(3,\), expected \(2,\): n = 2 i",
    ),
    ("q-strings", dict(q=["a", "b"]), ValueError, r"^q must be numeric"),
    ("P-indefinite", dict(P=INDEFINITE), NonConvexError, r"^P is not positive semidefinite"),
]


def _from_qpsolvers_case(kw: dict, via_solve_qp: bool) -> Callable[[], Any]:
    args = dict(P=I2, q=np.array([1.0, -1.0])) | kw
    if via_solve_qp:
        return lambda: solve_qp(**args, backend="clarabel")
    return lambda: QP.from_qpsolvers(**args)


FQ_CASES = [
    raises(f"{via}-{name}", _from_qpsolvers_case(kw, via == "solve_qp"), err, names)
    for name, kw, err, names in FROM_QPSOLVERS
    for via in ("from_qpsolvers", "solve_qp")
]

# ------------------------------------------------------------------ solve / solve_batch
_NONCONVEX_UNCHECKED = lambda: _qp(P=INDEFINITE, check_convex=False)  # noqa: E731
ENTRY_CASES = [
    raises("solve-not-a-qp", lambda: solve("qp", "clarabel"), TypeError, r"qp must be a solvers"),
    raises("solve-backend-int", lambda: solve(_qp(), 3), TypeError, r"backend must be a string"),
    raises("solve-unknown", lambda: solve(_qp(), "nope"), UnknownBackendError, r"'nope'.*clarab"),
    raises(
        "solve-check_convex-str",
        lambda: solve(_qp(), "clarabel", check_convex="x"),
        ValueError,
        r"^check_convex must be",
    ),
    raises(
        "solve-forces-convexity-check",
        lambda: solve(_NONCONVEX_UNCHECKED(), "clarabel", check_convex=True),
        NonConvexError,
        r"^P is not positive semidefinite",
    ),
    raises(
        "ws-x-shape",
        lambda: solve(_qp(), "clarabel", warm_start=(np.zeros(3), None)),
        ValueError,
        r"^warm_start x has shape \(3,\)",
    ),
    raises(
        "ws-y-shape",
        lambda: solve(_qp(), "clarabel", warm_start=(np.zeros(2), np.zeros(5))),
        ValueError,
        r"^warm_start y has shape \(5,\)",
    ),
    raises(
        "ws-3-tuple",
        lambda: solve(_qp(), "clarabel", warm_start=(1, 2, 3)),
        ValueError,
        r"^warm_start as a tuple",
    ),
    raises(
        "ws-string", lambda: solve(_qp(), "clarabel", warm_start="x"), ValueError, r"^warm_start"
    ),
    raises(
        "ws-complex",
        lambda: solve(_qp(), "clarabel", warm_start=(np.ones(2) * 1j, None)),
        ValueError,
        r"^warm_start",
    ),
    raises(
        "ws-setting-in-kwargs-of-native",
        lambda: get_backend("clarabel").native_settings({"warm_start": 1}),
        InvalidSettingError,
        r"^warm_start is a keyword",
    ),
    raises("batch-not-a-batch", lambda: solve_batch(_qp(), "clarabel"), TypeError, r"QPBatch"),
    raises(
        "batch-ws-size",
        lambda: solve_batch(_batch(), "clarabel", warm_start=(np.zeros((3, 2)), None)),
        ValueError,
        r"^warm_start x has shape \(3, 2\)",
    ),
    raises(
        "batch-ws-single-solution",
        lambda: solve_batch(_batch(), "clarabel", warm_start=solve(_qp(), "clarabel")),
        ValueError,
        r"^warm_start must be a BatchSolution",
    ),
    raises(
        "batch-forces-convexity-check",
        lambda: solve_batch(
            _batch(P=INDEFINITE, check_convex=False), "clarabel", check_convex=True
        ),
        NonConvexError,
        r"^P is not positive",
    ),
]
if any(b.startswith("qpsolvers:") for b in BACKENDS):
    ENTRY_CASES.append(
        raises(
            "qpsolvers-unknown-solver",
            lambda: solve(_qp(), "qpsolvers:nope"),
            UnknownBackendError,
            r"no installed solver 'nope'",
        )
    )

# --------------------------------------------------------- per backend: settings and statuses
BAD_SETTINGS = [
    ("unknown", {"eps_typo": 1.0}, r"^unknown setting 'eps_typo' for backend .*valid names: "),
    ("eps_abs-negative", {"eps_abs": -1.0}, r"^eps_abs must be"),
    ("eps_rel-nan", {"eps_rel": float("nan")}, r"^eps_rel must be"),
    ("eps_abs-string", {"eps_abs": "1e-5"}, r"^eps_abs must be"),
    ("max_iter-zero", {"max_iter": 0}, r"^max_iter must be a positive integer"),
    ("max_iter-float", {"max_iter": 2.5}, r"^max_iter must be a positive integer"),
    ("time_limit-negative", {"time_limit": -1.0}, r"^time_limit must be"),
    ("verbose-string", {"verbose": "yes"}, r"^verbose must be True or False"),
]

_NOT_SOLVED = frozenset(Status) - {Status.SOLVED, Status.SOLVED_INACCURATE}


def _primal_infeasible() -> QP:  # x0 ≥ 1 and x0 ≤ 0
    A = np.array([[1.0, 0.0], [1.0, 0.0]])
    return QP(I2, np.zeros(2), A, np.array([1.0, -np.inf]), np.array([np.inf, 0.0]))


def _dual_infeasible() -> QP:  # an unbounded LP: min −x0 − x1, x ≥ −1
    return QP(np.zeros((2, 2)), -np.ones(2), I2, -np.ones(2), np.full(2, np.inf))


def _mixed_batch() -> QPBatch:
    """Member 0 feasible (x0 ∈ [−1, 1]), member 1 infeasible (x0 ≥ 1 and x0 ≤ 0)."""
    A = np.array([[1.0, 0.0], [1.0, 0.0]])
    l = np.array([[-1.0, -1.0], [1.0, -np.inf]])
    u = np.array([[1.0, 1.0], [np.inf, 0.0]])
    return QPBatch(I2, A, np.array([[1.0, 1.0], [0.0, 0.0]]), l, u)


def _mixed_batch_outcome(sol: BatchSolution) -> None:
    assert Status(int(sol.status[1])) in _NOT_SOLVED, Status(int(sol.status[1])).name
    if Status(int(sol.status[0])) is Status.SOLVED:
        np.testing.assert_allclose(sol.x[0], [-1.0, -1.0], atol=1e-3)


def _huge_equality() -> QP:
    """x0 = 1e25 (a finite equality, absurdly large): never an infinite row, never SOLVED with
    an infinite residual."""
    return QP(I2, np.zeros(2), I2, np.array([1e25, -1.0]), np.array([1e25, 1.0]))


def _huge_equality_outcome(sol: Solution) -> None:
    if sol.status is Status.SOLVED:
        assert np.isfinite(sol.primal_residual)
        check = sol.extras["residual_check"]
        # a SOLVED far off the row is flagged, never reported as clean
        assert check["result"] == "passed" or check["primal_residual"] > check["tolerance"]
        assert check["result"] == "failed" or sol.primal_residual <= 100 * check["tolerance"]


#: right answers whose terms are all near zero (optimum x = 0): solve_qp as the user calls it
_ZERO_OPT = dict(q=[1.0, -1.0], G=[[1.0, 1.0]], h=[0.2], A=[[1.0, -1.0]], b=[0.0], lb=[-1, -1])
_TEXTBOOK = dict(P=[[4.0, 1.0], [1.0, 2.0]], q=[1.0, 1.0], G=[[1.0, 1.0]], h=[1.0], lb=[0, 0])
#: backends that reach these optima at their defaults (the others may stop early themselves)
_ZERO_SOLVED = frozenset({"clarabel", "osqp", "ipm", "admm", "cvxpy", "qpsolvers:clarabel"})


def _solved_at_zero(be: str) -> Callable[[Any], None]:
    def check(sol: Any) -> None:
        sols = [sol] if isinstance(sol, Solution) else [sol[i] for i in range(len(sol))]
        for one in sols:
            c = one.extras["check"]
            near = np.all(np.isfinite(one.x)) and np.max(np.abs(one.x)) <= 1e-4
            assert not (near and c["result"] == "far"), f"{be}: right answer rejected: {c}"
            if be in _ZERO_SOLVED:
                assert one.status is Status.SOLVED and near, f"{be}: {one.status.name} {c}"

    return check


def _backend_cases(be: str) -> list[Case]:
    cases: list[Case] = []
    for name, kw, names in BAD_SETTINGS:
        cases.append(
            raises(
                f"{be}-solve-{name}",
                lambda kw=kw: solve(_qp(), be, **kw),
                InvalidSettingError,
                names,
            )
        )
    for name, kw, names in BAD_SETTINGS[:2]:
        cases.append(
            raises(
                f"{be}-batch-{name}",
                lambda kw=kw: solve_batch(_batch(), be, **kw),
                InvalidSettingError,
                names,
            )
        )
        cases.append(
            raises(
                f"{be}-solve_qp-{name}",
                lambda kw=kw: solve_qp(
                    I2, [1.0, -1.0], lb=[-0.5] * 2, ub=[1.0] * 2, backend=be, **kw
                ),
                InvalidSettingError,
                names,
            )
        )
    cases += [
        raises(
            f"{be}-nonconvex-solve_qp",
            lambda: solve_qp(INDEFINITE, [0.0, 0.0], lb=[-1.0] * 2, ub=[1.0] * 2, backend=be),
            NonConvexError,
            r"^P is not positive semidefinite",
        ),
        raises(
            f"{be}-nonconvex-forced",
            lambda: solve(_NONCONVEX_UNCHECKED(), be, check_convex=True),
            NonConvexError,
            r"^P is not positive semidefinite",
        ),
        Case(
            f"{be}-primal-infeasible", lambda: solve(_primal_infeasible(), be), statuses=_NOT_SOLVED
        ),
        Case(f"{be}-dual-infeasible", lambda: solve(_dual_infeasible(), be), statuses=_NOT_SOLVED),
        Case(
            f"{be}-batch-with-infeasible-member",
            lambda: solve_batch(_mixed_batch(), be),
            check=_mixed_batch_outcome,
        ),
        Case(
            f"{be}-eq-1e25-not-solved-as-inf",
            lambda: solve(_huge_equality(), be),
            check=_huge_equality_outcome,
        ),
        Case(
            f"{be}-zero-optimum-dense",
            lambda: solve_qp(I2, **_ZERO_OPT, ub=[1, 1], backend=be),
            check=_solved_at_zero(be),
        ),
        Case(
            f"{be}-zero-optimum-sparse",
            lambda: solve_qp(sp.identity(2, format="csc"), **_ZERO_OPT, ub=[1, 1], backend=be),
            check=_solved_at_zero(be),
        ),
        Case(
            f"{be}-textbook-on-lower-bounds",
            lambda: solve_qp(**_TEXTBOOK, ub=[1, 1], backend=be),
            check=_solved_at_zero(be),
        ),
        Case(
            f"{be}-textbook-batch-of-5",
            lambda: solve_batch(
                QPBatch.from_qpsolvers(
                    np.array(_TEXTBOOK["P"]),
                    np.tile(_TEXTBOOK["q"], (5, 1)),
                    G=_TEXTBOOK["G"],
                    h=_TEXTBOOK["h"],
                    lb=_TEXTBOOK["lb"],
                    ub=[1, 1],
                ),
                be,
            ),
            check=_solved_at_zero(be),
        ),
    ]
    return cases


BACKEND_CASES = [c for be in BACKENDS for c in _backend_cases(be)]
ALL = QP_CASES + BATCH_CASES + FQ_CASES + ENTRY_CASES + BACKEND_CASES

#: (case id, status) of every solution returned over the corpus, for the zero-wrong-SOLVED check
_SEEN: list[tuple[str, Status]] = []


@pytest.mark.parametrize("case", ALL, ids=[c.id for c in ALL])
def test_corpus_case(case: Case):
    if case.error is not None:
        with pytest.raises(case.error, match=case.names):
            case.call()
        return
    sol = case.call()
    if case.check is not None:
        case.check(sol)
    if not isinstance(sol, (Solution, BatchSolution)):
        return
    statuses = [sol.status] if isinstance(sol, Solution) else [Status(int(s)) for s in sol.status]
    _SEEN.extend((case.id, s) for s in statuses)
    if isinstance(sol, Solution) and case.statuses:
        assert sol.status in case.statuses, f"{case.id}: {sol.status.name} {sol.extras}"
        if get_backend(sol.backend).detects_infeasibility and "primal-inf" in case.id:
            assert sol.status is Status.PRIMAL_INFEASIBLE, sol.status.name


def test_case_count_covers_the_api():
    """The corpus is broad: well over 150 cases, every backend present in it."""
    assert len(ALL) >= 150, len(ALL)
    for be in BACKENDS:
        assert any(c.id.startswith(f"{be}-") for c in ALL)


def test_zero_wrong_solved_over_the_corpus():
    """Every solve in the corpus was of an infeasible or unbounded problem or a batch holding one:
    none came back SOLVED where it cannot be (runs after the cases in file order)."""
    assert _SEEN, "run the whole file: the cases record what they saw"
    wrong = [
        (i, s.name)
        for i, s in _SEEN
        if s is Status.SOLVED and "infeasible" in i and "batch" not in i
    ]
    assert not wrong, wrong
