"""ABC model choice against Bayes factors known in closed form, and its contracts.

The analytic case (Robert, Cornuet, Marin & Pillai 2011; Didelot et al. 2011): ``n`` counts,
model "poisson" with rate ``lambda ~ U(0, L)``, model "geometric" (failures before a success)
with ``p ~ U(0, 1)``, summary ``S = sum(x)`` and distance ``|S_sim - S_obs|``.  The ABC evidence
at tolerance ``eps`` is ``sum_{|s - S| <= eps} m(s)`` with the prior predictive of ``S``:

* Poisson: ``S ~ Poisson(n lambda)``, so ``m(s) = P(s + 1, n L) / (n L)`` (regularised lower
  incomplete gamma);
* geometric: ``S ~ NegBin(n, p)``, so ``m(s) = n / ((n + s)(n + s + 1))``.

At ``eps = 0`` (reachable: ``S`` is an integer) that is the Bayes factor of ``S``, which the
sampler must reproduce within its reported Monte Carlo error at every tolerance it passes.
"""

from __future__ import annotations

import json
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.scipy.special import gammaln, xlogy
from scipy.special import gammainc

import jaxabc
from jaxabc.model_choice import Model, load_model_choice, run_model_choice
from jaxabc.model_choice.result import probabilities_with_errors

NUM_COUNTS = 10
RATE_MAX = 10.0
_K = jnp.arange(64.0)  # P(X >= 64) < 1e-25 for rates up to RATE_MAX


def poisson_sum(key, theta):
    """Sum of NUM_COUNTS Poisson(theta[0]) counts, shape (1,).

    Inversion with a CDF table: exact to float32 rounding, and it compiles in a fraction of the
    time of ``jax.random.poisson``'s rejection loop.
    """
    cdf = jnp.cumsum(jnp.exp(xlogy(_K, theta[0]) - theta[0] - gammaln(_K + 1.0)))
    counts = jnp.searchsorted(cdf, jax.random.uniform(key, (NUM_COUNTS,)), side="left")
    return jnp.sum(counts).astype(jnp.float32)[None]


def geometric_sum(key, theta):
    """Sum of NUM_COUNTS geometric(theta[0]) counts (failures before a success), shape (1,)."""
    u = 1.0 - jax.random.uniform(key, (NUM_COUNTS,))  # in (0, 1]
    return jnp.sum(jnp.floor(jnp.log(u) / jnp.log1p(-theta[0])))[None]


POISSON = Model("poisson", poisson_sum, jaxabc.Uniform([0.0], [RATE_MAX], names=("rate",)))
GEOMETRIC = Model("geometric", geometric_sum, jaxabc.Uniform([0.0], [1.0], names=("p",)))


def _evidence(s_obs: int, eps: float) -> tuple[float, float]:
    s = np.arange(max(0, s_obs - int(np.floor(eps))), s_obs + int(np.floor(eps)) + 1, dtype=np.float64)
    nl = NUM_COUNTS * RATE_MAX
    poisson = np.sum(gammainc(s + 1.0, nl) / nl)
    geometric = np.sum(NUM_COUNTS / ((NUM_COUNTS + s) * (NUM_COUNTS + s + 1.0)))
    return float(poisson), float(geometric)


def _poisson_probability(s_obs: int, eps: float) -> float:
    zp, zg = _evidence(s_obs, eps)
    return zp / (zp + zg)


@pytest.fixture(scope="module")
def counts_run():
    """One run to tolerance 0 on S = 5 (the geometric model is favoured about 4 : 1)."""
    return jaxabc.run([POISSON, GEOMETRIC], observed=[5.0], num_particles=300, final_threshold=0.0, num_steps=20)


