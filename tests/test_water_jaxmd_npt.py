"""Tests of the Monte Carlo barostat for rigid TIP4P on jax-md (md.water.jaxmd.npt).

The known answer is the ideal gas of rigid molecules: with centre-of-mass scaling the
isothermal-isobaric volume density is ``V^N exp(-P V / kT)``, a Gamma law with mean
``(N + 1) kT / P`` and relative spread ``1 / sqrt(N + 1)``.  The other tests check the move's
mechanics on a small water box: a rejected move changes nothing, an accepted one scales the
centres and the box, keeps every molecule's geometry and refreshes the forces, the proposal
width adapts only when told to, and a run is a function of its key (batched or not).
"""

from __future__ import annotations

import arviz
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax_md import rigid_body

from md.lj.npt import jax_md_float32
from md.units import BAR_IN_KJ_MOL_NM3, BOLTZMANN_KJ_MOL_K
from md.water.jaxmd.engine import RigidWater
from md.water.jaxmd.forcefield import MODELS, ReactionField
from md.water.jaxmd.npt import STATUS_BOX_AT_CUTOFF_LIMIT, MonteCarloBarostat, density_kg_m3
from md.water.jaxmd.simulator import lattice_configuration

TIP4P = MODELS["tip4p"]
# 64 molecules at about 1 g/cm^3; r_c 0.55 nm keeps the minimum image valid down to -14 % volume.
WATER_MOLECULES, WATER_BOX_NM, WATER_CUTOFF_NM = 64, 1.243, 0.55


def _leaves_equal(a, b) -> bool:
    return all(
        np.array_equal(np.asarray(x), np.asarray(y))
        for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True)
    )


def _row(tree, i):
    return jax.tree_util.tree_map(lambda x: x[i], tree)


@pytest.fixture(scope="module", autouse=True)
def _no_persistent_compilation_cache():
    """This module's programs are compiled in-process only.

    Late in a full run (after jaxabc.run has turned the persistent XLA cache on for the process),
    writing or reading these large programs' cache entries aborted the interpreter twice (SIGABRT
    inside jax's compilation_cache); compiled without it they pass. Free the in-memory caches of
    the modules before, too.
    """
    jax.clear_caches()
    previous = jax.config.jax_enable_compilation_cache
    jax.config.update("jax_enable_compilation_cache", False)
    yield
    jax.config.update("jax_enable_compilation_cache", previous)


@pytest.fixture(scope="module")
def water():
    """A 64-molecule lattice box, its barostat at 1 bar and 298 K, and an initial state."""
    with jax_md_float32():
        engine = RigidWater(
            WATER_MOLECULES, [WATER_BOX_NM] * 3, TIP4P, ReactionField(WATER_CUTOFF_NM), neighbor_list=False
        )
        barostat = MonteCarloBarostat(engine, pressure_bar=1.0, temperature_k=298.0, interval_steps=5)
        lattice = engine.bodies(lattice_configuration(WATER_MOLECULES, WATER_BOX_NM, TIP4P))
        # Turned a little at random: the aligned lattice's forces cancel to round-off.
        turn = np.random.default_rng(0).normal(scale=0.15, size=(WATER_MOLECULES, 4))
        quaternion = np.asarray(lattice.orientation.vec) + turn  # pyright: ignore[reportAttributeAccessIssue]
        quaternion /= np.linalg.norm(quaternion, axis=1, keepdims=True)
        orientation = rigid_body.Quaternion(jnp.asarray(quaternion, jnp.float32))  # pyright: ignore[reportCallIssue]
        body = rigid_body.RigidBody(lattice.center, orientation)  # pyright: ignore[reportCallIssue]
        state = jax.jit(barostat.init)(jax.random.PRNGKey(0), TIP4P, body)
        moves = jax.jit(jax.vmap(lambda k, s: barostat.volume_move(k, s, TIP4P), in_axes=(0, None)))
    return engine, barostat, body, state, moves


