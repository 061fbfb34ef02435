"""GROMACS as the reference for the JAX water engine: energy and forces of one configuration.

:func:`gromacs_single_point` writes the project's own TIP4P topology
(:func:`md.water.topology.topology_text`) for a :class:`~md.water.jaxmd.forcefield.WaterModel`,
an ``.mdp`` with the same reaction field, cut-off and LJ shift as
:class:`~md.water.jaxmd.forcefield.ReactionField`, and runs ``gmx grompp`` and
``gmx mdrun -rerun`` on the configuration, with the M sites placed from O and H by the
``virtual_sites3`` rule and written into the file (a rerun does not rebuild them).  It reads
``LJ (SR)`` and ``Coulomb (SR)`` with ``gmx energy -dp`` (as stored, in float32) and the forces
on every atom from ``gmx dump`` of the trajectory (6 significant digits, as it prints them).
"""

from __future__ import annotations

import math
import os
import re
import subprocess
from pathlib import Path
from typing import NamedTuple

import numpy as np

from md.water.jaxmd.forcefield import ReactionField, WaterModel

__all__ = ["GromacsSinglePoint", "gromacs_single_point", "read_gro", "rerun_mdp_text"]


class GromacsSinglePoint(NamedTuple):
    """GROMACS's energies (kJ/mol) and forces (kJ/mol/nm) of one configuration.

    Attributes
    ----------
    lj, coulomb : float
        ``LJ (SR)`` and ``Coulomb (SR)`` (the latter includes GROMACS's constant
        reaction-field terms of excluded pairs and self pairs).
    forces : np.ndarray, shape (num_molecules, 4, 3)
        On O, H1, H2, M after GROMACS spread the M-site force onto the atoms.
    """

    lj: float
    coulomb: float
    forces: np.ndarray