def test_probabilities_match_the_analytic_bayes_factor_at_every_tolerance(counts_run):
    r = counts_run
    assert r.threshold == 0.0 and "final threshold" in r.stop_reason
    assert r.names == ("poisson", "geometric")
    history = zip(r.thresholds[1:], r.probability_history[1:], r.standard_error_history[1:], strict=True)
    for eps, probs, errors in history:
        truth = _poisson_probability(5, eps)
        assert abs(probs[0] - truth) < 4.0 * errors[0], (eps, probs[0], truth, errors[0])
        assert abs(probs.sum() - 1.0) < 1e-12
    # The error is small enough that the check above has teeth (P(poisson | S=5) = 0.194).
    assert r.standard_errors[0] < 0.03
    zp, zg = _evidence(5, 0.0)
    bayes, log_error = r.bayes_factor("poisson", "geometric")
    assert abs(np.log(bayes) - np.log(zp / zg)) < 4.0 * log_error
    assert abs(r.log_evidence[1] - np.log(zg)) < 4.0 * r.log_evidence_errors[1]
    assert r.best == "geometric"


def test_each_model_gets_its_conjugate_posterior(counts_run):
    # At tolerance 0: rate | S ~ Gamma(S + 1, n) (truncation at 10 is negligible); p | S ~ Beta(n + 1, S + 1).
    rate = counts_run.posterior("poisson")
    p = counts_run.posterior("geometric")
    assert abs(rate.bayes_estimate()[0] - 6.0 / NUM_COUNTS) < 4.0 * rate.mcse()[0]
    assert abs(p.bayes_estimate()[0] - 11.0 / 17.0) < 4.0 * p.mcse()[0]
    assert abs(np.sqrt(rate.covariance()[0, 0]) - np.sqrt(6.0) / NUM_COUNTS) < 0.15 * np.sqrt(6.0) / NUM_COUNTS
    assert rate.effective_sample_size() > 100 and p.effective_sample_size() > 100
    assert rate.log_evidence == pytest.approx(counts_run.log_evidence[0])
    assert rate.num_simulations + p.num_simulations == counts_run.num_simulations
    assert np.all(rate.distances == 0.0)


def test_delta_method_errors_match_a_monte_carlo_of_the_estimates():
    log_z = np.log([0.02, 0.05, 0.01])
    rel = np.array([0.05, 0.02, 0.10])
    prior = np.array([0.5, 0.25, 0.25])
    probs, errors = probabilities_with_errors(log_z, rel, prior)
    rng = np.random.default_rng(0)
    z = np.exp(log_z) * (1.0 + rel * rng.standard_normal((200_000, 3)))
    draws = prior * z / np.sum(prior * z, axis=1, keepdims=True)
    np.testing.assert_allclose(probs, prior * np.exp(log_z) / np.sum(prior * np.exp(log_z)))
    np.testing.assert_allclose(errors, draws.std(axis=0), rtol=0.03)


def _mean_and_sd(counts):
    return jnp.stack([jnp.mean(counts), jnp.var(counts) / jnp.mean(counts)])


def _poisson_data(key, theta):
    cdf = jnp.cumsum(jnp.exp(xlogy(_K, theta[0]) - theta[0] - gammaln(_K + 1.0)))
    return _mean_and_sd(jnp.searchsorted(cdf, jax.random.uniform(key, (100,)), side="left").astype(jnp.float32))


def _geometric_data(key, theta):
    u = 1.0 - jax.random.uniform(key, (100,))
    return _mean_and_sd(jnp.floor(jnp.log(u) / jnp.log1p(-theta[0])))


@pytest.mark.parametrize(("truth", "theta"), [("poisson", 4.0), ("geometric", 0.2)])
def test_picks_the_model_that_simulated_the_data(truth, theta):
    """100 counts with mean 4 either way: the spread (sd 2 vs 4.5) tells the models apart."""
    models = [
        Model("poisson", _poisson_data, jaxabc.Uniform([0.0], [RATE_MAX])),
        Model("geometric", _geometric_data, jaxabc.Uniform([0.0], [1.0])),
    ]
    data_model = models[0] if truth == "poisson" else models[1]
    observed = data_model.simulate(jax.random.key(42), jnp.array([theta]))
    loser = "geometric" if truth == "poisson" else "poisson"
    # The loser cannot match the spread: it dies out, and its probability gets an upper bound.
    with pytest.warns(UserWarning, match=f"no simulation of {loser}"):
        r = jaxabc.run(models, observed=observed, num_particles=200, num_steps=6, distance="euclidean", seed=1)
    assert r.best == truth
    assert r.probability(truth)[0] > 0.95
    assert r.probability_upper_bounds[r.names.index(loser)] < 0.2
    # The winner's posterior is where the data came from.
    lo, hi = r.posterior(truth).credible_interval(0.99)[0]
    assert lo < theta < hi


