"""RDF and MSD kernels against analytic results (ideal gas, lattices, random walks)."""

from __future__ import annotations

import numpy as np
import pytest

from md.water import analysis


def test_ideal_gas_is_one_under_a_fluctuating_box():
    rng = np.random.default_rng(1)
    num_frames, num_points = 40, 300
    # Box edges 1.8-2.4 nm: volumes differ by 2.4x, so <1/V><V> = 1.06; a normalisation with
    # the mean volume instead of each frame's would be 6 % off, far outside the tolerance.
    edges = rng.uniform(1.8, 2.4, num_frames)
    box = np.repeat(edges[:, None], 3, axis=1)
    positions = rng.uniform(0, 1, (num_frames, num_points, 3)) * box[:, None, :]
    ids = np.arange(num_points)
    r, g = analysis.radial_distribution(positions, positions, box, ids, ids, r_max_nm=0.9)
    assert r.shape == g.shape == (450,)
    tail = r > 0.3
    assert np.mean(g[tail]) == pytest.approx(1.0, abs=0.006)
    for block in np.array_split(g[tail], 6):  # no trend with r
        assert np.mean(block) == pytest.approx(1.0, abs=0.02)
    # gmx rdf's normalisation (N*M instead of N*(N-1)) is lower by (N-1)/N
    _, g_gmx = analysis.radial_distribution(positions, positions, box, ids, ids, r_max_nm=0.9, normalise_excluded=False)
    np.testing.assert_allclose(g_gmx, g * (num_points - 1) / num_points, rtol=1e-6)


def _cubic_lattice(spacing: float, cells: int) -> np.ndarray:
    grid = np.arange(cells) * spacing
    return np.stack(np.meshgrid(grid, grid, grid, indexing="ij"), -1).reshape(-1, 3)


def test_simple_cubic_lattice_coordination_numbers():
    # two frames with different lattice constants (a box that breathes): the counts of
    # neighbours in each shell are exact integers whatever the box.
    frames = [_cubic_lattice(0.30, 6), _cubic_lattice(0.33, 6)]
    positions = np.stack(frames) + 0.01
    box = np.array([[1.80] * 3, [1.98] * 3])
    ids = np.arange(positions.shape[1])
    r, g = analysis.radial_distribution(positions, positions, box, ids, ids, r_max_nm=0.9, bin_width_nm=0.001)
    edges = 0.001 * np.arange(r.size + 1)
    shell = 4 / 3 * np.pi * np.diff(edges**3)
    density = np.mean((ids.size - 1) / np.prod(box, axis=1))  # the estimator's mean density
    cumulative = np.cumsum(g * shell * density)
    for radius, neighbours in [(0.35, 6), (0.48, 18), (0.58, 26), (0.62, 26 + 6 / 2)]:
        # at 0.62 nm: a=0.30 has its 4th shell (6 at 0.60) inside, a=0.33 (at 0.66) not
        assert cumulative[int(radius / 0.001)] == pytest.approx(neighbours, abs=1e-4)
    assert np.all(g[r < 0.299] == 0)


def _water_like_molecules(num_frames: int = 3):
    """Oxygens on a cubic lattice, each with two H at 0.09572 nm (HOH angle 104.52 deg)."""
    rng = np.random.default_rng(2)
    oxygens = _cubic_lattice(0.31, 6)
    half_angle = np.deg2rad(104.52 / 2)
    o_frames, h_frames = [], []
    for _ in range(num_frames):
        hydrogens = []
        for _o in oxygens:
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            other = np.cross(axis, rng.normal(size=3))
            other /= np.linalg.norm(other)
            for sign in (1, -1):
                hydrogens.append(0.09572 * (np.cos(half_angle) * axis + sign * np.sin(half_angle) * other))
        o_frames.append(oxygens)
        h_frames.append(np.repeat(oxygens, 2, axis=0) + np.array(hydrogens))
    box = np.full((num_frames, 3), 6 * 0.31)
    return analysis.WaterTrajectory(np.arange(num_frames, dtype=float), np.stack(o_frames), np.stack(h_frames), box)


def test_goh_excludes_the_molecules_own_hydrogens():
    trajectory = _water_like_molecules()
    r, g_inter = analysis.rdf_oh(trajectory, r_max_nm=0.9, intermolecular=True)
    _, g_all = analysis.rdf_oh(trajectory, r_max_nm=0.9, intermolecular=False, normalise_excluded=False)
    bond = np.argmin(np.abs(r - 0.09572))
    assert g_inter[bond] == 0 and g_all[bond] > 100
    assert np.all(g_inter[r < 0.2] == 0)  # the nearest foreign H is 0.31 - 0.0957 nm away
    # with the bond included, each O has exactly 2 hydrogens within 0.1 nm
    edges = 0.002 * np.arange(r.size + 1)
    shell = 4 / 3 * np.pi * np.diff(edges**3)
    density = np.mean(trajectory.hydrogen_nm.shape[1] / np.prod(trajectory.box_nm, axis=1))
    assert np.sum((g_all * shell * density)[r < 0.1]) == pytest.approx(2.0, abs=1e-6)


def test_rmax_beyond_half_box_is_refused():
    trajectory = _water_like_molecules(1)
    with pytest.raises(ValueError, match="half the smallest box edge"):
        analysis.rdf_oo(trajectory, r_max_nm=1.0)


def test_unwrap_recovers_a_random_walk():
    rng = np.random.default_rng(3)
    steps = 0.05 * rng.standard_normal((300, 40, 3))
    true = np.cumsum(steps, axis=0) + 1.0
    box = np.full((300, 3), 2.0)
    wrapped = np.mod(true, box[:, None, :])
    unwrapped = np.asarray(analysis.unwrap(wrapped, box))
    np.testing.assert_allclose(unwrapped - unwrapped[0], true - true[0], atol=2e-5)


def _walk_trajectory(steps: np.ndarray, frame_ps: float) -> analysis.WaterTrajectory:
    num_frames = steps.shape[0]
    positions = np.mod(np.cumsum(steps, axis=0), 3.0)
    return analysis.WaterTrajectory(
        frame_ps * np.arange(num_frames), positions, np.repeat(positions, 2, axis=1), np.full((num_frames, 3), 3.0)
    )


def test_msd_of_a_random_walk_gives_its_diffusion_coefficient():
    rng = np.random.default_rng(4)
    sigma, frame_ps = 0.03, 0.2
    steps = sigma * rng.standard_normal((400, 300, 3))
    lag, msd = analysis.mean_squared_displacement(_walk_trajectory(steps, frame_ps), remove_drift=False)
    assert lag[1] == pytest.approx(frame_ps, rel=1e-6)
    expected_slope = 3 * sigma**2 / frame_ps  # = 6 D
    assert analysis.fit_msd_slope(lag, msd) == pytest.approx(expected_slope, rel=0.05)


def test_msd_of_ballistic_motion_is_exact():
    velocity = np.random.default_rng(5).normal(size=(1, 50, 3)) * 0.01
    steps = np.repeat(velocity, 30, axis=0)
    lag, msd = analysis.mean_squared_displacement(
        _walk_trajectory(steps, 1.0), origin_interval_ps=3.0, remove_drift=False
    )
    speed2 = np.mean(np.sum(velocity[0] ** 2, axis=-1))
    np.testing.assert_allclose(msd, speed2 * lag**2, rtol=1e-4, atol=1e-9)


def test_fit_window_must_hold_points():
    with pytest.raises(ValueError, match="fewer than two"):
        analysis.fit_msd_slope(np.arange(5.0), np.arange(5.0), window_ps=(10.0, 20.0))
