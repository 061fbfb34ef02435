"""Every algorithm against analytic ABC posteriors (see jaxabc.examples for the derivations).

Tolerances are Monte Carlo errors at the run's effective sample size: the standard error of a
weighted mean is sd / sqrt(ESS), of a variance var * sqrt(2 / ESS), of a correlation
(1 - rho^2) / sqrt(ESS).  Checks use 4 standard errors at fixed seeds.  For ABCsubsim the
particles of a level are correlated along their chains, so its effective size is taken as the
number of chains (N P0), a conservative bound.
"""

import math

import numpy as np
import pytest

import jaxabc
from jaxabc import examples

Z = 4.0


def _check_gaussian(result, ess):
    eps = float(result.thresholds[-1])
    var_exact = examples.gaussian_abc_variance(eps)
    mean = result.bayes_estimate()[0]
    var = result.covariance()[0, 0]
    assert abs(mean) < Z * math.sqrt(var_exact / ess), (mean, ess)
    assert abs(var - var_exact) < Z * var_exact * math.sqrt(2 / ess), (var, var_exact, ess)
    return eps, var


GAUSS_CASES = {
    "rejection": dict(num_particles=2000, quantile=0.02),
    "pmcabc": dict(num_particles=1000, num_steps=5),
    "apmcabc": dict(num_particles=5000, num_steps=6, alpha=0.1, acceptance_cutoff=0.03),
    "abcsubsim": dict(num_particles=2000, p0=0.2, final_threshold=0.4, num_steps=10),
}


@pytest.mark.parametrize("algorithm", sorted(GAUSS_CASES))
def test_gaussian_mean_posterior(algorithm, gaussian_problem):
    prior, simulate, observed = gaussian_problem
    opts = dict(GAUSS_CASES[algorithm])
    n = opts.pop("num_particles")
    result = jaxabc.run(algorithm, simulate, prior, observed, num_particles=n,
                        distance="euclidean", seed=11, **opts)
    assert np.isclose(result.weights.sum(), 1.0)
    ess = result.effective_sample_size()
    if algorithm == "abcsubsim":
        ess = min(ess, n * 0.2)
    _check_gaussian(result, ess)


@pytest.mark.parametrize("algorithm", ["rejection", "pmcabc", "apmcabc"])
def test_correlated_gaussian_posterior(algorithm, correlated_problem):
    prior, simulate, observed = correlated_problem
    opts = {"rejection": dict(quantile=0.01), "pmcabc": dict(num_steps=4),
            "apmcabc": dict(num_steps=8, alpha=0.1)}[algorithm]
    n = 5000 if algorithm == "apmcabc" else 2000
    result = jaxabc.run(algorithm, simulate, prior, observed, num_particles=n,
                        distance="euclidean", seed=5, **opts)
    eps = float(result.thresholds[-1])
    ess = result.effective_sample_size()
    rho_exact = examples.correlated_abc_correlation(eps)
    cov_exact = np.array([[1, examples.RHO], [examples.RHO, 1]]) + eps**2 / 4 * np.eye(2)
    np.testing.assert_array_less(np.abs(result.bayes_estimate()),
                                 Z * np.sqrt(np.diag(cov_exact) / ess))
    rho = result.correlation()[0, 1]
    assert abs(rho - rho_exact) < Z * (1 - rho_exact**2) / math.sqrt(ess), (rho, rho_exact, ess)


def test_abc_posterior_converges_as_threshold_shrinks(gaussian_problem):
    prior, simulate, observed = gaussian_problem
    variances = []
    for q in (0.5, 0.01):
        r = jaxabc.run("rejection", simulate, prior, observed, num_particles=3000, quantile=q,
                       distance="euclidean", seed=2)
        eps, var = _check_gaussian(r, r.effective_sample_size())
        variances.append((eps, var))
    (eps_big, var_big), (eps_small, var_small) = variances
    assert eps_small < 0.2 < 1.5 < eps_big
    # The wide tolerance inflates the variance well beyond its error; the small one does not.
    assert var_big - 1 > Z * var_big * math.sqrt(2 / 3000)
    assert abs(var_small - 1) < Z * math.sqrt(2 / 3000) + eps_small**2 / 3


