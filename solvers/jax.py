"""A differentiable QP layer in JAX: :func:`solve_qp` with gradients by implicit differentiation.

::

    import jax, jax.numpy as jnp
    import solvers.jax as sj

    with jax.enable_x64(True):
        def loss(q):
            sol = sj.solve_qp(P, q, A, l, u)          # method="ipm" (default) or "admm"
            return jnp.sum(sol.x ** 2)
        g = jax.grad(loss)(q)                         # also jax.jacfwd / jax.jvp / jax.vmap / jit

One QP ``min ½xᵀPx + qᵀx  s.t.  l ≤ Ax ≤ u`` with dense ``P (n, n)``, ``q (n,)``, ``A (m, n)``,
``l, u (m,)`` (``±inf`` allowed, ``l == u`` an equality).  Batches go through ``jax.vmap``;
every argument may be traced (``P`` and ``A`` too: the Ruiz scaling and, for ``"admm"``, the
step-size ladder's inverses are computed in JAX, so no host round trip).  Returns a
:class:`QPSolution` ``(x, y, status)`` with ``y`` in OSQP's sign convention (``Px + q + Aᵀy = 0``,
``y ≥ 0`` on active upper bounds, ``y ≤ 0`` on active lower bounds) and ``status`` the
:class:`solvers.Status` integer code.  Nothing raises inside ``jit``: an infeasible or unsolved QP
is reported by its status.

Solvers
-------
* ``method="ipm"``: the interior-point iteration of :mod:`solvers.ipm` (dense linear algebra, no
  variable reordering) on one QP.  Needs JAX's x64 mode (``with jax.enable_x64(True):`` around the
  trace and the call); settings are those of :class:`solvers.ipm.IPMSettings` except
  ``linear_solver`` and ``chunk_size``, with ``shifted_start=False`` unless given (the floored
  start: its final iterate suits the active-set rule below on weakly active rows).
* ``method="admm"``: the ADMM iteration of :mod:`solvers.admm` followed, when ``polish=True``
  (default), by an active-set polish done in JAX (the reduced KKT system below, solved with the
  active set read from ADMM's multipliers and kept only where it is primal feasible and its
  multipliers have the right signs).  Settings are those of :class:`solvers.admm.ADMMSettings`
  except ``stage_iter`` and ``fallback`` (host-side); ``dtype`` defaults to float64 in x64 mode
  and float32 otherwise.

Derivatives (implicit differentiation of the KKT conditions)
------------------------------------------------------------
The iterations are never differentiated.  :func:`solve_qp` is a :func:`jax.custom_jvp`: the
tangent of ``(x, y)`` at the returned solution solves the linearised KKT system on the active set

    [[P, Aᵀ S], [S A, −(I − S)]] (dx, dy) = (−(dP x + dq + dAᵀ y), S(W_l dl + W_u du − dA x)),

``S`` the diagonal 0/1 mask of active rows, ``W_l, W_u`` which bound each active row is at.  The
tangent map is linear in ``(dP, dq, dA, dl, du)`` and built from transposable primitives, so JAX
transposes it for reverse mode: ``jax.grad``, ``jax.vjp``, ``jax.jacrev`` as well as ``jax.jvp``
and ``jax.jacfwd`` all work, and compose with ``jit`` and ``vmap``.  The system is condensed
onto the variables: one ``n × n`` Cholesky of ``P + σI + AᵀSA/δ`` per QP and differentiation,
and three steps of iterative refinement against the unregularised system remove ``σ``, ``δ``
(:func:`_kkt_solver`); a backward pass costs a fraction of the forward solve
(``benchmarks/qp_diff.py``).

Conventions (stated, because the solution map is only piecewise smooth):

* **Active set.**  Row ``i`` is active at its lower bound when ``y_i < −τ`` and the row is at
  that bound, and at its upper bound when ``y_i > τ`` and the row is at that bound, with
  ``τ = active_tol · max(1, ‖y‖∞)`` (``active_tol = 1e-6`` by default).  "At its bound" is
  relative to the multiplier: the slack ``A_i x − l_i`` (or ``u_i − A_i x``), divided by the
  row's size ``max(1, |bound|, (|A||x|)_i)``, is at most ``|y_i| / max(1, ‖y‖∞)`` (plus ten
  times the solver's primal tolerance).  An interior-point solution has slack × multiplier ≈ μ
  on every row: an active row has a slack far below its multiplier, a row that only approaches
  its bound the reverse, even when its multiplier passes ``τ`` at a loose tolerance.  Equality
  rows (``l_i == u_i``) are always active; their sensitivity goes to ``l_i`` when
  ``y_i < −τ``, to ``u_i`` when ``y_i > τ`` and half to each otherwise (so ``d/dl + d/du`` is the
  derivative with respect to the common right-hand side).
* **Weakly active rows** (``|y_i| ≤ τ`` while ``A_i x`` sits at a bound) are treated as inactive:
  the derivative is the one-sided derivative in the directions that keep the row from becoming
  binding (for instance, loosening that bound).  Under strict complementarity it is the derivative.
  An interior-point solution at such a point has ``y_i`` and the row's slack both of the order of
  ``√μ`` (the last barrier parameter): the row counts as active only if its relative slack is
  below its relative multiplier (then it gives the other one-sided derivative); ADMM and
  polished solutions have ``y_i = 0`` exactly there.
* ``P`` enters only through its symmetric part: the derivative with respect to ``P`` is
  symmetric (``∂/∂P = ½(G + Gᵀ)``).
* **QPs that are not solved** (``status != SOLVED``: infeasible, unbounded, out of iterations) have
  NaN derivatives — every entry of the tangent, and every gradient entry that depends on them —
  together with their status; check ``status`` before using a gradient.
* **Linearly dependent active rows** (the same constraint twice, more active rows than
  variables): the reduced KKT system is singular.  The regularised, refined solve above still
  gives ``dx``, the derivative, and one of the (non-unique) multiplier derivatives ``dy``.

The host-side counterpart for a :class:`solvers.QP` solved by any backend is
:func:`solvers.vjp`.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .cache import BoundedCache
from .scaling import ruiz_equilibrate
from .solution import STATUS_CODES

__all__ = ["QPSolution", "solve_qp", "METHODS", "clear_cache"]

#: the solvers :func:`solve_qp` accepts
METHODS = ("ipm", "admm")
#: custom-JVP solve functions kept, one per (method, settings, polish, active_tol)
SOLVER_CACHE_SIZE = 64


class QPSolution(NamedTuple):
    """Result of :func:`solve_qp`: primal ``x (n,)``, dual ``y (m,)`` (OSQP's sign convention) and
    ``status`` (int32 :class:`solvers.Status` code; ``SOLVED == 1``).  Batched under ``vmap``."""

    x: Any
    y: Any
    status: Any


# --------------------------------------------------------------------------- active set (JAX)
class _Active(NamedTuple):
    a: Any  # (m,) 1.0 on active rows
    wl: Any  # (m,) weight of dl in an active row's right-hand side
    wu: Any  # (m,) weight of du


def _active_set(y, l, u, active_tol: float, A=None, x=None, slack_tol=0.0) -> _Active:
    """The convention of the module docstring, as 0/1 (and ½) masks in ``y``'s dtype.

    With ``A`` and ``x`` given, an inequality side also has to be at its bound: a row whose
    multiplier passes ``τ`` while ``A_i x`` is still ``> τ_s,i`` away from the bound (an
    interior-point iterate on a row that only approaches it) is inactive, ``τ_s,i =
    active_tol · max(1, |b_i|, (|A||x|)_i) + slack_tol``.
    """
    dt = y.dtype
    tau = active_tol * jnp.maximum(1.0, jnp.max(jnp.abs(y), initial=0.0))
    fin_l, fin_u = jnp.isfinite(l), jnp.isfinite(u)
    eq = fin_l & (l == u)
    lo, up = y < -tau, y > tau
    if A is not None:
        Ax = A @ x
        size = jnp.abs(A) @ jnp.abs(x)
        lf, uf = jnp.where(fin_l, l, 0.0), jnp.where(fin_u, u, 0.0)
        # the row's slack, relative to its size, below its multiplier, relative to ‖y‖∞
        ynorm = jnp.abs(y) / jnp.maximum(1.0, jnp.max(jnp.abs(y), initial=0.0))
        tol_l = ynorm * jnp.maximum(jnp.maximum(1.0, jnp.abs(lf)), size) + slack_tol
        tol_u = ynorm * jnp.maximum(jnp.maximum(1.0, jnp.abs(uf)), size) + slack_tol
        lo = lo & fin_l & (Ax - lf <= tol_l)
        up = up & fin_u & (uf - Ax <= tol_u)
    zero = ~(lo | up)
    a = (lo | up | eq).astype(dt)
    wl = jnp.where(lo, 1.0, jnp.where(eq & zero, 0.5, 0.0)).astype(dt)
    wu = jnp.where(up, 1.0, jnp.where(eq & zero, 0.5, 0.0)).astype(dt)
    return _Active(a, wl, wu)


def _kkt_solver(P, A, act: _Active, refine: int = 3):
    """``(r1, r2) ↦ (dx, dy)`` solving the reduced KKT system of :func:`_kkt_matrix`,
    ``[[P, AᵀS], [SA, −(I − S)]] (dx, dy) = (r1, r2)`` (``r2 = 0`` off the active rows), by one
    ``n × n`` Cholesky.

    The regularised system (``P + σI``, ``−δ`` on the active rows' diagonal) condenses onto
    ``M = P + σI + AᵀSA / δ``; ``refine`` steps of iterative refinement against the
    unregularised system remove ``σ`` and ``δ`` (each step shrinks the error by about
    ``δ / (δ + λ)``, ``λ`` the smallest eigenvalue of ``S A P⁻¹ AᵀS`` on the active rows).  With
    linearly dependent active rows (``λ = 0``) ``dx`` converges and the component of ``dy``
    along the dependency stays as the regularised solve left it (one of the solutions).
    ``δ = √ε_mach · ‖A‖²max / ‖P‖max``, ``σ = 1e-2 · √ε_mach · ‖P‖max``.
    """
    dt = P.dtype
    n = P.shape[0]
    c = float(np.sqrt(np.finfo(dt).eps))
    sP = jnp.maximum(jnp.max(jnp.abs(P)), 1e-300)
    sA = jnp.maximum(jnp.max(jnp.abs(A), initial=0.0), 1e-300)
    delta = c * sA * sA / sP
    sigma = 1e-2 * c * sP
    a = act.a
    M = P + sigma * jnp.eye(n, dtype=dt) + (A.T * (a / delta)[None, :]) @ A
    L = jax.scipy.linalg.cho_factor(M, lower=True)

    def regularised(r1, r2):
        dx = jax.scipy.linalg.cho_solve(L, r1 + A.T @ (a * r2) / delta)
        Adx = A @ dx
        return dx, a * (Adx - r2) / delta - (1.0 - a) * r2, Adx

    def solve(r1, r2):
        dx, dy, Adx = regularised(r1, r2)
        for _ in range(refine):
            e1 = r1 - P @ dx - A.T @ (a * dy)
            e2 = r2 - a * Adx + (1.0 - a) * dy
            cx, cy, Acx = regularised(e1, e2)
            dx, dy, Adx = dx + cx, dy + cy, Adx + Acx
        return dx, dy

    return solve


def _kkt_matrix(P, A, act: _Active):
    """``[[P, Aᵀ S], [S A, −(I − S)]]`` (symmetric when ``P`` is)."""
    a = act.a
    top = jnp.concatenate([P, A.T * a[None, :]], axis=1)
    bot = jnp.concatenate([a[:, None] * A, jnp.diag(a - 1.0)], axis=1)
    return jnp.concatenate([top, bot], axis=0)


# ------------------------------------------------------------------------------ forward solves
def _ipm_forward(s, P, q, A, l, u):
    from .ipm import IPMSetup, ipm_iterate, tunable_params

    n, m = P.shape[0], A.shape[0]
    D, E, c = ruiz_equilibrate(P, A, s.scaling_iter, xp=jnp)
    arrays = {
        "P": c * D[:, None] * P * D[None, :],
        "A": E[:, None] * A * D[None, :],
        "D": D,
        "E": E,
        "c": c,
        "perm": jnp.arange(n, dtype=jnp.int32),
        "iperm": jnp.arange(n, dtype=jnp.int32),
        "params": jnp.asarray(tunable_params(s)),
    }
    setup = IPMSetup(arrays, "dense", n - 1, n, m, s.refine_iter, None)
    res = ipm_iterate(setup, q, l, u)
    return res.x, res.y, res.status


def _admm_forward(s, polish: bool, active_tol: float, P, q, A, l, u):
    from .admm.core import ADMMFactor, admm_iterate

    n, m = P.shape[0], A.shape[0]
    dt = jnp.dtype(s.dtype)
    P, q, A, l, u = (v.astype(dt) for v in (P, q, A, l, u))
    D, E, c = ruiz_equilibrate(P, A, s.scaling_iter, xp=jnp)
    Ps = c * D[:, None] * P * D[None, :]
    As = E[:, None] * A * D[None, :]
    eq = jnp.isfinite(l) & (l == u)
    free = jnp.isinf(l) & jnp.isinf(u) & ~eq
    Rbase = jnp.where(eq, s.rho_eq_scale, 1.0).astype(dt)
    ladder = jnp.asarray(s.rho_ladder, dt)
    eye = jnp.eye(n, dtype=dt)

    def inverse(rho):
        R = jnp.where(free, s.rho_free, rho * Rbase)
        K = Ps + s.sigma * eye + As.T @ (R[:, None] * As)
        Ki = jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(K, lower=True), eye)
        return 0.5 * (Ki + Ki.T)

    Kinv = jnp.stack([inverse(ladder[r]) for r in range(len(s.rho_ladder))])
    factor = ADMMFactor(Ps, As, D, E, c, Kinv, ladder, Rbase, free, settings=s)
    st = admm_iterate(factor, q, l, u)
    x, y, status = st.x, st.y, st.status
    if polish and m > 0:
        x, y = _polish(P, q, A, l, u, x, y, active_tol)
        # the polished point replaces ADMM's when it is a KKT point to ADMM's own tolerances
        ok = _kkt_ok(P, q, A, l, u, x, y, s.eps_abs, s.eps_rel)
        x = jnp.where(ok, x, st.x)
        y = jnp.where(ok, y, st.y)
        status = jnp.where(ok, STATUS_CODES.SOLVED, status).astype(jnp.int32)
    return x, y, status


def _polish(P, q, A, l, u, x, y, active_tol):
    """Solve the equality-constrained QP on the active set read from ``y``."""
    act = _active_set(y, l, u, active_tol)
    b = act.wl * jnp.where(jnp.isfinite(l), l, 0.0) + act.wu * jnp.where(jnp.isfinite(u), u, 0.0)
    K = _kkt_matrix(P, A, act)
    sol = jnp.linalg.solve(K, jnp.concatenate([-q, act.a * b]))
    n = P.shape[0]
    return sol[:n], sol[n:]


def _kkt_ok(P, q, A, l, u, x, y, eps_abs, eps_rel):
    """OSQP's unscaled termination test on ``(x, y)`` plus the sign of ``y`` on each side."""
    Ax = A @ x
    z = jnp.clip(Ax, l, u)
    inf = lambda v: jnp.max(jnp.abs(v), initial=0.0)  # noqa: E731
    Px, ATy = P @ x, A.T @ y
    prim = inf(Ax - z)
    dual = inf(Px + q + ATy)
    eps_p = eps_abs + eps_rel * jnp.maximum(inf(Ax), inf(z))
    eps_d = eps_abs + eps_rel * jnp.maximum(jnp.maximum(inf(Px), inf(ATy)), inf(q))
    tol = eps_abs + eps_rel * inf(y)
    # y > 0 only at the upper bound, y < 0 only at the lower bound
    gap_u = jnp.where(jnp.isfinite(u), u - Ax, jnp.inf)
    gap_l = jnp.where(jnp.isfinite(l), Ax - l, jnp.inf)
    signs = jnp.all(jnp.where(y > tol, gap_u <= eps_p, True)) & jnp.all(
        jnp.where(y < -tol, gap_l <= eps_p, True)
    )
    finite = jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(y))
    return (prim <= eps_p) & (dual <= eps_d) & signs & finite


# ----------------------------------------------------------------------- the differentiable map
#: one custom-JVP function per (method, settings, polish, active_tol), see :mod:`solvers.cache`
_SOLVERS: BoundedCache[tuple, Any] = BoundedCache(SOLVER_CACHE_SIZE)


def clear_cache() -> None:
    """Forget the solve functions built for each settings (``jit`` then retraces a new one; the
    results are unchanged)."""
    _SOLVERS.clear()


def _solver(method: str, settings: Any, polish: bool, active_tol: float):
    """The custom-JVP solve for one (method, settings) pair (cached: one Python function each,
    so ``jit`` caches its traces)."""
    key = (method, settings, polish, active_tol)
    return _SOLVERS.get_or_create(key, lambda: _build_solver(method, settings, polish, active_tol))


def _build_solver(method: str, settings: Any, polish: bool, active_tol: float):
    """The custom-JVP solve of :func:`_solver` (uncached)."""
    eps_abs, eps_rel = float(settings.eps_abs), float(settings.eps_rel)
    if method == "ipm":
        forward = functools.partial(_ipm_forward, settings)
    else:
        forward = functools.partial(_admm_forward, settings, polish, active_tol)

    @jax.custom_jvp
    def solve(P, q, A, l, u):
        return forward(P, q, A, l, u)

    @solve.defjvp
    def solve_jvp(primals, tangents):
        P, q, A, l, u = primals
        dP, dq, dA, dl, du = tangents
        x, y, status = forward(P, q, A, l, u)
        x, y = lax.stop_gradient(x), lax.stop_gradient(y)
        dt = x.dtype
        P, A, l, u = (v.astype(dt) for v in (P, A, l, u))
        dP, dq, dA, dl, du = (v.astype(dt) for v in (dP, dq, dA, dl, du))
        # active: multiplier above τ and the row at its bound to the solver's accuracy
        slack_tol = 10.0 * (eps_abs + eps_rel * jnp.max(jnp.abs(A @ x), initial=0.0))
        act = _active_set(y, l, u, active_tol, A, x, slack_tol)
        kkt = _kkt_solver(0.5 * (P + P.T), A, act)
        dPs = 0.5 * (dP + dP.T)
        r1 = -(dPs @ x + dq + dA.T @ y)
        # infinite bounds carry no tangent (their weights are 0; keep inf·0 out of the product)
        dlf = jnp.where(jnp.isfinite(l), dl, 0.0)
        duf = jnp.where(jnp.isfinite(u), du, 0.0)
        r2 = act.wl * dlf + act.wu * duf - act.a * (dA @ x)
        # NaN derivatives for a QP that is not solved (products on both sides of the solve, so
        # reverse mode inherits it in every entry)
        bad = jnp.where(status == STATUS_CODES.SOLVED, 1.0, jnp.nan).astype(dt)
        dx, dy = kkt(bad * r1, bad * r2)
        dx, dy = bad * dx, bad * dy
        dstatus = np.zeros(np.shape(status), dtype=jax.dtypes.float0)
        return (x, y, status), (dx, dy, dstatus)

    return solve


def _settings(method: str, settings: dict[str, Any]):
    """The validated settings object of ``method`` and the polish flag."""
    if method == "ipm":
        from .ipm import IPMSettings

        for bad in ("linear_solver", "chunk_size"):
            if bad in settings:
                raise ValueError(
                    f"{bad} is not a setting of solvers.jax.solve_qp (one dense QP per call)"
                )
        # the floored start unless asked otherwise: on a weakly active row (its multiplier
        # tending to 0 at its bound) the shifted start's final iterate at the default tolerance
        # can leave the multiplier above the activity threshold of the derivative
        kw = {"shifted_start": False, **settings}
        return IPMSettings.from_kwargs(**kw).replace(chunk_size=None), False
    from .admm.core import ADMMSettings

    for bad in ("stage_iter", "fallback"):
        if settings.get(bad) is not None:
            raise ValueError(f"{bad} runs on the host: not available in solvers.jax.solve_qp")
    kw = dict(settings)
    kw.setdefault("dtype", "float64" if jax.config.jax_enable_x64 else "float32")
    s = ADMMSettings.from_kwargs(**kw)
    return s, bool(s.polish)


def _check_shapes(P, q, A, l, u) -> None:
    shapes = {k: np.shape(v) for k, v in zip("PqAlu", (P, q, A, l, u), strict=True)}
    if len(shapes["q"]) != 1 or shapes["q"][0] == 0:
        raise ValueError(f"q must be a non-empty 1-D array, got shape {shapes['q']}")
    n = shapes["q"][0]
    if shapes["P"] != (n, n):
        raise ValueError(f"P must have shape ({n}, {n}), got {shapes['P']}")
    if len(shapes["A"]) != 2 or shapes["A"][1] != n:
        raise ValueError(f"A must have shape (m, {n}), got {shapes['A']}")
    m = shapes["A"][0]
    for k in "lu":
        if shapes[k] != (m,):
            raise ValueError(f"{k} must have shape ({m},), got {shapes[k]}")


def solve_qp(
    P: Any,
    q: Any,
    A: Any,
    l: Any,
    u: Any,
    *,
    method: str = "ipm",
    active_tol: float = 1e-6,
    **settings: Any,
) -> QPSolution:
    """Solve ``min ½xᵀPx + qᵀx  s.t.  l ≤ Ax ≤ u`` in JAX, differentiably (see the module
    docstring for the solvers, the derivative and its conventions).

    Parameters
    ----------
    P : (n, n) symmetric positive semidefinite (dense).
    q : (n,)
    A : (m, n) dense; ``m`` may be 0.
    l, u : (m,), ``±inf`` allowed; ``l == u`` is an equality.
    method : ``"ipm"`` (needs x64 mode) or ``"admm"``.
    active_tol : relative threshold ``τ`` on ``|y_i|`` that makes a row active in the derivative.
    **settings : the method's settings (:class:`solvers.ipm.IPMSettings`,
        :class:`solvers.admm.ADMMSettings` fields); unknown names raise ``ValueError``.

    Returns
    -------
    QPSolution
        ``(x, y, status)``; jittable (settings are static), vmappable over every argument.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if isinstance(active_tol, bool) or not (
        isinstance(active_tol, (int, float, np.floating)) and 0.0 <= active_tol < 1.0
    ):
        raise ValueError(f"active_tol must be a number in [0, 1), got {active_tol!r}")
    _check_shapes(P, q, A, l, u)
    s, polish = _settings(method, settings)
    if method == "ipm" and not jax.config.jax_enable_x64:
        raise RuntimeError(
            "solve_qp(method='ipm') computes in float64: call it (and trace your jit) inside "
            "`with jax.enable_x64(True):`, or use method='admm'"
        )
    dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    P, q, A, l, u = (jnp.asarray(v, dt) for v in (P, q, A, l, u))
    x, y, status = _solver(method, s, polish, float(active_tol))(P, q, A, l, u)
    return QPSolution(x, y, status)
