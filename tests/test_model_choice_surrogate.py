"""Model choice by surrogate evidence (``jaxabc.run(models, ..., method="surrogate")``).

Linear-Gaussian models ``s_j = a theta + b + sigma e_j`` (two summaries, ``theta ~ U(-3, 3)``)
have the closed-form evidence

    Z = N(s_1 - s_2; 0, 2 sigma^2) [Phi(hi; s_bar, sigma^2/2) - Phi(lo; s_bar, sigma^2/2)] / (a (H - L))

with ``[lo, hi] = [a L + b, a H + b]``.  The surrogate's estimates must agree within four of
their own standard errors (importance sampling plus the delete-a-group jackknife over the design).
"""

from __future__ import annotations

import jax
import numpy as np
import pytest
from scipy.stats import norm

import jaxabc
from jaxabc.model_choice import load_model_choice

L, H = -3.0, 3.0
PRIOR = jaxabc.Uniform(np.array([L]), np.array([H]), names=("theta",))


def linear(a: float, b: float, sigma: float):
    def simulate(key, theta):
        return a * theta[0] + b + sigma * jax.random.normal(key, (2,))

    return simulate


def analytic_log_evidence(s: np.ndarray, a: float, b: float, sigma: float) -> float:
    lo, hi = a * L + b, a * H + b
    mean, sd = 0.5 * (s[0] + s[1]), sigma / np.sqrt(2.0)
    return float(
        -np.log(a * (H - L))
        + norm.logpdf(s[0] - s[1], 0.0, np.sqrt(2.0) * sigma)
        + np.log(norm.cdf(hi, mean, sd) - norm.cdf(lo, mean, sd))
    )


MODELS = {"steep": (5.0, 0.0, 0.2), "shallow": (2.0, 0.5, 0.4)}


def test_surrogate_evidence_matches_the_analytic_evidence_and_resumes(tmp_path):
    observed = np.array([1.05, 1.25])
    models = [(name, linear(*p), PRIOR) for name, p in MODELS.items()]
    result = jaxabc.run(
        models, observed=observed, method="surrogate", max_simulations=300, seed=0, checkpoint_dir=tmp_path / "ck"
    )
    assert result.num_simulations <= 300
    assert result.stop_reason.startswith("every model's emulator validated")
    assert not result.metadata["misspecified"] and "MISSPECIFIED" not in result.stop_reason
    exact = np.array([analytic_log_evidence(observed, *p) for p in MODELS.values()])
    se = result.log_evidence_errors
    assert np.all(se > 0) and np.all(np.isfinite(se))
    assert np.all(np.abs(result.log_evidence - exact) <= 4.0 * se), (result.log_evidence, exact, se)
    log_b, log_b_se = np.log(result.bayes_factor("steep", "shallow")[0]), result.bayes_factor("steep", "shallow")[1]
    assert abs(log_b - (exact[0] - exact[1])) <= 4.0 * log_b_se
    assert np.isclose(result.probabilities.sum(), 1.0)
    low, high = np.asarray(result.metadata["probability_interval_95"]).T
    assert np.all((low <= result.probabilities) & (result.probabilities <= high))
    for post in result.posteriors:
        assert post.particles.shape[0] >= 1000
        assert post.diagnostics["validated"]
        # Both models reproduce these data: the predictive check must not reject them.
        assert post.diagnostics["observed_misfit"]["p_value"] > 1e-3

    again = jaxabc.run(
        models,
        observed=observed,
        method="surrogate",
        max_simulations=300,
        seed=0,
        checkpoint_dir=tmp_path / "ck",
        resume=True,
    )
    np.testing.assert_array_equal(again.probabilities, result.probabilities)
    np.testing.assert_array_equal(again.log_evidence, result.log_evidence)

    result.save(tmp_path / "saved")
    loaded = load_model_choice(tmp_path / "saved")
    np.testing.assert_array_equal(loaded.probabilities, result.probabilities)
    assert np.isnan(loaded.threshold) and "surrogate evidence" in loaded.summary()


@pytest.mark.slow  # default-suite time: 25-75 s on 2 cores
def test_surrogate_model_choice_picks_the_model_that_made_the_data():
    # Model "mirror" predicts s_2 = -s_1; data simulated from "same" (s_2 = s_1) at theta = 0.8.
    def mirror(key, theta):
        return np.array([1.0, -1.0]) * theta[0] + 0.1 * jax.random.normal(key, (2,))

    same = linear(1.0, 0.0, 0.1)
    observed = np.asarray(same(jax.random.key(123), np.array([0.8])))
    result = jaxabc.run(
        [("same", same, PRIOR), ("mirror", mirror, PRIOR)], observed=observed, method="surrogate", max_simulations=160
    )
    p, se = result.probability("same")
    assert result.best == "same"
    assert p - 4.0 * se > 0.99
    # The wrong model cannot reproduce the data; the predictive check says so, the right one passes.
    wrong = result.posterior("mirror").diagnostics["observed_misfit"]
    assert wrong["p_value"] < 1e-6 and wrong["dof"] == 2
    assert result.posterior("same").diagnostics["observed_misfit"]["p_value"] > 1e-3
    assert not result.metadata["misspecified"]


