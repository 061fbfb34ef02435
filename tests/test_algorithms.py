"""Every algorithm against analytic ABC posteriors (see jaxabc.examples for the derivations).

Tolerances are Monte Carlo errors at the run's effective sample size: the standard error of a
weighted mean is sd / sqrt(ESS), of a variance var * sqrt(2 / ESS), of a correlation
(1 - rho^2) / sqrt(ESS).  Checks use 4 standard errors at fixed seeds.  For ABCsubsim the
particles of a level are correlated along and across their chains; its reported ESS accounts
for that (and is capped here at the number of chains, N P0).
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
    result = jaxabc.run(algorithm, simulate, prior, observed, num_particles=n, distance="euclidean", seed=11, **opts)
    assert np.isclose(result.weights.sum(), 1.0)
    ess = result.effective_sample_size()
    if algorithm == "abcsubsim":
        ess = min(ess, n * 0.2)
    _check_gaussian(result, ess)


@pytest.mark.parametrize("algorithm", ["rejection", "pmcabc", "apmcabc"])
def test_correlated_gaussian_posterior(algorithm, correlated_problem):
    prior, simulate, observed = correlated_problem
    opts = {"rejection": dict(quantile=0.01), "pmcabc": dict(num_steps=4), "apmcabc": dict(num_steps=8, alpha=0.1)}[
        algorithm
    ]
    n = 5000 if algorithm == "apmcabc" else 2000
    result = jaxabc.run(algorithm, simulate, prior, observed, num_particles=n, distance="euclidean", seed=5, **opts)
    eps = float(result.thresholds[-1])
    ess = result.effective_sample_size()
    rho_exact = examples.correlated_abc_correlation(eps)
    cov_exact = np.array([[1, examples.RHO], [examples.RHO, 1]]) + eps**2 / 4 * np.eye(2)
    np.testing.assert_array_less(np.abs(result.bayes_estimate()), Z * np.sqrt(np.diag(cov_exact) / ess))
    rho = result.correlation()[0, 1]
    assert abs(rho - rho_exact) < Z * (1 - rho_exact**2) / math.sqrt(ess), (rho, rho_exact, ess)


def test_abc_posterior_converges_as_threshold_shrinks(gaussian_problem):
    prior, simulate, observed = gaussian_problem
    variances = []
    for q in (0.5, 0.01):
        r = jaxabc.run(
            "rejection", simulate, prior, observed, num_particles=3000, quantile=q, distance="euclidean", seed=2
        )
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
    r = jaxabc.run(
        "apmcabc", simulate, prior, observed, num_particles=n, num_steps=5, alpha=alpha, acceptance_cutoff=0.0, seed=0
    )
    k = len(r.thresholds) - 1
    assert k == 4
    assert r.num_simulations == n + k * (n - math.ceil(alpha * n))
    assert list(r.simulations_per_step) == [n] + [n - math.ceil(alpha * n)] * k
    assert np.all(np.diff(r.thresholds) <= 0)


def test_apmcabc_stops_on_acceptance_cutoff(gaussian_problem):
    prior, simulate, observed = gaussian_problem
    r = jaxabc.run("apmcabc", simulate, prior, observed, num_particles=1000, alpha=0.1, acceptance_cutoff=0.03, seed=0)
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
        r = jaxabc.run(
            "apmcabc",
            simulate,
            prior,
            observed,
            num_particles=2000,
            num_steps=8,
            alpha=0.1,
            acceptance_cutoff=0.03,
            weights=mode,
            distance="euclidean",
            seed=3,
        )
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
    r = jaxabc.run(
        "abcsubsim",
        simulate,
        prior,
        observed,
        num_particles=2000,
        p0=0.2,
        final_threshold=0.15,
        num_steps=10,
        distance="euclidean",
        seed=4,
    )
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
    study = jaxabc.coverage_study(
        "apmcabc",
        simulate,
        prior,
        num_datasets=400,
        num_particles=1000,
        num_steps=10,
        seed=0,
        sample_data=examples.correlated_truth_and_data,
        alpha=0.1,
        acceptance_cutoff=0.03,
    )
    assert np.all(study.posterior_size == 100) and np.all(study.generations >= 3)
    sigma = np.array([[1.0, examples.RHO], [examples.RHO, 1.0]])
    z = np.random.default_rng(0).multivariate_normal(np.zeros(2), sigma, 100_000)
    for q in (0.5, 0.9):
        covered, se = study.hpd_coverage(q)
        ideal = np.mean(
            [
                np.mean(chi2.cdf(np.einsum("ij,jk,ik->i", z, np.linalg.inv(sigma + e**2 / 4 * np.eye(2)), z), 2) < q)
                for e in study.thresholds[:50]
            ]
        )
        assert math.ceil(100 * q) / 101 - Z * se < covered < ideal + Z * se, (q, covered, se, ideal)


def test_coverage_study_draws_truths_from_the_prior_and_rejects_bad_input(gaussian_problem):
    prior, simulate, _ = gaussian_problem
    study = jaxabc.coverage_study(
        "rejection", simulate, prior, num_datasets=50, num_particles=50, num_steps=1, seed=1, quantile=0.05
    )
    assert study.truths.shape == (50, 1) and np.all((study.levels >= 0) & (study.levels <= 1))
    assert np.all(np.abs(study.truths) <= 10) and np.std(study.truths) > 3  # spread over U[-10, 10]
    assert 0.3 < study.hpd_coverage(0.5)[0] < 0.8
    with pytest.raises(ValueError, match="not computed"):
        study.interval_coverage(0.99)
    with pytest.raises(ValueError, match="unknown algorithm"):
        jaxabc.coverage_study("smc", simulate, prior, num_datasets=5, num_particles=10, num_steps=1)


# -- ABCsubsim's effective sample size: a population of chains is not N independent draws ------

SUBSIM_OBSERVED = (1.3, -0.5)


def _subsim_final_states(num_particles, levels, num_seeds):
    """ABCsubsim on the correlated Gaussian, ``levels`` chain levels, one run per seed (vmapped)."""
    import jax
    import jax.numpy as jnp

    from jaxabc.algorithms import make_jax_step, subsim
    from jaxabc.distances import euclidean

    prior = jaxabc.Uniform(low=[-10.0, -10.0], high=[10.0, 10.0], names=("a", "b"))
    algo = subsim.build(prior, num_particles, p0=0.2)
    init, step = make_jax_step(algo, examples.correlated_simulate, euclidean, jnp.asarray(SUBSIM_OBSERVED))
    chain_length = algo.settings["chain_length"]

    def one(key):
        state, _ = init(jax.random.fold_in(key, 0))
        return jax.lax.fori_loop(
            0, levels * chain_length, lambda i, s: step(jax.random.fold_in(key, i + 1), s)[0], state
        )

    states = jax.jit(jax.vmap(one))(jax.random.split(jax.random.key(0), num_seeds))
    return prior, algo, [jax.tree.map(lambda x, s=s: x[s], states) for s in range(num_seeds)]


def test_abcsubsim_mcse_bounds_the_error_of_the_bayes_estimate():
    """With a flat prior the ABC posterior mean of the correlated example is the observation
    exactly, at any tolerance.  After 4 levels (N = 1000, P0 = 0.2) the chains barely move and
    the population holds a few dozen distinct particles: the error of the Bayes estimate must lie
    within ~3 reported MCSE on every seed, which the old ESS (= N) misses by an order of
    magnitude."""
    import warnings

    from jaxabc.algorithms import subsim

    n = 1000
    prior, algo, states = _subsim_final_states(n, levels=4, num_seeds=8)
    z_new, z_old = [], []
    for seed, state in enumerate(states):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            extras = subsim.finalize(state, algo.settings)
        result = jaxabc.ABCResult(
            particles=np.asarray(state.particles, np.float64),
            weights=np.full(n, 1.0 / n),
            distances=np.asarray(state.distances, np.float64),
            thresholds=np.full(5, np.nan),
            simulations_per_step=np.zeros(5),
            acceptance_rates=np.full(5, np.nan),
            ess=np.array([extras["ess"]]),
            num_simulations=0,
            algorithm="abcsubsim",
            settings=algo.settings,
            prior=prior,
            seed=seed,
            diagnostics=extras["diagnostics"],
        )
        distinct = extras["diagnostics"]["num_distinct"]
        assert 1 <= result.effective_sample_size() <= distinct < n
        err = result.bayes_estimate() - np.asarray(SUBSIM_OBSERVED)
        z_new.append(err / result.mcse())
        z_old.append(err / np.sqrt(np.diag(result.covariance()) / n))
    z_new, z_old = np.abs(z_new), np.abs(z_old)
    assert z_new.max() < 3.5, z_new
    assert np.sqrt(np.mean(z_new**2)) < 2.0, z_new
    assert z_old.max() > 10.0, z_old


def test_chain_ess_is_autocorrelation_aware_and_bounded_by_distinct_draws():
    """AR(1) chains with coefficient phi have ESS n (1 - phi) / (1 + phi) for long chains;
    repeated draws count once; short chains fall back to batch means."""
    from jaxabc.diagnostics import chain_ess

    rng = np.random.default_rng(0)
    c, length, phi = 50, 200, 0.8
    x = np.zeros((c, length, 2))
    x[:, 0] = rng.normal(size=(c, 2))
    for t in range(1, length):
        x[:, t] = phi * x[:, t - 1] + math.sqrt(1 - phi**2) * rng.normal(size=(c, 2))
    expected = c * length * (1 - phi) / (1 + phi)
    assert abs(chain_ess(x) - expected) < 0.25 * expected
    iid = rng.normal(size=(400, 5, 2))
    assert 0.7 * 2000 < chain_ess(iid) <= 2000
    stuck = np.repeat(rng.normal(size=(400, 1, 2)), 5, axis=1)
    stuck[200:] = stuck[:200]  # 200 distinct draws, each repeated 10 times
    assert chain_ess(stuck) <= 200
    assert chain_ess(np.zeros((10, 5, 1))) == 1.0
    assert 1.0 <= chain_ess(rng.normal(size=(100, 2, 1))) <= 200  # too short for ArviZ
    with pytest.raises(ValueError, match="num_chains, num_draws, d"):
        chain_ess(np.zeros((10, 5)))


def test_abcsubsim_warns_and_stops_when_the_chains_stop_moving(correlated_problem):
    """A UserWarning names the level and the distinct count; with min_distinct_fraction the
    algorithm's own rule ends the run there and says why; the result's ESS is honest."""
    prior, simulate, _ = correlated_problem
    with pytest.warns(UserWarning, match=r"ABCsubsim level \d+: .* (\d+) distinct particles of 500"):
        r = jaxabc.run(
            "abcsubsim",
            simulate,
            prior,
            np.array(SUBSIM_OBSERVED),
            num_particles=500,
            p0=0.2,
            num_steps=9,
            min_distinct_fraction=0.2,
            distance="euclidean",
            seed=1,
        )
    diag = r.diagnostics
    assert diag["chains_stuck"] and diag["num_distinct"] < 100
    assert diag["level"] == len(r.thresholds) - 1 < 8
    assert "chains stopped moving" in r.stop_reason and "distinct" in r.stop_reason
    # float32 (the population) against float64 (the diagnostics): equal to rounding.
    assert r.ess[-1] == pytest.approx(r.effective_sample_size(), rel=1e-6)
    assert r.effective_sample_size() <= diag["num_distinct"]
    assert "MCSE" in r.summary() and "stopped moving" in r.summary()
    with pytest.raises(ValueError, match="min_distinct_fraction"):
        jaxabc.run(
            "abcsubsim",
            simulate,
            prior,
            np.array(SUBSIM_OBSERVED),
            num_particles=500,
            num_steps=3,
            min_distinct_fraction=1.5,
        )
