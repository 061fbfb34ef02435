"""The host-side simulator ``simulate(key, theta) -> S1..S9`` for TIP4P water with GROMACS.

``make_simulator`` returns an instance of the top-level class :class:`TIP4PSimulator`, so a
process pool can pickle it and send it to its workers.  Each call:

1. derives GROMACS's ``gen_seed`` and ``ld_seed`` from the particle's JAX key
   (:func:`jaxabc.seeding.seeds_from_key`), so a rerun with the same key is identical;
2. runs solvate / minimisation / NPT in a fresh temporary directory with one single-threaded
   ``gmx mdrun`` (:func:`md.water.gromacs.run_gromacs`), removed afterwards;
3. reads the XTC (mdtraj), rejects vaporised or collapsed runs
   (:func:`md.water.gromacs.check_physical`), computes g_OO, g_OH and the oxygen MSD in JAX
   (:func:`md.water.analysis.compute_curves`) and S1..S9 (:mod:`md.water.statistics`).

Failures (non-zero exit, killed, timeout, NaN energies, vapour, collapse, a box below twice the
cut-off, curves without a first peak and minimum) raise :class:`jaxabc.errors.SimulationFailure`
with the reason; the core's executors record it as a failed particle (distance ``+inf``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxabc.errors import SimulationFailure
from md.water.analysis import WaterCurves, compute_curves, load_trajectory
from md.water.gromacs import (
    GromacsRun,
    Protocol,
    TIP4PParameters,
    check_physical,
    find_gmx,
    get_protocol,
    run_gromacs,
    seeds_for_key,
    temporary_run_directory,
)
from md.water.statistics import VARIANTS, summary_statistics

__all__ = ["OBSERVED_KINDS", "SimulationOutput", "TIP4PSimulator", "make_simulator"]

#: Which statistics each kind of observed data measures (True = used).  X-ray data give only
#: g_OO (and a literature diffusion coefficient), so S1..S3 are not observed.
OBSERVED_KINDS: dict[str, np.ndarray] = {
    "simulated": np.ones(9, dtype=bool),
    "neutron": np.ones(9, dtype=bool),
    "xray": np.array([False, False, False, True, True, True, True, True, True]),
}


class SimulationOutput(NamedTuple):
    """Everything one simulation produced, for model criticism.

    Attributes
    ----------
    statistics : np.ndarray, shape (9,)
        S1..S9 (unobserved entries are *not* zeroed here).
    curves : WaterCurves
    run : GromacsRun
        File paths are only valid if the run was kept (``keep_directory``).
    """

    statistics: np.ndarray
    curves: WaterCurves
    run: GromacsRun


class TIP4PSimulator:
    """Picklable ``simulate(key, theta) -> np.ndarray (9,)`` running GROMACS TIP4P water.

    Parameters
    ----------
    preset : str or Protocol
        ``"quick"`` (216 molecules, 20 ps) or ``"paper"`` (515 molecules, 100 ps), see
        :data:`md.water.gromacs.PRESETS`.
    statistics : {"robust", "paper"}
        Variant of S1..S9 (:mod:`md.water.statistics`); it also selects how the curves are
        computed (intermolecular g_OH or not, see :func:`md.water.analysis.compute_curves`).
    observed_kind : {"simulated", "neutron", "xray"}
        For ``"xray"`` the unobserved S1..S3 are returned as 0.0 (and
        :func:`md.water.datasets.observed_statistics` puts 0.0 there too), so the 9-vector
        contract holds and they add nothing to a mean absolute distance.  That distance is then
        6/9 of the paper's six-statistic mean, a constant factor.
    gmx : str, optional
        GROMACS executable; checked now, so a missing ``gmx`` fails before any sampling.
    base_parameters : TIP4PParameters
        Everything not in theta (charges, M-site distance) comes from here.
    **protocol_overrides
        Fields of :class:`md.water.gromacs.Protocol` to change, e.g. ``num_steps=2000``.
    """

    def __init__(
        self,
        preset: str | Protocol = "quick",
        statistics: str = "robust",
        observed_kind: str = "simulated",
        gmx: str | None = None,
        base_parameters: TIP4PParameters | None = None,
        **protocol_overrides,
    ) -> None:
        if statistics not in VARIANTS:
            raise ValueError(f"statistics must be one of {VARIANTS}, got {statistics!r}")
        if observed_kind not in OBSERVED_KINDS:
            raise ValueError(f"observed_kind must be one of {sorted(OBSERVED_KINDS)}, got {observed_kind!r}")
        self.protocol = get_protocol(preset, **protocol_overrides)
        self.statistics = statistics
        self.observed_kind = observed_kind
        self.gmx = find_gmx(gmx)
        self.base_parameters = base_parameters or TIP4PParameters()

    def __repr__(self) -> str:
        return (
            f"TIP4PSimulator(preset={self.protocol.name!r}, statistics={self.statistics!r}, "
            f"observed_kind={self.observed_kind!r}, gmx={self.gmx!r})"
        )

    #: What theta holds, in order; the paper calibrates the first two.  Later issues may pass
    #: three or four entries to vary the charges (q_M = -2 q_H) and the M-site distance.
    THETA_NAMES = ("sigma_ow_nm", "epsilon_ow_kj_mol", "charge_h_e", "om_distance_nm")

    def parameters(self, theta) -> TIP4PParameters:
        """Force-field parameters for ``theta = (sigma_OW nm, epsilon_OW kJ/mol[, q_H e[,
        d_OM nm]])``; entries not in theta come from ``base_parameters``."""
        theta = np.asarray(theta, dtype=np.float64).reshape(-1)
        if not 2 <= theta.size <= 4 or not np.all(np.isfinite(theta)):
            raise ValueError(
                "theta must hold 2 to 4 finite numbers (sigma_OW nm, epsilon_OW kJ/mol[, q_H e"
                f"[, d_OM nm]]), got {theta}"
            )
        values = {
            name: getattr(self.base_parameters, name)
            for name in (*self.THETA_NAMES, "oh_distance_nm", "hh_distance_nm")
        }
        values.update({name: float(v) for name, v in zip(self.THETA_NAMES, theta, strict=False)})
        return TIP4PParameters(**values)

    def run(self, key, theta, keep_directory: str | os.PathLike | None = None) -> SimulationOutput:
        """Simulate and analyse; return statistics, curves and run record.

        Parameters
        ----------
        key : array_like
            JAX PRNG key (raw ``uint32[2]`` or typed).
        theta : array_like, shape (2,)
        keep_directory : path-like, optional
            Run in this (existing, empty) directory and keep the files; default: a temporary
            directory removed on return.

        Raises
        ------
        jaxabc.errors.SimulationFailure
        """
        params = self.parameters(theta)
        gen_seed, ld_seed = seeds_for_key(key)
        if keep_directory is not None:
            return self._run_in(Path(keep_directory), params, gen_seed, ld_seed)
        with temporary_run_directory() as workdir:
            return self._run_in(Path(workdir), params, gen_seed, ld_seed)

    def _run_in(self, workdir: Path, params, gen_seed: int, ld_seed: int) -> SimulationOutput:
        run = run_gromacs(params, self.protocol, workdir, gen_seed, ld_seed, gmx=self.gmx)
        try:
            trajectory = load_trajectory(run.trajectory, start_ps=self.protocol.analysis_start_ps)
        except (OSError, ValueError) as error:
            raise SimulationFailure(f"unreadable trajectory: {error}") from error
        density = check_physical(trajectory.box_nm, run.num_molecules, self.protocol)
        curves = compute_curves(trajectory, self.statistics, density_kg_m3=density)
        statistics = summary_statistics(curves, self.statistics)
        if not np.all(np.isfinite(statistics)):
            bad = [f"S{i + 1}" for i in np.flatnonzero(~np.isfinite(statistics))]
            raise SimulationFailure(f"no first peak/minimum found for {', '.join(bad)} (density {density:.4g} kg/m3)")
        return SimulationOutput(statistics, curves, run)

    def __call__(self, key, theta) -> np.ndarray:
        """S1..S9 for one particle; shape (9,), float64 (see :mod:`md.water.statistics`)."""
        statistics = self.run(key, theta).statistics
        return np.where(OBSERVED_KINDS[self.observed_kind], statistics, 0.0)


def make_simulator(
    preset: str | Protocol = "quick",
    statistics: str = "robust",
    observed_kind: str = "simulated",
    **options,
) -> TIP4PSimulator:
    """Build the host simulator ``simulate(key, theta) -> np.ndarray (9,)``.

    See :class:`TIP4PSimulator` for the parameters.  Raises
    :class:`md.water.gromacs.GromacsNotFoundError` (with the install command) if ``gmx`` is
    missing.

    Examples
    --------
    >>> simulate = make_simulator("quick", "robust")            # doctest: +SKIP
    >>> simulate(jax.random.PRNGKey(0), (0.315365, 0.64852))    # doctest: +SKIP
    array([...])  # shape (9,)
    """
    return TIP4PSimulator(preset, statistics, observed_kind, **options)