def test_same_seed_same_numbers_and_another_seed_other_numbers():
    kw = dict(observed=[12.0], num_particles=100, num_steps=3, seed=3)
    a = jaxabc.run([POISSON, GEOMETRIC], **kw)
    b = jaxabc.run([POISSON, GEOMETRIC], **kw)
    c = jaxabc.run([POISSON, GEOMETRIC], **{**kw, "seed": 4})
    np.testing.assert_array_equal(a.probabilities, b.probabilities)
    np.testing.assert_array_equal(a.thresholds, b.thresholds)
    for pa, pb in zip(a.posteriors, b.posteriors, strict=True):
        np.testing.assert_array_equal(pa.particles, pb.particles)
        np.testing.assert_array_equal(pa.records["theta"], pb.records["theta"])
    assert not np.array_equal(a.posteriors[0].records["theta"], c.posteriors[0].records["theta"])


def test_a_model_that_never_comes_close_gets_probability_zero_with_a_warning():
    far = Model("far", lambda key, theta: jnp.array([100.0]) + 0.0 * theta, jaxabc.Uniform([0.0], [1.0]))
    with pytest.warns(UserWarning, match=r"no simulation of far \(below .*\) met the tolerance") as caught:
        r = jaxabc.run([POISSON, far], observed=[5.0], num_particles=100, num_steps=4, seed=0)
    assert caught[0].filename == __file__  # the warning points at the caller
    assert r.probability("far") == (0.0, 0.0)
    assert r.probability("poisson")[0] == 1.0
    assert r.log_evidence[1] == -np.inf
    assert r.bayes_factor("poisson", "far") == (np.inf, np.inf)
    # Once the tolerance is below 95, nothing of 'far' lies within it, so it gets the most
    # proposals (50 N), 5% of them prior draws, none accepted: Z < 3 / 250 at 95% (rule of three).
    far_post = r.posterior("far")
    died = int(np.flatnonzero(far_post.acceptance_rates == 0)[0])
    assert far_post.metadata["proposals_per_step"][died] == 50 * 100
    assert np.all(far_post.distances == 95.0) and far_post.thresholds[died] < 95.0
    z_up, z_poisson = 3.0 / 250, np.exp(r.log_evidence[0])
    assert r.probability_upper_bounds[1] == pytest.approx(z_up / (z_up + z_poisson))
    assert np.isnan(r.probability_upper_bounds[0])
    assert "posterior is that of tolerance" in r.posterior("far").stop_reason
    assert r.posterior("far").particles.shape[0] > 0


def test_failures_are_recorded_and_a_model_that_always_fails_stops_the_run():
    def flaky(key, theta):  # NaN summaries for half of the prior: recorded failures, not a crash
        return jnp.where(theta[0] > 0.5, jnp.nan, geometric_sum(key, theta))

    r = jaxabc.run(
        [POISSON, Model("flaky", flaky, jaxabc.Uniform([0.0], [1.0]))],
        observed=[5.0],
        num_particles=100,
        num_steps=3,
        seed=0,
        max_failure_fraction=0.9,
    )
    flaky_post = r.posterior("flaky")
    assert flaky_post.num_failures > 0
    assert np.all(flaky_post.particles[:, 0] <= 0.5)
    broken = Model("broken", lambda key, theta: jnp.full((1,), jnp.nan) + theta, jaxabc.Uniform([0.0], [1.0]))
    with pytest.raises(jaxabc.TooManyFailures, match="model 'broken': all 100 simulations failed"):
        jaxabc.run([POISSON, broken], observed=[5.0], num_particles=100, num_steps=3)


