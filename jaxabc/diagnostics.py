"""Monte Carlo diagnostics of posterior samples made of Markov chains (host code, NumPy).

ABCsubsim's population is ``C`` short chains (``1 / P0`` states each) rather than independent
draws, so its effective sample size is not its size.  :func:`chain_ess` gives an
autocorrelation-aware estimate across the chains from ArviZ, never more than the number of
distinct draws.  It assumes the chains are independent of one another; ABCsubsim's chains share
ancestors, which :func:`jaxabc.algorithms.subsim.population_ess_bound` accounts for, so the
effective sample size of an ABCsubsim population is the smaller of the two.

The Monte Carlo standard error of a weighted mean needs more than an effective sample size when
the particles share ancestors (ABCsubsim's chains, APMCABC's resampled parents): the spread of
a few lineages says how far the estimate may be off, the spread within them does not.
:func:`lineage_variance` and :func:`cluster_variance` estimate the variance of the weighted mean
from the lineages, :func:`importance_variance` without them.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

__all__ = [
    "batch_means_ess",
    "chain_ess",
    "cluster_variance",
    "count_distinct",
    "discrepancy_identification",
    "effective_lineages",
    "importance_variance",
    "lineage_variance",
    "prior_edge_mass",
    "prior_edge_messages",
    "prior_limit_notes",
]

#: ``prior_edge_mass`` above this, at the default width, is a :class:`jaxabc.PriorEdgeWarning`.
PRIOR_EDGE_LIMIT = 0.05
PRIOR_EDGE_WIDTH = 0.02

#: A discrepancy sd with at least this share of its posterior in the upper half of its prior
#: range ``[0, max_sd]`` (a flat posterior puts 0.5 there) is bounded by the data from below only.
PRIOR_LIKE_SHARE = 0.25

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


def _lineage_sums(x: np.ndarray, weights: np.ndarray, lineage: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each lineage's share of the weight (k,) and its weighted residual sum (k, d).

    Only particles with positive weight count: a lineage without weight is not one.
    """
    x = np.asarray(x, np.float64).reshape(len(x), -1)
    w = np.asarray(weights, np.float64)
    keep = w > 0
    x, w = x[keep], w[keep] / w[keep].sum()
    _, inverse = np.unique(np.asarray(lineage).reshape(-1)[keep], return_inverse=True)
    inverse = inverse.reshape(-1)
    residual = w[:, None] * (x - w @ x)
    k = int(inverse.max()) + 1
    sums = np.zeros((k, x.shape[1]))
    np.add.at(sums, inverse, residual)
    return np.bincount(inverse, weights=w, minlength=k), sums


def effective_lineages(weights: np.ndarray, lineage: np.ndarray) -> tuple[int, float]:
    """Number of lineages and Kish's effective number ``1 / sum_c W_c^2`` of their weights.

    Parameters
    ----------
    weights : numpy.ndarray, shape (n,)
        Non-negative, not necessarily normalised.
    lineage : numpy.ndarray, shape (n,)
        A label per particle; particles with one label share an ancestor.

    Returns
    -------
    tuple of (int, float)
        Lineages holding weight, and their effective number (1 when one lineage holds it all).
    """
    per_lineage, _ = _lineage_sums(np.zeros((len(weights), 1)), weights, lineage)
    return int(per_lineage.size), float(1.0 / np.sum(per_lineage**2))