def test_apmcabc_simulation_count(gaussian_problem):
    prior, simulate, observed = gaussian_problem
    n, alpha = 1000, 0.15
    r = jaxabc.run("apmcabc", simulate, prior, observed, num_particles=n, num_steps=5,
                   alpha=alpha, acceptance_cutoff=0.0, seed=0)
    k = len(r.thresholds) - 1
    assert k == 4
    assert r.num_simulations == n + k * (n - math.ceil(alpha * n))
    assert list(r.simulations_per_step) == [n] + [n - math.ceil(alpha * n)] * k
    assert np.all(np.diff(r.thresholds) <= 0)


def test_apmcabc_stops_on_acceptance_cutoff(gaussian_problem):
    prior, simulate, observed = gaussian_problem
    r = jaxabc.run("apmcabc", simulate, prior, observed, num_particles=1000, alpha=0.1,
                   acceptance_cutoff=0.03, seed=0)
    assert "cutoff" in r.stop_reason
    assert r.acceptance_rates[-1] < 0.03 <= r.acceptance_rates[-2]


def test_abcpy_weight_mode_misestimates_posterior_variance(gaussian_problem):
    """ABCpy 0.6 mixes renormalised kept weights with unnormalised new ones and reports the
    merged population.  Measured with ABCpy 0.6.3 itself on this problem (N=1000, alpha=0.1,
    4 seeds): posterior variance 4.4-28 instead of about 1.  Our 'abcpy' mode reproduces the
    failure, the default 'lenormand' mode does not."""
    prior, simulate, observed = gaussian_problem
    out = {}
    for mode in ("lenormand", "abcpy"):
        r = jaxabc.run("apmcabc", simulate, prior, observed, num_particles=2000, num_steps=8,
                       alpha=0.1, acceptance_cutoff=0.03, weights=mode, distance="euclidean",
                       seed=3)
        out[mode] = (r.covariance()[0, 0], r.effective_sample_size(), float(r.thresholds[-1]))
    var, ess, eps = out["lenormand"]
    assert abs(var - examples.gaussian_abc_variance(eps)) < Z * math.sqrt(2 / ess)
    var_abcpy, ess_abcpy, eps_abcpy = out["abcpy"]
    assert var_abcpy - examples.gaussian_abc_variance(eps_abcpy) > 10 * math.sqrt(2 / ess_abcpy)


def test_abcsubsim_evidence_matches_acceptance_probability(gaussian_problem):
    """P(|theta + Z| < eps) under U[-10, 10] is computable; ABCsubsim estimates it as P0^j.

    The estimator's coefficient of variation is about sqrt(j (1 - P0) / (P0 N) (1 + gamma))
    (Au & Beck 2001) with gamma the chain correlation factor; with gamma <= 3 (chains of 5)
    and j <= 4 levels, N = 2000, that is < 0.2, so the log estimate is checked within 0.6
    (3 CoV)."""
    from scipy.integrate import quad
    from scipy.stats import norm

    prior, simulate, observed = gaussian_problem
    r = jaxabc.run("abcsubsim", simulate, prior, observed, num_particles=2000, p0=0.2,
                   final_threshold=0.15, num_steps=10, distance="euclidean", seed=4)
    eps = float(r.thresholds[-1])
    levels = len(r.thresholds) - 1
    exact = quad(lambda t: (norm.cdf(eps - t) - norm.cdf(-eps - t)) / 20.0, -10, 10)[0]
    assert r.log_evidence == pytest.approx(levels * math.log(0.2))
    cov = math.sqrt(levels * 0.8 / (0.2 * 2000) * 4)
    assert abs(r.log_evidence - math.log(exact)) < 3 * cov, (r.log_evidence, math.log(exact))


