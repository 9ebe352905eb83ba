"""The compile options of the package's jitted programs (:mod:`solvers.xla`): when they apply,
that a caller's own flag wins, that nested use stays legal, and that every jitted entry point of
the three packages goes through them."""

from __future__ import annotations

import ast
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from solvers import xla

ROOT = Path(__file__).resolve().parents[2]
OFF = {xla.FUSION_EMITTERS: False}
NEW = ("0.10.2", "0.10.2")


@pytest.mark.parametrize(
    "flags, versions, expected",
    [
        ("", NEW, OFF),
        ("--xla_cpu_max_isa=AVX2", NEW, OFF),  # other flags leave the choice to the package
        ("--xla_cpu_use_fusion_emitters=true", NEW, {}),  # the caller's choice wins
        ("--xla_cpu_use_fusion_emitters=false", NEW, {}),
        ("", ("0.6.0", "0.6.0"), OFF),  # the first releases whose XLA knows the option
        ("", ("0.5.3", "0.5.3"), {}),  # older XLA refuses an option it does not know
        ("", ("0.10.2", "0.5.3"), {}),  # jax and jaxlib must both know it
        ("", ("0.7.0rc1", "0.7.0+cuda12"), OFF),  # pre-release and local suffixes
    ],
)
def test_fusion_emitters_are_off_unless_the_caller_chose_or_xla_predates_them(
    flags, versions, expected
):
    assert xla.compile_options(flags, versions) == expected


def test_flags_that_are_not_a_string_are_refused():
    with pytest.raises(ValueError, match="xla_flags"):
        xla.compile_options(["--xla_cpu_use_fusion_emitters=true"], NEW)


def _gather_scatter(x, idx):
    # the kind of program the option is for: gathers and a scatter-add
    return jnp.zeros_like(x).at[idx].add(jnp.sin(x[idx]) * x[idx[::-1]]).sum() + x @ x


def test_top_level_and_traced_calls_agree_with_jax_jit():
    """At the top level the options apply; inside jit, vmap and grad the function is a plain
    nested jit (JAX refuses compile options there), with the same values."""
    f = xla.jit(_gather_scatter)
    ref = jax.jit(_gather_scatter)
    x = jnp.asarray(np.random.default_rng(0).normal(size=16), jnp.float32)
    idx = jnp.asarray([3, 1, 4, 1, 5, 9, 2, 6])
    np.testing.assert_allclose(f(x, idx), ref(x, idx), rtol=1e-6)
    np.testing.assert_allclose(jax.jit(f)(x, idx), ref(x, idx), rtol=1e-6)
    xs = jnp.stack([x, 2 * x])
    np.testing.assert_allclose(
        jax.vmap(f, (0, None))(xs, idx), jax.vmap(ref, (0, None))(xs, idx), rtol=1e-6
    )
    np.testing.assert_allclose(jax.grad(f)(x, idx), jax.grad(ref)(x, idx), rtol=1e-6)
    np.testing.assert_allclose(f.lower(x, idx).compile()(x, idx), ref(x, idx), rtol=1e-6)
    assert f.__name__ == "_gather_scatter"


def test_decorator_form_and_explicit_options_are_plain_jax_jit():
    @xla.jit(static_argnames=("k",))
    def power(x, k):
        return x**k

    assert float(power(jnp.asarray(2.0), k=3)) == 8.0
    explicit = xla.jit(jnp.sin, compiler_options={})
    assert float(explicit(jnp.asarray(0.0))) == 0.0


def _jax_jit_calls(path: Path) -> list[int]:
    """Lines of ``path`` that call or decorate with ``jax.jit`` (code, not docstrings)."""
    lines = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Attribute) and ast.unparse(node) == "jax.jit":
            lines.append(node.lineno)
    return lines


def test_every_jitted_entry_point_of_the_packages_compiles_with_the_options():
    found = {
        str(p.relative_to(ROOT)): lines
        for pkg in ("solvers", "frenet", "mmdopt")
        for p in sorted((ROOT / pkg).rglob("*.py"))
        if p.name != "xla.py" and (lines := _jax_jit_calls(p))
    }
    assert not found, f"use solvers.xla.jit instead of jax.jit: {found}"
