"""The helium model (md.helium): purity, batching, overflow handling, physical limits."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from md import helium, lj
from md.units import BOLTZMANN_KJ_MOL_K, ZJ_IN_KJ_MOL

# Short runs of the CPU preset: the physics is the same, only the series is shorter.
SHORT = dict(equilibration_ps=1.0, production_ps=2.0)
# Equality checks use very short runs: MD is chaotic, so float32 rounding differences between
# differently shaped (vmapped, padded, re-allocated) computations grow exponentially with time;
# over a few hundred steps they stay at rounding level.
TINY = dict(equilibration_ps=0.02, production_ps=0.5)
TRUTH = jnp.asarray(helium.TRUE_THETA, jnp.float32)


def block_mean_error(x, num_blocks: int = 10):
    x = np.asarray(x, np.float64)
    blocks = x[: len(x) // num_blocks * num_blocks].reshape(num_blocks, -1).mean(axis=1)
    return float(x.mean()), float(blocks.std(ddof=1) / np.sqrt(num_blocks))


def test_presets_match_the_paper_and_validate():
    paper = helium.get_preset("paper")
    assert (paper.num_atoms, paper.box_nm, paper.temperature_k, paper.pressure_atm) == (1000, 27.3, 300.0, 1.0)
    assert (paper.cutoff_nm, paper.dt_ps, paper.tau_t_ps, paper.tau_p_ps) == (0.639, 0.002, 2.0, 20.0)
    assert paper.num_samples == 1000 and paper.blocks_per_sample * paper.rebuild_every == 1000
    assert paper.equilibration_ps == 200.0
    cpu = helium.get_preset("cpu")
    assert cpu.num_samples == 100
    with pytest.raises(ValueError, match="unknown helium preset"):
        helium.get_preset("gpu")
    with pytest.raises(ValueError, match="whole number"):
        _ = helium.get_preset("cpu", sample_every_ps=0.03).blocks_per_sample


def test_simulate_is_pure_vmappable_and_matches_batch():
    simulate = helium.make_simulator("cpu", **TINY)
    batch = helium.make_batch_simulator("cpu", batch_size=4, **TINY)
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    thetas = jnp.asarray([helium.TRUE_THETA, (0.4, 0.3), (0.2, 0.05)], jnp.float32)
    vmapped = np.asarray(jax.jit(jax.vmap(simulate))(keys, thetas))
    single = jax.jit(simulate)
    one_by_one = np.stack([np.asarray(single(k, t)) for k, t in zip(keys, thetas, strict=True)])
    batched, ok = batch(keys, thetas)
    assert vmapped.shape == (3, 5) and np.all(np.isfinite(vmapped)) and ok.all()
    # Rounding differs between batch shapes (fusion, padding) and chaos amplifies it; 1e-3 is
    # far below the effect of any real difference in the dynamics (see the overflow test).
    np.testing.assert_allclose(vmapped, one_by_one, rtol=1e-3)
    np.testing.assert_allclose(batched, one_by_one, rtol=1e-3)
    # Same key, same series; another key, another series.
    again = np.asarray(jax.jit(simulate)(keys[0], thetas[0]))
    np.testing.assert_array_equal(again, one_by_one[0])
    assert not np.allclose(one_by_one[0], np.asarray(jax.jit(simulate)(keys[1], thetas[0])))


def test_ideal_gas_limit():
    """epsilon -> 0: f_B -> exp(-2.5 (N-1)/N) exactly; <P V> = (N-1) k_B T; P and T on target."""
    preset = helium.get_preset("cpu", equilibration_ps=4.0, production_ps=40.0)
    engine = helium.make_engine(preset)
    # epsilon = 0 exactly: with any finite epsilon the r^-12 wall still acts when two atoms pass
    # through each other, so the limit is taken at the limit itself.
    params = lj.LJParams(jnp.float32(0.2556), jnp.float32(0.0 * ZJ_IN_KJ_MOL), jnp.float32(0))

    @jax.jit
    def run(key):
        carry = engine.init(key, params)
        carry, _ = engine.run(carry, params, preset.equilibration_blocks, 1)
        return engine.run(carry, params, 400, preset.blocks_per_sample, engine.thermo)[1]

    t = jax.tree.map(np.asarray, run(jax.random.PRNGKey(1)))
    n = preset.num_atoms
    enthalpy = t.kinetic + t.potential + t.pressure * t.volume
    f_b = np.exp(-enthalpy / (n * BOLTZMANN_KJ_MOL_K * t.temperature))
    np.testing.assert_allclose(f_b, helium.f_b_ideal_gas(n), rtol=2e-5)
    kt = BOLTZMANN_KJ_MOL_K * preset.temperature_k
    pv, pv_err = block_mean_error(t.pressure * t.volume)
    assert abs(pv - (n - 1) * kt) < 4 * pv_err, (pv, (n - 1) * kt, pv_err)
    temp, temp_err = block_mean_error(t.temperature)
    assert abs(temp - preset.temperature_k) < 4 * temp_err
    p, p_err = block_mean_error(t.pressure)
    p_target = engine.config.pressure_kj_mol_nm3
    assert abs(p - p_target) < 4 * p_err, (p, p_target, p_err)


def test_f_b_responds_to_parameters():
    simulate = jax.jit(jax.vmap(helium.make_simulator("cpu", **SHORT)))
    keys = jax.random.split(jax.random.PRNGKey(2), 3)
    thetas = jnp.asarray([helium.TRUE_THETA, (0.5, 0.141), (0.1, 0.01)], jnp.float32)
    means = np.asarray(simulate(keys, thetas)).mean(axis=1)
    ideal = helium.f_b_ideal_gas(helium.get_preset("cpu").num_atoms)
    # Bigger atoms push the virial up and f_B down; tiny weak atoms are nearly an ideal gas
    # (second virial coefficient 2 pi sigma^3 / 3 at 0.1 nm: f_B lower by ~0.2%).
    assert means[1] < means[0] < means[2]
    assert means[2] == pytest.approx(ideal, rel=1e-2)
    assert abs(means[2] - ideal) < abs(means[0] - ideal)


def test_prior_corner_stays_finite():
    """sigma = 0.8 nm > r_c: plain truncation is a repulsive step; the run stays finite."""
    simulate = jax.jit(helium.make_simulator("cpu", **SHORT))
    f_b = np.asarray(simulate(jax.random.PRNGKey(3), jnp.asarray([0.8, 1.0])))
    assert np.all(np.isfinite(f_b)) and np.all(f_b > 0)


_OVERFLOW_KEYS = jax.random.split(jax.random.PRNGKey(4), 2)
_OVERFLOW_THETAS = jnp.asarray([helium.TRUE_THETA, (0.3, 0.5)], jnp.float32)


def _overflow_preset(atoms: int) -> helium.HeliumPreset:
    return helium.get_preset("cpu", num_atoms=atoms, use_neighbor_list=True, batch_size=2, **TINY)


@functools.cache
def _roomy_reference(atoms: int) -> np.ndarray:
    """f_B with the engine's own (roomy) list: computed once per size, before any test below
    shrinks that list, and shared by the overflow cases of that size."""
    simulate = helium.make_simulator(_overflow_preset(atoms))
    return np.asarray(jax.jit(jax.vmap(simulate))(_OVERFLOW_KEYS, _OVERFLOW_THETAS))


# Each case compiles the helium engine three times over: the default suite overflows pair slots
# without cells and atoms per cell with them; the other two kinds run under `slow`.
@pytest.mark.parametrize(
    "atoms, tighten",
    [
        (32, "capacity"),  # too few cells a side: every atom a candidate, pair slots overflow
        pytest.param(128, "capacity", marks=pytest.mark.slow),  # 3 cells a side: sort-free cell list
        # atoms per cell (43 s: slow; the 32-atom case keeps reallocation in the default suite)
        pytest.param(128, "cell_capacity", marks=pytest.mark.slow),
        pytest.param(128, "candidate_capacity", marks=pytest.mark.slow),  # (atom, stencil-cell partner) slots
    ],
)
def test_neighbor_list_overflow_is_reallocated_not_dropped(atoms, tighten):
    preset = _overflow_preset(atoms)
    engine = helium.make_engine(preset)
    keys, thetas = _OVERFLOW_KEYS, _OVERFLOW_THETAS
    reference = _roomy_reference(atoms)
    assert np.all(np.isfinite(reference))
    roomy = engine.neighbor_template
    assert (roomy.spec.cells_per_side >= 3) == (atoms == 128)
    # A list with (almost) no room of one kind: it must overflow at the first rebuild.
    spec = dataclasses.replace(roomy.spec, **{tighten: 1})
    lattice = jnp.asarray(lj.lattice_positions(preset.num_atoms))
    tight = lj.build_neighbor_list(spec, lattice, engine.box0)
    try:
        engine.neighbor_template = tight
        traced = np.asarray(jax.jit(helium.make_simulator(preset))(keys[0], thetas[0]))
        assert np.all(np.isnan(traced))  # a traced call cannot re-allocate: failure, not loss
        batch = helium.make_batch_simulator(preset)
        f_b, ok = batch(keys, thetas)
        assert ok.all()
        assert getattr(engine.neighbor_template.spec, tighten) > 1
        # Different list capacities sum pairs in a different order; chaos amplifies that
        # rounding to ~1e-4 over these 130 steps.  A dropped pair would remove its virial
        # (f_B off by 1e-2 or more), which this tolerance still catches.
        np.testing.assert_allclose(f_b, reference, rtol=1e-3)
    finally:
        engine.neighbor_template = roomy


@pytest.mark.lammps
def test_agrees_with_lammps():
    """Same helium system in LAMMPS: T, P, V and f_B means agree within statistical error and
    the jax-md/LAMMPS KL is within the jax-md seed-to-seed KL spread."""
    from md import lammps_reference

    result = lammps_reference.compare_with_jax_md(jax.random.PRNGKey(7), helium.TRUE_THETA, "cpu", num_seeds=8)
    assert not result["jax_md_failed"]
    for name, q in result["quantities"].items():
        # 4 standard errors; four quantities tested, so a false alarm is ~1e-3.
        assert abs(q["z"]) < 4.0, (name, q)
    cross, seed = np.asarray(result["kl_cross"]), np.asarray(result["kl_jax_md_seed_to_seed"])
    assert np.median(cross) <= np.max(seed), (cross, seed)


def test_batch_groups_on_threads_give_the_same_series():
    # Groups of batch_size run concurrently (one per core); each group's program is the same,
    # so the series cannot depend on the number of threads.
    keys = jax.random.split(jax.random.PRNGKey(3), 9)
    thetas = jnp.asarray(np.column_stack([np.linspace(0.24, 0.27, 9), np.linspace(0.12, 0.16, 9)]), jnp.float32)
    one = helium.make_batch_simulator("cpu", batch_size=4, threads=1, **TINY)(keys, thetas)
    three = helium.make_batch_simulator("cpu", batch_size=4, threads=3, **TINY)(keys, thetas)
    np.testing.assert_array_equal(one[0], three[0])
    np.testing.assert_array_equal(one[1], three[1])
