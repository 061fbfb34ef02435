"""Priors from numpyro distributions with unbounded support, given as they are (no ``bounds``).

``jaxabc.Independent(t=dist.Normal(1, 0.5))`` cuts an unbounded side at the distribution's far
quantile ``tail = 1e-9``: the prior mass left out is reported per parameter (``tail_mass``), is
at most ``tail`` per side (the tolerance of these tests: the prior used and the one given differ
by that total variation), and the automatic bounds are physical limits, so a posterior piled
there is noted, not warned about.  The posteriors are checked against exact ones: with
``x = t + N(0, 1)`` accepted iff ``|x - y| < eps``, the ABC posterior at ``eps`` is
``pi(t) [Phi(y + eps - t) - Phi(y - eps - t)]`` normalised, whose moments quadrature gives; at a
Normal prior it tends to the conjugate posterior ``N(m, v)``, ``v = 1 / (1 / s0^2 + 1)``,
``m = v (m0 / s0^2 + y)``, also checked in closed form.  Tolerances: ``z`` Monte Carlo standard
errors of the reported ESS, at fixed seeds.
"""

from __future__ import annotations

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxabc
from jaxabc import examples
from jaxabc.driver.fused import run_fused
from jaxabc.priors.independent import TAIL

dist = pytest.importorskip("numpyro.distributions")
scipy_stats = pytest.importorskip("scipy.stats")

OBSERVED = 2.0
PRIOR_MEAN, PRIOR_SD = 1.0, 0.5


def _abc_posterior_moments(log_prior, eps: float, low: float, high: float) -> tuple[float, float]:
    """Mean and variance of the ABC posterior of ``x = t + N(0, 1)``, window ``|x - y| < eps``."""
    t = np.linspace(low, high, 400001)
    window = scipy_stats.norm.cdf(OBSERVED + eps - t) - scipy_stats.norm.cdf(OBSERVED - eps - t)
    p = np.exp(log_prior(t)) * window
    p /= np.trapezoid(p, t)
    mean = np.trapezoid(t * p, t)
    return mean, np.trapezoid((t - mean) ** 2 * p, t)


def _conjugate() -> tuple[float, float]:
    v = 1.0 / (1.0 / PRIOR_SD**2 + 1.0)
    return v * (PRIOR_MEAN / PRIOR_SD**2 + OBSERVED), v


def _assert_moments(result, mean: float, var: float, z: float) -> None:
    ess = result.effective_sample_size()
    got_mean, got_var = result.bayes_estimate()[0], result.covariance()[0, 0]
    assert abs(got_mean - mean) < z * math.sqrt(var / ess), (got_mean, mean, ess)
    assert abs(got_var - var) < z * var * math.sqrt(2 / ess), (got_var, var, ess)


def test_the_far_quantile_box_and_the_mass_it_leaves_out():
    prior = jaxabc.Independent(
        t=dist.Normal(PRIOR_MEAN, PRIOR_SD),
        rate=dist.Exponential(2.0),
        scale=dist.LogNormal(0.0, 1.0),
        shape=dist.Gamma(2.0, 1.0),  # no numpyro icdf: bisection of the cdf
        half=dist.Normal(0.0, 1.0),
        bounds={"half": (0.0, np.inf)},
    )
    norm, expon, lognorm, gamma = (
        scipy_stats.norm(PRIOR_MEAN, PRIOR_SD),
        scipy_stats.expon(scale=0.5),
        scipy_stats.lognorm(1.0),
        scipy_stats.gamma(2.0),
    )
    low, high = np.asarray(prior.low, np.float64), np.asarray(prior.high, np.float64)
    # The stated quantiles, to float32 rounding of the box.
    np.testing.assert_allclose(low[[0, 1, 2, 3, 4]], [norm.ppf(TAIL), 0.0, 0.0, 0.0, 0.0], rtol=1e-6)
    np.testing.assert_allclose(
        high,
        [norm.isf(TAIL), expon.isf(TAIL), lognorm.isf(TAIL), gamma.isf(TAIL), scipy_stats.norm.isf(TAIL)],
        rtol=1e-6,
    )
    # The reported mass is the base distribution's outside the automatic sides of the box ...
    exact = [
        norm.cdf(low[0]) + norm.sf(high[0]),
        expon.sf(high[1]),
        lognorm.sf(high[2]),
        gamma.sf(high[3]),
        scipy_stats.norm.sf(high[4]),
    ]
    np.testing.assert_allclose(prior.tail_mass, exact, rtol=1e-5)
    # ... and within the stated tolerance: TAIL per automatic side (float64 rounding of a cdf
    # near 1 is 1e-16, a relative 1e-7 of TAIL).
    sides = np.array([2, 1, 1, 1, 1])
    assert np.all(prior.tail_mass <= sides * TAIL * (1 + 1e-6)) and np.all(prior.tail_mass > 0.5 * sides * TAIL)
    # Automatic bounds, and the 0 the half-line supports fix, are physical limits; the given 0 is not.
    assert prior.limits == ((True, True), (True, True), (True, True), (True, True), (False, True))
    assert "left out" in repr(prior)
    # Bounds given in full leave nothing out and are choices, as before.
    given = jaxabc.Independent(t=dist.Normal(0.0, 1.0), bounds={"t": (-3.0, 3.0)})
    assert given.tail_mass.tolist() == [0.0] and given.limits == ((False, False),)
    assert "limits" not in given.to_dict()
    # Samples stay in the box, and the files rebuild the same prior.
    x = np.asarray(prior.sample(jax.random.key(0), 4000))
    assert np.all(prior.contains(jnp.asarray(x)))
    assert abs(x[:, 3].mean() - gamma.mean()) < 4 * gamma.std() / math.sqrt(4000)
    back = jaxabc.Independent.from_dict(prior.to_dict())
    np.testing.assert_array_equal(back.low, prior.low)
    np.testing.assert_array_equal(back.high, prior.high)
    assert back.limits == prior.limits and np.array_equal(back.tail_mass, prior.tail_mass)
    # A smaller tail: a wider box, less left out.
    tighter = jaxabc.Independent(t=dist.Normal(0.0, 1.0), tail=1e-12)
    assert float(tighter.high[0]) > 7.0 and tighter.tail_mass[0] <= 2e-12 * (1 + 1e-6)


