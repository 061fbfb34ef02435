"""B2 from a reference pair potential (md.fluids.pair_b2): quadrature, data and the loop at fh = 1."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxabc
from jaxabc.criticism import critique
from md.fluids.pair_b2 import BASE_NAMES, NEON_HFD_B, NEON_TT2003, b2_catalogue, b2_design, b2_pair, mie
from md.fluids.virial import N_A, b2_lj, fh_coefficient

SIGMA_A, EPS_K, MASS = 2.749, 35.6, 20.1797


def lj(r):
    q = (SIGMA_A / r) ** 6
    return 4.0 * EPS_K * (q * q - q)


@pytest.mark.parametrize("t", [25.0, 40.0, 150.0])
@pytest.mark.parametrize("fh", [0.0, 1.0])
def test_quadrature_matches_the_lj_reference_with_and_without_feynman_hibbs(t, fh):
    got = float(b2_pair(lj, jnp.float32(t), fh, MASS))
    d_star = fh * fh_coefficient(t, MASS, SIGMA_A * 1e-10)
    want = float(b2_lj(t / EPS_K, d_star)) * N_A * (SIGMA_A * 1e-8) ** 3
    assert got == pytest.approx(want, abs=0.02 + 2e-4 * abs(want))


def test_reference_potentials_have_their_published_wells():
    assert NEON_TT2003.well_depth_k == pytest.approx(42.37, abs=0.02)
    assert NEON_HFD_B.well_depth_k == pytest.approx(42.25, abs=0.01)
    assert NEON_HFD_B.r_min == pytest.approx(3.091, abs=2e-3)


def chi2(design, thetas):
    out = np.asarray(jax.vmap(design.simulate, in_axes=(None, 0))(jax.random.key(0), jnp.asarray(thetas)))
    return (((out - design.observed) / design.uncertainty) ** 2).sum(1)


def test_classical_potential_within_its_box_misses_the_data_and_feynman_hibbs_fits_it():
    design = b2_design(measurement_noise=False, length_uncertainty=0.005, energy_uncertainty=0.01)
    scales = [(a, b) for a in np.linspace(0.995, 1.005, 11) for b in np.linspace(0.99, 1.01, 11)]
    grid = np.array([[a, b, 0, fh, 0, 0] for a, b in scales for fh in (0, 1)], np.float32)
    c = chi2(design, grid)
    classical, quantum = c[grid[:, 3] == 0].min(), c[grid[:, 3] == 1].min()
    assert classical > 50.0 and quantum < design.observed.size, (classical, quantum)


def test_bad_designs_are_refused():
    with pytest.raises(ValueError, match="no pair potentials"):
        b2_design("xenon")
    with pytest.raises(ValueError, match="unknown potential"):
        b2_design("argon", potential="tt2003")
    with pytest.raises(ValueError, match="among the data"):
        b2_design(temperatures_k=[31.0])
    with pytest.raises(ValueError, match="uncertainty"):
        b2_design(length_uncertainty=0.0)
    with pytest.raises(ValueError, match="odd"):
        b2_pair(lj, jnp.float32(30.0), num_points=1000)


@pytest.mark.parametrize("fh, expect_named", [(1.0, True), (0.0, False)])
def test_the_loop_names_feynman_hibbs_at_its_physical_strength_and_nothing_under_the_null(fh, expect_named):
    design = b2_design(length_uncertainty=0.005, energy_uncertainty=0.01)
    truth = jnp.asarray([1.0, 1.0, 0.0, fh, 0.0, 0.0], jnp.float32)
    observed = np.asarray(design.simulate(jax.random.key(3), truth), float)
    train = ~np.isin(design.temperature_k, [27.0, 35.0, 50.0, 100.0, 200.0])

    def base(key, theta):
        return design.simulate(key, jnp.concatenate([theta, jnp.zeros(4, jnp.float32)]))[train]

    prior = jaxabc.Uniform(design.low, design.high, names=BASE_NAMES)
    result = jaxabc.run(
        "apmcabc", base, prior, observed[train], num_particles=200, num_steps=6, seed=0,
        distance=jaxabc.distances.standardized_euclidean(design.uncertainty[train]),
    )  # fmt: skip
    report = critique(
        result, design.simulate, observed, design.catalogue, held_out=~train, seed=1,
        groups={"B2": np.arange(observed.size)}, num_draws=50, num_replicates=100,
        num_power_replicates=0, base_prior="prior", extend=False,
    )  # fmt: skip
    named = bool(report.misfits) and "feynman_hibbs" in report.cause_analysis.needed
    assert named == expect_named, report.verdict
    if expect_named:
        assert report.causes[0].name == "feynman_hibbs"
    assert next(c for c in report.causes if c.name == "axilrod_teller").invisible


def test_mie_family_is_lj_at_12_and_keeps_its_well():
    r = jnp.linspace(3.0, 6.0, 30001)
    for n in (12.0, 16.0):
        e = np.asarray(mie(r, 3.405, 119.8, n))
        assert e.min() == pytest.approx(-119.8, rel=1e-5)
    q = (3.405 / r) ** 6
    # float32: the terms are up to 4 eps (480 K) before they cancel near sigma, so 1e-3 K absolute.
    np.testing.assert_allclose(mie(r, 3.405, 119.8), 4 * 119.8 * (q * q - q), rtol=1e-5, atol=1e-3)
    with pytest.raises(ValueError, match="shape"):
        b2_catalogue("cubic")


def test_lj_argon_b2_names_the_pair_shape():
    design = b2_design("argon", "lj", length_uncertainty=0.1, energy_uncertainty=0.2)
    assert design.catalogue.names == ["temperature_offset", "feynman_hibbs", "pair_shape", "axilrod_teller"]
    train = np.isin(design.temperature_k, [90.0, 130.0, 200.0, 400.0])

    def base(key, theta):
        return design.simulate(key, jnp.concatenate([theta, jnp.zeros(4, jnp.float32)]))[train]

    prior = jaxabc.Uniform(design.low, design.high, names=BASE_NAMES)
    result = jaxabc.run(
        "apmcabc", base, prior, design.observed[train], num_particles=200, num_steps=6, seed=0,
        distance=jaxabc.distances.standardized_euclidean(design.uncertainty[train]),
    )  # fmt: skip
    report = critique(
        result, design.simulate, design.observed, design.catalogue, held_out=~train, seed=1,
        groups={"B2": np.arange(design.observed.size)}, num_draws=50, num_replicates=100,
        num_power_replicates=0, extend=False,
    )  # fmt: skip
    assert report.misfits and report.causes[0].name == "pair_shape", report.verdict
    assert "pair_shape" in report.cause_analysis.needed
