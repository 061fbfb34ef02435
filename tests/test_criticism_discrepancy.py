"""critique refuses a fit with model-discrepancy columns; without_discrepancy gives its marginal."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxabc
from jaxabc.criticism import Catalogue, Effect, critique, without_discrepancy

OBS = np.array([0.4, -0.2])


def simulate(key, theta):
    return theta[0] + 0.3 * jax.random.normal(key, (2,))


def simulate_with_effects(key, theta_full):
    return simulate(key, theta_full[:1]) + theta_full[1]


def _fit():
    prior = jaxabc.Uniform([-2.0], [2.0], names=("a",), units=("u",))
    return jaxabc.run(
        "rejection",
        simulate,
        prior,
        OBS,
        num_particles=60,
        quantile=0.2,
        seed=3,
        discrepancy=jaxabc.Discrepancy([0.5, 1.0]),
    )


def test_critique_refuses_discrepancy_columns_and_names_the_marginal():
    fit = _fit()
    assert fit.prior.names == ("a", "discrepancy_sd[0]", "discrepancy_sd[1]")
    catalogue = Catalogue([Effect("offset", null=0.0, low=-1.0, high=1.0)])
    with pytest.raises(ValueError, match=r"discrepancy_sd\[0\].*without_discrepancy"):
        critique(fit, simulate_with_effects, OBS, catalogue, held_out=[1], num_draws=10, num_replicates=10)


def test_without_discrepancy_is_the_marginal_with_the_same_weights():
    fit = _fit()
    m = without_discrepancy(fit)
    assert m.prior.names == ("a",) and m.prior.units == ("u",)
    np.testing.assert_array_equal(m.prior.low, [-2.0])
    np.testing.assert_array_equal(m.particles, np.asarray(fit.particles)[:, :1])
    np.testing.assert_array_equal(m.weights, fit.weights)
    # The marginal's moments are the joint's first coordinate's (weights unchanged).
    np.testing.assert_allclose(m.bayes_estimate(), fit.bayes_estimate()[:1], rtol=1e-6)
    assert m.num_simulations == fit.num_simulations
    # Nothing to drop: the same object.
    assert without_discrepancy(m) is m


def test_without_discrepancy_needs_a_box_prior():
    fit = _fit()

    class Box:  # a duck-typed prior that is not a Uniform
        def __init__(self, p):
            self.low, self.high, self.names, self.units, self.dim = p.low, p.high, p.names, p.units, p.dim

    fake = type(fit).__new__(type(fit))
    fake.__dict__.update(fit.__dict__)
    fake.__dict__["prior"] = Box(fit.prior)
    with pytest.raises(TypeError, match="Uniform"):
        without_discrepancy(fake)


def test_marginal_critique_runs():
    """The marginal of a discrepancy fit is accepted (a smoke check of the contract, not of the
    criticism's statistics, which tests/test_criticism.py covers)."""
    m = without_discrepancy(_fit())
    catalogue = Catalogue([Effect("offset", null=0.0, low=-1.0, high=1.0)])
    report = critique(
        m,
        simulate_with_effects,
        jnp.asarray(OBS),
        catalogue,
        held_out=[1],
        num_draws=20,
        num_replicates=20,
        extend=False,
    )
    assert report.misfits is not None
