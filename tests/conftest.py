"""Shared fixtures: the location of ../shared/data, skipping clearly where it is absent."""

from __future__ import annotations

import atexit
import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("MMDOPT_SHARED_DATA", REPO.parent / "shared" / "data"))


def _share_jax_compiles() -> None:
    """One JAX persistent compilation cache for the whole run: the xdist workers and every
    subprocess a test starts (process pools, Ray workers, CLI runs, notebook kernels) inherit the
    environment, so each jitted program is compiled once per run instead of once per process.
    Every program is stored, however quick its compile (minimum compile time 0 s): a planner run
    calls a few hundred small jitted functions, and a fresh worker that loads them all from the
    cache plans a task in about half the time of one that recompiles those under 0.5 s.
    A fresh folder per run (removed at exit); ``MMDOPT_TEST_JAX_CACHE=0`` turns it off, and a
    ``JAX_COMPILATION_CACHE_DIR`` the caller set is used as is.  Results are unchanged: an entry
    is keyed by the program, the compile options, the XLA flags and the JAX version."""
    if os.environ.get("MMDOPT_TEST_JAX_CACHE", "1") == "0":
        return
    if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
        path = tempfile.mkdtemp(prefix="mmdopt-test-jax-cache-")
        os.environ["JAX_COMPILATION_CACHE_DIR"] = path
        atexit.register(shutil.rmtree, path, ignore_errors=True)
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    if "jax" in sys.modules:  # imported before this file (a plugin): set it in-process too
        import jax

        jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
        jax.config.update(
            "jax_persistent_cache_min_compile_time_secs",
            float(os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"]),
        )


_share_jax_compiles()

#: the XLA flags the suite compiles with (``_compile_faster``), by option name
SUITE_XLA_FLAGS = {
    "xla_cpu_use_fusion_emitters": "--xla_cpu_use_fusion_emitters=false",
    "xla_backend_optimization_level": "--xla_backend_optimization_level=0",
}


def _compile_faster() -> None:
    """Two XLA settings that make compiles faster, for the whole run (``XLA_FLAGS``, inherited
    by the xdist workers and every subprocess a test starts).  The suite is bound by XLA
    compiles (each distinct config and shape compiles Algorithm 1 anew):

    - the CPU fusion emitters off: they spend much of a compile on the gathers and scatters of
      the batched QP iterations (the suite took 0.7 × the time with them off);
    - LLVM's optimisation level 1 instead of 2: the suite takes 0.8 × the time again (about 16
      against 20 min on 2 cores), and a compiled plan runs as fast as with the emitters off
      alone (``python -m benchmarks.first_plan --fixed --xla-flags="<both>"``: MMD-Opt's
      compile 0.61 ×, its steady plan 1.20 × XLA's defaults).

    XLA then orders some float operations differently: results agree to rounding, which the
    CEM can turn into another winning sample, as another CPU's vector width can (one of four
    MMD-Opt plans of ``python -m benchmarks.first_plan --fixed
    --xla-flags=--xla_cpu_use_fusion_emitters=false`` moved by up to 0.9 m); the tests assert
    properties that hold either way.  With the emitters off a plan can take up to 1.2 × as
    long once compiled, so the package leaves XLA's defaults alone and the benchmarks run with
    them.

    An ``XLA_FLAGS`` that already names an option keeps its value;
    ``MMDOPT_TEST_XLA_DEFAULTS=1`` keeps XLA's defaults; ``tests/mmdopt/test_step_api.py``
    plans under them in a subprocess either way.  Set before any test starts a JAX backend
    (XLA reads its flags then)."""
    if os.environ.get("MMDOPT_TEST_XLA_DEFAULTS", "0") == "1":
        return
    flags = os.environ.get("XLA_FLAGS", "")
    for option, flag in SUITE_XLA_FLAGS.items():
        if option not in flags:
            flags = f"{flags} {flag}".strip()
    os.environ["XLA_FLAGS"] = flags


_compile_faster()


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared test data not found at {SHARED_DATA} (set MMDOPT_SHARED_DATA)")
    return SHARED_DATA


@pytest.fixture
def x64():
    """JAX's x64 mode for the duration of a test (the numerics of float64 code paths); the
    package itself never switches it on globally."""
    import jax

    with jax.enable_x64(True):
        yield
