"""Tests of the in-process rigid TIP4P engine (md.water.jaxmd).

The GROMACS test (marker ``gromacs``) compares energies per term and per-atom forces of GROMACS's
equilibrated 216-molecule box with ``gmx mdrun -rerun`` under the same reaction field.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from md.water.jaxmd import forcefield as ff
from md.water.jaxmd.engine import RigidWater, quaternion_from_rotation, rigid_bodies_from_atoms, rotation_matrix
from md.water.topology import TIP4P_PARAMETERS


def _enable_x64():
    if hasattr(jax, "enable_x64"):
        return jax.enable_x64(True)
    from jax.experimental import enable_x64  # pyright: ignore[reportAttributeAccessIssue]

    return enable_x64()


@pytest.fixture(scope="module")
def tip4p_box(tmp_path_factory):
    """GROMACS's equilibrated tip4p.gro (216 molecules), via the plugin's own build step."""
    from md.water.gromacs import build_system, find_gmx, get_protocol
    from md.water.jaxmd.reference import read_gro

    try:
        gmx = find_gmx()
    except FileNotFoundError as error:
        pytest.skip(f"needs GROMACS's tip4p.gro: {error}")
    workdir = tmp_path_factory.mktemp("tip4p")
    build_system(get_protocol("quick"), workdir, gmx)
    return read_gro(workdir / "conf.gro")


# --------------------------------------------------------------------------------------------
# Force field
# --------------------------------------------------------------------------------------------


def test_tip4p_matches_the_gromacs_plugin_parameters():
    model = ff.MODELS["tip4p"]
    assert model.to_gromacs() == TIP4P_PARAMETERS
    assert float(model.vsite_coefficient) == pytest.approx(TIP4P_PARAMETERS.vsite_coefficient, rel=1e-6)
    # every published model: HOH angle 104.52 degrees
    for model in ff.MODELS.values():
        angle = 2 * math.degrees(math.asin(model.hh_distance_nm / (2 * model.oh_distance_nm)))
        assert angle == pytest.approx(104.52, abs=1e-3)
    with pytest.raises(ValueError, match="unknown water model"):
        ff.get_model("spc")


def test_m_site_lies_on_the_bisector_at_d_om():
    model = ff.MODELS["tip4p-2005"]
    atoms, bisector, _ = ff.body_frame(model)
    sites = np.asarray(ff.place_m_site(jnp.asarray(atoms[None]), model))[0]
    om = sites[3] - sites[0]
    assert np.linalg.norm(om) == pytest.approx(model.om_distance_nm, rel=1e-6)
    assert np.allclose(om / np.linalg.norm(om), bisector, atol=1e-6)


def test_reaction_field_pair_vanishes_at_the_cutoff():
    qq, inside = jnp.asarray(-0.5), jnp.asarray(True)
    for epsilon_rf in (math.inf, 78.0):
        settings = ff.ReactionField(0.9, epsilon_rf)
        rc = settings.cutoff_nm

        def pair(r, settings=settings):
            return ff._coulomb(r, qq, inside, settings)

        # continuous at r_c (potential shift), zero beyond
        assert float(pair(jnp.asarray(rc - 1e-6))) == pytest.approx(0.0, abs=1e-4)
        assert float(pair(jnp.asarray(rc + 1e-6))) == 0.0
        slope = float(jax.grad(pair)(jnp.asarray(rc - 1e-6)))
        # force -f qq (1/r^2 - 2 k_rf r): zero at r_c for a conducting boundary (k_rf = 1/(2 r_c^3))
        expected = ff.COULOMB_CONSTANT_KJ_MOL_NM * float(qq) * (-1 / rc**2 + 2 * settings.k_rf * rc)
        assert slope == pytest.approx(expected, rel=1e-3, abs=1e-3)
        if math.isinf(epsilon_rf):
            assert slope == pytest.approx(0.0, abs=1e-3)
    assert ff.ReactionField(1.0, 1.0).k_rf == 0.0  # eps_rf = 1: plain cut-off Coulomb, shifted
    with pytest.raises(ValueError, match="twice the cut-off"):
        ff.ReactionField(0.95).validate(np.array([1.8, 2.0, 2.0]))


def test_neighbor_form_matches_all_pairs():
    model = ff.MODELS["tip4p"]
    settings = ff.ReactionField(0.7)
    rng = np.random.default_rng(3)
    box = np.array([2.0, 2.1, 2.2])
    atoms, _, _ = ff.body_frame(model)
    # 40 randomly placed and oriented molecules (overlaps do not matter for this identity)
    rotations = np.linalg.qr(rng.normal(size=(40, 3, 3)))[0]
    rotations *= np.sign(np.linalg.det(rotations))[:, None, None]
    centers = rng.uniform(0, 1, (40, 3)) * box
    molecules = centers[:, None] + np.einsum("nij,kj->nki", rotations, atoms)
    sites = ff.place_m_site(jnp.asarray(molecules, jnp.float32), model)
    energy = jax.jit(ff.energy_terms, static_argnames="settings")
    dense = energy(sites, box, model, settings)
    everyone = np.array([[j for j in range(40) if j != i] for i in range(40)])
    listed = energy(sites, box, model, settings, neighbors=jnp.asarray(everyone))
    # a list with padding (index 40 = none) and only molecules whose centres are near enough
    delta = centers[:, None] - centers[None]
    delta -= box * np.round(delta / box)
    near = (np.linalg.norm(delta, axis=-1) < settings.cutoff_nm + 0.25) & ~np.eye(40, dtype=bool)
    width = near.sum(1).max() + 3
    padded = np.full((40, width), 40)
    for i in range(40):
        padded[i, : near[i].sum()] = np.flatnonzero(near[i])
    short = energy(sites, box, model, settings, neighbors=jnp.asarray(padded))
    for other in (listed, short):
        assert float(other.lj) == pytest.approx(float(dense.lj), rel=1e-5)
        assert float(other.coulomb) == pytest.approx(float(dense.coulomb), rel=1e-5)


@pytest.mark.gromacs
def test_energies_and_forces_match_gromacs_rerun(tip4p_box, tmp_path):
    """Per term and per atom, three models, float64 and float32, against GROMACS (mixed precision)."""
    from md.water.jaxmd.reference import gromacs_single_point

    atoms, box = tip4p_box
    settings = ff.ReactionField(0.85)

    def gromacs_convention(atoms, model):
        sites = ff.place_m_site(atoms, model)
        terms = ff.energy_terms(sites, jnp.asarray(box, atoms.dtype), model, settings)
        return terms._replace(coulomb=terms.coulomb + ff.intramolecular_rf_energy(sites, model, settings))

    def energy_and_forces(atoms, model):
        terms, pullback = jax.vjp(lambda a: gromacs_convention(a, model), atoms)
        (gradient,) = pullback(ff.EnergyTerms(jnp.ones((), atoms.dtype), jnp.ones((), atoms.dtype)))
        return terms, -gradient

    compiled = jax.jit(energy_and_forces)
    for name in ("tip4p", "tip4p-2005", "tip4p-ew"):
        model = ff.MODELS[name]
        workdir = tmp_path / name
        workdir.mkdir()
        reference = gromacs_single_point(atoms, box, model, settings, workdir)
        assert np.allclose(reference.forces[:, 3], 0.0)  # GROMACS spread M's force onto O, H, H
        scale = np.abs(reference.forces).max()
        for dtype, rel in ((jnp.float64, 1e-5), (jnp.float32, 2e-5)):
            with _enable_x64():
                typed_model = ff.WaterModel(*(jnp.asarray(v, dtype) for v in model))
                terms, forces = compiled(jnp.asarray(atoms, dtype), typed_model)
                terms, forces = jax.tree.map(np.asarray, (terms, forces))
            # GROMACS accumulates in float32: ~1e-6 relative on sums of ~10^5 pair terms.
            assert float(terms.lj) == pytest.approx(reference.lj, rel=rel), (name, dtype)
            assert float(terms.coulomb) == pytest.approx(reference.coulomb, rel=rel), (name, dtype)
            difference = forces - reference.forces[:, :3]
            # 6 printed digits of GROMACS's forces (+-5e-6 relative) and float32 sums.
            assert np.abs(difference).max() < 1e-5 * scale, (name, dtype, np.abs(difference).max())
            assert np.linalg.norm(difference) < 1e-5 * np.linalg.norm(reference.forces), (name, dtype)


# --------------------------------------------------------------------------------------------
# Rigid bodies
# --------------------------------------------------------------------------------------------


def test_rotation_matrix_is_jax_md_quaternion_rotation():
    from jax_md import rigid_body

    q = rigid_body.random_quaternion(jax.random.split(jax.random.PRNGKey(0), 5), jnp.float32)
    v = jax.random.normal(jax.random.PRNGKey(1), (5, 3))
    expected = rigid_body.quaternion_rotate(q, v)
    assert np.allclose(jnp.einsum("nij,nj->ni", rotation_matrix(q.vec), v), expected, atol=1e-5)
    back = quaternion_from_rotation(np.asarray(rotation_matrix(q.vec), np.float64))
    sign = np.sign(np.sum(back * np.asarray(q.vec), axis=1))[:, None]
    assert np.allclose(back * sign, q.vec, atol=1e-5)


def test_body_frame_is_principal_and_centred():
    model = ff.MODELS["tip4p"]
    atoms, _, moments = ff.body_frame(model)
    masses = np.array([ff.OXYGEN_MASS_AMU, ff.HYDROGEN_MASS_AMU, ff.HYDROGEN_MASS_AMU])
    assert np.allclose(masses @ atoms, 0.0, atol=1e-12)
    inertia = sum(m * (p @ p * np.eye(3) - np.outer(p, p)) for m, p in zip(masses, atoms, strict=True))
    assert np.allclose(inertia, np.diag(moments), atol=1e-12)
    # a planar body: I_3 = I_1 + I_2 (perpendicular-axis theorem)
    assert moments[2] == pytest.approx(moments[0] + moments[1], rel=1e-12)


def test_rigid_fit_recovers_a_rigid_configuration():
    model = ff.MODELS["tip4p"]
    atoms, _, _ = ff.body_frame(model)
    rng = np.random.default_rng(0)
    rotations = np.linalg.qr(rng.normal(size=(6, 3, 3)))[0]
    rotations *= np.sign(np.linalg.det(rotations))[:, None, None]
    box = np.array([2.0, 2.0, 2.0])
    centers = rng.uniform(0, 2, (6, 3))
    molecules = centers[:, None] + np.einsum("nij,kj->nki", rotations, atoms)
    fitted_centers, quaternions = rigid_bodies_from_atoms(molecules, box, model)
    assert np.allclose(fitted_centers, np.mod(centers, 2.0), atol=1e-10)
    assert np.allclose(np.asarray(rotation_matrix(jnp.asarray(quaternions))), rotations, atol=1e-5)
    engine = RigidWater(6, box, model, ff.ReactionField(0.6))
    sites = np.asarray(engine.sites(engine.bodies(molecules), model))
    delta = sites[:, :3] - molecules
    delta -= box * np.round(delta / box)
    assert np.abs(delta).max() < 1e-5


# --------------------------------------------------------------------------------------------
# Dynamics
# --------------------------------------------------------------------------------------------


def _nve_energies(dtype, dt_ps: float, duration_ps: float = 0.4):
    """Total and kinetic energy along an NVE run of 64 molecules (lattice start, r_c 0.6 nm)."""
    from md.lj.npt import jax_md_float32
    from md.water.jaxmd.simulator import lattice_configuration

    model = ff.MODELS["tip4p"]
    edge = 1.86824 * (64 / 216) ** (1 / 3)
    engine = RigidWater(64, [edge] * 3, model, ff.ReactionField(0.6), dt_ps=dt_ps, dtype=dtype, neighbor_list=False)
    body = engine.bodies(lattice_configuration(64, edge, model))
    typed_model = ff.WaterModel(*(jnp.asarray(v, dtype) for v in model))
    steps = round(duration_ps / 20 / dt_ps)
    with jax_md_float32():
        frames, status = jax.jit(lambda key: engine.run_nvt(key, typed_model, body, 298.0, 20, steps, ensemble="nve"))(
            jax.random.PRNGKey(0)
        )
    assert int(status) == 0
    total = np.asarray(frames.potential_kj_mol + frames.kinetic_kj_mol, np.float64)
    return total, np.asarray(frames.kinetic_kj_mol, np.float64)


def test_nve_conserves_energy_float32():
    """2 fs steps in float32: total energy fluctuates ~1 % of the kinetic energy's fluctuation.

    The lattice start melts (the kinetic energy more than triples), the hardest part of a run.
    """
    total, kinetic = _nve_energies(jnp.float32, 0.002)
    assert total.std() < 0.03 * kinetic.std(), (total.std(), kinetic.std())
    assert abs(total[-1] - total[0]) < 0.1 * kinetic.std(), (total[-1] - total[0], kinetic.std())


@pytest.mark.slow
def test_nve_energy_error_is_second_order_in_the_time_step():
    """NO_SQUISH is a second-order symplectic splitting: halving dt quarters the energy error."""
    with _enable_x64():
        coarse, _ = _nve_energies(jnp.float64, 0.002)
        fine, _ = _nve_energies(jnp.float64, 0.001)
    ratio = coarse.std() / fine.std()
    assert 3.0 < ratio < 5.5, ratio


# --------------------------------------------------------------------------------------------
# Simulator and summaries
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny_simulator(tip4p_box):
    from md.lj.npt import jax_md_float32
    from md.water.jaxmd.simulator import make_simulator

    with jax_md_float32():
        yield make_simulator("tiny", equilibration_steps=50, frame_interval_steps=25, num_frames=8)


@pytest.mark.slow  # compiles the 216-molecule engine and the analysis (~1 min on 2 shared cores)
def test_jax_summaries_equal_the_host_pipeline(tiny_simulator):
    """S1..S9 in JAX from the frames = md.water.analysis + statistics (float64, numpy) on them."""
    from md.water import analysis, statistics
    from md.water.jaxmd.simulator import summaries_from_frames

    simulator = tiny_simulator
    theta = jnp.array([0.315365, 0.648520])
    frames, status = simulator._frames(jax.random.PRNGKey(3), theta)  # the compiled first half
    assert int(status) == 0
    box = np.asarray(simulator.engine.box_nm)
    ours = np.asarray(summaries_from_frames(frames, box, simulator.preset.frame_interval_ps))
    num_frames = frames.oxygen_nm.shape[0]
    trajectory = analysis.WaterTrajectory(
        time_ps=simulator.preset.frame_interval_ps * np.arange(num_frames),
        oxygen_nm=np.asarray(frames.oxygen_nm),
        hydrogen_nm=np.asarray(frames.hydrogen_nm),
        box_nm=np.tile(box, (num_frames, 1)),
    )
    curves = analysis.compute_curves(trajectory, "robust")
    host = statistics.summary_statistics(curves, "robust")
    assert np.all(np.isfinite(host))
    np.testing.assert_allclose(ours, host, rtol=2e-4, atol=1e-5)


@pytest.mark.slow
def test_simulator_runs_and_reports_failures(tiny_simulator, monkeypatch):
    from jaxabc.errors import SimulationFailure
    from md.water.jaxmd.engine import STATUS_NONFINITE_ENERGY
    from md.water.jaxmd.simulator import STATUS_NO_EXTREMUM, failure_reason

    simulator = tiny_simulator
    key = jax.random.PRNGKey(0)
    summaries = simulator(key, (0.315365, 0.648520))
    assert summaries.shape == (9,) and np.all(np.isfinite(summaries))
    # first g_OO peak of liquid water near 0.28 nm, g -> 1 on average
    assert 0.26 < summaries[7] < 0.29 and 0.9 < summaries[3] < 1.1
    np.testing.assert_allclose(simulator(key, (0.315365, 0.648520)), summaries)  # same key, same run
    # failures are data inside JAX ...
    bad, status = simulator._finish(*simulator._frames(key, jnp.array([jnp.nan, 0.6])))
    assert int(status) & STATUS_NONFINITE_ENERGY and np.all(np.isnan(bad))
    # ... and a SimulationFailure with the reason on the host
    monkeypatch.setattr(simulator, "_finish", lambda f, s: (jnp.full(9, jnp.nan), jnp.asarray(STATUS_NO_EXTREMUM)))
    with pytest.raises(SimulationFailure, match="no first peak"):
        simulator(key, (0.3, 0.6))
    assert failure_reason(0) == "ok"
    with pytest.raises(ValueError, match="2 to 4 finite"):
        simulator(key, (0.3,))


@pytest.mark.slow
def test_batch_equals_single_runs(tiny_simulator):
    simulator = tiny_simulator
    keys = jax.random.split(jax.random.PRNGKey(5), 2)
    thetas = np.array([[0.315365, 0.648520], [0.30, 0.80]])
    summaries, status = simulator.batch(keys, thetas)
    assert summaries.shape == (2, 9) and np.all(status == 0)
    for i in range(2):
        np.testing.assert_allclose(summaries[i], simulator(keys[i], thetas[i]), rtol=1e-3, atol=1e-4)


@pytest.mark.slow
def test_forward_mode_derivatives_match_finite_differences(tip4p_box):
    """d(<U>/N, n_OO)/d(sigma, epsilon) by jax.jacfwd through 80 steps of NVT, against central
    differences with common random numbers (same key: same velocities), float64."""
    from md.lj.npt import jax_md_float32
    from md.water.jaxmd.sensitivity import observable_derivatives, smooth_observables
    from md.water.jaxmd.simulator import make_simulator

    key = jax.random.PRNGKey(0)
    with _enable_x64(), jax_md_float32():
        simulator = make_simulator(
            "tiny", dtype=jnp.float64, equilibration_steps=0, frame_interval_steps=10, num_frames=8
        )
        theta = jnp.array([0.315365, 0.648520])
        _, jacobian = jax.jit(lambda t: observable_derivatives(simulator, key, t))(theta)
        observe = jax.jit(lambda t: smooth_observables(simulator.frames(key, t)[0], simulator.engine.box_nm))
        for i, step in ((0, 1e-5), (1, 1e-4)):
            shift = jnp.zeros(2).at[i].set(step)
            central = (observe(theta + shift) - observe(theta - shift)) / (2 * step)
            # central differences carry O(step^2) error: ~1e-3 relative at these steps
            np.testing.assert_allclose(np.asarray(jacobian[:, i]), np.asarray(central), rtol=3e-3)
            assert np.all(np.abs(np.asarray(central)) > 0.1)  # the derivatives are not trivially zero


@pytest.mark.slow  # two compilations of the engine
def test_engine_neighbor_list_matches_all_pairs():
    """The engine's jax-md neighbour list gives the all-pairs energies along a short NVE run."""
    from md.lj.npt import jax_md_float32
    from md.water.jaxmd.simulator import lattice_configuration

    model = ff.MODELS["tip4p"]
    edge = 1.86824 * (64 / 216) ** (1 / 3)
    settings = ff.ReactionField(0.3)  # small enough for a list in this 1.245 nm box
    typed_model = ff.WaterModel(*(jnp.asarray(v, jnp.float32) for v in model))
    energies = []
    with jax_md_float32():
        for use_list in (False, True):
            engine = RigidWater(64, [edge] * 3, model, settings, neighbor_list=use_list, skin_nm=0.05)
            assert engine.use_neighbor_list is use_list
            body = engine.bodies(lattice_configuration(64, edge, model))
            neighbors = engine.allocate_neighbors(body)
            frames, status = jax.jit(
                lambda key, nbrs, engine=engine, body=body: engine.run_nvt(
                    key, typed_model, body, 298.0, 8, 5, ensemble="nve", neighbor=nbrs
                )
            )(jax.random.PRNGKey(1), neighbors)
            assert int(status) == 0
            energies.append(np.asarray(frames.potential_kj_mol))
    np.testing.assert_allclose(energies[1], energies[0], rtol=1e-4, atol=0.05)


