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


def seeds_from_key(key: jax.Array | np.ndarray, num: int, high: int = 2**31 - 1) -> list[int]:
    """Return ``num`` integer seeds in ``[1, high)`` drawn from ``key``.

    Parameters
    ----------
    key : jax.Array or numpy.ndarray
        A typed JAX PRNG key, or its raw data (``jax.random.key_data``, ``uint32[2]``).
    num : int
        How many seeds, ``>= 0``.
    high : int
        Exclusive upper bound, ``2 <= high <= 2**31 - 1``; the default fits a signed 32-bit
        integer, as GROMACS and LAMMPS expect.

    Raises
    ------
    ValueError
        If ``num`` or ``high`` is out of range, or ``key`` is neither a typed key nor ``uint32[2]``.
    """
    if num < 0:
        raise ValueError(f"num must be >= 0 seeds, got {num}")
    if not 2 <= high <= 2**31 - 1:
        raise ValueError(f"high must be in [2, 2**31 - 1] so that [1, high) holds a signed 32-bit seed, got {high}")
    if not jnp.issubdtype(getattr(key, "dtype", np.uint32), jax.dtypes.prng_key):
        # Executors hand host simulators the raw key data (uint32[2]), which pickles cheaply.
        raw = np.asarray(key)
        if raw.shape != (2,) or not np.issubdtype(raw.dtype, np.integer):
            raise ValueError(
                f"key must be a typed JAX key or its raw data uint32[2] (jax.random.key_data(key)), "
                f"got {raw.dtype}{list(raw.shape)}"
            )
        key = jax.random.wrap_key_data(jnp.asarray(raw, dtype=jnp.uint32))
    draws = jax.random.randint(key, (num,), 1, high, dtype=jnp.int32)
    return [int(v) for v in np.asarray(draws)]


def seed_from_key(key: jax.Array | np.ndarray, high: int = 2**31 - 1) -> int:
    """Return one integer seed in ``[1, high)`` drawn from ``key``; see :func:`seeds_from_key`."""
    return seeds_from_key(key, 1, high)[0]
