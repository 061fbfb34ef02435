"""The jax-md LJ fluid against LAMMPS at identical settings, and LAMMPS against JZG (1993).

Measured here (this is why the comparison is with LAMMPS at the same N, and JZG only at a larger
N): at T* = 1.5, rho* = 0.7, r_c = 2.5 with tail corrections, LAMMPS gives P* = 1.55 for 108 atoms
and 1.60 for 500 atoms (JZG: 1.596); the finite-size shift of a 108-atom box (-0.05, 3 %) is as
large as JZG's quoted accuracy, so the engine's 108-atom preset is checked against LAMMPS's
108-atom run within statistical error, and JZG is checked against a 500-atom LAMMPS run.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

from md import lj_fluid
from md.lammps_reference import lammps_available, run_lj_fluid

pytestmark = [pytest.mark.lammps,
              pytest.mark.skipif(not lammps_available(), reason="lmp not found: apt-get install lammps")]

STATE = dict(temperature=1.5, density=0.7)


def block_mean_error(x: np.ndarray, num_blocks: int = 10) -> tuple[float, float]:
    """Mean and its standard error from block averages (blocks much longer than the correlation time)."""
    x = np.asarray(x, np.float64)
    blocks = x[: len(x) // num_blocks * num_blocks].reshape(num_blocks, -1).mean(axis=1)
    return float(x.mean()), float(blocks.std(ddof=1) / np.sqrt(num_blocks))


@pytest.fixture(scope="module")
def engine_run() -> dict:
    preset = lj_fluid.get_preset("reduced_dense_fluid", temperature_reduced=STATE["temperature"],
                                 density_reduced=STATE["density"], equilibration_steps=1000,
                                 production_steps=20_000, sample_every=20, dt_reduced=0.004, truncation="plain")
    obs = jax.jit(lambda k: lj_fluid.run_details(preset, k, preset.default_theta))(jax.random.PRNGKey(6))
    assert not bool(obs["failed"])
    u_tail, p_tail = lj_fluid.tail_corrections(STATE["density"], preset.cutoff_reduced)
    return {"pressure": np.asarray(obs["pressure"]) + p_tail,
            "potential": np.asarray(obs["potential"]) / preset.num_atoms + u_tail,
            "num_atoms": preset.num_atoms}


def test_engine_matches_lammps_at_the_same_settings(engine_run: dict) -> None:
    ref = run_lj_fluid(**STATE, fcc_cells=3, production_steps=100_000)
    assert ref["num_atoms"] == engine_run["num_atoms"] == 108
    for name in ("pressure", "potential"):
        m_eng, e_eng = block_mean_error(engine_run[name])
        m_ref, e_ref = block_mean_error(ref[name])
        # Two independent estimates of the same number: 4 combined standard errors.
        assert abs(m_eng - m_ref) < 4.0 * np.hypot(e_eng, e_ref), (name, m_eng, e_eng, m_ref, e_ref)
    assert np.mean(ref["temperature"]) == pytest.approx(STATE["temperature"], rel=0.01)


def test_lammps_500_atoms_matches_jzg() -> None:
    """JZG's fit reproduces their simulations to a few percent in P* and about 0.05 in U*/N."""
    ref = run_lj_fluid(**STATE, fcc_cells=5, production_steps=40_000)
    p_jzg, u_jzg = lj_fluid.jzg_equation_of_state(STATE["density"], STATE["temperature"])
    p, p_err = block_mean_error(ref["pressure"])
    u, u_err = block_mean_error(ref["potential"])
    assert abs(p - p_jzg) < 0.03 * abs(p_jzg) + 4 * p_err, (p, p_err, p_jzg)
    assert abs(u - u_jzg) < 0.05 + 4 * u_err, (u, u_err, u_jzg)
