"""GROMACS TIP4P water simulator: topology, protocol presets, one ``gmx mdrun`` per call.

The plugin writes a self-contained TIP4P topology (no system force-field files are read or
edited) in which every parameter a calibration may vary is a preprocessor macro with TIP4P's
own value as default, and each run sets its values through the ``define`` line of the ``.mdp``
file::

    define = -DSIGMA_OW=0.315365 -DEPSILON_OW=0.64852 -DQ_H=0.52 -DQ_M=-1.04 -DVSITE_A=0.128...

* ``SIGMA_OW`` (nm), ``EPSILON_OW`` (kJ/mol): the oxygen Lennard-Jones parameters (the two
  parameters of Dutta et al. 2018);
* ``Q_H`` and ``Q_M = -2 Q_H`` (e): the hydrogen and M-site charges, kept neutral by construction;
* ``VSITE_A``: the GROMACS ``virtual_sites3`` coefficient that places the M site at distance
  ``d_OM`` on the HOH bisector, ``a = d_OM / (2 d_OH cos(theta_HOH / 2))``.

A run is: ``gmx solvate`` (or the equilibrated 216-molecule ``tip4p.gro`` as is), steepest-descent
energy minimisation, then NPT molecular dynamics, each ``gmx mdrun`` single-threaded
(``-ntmpi 1 -ntomp 1``): with one worker per core this gave the same throughput per core as
threading on this machine and does not degrade when cores are shared.  Every run happens in its
own temporary directory, which is removed afterwards.

GROMACS does not stop when a parameter turns the liquid into a gas or collapses it (measured with
the ``quick`` preset: sigma 0.53 nm / epsilon 0.9 kJ/mol reaches an average box edge of 450 nm in
20 ps; sigma 0.281 / epsilon 0.2 shrinks the box to 1.40 nm, below twice the 0.85 nm cut-off,
without any error).  :func:`check_physical` detects such runs, and :class:`TIP4PSimulator` raises
:class:`jaxabc.errors.SimulationFailure` with the reason, which the executors turn into data.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxabc.errors import SimulationFailure
from jaxabc.seeding import seeds_from_key

__all__ = [
    "GMX_INSTALL_HINT",
    "PRESETS",
    "TIP4P_PARAMETERS",
    "GromacsNotFoundError",
    "GromacsRun",
    "Protocol",
    "TIP4PParameters",
    "build_system",
    "check_physical",
    "find_gmx",
    "get_protocol",
    "mdp_text",
    "run_gromacs",
    "seeds_for_key",
    "temporary_run_directory",
    "topology_text",
]

#: Mass of one TIP4P molecule (g/mol): O 15.9994 + 2 H 1.008; the M site is massless.
WATER_MOLAR_MASS_G_MOL = 15.9994 + 2 * 1.008
AVOGADRO = 6.02214076e23
#: kg/m3 per (molecules / nm3): (g/mol / N_A) g per molecule, 1 nm3 = 1e-27 m3, 1 g = 1e-3 kg.
_KG_M3_PER_MOLECULE_NM3 = WATER_MOLAR_MASS_G_MOL / AVOGADRO * 1e-3 / 1e-27

GMX_INSTALL_HINT = (
    "GROMACS `gmx` was not found on PATH. Install it with\n"
    "    sudo apt-get install -y gromacs\n"
    "(Debian/Ubuntu; this project was measured with GROMACS 2022.5), or pass the path of the "
    "executable as `gmx=...` / set the environment variable JAXABC_GMX."
)


class GromacsNotFoundError(FileNotFoundError):
    """Raised when the GROMACS ``gmx`` executable cannot be found.

    This is a configuration error, not a failed simulation: it is raised eagerly (when the
    simulator is built) so that a calibration does not turn every particle into a failure.
    """


def find_gmx(gmx: str | None = None) -> str:
    """Return the absolute path of the GROMACS executable.

    Parameters
    ----------
    gmx : str, optional
        Name or path of the executable. Defaults to ``$JAXABC_GMX`` or ``"gmx"``.

    Raises
    ------
    GromacsNotFoundError
        With the ``apt-get`` command to install GROMACS.
    """
    name = gmx or os.environ.get("JAXABC_GMX", "gmx")
    path = shutil.which(name)
    if path is None:
        raise GromacsNotFoundError(f"{GMX_INSTALL_HINT}\n(looked for {name!r})")
    return path


def _gmx_data_dir(gmx_path: str) -> Path:
    """Return GROMACS's ``share/gromacs/top`` directory (where ``tip4p.gro`` lives)."""
    env = os.environ.get("GMXDATA")
    candidates = [Path(env) / "top"] if env else []
    prefix = Path(gmx_path).resolve().parent.parent
    candidates += [prefix / "share" / "gromacs" / "top", Path("/usr/share/gromacs/top")]
    for candidate in candidates:
        if (candidate / "tip4p.gro").is_file():
            return candidate
    raise GromacsNotFoundError(
        f"found {gmx_path} but not GROMACS's data file tip4p.gro (looked in "
        f"{[str(c) for c in candidates]}); set GMXDATA to GROMACS's share/gromacs directory."
    )


