"""Density and potential energy of rigid TIP4P at 298 K and 1 bar: jax-md NPT against GROMACS NPT.

Same state point and interactions in both engines: 216 TIP4P molecules from GROMACS's
``tip4p.gro``, 298 K (Nose-Hoover, tau_t 0.1 ps), 1 bar, 2 fs steps, reaction field with
r_c 0.85 nm and epsilon_rf = infinity, LJ potential-shift, no dispersion correction (the
``quick`` preset of :mod:`md.water.jaxmd`).  The engines differ in how they hold the pressure:

- jax-md: :class:`md.water.jaxmd.npt.MonteCarloBarostat` (a volume move on the molecular
  centres every 25 steps, proposal width adapted during equilibration, frozen in production);
  all seeds in one ``vmap``;
- GROMACS: ``gmx mdrun`` with SETTLE and the C-rescale barostat (Bernetti & Bussi, J. Chem. Phys. 153, 114107 (2020):
  stochastic cell rescaling, which samples the isothermal-isobaric ensemble; tau_p 1 ps,
  compressibility 4.5e-5 bar^-1), the same ``.mdp`` interaction lines as the engine's
  single-point check (:func:`md.water.jaxmd.reference.rerun_mdp_text`).

Both equilibrate for the same time from the same box, then average density (kg/m^3) and
potential energy per molecule (kJ/mol; jax-md's plus GROMACS's constant intramolecular
reaction-field terms, which its ``Potential`` includes) over production.  Compared as mean +-
standard error over seeds, and the difference in units of the combined standard error; the JSON
also keeps each seed's means, an autocorrelation-corrected standard error of each seed's density
series (arviz ESS), jax-md's acceptance rates and proposal widths, and the CPU seconds of each
engine.

Run: ``nice -n 15 python -m benchmarks.water_jaxmd_density [--seeds 4] [--quick]``.  The full
run (4 seeds, 10 ps equilibration, 30 ps production each) is mostly jax-md's time (its cost is
recorded in the JSON); ``--quick`` (2 seeds, 1 + 1 ps) writes to ``results/quick/``.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import tempfile
import time
from pathlib import Path

import arviz
import jax
import jax.numpy as jnp
import numpy as np

from benchmarks import _common
from md.lj.npt import jax_md_float32
from md.water.gromacs import _gmx_data_dir, find_gmx
from md.water.jaxmd.engine import RigidWater
from md.water.jaxmd.forcefield import MODELS, ReactionField, body_frame, intramolecular_rf_energy, place_m_site
from md.water.jaxmd.npt import MonteCarloBarostat
from md.water.jaxmd.reference import read_gro, rerun_mdp_text
from md.water.topology import topology_text

TEMPERATURE_K = 298.0
PRESSURE_BAR = 1.0
TIMESTEP_PS = 0.002
TAU_T_PS = 0.1
TAU_P_PS = 1.0
COMPRESSIBILITY_PER_BAR = 4.5e-5
CUTOFF_NM = 0.85
MOVE_INTERVAL_STEPS = 25
NUM_MOLECULES = 216
NAMES = ("density kg/m3", "U/N kJ/mol")


def constant_rf_energy_per_molecule(settings: ReactionField) -> float:
    """GROMACS's reaction-field terms of excluded and self pairs, per rigid molecule (kJ/mol)."""
    model = MODELS["tip4p"]
    sites = place_m_site(jnp.asarray(body_frame(model)[0][None]), model)
    return float(intramolecular_rf_energy(sites, model, settings))


def _series_standard_error(series: np.ndarray) -> float:
    """Standard error of a series' mean, corrected for autocorrelation by arviz's ESS."""
    ess = float(arviz.ess(np.asarray(series, np.float64)[None]))
    return float(np.std(series, ddof=1) / np.sqrt(max(ess, 1.0)))


