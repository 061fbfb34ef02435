"""Same state point, same interactions: the in-process rigid TIP4P against GROMACS, over seeds.

Both engines start from GROMACS's equilibrated ``tip4p.gro`` (216 molecules, 1.86824 nm, fixed
box, so the density is the same by construction) and run TIP4P in NVT at 298 K (Nose-Hoover,
tau 0.1 ps), 2 fs steps, reaction field with r_c 0.85 nm and epsilon_rf = infinity, LJ
potential-shift: the ``quick`` preset's timing (5 ps equilibration, 15 ps analysed, frames
every 0.2 ps).  jax-md: :func:`md.water.jaxmd.make_simulator` (``quick``), one vmapped batch
of seeds.  GROMACS: ``gmx mdrun`` with SETTLE and leap-frog Nose-Hoover, its trajectory analysed
by the plugin's own reader and statistics (:mod:`md.water.analysis`, ``robust``).

Compared, as mean +- standard error over seeds: potential energy per molecule, the kinetic
temperature (6N - 3 degrees of freedom in both), g_OO first-peak height (S7) and position (S8),
and the self-diffusion coefficient (S9, 1e-5 cm^2/s); the JSON keeps every statistic S1..S9 of
every seed and the difference in units of the combined standard error.  ``--timestep-ps`` runs
both engines at another step with the same times (5 ps, frames every 0.2 ps, 15 ps), which
separates integrator error from a difference in the model.

Run: ``nice -n 15 python -m benchmarks.water_jaxmd_agreement [--seeds 6] [--timestep-ps 0.001
--output water_jaxmd_agreement_1fs] [--quick]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import subprocess
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks import _common
from md.lj.npt import jax_md_float32
from md.units import BOLTZMANN_KJ_MOL_K
from md.water import analysis, statistics
from md.water.gromacs import _gmx_data_dir, find_gmx
from md.water.jaxmd import PRESETS, make_simulator
from md.water.jaxmd.forcefield import MODELS, ReactionField, body_frame, intramolecular_rf_energy, place_m_site
from md.water.jaxmd.reference import rerun_mdp_text
from md.water.topology import topology_text

NAMES = ("U/N kJ/mol", "T K", *(f"S{i}" for i in range(1, 10)))


def run_jax(seeds: int, overrides: dict) -> np.ndarray:
    """Rows (seed) of [U/N, T, S1..S9]."""
    with jax_md_float32():
        simulator = make_simulator("quick", **overrides)
        keys = jax.random.split(jax.random.PRNGKey(2026), seeds)
        theta = jnp.tile(jnp.array([MODELS["tip4p"].sigma_nm, MODELS["tip4p"].epsilon_kj_mol]), (seeds, 1))
        frames, status = jax.jit(jax.vmap(simulator.frames))(keys, theta)
        summaries, status = jax.jit(jax.vmap(simulator.finish))(frames, status)
    if np.any(np.asarray(status)):
        raise RuntimeError(f"jax-md runs failed: status {np.asarray(status)}")
    num_molecules = simulator.engine.num_molecules
    energy = np.asarray(frames.potential_kj_mol, np.float64).mean(axis=1) / num_molecules
    kinetic = np.asarray(frames.kinetic_kj_mol, np.float64).mean(axis=1)
    temperature = 2 * kinetic / (BOLTZMANN_KJ_MOL_K * (6 * num_molecules - 3))
    return np.column_stack([energy + gromacs_constant_per_molecule(), temperature, np.asarray(summaries, np.float64)])


def gromacs_constant_per_molecule() -> float:
    """GROMACS's reaction-field terms of excluded and self pairs, per rigid molecule (kJ/mol).

    Its ``Coulomb (SR)``, hence its ``Potential``, includes them; the engine's energy does not
    (they are constant for rigid molecules), so they are added to jax-md's U/N to compare.
    """
    model = MODELS["tip4p"]
    sites = place_m_site(jnp.asarray(body_frame(model)[0][None]), model)
    return float(intramolecular_rf_energy(sites, model, ReactionField(PRESETS["quick"].cutoff_nm)))


def run_gromacs(seed: int, preset) -> np.ndarray:
    gmx = find_gmx()
    with tempfile.TemporaryDirectory(prefix="jaxabc-agree-") as tmp:
        work = Path(tmp)
        (work / "conf.gro").write_text((_gmx_data_dir(gmx) / "tip4p.gro").read_text())
        (work / "topol.top").write_text(topology_text(216, MODELS["tip4p"].to_gromacs()))
        mdp = rerun_mdp_text(ReactionField(preset.cutoff_nm))
        mdp = re.sub(
            r"^(nsteps|verlet-buffer-tolerance|nstlist|rlist|nstfout|nstcalcenergy|nstenergy)\s*=.*\n",
            "",
            mdp,
            flags=re.M,
        )
        num_steps = preset.equilibration_steps + preset.num_frames * preset.frame_interval_steps
        mdp += (
            f"nsteps = {num_steps}\ndt = {preset.timestep_ps}\nnstcalcenergy = {preset.frame_interval_steps}\n"
            f"nstenergy = {preset.frame_interval_steps}\nnstxout-compressed = {preset.frame_interval_steps}\n"
            f"tcoupl = nose-hoover\nnsttcouple = 1\ntc-grps = System\ntau_t = {preset.tau_t_ps}\n"
            f"ref_t = {preset.temperature_k}\ngen_vel = yes\ngen_temp = {preset.temperature_k}\ngen_seed = {seed}\n"
        )
        (work / "md.mdp").write_text(mdp)
        env = {**os.environ, "OMP_NUM_THREADS": "1", "GMX_MAXBACKUP": "-1"}
        for args, stdin in (
            (["grompp", "-f", "md.mdp", "-c", "conf.gro", "-p", "topol.top", "-o", "md.tpr"], None),
            (["mdrun", "-deffnm", "md", "-ntmpi", "1", "-ntomp", "1", "-pin", "off"], None),
            (["energy", "-f", "md.edr", "-o", "energy.xvg"], "Potential\nTemperature\n\n"),
        ):
            done = subprocess.run([gmx, *args], cwd=work, capture_output=True, text=True, input=stdin, env=env)
            if done.returncode:
                raise RuntimeError(f"gmx {args[0]} failed:\n{done.stdout[-1500:]}{done.stderr[-1500:]}")
        start_ps = preset.equilibration_steps * preset.timestep_ps
        rows = [line.split() for line in (work / "energy.xvg").read_text().splitlines() if line[:1] not in "@#"]
        energy = np.array([[float(v) for v in r[:3]] for r in rows if r])
        # frames after equilibration, as the jax-md frames (first one a frame interval later)
        analysed = energy[energy[:, 0] > start_ps + 1e-6]
        trajectory = analysis.load_trajectory(work / "md.xtc", start_ps=start_ps + preset.frame_interval_ps)
        curves = analysis.compute_curves(trajectory, "robust")
        summaries = statistics.summary_statistics(curves, "robust")
    return np.concatenate([[analysed[:, 1].mean() / 216, analysed[:, 2].mean()], summaries])


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=6)
    parser.add_argument("--quick", action="store_true", help="2 seeds, 1 ps equilibration, 2 ps analysed")
    parser.add_argument("--timestep-ps", type=float, default=PRESETS["quick"].timestep_ps)
    parser.add_argument("--output", default=None)
    args = parser.parse_args()
    overrides = {"equilibration_steps": 500, "num_frames": 10} if args.quick else {}
    base = PRESETS["quick"]
    if args.timestep_ps != base.timestep_ps:
        # The same times at another step: equilibration, frame spacing and window in ps.
        ratio = base.timestep_ps / args.timestep_ps
        if abs(ratio - round(ratio)) > 1e-9:
            raise SystemExit(f"--timestep-ps must divide {base.timestep_ps} ps")
        steps = overrides.get("equilibration_steps", base.equilibration_steps)
        overrides |= {
            "timestep_ps": args.timestep_ps,
            "equilibration_steps": round(steps * ratio),
            "frame_interval_steps": round(base.frame_interval_steps * ratio),
        }
    seeds = 2 if args.quick else args.seeds
    jax_rows = run_jax(seeds, overrides)
    preset = dataclasses.replace(PRESETS["quick"], **overrides)
    gromacs_rows = np.array([run_gromacs(seed + 1, preset) for seed in range(seeds)])
    write(jax_rows, gromacs_rows, args.quick, args.output, args.timestep_ps)


def write(jax_rows: np.ndarray, gromacs_rows: np.ndarray, quick: bool, output: str | None, timestep_ps: float) -> None:
    seeds = jax_rows.shape[0]
    comparison = {}
    for k, name in enumerate(NAMES):
        a, b = jax_rows[:, k], gromacs_rows[:, k]
        se_a, se_b = a.std(ddof=1) / np.sqrt(seeds), b.std(ddof=1) / np.sqrt(seeds)
        combined = float(np.hypot(se_a, se_b))
        comparison[name] = {
            "jax_md_mean": float(a.mean()),
            "jax_md_standard_error": float(se_a),
            "gromacs_mean": float(b.mean()),
            "gromacs_standard_error": float(se_b),
            "difference_in_combined_standard_errors": float((a.mean() - b.mean()) / combined) if combined else None,
        }
        print(f"{name:>12}: jax-md {a.mean():.4g} +- {se_a:.2g}   GROMACS {b.mean():.4g} +- {se_b:.2g}")
    payload = {
        "state_point": "216 TIP4P, 1.86824 nm (tip4p.gro), 298 K NVT Nose-Hoover, reaction field r_c 0.85 nm",
        "timestep_ps": timestep_ps,
        "seeds": seeds,
        "statistic_names": list(NAMES),
        "jax_md_rows": jax_rows,
        "gromacs_rows": gromacs_rows,
        "comparison": comparison,
    }
    path = _common.write_result(output or "water_jaxmd_agreement", payload, quick=quick)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
