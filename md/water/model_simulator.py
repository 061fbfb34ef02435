"""``simulate(key, theta)`` for any published rigid water model, on the joint summaries.

:class:`WaterModelSimulator` is :class:`md.water.simulator.TIP4PSimulator` (same presets,
seeding, temporary directories and :class:`jaxabc.errors.SimulationFailure` statuses) for a
:class:`md.water.models.WaterModel`, with ``theta = (sigma_OO nm, epsilon_OO kJ/mol)``:

* 4-site models (TIP4P, TIP4P/2005, TIP4P-Ew) run through the frozen
  :func:`md.water.gromacs.run_gromacs`, with the model's charges, M site and geometry as the
  TIP4P topology's ``base_parameters``;
* 3-site models (SPC/E, TIP3P) run the same steps (minimisation, NPT, the same ``.mdp``) on
  GROMACS's equilibrated 3-site box ``spc216.gro`` with
  :func:`md.water.models.three_site_topology_text`.

A call returns the joint summaries, shape (14,): S1..S9 of :mod:`md.water.statistics`
(unobserved ones zeroed as in ``TIP4PSimulator``; S9 is the finite-size corrected D, below), the
mean density (kg/m3), the enthalpy of vaporisation (kJ/mol) over the analysed frames and the
second-shell summaries of g_OO (:func:`md.water.statistics.second_shell_statistics`: g at the
first minimum, position and height of the second maximum).  The enthalpy is
``dH_vap = -<U_pot>/N + R T - E_pol(model)``: the ideal-gas ``pV = RT`` of the vapour and
Berendsen et al.'s (1987) self-polarisation correction
(:func:`md.water.models.polarisation_correction_kj_mol`), so that it compares with the measured
value directly (:mod:`md.water.joint_data` states what else is left out).

Self-diffusion: the robust S9 is ``D_box + xi k_B T / (6 pi eta L)`` (Yeh & Hummer 2004), with
``L`` the mean box edge over the analysed frames, ``T`` the protocol's temperature and ``eta``
the model's viscosity (:func:`md.water.finite_size.model_viscosity_mpa_s`); the uncorrected
value and the shift are in :class:`ModelOutput`.  ``finite_size_correction=False`` turns it off.
"""

from __future__ import annotations

import functools
import inspect
import os
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any, NamedTuple
from typing import Protocol as TypingProtocol

import numpy as np

from jaxabc.errors import SimulationFailure
from jaxabc.executors.cache import RunCache, source_digest
from md.water.analysis import WaterCurves, compute_curves, load_trajectory
from md.water.finite_size import correct_diffusion, model_viscosity_mpa_s

# Private helpers of the frozen runner, reused so that the 3-site path fails exactly as the
# 4-site one does (same timeouts, exit-status and NaN-energy checks).
from md.water.gromacs import (
    GromacsRun,
    TIP4PParameters,
    _check_log_energies,
    _gmx_data_dir,
    _run_gmx,
    check_physical,
    mdp_text,
    run_gromacs,
)
from md.water.models import (
    WaterModel,
    get_model,
    polarisation_correction_kj_mol,
    three_site_defines,
    three_site_topology_text,
)
from md.water.protocol import Protocol
from md.water.simulator import OBSERVED_KINDS, TIP4PSimulator
from md.water.statistics import SECOND_SHELL_NAMES, second_shell_statistics, summary_statistics

__all__ = [
    "JOINT_SUMMARY_NAMES",
    "CachedSummaries",
    "ModelOutput",
    "ModelRunner",
    "WaterModelSimulator",
    "make_model_simulator",
    "simulation_code_digest",
]

#: Names of the joint summaries, in the order a call returns them.
JOINT_SUMMARY_NAMES: tuple[str, ...] = (
    *(f"S{i}" for i in range(1, 10)),
    "density_kg_m3",
    "hvap_kj_mol",
    *SECOND_SHELL_NAMES,
)
_LEGACY_NUM_SUMMARIES = 11
#: The modules of ``md/water`` whose code makes a simulation's summaries: a cached simulation is
#: replayed only for the same code (:attr:`CachedSummaries.cache`).
_SIMULATION_CODE = (
    "analysis.py",
    "finite_size.py",
    "gromacs.py",
    "joint_data.py",
    "model_simulator.py",
    "models.py",
    "protocol.py",
    "simulator.py",
    "statistics.py",
    "topology.py",
)


