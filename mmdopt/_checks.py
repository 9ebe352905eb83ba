"""Input checks shared across the method's public functions."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def check_key(key):
    """``ValueError`` unless ``key`` is one jax PRNG key (typed, or a raw uint32 pair)."""
    try:
        k = jnp.asarray(key)
        ok = jnp.issubdtype(k.dtype, jax.dtypes.prng_key) or (
            k.dtype == jnp.uint32 and k.shape == (2,)
        )
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError("key must be a jax PRNG key (jax.random.PRNGKey(seed) or jax.random.key)")
    return key
