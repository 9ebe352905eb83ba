"""The shared pieces of :mod:`solvers`: the one Ruiz scaling, the one bounded cache, the one table
of status codes, the jittable-projector contract, and no private name imported across modules."""

from __future__ import annotations

import ast
import pickle
from pathlib import Path

import numpy as np
import pytest

import solvers
from solvers import STATUS_CODES, Status, StatusCodes
from solvers.cache import BoundedCache
from solvers.scaling import ruiz_equilibrate
from solvers.solution import RUNNING_CODE

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------------------ Ruiz scaling
def _reference_ruiz(P: np.ndarray, A: np.ndarray, iters: int):
    """The rule written out on the whole KKT matrix: scale ``K = [[c·DPD, DAᵀE], [EAD, 0]]``'s
    columns by ``1/√‖col‖∞`` (norm < 1e-4 → 1, factors clipped to [1e-4, 1e4]), then the cost
    by ``1/mean_j ‖(c·DPD)_{:,j}‖∞`` (clipped likewise, 1 below 1e-4)."""
    n, m = P.shape[0], A.shape[0]
    K = np.block([[P, A.T], [A, np.zeros((m, m))]])
    d, c = np.ones(n + m), 1.0
    for _ in range(iters):
        Ks = d[:, None] * K * d[None, :]
        Ks[:n, :n] *= c
        norms = np.abs(Ks).max(axis=0)
        d = d * np.clip(1.0 / np.sqrt(np.where(norms < 1e-4, 1.0, norms)), 1e-4, 1e4)
        Ps = c * d[:n, None] * P * d[None, :n]
        mean = np.abs(Ps).max(axis=0).mean()
        c *= np.clip(1.0 / mean, 1e-4, 1e4) if mean >= 1e-4 else 1.0
    return d[:n], d[n:], c


def _random_qp(seed: int, n: int = 6, m: int = 9):
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((n, n)) * np.exp(rng.uniform(-3, 3, (n, 1)))
    P = M @ M.T + 1e-3 * np.eye(n)
    A = rng.standard_normal((m, n)) * np.exp(rng.uniform(-4, 4, (m, 1)))
    return P, A


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ruiz_matches_the_rule_written_on_the_whole_kkt_matrix(seed):
    P, A = _random_qp(seed)
    for iters in (0, 1, 4, 10):
        D, E, c = ruiz_equilibrate(P, A, iters)
        Dr, Er, cr = _reference_ruiz(P, A, iters)
        np.testing.assert_allclose(D, Dr, rtol=1e-12)
        np.testing.assert_allclose(E, Er, rtol=1e-12)
        assert c == pytest.approx(cr, rel=1e-12)
        assert isinstance(c, float) and D.dtype == E.dtype == np.float64


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ruiz_equilibrates_the_kkt_rows_and_columns_to_unit_norm(seed):
    P, A = _random_qp(seed)
    D, E, c = ruiz_equilibrate(P, A, 50)
    Ps, As = c * D[:, None] * P * D[None, :], E[:, None] * A * D[None, :]
    col = np.maximum(np.abs(Ps).max(axis=0), np.abs(As).max(axis=0))
    row = np.abs(As).max(axis=1)
    before = np.concatenate([np.maximum(np.abs(P).max(0), np.abs(A).max(0)), np.abs(A).max(1)])
    assert np.ptp(np.log10(before)) > 3  # badly scaled to begin with
    np.testing.assert_allclose(col, 1.0, atol=0.05)
    np.testing.assert_allclose(row, 1.0, atol=0.05)