@functools.cache
def simulation_code_digest(runner_source: str | None = None) -> str:
    """16 hex digits of the code that makes a water simulation's summaries: the modules of
    :data:`_SIMULATION_CODE` and ``runner_source`` (the file of the simulator's own class, such
    as :mod:`md.water.joint_criticism` for a model with effects).  Read once per process."""
    here = Path(__file__).resolve().parent
    files = {here / name for name in _SIMULATION_CODE}
    if runner_source is not None:
        files.add(Path(runner_source).resolve())
    return source_digest(*sorted(files))[:16]


#: Molar gas constant (kJ/mol/K).
GAS_CONSTANT_KJ_MOL_K = 8.314462618e-3


class ModelOutput(NamedTuple):
    """One simulation of a water model.

    Attributes
    ----------
    statistics : np.ndarray, shape (9,)
        S1..S9, unobserved entries not zeroed; S9 finite-size corrected (when enabled).
    density_kg_m3 : float
    potential_kj_mol : float
        Mean potential energy per molecule over the analysed frames.
    hvap_kj_mol : float
        ``-potential_kj_mol + R T - E_pol``.
    curves : WaterCurves
    run : GromacsRun
    second_shell : np.ndarray, shape (3,)
        ``[g_OO at the first minimum, r (nm) and g of the second maximum]``.
    finite_size : dict
        The Yeh-Hummer correction applied to S9: ``d_box`` (uncorrected S9), ``shift``,
        ``box_nm``, ``viscosity_mpa_s``, ``temperature_k`` (``shift`` 0.0 when disabled).
    """

    statistics: np.ndarray
    density_kg_m3: float
    potential_kj_mol: float
    hvap_kj_mol: float
    curves: WaterCurves
    run: GromacsRun
    second_shell: np.ndarray | None = None
    finite_size: dict | None = None


def _mean_potential(run: GromacsRun, gmx: str, start_ps: float, deadline: float) -> float:
    """Mean total potential energy (kJ/mol, whole box) from ``gmx energy`` after ``start_ps``."""
    xvg = run.workdir / "potential.xvg"
    remaining = deadline - time.monotonic()
    if remaining <= 0:
        raise SimulationFailure("timeout: no time left for `gmx energy`")
    done = subprocess.run(
        [gmx, "energy", "-f", run.energy.name, "-o", xvg.name, "-b", repr(start_ps)],
        input="Potential\n\n",
        text=True,
        cwd=run.workdir,
        capture_output=True,
        timeout=remaining,
        env=dict(os.environ, GMX_MAXBACKUP="-1"),
    )
    if done.returncode != 0 or not xvg.is_file():
        raise SimulationFailure(f"`gmx energy` exited with status {done.returncode}: {done.stdout[-400:]}")
    table = np.loadtxt(xvg, comments=["#", "@"], ndmin=2)
    if table.shape[0] == 0 or not np.all(np.isfinite(table[:, 1])):
        raise SimulationFailure("`gmx energy` gave no finite potential energy in the analysis window")
    return float(np.mean(table[:, 1]))


