"""Run the same helium system in LAMMPS (Debian ``lmp``) as an independent reference.

The input mirrors the published pipeline: ``units nano`` (nm, ns, attogram, zJ, K; pressure in
ag/(nm ns^2) = 1e6 Pa), ``pair_style lj/cut 0.639`` (plain truncation, no shift, no tail
correction), ``fix npt ... iso`` (Nose-Hoover chains of length 3 on particles and box, the
MTK barostat whose form jax-md implements), ``thermo`` keyword ``enthalpy``, and
f_B = exp(-H / (N k_B T)) with LAMMPS's own T (3N - 3 degrees of freedom).  The start is the
same jittered simple-cubic lattice as :func:`md.lj.lattice_positions`, written as a data file;
velocities come from LAMMPS's generator with a seed derived from the JAX key
(:func:`jaxabc.seeding.seed_from_key`), so runs are reproducible.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import numpy as np

from md.helium import HeliumPreset, get_preset
from md.lj import lattice_positions
from md.units import AMU_IN_KG, ATM_IN_KJ_MOL_NM3

__all__ = ["BOLTZMANN_ZJ_K", "LammpsRun", "lammps_available", "run_helium", "run_lj_fluid"]

#: k_B in LAMMPS ``units nano`` (zJ/K).
BOLTZMANN_ZJ_K = 0.01380649
#: One atm in ``units nano`` pressure units (ag / (nm ns^2) = 1e6 Pa).
ATM_IN_NANO = 101325.0 / 1e6


@dataclass
class LammpsRun:
    """Thermo series of one LAMMPS helium run, sampled every ``sample_every_ps``.

    Attributes
    ----------
    f_b : np.ndarray, shape (S,)
        exp(-H / (N k_B T)) per sample.
    temperature_k, pressure_atm, volume_nm3, enthalpy_zj, potential_zj : np.ndarray, (S,)
    wall_seconds : float
        LAMMPS wall time of the whole run (equilibration + production), start-up included.
    loop_seconds : float
        LAMMPS's own "Loop time" summed over its ``run`` commands: the MD steps alone.
    steps : int
        Total MD steps.
    loop_cpu_seconds : float
        The loop times times LAMMPS's reported "% CPU use": the CPU seconds of the MD steps,
        which, unlike the loop time, do not grow when other work shares the core.
    """

    f_b: np.ndarray
    temperature_k: np.ndarray
    pressure_atm: np.ndarray
    volume_nm3: np.ndarray
    enthalpy_zj: np.ndarray
    potential_zj: np.ndarray
    wall_seconds: float
    steps: int
    loop_seconds: float = float("nan")
    loop_cpu_seconds: float = float("nan")


def _loop_seconds(log: str) -> tuple[float, float]:
    """Summed "Loop time" and its CPU share ("NN% CPU use") over the runs of a LAMMPS log."""
    loops = [float(m) for m in re.findall(r"^Loop time of ([0-9.eE+-]+)", log, re.M)]
    shares = [float(m) / 100.0 for m in re.findall(r"([0-9.]+)% CPU use", log)]
    cpu = sum(t * f for t, f in zip(loops, shares, strict=False)) if len(shares) == len(loops) else float("nan")
    return sum(loops), cpu


def lammps_available(executable: str = "lmp") -> bool:
    """True when the LAMMPS executable is on PATH."""
    return shutil.which(executable) is not None


def _data_file(path: Path, preset: HeliumPreset, rng: np.random.Generator) -> None:
    n = preset.num_atoms
    side = preset.initial_box_nm
    spacing = 1.0 / np.ceil(n ** (1.0 / 3.0) - 1e-9)
    frac = lattice_positions(n) + 0.05 * spacing * rng.uniform(-1, 1, size=(n, 3))
    pos = np.mod(frac, 1.0) * side
    lines = [
        "helium start (jaxabc md.lammps_reference)",
        "",
        f"{n} atoms",
        "1 atom types",
        "",
        f"0 {side:.10f} xlo xhi",
        f"0 {side:.10f} ylo yhi",
        f"0 {side:.10f} zlo zhi",
        "",
        "Masses",
        "",
        f"1 {preset_mass_attogram():.10e}",
        "",
        "Atoms # atomic",
        "",
    ]
    lines += [f"{i + 1} 1 {x:.8f} {y:.8f} {z:.8f}" for i, (x, y, z) in enumerate(pos)]
    path.write_text("\n".join(lines) + "\n")


def preset_mass_attogram() -> float:
    """Helium mass 4.0026 amu in attograms (1 ag = 1e-21 kg)."""
    from md.units import HELIUM_MASS_AMU

    return HELIUM_MASS_AMU * AMU_IN_KG / 1e-21


def run_helium(
    key: jax.Array,
    theta: tuple[float, float],
    preset: str | HeliumPreset = "cpu",
    num_samples: int | None = None,
    executable: str = "lmp",
    timeout_s: float = 600.0,
    **overrides,
) -> LammpsRun:
    """Run the helium preset in LAMMPS and return its thermo series.

    Parameters
    ----------
    key : PRNG key
        Seeds (lattice jitter and velocities) derive from it.
    theta : (sigma_nm, epsilon_zJ)
    preset : str or HeliumPreset
    num_samples : int, optional
        Samples after equilibration; default ``preset.num_samples``.
    executable : str
    timeout_s : float
    **overrides
        Fields of :class:`md.helium.HeliumPreset`.

    Returns
    -------
    LammpsRun
        Raises ``jaxabc.errors.SimulationFailure`` if LAMMPS fails or times out.
    """
    from jaxabc.errors import SimulationFailure
    from jaxabc.seeding import seeds_from_key

    p = get_preset(preset, **overrides)
    n_samples = p.num_samples if num_samples is None else int(num_samples)
    seed_pos, seed_vel = seeds_from_key(key, 2, high=900_000_000)
    sigma, epsilon = float(theta[0]), float(theta[1])
    every = round(p.sample_every_ps / p.dt_ps)
    equil = round(p.equilibration_ps / p.dt_ps)
    prod = every * n_samples
    pressure_nano = p.pressure_atm * ATM_IN_NANO
    # Consistency of the two unit systems (kJ/mol/nm^3 <-> 1e6 Pa) is checked in tests.
    assert abs(ATM_IN_KJ_MOL_NM3 - 0.0610193) < 1e-6
    script = f"""
