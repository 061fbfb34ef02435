"""Linear-algebra and test helpers of :mod:`jaxabc.criticism.causes`."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import stats

__all__ = ["directed_score", "prior_span", "projector", "residual_test"]


def prior_span(eff: Any) -> float:
    """Largest move of the effect parameter away from its null that its prior allows."""
    if eff.one_sided == 1:
        return eff.high - eff.null
    if eff.one_sided == -1:
        return eff.null - eff.low
    return max(eff.high - eff.null, eff.null - eff.low)


def projector(u: np.ndarray, prec: np.ndarray) -> np.ndarray:
    """``I - U (U' W U)^+ U' W``: removes what the columns of ``u`` explain in the ``W`` metric."""
    s = u.shape[0]
    if u.shape[1] == 0:
        return np.eye(s)
    return np.eye(s) - u @ np.linalg.pinv(u.T @ prec @ u, rcond=1e-10, hermitian=True) @ u.T @ prec


def residual_test(r: np.ndarray, cov: np.ndarray, num_replicates: int | None, num_fitted: int) -> dict:
    """Quadratic form of a residual in the null precision and its tail p-value.

    The rank of ``cov`` less ``num_fitted`` (effect amplitudes fitted by projection) is the
    degrees of freedom; with ``num_replicates`` the Hotelling F tail accounts for a covariance
    estimated from that many replicates, otherwise the chi-squared tail.
    """
    w, v = np.linalg.eigh(cov)
    keep = w > 1e-8 * max(w.max(), 1e-300)
    proj = v[:, keep].T @ r
    q = float(np.sum(proj**2 / w[keep]))
    k = max(int(keep.sum()) - num_fitted, 1)
    if num_replicates is not None and num_replicates - k > 2:
        dof = num_replicates - k
        p = float(stats.f.sf(q * dof / (k * (num_replicates - 1)), k, dof))
    else:
        p = float(stats.chi2.sf(q, k))
    return dict(chi2=q, dof=k, p_value=p)


def directed_score(t: float, one_sided: int) -> tuple[float, float]:
    """Score and p-value of a matched-filter statistic ``t`` under the effect's prior sign.

    Parameters
    ----------
    t : float
        Signed statistic, positive in the direction of increasing effect parameter; N(0, 1) under
        the null.
    one_sided : {-1, 0, 1}
        :attr:`Effect.one_sided`: 0 scores ``|t|`` with a two-sided p-value; +-1 scores only the
        sign the prior allows (``max(signed t, 0)``) with a one-sided p-value.

    Returns
    -------
    (score, p_value) : tuple of float
    """
    signed = t * (one_sided if one_sided else 1.0)
    score = max(signed, 0.0) if one_sided else abs(t)
    p = float(stats.norm.sf(signed) if one_sided else 2 * stats.norm.sf(abs(t)))
    return score, p