def run_jax(seeds: int, equilibration_steps: int, production_steps: int, start: Path) -> dict:
    """jax-md NPT for ``seeds`` keys in one vmapped batch: per-seed means and diagnostics."""
    atoms, box = read_gro(start)
    model = MODELS["tip4p"]
    settings = ReactionField(CUTOFF_NM)
    with jax_md_float32():
        engine = RigidWater(NUM_MOLECULES, box, model, settings, dt_ps=TIMESTEP_PS, neighbor_list=False)
        barostat = MonteCarloBarostat(
            engine, PRESSURE_BAR, TEMPERATURE_K, interval_steps=MOVE_INTERVAL_STEPS, tau_t_ps=TAU_T_PS
        )
        body = engine.bodies(atoms, box)
        keys = jax.random.split(jax.random.PRNGKey(2026), seeds)
        run = jax.jit(
            jax.vmap(
                lambda key: barostat.run(
                    key,
                    model,
                    body,
                    equilibration_steps // MOVE_INTERVAL_STEPS,
                    production_steps // MOVE_INTERVAL_STEPS,
                )
            )
        )
        cpu = time.process_time()
        result = jax.block_until_ready(run(keys))
        cpu = time.process_time() - cpu
    status = np.asarray(result.status)
    if np.any(status):
        raise RuntimeError(f"jax-md NPT runs failed: status {status}")
    density = np.asarray(result.density_kg_m3, np.float64)
    energy = np.asarray(result.potential_kj_mol_per_molecule, np.float64) + constant_rf_energy_per_molecule(settings)
    return {
        "rows": np.column_stack([density.mean(axis=1), energy.mean(axis=1)]),
        "density_series_standard_error": [_series_standard_error(d) for d in density],
        "acceptance_rate": np.asarray(result.acceptance_rate, np.float64),
        "log_volume_step": np.asarray(result.log_volume_step, np.float64),
        "cpu_seconds_including_compilation": cpu,
        "samples_per_seed": density.shape[1],
    }


def _mdp(equilibration_steps: int, production_steps: int, seed: int, interval: int) -> str:
    mdp = rerun_mdp_text(ReactionField(CUTOFF_NM))
    # A dynamic run: GROMACS sets the list buffer and output itself (the single point had none).
    mdp = re.sub(
        r"^(nsteps|verlet-buffer-tolerance|nstlist|rlist|nstfout|nstcalcenergy|nstenergy)\s*=.*\n", "", mdp, flags=re.M
    )
    return mdp + (
        f"nsteps = {equilibration_steps + production_steps}\ndt = {TIMESTEP_PS}\n"
        f"nstcalcenergy = {interval}\nnstenergy = {interval}\n"
        f"tcoupl = nose-hoover\nnsttcouple = 1\ntc-grps = System\ntau_t = {TAU_T_PS}\nref_t = {TEMPERATURE_K}\n"
        f"pcoupl = C-rescale\npcoupltype = isotropic\ntau_p = {TAU_P_PS}\nref_p = {PRESSURE_BAR}\n"
        f"compressibility = {COMPRESSIBILITY_PER_BAR}\n"
        f"gen_vel = yes\ngen_temp = {TEMPERATURE_K}\ngen_seed = {seed}\nld_seed = {seed}\n"
    )


def run_gromacs(seed: int, equilibration_steps: int, production_steps: int, start: Path) -> tuple[np.ndarray, dict]:
    """One GROMACS NPT run: [density, U/N] means over production, and its diagnostics."""
    gmx = find_gmx()
    # Energies every 25 steps (0.05 ps), as jax-md's volume moves.
    interval = MOVE_INTERVAL_STEPS
    with tempfile.TemporaryDirectory(prefix="jaxabc-density-") as tmp:
        work = Path(tmp)
        (work / "conf.gro").write_text(start.read_text())
        (work / "topol.top").write_text(topology_text(NUM_MOLECULES, MODELS["tip4p"].to_gromacs()))
        (work / "md.mdp").write_text(_mdp(equilibration_steps, production_steps, seed, interval))
        env = {**os.environ, "OMP_NUM_THREADS": "1", "GMX_MAXBACKUP": "-1"}
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        for args, stdin in (
            (["grompp", "-f", "md.mdp", "-c", "conf.gro", "-p", "topol.top", "-o", "md.tpr"], None),
            (["mdrun", "-deffnm", "md", "-ntmpi", "1", "-ntomp", "1", "-pin", "off"], None),
            (["energy", "-f", "md.edr", "-o", "energy.xvg"], "Potential\nDensity\n\n"),
        ):
            done = subprocess.run([gmx, *args], cwd=work, capture_output=True, text=True, input=stdin, env=env)
            if done.returncode:
                raise RuntimeError(f"gmx {args[0]} failed:\n{done.stdout[-1500:]}{done.stderr[-1500:]}")
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        lines = (work / "energy.xvg").read_text().splitlines()
    legends = [re.findall(r'legend "(.*)"', line)[0] for line in lines if re.match(r"@ s\d+ legend", line)]
    values = np.array([[float(v) for v in line.split()] for line in lines if line and line[0] not in "@#"])
    columns = {name: values[:, 1 + k] for k, name in enumerate(legends)}
    production = values[:, 0] > equilibration_steps * TIMESTEP_PS + 1e-6
    density, energy = columns["Density"][production], columns["Potential"][production] / NUM_MOLECULES
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    diagnostics = {"density_series_standard_error": _series_standard_error(density), "cpu_seconds": cpu}
    return np.array([density.mean(), energy.mean()]), diagnostics