def test_the_batched_host_path_climbs_the_neighbour_list_ladder():
    """64 lattice molecules (r_c 0.3 nm, a box too small for S1..S8: status NO_EXTREMUM), a list
    with no headroom: every run overflows at the first list and none after one reallocation."""
    from md.lj.npt import jax_md_float32
    from md.water.jaxmd.engine import STATUS_NEIGHBOR_OVERFLOW
    from md.water.jaxmd.simulator import STATUS_NO_EXTREMUM, make_simulator

    with jax_md_float32():
        simulator = make_simulator(
            "tiny",
            start="lattice",
            lattice_molecules=64,
            lattice_box_nm=1.86824 * (64 / 216) ** (1 / 3),
            cutoff_nm=0.3,
            neighbor_list=True,
            neighbor_extra_capacity=0,
            neighbor_capacity_multiplier=1.0,
            frame_interval_steps=20,
        )
        keys = jax.random.split(jax.random.PRNGKey(0), 2)
        thetas = jnp.array([[0.315365, 0.648520], [0.31, 0.70]])
        _, first = simulator._batch(keys, thetas, simulator._neighbors(0))
        assert np.all(np.asarray(first) & STATUS_NEIGHBOR_OVERFLOW)
        _, status = simulator.batch(keys, thetas)
    np.testing.assert_array_equal(status, STATUS_NO_EXTREMUM)
    assert simulator.neighbor_reallocations == 2
    assert simulator._neighbors(1).idx.shape[1] > simulator._neighbors(0).idx.shape[1]


