"""The XLA compile options of the package's jitted programs (:func:`jit`, :func:`compile_options`).

On CPU, XLA's MLIR fusion emitters (its default since jax 0.6) spend much of the compile time of
programs full of gathers and scatters, as the batched QP iterations inside Algorithm 1's
sampling loop and the reduced-set selection are.  With them off
(``xla_cpu_use_fusion_emitters = False``) XLA emits those fusions the way it did before: the
planner's first plan compiles in about two thirds of the time, with the same plans (bit for bit
on the planners' tuning scenes) and the same plan time once compiled
(``python -m benchmarks.first_plan --xla-default`` measures both).

Every jitted entry point of :mod:`solvers`, :mod:`frenet` and :mod:`mmdopt` is built with
:func:`jit`, which passes :func:`compile_options` to :func:`jax.jit` where the call is at the
top level and JAX's default backend is the CPU.  Nothing global changes: your own ``jax.jit``
programs keep XLA's defaults, and on a GPU ours do too.  To keep XLA's default on the CPU as
well, set the flag yourself before importing the package (a flag you set wins)::

    XLA_FLAGS=--xla_cpu_use_fusion_emitters=true python my_script.py

The options are passed only with jax and jaxlib ≥ 0.6, the first releases that know them
(older ones would refuse them).  Importing this module imports JAX but starts no backend.
"""

from __future__ import annotations

import functools
import os
import re
from collections.abc import Callable
from typing import Any

import jax
import jaxlib
from jax._src import core as _jax_core  # trace_state_clean: JAX's own top-level test

__all__ = ["FUSION_EMITTERS", "compile_options", "jit"]

#: the XLA debug option this module sets (off) in :func:`compile_options`
FUSION_EMITTERS = "xla_cpu_use_fusion_emitters"
#: the first jax / jaxlib release whose XLA knows :data:`FUSION_EMITTERS`
_FIRST_RELEASE = (0, 6, 0)


def _release(version: str) -> tuple[int, ...]:
    """``"0.10.2"`` → ``(0, 10, 2)``; a pre-release or local suffix is ignored."""
    return tuple(int(m) for m in re.findall(r"\d+", version.split("+")[0])[:3])


def compile_options(
    xla_flags: str | None = None, versions: tuple[str, str] | None = None
) -> dict[str, Any]:
    """The compiler options :func:`jit` passes to :func:`jax.jit`:
    ``{"xla_cpu_use_fusion_emitters": False}``, or ``{}`` where the caller's ``XLA_FLAGS``
    names that option (their choice wins) or where jax or jaxlib predates it.

    ``xla_flags`` (default: the environment's ``XLA_FLAGS``) and ``versions`` (default: the
    installed ``(jax, jaxlib)`` versions) are for tests."""
    flags = os.environ.get("XLA_FLAGS", "") if xla_flags is None else xla_flags
    if not isinstance(flags, str):
        raise ValueError(f"xla_flags must be a str, got {type(flags).__name__}")
    if FUSION_EMITTERS in flags:
        return {}
    jax_v, jaxlib_v = (jax.__version__, jaxlib.__version__) if versions is None else versions
    if min(_release(jax_v), _release(jaxlib_v)) < _FIRST_RELEASE:
        return {}
    return {FUSION_EMITTERS: False}


def _compiles_here() -> bool:
    """Whether a call now is one XLA's CPU compiler compiles with the options: no JAX
    transformation traces the caller (JAX's own test; nested jits take no compile options) and
    JAX's default backend is the CPU.  ``False`` where this JAX lacks the test."""
    clean = getattr(_jax_core, "trace_state_clean", None)
    return clean is not None and bool(clean()) and jax.default_backend() == "cpu"


class _Jit:
    """A function jitted twice: with the compile options where it is called at the top level on
    the CPU, plainly elsewhere (where another jit, vmap or grad traces it, JAX refuses compile
    options on the nested jit and compiles it within the outer program; on another backend)."""

    def __init__(self, fun: Callable, options: dict[str, Any], kwargs: dict[str, Any]):
        self._plain = jax.jit(fun, **kwargs)
        self._top = jax.jit(fun, compiler_options=options, **kwargs)
        functools.update_wrapper(self, fun)

    def _pick(self):
        return self._top if _compiles_here() else self._plain

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self._pick()(*args, **kwargs)

    def lower(self, *args: Any, **kwargs: Any) -> Any:
        return self._pick().lower(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:  # eval_shape, trace, _cache_size, clear_cache…
        if name in ("_top", "_plain"):  # not set yet (copy, unpickling): no recursion
            raise AttributeError(name)
        return getattr(self._top, name)


def jit(fun: Callable | None = None, /, **kwargs: Any) -> Any:
    """:func:`jax.jit` with :func:`compile_options` where the function is called at the top
    level on the CPU (JAX takes compile options only there; traced inside another program, or on
    another backend, it is a plain ``jax.jit``).  Also a decorator with keyword arguments only, as
    ``jit(static_argnames=("m",))``; with ``compiler_options=`` given, exactly ``jax.jit``."""
    if fun is None:
        return functools.partial(jit, **kwargs)
    options = compile_options()
    if "compiler_options" in kwargs or not options:
        return jax.jit(fun, **kwargs)
    return _Jit(fun, options, kwargs)
