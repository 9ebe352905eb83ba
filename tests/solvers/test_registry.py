"""Backend registry: lazy imports, import isolation, clear errors, user backends.

Import isolation follows cvxpylayers' ``test_import_isolation``: in a fresh interpreter an optional
package is made unimportable (``sys.modules[name] = None``) before ``import solvers``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import solvers
from solvers import (
    QP,
    Backend,
    BackendUnavailableError,
    QPBatch,
    Solution,
    Status,
    UnknownBackendError,
    available_backends,
    get_backend,
    register_backend,
    solve,
    solve_batch,
)
from solvers import registry as reg

REPO = Path(__file__).resolve().parents[2]


def _qp() -> QP:
    return QP(np.eye(2), np.array([1.0, -1.0]), np.eye(2), np.array([-0.5, -0.5]), np.ones(2))


def _run_without(blocked: list[str], body: str) -> dict:
    """Run ``body`` in a fresh interpreter where the ``blocked`` packages cannot be imported."""
    code = (
        textwrap.dedent(
            f"""
        import json, sys
        for name in {blocked!r}:
            sys.modules[name] = None  # `import name` now raises ImportError
        import numpy as np
        import solvers
        out = {{}}
        """
        )
        + textwrap.dedent(body)
        + "\nprint(json.dumps(out))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


_PROBE = """
qp = solvers.QP(np.eye(2), np.ones(2), np.eye(2), -np.ones(2), np.ones(2))
out["available"] = solvers.available_backends()
out["clarabel"] = solvers.solve(qp, "clarabel").status.name
try:
    solvers.solve(qp, backend=NAME)
    out["error"] = None
except solvers.BackendUnavailableError as exc:
    out["error"] = str(exc)
    out["is_import_error"] = isinstance(exc, ImportError)
"""


@pytest.mark.parametrize(
    "package, name, extra",
    [
        ("osqp", "osqp", "mmdopt[osqp]"),
        ("cvxpy", "cvxpy", "mmdopt[cvxpy]"),
        ("qpsolvers", "qpsolvers:piqp", "mmdopt[qpsolvers]"),
    ],
)
def test_missing_optional_package_is_isolated_and_named(package, name, extra):
    pytest.importorskip(package)  # only meaningful where the package is normally there
    out = _run_without([package], _PROBE.replace("NAME", repr(name)))
    assert name not in out["available"]
    if package == "qpsolvers":
        assert not any(b.startswith("qpsolvers:") for b in out["available"])
    assert "clarabel" in out["available"] and out["clarabel"] == "SOLVED"
    assert out["error"] is not None and out["is_import_error"]
    assert repr(package) in out["error"] and extra in out["error"]


def test_all_optional_packages_missing_leaves_core_working():
    out = _run_without(["osqp", "cvxpy", "qpsolvers"], _PROBE.replace("NAME", "'osqp'"))
    assert set(out["available"]) <= {"clarabel", "admm", "ipm"}
    assert out["clarabel"] == "SOLVED" and "mmdopt[osqp]" in out["error"]


def test_import_solvers_does_not_import_optional_packages():
    out = _run_without(
        [],
        'out["loaded"] = [m for m in ("osqp", "cvxpy", "qpsolvers", "jax") if m in sys.modules]',
    )
    assert out["loaded"] == []


def test_unknown_backend_names_are_rejected_with_the_available_list():
    with pytest.raises(UnknownBackendError, match="available: .*clarabel"):
        solve(_qp(), backend="no-such-solver")
    with pytest.raises(TypeError, match="backend must be a string"):
        get_backend(None)  # type: ignore[arg-type]
    if "qpsolvers" not in " ".join(available_backends()):
        pytest.skip("qpsolvers not installed")
    with pytest.raises(UnknownBackendError, match="no installed solver 'no-such'"):
        solve(_qp(), backend="qpsolvers:no-such")
    assert issubclass(UnknownBackendError, ValueError)
    assert issubclass(BackendUnavailableError, ImportError)


def test_available_backends_all_resolve_and_solve(backend):
    be = get_backend(backend)
    assert isinstance(be, Backend) and be.name == backend
    assert get_backend(backend) is be  # cached
    sol = solve(_qp(), backend)  # the backend's own defaults
    assert sol.status in (Status.SOLVED, Status.SOLVED_INACCURATE) and sol.backend == backend
    np.testing.assert_allclose(sol.x, [-0.5, 1.0], atol=1e-2)


class _ProjectOntoBox(Backend):
    """A user backend: exact for diagonal P with A = I (a box projection)."""

    name = "box-projection"
    detects_infeasibility = False

    def solve(self, qp: QP, *, warm_start: Solution | None = None, **settings) -> Solution:
        d = np.diag(qp.P if isinstance(qp.P, np.ndarray) else qp.P.toarray())
        x = np.clip(-qp.q / d, qp.l, qp.u)
        y = -(d * x + qp.q)
        return Solution(
            x=x,
            y=y,
            status=Status.SOLVED,
            objective=qp.objective(x),
            iterations=1,
            solve_time=0.0,
            primal_residual=qp.constraint_violation(x),
            dual_residual=qp.dual_residual(x, y),
            backend=self.name,
            settings=dict(settings),
        )


@pytest.fixture
def clean_registry(monkeypatch):
    monkeypatch.setattr(reg, "_USER", dict(reg._USER))
    monkeypatch.setattr(reg, "_CACHE", dict(reg._CACHE))


def test_user_registered_backend_is_listed_and_used(clean_registry):
    register_backend("box-projection", _ProjectOntoBox)
    assert "box-projection" in available_backends()
    sol = solve(_qp(), backend="box-projection", note="passed through")
    np.testing.assert_allclose(sol.x, [-0.5, 1.0])
    np.testing.assert_allclose(sol.y, [-0.5, 0.0])  # OSQP convention: < 0 on an active lower bound
    assert sol.settings == {"note": "passed through"}
    qp = _qp()
    batch = QPBatch(qp.P, qp.A, np.stack([qp.q, -qp.q]), np.stack([qp.l] * 2), np.stack([qp.u] * 2))
    bs = solve_batch(batch, backend="box-projection")  # the default loop over solve
    assert bs.all_solved and bs.x.shape == (2, 2)
    np.testing.assert_allclose(bs.x[1], [1.0, -0.5])


def test_register_backend_rejects_bad_names(clean_registry):
    for bad in ("", "qpsolvers:mine", None):
        with pytest.raises(ValueError, match="backend name"):
            register_backend(bad, _ProjectOntoBox)  # type: ignore[arg-type]


def test_registering_again_replaces_the_cached_backend(clean_registry):
    register_backend("box-projection", _ProjectOntoBox)
    first = get_backend("box-projection")
    register_backend("box-projection", _ProjectOntoBox)
    assert get_backend("box-projection") is not first


def test_solve_rejects_wrong_argument_types():
    with pytest.raises(TypeError, match="solvers.QP"):
        solve("not a qp", "clarabel")  # type: ignore[arg-type]
    qp = _qp()
    batch = QPBatch(qp.P, qp.A, qp.q[None], qp.l[None], qp.u[None])
    with pytest.raises(TypeError, match="solvers.QPBatch"):
        solve_batch(qp, "clarabel")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="warm_start"):
        solve_batch(batch, "clarabel", warm_start="nope")  # type: ignore[arg-type]


def test_public_names():
    for name in ("QP", "QPBatch", "solve", "solve_batch", "available_backends", "Status"):
        assert name in solvers.__all__