def compare(jax_rows: np.ndarray, gromacs_rows: np.ndarray) -> dict:
    """Mean +- standard error over seeds per quantity, and the difference in combined SE."""
    comparison = {}
    for k, name in enumerate(NAMES):
        a, b = jax_rows[:, k], gromacs_rows[:, k]
        se_a, se_b = a.std(ddof=1) / np.sqrt(len(a)), b.std(ddof=1) / np.sqrt(len(b))
        combined = float(np.hypot(se_a, se_b))
        comparison[name] = {
            "jax_md_mean": float(a.mean()),
            "jax_md_standard_error": float(se_a),
            "gromacs_mean": float(b.mean()),
            "gromacs_standard_error": float(se_b),
            "difference_in_combined_standard_errors": float((a.mean() - b.mean()) / combined) if combined else None,
        }
        print(f"{name:>14}: jax-md {a.mean():.5g} +- {se_a:.2g}   GROMACS {b.mean():.5g} +- {se_b:.2g}")
    return comparison


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--equilibration-ps", type=float, default=10.0)
    parser.add_argument("--production-ps", type=float, default=30.0)
    parser.add_argument("--quick", action="store_true", help="2 seeds, 1 ps equilibration, 1 ps production")
    parser.add_argument("--output", default=None)
    args = parser.parse_args()
    seeds = 2 if args.quick else args.seeds
    if seeds < 2:
        parser.error("--seeds must be at least 2 (standard errors come from the spread over seeds)")
    equilibration_ps, production_ps = (1.0, 1.0) if args.quick else (args.equilibration_ps, args.production_ps)
    # Whole volume-move intervals, so both engines run the same number of steps.
    equilibration_steps = round(equilibration_ps / TIMESTEP_PS / MOVE_INTERVAL_STEPS) * MOVE_INTERVAL_STEPS
    production_steps = round(production_ps / TIMESTEP_PS / MOVE_INTERVAL_STEPS) * MOVE_INTERVAL_STEPS
    if production_steps < MOVE_INTERVAL_STEPS:
        parser.error(f"--production-ps must cover at least one volume move ({MOVE_INTERVAL_STEPS * TIMESTEP_PS} ps)")
    start = _gmx_data_dir(find_gmx()) / "tip4p.gro"
    _common.declare_input(start)

    jax_result = run_jax(seeds, equilibration_steps, production_steps, start)
    gromacs = [run_gromacs(seed + 1, equilibration_steps, production_steps, start) for seed in range(seeds)]
    gromacs_rows = np.array([row for row, _ in gromacs])
    comparison = compare(jax_result["rows"], gromacs_rows)
    payload = {
        "state_point": (
            f"{NUM_MOLECULES} TIP4P from tip4p.gro, {TEMPERATURE_K} K Nose-Hoover (tau_t {TAU_T_PS} ps), "
            f"{PRESSURE_BAR} bar, dt {TIMESTEP_PS} ps, reaction field r_c {CUTOFF_NM} nm epsilon_rf inf, "
            "LJ potential-shift, no dispersion correction"
        ),
        "barostats": {
            "jax_md": f"Monte Carlo, ln V moves every {MOVE_INTERVAL_STEPS} steps on molecular centres",
            "gromacs": f"C-rescale, tau_p {TAU_P_PS} ps, compressibility {COMPRESSIBILITY_PER_BAR} /bar",
        },
        "seeds": seeds,
        "equilibration_steps": equilibration_steps,
        "production_steps": production_steps,
        "statistic_names": list(NAMES),
        "jax_md_rows": jax_result["rows"],
        "gromacs_rows": gromacs_rows,
        "comparison": comparison,
        "jax_md": {k: v for k, v in jax_result.items() if k != "rows"},
        "gromacs": {
            "density_series_standard_error": [d["density_series_standard_error"] for _, d in gromacs],
            "cpu_seconds": [d["cpu_seconds"] for _, d in gromacs],
        },
        "jax_device": jax.devices()[0].platform,
    }
    path = _common.write_result(args.output or "water_jaxmd_density", payload, quick=args.quick)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
