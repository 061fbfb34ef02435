"""GROMACS protocols for the TIP4P simulator: presets and the ``.mdp`` files they write."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from md.water.topology import TIP4PParameters

__all__ = ["PRESETS", "Protocol", "get_protocol", "mdp_text"]


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
                f"analysis_start_ps={self.analysis_start_ps} must be below the run length {self.length_ps} ps"
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
                f"unknown GROMACS preset {preset!r}; choose one of {sorted(PRESETS)} or pass a Protocol"
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
