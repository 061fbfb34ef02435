"""Gain of the extended model on held-out summaries, each measure with a standard error.

Measures (flat dict, JSON-ready):

- ``delta_lpd``: log predictive density of the held-out vector, extended minus base, with a
  multivariate Gaussian predictive density per model (mean and shrunk covariance of its posterior
  predictive draws).  ``delta_lpd_se`` is its standard deviation over replicate data sets
  simulated at the extended model's estimate (fresh seeds): how much the gain would move with
  another realisation of the measurement noise.  ``delta_lpd_se_summaries`` is the alternative
  SE over noise-whitened held-out summaries (as in LOO-CV's elpd difference).
- ``discrepancy_base`` / ``discrepancy_extended`` / ``discrepancy_reduction``: mean squared
  noise-whitened distance of the observed held-out summaries from each predictive mean (SE as
  above).
- ``coverage_base`` / ``coverage_extended``: fraction of held-out summaries inside each model's
  90 % predictive band (binomial SE).
- ``effect_mean``, ``effect_sd``, ``effect_ci95``, ``effect_excludes_null``,
  ``effect_z_from_null``: the new parameter's posterior against its null.
- ``log_bayes_factor``: Savage-Dickey ``log p(eta_null) - log p(eta_null | data)`` for the nested
  pair (extended : base), with a bootstrap SE; a lower bound when no particle lies near the null.
  A KDE of n particles cannot resolve a density below about one particle's kernel, so the value
  is capped at ``log_bayes_factor_cap`` (which grows only like log n); ``log_bayes_factor_gaussian``
  evaluates a Gaussian fitted to the weighted particles (truncated to the prior box) at the null,
  which is not capped and is the figure to read when the KDE value sits at its cap.
- ``effect_contraction``: ``1 - posterior sd / prior sd`` of the new parameter;
  ``effect_excludes_null`` needs the 95 % interval to exclude the null *and* a contraction above
  one half (a posterior that repeats a one-sided prior "excludes" a boundary null trivially).
- ``significant``: ``delta_lpd > 2 * delta_lpd_se``; ``counts``: significant and the new
  parameter is away from its null.  A gain counts only when it exceeds its uncertainty (a wider
  predictive alone can raise the log density of an outlier).
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from jaxabc.criticism.causes import Effect
from jaxabc.criticism.predictive import shrunk_covariance
from jaxabc.results import ABCResult

__all__ = ["gaussian_log_density", "held_out_gain", "savage_dickey", "savage_dickey_cap", "savage_dickey_gaussian"]


def gaussian_log_density(y: np.ndarray, draws: np.ndarray) -> np.ndarray:
    """Log density of rows of ``y`` (n, k) under a Gaussian fitted to ``draws`` (m, k); (n,)."""
    mean = draws.mean(axis=0)
    cov = shrunk_covariance(draws) if draws.shape[1] > 1 else np.atleast_2d(draws.var(ddof=1))
    # scipy's stubs type ``cov`` as int; it takes any (k, k) covariance array.
    dist = stats.multivariate_normal(mean, cov, allow_singular=True)  # pyright: ignore[reportArgumentType]
    return dist.logpdf(np.atleast_2d(y)).reshape(-1)


def _weighted_kde_at(x0: float, x: np.ndarray, w: np.ndarray, low: float, high: float) -> float:
    """Weighted Gaussian KDE at ``x0`` with reflection at the prior bounds."""
    sd = np.sqrt(np.cov(x, aweights=w)) if x.size > 1 else 0.0
    n_eff = 1.0 / np.sum(w**2)
    h = max(1.06 * sd * n_eff ** (-0.2), 1e-6 * (high - low))
    dens = np.sum(w * stats.norm.pdf(x0, x, h))
    dens += np.sum(w * stats.norm.pdf(x0, 2 * low - x, h)) + np.sum(w * stats.norm.pdf(x0, 2 * high - x, h))
    return float(dens)


def savage_dickey(
    result: ABCResult, column: int, effect: Effect, seed: int = 0, num_bootstrap: int = 100
) -> tuple[float, float, bool]:
    """Savage-Dickey log Bayes factor (extended : base) at ``effect.null``; (value, se, is_bound).

    The base model is the extended one with ``eta = null``, so ``BF = p(null) / p(null | data)``
    with the prior density ``1 / (high - low)``.  The posterior density comes from a reflected
    weighted KDE; when it is below what one particle would give, the value is reported as a
    lower bound.
    """
    x, w = result.particles[:, column], result.weights
    prior_density = 1.0 / (effect.high - effect.low)
    n_eff = 1.0 / np.sum(w**2)
    sd = float(np.sqrt(np.cov(x, aweights=w)))
    floor = 1.0 / (n_eff * max(1.06 * sd * n_eff ** (-0.2), 1e-12) * np.sqrt(2 * np.pi)) * np.exp(-2.0)
    dens = _weighted_kde_at(effect.null, x, w, effect.low, effect.high)
    bound = dens < floor
    value = float(np.log(prior_density) - np.log(max(dens, floor)))
    rng = np.random.default_rng(seed)
    boots = []
    for _ in range(num_bootstrap):
        i = rng.choice(x.size, x.size, p=w)
        d = _weighted_kde_at(effect.null, x[i], np.full(x.size, 1.0 / x.size), effect.low, effect.high)
        boots.append(np.log(prior_density) - np.log(max(d, floor)))
    return value, float(np.std(boots)), bool(bound)


def savage_dickey_cap(result: ABCResult, column: int, effect: Effect) -> float:
    """The largest log Bayes factor :func:`savage_dickey` can return with this sample."""
    x, w = result.particles[:, column], result.weights
    n_eff = 1.0 / np.sum(w**2)
    sd = float(np.sqrt(np.cov(x, aweights=w)))
    floor = 1.0 / (n_eff * max(1.06 * sd * n_eff ** (-0.2), 1e-12) * np.sqrt(2 * np.pi)) * np.exp(-2.0)
    return float(-np.log(effect.high - effect.low) - np.log(floor))


def savage_dickey_gaussian(result: ABCResult, column: int, effect: Effect) -> float:
    """Savage-Dickey log Bayes factor with a Gaussian posterior for the effect parameter.

    The weighted mean and sd of column ``column`` define a normal truncated to the prior box;
    ``log BF = log p(null) - log p(null | data)`` is then exact for that density, with no floor,
    so an effect many posterior sd from its null gets ``~ z^2 / 2``.  It assumes the marginal
    posterior is close to Gaussian near its bulk and extrapolates its tail to the null.
    """
    x, w = result.particles[:, column], result.weights
    mean = float(np.sum(w * x))
    sd = float(np.sqrt(np.sum(w * (x - mean) ** 2)))
    if not sd > 0:
        return float("inf") if mean != effect.null else float("nan")
    mass = stats.norm.cdf(effect.high, mean, sd) - stats.norm.cdf(effect.low, mean, sd)
    log_post = stats.norm.logpdf(effect.null, mean, sd) - np.log(max(mass, 1e-300))
    return float(-np.log(effect.high - effect.low) - log_post)


def held_out_gain(
    observed: np.ndarray,
    held_out: np.ndarray,
    base_draws: np.ndarray,
    extended_draws: np.ndarray,
    extended_replicates: np.ndarray,
    noise_cov: np.ndarray,
    extension: ABCResult | None = None,
    effect: Effect | None = None,
    effect_column: int | None = None,
    level: float = 0.9,
    seed: int = 0,
) -> dict[str, float | bool | list[float] | None]:
    """Held-out measures of the gain, each with a standard error.

    Parameters
    ----------
    observed : numpy.ndarray, shape (s,)
    held_out : numpy.ndarray of bool, shape (s,)
        The held-out summaries that vary (constant ones excluded by the caller).
    base_draws, extended_draws : numpy.ndarray, shape (m, s)
        Posterior predictive draws of each model.
    extended_replicates : numpy.ndarray, shape (r, s)
        Replicates at the extended model's estimate (fresh seeds): the pseudo-data for the SEs.
    noise_cov : numpy.ndarray, shape (s, s)
    extension : ABCResult, optional
        The extended fit, for the new parameter's posterior and the Bayes factor.
    effect : Effect, optional
    effect_column : int, optional
        Column of the effect parameter in ``extension.particles``.
    """
    out: dict[str, float | bool | list[float] | None] = {"num_held_out": int(held_out.sum())}
    if held_out.any():
        h = held_out
        out.update(
            _predictive_measures(
                observed[h],
                base_draws[:, h],
                extended_draws[:, h],
                extended_replicates[:, h],
                noise_cov[np.ix_(h, h)],
                level,
            )
        )
    else:
        out["significant"] = False
    if extension is not None and effect is not None and effect_column is not None:
        out.update(_effect_measures(extension, effect, effect_column, seed))
    out["counts"] = bool(out.get("significant") and out.get("effect_excludes_null", True))
    return out


def _predictive_measures(
    y: np.ndarray, bd: np.ndarray, ed: np.ndarray, reps: np.ndarray, cov: np.ndarray, level: float
) -> dict[str, float | bool | None]:
    """Log density, discrepancy and coverage of the held-out data ``y`` (h,) under the base
    and extended predictive draws ``bd``, ``ed`` (m, h), with SEs over the replicates ``reps``
    (r, h) at the extended estimate; ``cov`` (h, h) is the noise covariance."""
    out: dict[str, float | bool | None] = {}
    pseudo = np.vstack([y[None], reps])
    lpd = gaussian_log_density(pseudo, ed) - gaussian_log_density(pseudo, bd)
    out["lpd_base"] = float(gaussian_log_density(y[None], bd)[0])
    out["lpd_extended"] = float(gaussian_log_density(y[None], ed)[0])
    out["delta_lpd"] = float(lpd[0])
    out["delta_lpd_se"] = float(np.std(lpd[1:], ddof=1))
    chol = np.linalg.cholesky(cov + 1e-12 * np.eye(y.size))
    white = lambda v: np.linalg.solve(chol, np.atleast_2d(v).T).T  # noqa: E731
    disc_b = np.mean(white(pseudo - bd.mean(axis=0)) ** 2, axis=1)
    disc_e = np.mean(white(pseudo - ed.mean(axis=0)) ** 2, axis=1)
    out["discrepancy_base"] = float(disc_b[0])
    out["discrepancy_extended"] = float(disc_e[0])
    out["discrepancy_reduction"] = float(disc_b[0] - disc_e[0])
    out["discrepancy_reduction_se"] = float(np.std(disc_b[1:] - disc_e[1:], ddof=1))
    # Per-summary lpd on whitened coordinates (roughly independent): the LOO-style SE.
    wy, wb, we = white(y)[0], white(bd), white(ed)
    per = stats.norm.logpdf(wy, we.mean(0), we.std(0, ddof=1)) - stats.norm.logpdf(wy, wb.mean(0), wb.std(0, ddof=1))
    out["delta_lpd_summaries"] = float(per.sum())
    out["delta_lpd_se_summaries"] = float(np.sqrt(per.size) * per.std(ddof=1)) if per.size > 1 else None
    q = (1.0 - level) / 2.0
    for label, draws in (("base", bd), ("extended", ed)):
        lo, hi = np.quantile(draws, q, axis=0), np.quantile(draws, 1 - q, axis=0)
        c = float(np.mean((y >= lo) & (y <= hi)))
        out[f"coverage_{label}"] = c
        out[f"coverage_{label}_se"] = float(np.sqrt(max(c * (1 - c), 1.0 / y.size) / y.size))
    out["coverage_level"] = level
    out["significant"] = bool(out["delta_lpd"] > 2.0 * out["delta_lpd_se"])
    return out


def _effect_measures(
    extension: ABCResult, effect: Effect, column: int, seed: int
) -> dict[str, float | bool | list[float]]:
    """The new parameter's posterior (column ``column`` of ``extension``) against its null, and
    the Savage-Dickey log Bayes factors (module doc)."""
    out: dict[str, float | bool | list[float]] = {}
    x, w = extension.particles[:, column], extension.weights
    mean = float(np.sum(w * x))
    sd = float(np.sqrt(np.sum(w * (x - mean) ** 2)))
    ci = extension.credible_interval(0.95)[column]
    out["effect_mean"] = mean
    out["effect_sd"] = sd
    out["effect_ci95"] = [float(ci[0]), float(ci[1])]
    # A posterior that merely repeats a one-sided prior has an equal-tailed interval that
    # "excludes" a null sitting on the boundary; require that the data taught something.
    prior_sd = (effect.high - effect.low) / np.sqrt(12.0)
    out["effect_contraction"] = float(1.0 - sd / prior_sd)
    out["effect_excludes_null"] = bool(not ci[0] <= effect.null <= ci[1] and sd < 0.5 * prior_sd)
    out["effect_z_from_null"] = float(abs(mean - effect.null) / sd) if sd > 0 else float("inf")
    bf, bf_se, bound = savage_dickey(extension, column, effect, seed=seed)
    out["log_bayes_factor"] = bf
    out["log_bayes_factor_se"] = bf_se
    out["log_bayes_factor_is_lower_bound"] = bound
    out["log_bayes_factor_cap"] = savage_dickey_cap(extension, column, effect)
    out["log_bayes_factor_gaussian"] = savage_dickey_gaussian(extension, column, effect)
    return out