@pytest.mark.slow  # three compilations of the 216-molecule engine with a list
def test_an_overflowing_neighbour_list_is_reallocated_and_rerun(tip4p_box):
    """A list sized exactly to the start (no headroom) overflows in the liquid; the host paths
    rerun the run with the next list of the ladder, so the result is that list's run, whatever
    ran before, and a run out of reallocations fails with the reason."""
    from jaxabc.errors import SimulationFailure
    from md.lj.npt import jax_md_float32
    from md.water.jaxmd.engine import STATUS_NEIGHBOR_OVERFLOW
    from md.water.jaxmd.simulator import make_simulator

    tight = {"cutoff_nm": 0.5, "neighbor_list": True, "neighbor_extra_capacity": 0, "neighbor_capacity_multiplier": 1.0}
    key, theta = jax.random.PRNGKey(0), jnp.array([0.315365, 0.648520])
    with jax_md_float32():
        simulator = make_simulator("tiny", **tight)
        _, status = simulator._frames(key, theta, simulator._neighbors(0))
        assert int(status) & STATUS_NEIGHBOR_OVERFLOW
        summaries = simulator(key, theta)
        assert simulator.neighbor_reallocations >= 1 and np.all(np.isfinite(summaries))
        level = simulator.neighbor_reallocations
        expected, expected_status = simulator._finish(*simulator._frames(key, theta, simulator._neighbors(level)))
        assert int(expected_status) == 0
        np.testing.assert_array_equal(summaries, np.asarray(expected, np.float64))
        # the batched host path climbs the same ladder: same numbers for the same key
        batched, batched_status = simulator.batch(key[None], theta[None])
        assert int(batched_status[0]) == 0
        np.testing.assert_allclose(batched[0], summaries, rtol=1e-3, atol=1e-4)
        stuck = make_simulator("tiny", neighbor_reallocations=0, **tight)
        with pytest.raises(SimulationFailure, match="neighbour list overflowed"):
            stuck(key, theta)


