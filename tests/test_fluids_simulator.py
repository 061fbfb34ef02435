"""The neon/argon state-point simulator: three-body term, B2 quadrature, tails, engine, criticism."""

from __future__ import annotations

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate

from md.fluids.simulator import (
    STATUS_BITS,
    FluidConfig,
    _pair,
    b2_quadrature,
    fluid_catalogue,
    fluid_setup,
    mie_prefactor,
    tail_corrections,
)
from md.fluids.three_body import axilrod_teller_energy, c9_reduced, nearest_neighbors
from md.fluids.virial import b2_reduced

# -- Axilrod-Teller ------------------------------------------------------------------------------


def _triple_loop_energy(pos: np.ndarray, side: float, nu: float, cutoff: float) -> float:
    """Direct sum over i < j < k with minimum-image sides, float64."""

    def vec(i, j):
        d = pos[j] - pos[i]
        return d - side * np.round(d / side)

    total = 0.0
    for i, j, k in itertools.combinations(range(len(pos)), 3):
        a, b = vec(i, j), vec(i, k)
        c = b - a
        ra, rb, rc = np.linalg.norm(a), np.linalg.norm(b), np.linalg.norm(c)
        if max(ra, rb, rc) >= cutoff:
            continue
        cos_i = a @ b / (ra * rb)
        cos_j = -(a @ c) / (ra * rc)
        cos_k = b @ c / (rb * rc)
        total += nu * (1.0 + 3.0 * cos_i * cos_j * cos_k) / (ra * rb * rc) ** 3
    return float(total)


def _configuration(num: int = 11, side: float = 3.8, seed: int = 3) -> np.ndarray:
    """Random atoms kept at least 0.8 apart (minimum image)."""
    rng = np.random.default_rng(seed)
    pos: list[np.ndarray] = []
    while len(pos) < num:
        x = rng.uniform(0, side, 3)
        d = np.array(pos) - x if pos else np.zeros((0, 3))
        d -= side * np.round(d / side)
        if not pos or np.min(np.linalg.norm(d, axis=1)) > 0.8:
            pos.append(x)
    return np.array(pos)


def test_axilrod_teller_energy_and_forces_match_a_triple_loop():
    side, cutoff, nu = 3.8, 1.9, 0.07
    pos = _configuration(side=side)
    n = len(pos)

    def energy(p):
        vec, _ = nearest_neighbors(p, jnp.asarray(side), n - 1)
        return axilrod_teller_energy(vec, nu, cutoff)

    with jax.enable_x64(True):
        p64 = jnp.asarray(pos, jnp.float64)
        e, grad = jax.jit(jax.value_and_grad(energy))(p64)
        e, forces = float(e), -np.asarray(grad)
    expect = _triple_loop_energy(pos, side, nu, cutoff)
    assert abs(expect) > 1e-4, "the configuration must hold triples inside the cutoff"
    assert e == pytest.approx(expect, rel=1e-10)
    # Forces on a few atoms: central differences of the loop (its triple set is fixed for small moves).
    h = 1e-6
    fd = np.zeros((3, 3))
    for i in range(3):
        for a in range(3):
            up, down = pos.copy(), pos.copy()
            up[i, a] += h
            down[i, a] -= h
            fd[i, a] = -(_triple_loop_energy(up, side, nu, cutoff) - _triple_loop_energy(down, side, nu, cutoff)) / (
                2 * h
            )
    assert np.max(np.abs(fd)) > 1e-3
    np.testing.assert_allclose(forces[:3], fd, atol=1e-6 * np.max(np.abs(fd)) + 1e-9, rtol=1e-5)
    np.testing.assert_allclose(forces.sum(axis=0), 0.0, atol=1e-10)  # Newton's third law


def test_axilrod_teller_sign_magnitude_and_virial():
    r = 1.1
    equilateral = np.array([[0, 0, 0], [r, 0, 0], [r / 2, r * np.sqrt(3) / 2, 0]])
    line = np.array([[0, 0, 0], [r, 0, 0], [2 * r, 0, 0]])

    @jax.jit
    def at(p):
        vec, _ = nearest_neighbors(p, jnp.asarray(50.0), 2)
        return axilrod_teller_energy(vec, 1.0, 3.0)

    def energy(p, scale=1.0):
        return float(at(jnp.asarray(p * scale, jnp.float32)))

    # Equilateral: 1 + 3 (1/2)^3 = 11/8 over r^9, repulsive; collinear: 1 - 3 = -2 over (2 r^3)^3.
    assert energy(equilateral) == pytest.approx(1.375 / r**9, rel=1e-5)
    assert energy(line) == pytest.approx(-2.0 / (2 * r**3) ** 3, rel=1e-5)
    # Homogeneous of degree -9: W = -dE/dln L = 9 E, the pressure formula the simulator uses.
    eps = 1e-3
    dlog = (energy(equilateral, 1 + eps) - energy(equilateral, 1 - eps)) / (2 * eps)
    assert -dlog == pytest.approx(9 * energy(equilateral), rel=1e-3)


