"""Solution types and the status enum shared by every backend."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np

__all__ = ["Status", "Solution", "BatchSolution"]


class Status(IntEnum):
    """Outcome of a QP solve.  Integer codes so a batch can hold them in an array."""

    SOLVED = 1
    SOLVED_INACCURATE = 2
    MAX_ITER = 3
    PRIMAL_INFEASIBLE = 4
    DUAL_INFEASIBLE = 5
    ERROR = 6

    @property
    def ok(self) -> bool:
        """True for ``SOLVED`` only."""
        return self is Status.SOLVED


@dataclass(frozen=True, eq=False)
class Solution:
    """Result of one QP solve.

    ``x`` is always returned (the last iterate when not solved; NaN only when the backend gave
    nothing).  ``y`` follows OSQP's sign convention: ``Px + q + Aᵀy = 0`` at the optimum, ``y ≥ 0``
    on active upper bounds and ``y ≤ 0`` on active lower bounds.
    """

    x: np.ndarray
    y: np.ndarray
    status: Status
    objective: float
    iterations: int
    solve_time: float
    primal_residual: float
    dual_residual: float
    backend: str
    settings: dict[str, Any] = field(default_factory=dict)
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status is Status.SOLVED


@dataclass(frozen=True, eq=False)
class BatchSolution:
    """Result of a batch solve: every field of :class:`Solution` with a leading batch axis.

    ``status`` is an int array of :class:`Status` codes; ``solve_time`` is per problem and
    ``total_time`` the wall time of the whole batch call.
    """

    x: np.ndarray  # (B, n)
    y: np.ndarray  # (B, m)
    status: np.ndarray  # (B,) int codes of Status
    objective: np.ndarray  # (B,)
    iterations: np.ndarray  # (B,)
    solve_time: np.ndarray  # (B,) seconds per problem (batch wall time / B for batched backends)
    primal_residual: np.ndarray  # (B,)
    dual_residual: np.ndarray  # (B,)
    backend: str
    total_time: float = float("nan")
    settings: dict[str, Any] = field(default_factory=dict)
    extras: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return self.x.shape[0]

    def __getitem__(self, i: int) -> Solution:
        return Solution(
            x=self.x[i],
            y=self.y[i],
            status=Status(int(self.status[i])),
            objective=float(self.objective[i]),
            iterations=int(self.iterations[i]),
            solve_time=float(self.solve_time[i]),
            primal_residual=float(self.primal_residual[i]),
            dual_residual=float(self.dual_residual[i]),
            backend=self.backend,
            settings=self.settings,
        )

    @property
    def solved(self) -> np.ndarray:
        """Boolean mask of problems with status ``SOLVED``."""
        return self.status == int(Status.SOLVED)

    @property
    def n_solved(self) -> int:
        return int(self.solved.sum())

    @property
    def all_solved(self) -> bool:
        return bool(self.solved.all())

    def status_counts(self) -> dict[str, int]:
        """``{status name: count}`` for the statuses present."""
        vals, counts = np.unique(self.status, return_counts=True)
        return {Status(int(v)).name: int(c) for v, c in zip(vals, counts, strict=True)}

    @classmethod
    def stack(
        cls,
        sols: list[Solution],
        backend: str,
        total_time: float,
        settings: dict[str, Any] | None = None,
        extras: dict[str, Any] | None = None,
    ) -> BatchSolution:
        """Stack per-problem solutions (used by backends that loop)."""
        return cls(
            x=np.stack([s.x for s in sols]),
            y=np.stack([s.y for s in sols]),
            status=np.array([int(s.status) for s in sols], dtype=np.int32),
            objective=np.array([s.objective for s in sols]),
            iterations=np.array([s.iterations for s in sols], dtype=np.int64),
            solve_time=np.array([s.solve_time for s in sols]),
            primal_residual=np.array([s.primal_residual for s in sols]),
            dual_residual=np.array([s.dual_residual for s in sols]),
            backend=backend,
            total_time=total_time,
            settings=settings if settings is not None else (sols[0].settings if sols else {}),
            extras=extras or {},
        )
