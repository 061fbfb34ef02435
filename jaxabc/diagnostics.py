"""Monte Carlo diagnostics of posterior samples made of Markov chains (host code, NumPy).

ABCsubsim's population is ``C`` short chains (``1 / P0`` states each) rather than independent
draws, so its effective sample size is not its size.  :func:`chain_ess` gives an
autocorrelation-aware estimate across the chains from ArviZ, never more than the number of
distinct draws.  It assumes the chains are independent of one another; ABCsubsim's chains share
ancestors, which :func:`jaxabc.algorithms.subsim.population_ess_bound` accounts for, so the
effective sample size of an ABCsubsim population is the smaller of the two.
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["batch_means_ess", "chain_ess", "count_distinct"]

# ArviZ's multi-chain estimate needs this many draws per chain.
_MIN_DRAWS_FOR_ARVIZ = 4


def count_distinct(x: np.ndarray) -> int:
    """Number of distinct rows of ``x`` (shape (n, ...)); 0 for an empty array."""
    x = np.asarray(x)
    if x.shape[0] == 0:
        return 0
    return int(np.unique(x.reshape(x.shape[0], -1), axis=0).shape[0])


def batch_means_ess(chains: np.ndarray) -> float:
    """Effective sample size of the pooled mean from the spread of the chains' means.

    ``n var / (L Var(chain means))`` per parameter, minimum over parameters, for chains of
    ``L`` draws; exact for independent chains whose draws are exchangeable batches.  Used where
    the chains are too short for ArviZ.

    Parameters
    ----------
    chains : numpy.ndarray, shape (num_chains, num_draws, d)

    Returns
    -------
    float
        In ``[1, num_chains * num_draws]``; ``num_chains * num_draws`` when nothing varies.
    """
    x = np.asarray(chains, np.float64)
    c, length = x.shape[:2]
    x = x.reshape(c, length, -1)
    var = x.reshape(c * length, -1).var(axis=0, ddof=1) if c * length > 1 else np.zeros(x.shape[2])
    var_means = x.mean(axis=1).var(axis=0, ddof=1) if c > 1 else np.zeros(x.shape[2])
    with np.errstate(divide="ignore", invalid="ignore"):
        ess = np.where(var_means > 0, c * var / np.where(var_means > 0, var_means, 1.0), np.inf)
    return float(np.clip(np.min(ess), 1.0, c * length))


def chain_ess(chains: np.ndarray) -> float:
    """Effective sample size of the pooled mean of several Markov chains.

    ArviZ's multi-chain estimate (``arviz.ess(..., method="identity")``: Geyer's initial
    monotone sequence over the chains' pooled autocorrelations, chains not split, since the
    chains here may be as short as 4 draws) per parameter, the minimum over parameters, and
    never more than the number of distinct draws.  Chains shorter than 4 draws fall back to
    :func:`batch_means_ess`.

    Parameters
    ----------
    chains : numpy.ndarray, shape (num_chains, num_draws, d)
        ``chains[c, t]`` is chain ``c`` after ``t`` moves.  A repeated draw (a rejected move)
        counts once towards the distinct bound.

    Returns
    -------
    float
        In ``[1, number of distinct draws]``.

    Raises
    ------
    ValueError
        If ``chains`` is not 3-D, is empty or holds non-finite values.
    """
    x = np.asarray(chains, np.float64)
    if x.ndim != 3 or x.size == 0:
        raise ValueError(f"chains must have shape (num_chains, num_draws, d), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("chains hold NaN or infinite values: no effective sample size")
    c, length, d = x.shape
    distinct = count_distinct(x.reshape(c * length, d))
    if distinct <= 1:
        return 1.0
    if length < _MIN_DRAWS_FOR_ARVIZ:
        ess = batch_means_ess(x)
    else:
        with warnings.catch_warnings():
            # ArviZ 0.x announces its 1.0 refactor with a FutureWarning on import.
            warnings.simplefilter("ignore", FutureWarning)
            import arviz as az
        per_param = [float(az.ess(x[:, :, j], method="identity")) for j in range(d) if np.ptp(x[:, :, j]) > 0]
        per_param = [e for e in per_param if np.isfinite(e)]
        ess = min(per_param) if per_param else float(c * length)
    return float(np.clip(ess, 1.0, distinct))
