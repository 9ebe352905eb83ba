"""What a jittable projector is: the contract between :mod:`solvers` and code that runs QPs
inside its own ``jit`` (the planner's projection in :mod:`frenet.projection`).

A *projector* solves a batch of QPs ``min ½xᵀPx + qᵀx  s.t.  l ≤ Ax ≤ u`` whose ``P`` and ``A``
were fixed when it was built (scaled and factored on the host, once): a call takes the per-QP
data ``q (B, n)``, ``l, u (B, m)`` and an optional warm start, and returns ``x``, ``y`` and a
status per QP.  It is pure JAX: jittable, vmappable, no host round trip, nothing raised for a
QP that is not solved (its status says so).  :func:`solvers.admm.admm_projector` builds one;
its result, :class:`solvers.admm.ADMMState`, and :class:`solvers.jax.QPSolution` both satisfy
:class:`JaxQPResult`.

Statuses are the integer codes of :data:`solvers.STATUS_CODES` (``STATUS_CODES.SOLVED == 1``),
compared as plain integers inside a trace.  Importing this module imports nothing but
:mod:`typing`.
"""

from __future__ import annotations

from typing import Any, Protocol

__all__ = ["JaxProjector", "JaxQPResult"]


class JaxQPResult(Protocol):
    """A projector's result: JAX arrays with a leading batch axis ``B``.

    Attributes
    ----------
    x : (B, n) primal solution (unscaled).
    y : (B, m) multipliers in OSQP's sign convention (``Px + q + Aᵀy = 0``, ``y ≥ 0`` on active
        upper bounds, ``y ≤ 0`` on active lower bounds).
    status : (B,) int32 codes of :data:`solvers.STATUS_CODES`.
    """

    @property
    def x(self) -> Any: ...

    @property
    def y(self) -> Any: ...

    @property
    def status(self) -> Any: ...


class JaxProjector(Protocol):
    """``project(q, l, u, x0=None, y0=None) -> JaxQPResult``: a jittable batched QP solve with
    ``P`` and ``A`` fixed at construction.

    ``q (B, n)``, ``l, u (B, m)`` (``±inf`` allowed, ``l == u`` an equality); ``x0 (B, n)`` and
    ``y0 (B, m)`` an optional warm start in the result's own convention (a previous call's
    ``x`` and ``y``).  A 1-D ``q, l, u`` is one QP (``B = 1``, squeezed back).  The call does
    no input validation beyond shapes (it must trace).
    """

    def __call__(self, q: Any, l: Any, u: Any, x0: Any = None, y0: Any = None) -> JaxQPResult: ...