@pytest.mark.slow  # compiles a batch of 216-molecule runs
def test_the_simulator_runs_under_jaxabc_on_the_vmap_executor_and_serially(tip4p_box):
    """``jaxabc.run`` takes the in-process water simulator as any other: one compiled batch per
    population through ``simulate_batch`` (vmap executor), or one run at a time (serial), with
    the same draws and the same summaries for a seed."""
    import jaxabc
    from md.lj.npt import jax_md_float32
    from md.water.jaxmd.simulator import make_simulator

    prior = jaxabc.Uniform([0.31, 0.60], [0.32, 0.70])
    with jax_md_float32():
        simulate = make_simulator("tiny", equilibration_steps=0, frame_interval_steps=10, num_frames=8)
        observed = simulate(jax.random.PRNGKey(7), (0.315365, 0.648520))
        runs = [
            jaxabc.run("rejection", simulate, prior, observed, num_particles=2, quantile=0.5, executor=executor)
            for executor in (jaxabc.VmapExecutor(), "serial")
        ]
    vmapped, serial = (r.records for r in runs)
    assert runs[0].num_simulations == runs[1].num_simulations == 4
    assert np.all(vmapped["status"] == 0) and np.all(serial["status"] == 0)
    np.testing.assert_array_equal(vmapped["theta"], serial["theta"])
    np.testing.assert_allclose(vmapped["summaries"], serial["summaries"], rtol=1e-3, atol=1e-4)
