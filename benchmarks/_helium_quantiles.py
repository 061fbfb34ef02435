"""The surrogate's helium problem (Table 1's data summarised by quantiles of f_B), shared by
``surrogate_helium`` and ``surrogate_helium_noise``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from md import helium
from md.helium_calibration import make_model

#: The quantile levels of f_B the summaries are.
LEVELS = np.linspace(0.03, 0.97, 16)


def quantile_problem(preset: str, seed: int):
    """The surrogate's helium problem: ``(simulate_quantiles, prior, observed series, observed
    quantiles, simulate)``, the Table 1 data of ``seed`` summarised by the 16 quantiles of f_B."""
    simulate, prior = make_model(preset)
    observed = helium.observed_series(jax.random.key(10_000 + seed), preset)
    levels = jnp.asarray(LEVELS, jnp.float32)

    def simulate_quantiles(key, theta):
        return jnp.quantile(simulate(key, theta), levels)

    return simulate_quantiles, prior, observed, np.quantile(np.asarray(observed), LEVELS), simulate
