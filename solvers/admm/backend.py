"""The registry's ``admm`` backend: batched, jitted ADMM in JAX for QPs sharing ``P`` and ``A``.

Meant for small dense shared matrices (``n`` up to a few hundred; a warning is given above
``n = 2000``): ``P`` and ``A`` are densified, and the batch of ``q, l, u`` is solved with batched
matrix products (:mod:`solvers.admm.core`), on GPU when JAX has one, on CPU otherwise.

* Iterations run in ``dtype`` (float32 by default) under a fixed budget ``max_iter``, in stages
  of ``stage_iter`` (200 by default); converged, infeasible or broken QPs are frozen by a per-QP
  mask, so a slow QP never holds the batch, and later stages run only the QPs still going.
* Between stages (``polish=True``) a batched active-set polish in float64 NumPy
  (:mod:`solvers.admm.polish`), on the QPs whose guessed active set has settled, accepting only
  an exact point; after the last stage, and for QPs the iterations declare solved, the full
  polish.  A polished point replaces the ADMM iterate only where it passes the same termination
  test (with its duals projected onto the normal cone) and is no worse.  A QP still going every
  ``rho_patience`` iterations tries another step size (:class:`~solvers.admm.PolishSettings`).
* Optional, visible and counted: ``fallback="clarabel"`` re-solves the QPs still not solved.
* Infeasibility claims are re-checked in float64 on the unscaled data (OSQP's certificates on
  the last ``δx``/``δy``); a claim that does not hold becomes ``MAX_ITER`` (then the fallback,
  if asked for, gets it).
* Before any status is reported, a final float64 check on the returned point (never on the
  float32 iterate): ``SOLVED`` needs OSQP's unscaled test with its duality gap (OSQP 1.x's
  ``check_dualgap``; the iterations test the primal and dual residuals only, the float64 check
  and the polish add the gap: ``SOLVED`` meets ``Solution.is_optimal(eps_abs, eps_rel)``)
  **and** the primal residual within
  ``eps_abs + eps_rel·max(1, ‖finite l, u‖∞)`` (an absolute floor that the size of a diverging
  iterate cannot loosen); a point with ``‖x‖∞`` beyond :data:`DIVERGED` times the data's scale
  that no certificate explains is ``ERROR`` ("iterates diverged").

Statuses (per QP, :class:`solvers.Status` codes): ``SOLVED`` as above, ``PRIMAL_INFEASIBLE`` /
``DUAL_INFEASIBLE`` from OSQP's certificates, ``MAX_ITER`` when the budget ran out,
``SOLVED_INACCURATE`` where only the iteration dtype (or only OSQP's relative test) met the
tolerance, ``ERROR`` on NaN or divergence.

Use::

    from solvers import solve_batch
    sol = solve_batch(batch, backend="admm", eps_abs=1e-5, polish=True, warm_start=prev)

Settings are the names of :meth:`~solvers.admm.ADMMSettings.names` plus the common names
(``time_limit`` and ``verbose`` are recorded as ignored); unknown names raise
:class:`~solvers.errors.InvalidSettingError`.  ``sol.extras`` holds the polish counts, the
fallback count, timings and the per-QP final ``rho``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
import warnings
from typing import Any

import jax
import numpy as np

from ..base import Backend, primal_tolerance
from ..cache import BoundedCache
from ..problem import QP, QPBatch
from ..settings import SettingsSpec, WarmStart
from ..solution import STATUS_CODES, BatchSolution, Solution, Status
from .core import (
    ADMMFactor,
    ADMMSettings,
    admm_factor,
    admm_iterate_jit,
    flops_per_call,
    rows_from_bounds,
)
from .polish import PolishData, active_guess, polish, polish_data, termination

__all__ = ["ADMMBackend", "DENSE_N_WARN", "DIVERGED", "make_backend"]

#: above this many variables the dense path warns (it stores (n, n) inverses per rung)
DENSE_N_WARN = 2000
#: ``‖x‖∞`` beyond this times ``max(1, ‖q‖∞, ‖finite l, u‖∞)``, with no certificate: diverged
DIVERGED = 1e8
#: factors (scaling, ladder of inverses, polish data) an :class:`ADMMBackend` keeps, oldest first
FACTOR_CACHE_SIZE = 16
#: a later stage's batch is padded to a power of two, at least this many: every new size
#: compiles the iterations again, and below it a smaller batch saves little time on a CPU
MIN_STAGE_BATCH = 16


#: the common vocabulary: ADMMSettings uses the common names; time_limit and verbose are ignored
SPEC = SettingsSpec(
    backend="admm",
    common={"eps_abs": ("eps_abs",), "eps_rel": ("eps_rel",), "max_iter": ("max_iter",)},
    native=frozenset(ADMMSettings.names()),
    warm_start=True,
    tolerance=("eps_abs", "eps_rel"),
    tolerance_defaults=(ADMMSettings.eps_abs, ADMMSettings.eps_rel),
)


class ADMMBackend(Backend):
    """Batched ADMM backend (see the module docstring)."""

    name = "admm"
    detects_infeasibility = True
    honours_warm_start = True

    def settings_spec(self, settings: dict[str, Any] | None = None) -> SettingsSpec:
        return SPEC

    def __init__(self) -> None:
        # one factor (and its polish data) per (P, A, row masks, settings): see solvers.cache
        self._factors: BoundedCache[tuple, tuple[ADMMFactor, PolishData | None]] = BoundedCache(
            FACTOR_CACHE_SIZE
        )

    def clear_cache(self) -> None:
        """Forget the cached factors (the next batch recomputes its scaling and inverses)."""
        self._factors.clear()

    # -- caching of the host-side precomputation per (P, A, row masks, settings)
    def _factor(self, P, A, eq, free, s: ADMMSettings, need_polish: bool):
        h = hashlib.blake2b(digest_size=16)
        for arr in (P, A, eq, free):
            h.update(np.ascontiguousarray(arr).tobytes())
            h.update(str(arr.shape).encode())
        key_s = s.replace(polish=False, fallback=None, eps_abs=0.0, eps_rel=0.0)
        key = (h.hexdigest(), key_s)
        f, pd = self._factors.get_or_create(
            key, lambda: (admm_factor(P, A, key_s, eq_rows=eq, free_rows=free), None)
        )
        if need_polish and pd is None:
            pd = polish_data(P, A, s, f.D, f.E, f.c)
            self._factors[key] = (f, pd)
        # the tolerances are not baked into the factor arrays: swap the settings in
        return dataclasses.replace(f, settings=s.replace(polish=False, fallback=None)), pd

    def solve(self, qp: QP, *, warm_start: Any = None, **settings: Any) -> Solution:
        batch = QPBatch(qp.P, qp.A, qp.q[None], qp.l[None], qp.u[None], check_convex=False)
        ws = None
        if warm_start is not None:
            ws = WarmStart(np.asarray(warm_start.x)[None], np.asarray(warm_start.y)[None])
        sol = self.solve_batch(batch, warm_start=ws, **settings)
        out = sol[0]
        return dataclasses.replace(out, extras=dict(sol.extras))

    def solve_batch(
        self, batch: QPBatch, *, warm_start: Any = None, **settings: Any
    ) -> BatchSolution:
        native, record = self.native_settings(settings)
        s = ADMMSettings.from_kwargs(**native)
        if s.dtype == "float64":
            with jax.enable_x64(True):
                sol = self._solve_batch(batch, warm_start, s)
        else:
            sol = self._solve_batch(batch, warm_start, s)
        sol.settings.update(record)
        return sol

    def _solve_batch(self, batch: QPBatch, warm_start, s: ADMMSettings) -> BatchSolution:
        t0 = time.perf_counter()
        P, A = batch.dense()
        P = np.asarray(P, np.float64)
        A = np.asarray(A, np.float64).reshape(batch.m, batch.n)
        if batch.n > DENSE_N_WARN:
            warnings.warn(
                f"admm densifies P and A and stores (n, n) inverses per rho rung; n = {batch.n} "
                f"is above {DENSE_N_WARN}: expect large memory use; a sparse backend (osqp, "
                "clarabel) is likely better",
                stacklevel=3,
            )
        eq, free = rows_from_bounds(batch.l, batch.u)
        factor, pd = self._factor(P, A, eq, free, s, s.polish)
        t_factor = time.perf_counter() - t0
        run = _Run.start(batch, warm_start, s)
        stage = s.max_iter if s.stage_iter is None else max(s.check_every, int(s.stage_iter))
        todo = np.arange(len(batch))
        done_iter = 0
        first = True
        while todo.size and (first or done_iter < s.max_iter):
            first = False
            k = min(stage, s.max_iter - done_iter)
            last = done_iter + k >= s.max_iter
            todo = _run_stage(run, factor, pd, P, A, batch, todo, k, s, last)
            done_iter += k
        extras = run.extras(t_factor, s)
        rejected = _recheck_certificates(batch, P, A, run.status, run.dx, run.dy, s)
        run.status[rejected] = STATUS_CODES.MAX_ITER
        extras["certificate_rejected"] = rejected
        fb = 0
        if s.fallback == "clarabel":
            extras["fallback_attempted"], fb = _clarabel_fallback(batch, run)
        extras["fallback_count"] = fb
        return _batch_solution(self.name, batch, run, s, extras, t0)


@dataclasses.dataclass(eq=False)
class _Run:
    """Per-QP results and counters of :meth:`ADMMBackend._solve_batch`, updated stage by stage
    (``B`` QPs of ``n`` variables and ``m`` rows; unscaled, OSQP sign convention)."""

    x: np.ndarray  # (B, n)
    y: np.ndarray  # (B, m)
    z: np.ndarray  # (B, m)
    dx: np.ndarray  # (B, n) the last δx (dual infeasibility certificate)
    dy: np.ndarray  # (B, m) the last δy (primal infeasibility certificate)
    rho: np.ndarray  # (B,) each QP's final rho
    status: np.ndarray  # (B,) int32, after the float64 re-check and the polish
    admm_status: np.ndarray  # (B,) int32, as the iterations left it
    iters: np.ndarray  # (B,) iterations each QP ran
    polished: np.ndarray  # (B,) bool, the polished point was accepted
    guess: np.ndarray | None = None  # (B, m) int8, the polish's active-set guess at the last stage
    moves: np.ndarray | None = None  # (B,) rho moves of each QP (:func:`_patient_rho`)
    side: np.ndarray | None = None  # (B,) ±1, the side of its first move
    t_iter: float = 0.0
    t_pol: float = 0.0
    flops: float = 0.0
    rung_mm: int = 0
    iters_run: int = 0
    attempted: int = 0

    @classmethod
    def start(cls, batch: QPBatch, warm_start, s: ADMMSettings) -> _Run:
        B, n, m = len(batch), batch.n, batch.m
        x = np.zeros((B, n))
        y = np.zeros((B, m))
        if warm_start is not None:
            x = np.nan_to_num(np.asarray(warm_start.x, float), nan=0.0, posinf=0.0, neginf=0.0)
            y = np.nan_to_num(np.asarray(warm_start.y, float), nan=0.0, posinf=0.0, neginf=0.0)
        status = np.full(B, STATUS_CODES.MAX_ITER, np.int32)
        return cls(
            x=x,
            y=y,
            z=np.zeros((B, m)),
            dx=np.zeros((B, n)),
            dy=np.zeros((B, m)),
            rho=np.full(B, s.rho),
            status=status,
            admm_status=status.copy(),
            iters=np.zeros(B, np.int64),
            polished=np.zeros(B, bool),
        )

    def extras(self, t_factor: float, s: ADMMSettings) -> dict[str, Any]:
        """The solution's extras so far: status counts, work, timings, polish counts."""
        extras: dict[str, Any] = {
            "admm_status_counts": _counts(self.admm_status),
            "iterations_run": self.iters_run,
            "rung_matmuls": self.rung_mm,
            "flops": self.flops,
            "rho": self.rho,
            "time_factor": t_factor,
            "time_iterations": self.t_iter,
            "time_polish": self.t_pol,
            "polished": self.polished,
        }
        if s.polish:
            extras["polish_attempted"] = self.attempted
            extras["polish_accepted"] = int(self.polished.sum())
        return extras