def test_host_simulators_on_the_serial_executor():
    def host_geometric(key, theta):  # plain NumPy, seeded from the key: no JAX tracing
        if theta[0] < 0.05:
            raise jaxabc.SimulationFailure("p below 0.05: counts too large to simulate")
        rng = np.random.default_rng(jaxabc.seed_from_key(key))
        return np.array([float(np.sum(rng.geometric(theta[0], NUM_COUNTS) - 1))])

    kw = dict(observed=[5.0], num_particles=60, num_steps=2, seed=2, executor="serial")
    a = jaxabc.run([POISSON, ("geometric", host_geometric, GEOMETRIC.prior)], **kw)
    b = jaxabc.run([POISSON, ("geometric", host_geometric, GEOMETRIC.prior)], **kw)
    np.testing.assert_array_equal(a.probabilities, b.probabilities)
    reasons = a.posterior("geometric").records["reasons"]
    theta = a.posterior("geometric").records["theta"][:, 0]
    assert all(("p below 0.05" in why) == (t < 0.05) for why, t in zip(reasons, theta, strict=True))


def test_a_stopped_run_resumes_to_the_uninterrupted_result(tmp_path):
    kw = dict(observed=[12.0], num_particles=100, num_steps=4, seed=5)
    full = jaxabc.run([POISSON, GEOMETRIC], **kw)
    part = jaxabc.run([POISSON, GEOMETRIC], checkpoint_dir=tmp_path, stop_after_iterations=2, **kw)
    assert "resumable" in part.stop_reason and len(part.thresholds) == 2
    with pytest.raises(jaxabc.checkpoint.CheckpointError, match="earlier run"):
        jaxabc.run([POISSON, GEOMETRIC], checkpoint_dir=tmp_path, **kw)
    with pytest.raises(jaxabc.checkpoint.CheckpointError, match="seed: checkpoint 5, this run 6"):
        jaxabc.run([POISSON, GEOMETRIC], checkpoint_dir=tmp_path, resume=True, **{**kw, "seed": 6})
    with pytest.raises(jaxabc.checkpoint.CheckpointError, match="settings"):
        jaxabc.run([POISSON, GEOMETRIC], checkpoint_dir=tmp_path, resume=True, model_prior=[0.3, 0.7], **kw)
    rest = jaxabc.run([POISSON, GEOMETRIC], checkpoint_dir=tmp_path, resume=True, **kw)
    np.testing.assert_array_equal(rest.probabilities, full.probabilities)
    np.testing.assert_array_equal(rest.thresholds, full.thresholds)
    for a, b in zip(rest.posteriors, full.posteriors, strict=True):
        np.testing.assert_array_equal(a.particles, b.particles)
        np.testing.assert_array_equal(a.records["theta"], b.records["theta"])
    # A finished run resumes to itself without simulating.
    again = jaxabc.run([POISSON, GEOMETRIC], checkpoint_dir=tmp_path, resume=True, **kw)
    np.testing.assert_array_equal(again.probabilities, full.probabilities)
    assert again.num_simulations == full.num_simulations


def test_save_load_and_json_summary(counts_run, tmp_path):
    path = counts_run.save(tmp_path / "choice")
    again = load_model_choice(tmp_path / "choice")
    np.testing.assert_array_equal(again.probabilities, counts_run.probabilities)
    np.testing.assert_array_equal(again.probability_history, counts_run.probability_history)
    np.testing.assert_array_equal(again.posterior("poisson").particles, counts_run.posterior("poisson").particles)
    assert again.thresholds[0] == np.inf
    summary = json.loads(path.read_text())
    assert summary["names"] == ["poisson", "geometric"]
    assert summary["posteriors"]["geometric"]["parameter_names"] == ["p"]
    with pytest.raises(FileExistsError, match="overwrite=True"):
        counts_run.save(tmp_path / "choice")
    assert "poisson" in counts_run.summary() and "+-" in counts_run.summary()


@pytest.mark.parametrize(
    ("models", "error", "match"),
    [
        ([], ValueError, "the list of models is empty"),
        ([POISSON], ValueError, "at least two models"),
        ([POISSON, "geometric"], TypeError, "model 1 is a str"),
        ([POISSON, POISSON], ValueError, "names must be unique"),
        ([POISSON, (geometric_sum, "not a prior")], TypeError, "'model1': the prior must be"),
    ],
)
def test_bad_model_lists_are_refused(models, error, match):
    with pytest.raises(error, match=match):
        jaxabc.run(models, observed=[5.0], num_particles=50, num_steps=2)


