"""The water criticism's and paper check's start from a model choice with the discrepancy term."""

from __future__ import annotations

import numpy as np

import jaxabc
from benchmarks._water_model_choice_paths import physical_marginal


def test_the_discrepancy_sds_are_dropped_and_the_weights_kept() -> None:
    prior = jaxabc.Uniform(
        low=[0.3, 0.4, 0.0, 0.0],
        high=[0.34, 1.6, 1.0, 10.0],
        names=("sigma_OO", "epsilon_OO", "discrepancy_sd[gOO_heights]", "discrepancy_sd[D]"),
        units=("nm", "kJ/mol", "summary units", "summary units"),
    )
    rng = np.random.default_rng(0)
    particles = prior.low + rng.random((50, 4)) * (prior.high - prior.low)
    weights = rng.random(50)
    full = jaxabc.ABCResult.from_sample(particles, weights, prior, algorithm="surrogate")
    base = physical_marginal(full)
    assert base.names == ("sigma_OO", "epsilon_OO") and base.prior.units == ("nm", "kJ/mol")
    np.testing.assert_array_equal(base.particles, particles[:, :2])
    np.testing.assert_array_equal(base.weights, full.weights)
    np.testing.assert_allclose(base.bayes_estimate(), full.bayes_estimate()[:2])
    assert base.effective_sample_size() == full.effective_sample_size()
    # Without discrepancy parameters the posterior is the model choice's own.
    assert physical_marginal(base) is base