def _run_stage(
    run: _Run, factor, pd, P, A, batch: QPBatch, todo, k: int, s: ADMMSettings, last: bool
):
    """One stage: ``k`` ADMM iterations on the QPs ``todo`` (a batch padded to a power of two,
    at least :data:`MIN_STAGE_BATCH`, unless it is the whole batch), the float64 re-check of
    what they declared solved, then the polish.  Updates ``run``; returns the QPs that go on
    (out of iterations and not polished)."""
    q, l, u = batch.q, batch.l, batch.u
    B, n, m = len(batch), batch.n, batch.m
    Bs = (
        todo.size
        if todo.size == B
        else min(B, max(MIN_STAGE_BATCH, 1 << (todo.size - 1).bit_length()))
    )
    sub = np.concatenate([todo, np.repeat(todo[:1], Bs - todo.size)])  # padded
    t1 = time.perf_counter()
    st = admm_iterate_jit(
        factor, q[sub], l[sub], u[sub], run.x[sub], run.y[sub], iters=k, rho0=run.rho[sub]
    )
    st = jax.tree_util.tree_map(np.asarray, st)
    run.t_iter += time.perf_counter() - t1
    r = slice(0, todo.size)
    run.x[todo] = st.x[r]
    run.y[todo] = st.y[r]
    run.z[todo] = st.z[r]
    run.dx[todo], run.dy[todo] = st.delta_x[r], st.delta_y[r]
    run.rho[todo] = st.rho[r]
    run.iters[todo] += st.iterations[r]
    stt = st.status[r].astype(np.int32)
    run.admm_status[todo] = stt
    run.status[todo] = stt
    it_s = int(st.iterations.max(initial=0))
    run.iters_run += it_s
    run.rung_mm += int(st.rung_matmuls)
    run.flops += flops_per_call(n, m, Bs, it_s, int(st.rung_matmuls), s.check_every)
    # float64 re-check of what the iteration dtype declared solved
    ok64, *_ = termination(P, A, q[todo], l[todo], u[todo], run.x[todo], run.y[todo], s)
    run.status[todo[(stt == STATUS_CODES.SOLVED) & ~ok64]] = STATUS_CODES.SOLVED_INACCURATE
    t2 = time.perf_counter()
    if s.polish:
        cand = todo[
            ~np.isin(
                stt,
                (STATUS_CODES.PRIMAL_INFEASIBLE, STATUS_CODES.DUAL_INFEASIBLE, STATUS_CODES.ERROR),
            )
        ]
        # QPs that stop here (the last stage, or solved by the iterations) get the full polish,
        # which keeps a point within the tolerance; the others only where their active-set guess
        # has settled, with a few passes, and only an exact point (else the iterations go on)
        final = np.full(todo.size, last) | (stt == STATUS_CODES.SOLVED)
        if not last:
            g = active_guess(pd, l[todo], u[todo], run.z[todo], run.y[todo])
            if run.guess is None:
                run.guess = np.zeros((B, m), np.int8)
                moved = np.full(todo.size, m + 1)
            else:
                moved = np.sum(g != run.guess[todo], axis=1)
            run.guess[todo] = g
            settled = todo[(moved <= s.polish_settle_rows) & ~final]
        else:
            settled = todo[:0]
        for ids_, passes, exact in (
            (np.intersect1d(cand, todo[final]), None, False),
            (np.intersect1d(cand, settled), s.polish_stage_passes, True),
        ):
            if ids_.size:
                _polish_into(run, pd, P, A, q, l, u, ids_, s, passes, exact)
    run.t_pol += time.perf_counter() - t2
    # only QPs that ran out of iterations and were not polished go on
    go = todo[(stt == STATUS_CODES.MAX_ITER) & ~run.polished[todo]]
    if s.rho_patience is not None and not s.adaptive_rho and go.size and not last:
        _patient_rho(run, P, A, q, l, u, go, k, s)
    return go