def run_gromacs_three_site(
    model: WaterModel,
    protocol: Protocol,
    workdir: Path,
    gen_seed: int,
    ld_seed: int,
    gmx: str,
) -> GromacsRun:
    """:func:`md.water.gromacs.run_gromacs` for a 3-site model, starting from ``spc216.gro``.

    ``protocol.expected_molecules`` is checked only for the copied 216-molecule box: ``gmx
    solvate`` from ``spc216.gro`` fills a box with another count than from ``tip4p.gro``.

    Raises
    ------
    jaxabc.errors.SimulationFailure
        As ``run_gromacs``.
    """
    start = time.monotonic()
    deadline = start + protocol.timeout_s
    source = _gmx_data_dir(gmx) / "spc216.gro"
    if protocol.box_nm is None:
        shutil.copyfile(source, workdir / "conf.gro")
    else:
        box = repr(protocol.box_nm)
        _run_gmx([gmx, "solvate", "-cs", str(source), "-box", box, box, box, "-o", "conf.gro"], workdir, deadline)
    num_atoms = int((workdir / "conf.gro").read_text().splitlines()[1])
    if num_atoms % 3:
        raise SimulationFailure(f"conf.gro has {num_atoms} atoms, not a multiple of 3")
    num_molecules = num_atoms // 3
    if protocol.box_nm is None and protocol.expected_molecules not in (None, num_molecules):
        raise RuntimeError(f"spc216.gro holds {num_molecules} molecules, preset expects {protocol.expected_molecules}")
    (workdir / "topol.top").write_text(three_site_topology_text(num_molecules, model))
    # The frozen mdp_text writes the TIP4P define line; everything else (cut-offs, PME,
    # thermostat, barostat, EM step) must stay identical across models, so only that line changes.
    for stage, seeds in (("em", (1, 1)), ("npt", (gen_seed, ld_seed))):
        lines = mdp_text(protocol, TIP4PParameters(), stage, *seeds).splitlines()
        lines = [f"{'define':<26}= {three_site_defines(model)}" if ln.startswith("define ") else ln for ln in lines]
        (workdir / f"{stage}.mdp").write_text("\n".join(lines) + "\n")
    threads = ["-ntmpi", "1", "-ntomp", "1", "-pin", "off"]
    _run_gmx([gmx, "grompp", "-f", "em.mdp", "-c", "conf.gro", "-p", "topol.top", "-o", "em.tpr"], workdir, deadline)
    _run_gmx([gmx, "mdrun", "-deffnm", "em", *threads], workdir, deadline)
    _run_gmx(
        [gmx, "grompp", "-f", "npt.mdp", "-c", "em.gro", "-p", "topol.top", "-o", "npt.tpr", "-maxwarn", "1"],
        workdir,
        deadline,
    )
    _run_gmx([gmx, "mdrun", "-deffnm", "npt", *threads], workdir, deadline)
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