units nano
atom_style atomic
boundary p p p
read_data start.data
pair_style lj/cut {p.cutoff_nm}
pair_coeff 1 1 {epsilon:.10g} {sigma:.10g}
pair_modify shift no tail no
neighbor {p.skin_nm} bin
neigh_modify every 1 delay 0 check yes
velocity all create {p.temperature_k} {seed_vel} dist gaussian mom yes rot no
fix integrate all npt temp {p.temperature_k} {p.temperature_k} {p.tau_t_ps * 1e-3} &
    iso {pressure_nano} {pressure_nano} {p.tau_p_ps * 1e-3} tchain 3 pchain 3 tloop 1 ploop 1
timestep {p.dt_ps * 1e-3}
thermo_style custom step temp press vol pe enthalpy
thermo_modify norm no format float %.10g
thermo {every}
run {equil}
run {prod}
"""
    with tempfile.TemporaryDirectory(prefix="jaxabc_lammps_") as tmp:
        tmp_path = Path(tmp)
        _data_file(tmp_path / "start.data", p, np.random.default_rng(seed_pos))
        (tmp_path / "in.helium").write_text(script)
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(
                [executable, "-in", "in.helium", "-log", "log.lammps", "-screen", "none", "-nocite"],
                cwd=tmp,
                capture_output=True,
                text=True,
                timeout=timeout_s,
            )
        except subprocess.TimeoutExpired as exc:
            raise SimulationFailure(f"LAMMPS timed out after {timeout_s} s") from exc
        wall = time.perf_counter() - t0
        log = (tmp_path / "log.lammps").read_text() if (tmp_path / "log.lammps").exists() else ""
        if proc.returncode != 0:
            tail = (log or proc.stdout + proc.stderr)[-800:]
            raise SimulationFailure(f"LAMMPS exited with {proc.returncode}: {tail}")
    rows = _thermo_blocks(log)
    if len(rows) < 2:
        raise SimulationFailure("LAMMPS log holds fewer than two thermo blocks")
    prod_rows = np.asarray(rows[-1], float)[1:]  # drop the repeated first line of the run
    temp, press, vol, pe, enthalpy = (prod_rows[:, i] for i in range(1, 6))
    f_b = np.exp(-enthalpy / (p.num_atoms * BOLTZMANN_ZJ_K * temp))
    return LammpsRun(
        f_b=f_b,
        temperature_k=temp,
        pressure_atm=press / ATM_IN_NANO,
        volume_nm3=vol,
        enthalpy_zj=enthalpy,
        potential_zj=pe,
        wall_seconds=wall,
        steps=equil + prod,
        loop_seconds=_loop_seconds(log)[0],
        loop_cpu_seconds=_loop_seconds(log)[1],
    )


def _thermo_blocks(log: str) -> list[list[list[float]]]:
    """Numeric thermo tables of a LAMMPS log, one list of rows per ``run``."""
    blocks: list[list[list[float]]] = []
    current: list[list[float]] | None = None
    number = re.compile(r"^\s*-?\d")
    for line in log.splitlines():
        if line.strip().startswith("Step"):
            current = []
            blocks.append(current)
            continue
        if current is not None:
            if number.match(line):
                try:
                    current.append([float(v) for v in line.split()])
                    continue
                except ValueError:
                    pass
            if line.startswith("Loop time"):
                current = None
    return blocks


def compare_with_jax_md(
    key: jax.Array,
    theta: tuple[float, float],
    preset: str | HeliumPreset = "cpu",
    num_seeds: int = 8,
    **overrides,
) -> dict:
    """Run ``num_seeds`` independent helium runs in each engine and compare them.

    For the mean temperature, pressure, volume and f_B, the difference of the two engines'
    means is divided by its standard error (from the run-to-run spread: independent runs are
    independent samples, so no autocorrelation analysis is needed).  The KL divergence between
    a jax-md and a LAMMPS series is compared with the jax-md seed-to-seed KL.

    Returns
    -------
    dict
        ``{"quantities": {name: {"jax_md", "lammps", "difference", "standard_error", "z"}},
        "kl_cross": [...], "kl_jax_md_seed_to_seed": [...], "seconds": {...}}``.
    """
    import jax.numpy as jnp

    from jaxabc.distances import kl_divergence
    from md import helium

    p = get_preset(preset, **overrides)
    k_jax, k_lmp = jax.random.split(key)
    keys = jax.random.split(k_jax, num_seeds)
    engine = helium.make_engine(p)
    params = helium._params(jnp.asarray(theta, jnp.float32))
    n = p.num_atoms

    def one(k: jax.Array) -> tuple:
        carry = engine.init(k, params)
        carry, _ = engine.run(carry, params, p.equilibration_blocks, 1)
        return engine.run(carry, params, p.num_samples, p.blocks_per_sample, engine.thermo)

    t0 = time.perf_counter()
    carry, thermo = jax.jit(jax.vmap(one))(keys)
    thermo = jax.tree.map(np.asarray, thermo)
    t_jax = time.perf_counter() - t0
    from md.units import BOLTZMANN_KJ_MOL_K

    enthalpy = thermo.kinetic + thermo.potential + thermo.pressure * thermo.volume
    fb_jax = np.exp(-enthalpy / (n * BOLTZMANN_KJ_MOL_K * thermo.temperature))
    jax_series = {
        "temperature_k": thermo.temperature,
        "pressure_atm": thermo.pressure / ATM_IN_KJ_MOL_NM3,
        "volume_nm3": thermo.volume,
        "f_b": fb_jax,
    }
    t0 = time.perf_counter()
    runs = [run_helium(k, theta, p) for k in jax.random.split(k_lmp, num_seeds)]
    t_lmp = time.perf_counter() - t0
    lmp_series = {
        "temperature_k": np.stack([r.temperature_k for r in runs]),
        "pressure_atm": np.stack([r.pressure_atm for r in runs]),
        "volume_nm3": np.stack([r.volume_nm3 for r in runs]),
        "f_b": np.stack([r.f_b for r in runs]),
    }
    quantities = {}
    for name in jax_series:
        a = jax_series[name].mean(axis=1)
        b = lmp_series[name].mean(axis=1)
        se = float(np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b)))
        diff = float(a.mean() - b.mean())
        quantities[name] = {
            "jax_md": float(a.mean()),
            "lammps": float(b.mean()),
            "difference": diff,
            "standard_error": se,
            "z": diff / se if se > 0 else float("inf"),
        }
    kl = jax.jit(jax.vmap(kl_divergence))
    fj = jnp.asarray(fb_jax, jnp.float32)
    fl = jnp.asarray(lmp_series["f_b"], jnp.float32)
    kl_cross = np.asarray(kl(fj, fl))
    kl_seed = np.asarray(kl(fj, jnp.roll(fj, 1, axis=0)))
    return {
        "preset": {k: v for k, v in vars(p).items()},
        "theta": list(theta),
        "num_seeds": num_seeds,
        "quantities": quantities,
        "kl_cross": kl_cross.tolist(),
        "kl_jax_md_seed_to_seed": kl_seed.tolist(),
        "seconds": {"jax_md_batched_including_compile": t_jax, "lammps_sequential": t_lmp},
        "jax_md_failed": bool(np.any(np.asarray(carry.diagnostics.failed()))),
    }


def run_lj_fluid(
    density: float,
    temperature: float,
    fcc_cells: int = 3,
    cutoff: float = 2.5,
    dt: float = 0.004,
    equilibration_steps: int = 5000,
    production_steps: int = 100_000,
    sample_every: int = 20,
    tau_t: float = 0.5,
    seed: int = 87287,
    executable: str = "lmp",
    timeout_s: float = 600.0,
) -> dict[str, Any]:
    """The LJ fluid in LAMMPS ``units lj``: NVT Nose-Hoover, plain truncation with tail corrections.

    ``pair_style lj/cut`` truncates without a shift, and ``pair_modify tail yes`` adds the
    long-range corrections of the full potential to the pressure and energy, so the result is an
    estimate of the full LJ fluid at ``4 fcc_cells^3`` atoms (108 for 3 cells, as the engine's
    ``reduced_dense_fluid`` preset).

    Returns
    -------
    dict
        Per-sample ``pressure`` (P*, tail included), ``potential`` (U*/N, tail included) and
        ``temperature`` (T*), plus ``num_atoms`` and ``wall_seconds``.
    """
    from jaxabc.errors import SimulationFailure

    n = 4 * fcc_cells**3
    script = f"""units lj
