"""Measurement error on simulated summaries: ``simulate(key, theta) + e``, ``e ~ N(0, diag(sd^2))``.

Measured data carry their own error.  Adding it to every simulation makes ABC, and the
surrogate's synthetic likelihood, target the posterior of the model *plus* that error:
Wilkinson (2013), "Approximate Bayesian computation (ABC) gives exact results under the
assumption of model error", Stat. Appl. Genet. Mol. Biol. 12, 129.  Without it a summary
measured to +-1 kJ/mol but simulated to +-0.05 is fitted as if exact, and a model that misses
it by one measurement error is rejected by twenty simulation errors.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["MeasurementError"]

# The error's key is folded from the simulation's key with this tag, so it never equals a key
# the simulator itself draws from.
_TAG = 0x6E6F6973  # "nois"


class MeasurementError:
    """``simulate`` with independent Gaussian measurement error added to its summaries.

    Picklable when ``simulate`` is, so it runs on process pools and MPI like the simulator.

    Parameters
    ----------
    simulate : callable ``(key, theta) -> summaries``
        A JAX function (typed keys, ``vmap``) or a host simulator (raw ``uint32[2]`` keys).
    sd : array_like, shape of the summaries
        Standard deviation of each summary's measurement error, in the summaries' units;
        0 where the data state none.  Non-negative and finite.

    Notes
    -----
    The error is drawn from ``fold_in(key, tag)``, so a seed fixes it on every executor; failed
    simulations (NaN summaries, :class:`jaxabc.SimulationFailure`) stay failed.
    """

    def __init__(self, simulate: Callable, sd: Any) -> None:
        if not callable(simulate):
            raise TypeError("simulate must be a callable simulate(key, theta) -> summaries")
        sd = np.asarray(sd, np.float64)
        if not np.all(np.isfinite(sd)) or np.any(sd < 0):
            raise ValueError(f"measurement sd must be finite and >= 0 (0 where none is stated), got {sd.tolist()}")
        self.simulate = simulate
        self.sd = sd
        # Checkpoints name the simulator by module:qualname: say what is wrapped, and with what.
        inner = getattr(simulate, "__qualname__", type(simulate).__qualname__)
        self.__qualname__ = f"MeasurementError[{inner}, sd={sd.tolist()}]"

    def __repr__(self) -> str:
        return f"MeasurementError({self.simulate!r}, sd={self.sd.tolist()})"

    def __call__(self, key: Any, theta: Any) -> Any:
        out = self.simulate(key, theta)
        if jnp.issubdtype(getattr(key, "dtype", np.uint32), jax.dtypes.prng_key):
            e = jax.random.normal(jax.random.fold_in(key, _TAG), jnp.shape(out), jnp.result_type(out))
            return out + jnp.asarray(self.sd, jnp.result_type(out)) * e
        raw = jax.random.wrap_key_data(jnp.asarray(np.asarray(key), dtype=jnp.uint32))
        e = np.asarray(jax.random.normal(jax.random.fold_in(raw, _TAG), np.shape(out), jnp.float32), np.float64)
        out = np.asarray(out, np.float64)
        if self.sd.shape not in ((), out.shape):
            raise ValueError(f"measurement sd has shape {self.sd.shape}, the summaries {out.shape}")
        return out + self.sd * e