def test_c9_conversion_to_reduced_units():
    # Argon, C9 = 521 au, sigma 3.405 A, epsilon 119.8 K: nu = C9 / (epsilon sigma^9) by hand.
    c9 = 521 * 4.3597447222071e-18 * (0.529177210903e-10) ** 9
    assert c9_reduced(521.0, 119.8, 3.405e-10) == pytest.approx(c9 / (119.8 * 1.380649e-23 * 3.405e-10**9))
    assert 0.06 < c9_reduced(521.0, 119.8, 3.405e-10) < 0.09
    with pytest.raises(ValueError, match="positive"):
        c9_reduced(521.0, -1.0, 3.4e-10)


# -- pair quantities ------------------------------------------------------------------------------


@pytest.mark.parametrize(("temperature", "d_star"), [(0.7, 0.0), (1.0, 0.003), (3.0, 0.0), (8.0, 0.001)])
def test_b2_quadrature_matches_adaptive_scipy(temperature, d_star):
    with jax.enable_x64(True):
        got = float(b2_quadrature(jnp.float64(temperature), jnp.float64(d_star)))
    assert got == pytest.approx(b2_reduced(temperature, d_star), rel=1e-6, abs=1e-6)


@pytest.mark.parametrize("n", [12.0, 10.0, 16.8])
def test_tail_corrections_match_numerical_integrals(n):
    rho, rc, d = 0.8, 2.3, 0.002
    c = float(mie_prefactor(n))

    def u(r):
        return c * (r**-n - r**-6) + d * c * (n * (n - 1) * r ** -(n + 2) - 30 * r**-8)

    def du(r):
        return c * (-n * r ** -(n + 1) + 6 * r**-7) + d * c * (-(n + 2) * n * (n - 1) * r ** -(n + 3) + 240 * r**-9)

    u_num = 2 * math.pi * rho * integrate.quad(lambda r: u(r) * r * r, rc, np.inf)[0]
    p_num = -2 * math.pi / 3 * rho**2 * integrate.quad(lambda r: du(r) * r**3, rc, np.inf)[0]
    u_tail, p_tail = tail_corrections(jnp.asarray(rho), jnp.asarray(rc), jnp.asarray(d), n)
    assert float(u_tail) == pytest.approx(u_num, rel=1e-5)
    assert float(p_tail) == pytest.approx(p_num, rel=1e-5)


def test_mie_pair_is_lj_bit_for_bit_at_12_and_has_its_well_and_derivative():
    r2 = jnp.linspace(0.8, 6.0, 500, dtype=jnp.float32)
    d = jnp.float32(0.003)
    u, _ = _pair(r2, d)
    # The plain 12-6 expressions as the engine wrote them before the Mie exponent existed.
    ir2 = 1.0 / r2
    ir6 = ir2 * ir2 * ir2
    ir12 = ir6 * ir6
    lj = 4.0 * (ir12 - ir6) + d * 4.0 * (132.0 * ir12 - 30.0 * ir6) * ir2
    assert bool(jnp.all(u == lj))
    with jax.enable_x64(True):
        r = jnp.linspace(0.95, 2.0, 200001, dtype=jnp.float64)
        for n in (9.0, 16.0):
            e = _pair(r * r, jnp.float64(0.0), n)[0]
            assert float(e.min()) == pytest.approx(-1.0, abs=1e-9)
            assert float(_pair(jnp.float64(1.0), jnp.float64(0.0), n)[0]) == pytest.approx(0.0, abs=1e-12)
            x = jnp.linspace(0.9, 4.0, 40, dtype=jnp.float64)
            grad = jax.vmap(jax.grad(lambda q, n=n: _pair(q, jnp.float64(0.002), n)[0]))(x)
            np.testing.assert_allclose(_pair(x, jnp.float64(0.002), n)[1], grad, rtol=1e-10, atol=1e-12)


def test_catalogue_setup_and_bad_input():
    cat = fluid_catalogue()
    assert cat.names == [
        "temperature_offset", "axilrod_teller", "feynman_hibbs", "density_error", "tail_correction", "pair_shape",
    ]  # fmt: skip
    s = fluid_setup("neon", state_points=[0, 5], b2_temperatures_k=[30.0, 100.0], config=FluidConfig(num_atoms=64))
    assert len(s.names) == 2 + 2 + 2 and s.observed.shape == s.uncertainty.shape == (6,)
    assert set(s.groups) == {"P 26 K", "U 26 K", "P 30 K", "U 30 K", "B2"}
    assert s.physical["feynman_hibbs"] == 1.0 and 0.02 < s.physical["axilrod_teller"] < 0.06
    with pytest.raises(ValueError, match="B2 temperatures"):
        fluid_setup("neon", b2_temperatures_k=[31.0])
    with pytest.raises(ValueError, match="multiple"):
        FluidConfig(production_steps=101)
    with pytest.raises(ValueError, match="fluid_catalogue"):
        fluid_setup("neon", catalogue=cat.subset(["feynman_hibbs"]))
    assert all(isinstance(v, str) for v in STATUS_BITS.values())


# -- the engine ------------------------------------------------------------------------------------