def test_a_heavy_tail_gets_a_warning_to_give_bounds():
    with pytest.warns(UserWarning, match=r"interquartile ranges wide.*bounds=\{'c'"):
        jaxabc.Independent(c=dist.Cauchy(0.0, 1.0))


@pytest.mark.parametrize(
    "algorithm, z, options",
    [
        ("apmcabc", 4.0, dict(num_particles=1000, num_steps=5, alpha=0.1, acceptance_cutoff=0.03)),
        ("rejection", 4.0, dict(num_particles=1000, quantile=0.05)),
    ],
)
def test_a_normal_prior_without_bounds_gives_the_conjugate_posterior(algorithm, z, options):
    prior = jaxabc.Independent(t=dist.Normal(PRIOR_MEAN, PRIOR_SD))
    with warnings.catch_warnings():
        warnings.simplefilter("error", jaxabc.PriorEdgeWarning)
        result = run_fused(
            algorithm, examples.gaussian_simulate, prior, np.array([OBSERVED]), distance="euclidean", seed=5, **options
        )
    eps = float(result.thresholds[-1])
    normal = scipy_stats.norm(PRIOR_MEAN, PRIOR_SD)
    mean, var = _abc_posterior_moments(normal.logpdf, eps, float(prior.low[0]), float(prior.high[0]))
    _assert_moments(result, mean, var, z)
    # At this eps the ABC posterior is the conjugate one to within a standard error of the run.
    exact_mean, exact_var = _conjugate()
    ess = result.effective_sample_size()
    assert abs(mean - exact_mean) < math.sqrt(exact_var / ess) and abs(var - exact_var) < exact_var * math.sqrt(2 / ess)
    _assert_moments(result, exact_mean, exact_var, z + 1.0)
    # The flat-prior answer (mean 2) is far outside these errors, and the box is the prior's.
    assert abs(result.bayes_estimate()[0] - OBSERVED) > 0.5
    assert not result.diagnostics["prior_edge"]["messages"]


def test_a_half_bounded_prior_without_bounds_runs():
    """Exponential(1) prior: the posterior at ``eps`` by quadrature on ``[0, high]``.  Its mass
    near 0 (the prior's mode) is no warning: the support fixes 0, a physical limit."""
    prior = jaxabc.Independent(rate=dist.Exponential(1.0))
    assert float(prior.low[0]) == 0.0 and prior.limits == ((True, True),)
    with warnings.catch_warnings():
        warnings.simplefilter("error", jaxabc.PriorEdgeWarning)
        result = run_fused(
            "apmcabc",
            examples.gaussian_simulate,
            prior,
            np.array([OBSERVED]),
            num_particles=1000,
            num_steps=5,
            distance="euclidean",
            seed=2,
        )
    assert np.all(prior.contains(jnp.asarray(result.particles)))
    eps = float(result.thresholds[-1])
    mean, var = _abc_posterior_moments(lambda t: -t, eps, 0.0, float(prior.high[0]))
    _assert_moments(result, mean, var, 4.0)


def _result(particles, prior):
    particles = np.asarray(particles, np.float64)
    n = particles.shape[0]
    return jaxabc.ABCResult(
        particles=particles,
        weights=np.full(n, 1.0 / n),
        distances=np.zeros(n),
        thresholds=np.array([1.0]),
        simulations_per_step=np.array([n]),
        acceptance_rates=np.array([1.0]),
        ess=np.array([float(n)]),
        num_simulations=n,
        algorithm="rejection",
        settings={},
        prior=prior,
        seed=0,
    )


def test_a_posterior_at_an_automatic_bound_is_noted_not_warned():
    """Data deep in the prior's tail pile the posterior at the far quantile: widening the box there
    adds at most ``tail`` of prior mass, so it is a physical limit; the same box given as
    ``bounds`` is a choice and warns."""
    auto = jaxabc.Independent(t=dist.Normal(0.0, 1.0))
    high = float(auto.high[0])
    particles = np.r_[np.full(20, high - 1e-3), np.linspace(-1.0, 1.0, 80)][:, None]
    with warnings.catch_warnings():
        warnings.simplefilter("error", jaxabc.PriorEdgeWarning)
        r = _result(particles, auto)
    edge = r.diagnostics["prior_edge"]
    assert not edge["messages"] and "physical limit" in edge["at_physical_limits"][0]
    given = jaxabc.Independent(t=dist.Normal(0.0, 1.0), bounds={"t": (float(auto.low[0]), high)})
    with pytest.warns(jaxabc.PriorEdgeWarning, match="upper bound"):
        _result(particles, given)
