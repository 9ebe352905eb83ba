"""The common settings vocabulary shared by every backend, and its translation to native names.

Six names mean the same on every backend::

    eps_abs, eps_rel   termination tolerances (absolute, relative)
    max_iter           iteration limit
    time_limit         wall-clock limit in seconds
    warm_start         a previous Solution, or a tuple (x, y) of arrays (y may be None)
    verbose            solver output on/off (off by default everywhere)

Each backend maps them onto its solver's own names (:class:`SettingsSpec`; the table is in the
README).  A common name a backend cannot honour (``time_limit`` on quadprog, ``warm_start`` on an
interior-point method) is recorded on the solution as ``"ignored"``, never an error.  Native names
still pass through; where a common name and one of its native names are both given, the native
one wins.  Any other name raises :class:`~solvers.errors.InvalidSettingError` listing the valid
names, on every backend.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import InvalidSettingError

__all__ = [
    "COMMON_SETTINGS",
    "IGNORED",
    "SettingsSpec",
    "WarmStart",
    "as_warm_start",
    "translate",
]

#: the common vocabulary (``warm_start`` is a keyword of ``solve`` itself, see :class:`WarmStart`)
COMMON_SETTINGS: tuple[str, ...] = (
    "eps_abs",
    "eps_rel",
    "max_iter",
    "time_limit",
    "warm_start",
    "verbose",
)
#: what the recorded settings say for a common setting the backend cannot honour
IGNORED = "ignored"

#: OSQP's own setting names (osqp 1.x): the native ``osqp`` backend and qpsolvers' ``osqp``
#: both pass them through (kept here, free of the ``osqp`` import, for both)
OSQP_NATIVE = frozenset(
    {
        "adaptive_rho",
        "adaptive_rho_fraction",
        "adaptive_rho_interval",
        "adaptive_rho_tolerance",
        "alpha",
        "cg_max_iter",
        "cg_precond",
        "cg_tol_fraction",
        "cg_tol_reduction",
        "check_dualgap",
        "check_termination",
        "delta",
        "device",
        "eps_abs",
        "eps_dual_inf",
        "eps_prim_inf",
        "eps_rel",
        "linsys_solver",
        "max_iter",
        "polish_refine_iter",
        "polishing",
        "rho",
        "rho_is_vec",
        "scaled_termination",
        "scaling",
        "sigma",
        "time_limit",
        "verbose",
        "warm_starting",
    }
)


@dataclass(frozen=True)
class SettingsSpec:
    """How one backend reads the common vocabulary.

    ``common`` maps a common name to the native names it sets (empty: not honoured, recorded as
    ignored).  ``native`` is the set of native names the backend accepts (``None``: not checked,
    everything passes through).  ``tolerance`` names the native ``(absolute, relative)`` primal
    tolerance keys and their defaults: the *stated* tolerance used by the residual check.
    """

    backend: str
    common: Mapping[str, tuple[str, ...]]
    native: frozenset[str] | None
    warm_start: bool = False
    tolerance: tuple[str | None, str | None] = (None, None)
    tolerance_defaults: tuple[float, float] = (1e-6, 1e-6)
    #: conversions of a common value for a native key (e.g. seconds -> int milliseconds)
    convert: Mapping[str, Any] = field(default_factory=dict)

    def valid_names(self) -> list[str]:
        return sorted(set(COMMON_SETTINGS) | set(self.native or ()))

    def stated_tolerance(self, used: Mapping[str, Any]) -> tuple[float, float]:
        """``(eps_abs, eps_rel)`` in effect for a solve whose native settings were ``used``."""
        out = []
        for key, default in zip(self.tolerance, self.tolerance_defaults, strict=True):
            v = used.get(key, default) if key else default
            try:
                out.append(float(v))
            except (TypeError, ValueError):
                out.append(default)
        return out[0], out[1]


def _check_common_value(key: str, value: Any) -> Any:
    """Validate the value of a common setting; returns it normalised."""
    if key in ("eps_abs", "eps_rel"):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
            raise InvalidSettingError(f"{key} must be a real number ≥ 0, got {value!r}")
        v = float(value)
        if not math.isfinite(v) or v < 0:
            raise InvalidSettingError(f"{key} must be a finite number ≥ 0, got {value!r}")
        return v
    if key == "max_iter":
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise InvalidSettingError(f"max_iter must be a positive integer, got {value!r}")
        return int(value)
    if key == "time_limit":
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
            raise InvalidSettingError(f"time_limit must be seconds > 0, got {value!r}")
        v = float(value)
        if math.isnan(v) or v <= 0:
            raise InvalidSettingError(f"time_limit must be seconds > 0, got {value!r}")
        return v
    if key == "verbose":
        if not isinstance(value, (bool, np.bool_)):
            raise InvalidSettingError(f"verbose must be True or False, got {value!r}")
        return bool(value)
    return value


def translate(spec: SettingsSpec, settings: Mapping[str, Any]) -> tuple[dict[str, Any], dict]:
    """Split ``settings`` into ``(native, record)`` for ``spec``'s backend.

    ``native``: the keyword arguments for the native solver.  ``record``: what to add to the
    solution's recorded settings for the common names given (their value, or ``"ignored"``).
    ``warm_start`` must not be in ``settings`` (it is a keyword of ``solve``).
    """
    native: dict[str, Any] = {}
    record: dict[str, Any] = {}
    explicit = {k: v for k, v in settings.items() if k not in spec.common}
    for key in explicit:
        if key in COMMON_SETTINGS:  # a common name the spec does not list: not honoured
            continue
        if spec.native is not None and key not in spec.native:
            raise InvalidSettingError(
                f"unknown setting {key!r} for backend {spec.backend!r}; valid names: "
                f"{', '.join(spec.valid_names())}"
            )
    for key, value in settings.items():
        if key == "warm_start":
            raise InvalidSettingError("warm_start is a keyword of solve(), not a solver setting")
        if key in COMMON_SETTINGS:
            value = _check_common_value(key, value)
            targets = spec.common.get(key, ())
            if not targets:
                record[key] = IGNORED
                continue
            record[key] = value
            for t in targets:
                if t not in explicit:  # a native name given explicitly wins
                    conv = spec.convert.get(t)
                    native[t] = conv(value) if conv else value
        else:
            native[key] = value
    return native, record


@dataclass(frozen=True, eq=False)
class WarmStart:
    """A warm start ``(x, y)``: one problem (``x (n,)``, ``y (m,)``) or a batch (``(B, n)``,
    ``(B, m)``).  ``y`` defaults to zeros.  Anything with ``.x``/``.y`` (a :class:`Solution`) can
    stand in for it in a backend."""

    x: np.ndarray
    y: np.ndarray

    def __len__(self) -> int:
        return self.x.shape[0]

    def __getitem__(self, i: int) -> WarmStart:
        return WarmStart(self.x[i], self.y[i])


def as_warm_start(ws: Any, n: int, m: int, batch: int | None = None) -> WarmStart | None:
    """Validate a warm start given as a Solution/BatchSolution/WarmStart or a tuple ``(x, y)``."""
    if ws is None:
        return None
    if isinstance(ws, tuple):
        if len(ws) != 2:
            raise ValueError(f"warm_start as a tuple must be (x, y), got {len(ws)} items")
        x, y = ws
    elif hasattr(ws, "x") and hasattr(ws, "y"):
        x, y = ws.x, ws.y
    else:
        raise ValueError(
            "warm_start must be a Solution (BatchSolution for a batch) or a tuple (x, y) of "
            f"arrays, got {type(ws).__name__}"
        )
    shape_x = (n,) if batch is None else (batch, n)
    shape_y = (m,) if batch is None else (batch, m)
    from .problem import real_array

    x = real_array(x, "warm_start x")
    y = np.zeros(shape_y) if y is None else real_array(y, "warm_start y")
    if x.shape != shape_x:
        raise ValueError(f"warm_start x has shape {x.shape}, expected {shape_x}")
    if y.shape != shape_y:
        raise ValueError(f"warm_start y has shape {y.shape}, expected {shape_y}")
    return WarmStart(x, y)