def test_pure_jax_step_matches_driver(gaussian_problem):
    """The fused, fully jitted step gives a valid APMCABC run too (no host loop inside)."""
    import jax

    from jaxabc.algorithms import apmc, make_jax_step
    from jaxabc.distances import euclidean

    prior, simulate, observed = gaussian_problem
    algo = apmc.build(prior, 1000, alpha=0.1)
    init, step = make_jax_step(algo, simulate, euclidean, observed)
    state, _ = jax.jit(init)(jax.random.key(0))
    step = jax.jit(step)
    for i in range(6):
        state, _info = step(jax.random.key(i + 1), state)
    x, lw = algo.posterior(state)
    w = np.exp(np.asarray(lw) - np.max(np.asarray(lw)))
    w /= w.sum()
    mean = float(np.sum(w * np.asarray(x[:, 0])))
    assert abs(mean) < Z * math.sqrt(1.0 / (1.0 / np.sum(w**2)))


def test_apmcabc_credible_regions_cover_the_truth(correlated_problem):
    """Simulation-based calibration: 400 exact (truth, data) pairs, one vmapped APMCABC run each.

    N = 1000, alpha 0.1 (100 kept particles).  A truth drawn with its data must fall inside the
    q HPD region at least as often as for 100 exchangeable draws, ceil(100 q) / 101 (0.495 and
    0.891 for q = 0.5 and 0.9), and at most as often as the analytic ABC posterior
    N(x, Sigma + eps^2/4 I) at the run's tolerance predicts (0.53 and 0.92 at eps ~0.33): both
    within 4 binomial standard errors.  A posterior with half the true covariance would cover
    0.29 / 0.68, one with twice 0.75 / 0.99.  ``benchmarks/coverage.py`` extends this to N = 100
    and 300 and to rejection ABC.
    """
    from scipy.stats import chi2

    prior, simulate, _ = correlated_problem
    study = jaxabc.coverage_study("apmcabc", simulate, prior, num_datasets=400, num_particles=1000,
                                  num_steps=10, seed=0, sample_data=examples.correlated_truth_and_data,
                                  alpha=0.1, acceptance_cutoff=0.03)
    assert np.all(study.posterior_size == 100) and np.all(study.generations >= 3)
    sigma = np.array([[1.0, examples.RHO], [examples.RHO, 1.0]])
    z = np.random.default_rng(0).multivariate_normal(np.zeros(2), sigma, 100_000)
    for q in (0.5, 0.9):
        covered, se = study.hpd_coverage(q)
        ideal = np.mean([np.mean(chi2.cdf(np.einsum("ij,jk,ik->i", z, np.linalg.inv(
            sigma + e**2 / 4 * np.eye(2)), z), 2) < q) for e in study.thresholds[:50]])
        assert math.ceil(100 * q) / 101 - Z * se < covered < ideal + Z * se, (q, covered, se, ideal)


def test_coverage_study_draws_truths_from_the_prior_and_rejects_bad_input(gaussian_problem):
    prior, simulate, _ = gaussian_problem
    study = jaxabc.coverage_study("rejection", simulate, prior, num_datasets=50, num_particles=50,
                                  num_steps=1, seed=1, quantile=0.05)
    assert study.truths.shape == (50, 1) and np.all((study.levels >= 0) & (study.levels <= 1))
    assert np.all(np.abs(study.truths) <= 10) and np.std(study.truths) > 3  # spread over U[-10, 10]
    assert 0.3 < study.hpd_coverage(0.5)[0] < 0.8
    with pytest.raises(ValueError, match="not computed"):
        study.interval_coverage(0.99)
    with pytest.raises(ValueError, match="unknown algorithm"):
        jaxabc.coverage_study("smc", simulate, prior, num_datasets=5, num_particles=10, num_steps=1)