@pytest.fixture(scope="module")
def water_run(water):
    """``run(key, theta)`` of the water box: 1 equilibration and 3 production moves of 5 steps."""
    _, barostat, body, _, _ = water
    return jax.jit(lambda key, theta: barostat.run(key, TIP4P.with_theta(theta), body, 1, 3))


@pytest.fixture(scope="module")
def ideal_gas():
    """Eight molecules with the forces off (epsilon = q_H = 0), P set for <V> = (3 nm)^3 at 298 K.

    Returns the barostat, the model, the number of molecules, the expected mean volume (nm^3)
    and ``run(key, box_nm)``: 4000 production moves, one NVT step each, no equilibration.
    """
    num_molecules, temperature_k, mean_box_nm = 8, 298.0, 3.0
    expected = mean_box_nm**3
    pressure_bar = (num_molecules + 1) * BOLTZMANN_KJ_MOL_K * temperature_k / expected / BAR_IN_KJ_MOL_NM3
    free = TIP4P._replace(sigma_nm=0.1, epsilon_kj_mol=0.0, charge_h_e=0.0)
    with jax_md_float32():
        # r_c 0.3 nm: volumes below (0.6 nm)^3 lie ~1e-11 into the Gamma law's lower tail.
        engine = RigidWater(num_molecules, [mean_box_nm] * 3, TIP4P, ReactionField(0.3), neighbor_list=False)
        # A width of 0.7 is near optimal for a relative spread of 1/3: no adaptation needed.
        barostat = MonteCarloBarostat(engine, pressure_bar, temperature_k, interval_steps=1, log_volume_step=0.7)
        body = engine.bodies(lattice_configuration(num_molecules, mean_box_nm, TIP4P))
        run = jax.jit(lambda key, box: barostat.run(key, free, body, 0, 4000, box_nm=box))
    return barostat, free, num_molecules, expected, run


def test_ideal_gas_mean_volume_is_n_plus_one_kt_over_p(ideal_gas):
    """<V> = (N + 1) kT / P within 4 autocorrelation-corrected standard errors, and the test can
    tell it from N kT / P (the answer of a walk in ln V with the Jacobian of a walk in V)."""
    _, _, num_molecules, expected, run_fn = ideal_gas
    with jax_md_float32():
        run = run_fn(jax.random.PRNGKey(0), jnp.full(3, 3.0))
    volume = np.asarray(run.volume_nm3, np.float64)
    assert int(run.status) == 0 and 0.3 < float(run.acceptance_rate) < 0.9
    ess = float(arviz.ess(volume[None]))
    standard_error = volume.std(ddof=1) / np.sqrt(ess)
    assert ess > 300
    assert abs(volume.mean() - expected) < 4 * standard_error
    assert abs(volume.mean() - expected * num_molecules / (num_molecules + 1)) > 4 * standard_error
    # Gamma(N + 1): relative spread 1/sqrt(N + 1); its sampling error at this ESS is ~3 %.
    assert volume.std() / volume.mean() == pytest.approx(1 / np.sqrt(num_molecules + 1), rel=0.12)
    np.testing.assert_allclose(np.asarray(run.density_kg_m3), density_kg_m3(volume, num_molecules), rtol=1e-5)


def test_proposals_below_twice_the_cutoff_are_rejected_and_flagged(ideal_gas):
    """From a box just above 2 r_c = 0.6 nm, compressions past it are refused and reported."""
    _, _, _, _, run_fn = ideal_gas
    with jax_md_float32():
        run = run_fn(jax.random.PRNGKey(1), jnp.full(3, 0.61))
    assert int(run.status) == STATUS_BOX_AT_CUTOFF_LIMIT
    assert float(np.min(np.asarray(run.volume_nm3))) > 0.6**3


def test_rejected_moves_leave_the_state_bit_identical(water):
    _, _, _, state, moves = water
    new, info = moves(jax.random.split(jax.random.PRNGKey(1), 16), state._replace(log_volume_step=jnp.float32(0.03)))
    accepted = np.asarray(info.accepted)
    assert 0 < accepted.sum() < accepted.size  # both kinds occur at this width
    for i in np.flatnonzero(~accepted):
        row = _row(new, i)
        assert _leaves_equal(row.nvt, state.nvt) and _leaves_equal(row.box_nm, state.box_nm)
        assert float(info.volume_nm3[i]) == float(jnp.prod(state.box_nm))
        assert int(row.attempts) == int(state.attempts) + 1 and int(row.accepted) == int(state.accepted)