def test_ruiz_leaves_zero_rows_and_columns_alone_and_its_input_unchanged():
    P, A = _random_qp(3)
    P[:, 2] = P[2, :] = 0.0
    A[:, 2] = 0.0
    A[4] = 0.0
    P0, A0 = P.copy(), A.copy()
    D, E, _ = ruiz_equilibrate(P, A, 10)
    assert D[2] == 1.0 and E[4] == 1.0  # a zero norm counts as 1: the factor stays 1
    np.testing.assert_array_equal(P, P0)
    np.testing.assert_array_equal(A, A0)
    D, E, c = ruiz_equilibrate(np.zeros((3, 3)), np.zeros((0, 3)), 5)
    np.testing.assert_array_equal(D, 1.0)
    assert E.shape == (0,) and c == 1.0


def test_ruiz_in_jax_matches_numpy_and_traces():
    jax = pytest.importorskip("jax")
    jnp = jax.numpy
    P, A = _random_qp(4, n=4, m=5)
    D, E, c = ruiz_equilibrate(P, A, 10)
    with jax.enable_x64(True):
        Dj, Ej, cj = jax.jit(lambda p, a: ruiz_equilibrate(p, a, 10, xp=jnp))(
            jnp.asarray(P), jnp.asarray(A)
        )
        assert Dj.dtype == jnp.float64 and cj.shape == ()
        np.testing.assert_allclose(np.asarray(Dj), D, rtol=1e-12)
        np.testing.assert_allclose(np.asarray(Ej), E, rtol=1e-12)
        assert float(cj) == pytest.approx(c, rel=1e-12)


@pytest.mark.parametrize(
    ("args", "kwargs", "named"),
    [
        ((np.ones((2, 3)), np.ones((1, 3)), 3), {}, "P must be square"),
        ((np.ones(2), np.ones((1, 2)), 3), {}, "P must be a 2-D"),
        ((np.eye(2), np.ones((1, 3)), 3), {}, "A must have shape"),
        ((np.eye(2), np.ones((1, 2), np.float32), 3), {}, "A must have P's dtype"),
        ((np.eye(2, dtype=int), np.ones((1, 2), int), 3), {}, "P must have a floating"),
        ((np.eye(2), np.ones((1, 2)), -1), {}, "iters"),
        ((np.eye(2), np.ones((1, 2)), 2.5), {}, "iters"),
        ((np.eye(2), np.ones((1, 2)), 2), {"xp": "numpy"}, "xp"),
    ],
)
def test_ruiz_names_a_bad_argument(args, kwargs, named):
    with pytest.raises(ValueError, match=named):
        ruiz_equilibrate(*args, **kwargs)


# ------------------------------------------------------------------------------ bounded cache
def test_bounded_cache_evicts_the_oldest_inserted_key_at_its_bound():
    cache: BoundedCache[str, int] = BoundedCache(3)
    for k in "abc":
        cache[k] = ord(k)
    assert cache["a"] == ord("a")  # a hit does not refresh (first in, first out)
    cache["b"] = 0  # replacing a value keeps its place
    cache["d"] = 4
    assert list(cache) == ["b", "c", "d"] and len(cache) == 3
    cache.setdefault("e", 5)
    cache.update({"f": 6}, g=7)
    cache |= {"h": 8}
    assert list(cache) == ["f", "g", "h"] and len(cache) == cache.maxsize
    assert isinstance(cache, dict)  # code that treats it as a mapping keeps working
    cache.clear()
    assert len(cache) == 0


def test_get_or_create_calls_the_factory_once_per_key():
    cache: BoundedCache[int, list] = BoundedCache(2)
    calls: list[int] = []

    def make(k):
        def factory():
            calls.append(k)
            return [k]

        return factory

    first = cache.get_or_create(1, make(1))
    assert cache.get_or_create(1, make(1)) is first
    cache.get_or_create(2, make(2))
    assert calls == [1, 2]
    cache.get_or_create(3, make(3))  # evicts 1
    assert 1 not in cache and list(cache) == [2, 3]
    cache.get_or_create(1, make(1))  # rebuilt after eviction
    assert calls == [1, 2, 3, 1]

    def broken():
        raise RuntimeError("no value")

    with pytest.raises(RuntimeError):
        cache.get_or_create(9, broken)
    assert list(cache) == [3, 1]  # a failing factory leaves the cache as it was
    with pytest.raises(ValueError, match="factory"):
        cache.get_or_create(4, None)