atom_style atomic
lattice fcc {density}
region box block 0 {fcc_cells} 0 {fcc_cells} 0 {fcc_cells}
create_box 1 box
create_atoms 1 box
mass 1 1.0
pair_style lj/cut {cutoff}
pair_modify tail yes
pair_coeff 1 1 1.0 1.0 {cutoff}
velocity all create {temperature} {seed} loop geom
timestep {dt}
fix 1 all nvt temp {temperature} {temperature} {tau_t}
thermo_style custom step temp press pe
thermo_modify norm yes
thermo {sample_every}
run {equilibration_steps}
run {production_steps}
"""
    with tempfile.TemporaryDirectory(prefix="jaxabc_lammps_lj_") as tmp:
        (Path(tmp) / "in.lj").write_text(script)
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(
                [executable, "-in", "in.lj", "-log", "log.lammps", "-screen", "none", "-nocite"],
                cwd=tmp,
                capture_output=True,
                text=True,
                timeout=timeout_s,
            )
        except subprocess.TimeoutExpired as exc:
            raise SimulationFailure(f"LAMMPS timed out after {timeout_s} s") from exc
        wall = time.perf_counter() - t0
        log = (Path(tmp) / "log.lammps").read_text() if (Path(tmp) / "log.lammps").exists() else ""
        if proc.returncode != 0:
            raise SimulationFailure(f"LAMMPS exited with {proc.returncode}: {(log or proc.stderr)[-800:]}")
    rows = np.asarray(_thermo_blocks(log)[-1], float)[1:]
    return {
        "temperature": rows[:, 1],
        "pressure": rows[:, 2],
        "potential": rows[:, 3],
        "num_atoms": n,
        "wall_seconds": wall,
    }