def test_accepted_moves_scale_centres_keep_molecules_rigid_and_refresh_forces(water):
    engine, barostat, _, state, moves = water
    new, info = moves(jax.random.split(jax.random.PRNGKey(2), 16), state._replace(log_volume_step=jnp.float32(0.03)))
    accepted = np.flatnonzero(np.asarray(info.accepted))
    assert accepted.size > 0
    force_fn = jax.jit(jax.grad(barostat.energy_fn(TIP4P)))
    for i in accepted:
        row = _row(new, i)
        scale = np.asarray(row.box_nm) / np.asarray(state.box_nm)
        assert np.ptp(scale) == 0 and scale[0] != 1  # isotropic, and a real change
        expected_centres = np.asarray(jnp.mod(state.nvt.position.center, state.box_nm) * scale[0])
        np.testing.assert_array_equal(np.asarray(row.nvt.position.center), expected_centres)
        assert _leaves_equal(row.nvt.position.orientation, state.nvt.position.orientation)
        assert _leaves_equal(row.nvt.momentum, state.nvt.momentum)
        assert _leaves_equal(row.nvt.chain, state.nvt.chain)
        sites = np.asarray(engine.sites(row.nvt.position, TIP4P), np.float64)
        oh = np.linalg.norm(sites[:, 1:3] - sites[:, :1], axis=-1)
        hh = np.linalg.norm(sites[:, 1] - sites[:, 2], axis=-1)
        np.testing.assert_allclose(oh, TIP4P.oh_distance_nm, rtol=2e-6)
        np.testing.assert_allclose(hh, TIP4P.hh_distance_nm, rtol=2e-6)
        # The stored force is the one at the new positions and box (the next half kick uses it).
        gradient = force_fn(row.nvt.position, box=row.box_nm)
        force = np.asarray(row.nvt.force.center)
        tolerance = 1e-5 * np.abs(force).max()
        np.testing.assert_allclose(force, -np.asarray(gradient.center), atol=tolerance)
        # ... which this check can tell from the force before the move
        assert np.abs(np.asarray(state.nvt.force.center) - force).max() > 10 * tolerance


def test_molecules_stay_rigid_along_a_run(water, water_run):
    engine = water[0]
    with jax_md_float32():
        run = water_run(jax.random.PRNGKey(3), jnp.array([TIP4P.sigma_nm, TIP4P.epsilon_kj_mol]))
    assert int(run.status) == 0 and float(run.acceptance_rate) > 0
    sites = np.asarray(engine.sites(run.final_state.nvt.position, TIP4P), np.float64)
    np.testing.assert_allclose(np.linalg.norm(sites[:, 1:3] - sites[:, :1], axis=-1), TIP4P.oh_distance_nm, rtol=2e-6)
    np.testing.assert_allclose(np.linalg.norm(sites[:, 1] - sites[:, 2], axis=-1), TIP4P.hh_distance_nm, rtol=2e-6)


def test_proposal_width_adapts_only_in_equilibration(ideal_gas):
    """OpenMM's rule: after 10 attempts, times 1.1 above 75 % acceptance, / 1.1 below 25 %, and
    the counts restart only when the width changed."""
    barostat, free, _, _, _ = ideal_gas
    with jax_md_float32():
        body = barostat.engine.bodies(lattice_configuration(8, 3.0, TIP4P))
        # U = 0 and a width of 1e-7: the move is accepted (the odds of a rejection are ~1e-6)
        state = jax.jit(barostat.init)(jax.random.PRNGKey(0), free, body)._replace(log_volume_step=jnp.float32(1e-7))
        move = jax.jit(lambda s, adapt: barostat.volume_move(jax.random.PRNGKey(1), s, free, adapt), static_argnums=1)
        nine = jnp.asarray(9, jnp.int32)
        for previously_accepted, factor in ((9, 1.1), (5, 1.0), (1, 1 / 1.1)):
            start = state._replace(attempts=nine, accepted=jnp.asarray(previously_accepted, jnp.int32))
            new, info = move(start, True)
            assert bool(info.accepted)
            assert float(new.log_volume_step) == pytest.approx(1e-7 * factor, rel=1e-6)
            restarted = factor != 1.0
            assert int(new.attempts) == (0 if restarted else 10)
            assert int(new.accepted) == (0 if restarted else previously_accepted + 1)
            new, _ = move(start, False)
            assert float(new.log_volume_step) == float(start.log_volume_step) and int(new.attempts) == 10