def test_surrogate_model_choice_says_when_no_model_fits():
    # Data s = (0.8, 0): "same" (s_2 = s_1) and "mirror" (s_2 = -s_1) both miss by ~4 noise sd
    # per summary at their best fit, so the probabilities rank misfits and the result says so.
    def mirror(key, theta):
        return np.array([1.0, -1.0]) * theta[0] + 0.1 * jax.random.normal(key, (2,))

    result = jaxabc.run(
        [("same", linear(1.0, 0.0, 0.1), PRIOR), ("mirror", mirror, PRIOR)],
        observed=np.array([0.8, 0.0]),
        method="surrogate",
        max_simulations=160,
    )
    assert result.metadata["misspecified"]
    assert all(p < 1e-4 for p in result.metadata["misfit_p_values"])
    assert "MISSPECIFIED" in result.stop_reason


def test_surrogate_model_choice_refuses_what_its_evidence_cannot_use():
    observed = np.array([0.1, 0.2])
    models = [("a", linear(1.0, 0.0, 0.1), PRIOR), ("b", linear(2.0, 0.0, 0.1), PRIOR)]
    with pytest.raises(TypeError, match="needs max_simulations"):
        jaxabc.run(models, observed=observed, method="surrogate")
    with pytest.raises(TypeError, match="distance"):
        jaxabc.run(models, observed=observed, method="surrogate", max_simulations=200, distance="euclidean")
    with pytest.raises(ValueError, match="sets \\['mode'\\] itself"):
        jaxabc.run(models, observed=observed, method="surrogate", max_simulations=200, mode="abc")
    with pytest.raises(ValueError, match="'abc_smc' or 'surrogate'"):
        jaxabc.run(models, observed=observed, method="bolfi", max_simulations=200)


@pytest.mark.slow
def test_surrogate_model_choice_refuses_models_whose_likelihoods_use_other_summaries():
    # The second model never varies its second summary, so its likelihood leaves it out: the
    # two evidences would be densities of different data.
    def flat_second(key, theta):
        return np.array([1.0, 0.0]) * theta[0] + np.array([0.1, 0.0]) * jax.random.normal(key, (2,))

    observed = np.array([0.5, 0.0])
    with pytest.raises(ValueError, match="different summaries"):
        jaxabc.run(
            [("both", linear(1.0, 0.0, 0.1), PRIOR), ("one", flat_second, PRIOR)],
            observed=observed,
            method="surrogate",
            max_simulations=120,
        )


def test_probability_intervals_follow_the_evidence_errors():
    from jaxabc.model_choice.surrogate import probability_intervals

    rng = np.random.default_rng(0)
    # Equal evidences known to +-0.1: P near 1/2 with delta-method sd 0.1 / sqrt(2) / 2.
    low, high = probability_intervals(np.zeros(2), np.full(2, 0.1), np.full(2, 0.5), rng)[0]
    half = 1.96 * 0.5 * 0.5 * np.sqrt(2) * 0.1
    assert abs(low - (0.5 - half)) < 0.01 and abs(high - (0.5 + half)) < 0.01
    # Errors of several nats: the interval spans nearly all of [0, 1].
    low, high = probability_intervals(np.zeros(2), np.full(2, 5.0), np.full(2, 0.5), rng)[0]
    assert low < 0.01 and high > 0.99


def test_evidence_is_nan_for_projected_summaries_and_refused_in_abc_mode():
    from jaxabc.surrogate import build
    from jaxabc.surrogate.evidence import with_evidence

    observed = np.array([1.05, 1.25])
    with pytest.raises(ValueError, match="synthetic-likelihood mode only"):
        with_evidence(build(PRIOR, 1000, observed=observed, max_simulations=100, mode="abc"), PRIOR, observed)
    # One principal component of two summaries: the likelihood is of a projection, not a density
    # of the summaries, so no evidence comparable across models exists.
    algo = with_evidence(build(PRIOR, 1000, observed=observed, max_simulations=80, max_outputs=1), PRIOR, observed)
    result = jaxabc.run(algo, linear(5.0, 0.0, 0.2), PRIOR, observed, max_simulations=80, dtype="float64")
    assert np.isnan(result.log_evidence) and np.isnan(result.diagnostics["log_evidence_se"])