@pytest.mark.slow
def test_engine_smoke_statuses_and_failures_as_data():
    """The smallest call: shapes, a clean status at a fluid state, and a failure as data (a density
    whose box cannot hold a 2 sigma cutoff gives status 4 and NaN, not an exception)."""
    # 1600 steps: the mean kinetic temperature of 48 atoms is then within 3 % (1 sd) of the set
    # point, so the 15 % status check cannot fire by chance.
    cfg = FluidConfig(num_atoms=48, equilibration_steps=100, production_steps=1600, sample_every=20)
    s = fluid_setup("neon", state_points=[18], b2_temperatures_k=[100.0], config=cfg)
    theta = jnp.asarray([[0.2749, 35.6, 0, 0, 0, 0, 0], [0.2749, 35.6, 0, 0, 0, 0.03, 0]], jnp.float32)
    # 60 K at 2.0 rho_c: rho* = 0.60 with sigma 0.2749 nm (box 4.3 sigma, also with a 3 % density
    # error); a 0.33 nm sigma makes rho* = 1.04 (box 3.6 < 4 sigma): status 4.
    theta = jnp.concatenate([theta, jnp.asarray([[0.33, 35.6, 0, 0, 0, 0, 0]], jnp.float32)])
    out, status = jax.jit(jax.vmap(s.simulate_with_status))(jax.random.split(jax.random.key(1), 3), theta)
    out, status = np.asarray(out), np.asarray(status)
    assert out.shape == (3, 3) and status.shape == (3, 1)
    assert np.all(status[:2] == 0) and np.all(np.isfinite(out[:2]))
    assert status[2, 0] & 4 and np.all(np.isnan(out[2, :2])) and np.isfinite(out[2, 2])


TINY = FluidConfig(num_atoms=64, equilibration_steps=200, production_steps=400, three_body_every=5)


@pytest.fixture(scope="module")
def tiny_neon():
    # A liquid point (26 K) and a supercritical one (60 K, 2.4 rho_c), B2 at 30 and 100 K.
    s = fluid_setup("neon", state_points=[0, 20], b2_temperatures_k=[30.0, 100.0], config=TINY)
    return s, jax.jit(jax.vmap(s.simulate_with_status))


@pytest.mark.slow
def test_engine_runs_feynman_hibbs_raises_pressure_and_b2(tiny_neon):
    """Eight classical and FH neon runs (literature sigma, epsilon), paired by key: every run is
    clean, FH raises the liquid pressure and B2 by many standard errors (a positive correction
    stiffens the core), and pressure and energy of the classical liquid lie in the known LJ range."""
    _setup, run = tiny_neon
    n = 8
    base = np.array([0.2749, 35.6, 0, 0, 0, 0, 0.0])
    thetas = np.stack([base] * n + [base + np.eye(7)[4]] * n)
    # Common random numbers: each FH run shares its key (start, thermostat, measurement noise)
    # with a classical one, so the paired difference carries the MD noise only.  Unpaired, four
    # replicates of 64 atoms left the pressure shift within 5 SE.
    keys = jax.random.split(jax.random.key(0), n)
    out, status = run(jnp.concatenate([keys, keys]), jnp.asarray(thetas, jnp.float32))
    out, status = np.asarray(out, np.float64), np.asarray(status)
    assert np.all(status == 0) and np.all(np.isfinite(out))
    classical, quantum = out[:n], out[n:]
    diff = quantum - classical
    mean, se = diff.mean(0), diff.std(0, ddof=1) / np.sqrt(n)
    assert mean[0] > 5 * se[0], (mean, se)  # liquid pressure, MPa
    # B2 is a quadrature: the paired difference is exact (its noise cancels).
    assert mean[4] > 0 and mean[5] > 0 and se[4] < 1e-3 * mean[4]  # B2 at 30 K and 100 K
    # Classical LJ at T* = 0.73, rho* = 0.76 (near the triple point): U*/N about -5.5 to -6.
    u_star = classical[:, 2].mean() / (35.6 * 8.314462618e-3)
    assert -6.3 < u_star < -5.0, u_star


@pytest.mark.slow
def test_axilrod_teller_effect_is_first_order_and_positive(tiny_neon):
    """The three-body correction is linear in nu by construction; physically it raises both P and
    U of a dense fluid (the triple-dipole term is repulsive on average at liquid densities)."""
    _setup, run = tiny_neon
    base = np.array([0.2749, 35.6, 0, 0, 0, 0, 0.0])
    thetas = np.stack([base, base + 0.1 * np.eye(7)[3], base + 0.2 * np.eye(7)[3]])
    # The same key for all three: the perturbation reuses one trajectory, so differences are exact.
    keys = jnp.stack([jax.random.key(5)] * 3)
    out = np.asarray(run(keys, jnp.asarray(thetas, jnp.float32))[0], np.float64)
    d1, d2 = out[1] - out[0], out[2] - out[0]
    np.testing.assert_allclose(d2[:4], 2 * d1[:4], rtol=1e-3, atol=1e-4)
    assert d1[0] > 0 and d1[2] > 0 and np.allclose(d1[4:], 0.0)
