"""A posterior that piles against a bound of the prior box is flagged on every result.

``ABCResult.prior_edge_mass`` is the weighted mass within 2 % of the range from each bound; a
result made by a run warns (:class:`jaxabc.PriorEdgeWarning`, once, naming the parameter and the
bound) when any of it exceeds 5 %, keeps the sentences in ``diagnostics["prior_edge"]`` and says
so in its summary.  The runs: ``x = mu + N(0, 0.1^2)`` observed at 6 under ``mu ~ U(-5, 1)``.
The data would take ``mu`` to 6: at tolerance ``eps`` the ABC posterior is about flat on
``[6 - eps, 1]``, so the band of width 0.12 under the upper bound holds ``0.12 / (eps - 5)``
of it, more than 5 % once ``eps < 7.4`` (every algorithm gets there in a few steps, and the
exact posterior is a point mass on the bound).  Against it, ``mu ~ U(-5, 5)`` observed at 0:
nothing within 40 sd of a bound.
"""

from __future__ import annotations

import warnings

import jax
import numpy as np
import pytest

import jaxabc
from jaxabc import examples
from jaxabc.diagnostics import PRIOR_EDGE_LIMIT

EDGE_PRIOR = jaxabc.Uniform([-5.0], [1.0], names=("mu",))
EDGE_OBSERVED = np.array([6.0])
INSIDE_PRIOR = jaxabc.Uniform([-5.0], [5.0], names=("mu",))
INSIDE_OBSERVED = np.array([0.0])

# Small budgets; the host driver ("vmap") compiles less than the fused program, which rejection
# covers (the two assemble their results in different places).
RUNS = {
    "rejection": dict(num_particles=200, quantile=0.1, executor=None),
    "pmcabc": dict(num_particles=200, num_steps=5, executor="vmap"),
    "apmcabc": dict(num_particles=200, num_steps=3, executor="vmap"),
    "abcsubsim": dict(num_particles=200, p0=0.2, num_steps=3, executor="vmap"),
}


def sharp_simulate(key, theta):
    """``theta + N(0, 0.1^2)``: the Gaussian mean, measured precisely."""
    return theta + 0.1 * jax.random.normal(key, theta.shape, theta.dtype)


def _result(particles, weights, prior, check=True):
    particles = np.asarray(particles, np.float64)
    n = particles.shape[0]
    return jaxabc.ABCResult(
        particles=particles,
        weights=np.asarray(weights, np.float64),
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
        check=check,
    )


def _edge_warnings(caught):
    return [w for w in caught if issubclass(w.category, jaxabc.PriorEdgeWarning)]


def _run(algorithm, prior, observed):
    options = dict(RUNS[algorithm])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = jaxabc.run(algorithm, sharp_simulate, prior, observed, distance="euclidean", seed=0, **options)
    return result, _edge_warnings(caught)


class _HalfLine:
    """A prior object with no upper bound on its first parameter (the ``Prior`` protocol allows it)."""

    low = np.array([0.0, 0.0])
    high = np.array([np.inf, 10.0])
    names = ("rate", "size")
    units = ("", "")


# -- the mass ----------------------------------------------------------------------------------


def test_edge_mass_is_the_weighted_share_within_the_band():
    """Known particles and weights: the mass is an exact sum of weights."""
    prior = jaxabc.Uniform([0.0, -1.0], [1.0, 1.0], names=("a", "b"))
    # Bands at width 0.02: a in [0, 0.02] and [0.98, 1]; b in [-1, -0.96] and [0.96, 1].
    particles = [[0.0, 0.0], [0.01, 0.5], [0.5, 0.97], [0.99, -0.98], [0.5, 0.0]]
    weights = [0.1, 0.2, 0.3, 0.25, 0.15]
    r = _result(particles, weights, prior, check=False)
    np.testing.assert_allclose(r.prior_edge_mass(), [[0.3, 0.25], [0.25, 0.3]], atol=1e-12)
    # A wider band catches more: a in [0, 0.1] and [0.9, 1]; b in [-1, -0.8] and [0.8, 1].
    np.testing.assert_allclose(r.prior_edge_mass(width=0.1), [[0.3, 0.25], [0.25, 0.3]], atol=1e-12)
    # Wider still: b's upper band [0.4, 1] takes in 0.5 as well.
    np.testing.assert_allclose(r.prior_edge_mass(width=0.3), [[0.3, 0.25], [0.25, 0.5]], atol=1e-12)
    assert r.prior_edge_mass().shape == (2, 2)
    np.testing.assert_allclose(r.diagnostics["prior_edge"]["mass"], [[0.3, 0.25], [0.25, 0.3]], atol=1e-12)
    # Unnormalised weights are normalised first.
    np.testing.assert_allclose(
        _result(particles, np.asarray(weights) * 7, prior, check=False).prior_edge_mass(), r.prior_edge_mass()
    )


