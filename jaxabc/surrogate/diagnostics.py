"""Can the emulator be trusted?  Replicate lack-of-fit and held-out real simulations.

Two checks, both in emulated-output coordinates:

* lack of fit (the classical regression test): the fitted nugget ``s_j^2`` should match the
  pure-error variance ``v_j`` of replicate runs; under that hypothesis ``nu v_j / s_j^2`` is
  chi-square with ``nu`` degrees of freedom.  A nugget far above the replicate scatter means the
  GP has swallowed structure it cannot represent (a discontinuity, a jump between phases) as
  noise.  The test assumes homoscedastic noise: replicate sites that are much quieter than the
  posterior region may trigger it.
* held-out simulations at posterior draws: standardised errors
  ``e_ij = (z_ij - mu_j) / sqrt(var_j + s_j^2)`` must be N(0, 1): the fraction inside +-1.96
  must reach 0.95 minus three binomial standard errors and the mean of ``e^2`` must stay below
  the 0.999 chi-square quantile (per degree of freedom).  With the noise correlation ``R``
  given, the joint errors ``m_i = d_i' (D R D + diag(var_i))^-1 d_i`` (``d_i`` the residual
  vector of run ``i``) must also have their mean per output below that quantile: marginal
  errors can look right while the correlation, and with it the posterior's width, is wrong.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.stats

__all__ = ["HoldoutCheck", "LocalCheck", "holdout_check", "lack_of_fit", "local_check", "replicate_variance"]


def replicate_variance(z: np.ndarray, group: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, int]:
    """Pooled within-group variance ``(q,)`` of successful replicate rows and its degrees of freedom."""
    ss = np.zeros(z.shape[1])
    df = 0
    for g in np.unique(group[(group >= 0) & ok]):
        rows = z[(group == g) & ok]
        if rows.shape[0] >= 2:
            ss += np.sum((rows - rows.mean(axis=0)) ** 2, axis=0)
            df += rows.shape[0] - 1
    return (ss / df if df else np.full(z.shape[1], np.nan)), df


def lack_of_fit(
    nugget_variance: np.ndarray, rep_variance: np.ndarray, df: int, level: float = 1e-3
) -> tuple[bool | None, np.ndarray]:
    """Test fitted nuggets against replicate scatter (Bonferroni over outputs).

    Returns
    -------
    passed : bool or None
        None when there are no replicates (``df == 0``).
    p_values : array, shape (q,)
        Lower-tail chi-square probabilities (small: replicates much quieter than the nugget).
    """
    if df == 0:
        return None, np.full(nugget_variance.shape, np.nan)
    p = scipy.stats.chi2.cdf(df * rep_variance / nugget_variance, df)
    return bool(np.all(p >= level / p.size)), p


class HoldoutCheck(NamedTuple):
    """Outcome of :func:`holdout_check`.

    Attributes
    ----------
    errors : array, shape (h, q)
        Standardised prediction errors of the successful held-out runs.
    coverage : float
        Fraction of ``|e| <= 1.96``.
    mean_squared : float
        Mean of ``e^2``.
    coverage_min, mean_squared_max : float
        The pass bounds (``mean_squared_max`` also bounds ``joint_mean_squared``).
    joint_mean_squared : float
        Mean over runs of the Mahalanobis distance per output (NaN without a noise correlation).
    passed : bool
    """

    errors: np.ndarray
    coverage: float
    mean_squared: float
    coverage_min: float
    mean_squared_max: float
    joint_mean_squared: float
    passed: bool


#: Successful held-out runs a validation needs (also the least ``num_holdout``).  Fewer leave
#: bounds too loose to catch a poor emulator, and mean that the posterior sits where most runs
#: fail: a validation from the two of twenty that succeeded is no validation.
MIN_HOLDOUT_RUNS = 5


#: Tail probability of the observed summaries under the posterior predictive below which a
#: run warns that the model does not reproduce the data (:func:`jaxabc.surrogate.evidence.observed_misfit`).
#: A posterior predictive p-value is conservative (it concentrates near 0.5 for a right model),
#: so this level flags misfits, not the chance scatter of a model that fits.
MISFIT_P_VALUE = 1e-3
#: Effective sample size of the reported posterior below which a run warns that its intervals
#: and correlation are not resolved (a quantile from ``n`` effective draws carries a standard
#: error of about ``sqrt(q (1 - q) / n)`` in probability: 0.02 at ``q = 0.975`` for 100).
MIN_POSTERIOR_ESS = 100


def holdout_bounds(n: int) -> tuple[float, float]:
    """Pass bounds ``(coverage_min, mean_squared_max)`` for ``n`` standardised errors."""
    return 0.95 - 3.0 * np.sqrt(0.95 * 0.05 / n), float(scipy.stats.chi2.ppf(0.999, n) / n)


def holdout_check(
    z: np.ndarray,
    mean: np.ndarray,
    var: np.ndarray,
    noise_var: np.ndarray,
    noise_corr: np.ndarray | None = None,
) -> HoldoutCheck:
    """Standardised errors of held-out runs ``z (h, q)`` against predictions ``mean, var (h, q)``,
    noise variances ``noise_var`` (``(q,)``, or ``(h, q)`` for noise that varies with theta) and,
    optionally, the noise correlation ``(q, q)``."""
    noise_var = np.broadcast_to(np.asarray(noise_var, np.float64), z.shape)
    e = (z - mean) / np.sqrt(var + noise_var)
    if e.size == 0:
        return HoldoutCheck(e, np.nan, np.nan, np.nan, np.nan, np.nan, False)
    cov_min, msq_max = holdout_bounds(e.size)
    coverage = float(np.mean(np.abs(e) <= 1.96))
    msq = float(np.mean(e**2))
    joint = np.nan
    if noise_corr is not None:
        d = z - mean
        joint = float(
            np.mean(
                [
                    r @ np.linalg.solve(np.sqrt(s)[:, None] * noise_corr * np.sqrt(s)[None, :] + np.diag(v), r)
                    for r, v, s in zip(d, var, noise_var, strict=True)
                ]
            )
            / z.shape[1]
        )
    passed = coverage >= cov_min and msq <= msq_max and not joint > msq_max
    return HoldoutCheck(e, coverage, msq, cov_min, msq_max, joint, bool(passed))


class LocalCheck(NamedTuple):
    """Outcome of :func:`local_check`: the largest ``|e|`` (NaN for no errors), its bound, and
    whether the errors passed."""

    max_abs: float
    bound: float
    passed: bool


def local_check(errors: np.ndarray, level: float = 1e-3) -> LocalCheck:
    """The standardised errors of the targeted held-out runs ``(t, q)`` on their own.

    Each ``|e|`` must stay below the two-sided normal quantile at ``level`` Bonferroni-divided
    over the ``n`` errors, and their mean square below the chi-square ``1 - level`` quantile per
    degree of freedom.  Passes trivially with no errors (nothing could be targeted).
    """
    e = np.asarray(errors, np.float64).ravel()
    if e.size == 0:
        return LocalCheck(np.nan, np.nan, True)
    bound = float(scipy.stats.norm.ppf(1.0 - level / (2.0 * e.size)))
    max_abs = float(np.max(np.abs(e)))
    mean_squared_ok = float(np.mean(e**2)) <= scipy.stats.chi2.ppf(1.0 - level, e.size) / e.size
    return LocalCheck(max_abs, bound, bool(max_abs <= bound and mean_squared_ok))