def test_bounded_cache_checks_its_bound_and_survives_pickling():
    for bad in (0, -1, 2.0, True, None):
        with pytest.raises(ValueError, match="maxsize"):
            BoundedCache(bad)
    cache: BoundedCache[str, int] = BoundedCache(2)
    cache.update(a=1, b=2)
    back = pickle.loads(pickle.dumps(cache))
    assert isinstance(back, BoundedCache) and back.maxsize == 2 and dict(back) == {"a": 1, "b": 2}
    copy = cache.copy()
    copy["c"] = 3
    assert isinstance(copy, BoundedCache) and list(copy) == ["b", "c"] and list(cache) == ["a", "b"]


def test_the_solvers_caches_are_bounded_caches_with_a_clear(monkeypatch):
    from solvers import registry

    assert isinstance(registry._CACHE, BoundedCache)
    pytest.importorskip("jax")
    import solvers.jax as sj
    from solvers.admm import ADMMBackend
    from solvers.ipm import IPMBackend

    for be, attr in ((IPMBackend(), "_setups"), (ADMMBackend(), "_factors")):
        cache = getattr(be, attr)
        assert isinstance(cache, BoundedCache) and cache.maxsize == 16
        cache["sentinel"] = None
        be.clear_cache()
        assert len(cache) == 0
    assert isinstance(sj._SOLVERS, BoundedCache) and sj._SOLVERS.maxsize == 64
    monkeypatch.setattr(sj, "_SOLVERS", BoundedCache(2))  # leave the session's traces alone
    sj._SOLVERS["sentinel"] = None
    sj.clear_cache()
    assert len(sj._SOLVERS) == 0


# ------------------------------------------------------------------------------ status codes
def test_the_status_table_has_one_equal_int_per_status_member():
    assert StatusCodes._fields == tuple(s.name for s in Status)
    for s in Status:
        code = getattr(STATUS_CODES, s.name)
        assert type(code) is int and code == int(s)
    assert len(set(STATUS_CODES)) == len(Status)
    assert RUNNING_CODE not in STATUS_CODES
    assert solvers.STATUS_CODES is STATUS_CODES


# ------------------------------------------------------------------------------ the projector
def test_admm_projector_is_admm_iterate_on_its_factor():
    pytest.importorskip("jax")
    from solvers.admm import ADMMSettings, admm_factor, admm_iterate, admm_projector

    P, A = np.eye(2), np.array([[1.0, 1.0]])
    factor = admm_factor(P, A, ADMMSettings(dtype="float32", check_every=5, max_iter=5))
    q, l, u = np.array([[1.0, -1.0]]), np.array([[-0.5]]), np.array([[0.5]])
    project: solvers.JaxProjector = admm_projector(factor, 5)
    got, want = project(q, l, u), admm_iterate(factor, q, l, u, iters=5)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert got.x.shape == (1, 2) and got.y.shape == (1, 1) and got.status.shape == (1,)
    with pytest.raises(ValueError, match="factor"):
        admm_projector(P)
    with pytest.raises(ValueError, match="iters"):
        admm_projector(factor, -1)


# ------------------------------------------------------------------- no private cross imports
def _private_imports(path: Path) -> list[str]:
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module != "__future__":
            names = [a.name for a in node.names if a.name.startswith("_")]
            if names:
                out.append(f"{path.relative_to(ROOT)}:{node.lineno}: {names}")
    return out


def test_no_module_of_solvers_or_frenet_imports_a_private_name():
    hits = [
        h
        for pkg in ("solvers", "frenet")
        for p in (ROOT / pkg).rglob("*.py")
        for h in _private_imports(p)
    ]
    assert not hits, hits