def test_a_parameter_without_a_finite_range_has_no_edge():
    """The band is a fraction of the range: with an infinite range there is none, at either side."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", jaxabc.PriorEdgeWarning)
        r = _result([[0.0, 10.0], [0.0, 5.0]], [0.5, 0.5], _HalfLine(), check=False)
    np.testing.assert_allclose(r.prior_edge_mass(), [[0.0, 0.0], [0.0, 0.5]])


def test_the_box_of_a_numpyro_prior_is_its_truncation():
    dist = pytest.importorskip("numpyro.distributions")
    prior = jaxabc.Independent(mu=dist.Normal(0.0, 1.0), bounds={"mu": (-2.0, 2.0)})
    r = _result([[1.99], [0.0], [-1.99], [-1.99]], [0.25] * 4, prior, check=False)
    np.testing.assert_allclose(r.prior_edge_mass(), [[0.5, 0.25]])


@pytest.mark.parametrize("width", [0.0, 0.5, -0.1, 0.7, float("nan")])
def test_a_width_outside_the_open_interval_is_refused(width):
    r = _result([[0.5]], [1.0], jaxabc.Uniform([0.0], [1.0]), check=False)
    with pytest.raises(ValueError, match="width"):
        r.prior_edge_mass(width)


# -- on construction ---------------------------------------------------------------------------


def test_a_result_on_an_edge_warns_once_naming_the_parameter_and_the_bound():
    prior = jaxabc.Uniform([0.0, 0.0], [1.0, 1.0], names=("sigma", "epsilon"))
    particles = np.column_stack([np.linspace(0.2, 0.8, 100), np.r_[np.full(10, 0.995), np.linspace(0.1, 0.9, 90)]])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = _result(particles, np.ones(100) / 100, prior)
    edge = _edge_warnings(caught)
    assert len(edge) == 1 and issubclass(edge[0].category, UserWarning)
    message = str(edge[0].message)
    assert "epsilon" in message and "upper bound 1" in message and "10%" in message
    assert "sigma" not in message and "lower" not in message
    assert edge[0].filename == __file__  # it points at the code that made the result
    stored = r.diagnostics["prior_edge"]
    assert stored["messages"] == [message]
    assert stored["mass"][1][1] == pytest.approx(0.1) and stored["mass"][0] == [0.0, 0.0]
    assert "prior edge:" in r.summary() and message in r.summary()


def test_a_flat_posterior_is_not_an_edge():
    """A prior sample holds 2 % at each bound: below the limit, no warning."""
    rng = np.random.default_rng(0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", jaxabc.PriorEdgeWarning)
        r = _result(rng.uniform(0.0, 1.0, (4000, 2)), np.ones(4000), jaxabc.Uniform([0.0, 0.0], [1.0, 1.0]))
    assert np.all(r.prior_edge_mass() < PRIOR_EDGE_LIMIT)
    assert r.diagnostics["prior_edge"]["messages"] == []
    assert "prior edge" not in r.summary()


def test_from_sample_does_not_warn_but_its_summary_says_so():
    with warnings.catch_warnings():
        warnings.simplefilter("error", jaxabc.PriorEdgeWarning)
        r = jaxabc.ABCResult.from_sample([[0.0], [0.0], [0.5]], [1.0, 1.0, 1.0], jaxabc.Uniform([0.0], [1.0]))
    assert "prior edge:" in r.summary() and "lower bound 0" in r.summary()


# -- runs --------------------------------------------------------------------------------------


@pytest.mark.parametrize("algorithm", sorted(RUNS))
def test_a_posterior_against_the_upper_bound_warns(algorithm):
    r, edge = _run(algorithm, EDGE_PRIOR, EDGE_OBSERVED)
    mass = r.prior_edge_mass()
    assert mass[0, 1] > PRIOR_EDGE_LIMIT and mass[0, 0] == 0.0
    assert len(edge) == 1, [str(w.message) for w in edge]
    message = str(edge[0].message)
    assert "of mu lies" in message and "upper bound 1" in message
    assert edge[0].filename == __file__  # the user's run(...), not the assembly
    assert r.diagnostics["prior_edge"]["messages"] == [message]
    assert "prior edge:" in r.summary() and "upper bound 1" in r.summary()


@pytest.mark.parametrize("algorithm", ["apmcabc", "pmcabc"])
def test_a_posterior_well_inside_the_box_does_not_warn(algorithm):
    r, edge = _run(algorithm, INSIDE_PRIOR, INSIDE_OBSERVED)
    assert edge == []
    assert np.all(r.prior_edge_mass() == 0.0)
    assert r.diagnostics["prior_edge"]["messages"] == []
    assert "prior edge" not in r.summary()


def test_a_loaded_result_does_not_warn_but_its_summary_says_so(tmp_path):
    r, edge = _run("rejection", EDGE_PRIOR, EDGE_OBSERVED)
    assert len(edge) == 1
    path = r.save(tmp_path / "edge")
    # A file written before the diagnostic existed: computed from the data on loading.
    r.diagnostics = {k: v for k, v in r.diagnostics.items() if k != "prior_edge"}
    old = r.save(tmp_path / "old")
    for p in (path, old):
        with warnings.catch_warnings():
            warnings.simplefilter("error", jaxabc.PriorEdgeWarning)
            loaded = jaxabc.load(p)
        np.testing.assert_allclose(loaded.prior_edge_mass(), r.prior_edge_mass())
        assert loaded.diagnostics["prior_edge"]["messages"] == [str(edge[0].message)]
        assert "prior edge:" in loaded.summary() and "upper bound 1" in loaded.summary()


@pytest.mark.slow
def test_a_surrogate_posterior_against_the_upper_bound_warns():
    """The surrogate's result goes through the same assembly (about a minute: its compilation).

    Its likelihood is the exact one, ``x = mu + N(0, 1)`` observed at 3: the posterior density
    rises e-fold per 0.5 towards the upper bound, 20 % of it within 0.12 of the bound.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = jaxabc.run("surrogate", examples.gaussian_simulate, EDGE_PRIOR, np.array([3.0]), seed=0, max_simulations=60)
    edge = _edge_warnings(caught)
    assert r.prior_edge_mass()[0, 1] > PRIOR_EDGE_LIMIT
    assert len(edge) == 1 and "of mu lies" in str(edge[0].message) and "upper bound 1" in str(edge[0].message)
    assert edge[0].filename == __file__
    assert "prior edge:" in r.summary()


def test_a_bound_that_is_a_physical_limit_is_noted_not_warned() -> None:
    """A discrepancy sd piled at 0 is what the data say, not a box cut too tight."""
    import warnings

    prior = jaxabc.Uniform([0.0, 0.0], [1.0, 1.0], names=("a", "sd"), limits=[(False, False), (True, False)])
    assert jaxabc.Uniform.from_dict(prior.to_dict()).limits == prior.limits
    assert "limits" not in jaxabc.Uniform([0.0], [1.0]).to_dict()  # older files and fingerprints unchanged
    x = np.column_stack([np.linspace(0.3, 0.7, 100), np.linspace(0.0, 0.01, 100)])
    with warnings.catch_warnings():
        warnings.simplefilter("error", jaxabc.PriorEdgeWarning)
        result = _result(x, np.full(100, 0.01), prior)
    edge = result.diagnostics["prior_edge"]
    assert not edge["messages"] and "sd" in edge["at_physical_limits"][0] and "physical limit" in result.summary()
    with pytest.raises(ValueError, match="limit flags"):
        jaxabc.Uniform([0.0], [1.0], limits=[(True, False), (False, False)])
