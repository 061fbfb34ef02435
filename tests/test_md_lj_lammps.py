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
from md.lammps_reference import run_lj_fluid

pytestmark = pytest.mark.lammps

STATE = dict(temperature=1.5, density=0.7)


def block_mean_error(x: np.ndarray, num_blocks: int = 10) -> tuple[float, float]:
    """Mean and its standard error from block averages (blocks much longer than the correlation time)."""
    x = np.asarray(x, np.float64)
    blocks = x[: len(x) // num_blocks * num_blocks].reshape(num_blocks, -1).mean(axis=1)
    return float(x.mean()), float(blocks.std(ddof=1) / np.sqrt(num_blocks))


def engine_run(name: str, dt: float) -> tuple[dict, dict]:
    """The engine's preset in reduced units (P*, U*/N with tail corrections) and its state point."""
    base = lj_fluid.get_preset(name)
    state = {"temperature": base.temperature_reduced, "density": base.density_reduced}
    if name == "reduced_dense_fluid":
        state = dict(STATE)
    preset = lj_fluid.get_preset(
        name,
        temperature_reduced=state["temperature"],
        density_reduced=state["density"],
        equilibration_steps=1000,
        production_steps=20_000,
        sample_every=20,
        dt_reduced=dt,
        truncation="plain",
    )
    obs = jax.jit(lambda k: lj_fluid.run_details(preset, k, preset.default_theta))(jax.random.PRNGKey(6))
    assert not bool(obs["failed"])
    u = preset.units  # physical units (argon) -> reduced: P* = P sigma^3 / epsilon, U* = U / epsilon
    u_tail, p_tail = lj_fluid.tail_corrections(state["density"], preset.cutoff_reduced)
    out = {
        "pressure": np.asarray(obs["pressure"]) * u.sigma_nm**3 / u.epsilon_kj_mol + p_tail,
        "potential": np.asarray(obs["potential"]) / preset.num_atoms / u.epsilon_kj_mol + u_tail,
        "num_atoms": preset.num_atoms,
    }
    return out, state


@pytest.mark.parametrize("name, dt", [("reduced_dense_fluid", 0.004), ("argon_liquid", 0.005)])
def test_engine_matches_lammps_at_the_same_settings(name: str, dt: float) -> None:
    """The supercritical check state, and liquid argon in physical units (tests the unit conversions)."""
    eng, state = engine_run(name, dt)
    ref = run_lj_fluid(**state, fcc_cells=3, dt=dt, production_steps=100_000)
    assert ref["num_atoms"] == eng["num_atoms"] == 108
    for key in ("pressure", "potential"):
        m_eng, e_eng = block_mean_error(eng[key])
        m_ref, e_ref = block_mean_error(ref[key])
        # Two independent estimates of the same number: 4 combined standard errors.
        assert abs(m_eng - m_ref) < 4.0 * np.hypot(e_eng, e_ref), (key, m_eng, e_eng, m_ref, e_ref)
    assert np.mean(ref["temperature"]) == pytest.approx(state["temperature"], rel=0.01)


def test_lammps_500_atoms_matches_jzg() -> None:
    """JZG's fit reproduces their simulations to a few percent in P* and about 0.05 in U*/N."""
    ref = run_lj_fluid(**STATE, fcc_cells=5, production_steps=40_000)
    p_jzg, u_jzg = lj_fluid.jzg_equation_of_state(STATE["density"], STATE["temperature"])
    p, p_err = block_mean_error(ref["pressure"])
    u, u_err = block_mean_error(ref["potential"])
    assert abs(p - p_jzg) < 0.03 * abs(p_jzg) + 4 * p_err, (p, p_err, p_jzg)
    assert abs(u - u_jzg) < 0.05 + 4 * u_err, (u, u_err, u_jzg)
