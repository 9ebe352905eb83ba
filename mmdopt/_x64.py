"""Local float64 for the method's public entry points (no process-wide JAX flag).

``import mmdopt`` leaves ``jax_enable_x64`` as it found it.  The reduced-set weights, the kernel
Gram matrices and the MMD diagnostics are compared at magnitudes below float32 resolution, so the
public functions that compute them run inside ``jax.enable_x64(True)`` (a no-op when x64 is
already on, e.g. when called from another public function).  The CEM loop itself runs at
``MMDOptConfig.dtype`` (float32 by default) with explicit casts.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ParamSpec, TypeVar

import jax

P = ParamSpec("P")
R = TypeVar("R")

__all__ = ["x64"]


def x64(fn: Callable[P, R]) -> Callable[P, R]:
    """Run ``fn`` with JAX's x64 mode on for the duration of the call."""

    @functools.wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        if jax.config.read("jax_enable_x64"):
            return fn(*args, **kwargs)
        with jax.enable_x64(True):
            return fn(*args, **kwargs)

    # a wrapped jitted function keeps its jit API (cache inspection, lowering)
    for attr in ("_cache_size", "lower", "trace", "clear_cache"):
        if hasattr(fn, attr):
            setattr(wrapper, attr, getattr(fn, attr))
    return wrapper
