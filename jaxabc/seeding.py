"""Deriving integer seeds for external programs from JAX keys.

An external simulator (GROMACS, LAMMPS) needs integer seeds.  They are derived from the
particle's JAX key, never from a worker's own state, so a run is identical whichever worker ran
which task and in which order.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["seed_from_key", "seeds_from_key"]


def seeds_from_key(key: jax.Array, num: int, high: int = 2**31 - 1) -> list[int]:
    """Return ``num`` integer seeds in ``[1, high)`` drawn from ``key``.

    Parameters
    ----------
    key : jax.Array or numpy.ndarray
        A typed JAX PRNG key, or its raw data (``jax.random.key_data``, ``uint32[2]``).
    num : int
        How many seeds.
    high : int
        Exclusive upper bound; the default fits a signed 32-bit integer, as GROMACS and
        LAMMPS expect.
    """
    if not jax.dtypes.issubdtype(getattr(key, "dtype", np.uint32), jax.dtypes.prng_key):
        # Executors hand host simulators the raw key data (uint32[2]), which pickles cheaply.
        key = jax.random.wrap_key_data(jnp.asarray(key, dtype=jnp.uint32))
    draws = jax.random.randint(key, (num,), 1, high, dtype=jnp.int32)
    return [int(v) for v in np.asarray(draws)]


def seed_from_key(key: jax.Array, high: int = 2**31 - 1) -> int:
    """Return one integer seed in ``[1, high)`` drawn from ``key``."""
    return seeds_from_key(key, 1, high)[0]
