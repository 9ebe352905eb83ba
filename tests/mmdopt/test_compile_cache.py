"""The persistent compilation cache is the caller's choice: ``mmdopt.enable_compile_cache``
turns it on (for this process and its workers) in a folder it names; importing ``mmdopt``
never does."""

from __future__ import annotations

import os
import subprocess
import sys

import jax
import pytest

import mmdopt
from mmdopt.compile_cache import compile_cache_dir

_KEYS = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
         "jax_compilation_cache_max_size")  # fmt: skip


@pytest.fixture
def restored(monkeypatch):
    """JAX's cache settings and the whole environment as they were, after the test (the
    function sets variables that were absent, which ``monkeypatch.delenv`` would not undo: a
    cache size left behind would switch later processes of the run to JAX's LRU cache)."""
    before = {k: getattr(jax.config, k) for k in _KEYS}
    saved = dict(os.environ)
    for k in ("JAX_COMPILATION_CACHE_DIR", "MMDOPT_COMPILE_CACHE"):
        monkeypatch.delenv(k, raising=False)
    yield monkeypatch
    monkeypatch.undo()
    os.environ.clear()
    os.environ.update(saved)
    for k, v in before.items():
        jax.config.update(k, v)


def test_it_turns_the_cache_on_in_the_folder_given(tmp_path, restored):
    got = mmdopt.enable_compile_cache(tmp_path / "c")
    assert got == tmp_path / "c" and got.is_dir()
    assert jax.config.jax_compilation_cache_dir == str(got)
    assert os.environ["JAX_COMPILATION_CACHE_DIR"] == str(got)  # the workers inherit it


def test_the_default_folder_follows_the_environment_and_0_turns_it_off(tmp_path, restored):
    assert compile_cache_dir({"XDG_CACHE_HOME": str(tmp_path)}) == tmp_path / "mmdopt" / "jax"
    assert compile_cache_dir({"MMDOPT_COMPILE_CACHE": str(tmp_path / "x")}) == tmp_path / "x"
    restored.setenv("MMDOPT_COMPILE_CACHE", "0")
    assert mmdopt.enable_compile_cache() is None
    assert not os.environ.get("JAX_COMPILATION_CACHE_DIR")


@pytest.mark.parametrize("bad", ["", "   ", 3.5])
def test_a_bad_folder_is_named(bad, restored):
    with pytest.raises(ValueError, match="path"):
        mmdopt.enable_compile_cache(bad)


def test_importing_mmdopt_leaves_jax_as_it_was():
    code = ("import jax, mmdopt; mmdopt.MMDOptConfig(); "
            "print(jax.config.jax_compilation_cache_dir)")  # fmt: skip
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         check=True).stdout.strip()  # fmt: skip
    assert out == "None"