class WaterModelSimulator(TIP4PSimulator):
    """Picklable ``simulate(key, theta) -> np.ndarray (14,)`` for one published water model.

    Parameters
    ----------
    model : WaterModel or str
        E.g. ``"SPC/E"`` or :data:`md.water.models.MODELS` ``["TIP4P/2005"]``; everything but
        the oxygen Lennard-Jones pair is held at the model's published values.
    preset, statistics, observed_kind, gmx, **protocol_overrides
        As for :class:`md.water.simulator.TIP4PSimulator`.

    Notes
    -----
    ``theta`` must hold exactly ``(sigma_OO nm, epsilon_OO kJ/mol)``.  Failures raise
    :class:`jaxabc.errors.SimulationFailure` with the reasons of ``TIP4PSimulator``, plus a
    failed ``gmx energy``.
    """

    def __init__(
        self,
        model: WaterModel | str,
        preset: str | Protocol = "quick",
        statistics: str = "robust",
        observed_kind: str = "simulated",
        gmx: str | None = None,
        finite_size_correction: bool = True,
        **protocol_overrides,
    ) -> None:
        self.model = get_model(model)
        self.finite_size_correction = bool(finite_size_correction)
        base = self.model.tip4p_parameters() if self.model.num_sites == 4 else None
        super().__init__(preset, statistics, observed_kind, gmx, base_parameters=base, **protocol_overrides)

    def __repr__(self) -> str:
        return (
            f"WaterModelSimulator(model={self.model.name!r}, preset={self.protocol.name!r}, "
            f"statistics={self.statistics!r}, observed_kind={self.observed_kind!r}, "
            f"finite_size_correction={self.finite_size_correction!r}, summaries={len(JOINT_SUMMARY_NAMES)})"
        )

    def parameters(self, theta) -> TIP4PParameters:
        """TIP4P-topology parameters for ``theta = (sigma_OO, epsilon_OO)`` (see the class)."""
        theta = np.asarray(theta, dtype=np.float64).reshape(-1)
        if theta.size != 2:
            raise ValueError(
                f"{self.model.name}: theta must be (sigma_OO nm, epsilon_OO kJ/mol), got {theta.size} numbers"
            )
        return super().parameters(theta)

    def model_for(self, theta) -> WaterModel:
        """The model with ``theta``'s Lennard-Jones pair."""
        params = self.parameters(theta)
        return self.model.with_lj(params.sigma_ow_nm, params.epsilon_ow_kj_mol)

    def _run_in(self, workdir: Path, params, gen_seed: int, ld_seed: int) -> ModelOutput:  # type: ignore[override]
        model = self.model.with_lj(params.sigma_ow_nm, params.epsilon_ow_kj_mol)
        start = time.monotonic()
        if model.num_sites == 4:
            run = run_gromacs(params, self.protocol, workdir, gen_seed, ld_seed, gmx=self.gmx)
        else:
            run = run_gromacs_three_site(model, self.protocol, workdir, gen_seed, ld_seed, self.gmx)
        try:
            trajectory = load_trajectory(
                run.trajectory, start_ps=self.protocol.analysis_start_ps, sites_per_molecule=model.num_sites
            )
        except (OSError, ValueError) as error:
            raise SimulationFailure(f"unreadable trajectory: {error}") from error
        density = check_physical(trajectory.box_nm, run.num_molecules, self.protocol)
        curves = compute_curves(trajectory, self.statistics, density_kg_m3=density)
        statistics = summary_statistics(curves, self.statistics)
        if not np.all(np.isfinite(statistics)):
            bad = [f"S{i + 1}" for i in np.flatnonzero(~np.isfinite(statistics))]
            raise SimulationFailure(f"no first peak/minimum found for {', '.join(bad)} (density {density:.4g} kg/m3)")
        deadline = start + self.protocol.timeout_s
        potential = _mean_potential(run, self.gmx, self.protocol.analysis_start_ps, deadline) / run.num_molecules
        rt = GAS_CONSTANT_KJ_MOL_K * self.protocol.temperature_k
        hvap = -potential + rt - polarisation_correction_kj_mol(model)
        second_shell = np.asarray(second_shell_statistics(curves.r_oo_nm, curves.g_oo), np.float64)
        if not np.all(np.isfinite(second_shell)):
            raise SimulationFailure(f"no second-shell summaries of g_OO (density {density:.4g} kg/m3)")
        statistics, finite_size = self._finite_size(statistics, trajectory.box_nm)
        return ModelOutput(statistics, density, potential, hvap, curves, run, second_shell, finite_size)

    def _finite_size(self, statistics: np.ndarray, box_nm: np.ndarray) -> tuple[np.ndarray, dict]:
        """S9 with the Yeh-Hummer correction (see the module docstring) and its record."""
        temperature = float(self.protocol.temperature_k)
        edge = float(np.mean(np.cbrt(np.prod(np.asarray(box_nm, np.float64), axis=1))))
        eta = model_viscosity_mpa_s(self.model, temperature)
        d_box = float(statistics[8])
        record = {"d_box": d_box, "shift": 0.0, "box_nm": edge, "viscosity_mpa_s": eta, "temperature_k": temperature}
        if not self.finite_size_correction:
            return statistics, record
        _, shift = correct_diffusion(d_box, edge, eta, temperature)
        # robust S9 is D in 1e-5 cm^2/s; paper S9 is the MSD slope 6 D in nm^2/ps (1e-5 cm^2/s = 1e-3 nm^2/ps).
        statistics = statistics.copy()
        statistics[8] = d_box + (shift if self.statistics == "robust" else 6.0 * shift * 1e-3)
        record["shift"] = shift
        return statistics, record

    def run(self, key, theta, keep_directory: str | os.PathLike | None = None) -> ModelOutput:  # type: ignore[override]
        """Simulate and analyse; see :meth:`TIP4PSimulator.run`.

        Raises
        ------
        jaxabc.errors.SimulationFailure
        """
        return super().run(key, theta, keep_directory)  # type: ignore[return-value]

    def __call__(self, key, theta) -> np.ndarray:
        """Joint summaries, shape (14,), float64, in :data:`JOINT_SUMMARY_NAMES` order."""
        out = self.run(key, theta)
        statistics = np.where(OBSERVED_KINDS[self.observed_kind], out.statistics, 0.0)
        second_shell = np.asarray(out.second_shell if out.second_shell is not None else np.full(3, np.nan), np.float64)
        return np.concatenate([statistics, [out.density_kg_m3, out.hvap_kj_mol], second_shell])


def make_model_simulator(model: WaterModel | str, preset: str | Protocol = "quick", **options) -> WaterModelSimulator:
    """Build :class:`WaterModelSimulator`; raises ``GromacsNotFoundError`` if ``gmx`` is missing."""
    return WaterModelSimulator(model, preset, **options)


class ModelRunner(TypingProtocol):
    """What :class:`CachedSummaries` needs of a simulator: :class:`WaterModelSimulator`, or
    :class:`md.water.joint_criticism.WaterModelWithEffects`."""

    model: WaterModel
    protocol: Any

    def __call__(self, key: Any, theta: Any, /) -> np.ndarray: ...


