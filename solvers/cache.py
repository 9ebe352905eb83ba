"""One bounded cache for everything :mod:`solvers` keeps between calls.

Caches
------
Every cache in :mod:`solvers` is a :class:`BoundedCache`: a ``dict`` with a ``maxsize``.
Inserting a new key into a full cache first evicts the oldest *inserted* key (first in, first
out: a hit does not refresh an entry, and replacing the value of a key already present keeps its
place).  Nothing expires by time.  What is cached:

* backend objects of :func:`solvers.get_backend`, keyed by backend name, at most 64;
  cleared by :func:`solvers.registry.clear_backend_cache`;
* ``ipm``: one :class:`~solvers.ipm.IPMSetup` (scaling, ordering, band tables) per hash of
  ``P`` and ``A`` and the scaling and linear-solver settings, at most 16 per backend object;
  cleared by ``get_backend("ipm").clear_cache()``;
* ``admm``: one :class:`~solvers.admm.ADMMFactor` (and its polish data) per hash of ``P``,
  ``A`` and the row masks and the settings other than the tolerances, at most 16 per backend
  object; cleared by ``get_backend("admm").clear_cache()``;
* :func:`solvers.jax.solve_qp`: one custom-JVP function per ``(method, settings, polish,
  active_tol)``, at most 64; cleared by :func:`solvers.jax.clear_cache`.

Why: the host-side precomputation (scaling, ordering, factorisations) is done once per shared
``P, A`` and reused by every batch that has them; one Python function per settings lets ``jit``
keep its traces.  Why FIFO: the entries are cheap to rebuild and few are live at once, so the
simplest rule whose behaviour is easy to state is enough.  The bound keeps a long-running process
that sees many different problems from holding every one of them.

Cached values are the same whether they came from the cache or were just built, so clearing a
cache never changes a result, only the time to the next one.  The one cache kept apart is the
``cvxpy`` backend's list of compiled cvxpy problems (16, least recently used first): it is found
by comparing ``P``, ``A`` and the row pattern with each entry's, not by a key
(``get_backend("cvxpy").clear_cache()`` empties it too).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterable
from typing import Any, Generic, TypeVar

__all__ = ["BoundedCache"]

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class BoundedCache(dict, Generic[K, V]):
    """A ``dict`` holding at most ``maxsize`` entries, the oldest inserted evicted first.

    A subclass of ``dict`` so that code (and tests) that treat a cache as a plain mapping
    (``key in cache``, ``cache[key]``, ``cache.clear()``, ``dict(cache)``) keep working; every
    way of inserting (``cache[key] = v``, :meth:`setdefault`, :meth:`update`, ``|=``) goes
    through the bound.
    """

    def __init__(self, maxsize: int) -> None:
        if isinstance(maxsize, bool) or not isinstance(maxsize, int) or maxsize < 1:
            raise ValueError(f"maxsize must be a positive integer, got {maxsize!r}")
        super().__init__()
        self.maxsize = maxsize

    def __setitem__(self, key: K, value: V) -> None:
        if key not in self:
            while len(self) >= self.maxsize:
                del self[next(iter(self))]  # the oldest inserted key
        super().__setitem__(key, value)

    def get_or_create(self, key: K, factory: Callable[[], V]) -> V:
        """The value cached under ``key``; on a miss, ``factory()`` (called once) is stored first.

        An exception from ``factory`` propagates and leaves the cache unchanged.
        """
        if not callable(factory):
            raise ValueError(f"factory must be callable, got {type(factory).__name__}")
        if key in self:
            return self[key]
        value = factory()
        self[key] = value
        return value

    def setdefault(self, key: K, default: V = None) -> V:  # type: ignore[override]
        if key not in self:
            self[key] = default
        return self[key]

    def update(self, other: Any = (), /, **kwargs: V) -> None:  # type: ignore[override]
        items: Iterable = other.items() if hasattr(other, "items") else other
        for k, v in items:
            self[k] = v
        for k, v in kwargs.items():
            self[k] = v

    def __ior__(self, other: Any) -> BoundedCache[K, V]:  # type: ignore[override]
        self.update(other)
        return self

    def copy(self) -> BoundedCache[K, V]:
        out: BoundedCache[K, V] = BoundedCache(self.maxsize)
        out.update(self)
        return out

    def __reduce__(self):
        # rebuild through __init__ (for maxsize) before the items go back in, oldest first
        return (type(self), (self.maxsize,), None, None, iter(self.items()))

    def __repr__(self) -> str:
        return f"BoundedCache(maxsize={self.maxsize}, {dict.__repr__(self)})"
