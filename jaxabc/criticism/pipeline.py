"""The data-dependent half of the criticism loop, as one reusable step.

:func:`jaxabc.criticism.critique` runs it once on the observed data; the detection-power
estimate (:mod:`jaxabc.criticism.power`) runs the very same step on replicate data sets, so that
"the pipeline names the effect" means the same thing in both places.

Given observed summaries and the posterior predictive of the base calibration (simulated once:
it does not depend on the data), :meth:`Pipeline.diagnose`

1. moves the base parameters from the Bayes estimate to the local best fit of the fitted
   summaries (Gauss-Newton, expectations over common random numbers);
2. re-simulates the replicates at that point (the noise yardstick);
3. estimates the base and effect sensitivities there;
4. tests the misfits (:func:`jaxabc.criticism.misfit.analyse_misfits`) and ranks the causes,
   with the joint (conditional) test (:func:`jaxabc.criticism.causes.rank_causes`).

Evaluations that do not depend on the data (the mean and sensitivities at the Bayes estimate,
where every Gauss-Newton run starts) are memoised: a replicate data set pays only for where its
own refit goes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import jax
import numpy as np

from jaxabc.criticism.causes import Catalogue, CauseAnalysis, rank_causes, sensitivities
from jaxabc.criticism.misfit import MisfitAnalysis, analyse_misfits
from jaxabc.criticism.predictive import PosteriorPredictive, shrunk_covariance, simulate_many

__all__ = ["Diagnosis", "Pipeline"]


@dataclass
class Diagnosis:
    """What one pass of :meth:`Pipeline.diagnose` found on one data set."""

    predictive: PosteriorPredictive
    theta: np.ndarray
    jacobian: np.ndarray
    directions: np.ndarray
    misfits: MisfitAnalysis
    causes: CauseAnalysis
    fitted: np.ndarray

    def names(self, effect: str) -> bool:
        """Whether the pipeline names ``effect``: something is flagged *and* the joint test
        selects the effect among the causes still needed."""
        return bool(self.misfits.flagged) and effect in self.causes.needed


@dataclass
class Pipeline:
    """Settings of the data-dependent criticism steps (see the module docstring)."""

    simulate: Callable
    executor: Any
    catalogue: Catalogue
    num_base: int
    held_out: np.ndarray
    groups: dict[str, np.ndarray]
    low: np.ndarray
    high: np.ndarray
    steps: np.ndarray
    num_gradient_replicates: int
    num_refit_iterations: int = 4
    alpha: float = 0.01
    correction: str = "holm"
    cause_alpha: float = 0.01
    ambiguity_cosine: float = 0.95
    invisible_snr: float = 3.0
    level: float = 0.9
    #: Gaussian prior on the base parameters for the local refit: precision (d, d) and centre
    #: (d,); None leaves them free (see :func:`jaxabc.criticism.critique`'s ``base_prior``).
    prior_precision: np.ndarray | None = None
    prior_centre: np.ndarray | None = None
    _memo: dict = field(default_factory=dict, repr=False)

    def base_points(self, theta: np.ndarray) -> list[tuple[int, float, float]]:
        lo, hi, st = self.low, self.high, self.steps
        return [(j, max(theta[j] - st[j], lo[j]), min(theta[j] + st[j], hi[j])) for j in range(self.num_base)]

    def _cached(self, what: str, theta: np.ndarray, keys: Any, fn: Callable[[], np.ndarray]) -> np.ndarray:
        # Keyed on the exact point and the common random numbers: a hit is the same computation.
        tag = (what, np.asarray(theta, float).tobytes(), np.asarray(jax.random.key_data(keys)).tobytes())
        if tag not in self._memo:
            self._memo[tag] = fn()
        return self._memo[tag]

    def _mean(self, theta: np.ndarray, keys: Any) -> np.ndarray:
        n = keys.shape[0]
        return self._cached(
            "mean",
            theta,
            keys,
            lambda: np.nanmean(simulate_many(self.simulate, keys, np.repeat(theta[None], n, 0), self.executor), 0),
        )

    def _sens(self, theta: np.ndarray, keys: Any, points: list) -> np.ndarray:
        tag = "sens" + repr(points)
        return self._cached(tag, theta, keys, lambda: sensitivities(self.simulate, theta, keys, points, self.executor))

    def diagnose(self, observed: np.ndarray, predictive: PosteriorPredictive) -> Diagnosis:
        """Refit locally, re-estimate the noise and sensitivities, test misfits and rank causes.

        Parameters
        ----------
        observed : numpy.ndarray, shape (s,)
        predictive : PosteriorPredictive
            The base calibration's predictive at its Bayes estimate (effects at null).
        """
        obs = np.asarray(observed, np.float64)
        d, pred = self.num_base, predictive
        ex, sim = self.executor, self.simulate
        num_grad = self.num_gradient_replicates
        grad_keys = pred.replicate_keys[:num_grad]
        fitted = pred.active & ~self.held_out
        prec_f = np.linalg.pinv(pred.noise_cov[np.ix_(fitted, fitted)], rcond=1e-10, hermitian=True)
        theta_hat = np.asarray(pred.theta_hat, float)
        theta = theta_hat.copy()
        jac = None
        for it in range(self.num_refit_iterations):
            mu = self._mean(theta, grad_keys)
            if jac is None or it % 2 == 0:
                # The Jacobian of smooth expectations barely changes over these short moves: it is
                # re-estimated on every other step only (each estimate costs 2 d times the mean's).
                jac = self._sens(theta, grad_keys, self.base_points(theta))
            jf = jac[fitted]
            if self.prior_precision is None or self.prior_centre is None:
                normal = np.linalg.pinv(jf.T @ prec_f @ jf, rcond=1e-8, hermitian=True)
                step = normal @ jf.T @ prec_f @ (obs - mu)[fitted]
            else:  # the maximum a posteriori step under the base parameters' Gaussian prior
                lam = self.prior_precision
                rhs = jf.T @ prec_f @ (obs - mu)[fitted] - lam @ (theta[:d] - self.prior_centre)
                step = np.linalg.pinv(jf.T @ prec_f @ jf + lam, rcond=1e-8, hermitian=True) @ rhs
            new = np.clip(theta[:d] + step, self.low, self.high)
            moved = np.abs(new - theta[:d])
            theta[:d] = new
            if np.all(moved < 0.05 * self.steps):
                break
        if self.num_refit_iterations:
            reps = simulate_many(sim, pred.replicate_keys, np.repeat(theta[None], len(pred.replicate_keys), 0), ex)
            ok_r = np.all(np.isfinite(reps), axis=1)
            pred = replace(
                pred,
                theta_hat=theta,
                replicates=reps[ok_r],
                replicate_keys=pred.replicate_keys[ok_r],
                noise_cov=shrunk_covariance(reps[ok_r]),
                extra=dict(pred.extra),
            )
            pred.extra["bayes_estimate"] = theta_hat
            grad_keys = pred.replicate_keys[:num_grad]
        points = self.base_points(theta) + [
            (d + k, *eff.finite_difference_points()) for k, eff in enumerate(self.catalogue)
        ]
        sens = self._sens(theta, grad_keys, points)
        jac, directions = sens[:, :d], sens[:, d:]
        prior = None
        if self.prior_precision is not None and self.prior_centre is not None:
            prior = (self.prior_precision, self.prior_centre, theta[:d])
        mis = analyse_misfits(
            obs, pred, jac, self.held_out, alpha=self.alpha, correction=self.correction, level=self.level, prior=prior
        )
        causes = rank_causes(
            self.catalogue,
            directions,
            mis.refit,
            mis.refit_residual,
            mis.null_cov,
            self.groups,
            alpha=self.cause_alpha,
            ambiguity_cosine=self.ambiguity_cosine,
            invisible_snr=self.invisible_snr,
            num_replicates=len(pred.replicate_keys),
        )
        return Diagnosis(pred, theta, jac, directions, mis, causes, pred.active & ~self.held_out)