def read_gro(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """O, H1, H2 positions and box of a four-site water ``.gro`` file (O, H, H, M order).

    Returns
    -------
    atoms_nm : np.ndarray, shape (num_molecules, 3, 3), float64
    box_nm : np.ndarray, shape (3,)
    """
    lines = Path(path).read_text().splitlines()
    num_atoms = int(lines[1])
    if num_atoms % 4:
        raise ValueError(f"{path}: {num_atoms} atoms is not a multiple of 4 (O, H, H, M per molecule)")
    # Fixed columns: 20 characters of names/numbers, then x, y, z in 8-character fields.
    xyz = np.array([[float(line[20 + 8 * k : 28 + 8 * k]) for k in range(3)] for line in lines[2 : 2 + num_atoms]])
    box = np.array([float(v) for v in lines[2 + num_atoms].split()[:3]])
    return xyz.reshape(-1, 4, 3)[:, :3].copy(), box


def _write_gro(path: Path, atoms_nm: np.ndarray, box_nm: np.ndarray, model: WaterModel) -> None:
    a = float(model.vsite_coefficient)
    oxygen = atoms_nm[:, 0]
    m_site = oxygen + a * (atoms_nm[:, 1] - oxygen) + a * (atoms_nm[:, 2] - oxygen)
    sites = np.concatenate([atoms_nm, m_site[:, None]], axis=1).reshape(-1, 3)
    names = ("OW", "HW1", "HW2", "MW")
    # `mdrun -rerun` takes the M sites from the file as they are (it does not rebuild virtual
    # sites), so they are written here, with 7 decimals (GROMACS reads the precision from the
    # spacing of the decimal points): float32 resolution, where 3 decimals (GROMACS's default)
    # would move M by up to 5e-4 nm and the forces by ~1e-2 relative.
    rows = [
        f"{i // 4 + 1:5d}SOL  {names[i % 4]:>5s}{(i + 1) % 100000:5d}{x:12.7f}{y:12.7f}{z:12.7f}"
        for i, (x, y, z) in enumerate(sites)
    ]
    path.write_text(
        "jaxabc single point\n"
        f"{len(sites)}\n" + "\n".join(rows) + f"\n{box_nm[0]:10.5f}{box_nm[1]:10.5f}{box_nm[2]:10.5f}\n"
    )


def rerun_mdp_text(settings: ReactionField) -> str:
    """``.mdp`` for a single-point ``mdrun -rerun`` with the engine's interactions."""
    epsilon_rf = "0" if math.isinf(settings.epsilon_rf) else repr(settings.epsilon_rf)  # 0 = infinity
    options = {
        "integrator": "md",
        "nsteps": "0",
        "cutoff-scheme": "Verlet",
        "pbc": "xyz",
        # No Verlet buffer: a single point needs none, and the buffered list radius would
        # otherwise exceed half of a small box (mdrun refuses such a frame).
        "verlet-buffer-tolerance": "-1",
        "nstlist": "1",
        "rlist": repr(settings.cutoff_nm),
        "coulombtype": "reaction-field",
        "coulomb-modifier": "Potential-shift",
        "epsilon-r": "1",
        "epsilon-rf": epsilon_rf,
        "rcoulomb": repr(settings.cutoff_nm),
        "vdwtype": "Cut-off",
        "vdw-modifier": "Potential-shift",
        "rvdw": repr(settings.cutoff_nm),
        "DispCorr": "no",
        "nstcalcenergy": "1",
        "nstenergy": "1",
        "nstfout": "1",
    }
    return "".join(f"{k:<20}= {v}\n" for k, v in options.items())


def _gmx(gmx: str, args: list[str], cwd: Path, stdin: str | None = None) -> str:
    result = subprocess.run(
        [gmx, *args],
        cwd=cwd,
        input=stdin,
        capture_output=True,
        text=True,
        env={**os.environ, "GMX_MAXBACKUP": "-1", "OMP_NUM_THREADS": "1"},
    )
    if result.returncode != 0:
        raise RuntimeError(f"`gmx {args[0]}` failed ({result.returncode}):\n{result.stderr[-3000:]}")
    return result.stdout


def gromacs_single_point(
    atoms_nm: np.ndarray,
    box_nm: np.ndarray,
    model: WaterModel,
    settings: ReactionField,
    workdir: str | Path,
    gmx: str = "gmx",
) -> GromacsSinglePoint:
    """Energies and forces of one configuration from GROMACS (``grompp`` + ``mdrun -rerun``).

    Parameters
    ----------
    atoms_nm : np.ndarray, shape (num_molecules, 3, 3)
        O, H1, H2 (nm); the M site is placed by the ``virtual_sites3`` rule.
    box_nm : np.ndarray, shape (3,)
    model : WaterModel
        Concrete values.
    settings : ReactionField
    workdir : path-like
        An existing directory for GROMACS's files.
    gmx : str
        The GROMACS executable (a mixed-precision build gives float32 results).

    Raises
    ------
    RuntimeError
        A ``gmx`` command failed (its message is included) or its output could not be read.
    """
    from md.water.topology import topology_text

    workdir = Path(workdir)
    atoms_nm = np.asarray(atoms_nm, dtype=np.float64)
    box_nm = np.asarray(box_nm, dtype=np.float64)
    _write_gro(workdir / "conf.gro", atoms_nm, box_nm, model)
    (workdir / "topol.top").write_text(topology_text(atoms_nm.shape[0], model.to_gromacs()))
    (workdir / "rerun.mdp").write_text(rerun_mdp_text(settings))
    _gmx(gmx, ["grompp", "-f", "rerun.mdp", "-c", "conf.gro", "-p", "topol.top", "-o", "rerun.tpr"], workdir)
    _gmx(
        gmx,
        ["mdrun", "-s", "rerun.tpr", "-rerun", "conf.gro", "-deffnm", "rerun", "-ntmpi", "1", "-ntomp", "1"],
        workdir,
    )
    # -dp: the energies as stored (float32), not rounded to 6 digits as in the log or `gmx dump`.
    _gmx(gmx, ["energy", "-f", "rerun.edr", "-dp", "-o", "energy.xvg"], workdir, stdin="LJ-(SR)\nCoulomb-(SR)\n\n")
    xvg = (workdir / "energy.xvg").read_text().splitlines()
    legends = [re.findall(r'legend "(.*)"', line)[0] for line in xvg if re.match(r"@ s\d+ legend", line)]
    values = [line.split() for line in xvg if line and line[0] not in "@#"]
    if legends != ["LJ (SR)", "Coulomb (SR)"] or len(values) != 1:
        raise RuntimeError(f"unexpected `gmx energy` output: legends {legends}, {len(values)} frames")
    lj, coulomb = float(values[0][1]), float(values[0][2])
    trajectory_dump = _gmx(gmx, ["dump", "-f", "rerun.trr"], workdir)
    number = r"([-+0-9.eE]+)"
    forces = np.array(
        re.findall(rf"^\s*f\[\s*\d+\]=\{{\s*{number},\s*{number},\s*{number}\}}", trajectory_dump, flags=re.M),
        dtype=np.float64,
    )
    if forces.shape != (4 * atoms_nm.shape[0], 3):
        raise RuntimeError(f"read {forces.shape} forces from rerun.trr, expected {(4 * atoms_nm.shape[0], 3)}")
    return GromacsSinglePoint(lj, coulomb, forces.reshape(-1, 4, 3))