def test_same_key_same_run(water_run):
    theta = jnp.array([TIP4P.sigma_nm, TIP4P.epsilon_kj_mol])
    with jax_md_float32():
        first = water_run(jax.random.PRNGKey(4), theta)
        assert _leaves_equal(first, water_run(jax.random.PRNGKey(4), theta))
        other = water_run(jax.random.PRNGKey(5), theta)
    assert not np.array_equal(np.asarray(first.volume_nm3), np.asarray(other.volume_nm3))


@pytest.mark.slow  # one more compilation of a whole run
def test_batched_over_parameters_equals_one_by_one(water, water_run):
    _, barostat, body, _, _ = water
    thetas = jnp.array([[0.315365, 0.648520], [0.30, 0.80]])
    keys = jax.random.split(jax.random.PRNGKey(6), 2)
    with jax_md_float32():
        batched = jax.jit(jax.vmap(lambda k, t: barostat.run(k, TIP4P.with_theta(t), body, 1, 3)))(keys, thetas)
        for i in range(2):
            alone = water_run(keys[i], thetas[i])
            row = _row(batched, i)
            assert int(row.status) == 0
            assert float(row.acceptance_rate) == float(alone.acceptance_rate)
            np.testing.assert_allclose(np.asarray(row.density_kg_m3), np.asarray(alone.density_kg_m3), rtol=1e-5)
            np.testing.assert_allclose(
                np.asarray(row.potential_kj_mol_per_molecule),
                np.asarray(alone.potential_kj_mol_per_molecule),
                rtol=1e-4,
            )


def test_bad_settings_are_refused():
    engine = RigidWater(8, [3.0] * 3, TIP4P, ReactionField(0.3), neighbor_list=True)
    with pytest.raises(ValueError, match="neighbor_list=False"):
        MonteCarloBarostat(engine)
    engine = RigidWater(8, [3.0] * 3, TIP4P, ReactionField(0.3), neighbor_list=False)
    with pytest.raises(ValueError, match="interval_steps >= 1"):
        MonteCarloBarostat(engine, interval_steps=0)
    with pytest.raises(ValueError, match="pressure_bar must be finite"):
        MonteCarloBarostat(engine, pressure_bar=float("nan"))
    barostat = MonteCarloBarostat(engine)
    body = engine.bodies(lattice_configuration(8, 3.0, TIP4P))
    with pytest.raises(ValueError, match="production_moves >= 1"):
        barostat.run(jax.random.PRNGKey(0), TIP4P, body, 1, 0)


# --------------------------------------------------------------------------------------------
# NPT in the simulator (``make_simulator(..., ensemble="npt")``)
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def npt_simulator():
    """The ``tiny`` preset at 1 bar from GROMACS's tip4p.gro: 4 equilibration moves, 8 frames
    of 2 moves (25 steps each)."""
    from md.water.gromacs import find_gmx
    from md.water.jaxmd.simulator import make_simulator

    try:
        find_gmx()
    except FileNotFoundError as error:
        pytest.skip(f"needs GROMACS's tip4p.gro: {error}")
    with jax_md_float32():
        yield make_simulator("tiny", ensemble="npt")