def test_models_with_different_summary_shapes_are_refused():
    two = Model("two", lambda key, theta: jnp.stack([theta[0], theta[0]]), jaxabc.Uniform([0.0], [1.0]))
    with pytest.raises(ValueError, match=r"different shapes \('poisson' \(1,\), 'two' \(2,\)\)"):
        jaxabc.run([POISSON, two], observed=[5.0], num_particles=50, num_steps=2)
    with pytest.raises(ValueError, match=r"returns summaries of shape \(1,\) but the observed data has shape \(2,\)"):
        jaxabc.run([POISSON, GEOMETRIC], observed=[5.0, 1.0], num_particles=50, num_steps=2)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        (dict(num_steps=None), ValueError, "needs a stopping rule"),
        (dict(model_prior=[1.0]), ValueError, "model_prior has 1 entries for 2 models"),
        (dict(model_prior=[1.0, -1.0]), ValueError, "positive and finite"),
        (dict(resume=True), ValueError, "resume=True needs checkpoint_dir"),
        (dict(alpha=0.1), TypeError, r"unknown option\(s\) \['alpha'\]"),
        (dict(quantile=1.0), ValueError, r"quantile must lie in \(0, 1\)"),
        (dict(defensive_fraction=0.0), ValueError, "defensive_fraction"),
        (dict(final_threshold=-1.0), ValueError, "non-negative"),
    ],
)
def test_bad_options_are_refused(kwargs, error, match):
    with pytest.raises(error, match=match):
        jaxabc.run([POISSON, GEOMETRIC], **{"observed": [5.0], "num_particles": 50, "num_steps": 2, **kwargs})


def test_driver_call_forms():
    with pytest.raises(TypeError, match="data by keyword"):
        jaxabc.run([POISSON, GEOMETRIC], [5.0])
    with pytest.raises(TypeError, match="needs the data"):
        jaxabc.run([POISSON, GEOMETRIC], num_particles=50, num_steps=2)
    with pytest.raises(TypeError, match="pass the list of models first"):
        jaxabc.run("apmcabc", [POISSON, GEOMETRIC], observed=[5.0])
    with pytest.raises(TypeError, match="needs simulate and prior"):
        jaxabc.run("apmcabc", observed=[5.0])
    direct = run_model_choice([POISSON, GEOMETRIC], [5.0], 50, 2, seed=7)
    via_run = jaxabc.run([POISSON, GEOMETRIC], observed=[5.0], num_particles=50, num_steps=2, seed=7)
    np.testing.assert_array_equal(direct.probabilities, via_run.probabilities)


def test_import_jaxabc_does_not_load_model_choice():
    code = (
        "import sys, jaxabc; print('jaxabc.model_choice' in sys.modules); "
        "jaxabc.Model; print('jaxabc.model_choice' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "True"]


@pytest.mark.slow
def test_reported_errors_match_the_spread_over_seeds():
    """Over 20 seeds the standardised errors (estimate - truth) / reported error have mean ~0, sd ~1."""
    z = []
    for seed in range(20):
        r = jaxabc.run([POISSON, GEOMETRIC], observed=[20.0], num_particles=300, final_threshold=0.0, seed=seed)
        z.append((r.probabilities[0] - _poisson_probability(20, 0.0)) / r.standard_errors[0])
    z = np.asarray(z)
    # For 20 standard normal draws: |mean| < 0.67 and 0.6 < sd < 1.4 fail with probability < 0.5 %.
    assert abs(z.mean()) < 0.67, z
    assert 0.6 < z.std(ddof=1) < 1.4, z


@pytest.mark.slow
def test_large_population_pins_the_probability_down():
    r = jaxabc.run([POISSON, GEOMETRIC], observed=[20.0], num_particles=3000, final_threshold=0.0, seed=11)
    truth = _poisson_probability(20, 0.0)
    assert r.standard_errors[0] < 0.01
    assert abs(r.probabilities[0] - truth) < 4.0 * r.standard_errors[0]
