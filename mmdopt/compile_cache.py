"""JAX's persistent compilation cache for the planner's programs, turned on by the caller.

A first :func:`mmdopt.plan` in a new process traces and compiles Algorithm 1, the selection and
the counts (seconds on a CPU).  With the persistent cache on, a later process loads those
programs from disk instead.  Importing :mod:`mmdopt` never changes JAX's configuration: the
cache is on only where :func:`enable_compile_cache` is called (the ``mmdopt`` CLI calls it for
every run unless ``--no-compile-cache``).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping
from pathlib import Path

__all__ = ["COMPILE_CACHE_MAX_BYTES", "compile_cache_dir", "enable_compile_cache"]

#: the most the compile cache may hold (bytes; JAX evicts the least recently used entries)
COMPILE_CACHE_MAX_BYTES = 2 * 1024**3


def compile_cache_dir(env: Mapping[str, str] | None = None) -> Path | None:
    """The folder of the persistent compilation cache: ``MMDOPT_COMPILE_CACHE`` when set
    (``0`` or empty: none), else ``$XDG_CACHE_HOME/mmdopt/jax``, else ``~/.cache/mmdopt/jax``."""
    env = os.environ if env is None else env
    if not isinstance(env, Mapping):
        raise ValueError(f"env must be a mapping of environment variables, got {type(env)}")
    own = env.get("MMDOPT_COMPILE_CACHE")
    if own is not None:
        return None if own.strip() in ("", "0") else Path(own).expanduser()
    base = env.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "mmdopt" / "jax"


def enable_compile_cache(path: str | os.PathLike | None = None) -> Path | None:
    """Turn on JAX's persistent compilation cache in ``path`` (default
    :func:`compile_cache_dir`; a ``JAX_COMPILATION_CACHE_DIR`` already set is used as it is),
    for this process and the worker processes it starts.  Every program is kept, however quick
    its compile (a plan calls many small ones), up to :data:`COMPILE_CACHE_MAX_BYTES`.

    Returns the folder, or ``None`` where the cache stays off: ``MMDOPT_COMPILE_CACHE=0``, or a
    folder that cannot be created (a read-only home).  Call it before the first plan: programs
    compiled before it are not written."""
    if path is None:
        if "JAX_COMPILATION_CACHE_DIR" in os.environ:
            return Path(os.environ["JAX_COMPILATION_CACHE_DIR"])
        path = compile_cache_dir()
        if path is None:
            return None
    elif not isinstance(path, (str, os.PathLike)) or not str(path).strip():
        raise ValueError(f"path must be a folder name, got {path!r}")
    path = Path(path).expanduser()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:  # a read-only home: run without it
        return None
    settings = {
        "JAX_COMPILATION_CACHE_DIR": str(path),
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
        "JAX_COMPILATION_CACHE_MAX_SIZE": str(COMPILE_CACHE_MAX_BYTES),
    }
    os.environ.update(settings)  # worker processes inherit it
    if "jax" in sys.modules:  # imported already (this process): set it there too
        import jax

        jax.config.update("jax_compilation_cache_dir", str(path))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_compilation_cache_max_size", COMPILE_CACHE_MAX_BYTES)
    return path