def test_npt_simulator_summaries_equal_the_host_pipeline_on_fluctuating_boxes(npt_simulator):
    """Frames carry each frame's (isotropically scaled) box; S1..S9 from them in JAX equal the
    GROMACS plugin's numpy pipeline (per-frame 1/V normalisation, von Buelow unwrapping)."""
    from md.water import analysis, statistics

    simulator = npt_simulator
    theta = jnp.array([0.315365, 0.648520])
    with jax_md_float32():
        frames, status = simulator._frames(jax.random.PRNGKey(3), theta)
        summaries, final = simulator._finish(frames, status)
    assert int(status) == 0 and int(final) == 0
    box = np.asarray(frames.box_nm, np.float64)
    assert box.shape == (8, 3) and np.ptp(box[:, 0]) > 0  # the barostat moved the box
    np.testing.assert_allclose(box / box[:, :1], 1.0, rtol=1e-6)  # isotropic
    assert np.min(box) > 2 * simulator.preset.cutoff_nm
    density = np.asarray(simulator.density_kg_m3(frames))
    np.testing.assert_allclose(density, density_kg_m3(np.prod(box, axis=1), 216), rtol=1e-5)
    num_frames = box.shape[0]
    trajectory = analysis.WaterTrajectory(
        time_ps=simulator.preset.frame_interval_ps * np.arange(num_frames),
        oxygen_nm=np.asarray(frames.oxygen_nm),
        hydrogen_nm=np.asarray(frames.hydrogen_nm),
        box_nm=box,
    )
    host = statistics.summary_statistics(analysis.compute_curves(trajectory, "robust"), "robust")
    assert np.all(np.isfinite(host))
    np.testing.assert_allclose(np.asarray(summaries, np.float64), host, rtol=2e-4, atol=1e-5)


def test_npt_simulator_is_a_function_of_key_and_theta_and_reports_density_failures(npt_simulator, monkeypatch):
    from jaxabc.errors import SimulationFailure
    from md.water.jaxmd.simulator import (
        STATUS_COLLAPSED,
        STATUS_VAPORISED,
        JaxWaterPreset,
        failure_reason,
        make_simulator,
    )

    simulator = npt_simulator
    key, theta = jax.random.PRNGKey(3), (0.315365, 0.648520)
    with jax_md_float32():
        first = simulator(key, theta)
        np.testing.assert_array_equal(simulator(key, theta), first)
        frames, status = simulator._frames(key, jnp.asarray(theta))
        mean_density = float(np.mean(np.asarray(simulator.density_kg_m3(frames))))
        # The same frames judged against a density band that excludes them.
        bands = {
            STATUS_VAPORISED: JaxWaterPreset("low", ensemble="npt", min_density_kg_m3=mean_density + 1),
            STATUS_COLLAPSED: JaxWaterPreset("high", ensemble="npt", max_density_kg_m3=mean_density - 1),
        }
        for bit, band in bands.items():
            judge = make_simulator(band, equilibration_steps=100, frame_interval_steps=50, num_frames=8)
            bad, bad_status = judge.finish(frames, status)
            assert int(bad_status) == bit and np.all(np.isnan(np.asarray(bad)))
            monkeypatch.setattr(judge, "_frames", lambda *unused, frames=frames, status=status: (frames, status))
            with pytest.raises(SimulationFailure, match=failure_reason(bit).split(":")[-1].strip()):
                judge(key, theta)
    assert "vaporised" in failure_reason(STATUS_VAPORISED) and "collapsed" in failure_reason(STATUS_COLLAPSED)


def test_npt_presets_refuse_what_they_cannot_do():
    from md.water.jaxmd.simulator import PRESETS, JaxWaterPreset

    assert PRESETS["quick_npt"].ensemble == "npt" and PRESETS["quick"].ensemble == "nvt"
    with pytest.raises(ValueError, match="divide"):
        JaxWaterPreset("x", ensemble="npt", frame_interval_steps=30)
    with pytest.raises(ValueError, match="all pairs"):
        JaxWaterPreset("x", ensemble="npt", neighbor_list=True)
    with pytest.raises(ValueError, match="ensemble must be"):
        JaxWaterPreset("x", ensemble="nph")
    with pytest.raises(ValueError, match="min_density"):
        JaxWaterPreset("x", ensemble="npt", min_density_kg_m3=1600.0)
