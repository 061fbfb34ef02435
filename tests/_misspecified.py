"""A misspecified problem with an exact answer, shared by the discrepancy tests.

K values per simulation, ``theta + N(0, S_DISC^2)``; the data carry an extra ``N(0, TAU^2)`` per
value that the model lacks.  With one discrepancy sd ``delta`` over all K values the likelihood
is ``prod_j N(y_j; theta, S_DISC^2 + delta^2)``, integrated on a grid for the exact posterior.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

K, S_DISC, TAU, THETA0 = 20, 0.5, 1.0, 1.0


def k_values(key, theta):
    """K values theta + N(0, S_DISC^2)."""
    return theta[0] + S_DISC * jax.random.normal(key, (K,))


def mean_and_sd(observed, simulated):
    """Distance on the sufficient statistics (mean, sample sd) of K iid Gaussian values: ABC
    at a small tolerance then approaches the exact posterior given all K values."""
    return jnp.abs(observed.mean() - simulated.mean()) + jnp.abs(observed.std(ddof=1) - simulated.std(ddof=1))


def observed(seed: int = 7) -> np.ndarray:
    """K data values with the extra noise TAU."""
    return THETA0 + np.sqrt(S_DISC**2 + TAU**2) * np.random.default_rng(seed).standard_normal(K)


def grid_posterior(
    y: np.ndarray, theta_range: tuple[float, float], max_sd: float, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact posterior of (theta, delta) under a flat prior on ``theta_range x [0, max_sd]``:
    the theta grid, the delta grid (both ``size``) and the normalised weights."""
    th, de = np.linspace(*theta_range, size[0]), np.linspace(0.0, max_sd, size[1])
    t, d = np.meshgrid(th, de, indexing="ij")
    v = S_DISC**2 + d**2
    ll = -0.5 * K * np.log(v) - 0.5 * ((y[None, None, :] - t[..., None]) ** 2).sum(-1) / v
    p = np.exp(ll - ll.max())
    return t, d, p / p.sum()
