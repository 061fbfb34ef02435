"""GROMACS TIP4P water runner: one ``gmx mdrun`` per call.

The topology lives in :mod:`md.water.topology` and the protocols and ``.mdp`` files in
:mod:`md.water.protocol`; their public names are re-exported here.

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

import os
import re
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxabc.errors import SimulationFailure
from jaxabc.seeding import seeds_from_key
from md.water.protocol import PRESETS, Protocol, get_protocol, mdp_text
from md.water.topology import TIP4P_PARAMETERS, TIP4PParameters, topology_text

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
        args,
        cwd=cwd,
        stdin=subprocess.PIPE if stdin is not None else subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    try:
        output, _ = process.communicate(input=stdin, timeout=remaining)
    except subprocess.TimeoutExpired:
        process.kill()
        process.communicate()
        raise SimulationFailure(f"timeout: `gmx {args[1]}` was killed after the run's time limit") from None
    if process.returncode < 0:
        raise SimulationFailure(
            f"`gmx {args[1]}` was killed by signal {-process.returncode} ({signal.Signals(-process.returncode).name})"
        )
    if process.returncode != 0:
        raise SimulationFailure(f"`gmx {args[1]}` exited with status {process.returncode}: {_fatal_message(output)}")


_NONFINITE = re.compile(r"(?<![A-Za-z])(nan|-?inf)(?![A-Za-z])", re.IGNORECASE)


def _check_log_energies(log: Path) -> None:
    """Raise SimulationFailure if an energy block of the mdrun log holds NaN or infinity."""
    text = log.read_text(errors="replace")
    for block in re.findall(r"Energies \(kJ/mol\)\n(.*?)\n\n", text, flags=re.S):
        # Name rows ("Kinetic En.") hold no standalone nan/inf word, so every row can be scanned.
        for row in block.splitlines():
            if _NONFINITE.search(row):
                raise SimulationFailure(f"non-finite energies in {log.name}: {row.strip()}")


def build_system(protocol: Protocol, workdir: Path, gmx_path: str, deadline: float | None = None) -> int:
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
        _run_gmx(
            [gmx_path, "solvate", "-cs", str(top_dir / "tip4p.gro"), "-box", box, box, box, "-o", "conf.gro"],
            workdir,
            deadline,
        )
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
    _run_gmx(
        [gmx_path, "grompp", "-f", "em.mdp", "-c", "conf.gro", "-p", "topol.top", "-o", "em.tpr"], workdir, deadline
    )
    _run_gmx([gmx_path, "mdrun", "-deffnm", "em", *mdrun_threads], workdir, deadline)
    # -maxwarn 1: the one warning is GROMACS's advice against Parrinello-Rahman right after
    # velocity generation; the paper's protocol does exactly that (its scripts used -maxwarn 2).
    _run_gmx(
        [gmx_path, "grompp", "-f", "npt.mdp", "-c", "em.gro", "-p", "topol.top", "-o", "npt.tpr", "-maxwarn", "1"],
        workdir,
        deadline,
    )
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
            f"density {mean_density:.4g} kg/m3 > {protocol.max_density_kg_m3:g} kg/m3: the liquid collapsed"
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