def importance_variance(x: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Delta-method variance of a self-normalised weighted mean: ``sum_i w_i^2 (x_i - mean)^2``.

    Unlike ``var / ESS`` with Kish's ESS, it lets the weights and the residuals go together
    (large weights in the tails).  Assumes independent particles.

    Parameters
    ----------
    x : numpy.ndarray, shape (n, d)
    weights : numpy.ndarray, shape (n,)

    Returns
    -------
    numpy.ndarray, shape (d,)
    """
    x = np.asarray(x, np.float64).reshape(len(x), -1)
    w = np.asarray(weights, np.float64)
    w = w / w.sum()
    return np.sum(w[:, None] ** 2 * (x - w @ x) ** 2, axis=0)


def cluster_variance(x: np.ndarray, weights: np.ndarray, lineage: np.ndarray) -> np.ndarray:
    """Cluster-robust variance of a weighted mean, the lineages as clusters.

    ``k / (k - 1) sum_c (sum_{i in c} w_i (x_i - mean))^2`` with ``k`` lineages (CR1): exact
    for independent lineages whatever the correlation inside them.  Suits many lineages
    (APMCABC's, a few generations back); with one lineage it is 0.

    Parameters
    ----------
    x : numpy.ndarray, shape (n, d)
    weights : numpy.ndarray, shape (n,)
    lineage : numpy.ndarray, shape (n,)

    Returns
    -------
    numpy.ndarray, shape (d,)
    """
    per_lineage, sums = _lineage_sums(x, weights, lineage)
    k = per_lineage.size
    return np.sum(sums**2, axis=0) * (k / (k - 1) if k > 1 else 0.0)


def lineage_variance(x: np.ndarray, weights: np.ndarray, lineage: np.ndarray) -> np.ndarray:
    """Variance of a weighted mean whose lineages are its independent units.

    The lineage means ``m_c`` with weights ``W_c`` are treated as independent draws of one
    variance ``s^2``, estimated without bias by ``sum_c W_c (m_c - mean)^2 / (1 - sum_c W_c^2)``;
    the variance of the mean is ``s^2 sum_c W_c^2``.  Unlike :func:`cluster_variance` it does
    not lose the variance of a lineage that holds most of the weight (its residual is small
    because it sets the mean); it suits a few lineages that barely move (ABCsubsim's chains).

    Parameters
    ----------
    x : numpy.ndarray, shape (n, d)
    weights : numpy.ndarray, shape (n,)
    lineage : numpy.ndarray, shape (n,)

    Returns
    -------
    numpy.ndarray, shape (d,)
        ``inf`` with a single lineage (no spread between lineages to measure).
    """
    per_lineage, sums = _lineage_sums(x, weights, lineage)
    concentration = float(np.sum(per_lineage**2))
    if per_lineage.size < 2 or concentration >= 1.0:
        return np.full(sums.shape[1], np.inf)
    # sums[c] = W_c (m_c - mean), so W_c (m_c - mean)^2 = sums[c]^2 / W_c.
    spread = np.sum(sums**2 / per_lineage[:, None], axis=0) / (1.0 - concentration)
    return spread * concentration


def prior_edge_mass(
    particles: np.ndarray,
    weights: np.ndarray | None,
    low: np.ndarray,
    high: np.ndarray,
    width: float = PRIOR_EDGE_WIDTH,
) -> np.ndarray:
    """Posterior mass near each bound of a box prior.

    Parameters
    ----------
    particles : array, shape (n, d)
    weights : array, shape (n,), or None for equal weights
        Normalised here; non-finite or negative weights are an error.
    low, high : array, shape (d,)
        The box; a non-finite bound has no edge (mass 0 there).
    width : float
        In (0, 0.5): the band's width as a fraction of ``high - low``.

    Returns
    -------
    numpy.ndarray, shape (d, 2)
        ``[:, 0]`` the mass within ``width`` of the lower bound, ``[:, 1]`` of the upper bound.
    """
    x = np.asarray(particles, np.float64)
    if x.ndim != 2:
        raise ValueError(f"particles must have shape (n, d), got {x.shape}")
    n, d = x.shape
    w = np.full(n, 1.0 / max(n, 1)) if weights is None else np.asarray(weights, np.float64)
    if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0) or n == 0 or w.sum() <= 0:
        raise ValueError("weights must be n finite, non-negative numbers with a positive sum")
    w = w / w.sum()
    if not 0 < float(width) < 0.5:
        raise ValueError(f"width must be a fraction of the range in (0, 0.5), got {width!r}")
    lo = np.broadcast_to(np.asarray(low, np.float64), (d,))
    hi = np.broadcast_to(np.asarray(high, np.float64), (d,))
    span = hi - lo
    finite = np.isfinite(span)
    band = np.where(finite, width * np.where(finite, span, 0.0), 0.0)
    near_low = (x <= (lo + band)[None, :]) & finite[None, :]
    near_high = (x >= (hi - band)[None, :]) & finite[None, :]
    return np.stack([w @ near_low, w @ near_high], axis=1)


def discrepancy_identification(
    particles: np.ndarray,
    weights: np.ndarray | None,
    names: tuple[str, ...] | list[str],
    low: np.ndarray,
    high: np.ndarray,
) -> tuple[dict[str, float], list[str]]:
    """How much of each discrepancy sd's posterior the data decide.

    The share of each ``discrepancy_sd[...]`` column's posterior mass in the upper half of its
    prior range: about 0 for an sd the data pin below ``max_sd``, 0.5 for one whose posterior
    is its (uniform) prior.  An sd of a group of one summary has one residual ``r``: the data
    rule out sds well below ``|r|`` and say little above, so its posterior, and the evidence of
    a model choice through it, follow ``max_sd``.

    Parameters
    ----------
    particles : array, shape (n, d)
    weights : array, shape (n,), or None for equal weights
    names : sequence of str, length d
    low, high : array, shape (d,)
        The prior box.

    Returns
    -------
    shares : dict
        ``{name: share}`` for the discrepancy columns (empty without any).
    messages : list of str
        One sentence per sd whose share reaches :data:`PRIOR_LIKE_SHARE`.
    """
    from jaxabc.noise import DISCREPANCY_PREFIX

    columns = [j for j, n in enumerate(names) if str(n).startswith(DISCREPANCY_PREFIX)]
    if not columns:
        return {}, []
    x = np.asarray(particles, np.float64)
    n = x.shape[0]
    w = np.full(n, 1.0 / max(n, 1)) if weights is None else np.asarray(weights, np.float64)
    if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0) or n == 0 or w.sum() <= 0:
        raise ValueError("weights must be n finite, non-negative numbers with a positive sum")
    w = w / w.sum()
    lo, hi = np.asarray(low, np.float64), np.asarray(high, np.float64)
    shares, messages = {}, []
    for j in columns:
        share = float(w @ (x[:, j] > 0.5 * (lo[j] + hi[j])))
        shares[str(names[j])] = share
        if share >= PRIOR_LIKE_SHARE:
            messages.append(
                f"{share:.0%} of {names[j]}'s posterior lies in the upper half of its range "
                f"[{lo[j]:.4g}, {hi[j]:.4g}] (a flat posterior: 50 %): the data bound it from below only, "
                "so it, and any evidence, follow its max_sd"
            )
    return shares, messages


def prior_edge_messages(
    mass: np.ndarray,
    names: tuple[str, ...] | list[str],
    low: np.ndarray,
    high: np.ndarray,
    width: float = PRIOR_EDGE_WIDTH,
    limits: Any = None,
) -> list[str]:
    """One sentence per bound whose mass (from :func:`prior_edge_mass`) exceeds ``PRIOR_EDGE_LIMIT``.

    ``limits`` (per parameter, ``(lower, upper)`` flags, as :class:`jaxabc.Uniform`'s) marks
    bounds that are physical limits: those are left out, see :func:`prior_limit_notes`.
    """
    out = []
    for i, name, side, bound in _piled(mass, names, low, high, limits, physical=False):
        which = "lower" if side == 0 else "upper"
        out.append(
            f"{mass[i, side]:.0%} of the posterior mass of {name} lies within {width:.0%} of the "
            f"range from its {which} bound {float(bound):.6g}: widen the prior there, or say "
            "which physical limit stops it"
        )
    return out


def prior_limit_notes(
    mass: np.ndarray,
    names: tuple[str, ...] | list[str],
    low: np.ndarray,
    high: np.ndarray,
    width: float = PRIOR_EDGE_WIDTH,
    limits: Any = None,
) -> list[str]:
    """Sentences for posteriors piled at a bound that is a physical limit (no warning: the box
    cannot be widened there; the posterior says the data favour the limit)."""
    out = []
    for i, name, side, bound in _piled(mass, names, low, high, limits, physical=True):
        which = "lower" if side == 0 else "upper"
        out.append(
            f"{mass[i, side]:.0%} of the posterior mass of {name} lies within {width:.0%} of the "
            f"range from its {which} bound {float(bound):.6g}, a physical limit"
        )
    return out


def _piled(mass: np.ndarray, names: Any, low: np.ndarray, high: np.ndarray, limits: Any, physical: bool) -> list:
    flags = [(False, False)] * len(names) if limits is None else [tuple(map(bool, pair)) for pair in limits]
    out = []
    for i, name in enumerate(names):
        for side, bound in ((0, low[i]), (1, high[i])):
            if mass[i, side] > PRIOR_EDGE_LIMIT and flags[i][side] == physical:
                out.append((i, name, side, bound))
    return out
