"""What the calibrated model gets wrong: standardised residuals and calibrated p-values.

Method
------
1. The residual is ``r = y_obs - mu`` with ``mu`` the mean of the replicates at the Bayes
   estimate.  Before testing, the base parameters absorb what they locally can: one generalised
   least-squares step on the *fitted* summaries, ``r_c = A r`` with
   ``A = I - J (J_f' S_ff^-1 J_f)^+ J_f' S_ff^-1 P_f`` (``J`` the finite-difference sensitivity of
   the expected summaries to the base parameters, ``S`` the simulation-noise covariance, ``P_f``
   the selection of fitted rows).  This makes the test insensitive to how tightly the ABC
   tolerance pinned the estimate down.
2. Calibration: under the model, ``r`` is noise plus the fit's use of that noise, so the null
   covariance of ``r_c`` is ``C = (1 + 1/R) A S A'`` -- the covariance of *replicate simulated
   data sets at the estimate* passed through the same refit (the ``1/R`` is the noise of ``mu``).
   This accounts both for the simulation noise and for the double use of the data on the fitted
   summaries (a plain posterior predictive p-value is conservative there).
3. Tests: each active summary, ``z = r_c / sqrt(C_ii)`` with a Student-t tail (``R - 1`` degrees
   of freedom, for the estimated noise); each group (region), the Hotelling statistic
   ``r_g' C_gg^+ r_g`` with an F tail.
4. Multiple testing: Holm's step-down (family-wise error rate) by default, or Benjamini-Hochberg
   (false-discovery rate), within two families -- fitted and held-out summaries -- each at level
   ``alpha / 2`` (Bonferroni across the families), so a correct model flags nothing with
   probability at least ``1 - alpha``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from jaxabc.criticism.predictive import PosteriorPredictive

__all__ = ["Misfit", "MisfitAnalysis", "adjust_pvalues", "analyse_misfits", "refit_operator"]


class Misfit(tuple):
    """A ranked misfit: unpacks as ``(name, standardised_residual, p_value)``.

    Further attributes: ``kind`` ("summary" or "group"), ``held_out``, ``adjusted_p_value``,
    ``flagged``, ``observed``, ``predictive_mean``, ``band`` (90 % predictive band),
    ``indices`` (summary indices), ``line`` (a human-readable sentence).
    """

    # Set per instance from ``details``; declared for type checkers.
    adjusted_p_value: float
    flagged: bool

    def __new__(cls, name: str, residual: float, p_value: float, **details):
        obj = super().__new__(cls, (name, float(residual), float(p_value)))
        obj.__dict__.update(details)
        return obj

    name = property(lambda self: self[0])
    residual = property(lambda self: self[1])
    p_value = property(lambda self: self[2])

    def __repr__(self) -> str:
        return (
            f"Misfit({self.name!r}, z={self.residual:+.2f}, p={self.p_value:.2e}, "
            f"adjusted={self.adjusted_p_value:.2e}{', flagged' if self.flagged else ''})"
        )


def adjust_pvalues(p: np.ndarray, method: str = "holm") -> np.ndarray:
    """Holm (FWER) or Benjamini-Hochberg (FDR) adjusted p-values, same shape as ``p``."""
    p = np.asarray(p, float)
    m = p.size
    if m == 0:
        return p
    order = np.argsort(p)
    ranked = p[order]
    if method == "holm":
        adj = np.maximum.accumulate((m - np.arange(m)) * ranked)
    elif method in ("bh", "fdr_bh", "benjamini-hochberg"):
        adj = np.minimum.accumulate(m / np.arange(m, 0, -1) * ranked[::-1])[::-1]
    else:
        raise ValueError(f"unknown multiple-testing correction {method!r}: use 'holm' or 'bh'")
    out = np.empty(m)
    out[order] = np.minimum(adj, 1.0)
    return out


def refit_operator(
    jacobian: np.ndarray, noise_cov: np.ndarray, fitted: np.ndarray, prior_precision: np.ndarray | None = None
) -> np.ndarray:
    """The linear refit ``A`` (s, s): residual after the base parameters absorb what they can.

    Parameters
    ----------
    jacobian : numpy.ndarray, shape (s, d)
        d E[summaries] / d theta_base.
    noise_cov : numpy.ndarray, shape (s, s)
    fitted : numpy.ndarray of bool, shape (s,)
        Summaries the base parameters were fitted to; only these steer the refit.
    prior_precision : numpy.ndarray, shape (d, d), optional
        Precision ``L`` of a Gaussian prior on the base parameters: the refit is then the
        maximum a posteriori step ``(J_f' S^-1 J_f + L)^-1 J_f' S^-1``, so parameters that
        independent knowledge pins down absorb only what that knowledge allows.  None: free.
    """
    s = jacobian.shape[0]
    jf = jacobian[fitted]
    prec = np.linalg.pinv(noise_cov[np.ix_(fitted, fitted)], rcond=1e-10, hermitian=True)
    normal = jf.T @ prec @ jf
    if prior_precision is not None:
        normal = normal + prior_precision
    # pinv: a parameter the fitted summaries do not see (zero column) simply absorbs nothing.
    gain = jacobian @ np.linalg.pinv(normal, rcond=1e-8, hermitian=True) @ jf.T @ prec
    a = np.eye(s)
    a[:, fitted] -= gain
    return a


def _group_stat(r: np.ndarray, cov: np.ndarray, num_replicates: int) -> tuple[float, float, int]:
    """Hotelling-type statistic of a region and its F-tail p-value; (T, p, rank)."""
    w, v = np.linalg.eigh(cov)
    keep = w > 1e-8 * max(w.max(), 1e-300)
    k = int(keep.sum())
    if k == 0:
        return 0.0, 1.0, 0
    proj = v[:, keep].T @ r
    t = float(np.sum(proj**2 / w[keep]))
    dof = num_replicates - k
    if dof > 2:
        p = float(stats.f.sf(t * dof / (k * (num_replicates - 1)), k, dof))
    else:
        p = float(stats.chi2.sf(t, k))
    return t, p, k


@dataclass
class MisfitAnalysis:
    """Everything the misfit step computed.

    Attributes
    ----------
    misfits : list of Misfit
        Every test, ranked by adjusted p-value (then |z|).
    residual : numpy.ndarray, shape (s,)
        ``y_obs - mu``.
    refit_residual : numpy.ndarray, shape (s,)
        ``A r`` (zero outside ``active``).
    null_cov : numpy.ndarray, shape (s, s)
        Null covariance of ``refit_residual``.
    refit : numpy.ndarray, shape (s, s)
        The operator ``A``.
    chi2, chi2_dof, chi2_p_value : float
        Global Hotelling statistic over all active summaries.
    """

    misfits: list[Misfit]
    residual: np.ndarray
    refit_residual: np.ndarray
    null_cov: np.ndarray
    refit: np.ndarray
    chi2: float
    chi2_dof: int
    chi2_p_value: float

    @property
    def flagged(self) -> list[Misfit]:
        return [m for m in self.misfits if m.flagged]


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def analyse_misfits(
    observed: np.ndarray,
    predictive: PosteriorPredictive,
    jacobian: np.ndarray,
    held_out: np.ndarray,
    *,
    alpha: float = 0.05,
    correction: str = "holm",
    level: float = 0.9,
    prior: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> MisfitAnalysis:
    """Standardised residuals and calibrated, corrected p-values per summary and per group.

    Parameters
    ----------
    observed : numpy.ndarray, shape (s,)
    predictive : PosteriorPredictive
    jacobian : numpy.ndarray, shape (s, d)
        Sensitivity of the expected summaries to the base parameters.
    held_out : numpy.ndarray of bool, shape (s,)
    alpha : float
        Overall family-wise level (split equally between the fitted and held-out families).
    correction : {"holm", "bh"}
    level : float
        Predictive band shown in the human-readable lines.
    prior : (precision (d, d), centre (d,), theta (d,)), optional
        A Gaussian prior on the base parameters and the point ``theta`` the residual was taken
        at: the refit becomes the maximum a posteriori step from the prior centre and the null
        covariance gains the prior's spread, ``J (N + L)^-1 L (N + L)^-1 J'`` with
        ``N = J_f' S^-1 J_f`` (see :func:`refit_operator`).  None: the base parameters are free.

    Returns
    -------
    MisfitAnalysis
        Every summary and group test, ranked by adjusted p-value (see the module doc).
    """
    act = predictive.active
    num_rep = predictive.replicates.shape[0]
    r = observed - predictive.replicate_mean
    a, null, shift = _refit_and_null(predictive, jacobian, held_out, prior)
    rc = a @ np.where(act, r, 0.0) + shift
    tests = _summary_tests(observed, predictive, rc, null, held_out, level)
    tests += _group_tests(observed, predictive, rc, null, held_out, level)
    _adjust_within_families(tests, held_out[act], alpha, correction)
    misfits = [_as_misfit(t, level) for t in tests]
    misfits.sort(key=lambda m: (m.adjusted_p_value, m.p_value, -abs(m.residual)))
    chi2, chi2_p, k = _group_stat(rc[act], null[np.ix_(act, act)], num_rep)
    return MisfitAnalysis(misfits, r, rc, null, a, chi2, k, chi2_p)


def _refit_and_null(
    predictive: PosteriorPredictive,
    jacobian: np.ndarray,
    held_out: np.ndarray,
    prior: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The refit operator ``A``, the null covariance ``(1 + 1/R) A S A'`` (both (s, s)) and a
    shift (s,) to add to ``A r``.

    Built on the active summaries and zero elsewhere; only the fitted (not held-out) summaries
    steer the refit.  ``R`` is the number of replicates behind the noise covariance ``S``.
    Without ``prior`` the shift is zero.  With a prior (precision ``L``, centre ``t0``, residual
    point ``t``), the refit is linearised about the prior centre: ``r_c = A (r + J (t - t0))
    = A r + J (N + L)^-1 L (t - t0)``, and the null covariance adds the prior's spread passed
    through the refit, ``J (N + L)^-1 L (N + L)^-1 J'`` (a linear-Gaussian model whose base
    parameters are drawn from the prior).
    """
    act = predictive.active
    s = act.shape[0]
    num_rep = predictive.replicates.shape[0]
    cov = predictive.noise_cov[np.ix_(act, act)]
    fitted = ~held_out[act]
    a_act = refit_operator(jacobian[act], cov, fitted, None if prior is None else prior[0])
    a = np.zeros((s, s))
    a[np.ix_(act, act)] = a_act
    null = np.zeros((s, s))
    null[np.ix_(act, act)] = (1.0 + 1.0 / num_rep) * a_act @ cov @ a_act.T
    shift = np.zeros(s)
    if prior is not None:
        lam, centre, theta = (np.asarray(x, float) for x in prior)
        jac = jacobian[act]
        jf = jac[fitted]
        prec = np.linalg.pinv(cov[np.ix_(fitted, fitted)], rcond=1e-10, hermitian=True)
        inv = np.linalg.pinv(jf.T @ prec @ jf + lam, rcond=1e-8, hermitian=True)
        absorbed = jac @ inv @ lam
        shift[act] = absorbed @ (theta - centre)
        null[np.ix_(act, act)] += absorbed @ inv @ jac.T
    return a, null, shift


def _summary_tests(
    observed: np.ndarray,
    predictive: PosteriorPredictive,
    rc: np.ndarray,
    null: np.ndarray,
    held_out: np.ndarray,
    level: float,
) -> list[dict]:
    """One test per active summary: ``z = rc_i / sqrt(C_ii)`` with a Student-t tail on ``R - 1``
    degrees of freedom (the noise is estimated from ``R`` replicates)."""
    num_rep = predictive.replicates.shape[0]
    band = predictive.band(level)
    pred_mean = predictive.mean()
    tests: list[dict] = []
    for i in np.flatnonzero(predictive.active):
        sd = np.sqrt(max(null[i, i], 1e-300))
        z = rc[i] / sd
        tests.append(
            dict(
                name=predictive.names[i],
                residual=z,
                p_value=float(2 * stats.t.sf(abs(z), num_rep - 1)),
                kind="summary",
                indices=np.array([i]),
                held_out=bool(held_out[i]),
                observed=float(observed[i]),
                predictive_mean=float(pred_mean[i]),
                band=(float(band[i, 0]), float(band[i, 1])),
            )
        )
    return tests


def _group_tests(
    observed: np.ndarray,
    predictive: PosteriorPredictive,
    rc: np.ndarray,
    null: np.ndarray,
    held_out: np.ndarray,
    level: float,
) -> list[dict]:
    """One Hotelling test per group of two or more active summaries (F tail).

    A group that mixes fitted and held-out summaries is tested as its two parts, one per
    family.  The reported ``z`` is the normal quantile of the p-value, signed like the mean
    standardised residual over the region.
    """
    act, num_rep = predictive.active, predictive.replicates.shape[0]
    tests: list[dict] = []
    for gname, idx in predictive.groups.items():
        idx = idx[act[idx]]
        parts = [(gname, idx)]
        if held_out[idx].any() and (~held_out[idx]).any():
            parts = [(f"{gname} [fitted part]", idx[~held_out[idx]]), (f"{gname} [held-out part]", idx[held_out[idx]])]
        for name, sub in parts:
            if sub.size < 2:
                continue  # a one-summary group is already tested as that summary
            t, p, _k = _group_stat(rc[sub], null[np.ix_(sub, sub)], num_rep)
            mean_res = float(np.mean(rc[sub] / np.sqrt(np.maximum(np.diag(null)[sub], 1e-300))))
            z = float(np.sign(mean_res) * stats.norm.isf(max(p, 1e-300) / 2))
            region_draws = predictive.draws[:, sub].mean(axis=1)
            tests.append(
                dict(
                    name=name,
                    residual=z,
                    p_value=p,
                    kind="group",
                    indices=sub,
                    held_out=bool(held_out[sub].all()),
                    observed=float(observed[sub].mean()),
                    predictive_mean=float(region_draws.mean()),
                    band=tuple(float(x) for x in np.quantile(region_draws, [(1 - level) / 2, (1 + level) / 2])),
                    statistic=t,
                )
            )
    return tests


def _adjust_within_families(tests: list[dict], held_out_active: np.ndarray, alpha: float, correction: str) -> None:
    """Add ``adjusted_p_value``, ``flagged`` and ``family_alpha`` to each test, in place.

    The fitted and held-out tests are separate families, each at ``alpha / 2`` when both exist
    (Bonferroni across them); ``held_out_active`` is the held-out mask of the active summaries.
    """
    both = held_out_active.any() and (~held_out_active).any()
    families = [False, True] if both else [bool(held_out_active.all())]
    fam_alpha = alpha / len(families)
    for fam in families:
        members = [t for t in tests if t["held_out"] == fam]
        adj = adjust_pvalues(np.array([t["p_value"] for t in members]), correction)
        for t, q in zip(members, adj, strict=True):
            t["adjusted_p_value"] = float(q)
            t["flagged"] = bool(q <= fam_alpha)
            t["family_alpha"] = fam_alpha


def _as_misfit(test: dict, level: float) -> Misfit:
    """The :class:`Misfit` of one test (consumed), with its human-readable ``line``."""
    t = test
    what = "mean over the region " if t["kind"] == "group" else ""
    t["line"] = (
        f"{t['name']}{' (held out)' if t['held_out'] else ''}: {what}observed {_fmt(t['observed'])}, "
        f"predictive {round(level * 100)}% band [{_fmt(t['band'][0])}, {_fmt(t['band'][1])}] "
        f"(z = {t['residual']:+.2f}, adjusted p = {t['adjusted_p_value']:.2g})"
    )
    return Misfit(t.pop("name"), t.pop("residual"), t.pop("p_value"), **t)