# --------------------------------------------------------------------------------------------
# Force field
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TIP4PParameters:
    """TIP4P force-field parameters that a run may vary.

    Defaults are TIP4P (Jorgensen et al. 1983) as in GROMACS's ``oplsaa.ff/tip4p.itp``.

    Attributes
    ----------
    sigma_ow_nm : float
        Oxygen Lennard-Jones sigma (nm).
    epsilon_ow_kj_mol : float
        Oxygen Lennard-Jones epsilon (kJ/mol).
    charge_h_e : float
        Hydrogen partial charge (e); the M site carries ``-2 * charge_h_e`` and the oxygen none.
    om_distance_nm : float
        Distance of the M site from the oxygen along the HOH bisector (nm).
    oh_distance_nm, hh_distance_nm : float
        Rigid geometry (nm), held by SETTLE. Not meant to be calibrated (SETTLE needs both).
    """

    sigma_ow_nm: float = 0.315365
    epsilon_ow_kj_mol: float = 0.648520
    charge_h_e: float = 0.52
    om_distance_nm: float = 0.015
    oh_distance_nm: float = 0.09572
    hh_distance_nm: float = 0.15139

    def __post_init__(self) -> None:
        for name in ("sigma_ow_nm", "epsilon_ow_kj_mol", "om_distance_nm", "oh_distance_nm",
                     "hh_distance_nm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"TIP4P parameter {name} must be finite and > 0, got {value!r}")
        if not math.isfinite(self.charge_h_e):
            raise ValueError(f"charge_h_e must be finite, got {self.charge_h_e!r}")

    @property
    def charge_m_e(self) -> float:
        """M-site charge (e), ``-2 * charge_h_e`` so that the molecule stays neutral."""
        return -2.0 * self.charge_h_e

    @property
    def vsite_coefficient(self) -> float:
        """``virtual_sites3`` coefficient ``a = b`` placing M at ``om_distance_nm``."""
        half_angle_cos = math.sqrt(1.0 - (self.hh_distance_nm / (2 * self.oh_distance_nm)) ** 2)
        return self.om_distance_nm / (2.0 * self.oh_distance_nm * half_angle_cos)

    def defines(self) -> str:
        """The ``define`` line of the ``.mdp`` file that sets these parameters."""
        # repr-precision floats: the topology must see exactly the theta the sampler proposed.
        return (
            f"-DSIGMA_OW={self.sigma_ow_nm!r} -DEPSILON_OW={self.epsilon_ow_kj_mol!r} "
            f"-DQ_H={self.charge_h_e!r} -DQ_M={self.charge_m_e!r} "
            f"-DVSITE_A={self.vsite_coefficient!r}"
        )


#: TIP4P's own parameters (the truth of the simulated-data calibration).
TIP4P_PARAMETERS = TIP4PParameters()


def topology_text(num_molecules: int, params: TIP4PParameters = TIP4P_PARAMETERS) -> str:
    """Return a self-contained TIP4P topology for ``num_molecules`` waters.

    Every variable parameter is a macro, defaulting to ``params`` (so ``grompp`` also works
    without a ``define`` line), overridden per run by :meth:`TIP4PParameters.defines`.
    """
    # comb-rule 2 (sigma/epsilon): only OW carries LJ, so the rule never mixes two values; the
    # [atomtypes] therefore hold exactly sigma and epsilon.  gen-pairs/fudge are irrelevant
    # (no 1-4 pairs in a rigid 4-site molecule).
    return f"""; jaxabc TIP4P water topology (self-contained; parameters are macros)
#ifndef SIGMA_OW
#define SIGMA_OW {params.sigma_ow_nm!r}
#endif
#ifndef EPSILON_OW
#define EPSILON_OW {params.epsilon_ow_kj_mol!r}
#endif
#ifndef Q_H
#define Q_H {params.charge_h_e!r}
#endif
#ifndef Q_M
#define Q_M {params.charge_m_e!r}
#endif
#ifndef VSITE_A
#define VSITE_A {params.vsite_coefficient!r}
#endif

[ defaults ]
; nbfunc  comb-rule  gen-pairs  fudgeLJ  fudgeQQ
1         2          no         1.0      1.0

[ atomtypes ]
; name  at.num  mass     charge  ptype  sigma     epsilon
OW      8       15.9994  0.0     A      SIGMA_OW  EPSILON_OW
HW      1       1.008    0.0     A      0.0       0.0
MW      0       0.0      0.0     D      0.0       0.0

[ moleculetype ]
; name  nrexcl
SOL     2

[ atoms ]
; nr  type  resnr  res  atom  cgnr  charge  mass
1     OW    1      SOL  OW    1     0.0     15.9994
2     HW    1      SOL  HW1   1     Q_H     1.008
3     HW    1      SOL  HW2   1     Q_H     1.008
4     MW    1      SOL  MW    1     Q_M     0.0

[ settles ]
; OW  funct  doh  dhh
1     1      {params.oh_distance_nm!r}  {params.hh_distance_nm!r}

[ exclusions ]
1 2 3 4
2 1 3 4
3 1 2 4
4 1 2 3

[ virtual_sites3 ]
; site  from       funct  a        b
4       1  2  3    1      VSITE_A  VSITE_A

[ system ]
TIP4P water

[ molecules ]
SOL {num_molecules}
"""


# --------------------------------------------------------------------------------------------
# Protocols
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Protocol:
    """A simulation protocol: system size, run length, cut-offs, coupling, analysis window.

    Attributes
    ----------
    name : str
    box_nm : float or None
        Edge of the cubic box given to ``gmx solvate -cs tip4p.gro``; ``None`` uses GROMACS's
        equilibrated ``tip4p.gro`` (216 molecules, 1.862 nm) as is.
    expected_molecules : int or None
        Checked after solvation (``solvate`` with a 2.5 nm box gives 515 with GROMACS 2022.5).
    cutoff_nm : float
        PME real-space and Lennard-Jones cut-off (nm).
    timestep_ps : float
    num_steps : int
        NPT MD steps.
    em_steps : int
        Maximum steepest-descent steps.
    frame_interval_steps : int
        Steps between XTC frames.
    analysis_start_ps : float
        Frames before this time are equilibration and are not analysed.
    temperature_k, pressure_bar : float
    tau_t_ps, tau_p_ps, compressibility_per_bar : float
    nstlist : int
    timeout_s : float
        Wall-clock limit for the whole run (all ``gmx`` calls); the run is killed past it.
    min_density_kg_m3, max_density_kg_m3 : float
        Mean density over the analysed frames outside this band is a failure (vapour, collapse).
    """

    name: str
    box_nm: float | None
    expected_molecules: int | None
    cutoff_nm: float
    timestep_ps: float
    num_steps: int
    em_steps: int
    frame_interval_steps: int
    analysis_start_ps: float
    temperature_k: float = 298.0
    pressure_bar: float = 1.01325
    tau_t_ps: float = 0.1
    tau_p_ps: float = 2.0
    compressibility_per_bar: float = 4.5e-5
    nstlist: int = 10
    timeout_s: float = 600.0
    min_density_kg_m3: float = 500.0
    max_density_kg_m3: float = 1500.0
    extra_mdp: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.num_steps <= 0 or self.frame_interval_steps <= 0:
            raise ValueError("num_steps and frame_interval_steps must be positive")
        if self.analysis_start_ps >= self.length_ps:
            raise ValueError(
                f"analysis_start_ps={self.analysis_start_ps} must be below the run length "
                f"{self.length_ps} ps"
            )
        if self.min_density_kg_m3 >= self.max_density_kg_m3:
            raise ValueError("min_density_kg_m3 must be below max_density_kg_m3")

    @property
    def length_ps(self) -> float:
        """Length of the NPT run (ps)."""
        return self.num_steps * self.timestep_ps

    @property
    def frame_interval_ps(self) -> float:
        """Time between trajectory frames (ps)."""
        return self.frame_interval_steps * self.timestep_ps


#: Protocol presets.
#:
#: ``paper``: Dutta et al. 2018: 515 molecules from ``gmx solvate`` in a 2.5 nm box, steepest
#: descent, 100 ps NPT with dt 2 fs, PME and LJ cut-offs 1.0 nm, v-rescale at 298 K,
#: Parrinello-Rahman at 1 atm, SETTLE, neighbour list every 10 steps; the published scripts
#: analysed 20-100 ps.  Not in the paper and chosen here: frames every 0.5 ps, tau_t 0.1 ps,
#: tau_p 2 ps, dispersion correction EnerPres (as in the published em.mdp).  Measured here:
#: 171 s of GROMACS on one (shared) core plus ~5 s of analysis per simulation.
#:
#: ``quick``: for tests and CPU demonstrations: GROMACS's equilibrated 216-molecule
#: ``tip4p.gro``, cut-offs 0.85 nm (the box, 1.86 nm, must stay above twice the cut-off),
#: 20 ps NPT, frames every 0.2 ps, analysis 5-20 ps.  About 7-10 s on one core here.
PRESETS: dict[str, Protocol] = {
    "paper": Protocol(
        name="paper",
        box_nm=2.5,
        expected_molecules=515,
        cutoff_nm=1.0,
        timestep_ps=0.002,
        num_steps=50_000,
        em_steps=5_000,
        frame_interval_steps=250,
        analysis_start_ps=20.0,
        timeout_s=1800.0,
    ),
    "quick": Protocol(
        name="quick",
        box_nm=None,
        expected_molecules=216,
        cutoff_nm=0.85,
        timestep_ps=0.002,
        num_steps=10_000,
        em_steps=1_000,
        frame_interval_steps=100,
        analysis_start_ps=5.0,
        timeout_s=300.0,
    ),
}


def get_protocol(preset: str | Protocol, **overrides) -> Protocol:
    """Return a preset by name (``"paper"`` or ``"quick"``), with optional field overrides.

    Examples
    --------
    >>> get_protocol("quick", num_steps=2000, analysis_start_ps=1.0).length_ps
    4.0
    """
    if isinstance(preset, Protocol):
        base = preset
    else:
        try:
            base = PRESETS[preset]
        except KeyError:
            raise ValueError(
                f"unknown GROMACS preset {preset!r}; choose one of {sorted(PRESETS)} or pass a "
                "Protocol"
            ) from None
    return replace(base, **overrides) if overrides else base


def mdp_text(
    protocol: Protocol,
    params: TIP4PParameters,
    stage: str,
    gen_seed: int = 1,
    ld_seed: int = 1,
) -> str:
    """Return the ``.mdp`` file for ``stage`` ``"em"`` (minimisation) or ``"npt"``."""
    cutoff = f"{protocol.cutoff_nm!r}"
    common = {
        "define": params.defines(),
        "cutoff-scheme": "Verlet",
        "nstlist": str(protocol.nstlist),
        "pbc": "xyz",
        "coulombtype": "PME",
        "rcoulomb": cutoff,
        "vdwtype": "Cut-off",
        "rvdw": cutoff,
        # rlist = cut-off silences grompp's note; mdrun sets the Verlet buffer itself.
        "rlist": cutoff,
        "DispCorr": "EnerPres",
    }
    if stage == "em":
        options = {
            "integrator": "steep",
            "nsteps": str(protocol.em_steps),
            "emtol": "100.0",
            # GROMACS's default first step, 0.01 nm, makes 2022.5's steepest descent crash
            # (SIGSEGV after ~12 steps, no message) at isolated, deterministic (sigma, epsilon):
            # 3 of a 12 x 12 grid over the prior, e.g. (0.304 nm, 0.455 kJ/mol), and 1-2 % of
            # every calibration's simulations, holes in the likelihood near the posterior.  At
            # 0.001 nm the same grid minimises without a crash (tests/test_water_gromacs.py).
            "emstep": "0.001",
            **common,
        }
    elif stage == "npt":
        options = {
            "integrator": "md",
            "dt": f"{protocol.timestep_ps!r}",
            "nsteps": str(protocol.num_steps),
            "nstxout-compressed": str(protocol.frame_interval_steps),
            # 1e-3 nm XTC precision is GROMACS's default; g(r) uses 0.002 nm bins.
            "compressed-x-precision": "1000",
            # nstenergy and nstlog must be multiples of nstcalcenergy (else grompp warns).
            "nstcalcenergy": str(math.gcd(100, protocol.frame_interval_steps)),
            "nstenergy": str(protocol.frame_interval_steps),
            "nstlog": str(10 * protocol.frame_interval_steps),
            **common,
            "tcoupl": "v-rescale",
            "tc-grps": "System",
            "tau_t": f"{protocol.tau_t_ps!r}",
            "ref_t": f"{protocol.temperature_k!r}",
            "pcoupl": "Parrinello-Rahman",
            "pcoupltype": "isotropic",
            "tau_p": f"{protocol.tau_p_ps!r}",
            "ref_p": f"{protocol.pressure_bar!r}",
            "compressibility": f"{protocol.compressibility_per_bar!r}",
            "gen_vel": "yes",
            "gen_temp": f"{protocol.temperature_k!r}",
            "gen_seed": str(int(gen_seed)),
            "ld_seed": str(int(ld_seed)),
            "continuation": "no",
            **protocol.extra_mdp,
        }
    else:
        raise ValueError(f"stage must be 'em' or 'npt', got {stage!r}")
    return "".join(f"{k:<26}= {v}\n" for k, v in options.items())


def seeds_for_key(key) -> tuple[int, int]:
    """``(gen_seed, ld_seed)`` for GROMACS, derived from a particle's JAX key.

    Parameters
    ----------
    key : array_like
        A JAX PRNG key, typed or raw ``uint32[2]`` (numpy arrays are accepted).
    """
    import jax.numpy as jnp

    gen_seed, ld_seed = seeds_from_key(jnp.asarray(key), 2)
    return gen_seed, ld_seed


# --------------------------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------------------------


class GromacsRun(NamedTuple):
    """Files of a finished run, all inside ``workdir``.

    Attributes
    ----------
    workdir : pathlib.Path
    structure : pathlib.Path
        ``.gro`` of the minimised starting structure (topology for reading the XTC).
    trajectory : pathlib.Path
        ``npt.xtc``: positions of all atoms every ``frame_interval_ps``.
    tpr, log, energy : pathlib.Path
        ``npt.tpr``, ``npt.log``, ``npt.edr``.
    num_molecules : int
    gen_seed, ld_seed : int
    wall_time_s : float
    """

    workdir: Path
    structure: Path
    trajectory: Path
    tpr: Path
    log: Path
    energy: Path
    num_molecules: int
    gen_seed: int
    ld_seed: int
    wall_time_s: float


def _tail(text: str, lines: int = 12) -> str:
    return "\n".join(text.strip().splitlines()[-lines:])


def _fatal_message(text: str) -> str:
    """The 'Fatal error' paragraph of GROMACS output, else its tail."""
    match = re.search(r"Fatal error:\n(.*?)\n\n", text, flags=re.S)
    return match.group(1).strip() if match else _tail(text, 6)


def _run_gmx(args: list[str], cwd: Path, deadline: float, stdin: str | None = None) -> None:
    """Run one ``gmx`` command; raise SimulationFailure on a non-zero exit or the deadline."""
    remaining = deadline - time.monotonic()
    if remaining <= 0:
        raise SimulationFailure(f"timeout: no time left before `gmx {args[1]}`")
    env = dict(os.environ)
    # One thread: one worker per core is the throughput-optimal layout measured here, and
    # GROMACS would otherwise pin threads and fight the other workers for cores.
    env["OMP_NUM_THREADS"] = "1"
    # Keep GROMACS from backing up files (#npt.log.1#) and from printing quotes we do not read.
    env["GMX_MAXBACKUP"] = "-1"
    # gmx stays in our process group on purpose: an executor that kills a stuck worker's group
    # (jaxabc.ProcessPoolExecutor does) then stops gmx too.  gmx is one process (thread-MPI),
    # so killing it on our own timeout needs no group kill.
    process = subprocess.Popen(
        args, cwd=cwd, stdin=subprocess.PIPE if stdin is not None else subprocess.DEVNULL,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
    )
    try:
        output, _ = process.communicate(input=stdin, timeout=remaining)
    except subprocess.TimeoutExpired:
        process.kill()
        process.communicate()
        raise SimulationFailure(
            f"timeout: `gmx {args[1]}` was killed after the run's time limit"
        ) from None
    if process.returncode < 0:
        raise SimulationFailure(
            f"`gmx {args[1]}` was killed by signal {-process.returncode} "
            f"({signal.Signals(-process.returncode).name})"
        )
    if process.returncode != 0:
        raise SimulationFailure(
            f"`gmx {args[1]}` exited with status {process.returncode}: {_fatal_message(output)}"
        )


_NONFINITE = re.compile(r"(?<![A-Za-z])(nan|-?inf)(?![A-Za-z])", re.IGNORECASE)


def _check_log_energies(log: Path) -> None:
    """Raise SimulationFailure if an energy block of the mdrun log holds NaN or infinity."""
    text = log.read_text(errors="replace")
    for block in re.findall(r"Energies \(kJ/mol\)\n(.*?)\n\n", text, flags=re.S):
        # Name rows ("Kinetic En.") hold no standalone nan/inf word, so every row can be scanned.
        for row in block.splitlines():
            if _NONFINITE.search(row):
                raise SimulationFailure(f"non-finite energies in {log.name}: {row.strip()}")


def build_system(
    protocol: Protocol, workdir: Path, gmx_path: str, deadline: float | None = None
) -> int:
    """Write ``conf.gro`` (the starting water box) into ``workdir``; return its molecule count.

    ``box_nm=None`` copies GROMACS's equilibrated ``tip4p.gro``; otherwise
    ``gmx solvate -cs tip4p.gro -box L L L`` fills a cubic box (515 molecules for L = 2.5 nm
    with GROMACS 2022.5).
    """
    top_dir = _gmx_data_dir(gmx_path)
    deadline = time.monotonic() + protocol.timeout_s if deadline is None else deadline
    if protocol.box_nm is None:
        shutil.copyfile(top_dir / "tip4p.gro", workdir / "conf.gro")
    else:
        box = f"{protocol.box_nm!r}"
        _run_gmx([gmx_path, "solvate", "-cs", str(top_dir / "tip4p.gro"), "-box", box, box, box,
                  "-o", "conf.gro"], workdir, deadline)
    lines = (workdir / "conf.gro").read_text().splitlines()
    num_atoms = int(lines[1])
    if num_atoms % 4:
        raise SimulationFailure(f"conf.gro has {num_atoms} atoms, not a multiple of 4 (TIP4P)")
    num_molecules = num_atoms // 4
    if protocol.expected_molecules is not None and num_molecules != protocol.expected_molecules:
        # Not a simulation failure: the protocol does not describe this GROMACS version.
        raise RuntimeError(
            f"preset {protocol.name!r} expects {protocol.expected_molecules} molecules but "
            f"`gmx solvate` gave {num_molecules}; set expected_molecules=None to accept it"
        )
    return num_molecules


def run_gromacs(
    params: TIP4PParameters,
    protocol: Protocol,
    workdir: str | os.PathLike,
    gen_seed: int,
    ld_seed: int,
    gmx: str | None = None,
) -> GromacsRun:
    """Build, minimise and run NPT TIP4P water in ``workdir``; return the output files.

    Parameters
    ----------
    params : TIP4PParameters
    protocol : Protocol
    workdir : path-like
        An existing, empty directory; the caller owns (and removes) it.
    gen_seed, ld_seed : int
        Velocity-generation and thermostat seeds (see :func:`seeds_for_key`).
    gmx : str, optional
        GROMACS executable (default ``$JAXABC_GMX`` or ``gmx``).

    Raises
    ------
    GromacsNotFoundError
        ``gmx`` is missing.
    jaxabc.errors.SimulationFailure
        A ``gmx`` step exited non-zero, was killed, ran past ``protocol.timeout_s``, or the log
        holds non-finite energies.  Physical checks on the trajectory are separate
        (:func:`check_physical`).
    """
    gmx_path = find_gmx(gmx)
    workdir = Path(workdir)
    start = time.monotonic()
    deadline = start + protocol.timeout_s
    num_molecules = build_system(protocol, workdir, gmx_path, deadline)
    (workdir / "topol.top").write_text(topology_text(num_molecules, params))
    (workdir / "em.mdp").write_text(mdp_text(protocol, params, "em"))
    (workdir / "npt.mdp").write_text(mdp_text(protocol, params, "npt", gen_seed, ld_seed))

    mdrun_threads = ["-ntmpi", "1", "-ntomp", "1", "-pin", "off"]
    _run_gmx([gmx_path, "grompp", "-f", "em.mdp", "-c", "conf.gro", "-p", "topol.top",
              "-o", "em.tpr"], workdir, deadline)
    _run_gmx([gmx_path, "mdrun", "-deffnm", "em", *mdrun_threads], workdir, deadline)
    # -maxwarn 1: the one warning is GROMACS's advice against Parrinello-Rahman right after
    # velocity generation; the paper's protocol does exactly that (its scripts used -maxwarn 2).
    _run_gmx([gmx_path, "grompp", "-f", "npt.mdp", "-c", "em.gro", "-p", "topol.top",
              "-o", "npt.tpr", "-maxwarn", "1"], workdir, deadline)
    _run_gmx([gmx_path, "mdrun", "-deffnm", "npt", *mdrun_threads], workdir, deadline)

    run = GromacsRun(
        workdir=workdir,
        structure=workdir / "em.gro",
        trajectory=workdir / "npt.xtc",
        tpr=workdir / "npt.tpr",
        log=workdir / "npt.log",
        energy=workdir / "npt.edr",
        num_molecules=num_molecules,
        gen_seed=int(gen_seed),
        ld_seed=int(ld_seed),
        wall_time_s=time.monotonic() - start,
    )
    if not run.trajectory.is_file() or run.trajectory.stat().st_size == 0:
        raise SimulationFailure("gmx mdrun exited normally but wrote no trajectory (npt.xtc)")
    _check_log_energies(run.log)
    return run


def check_physical(box_nm: np.ndarray, num_molecules: int, protocol: Protocol) -> float:
    """Reject vaporised, collapsed or too-small boxes; return the mean density (kg/m3).

    Parameters
    ----------
    box_nm : np.ndarray, shape (num_frames, 3)
        Box edges of the analysed frames (nm).
    num_molecules : int
    protocol : Protocol
        Gives the density band and the cut-off.

    Raises
    ------
    jaxabc.errors.SimulationFailure
        Non-finite box, mean density outside ``[min_density_kg_m3, max_density_kg_m3]``, or a
        box edge below twice the cut-off in any frame (minimum image no longer holds for the
        interactions; GROMACS 2022 does not stop in that case).
    """
    box_nm = np.asarray(box_nm, dtype=np.float64)
    if box_nm.size == 0:
        raise SimulationFailure("no trajectory frames in the analysis window")
    if not np.all(np.isfinite(box_nm)):
        raise SimulationFailure("non-finite box in the trajectory")
    density = num_molecules / np.prod(box_nm, axis=1) * _KG_M3_PER_MOLECULE_NM3
    mean_density = float(np.mean(density))
    if mean_density < protocol.min_density_kg_m3:
        raise SimulationFailure(
            f"density {mean_density:.4g} kg/m3 < {protocol.min_density_kg_m3:g} kg/m3: the "
            f"liquid vaporised (largest box edge {box_nm.max():.4g} nm)"
        )
    if mean_density > protocol.max_density_kg_m3:
        raise SimulationFailure(
            f"density {mean_density:.4g} kg/m3 > {protocol.max_density_kg_m3:g} kg/m3: the "
            "liquid collapsed"
        )
    smallest = float(box_nm.min())
    if smallest < 2.0 * protocol.cutoff_nm:
        raise SimulationFailure(
            f"box edge {smallest:.4g} nm < twice the cut-off ({2 * protocol.cutoff_nm:g} nm): "
            f"the box collapsed (mean density {mean_density:.4g} kg/m3)"
        )
    return mean_density


def temporary_run_directory(prefix: str = "jaxabc-gmx-") -> tempfile.TemporaryDirectory:
    """A per-run temporary directory (``$JAXABC_TMPDIR`` or the system default), removed on exit."""
    return tempfile.TemporaryDirectory(prefix=prefix, dir=os.environ.get("JAXABC_TMPDIR"))