def _polish_into(run: _Run, pd, P, A, q, l, u, ids, s: ADMMSettings, passes, exact) -> None:
    """Polish the QPs ``ids``; where a polished point is accepted it replaces the iterate."""
    acc, xp, yp, _, _ = polish(
        pd, P, A, q[ids], l[ids], u[ids], run.x[ids], run.z[ids], run.y[ids], s, passes, exact
    )
    done = ids[acc]
    run.x[done], run.y[done] = xp[acc], yp[acc]
    run.status[done] = STATUS_CODES.SOLVED
    run.polished[done] = True
    run.attempted += int(ids.size)


def _patient_rho(run: _Run, P, A, q, l, u, go: np.ndarray, k: int, s: ADMMSettings) -> None:
    """Each time a QP that goes on passes another ``rho_patience`` iterations, it tries another
    rung around its start: first the neighbour that OSQP's residual-balancing rule points to (up
    when the primal residual, relative to its tolerance, is the larger; Stellato et al. 2020,
    §5.2), then the other neighbour, then two rungs away on the first side, and so on.  The rule
    alone is not enough: on projections with most rows active it points down where a larger step
    finds the active set sooner."""
    it = run.iters[go]
    due = go[(it // s.rho_patience) > ((it - k) // s.rho_patience)]
    if not due.size:
        return
    if run.moves is None:
        run.moves = np.zeros(run.x.shape[0], np.int64)
        run.side = np.zeros(run.x.shape[0], np.int64)
    first = due[run.moves[due] == 0]
    if first.size:
        _, prim, dual, eps_p, eps_d = termination(
            P, A, q[first], l[first], u[first], run.x[first], run.y[first], s
        )
        run.side[first] = np.where(prim / eps_p >= dual / eps_d, 1, -1)
    run.moves[due] += 1
    j = run.moves[due]
    offset = run.side[due] * np.where(j % 2 == 1, 1, -1) * ((j + 1) // 2)
    lad = np.asarray(s.rho_ladder)
    start = int(np.argmin(np.abs(np.log(lad) - np.log(s.rho))))
    run.rho[due] = lad[np.clip(start + offset, 0, lad.size - 1)]


def _clarabel_fallback(batch: QPBatch, run: _Run) -> tuple[int, int]:
    """Re-solve with Clarabel every QP neither solved nor certified infeasible; keep the answers
    Clarabel solves or certifies.  Returns ``(attempted, replaced)``."""
    from ..clarabel_ import ClarabelBackend

    need = np.flatnonzero(
        ~np.isin(
            run.status,
            (STATUS_CODES.SOLVED, STATUS_CODES.PRIMAL_INFEASIBLE, STATUS_CODES.DUAL_INFEASIBLE),
        )
    )
    cb = ClarabelBackend()
    fb = 0
    for i in need:
        r = cb.solve(batch[i])
        if r.status in (Status.SOLVED, Status.PRIMAL_INFEASIBLE, Status.DUAL_INFEASIBLE):
            run.x[i], run.y[i], run.status[i] = r.x, r.y, int(r.status)
            fb += 1
    return int(need.size), fb


def _batch_solution(
    name: str, batch: QPBatch, run: _Run, s: ADMMSettings, extras: dict[str, Any], t0: float
) -> BatchSolution:
    """The :class:`BatchSolution`: residuals on the returned points, the final status check."""
    x, y, status = run.x, run.y, run.status
    total = time.perf_counter() - t0
    finite = np.all(np.isfinite(x), axis=1)
    status[~finite] = STATUS_CODES.ERROR
    xs = np.where(finite[:, None], x, 0.0)
    obj = np.where(finite, batch.objective(xs), np.nan)
    prim = np.where(finite, batch.constraint_violation(xs), np.nan)
    status, diverged, floor_failed = _final_check(batch, xs, prim, status, s)
    extras["diverged"] = diverged
    extras["floor_failed"] = floor_failed
    yfin = np.all(np.isfinite(y), axis=1)
    dual = np.where(finite & yfin, batch.dual_residual(xs, np.where(yfin[:, None], y, 0.0)), np.nan)
    B = len(batch)
    return BatchSolution(
        x=x,
        y=y,
        status=status,
        objective=obj,
        iterations=run.iters,
        solve_time=np.full(B, total / B),
        primal_residual=prim,
        dual_residual=dual,
        backend=name,
        total_time=total,
        settings=s.as_dict(),
        extras=extras,
    )


def _recheck_certificates(batch: QPBatch, P, A, status, dx, dy, s: ADMMSettings) -> np.ndarray:
    """OSQP's infeasibility certificates again, in float64 on the unscaled data, for every QP the
    iterations declared infeasible (the float32 test ran on the scaled problem).  Returns the mask
    of claims that do not hold (they become ``MAX_ITER``: nothing is certified).
    (Stellato et al. 2020, §3.4: ``‖Aᵀδy‖ ≤ ε‖δy‖, uᵀδy₊ + lᵀδy₋ ≤ −ε‖δy‖`` and ``‖Pδx‖ ≤ ε‖δx‖,
    qᵀδx ≤ −ε‖δx‖, Aδx ∈ recession cone of [l, u] ± ε‖δx‖``.)"""
    l, u, q = batch.l, batch.u, batch.q
    fl, fu = np.isfinite(l), np.isfinite(u)
    rejected = np.zeros(len(batch), bool)
    pinf = status == STATUS_CODES.PRIMAL_INFEASIBLE
    if pinf.any():
        d = dy[pinf]
        d = np.where(fu[pinf], d, np.minimum(d, 0.0))
        d = np.where(fl[pinf], d, np.maximum(d, 0.0))
        nd = np.abs(d).max(axis=1, initial=0.0)
        At = np.abs(d @ A).max(axis=1, initial=0.0)
        supp = np.sum(
            np.where(d > 0, np.where(fu[pinf], u[pinf], 0.0) * d, 0.0)
            + np.where(d < 0, np.where(fl[pinf], l[pinf], 0.0) * d, 0.0),
            axis=1,
        )
        ok = (nd > 0) & (At <= s.eps_prim_inf * nd) & (supp <= -s.eps_prim_inf * nd)
        rejected[np.flatnonzero(pinf)[~ok]] = True
    dinf = status == STATUS_CODES.DUAL_INFEASIBLE
    if dinf.any():
        d = dx[dinf]
        nd = np.abs(d).max(axis=1, initial=0.0)
        Pd = np.abs(d @ P).max(axis=1, initial=0.0)
        qd = np.sum(q[dinf] * d, axis=1)
        Ad = d @ A.T
        tol = s.eps_dual_inf * nd[:, None]
        rows = np.where(fu[dinf], Ad <= tol, True) & np.where(fl[dinf], Ad >= -tol, True)
        ok = (
            (nd > 0)
            & (Pd <= s.eps_dual_inf * nd)
            & (qd <= -s.eps_dual_inf * nd)
            & np.all(rows, axis=1)
        )
        rejected[np.flatnonzero(dinf)[~ok]] = True
    return rejected


def _final_check(
    batch: QPBatch, x: np.ndarray, prim: np.ndarray, status: np.ndarray, s: ADMMSettings
):
    """The last word on each status, in float64 on the point returned (never on the iterate).

    * ``SOLVED`` stays only if the unscaled primal residual is within the absolute floor
      ``eps_abs + eps_rel·max(1, ‖finite l, u‖∞)`` (:func:`solvers.base.primal_tolerance`), which
      a diverging iterate cannot loosen (OSQP's relative test, met with ``‖Ax‖`` blown up, can);
      else ``SOLVED_INACCURATE``.
    * Divergence guard: a point with ``‖x‖∞ > DIVERGED·max(1, ‖q‖∞, ‖finite l, u‖∞)`` that no
      infeasibility certificate explains is ``ERROR``.
    Returns ``(status, diverged mask, floor-failed mask)``.
    """
    status = status.copy()
    tol = primal_tolerance(batch.l, batch.u, s.eps_abs, s.eps_rel)
    solved = status == STATUS_CODES.SOLVED
    with np.errstate(invalid="ignore"):
        floor_failed = solved & ~(prim <= tol)
    status[floor_failed] = STATUS_CODES.SOLVED_INACCURATE
    bounds = np.maximum(
        np.where(np.isfinite(batch.l), np.abs(batch.l), 0.0).max(axis=1, initial=0.0),
        np.where(np.isfinite(batch.u), np.abs(batch.u), 0.0).max(axis=1, initial=0.0),
    )
    data = np.maximum(1.0, np.maximum(np.abs(batch.q).max(axis=1), bounds))
    certified = np.isin(status, (STATUS_CODES.PRIMAL_INFEASIBLE, STATUS_CODES.DUAL_INFEASIBLE))
    diverged = ~certified & (np.abs(x).max(axis=1, initial=0.0) > DIVERGED * data)
    status[diverged] = STATUS_CODES.ERROR
    return status, diverged, floor_failed


def _counts(status: np.ndarray) -> dict[str, int]:
    vals, cnt = np.unique(np.asarray(status), return_counts=True)
    return {Status(int(v)).name: int(c) for v, c in zip(vals, cnt, strict=True)}


def make_backend() -> Backend:
    return ADMMBackend()