class CachedSummaries:
    """Picklable ``simulate(key, theta)`` returning the ``fitted`` joint summaries, with a disk cache.

    Every simulation's full output (all 14 joint summaries, or its failure reason) is stored in
    ``cache_dir`` by a :class:`jaxabc.executors.cache.RunCache` (see :attr:`cache`), keyed on
    the simulator (model, preset, protocol), the key and theta, so that (a) a rerun with the same
    seed after an interruption replays finished simulations instead of repeating them, and (b)
    held-out summaries stay available for criticism (:meth:`full`).  This class only selects the
    fitted summaries: storing, replaying and what is cached (summaries and
    :class:`~jaxabc.errors.SimulationFailure`, not crashes or timeouts) are ``RunCache``'s.

    Parameters
    ----------
    simulate : WaterModelSimulator or ModelRunner
        Returns the 14 joint summaries; ``model`` and ``protocol`` name it in the cache.
    fitted : array_like of bool, shape (14,)
        Which joint summaries the call returns (the distance sees only these); a mask of
        shape (11,) (before the second-shell summaries) is padded with False.
    cache_dir : path-like, optional
        Created if missing; no caching when None.
    """

    def __init__(self, simulate: ModelRunner, fitted, cache_dir: str | os.PathLike | None = None) -> None:
        fitted = np.asarray(fitted, dtype=bool)
        if fitted.shape == (_LEGACY_NUM_SUMMARIES,):
            # A mask over the 11 summaries before the second shell was appended (S1..S9,
            # density, hvap): the same positions, the second shell not returned.
            fitted = np.concatenate([fitted, np.zeros(len(JOINT_SUMMARY_NAMES) - _LEGACY_NUM_SUMMARIES, bool)])
        if fitted.shape != (len(JOINT_SUMMARY_NAMES),) or not fitted.any():
            raise ValueError(f"fitted must be a boolean mask of shape ({len(JOINT_SUMMARY_NAMES)},) with a True entry")
        # These three attributes are what jaxabc.checkpoint.describe_callable sees of this
        # object (checkpoint fingerprints): the RunCache is built from them, not stored.
        self.simulate = simulate
        self.fitted = fitted
        self.cache_dir = None if cache_dir is None else Path(cache_dir)
        if self.cache_dir is not None:
            self.cache_dir.mkdir(parents=True, exist_ok=True)

    def __repr__(self) -> str:
        return f"CachedSummaries({self.simulate!r}, fitted={self.fitted.astype(int).tolist()})"

    @property
    def cache(self) -> RunCache | None:
        """The :class:`~jaxabc.executors.cache.RunCache` of ``simulate`` in ``cache_dir`` (None
        without a cache).

        Its identity is ``repr((simulate, simulate.protocol))`` and the digest of the code that
        makes the summaries (:func:`simulation_code_digest`): a simulation cached by other code
        (an edited analysis, an upgrade between sittings) is run again, never replayed.  Files
        are named ``<model slug>-<digest>.npz``.
        """
        if self.cache_dir is None:
            return None
        code = simulation_code_digest(inspect.getsourcefile(type(self.simulate)))
        identity = repr((self.simulate, self.simulate.protocol)) + f" code {code}"
        return RunCache(self.simulate, self.cache_dir, identity=identity, prefix=f"{self.simulate.model.slug}-")

    def cache_path(self, key, theta) -> Path | None:
        """The cache file of one simulation (None without a cache)."""
        cache = self.cache
        return None if cache is None else cache.path(key, theta)

    def full(self, key, theta) -> np.ndarray:
        """All 14 joint summaries (from the cache when present).

        Raises
        ------
        jaxabc.errors.SimulationFailure
            The simulation failed (now or when it was cached), with its reason.
        """
        cache = self.cache
        return np.asarray((self.simulate if cache is None else cache)(key, theta))

    def __call__(self, key, theta) -> np.ndarray:
        """The fitted summaries, shape ``(fitted.sum(),)``."""
        summaries = self.full(key, theta)
        mask = self.fitted
        if summaries.size < mask.size and not mask[summaries.size :].any():
            mask = mask[: summaries.size]  # a simulator of the 11 summaries before the second shell
        return summaries[mask]
