"""``simulate(key, theta) -> S1..S9`` for rigid TIP4P on jax-md, pure JAX and batched by ``vmap``.

One simulation: rigid bodies fitted to the starting configuration, Nose-Hoover NVT at the
preset's temperature (velocities drawn from ``key``) in a fixed box, or NPT with the Monte
Carlo barostat of :mod:`md.water.jaxmd.npt` (``ensemble="npt"``), equilibration, then frames
every ``frame_interval_steps``; from the recorded O and H positions g_OO, the intermolecular g_OH and
the oxygen MSD are computed in JAX by the GROMACS plugin's own kernels
(:mod:`md.water.analysis`: ``_pair_histogram``, ``unwrap``, ``_msd``) and S1..S8 by the
``robust`` statistics kernels of :mod:`md.water.statistics` (their jitted array functions,
without the float64 host wrapper); S9 is D from the same least-squares window (10-50 % of the
longest lag) as :func:`md.water.analysis.fit_msd_slope`, written in JAX.  Nothing leaves the
device and no file is written.

Failures are data: :meth:`JaxWaterSimulator.pure` returns a status bitmask with the summaries
(NaN where it is not 0); the host-side ``__call__`` raises :class:`jaxabc.errors.SimulationFailure`
with the reason, as :class:`md.water.simulator.TIP4PSimulator` does, so executors record it.
In NVT the box is fixed and checked against twice the cut-off when the simulator is built; in
NPT the plugin's checks apply in JAX: mean density over the frames outside
``[min_density_kg_m3, max_density_kg_m3]`` (vapour, collapse) and a box edge proposed at twice
the cut-off are failures.

Neighbour lists (large boxes, NVT only) have a capacity fixed on the host.  A run that outgrows
it is rerun from the start with a larger list (a fixed ladder of capacities, so a simulation's
result is a function of its key and theta alone, whatever ran before); :meth:`pure` cannot
reallocate and reports ``STATUS_NEIGHBOR_OVERFLOW``, the host paths (``__call__``, :meth:`batch`)
do, and count it in ``neighbor_reallocations``.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.errors import SimulationFailure
from md.water.jaxmd.engine import STATUS_NEIGHBOR_OVERFLOW, STATUS_NONFINITE_ENERGY, Frames, RigidWater
from md.water.jaxmd.forcefield import ReactionField, WaterModel, get_model
from md.water.jaxmd.npt import STATUS_BOX_AT_CUTOFF_LIMIT, MonteCarloBarostat, density_kg_m3

__all__ = [
    "PRESETS",
    "STATUS_COLLAPSED",
    "STATUS_NO_EXTREMUM",
    "STATUS_VAPORISED",
    "JaxWaterPreset",
    "JaxWaterSimulator",
    "failure_reason",
    "lattice_configuration",
    "make_simulator",
    "summaries_from_frames",
]

#: Status bit: a g(r) had no first peak or minimum inside its search window (S1..S8 NaN).
STATUS_NO_EXTREMUM = 4
#: Status bits (NPT): mean density over the frames below / above the preset's band.
STATUS_VAPORISED = 16
STATUS_COLLAPSED = 32

_REASONS = {
    STATUS_NONFINITE_ENERGY: "non-finite energy or positions (the integration blew up)",
    STATUS_NEIGHBOR_OVERFLOW: "the neighbour list overflowed, after every reallocation",
    STATUS_NO_EXTREMUM: "no first peak/minimum of g_OO or g_OH in its search window",
    STATUS_BOX_AT_CUTOFF_LIMIT: "the barostat proposed a box edge at twice the cut-off (the box collapsed)",
    STATUS_VAPORISED: "mean density below the preset's minimum: the liquid vaporised",
    STATUS_COLLAPSED: "mean density above the preset's maximum: the liquid collapsed",
}
# 1 nm^2/ps = 1e-2 cm^2/s = 1e3 x (1e-5 cm^2/s), as in md.water.statistics.
_NM2_PER_PS_IN_1E5_CM2_PER_S = 1e3


def failure_reason(status: int) -> str:
    """The reasons a status bitmask stands for, joined; ``"ok"`` for 0."""
    reasons = [text for bit, text in _REASONS.items() if int(status) & bit]
    return "; ".join(reasons) if reasons else "ok"


@dataclasses.dataclass(frozen=True)
class JaxWaterPreset:
    """A protocol for the in-process engine (the counterpart of :class:`md.water.protocol.Protocol`).

    Attributes
    ----------
    name : str
    start : {"gromacs", "lattice"}
        ``"gromacs"``: GROMACS's equilibrated ``tip4p.gro`` (216 molecules, 1.86824 nm, the
        ``quick`` preset's start; needs GROMACS's data files).  ``"lattice"``: identical
        molecules on a simple cubic lattice at ``lattice_molecules`` and ``lattice_box_nm``
        (no GROMACS needed; it melts during equilibration).
    cutoff_nm, epsilon_rf : float
        Reaction field (:class:`~md.water.jaxmd.forcefield.ReactionField`).
    timestep_ps : float
    equilibration_steps, frame_interval_steps, num_frames : int
        Steps before the first frame, between frames, and the number of frames analysed.
    temperature_k, tau_t_ps : float
        Nose-Hoover target and time constant.
    bin_width_nm : float
        g(r) histogram bins (``gmx rdf``'s 0.002 nm).
    neighbor_list : bool or None
        See :class:`~md.water.jaxmd.engine.RigidWater` (``None``: by box size; all pairs in NPT).
    neighbor_extra_capacity : int
        Spare slots of the first neighbour list; the k-th reallocation gets
        ``(neighbor_extra_capacity + 8) 2^k - 8``.
    neighbor_reallocations : int
        How many larger lists a run that overflows is retried with before it fails.
    neighbor_capacity_multiplier : float
        jax-md's headroom over the starting occupancy.
    ensemble : {"nvt", "npt"}
        Fixed box, or the Monte Carlo barostat (:class:`~md.water.jaxmd.npt.MonteCarloBarostat`,
        all pairs, proposal width adapted in equilibration only).
    pressure_bar : float
        NPT target pressure.
    barostat_interval_steps : int
        NPT: MD steps between volume moves; must divide ``equilibration_steps`` and
        ``frame_interval_steps``.
    min_density_kg_m3, max_density_kg_m3 : float
        NPT: the band of the mean density over the frames outside which a run fails (the
        GROMACS plugin's defaults).
    """

    name: str
    start: str = "gromacs"
    lattice_molecules: int = 216
    lattice_box_nm: float = 1.86824
    cutoff_nm: float = 0.85
    epsilon_rf: float = math.inf
    timestep_ps: float = 0.002
    equilibration_steps: int = 2500
    frame_interval_steps: int = 100
    num_frames: int = 75
    temperature_k: float = 298.0
    tau_t_ps: float = 0.1
    bin_width_nm: float = 0.002
    neighbor_list: bool | None = None
    neighbor_extra_capacity: int = 6
    neighbor_reallocations: int = 3
    neighbor_capacity_multiplier: float = 1.25
    ensemble: str = "nvt"
    pressure_bar: float = 1.0
    barostat_interval_steps: int = 25
    min_density_kg_m3: float = 500.0
    max_density_kg_m3: float = 1500.0

    def __post_init__(self) -> None:
        if self.start not in ("gromacs", "lattice"):
            raise ValueError(f"start must be 'gromacs' or 'lattice', got {self.start!r}")
        if self.num_frames < 8 or self.frame_interval_steps < 1 or self.equilibration_steps < 0:
            raise ValueError("need num_frames >= 8 (the MSD fit), frame_interval_steps >= 1, equilibration_steps >= 0")
        if self.neighbor_extra_capacity < 0 or self.neighbor_reallocations < 0 or self.neighbor_capacity_multiplier < 1:
            raise ValueError(
                "need neighbor_extra_capacity >= 0, neighbor_reallocations >= 0 and neighbor_capacity_multiplier >= 1"
            )
        if self.ensemble not in ("nvt", "npt"):
            raise ValueError(f"ensemble must be 'nvt' or 'npt', got {self.ensemble!r}")
        if self.ensemble == "npt":
            interval = self.barostat_interval_steps
            if interval < 1 or self.frame_interval_steps % interval or self.equilibration_steps % interval:
                raise ValueError(
                    f"NPT: barostat_interval_steps ({interval}) must be >= 1 and divide frame_interval_steps "
                    f"({self.frame_interval_steps}) and equilibration_steps ({self.equilibration_steps})"
                )
            if self.neighbor_list:
                raise ValueError("NPT uses all pairs (the box changes): leave neighbor_list as None or False")
            if not (math.isfinite(self.pressure_bar) and 0 < self.min_density_kg_m3 < self.max_density_kg_m3):
                raise ValueError("NPT: need a finite pressure_bar and 0 < min_density_kg_m3 < max_density_kg_m3")

    @property
    def frame_interval_ps(self) -> float:
        return self.frame_interval_steps * self.timestep_ps


#: ``quick``: the GROMACS ``quick`` preset's box, cut-off, frame spacing and analysis window
#: (216 molecules from ``tip4p.gro``, 0.85 nm, frames every 0.2 ps, 5 ps equilibration then 15 ps
#: analysed), at a fixed box with reaction field instead of NPT with PME.
#: ``quick_npt``: the same at 1 bar with the Monte Carlo barostat (a volume move every 25
#: steps), like the GROMACS preset's NPT.
#: ``tiny``: for tests: the same box, 0.2 ps equilibration and 8 frames 0.1 ps apart.
PRESETS: dict[str, JaxWaterPreset] = {
    "quick": JaxWaterPreset("quick"),
    "quick_npt": JaxWaterPreset("quick_npt", ensemble="npt"),
    "tiny": JaxWaterPreset("tiny", equilibration_steps=100, frame_interval_steps=50, num_frames=8),
}


def lattice_configuration(num_molecules: int, box_nm: float, model: WaterModel) -> np.ndarray:
    """Identically oriented molecules on a simple cubic lattice; shape (num_molecules, 3, 3).

    ``num_molecules`` must be a cube (216 = 6^3).  Aligned neighbours keep every intermolecular
    site pair at least one lattice spacing minus an O-H bond apart, so the first forces are mild.
    """
    from md.water.jaxmd.forcefield import body_frame

    side = round(num_molecules ** (1 / 3))
    if side**3 != num_molecules:
        raise ValueError(f"lattice_molecules must be a cube (e.g. 216 = 6^3), got {num_molecules}")
    atoms, _, _ = body_frame(model)
    grid = (np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5) * (box_nm / side)
    return grid[:, None, :] + atoms[None]


def _start(preset: JaxWaterPreset, geometry: WaterModel, gmx: str | None) -> tuple[np.ndarray, np.ndarray]:
    if preset.start == "lattice":
        box = np.full(3, preset.lattice_box_nm)
        return lattice_configuration(preset.lattice_molecules, preset.lattice_box_nm, geometry), box
    from md.water.gromacs import _gmx_data_dir, find_gmx
    from md.water.jaxmd.reference import read_gro

    return read_gro(Path(_gmx_data_dir(find_gmx(gmx))) / "tip4p.gro")


def summaries_from_frames(
    frames: Frames,
    box_nm: jax.Array | np.ndarray,
    frame_interval_ps: float,
    bin_width_nm: float = 0.002,
    r_max_nm: float | None = None,
) -> jax.Array:
    """Robust S1..S9 of recorded frames, in JAX (traceable, vmappable).

    Parameters
    ----------
    frames : Frames
        ``oxygen_nm (num_frames, N, 3)``, ``hydrogen_nm (num_frames, 2N, 3)``, wrapped.
    box_nm : array, shape (3,) or (num_frames, 3)
        The fixed box, or each frame's (NPT; the g(r) normalisation sums 1 / V over frames, as
        :func:`md.water.analysis.radial_distribution`).
    frame_interval_ps : float
        Static.
    r_max_nm : float, optional
        Static histogram range; default half the smallest edge of ``box_nm`` (then ``box_nm``
        must be concrete).  NPT passes the cut-off, below half of every frame's box.

    Returns
    -------
    jax.Array, shape (9,)
        S1..S9 as :func:`md.water.statistics.summary_statistics` with ``variant="robust"``
        (S9 = D in 1e-5 cm^2/s); NaN where a peak or minimum was not found.
    """
    from md.water import analysis, statistics

    oxygen, hydrogen = frames.oxygen_nm, frames.hydrogen_nm
    num_frames, num_molecules, _ = oxygen.shape
    dtype = oxygen.dtype
    boxes = jnp.broadcast_to(jnp.asarray(box_nm, dtype), (num_frames, 3))
    molecules = jnp.arange(num_molecules)
    if r_max_nm is None:
        r_max_nm = 0.5 * float(np.min(np.asarray(box_nm)))
    num_bins = math.floor(r_max_nm / bin_width_nm + 1e-9)
    edges = bin_width_nm * np.arange(num_bins + 1, dtype=np.float64)
    shell = jnp.asarray(4.0 / 3.0 * np.pi * np.diff(edges**3), dtype)
    centres = jnp.asarray(0.5 * (edges[1:] + edges[:-1]), dtype)
    inverse_volume_sum = jnp.sum(1.0 / jnp.prod(boxes, axis=1))

    def rdf(positions_b, molecule_b, num_pairs):
        counts = analysis._pair_histogram(
            oxygen,
            positions_b,
            boxes,
            molecules,
            molecule_b,
            jnp.asarray(bin_width_nm, dtype),
            jnp.asarray(0.0, dtype),
            num_bins,
            num_frames,
        )
        return counts.astype(dtype) / (num_pairs * inverse_volume_sum * shell)

    # Same estimator as analysis.radial_distribution (normalise_excluded=True): pairs in one
    # molecule excluded from the counts and from the ideal-gas normalisation.
    g_oo = rdf(oxygen, molecules, num_molecules * (num_molecules - 1))
    g_oh = rdf(hydrogen, jnp.repeat(molecules, 2), num_molecules * 2 * (num_molecules - 1))
    # The jitted kernels under the float64/numpy host wrapper (functools.wraps keeps them).
    oh = statistics.robust_oh_statistics.__wrapped__(centres, g_oh)  # pyright: ignore[reportAttributeAccessIssue]
    oo = statistics.robust_oo_statistics.__wrapped__(centres, g_oo)  # pyright: ignore[reportAttributeAccessIssue]

    unwrapped = analysis.unwrap(oxygen, boxes)
    max_lag = num_frames - 1
    msd = analysis._msd(unwrapped, max_lag, 1, True)
    lag = frame_interval_ps * jnp.arange(max_lag + 1, dtype=dtype)
    # fit_msd_slope's default window: lags in [10 %, 50 %] of the longest lag.
    window = (lag >= 0.1 * lag[-1] - 1e-9) & (lag <= 0.5 * lag[-1] + 1e-9)
    weight = window.astype(dtype)
    mean_lag = jnp.sum(weight * lag) / jnp.sum(weight)
    mean_msd = jnp.sum(weight * msd) / jnp.sum(weight)
    slope = jnp.sum(weight * (lag - mean_lag) * (msd - mean_msd)) / jnp.sum(weight * (lag - mean_lag) ** 2)
    diffusion = slope / 6.0 * _NM2_PER_PS_IN_1E5_CM2_PER_S
    return jnp.concatenate([oh.astype(dtype), oo.astype(dtype), diffusion[None]])


class JaxWaterSimulator:
    """``simulate(key, theta) -> np.ndarray (9,)`` running rigid TIP4P on jax-md in process.

    The same interface as :class:`md.water.simulator.TIP4PSimulator` (``theta = (sigma_OW nm,
    epsilon_OW kJ/mol[, q_H e[, d_OM nm]])``, failures raised as ``SimulationFailure``), plus
    the pure form :meth:`pure` and the batched form :meth:`batch`.

    Parameters
    ----------
    preset : str or JaxWaterPreset
        ``"quick"``, ``"quick_npt"`` or ``"tiny"`` (see :data:`PRESETS`).
    statistics : {"robust"}
        Only the robust variant: the ``paper`` variant needs ``gmx rdf``'s intramolecular g_OH.
    observed_kind : {"simulated", "neutron", "xray"}
        As for the GROMACS simulator (``"xray"`` zeroes S1..S3).
    model : str or WaterModel
        Everything not in theta (charges, geometry) comes from it; default TIP4P.
    dtype : jnp.float32 or jnp.float64
        float64 needs ``jax.config.update("jax_enable_x64", True)``.
    gmx : str, optional
        GROMACS executable, used only to find ``tip4p.gro`` for ``start="gromacs"``.
    **preset_overrides
        Fields of :class:`JaxWaterPreset` (e.g. ``ensemble="npt"``).

    Attributes
    ----------
    neighbor_reallocations : int
        Runs rerun with a larger neighbour list so far (host paths).
    """

    THETA_NAMES = ("sigma_ow_nm", "epsilon_ow_kj_mol", "charge_h_e", "om_distance_nm")

    def __init__(
        self,
        preset: str | JaxWaterPreset = "quick",
        statistics: str = "robust",
        observed_kind: str = "simulated",
        model: str | WaterModel = "tip4p",
        dtype=jnp.float32,
        gmx: str | None = None,
        **preset_overrides,
    ) -> None:
        from md.water.simulator import OBSERVED_KINDS

        if statistics != "robust":
            raise ValueError(
                f"statistics={statistics!r}: the JAX engine computes the 'robust' variant only "
                "(use md.water.make_simulator for 'paper')"
            )
        if observed_kind not in OBSERVED_KINDS:
            raise ValueError(f"observed_kind must be one of {sorted(OBSERVED_KINDS)}, got {observed_kind!r}")
        if isinstance(preset, str):
            if preset not in PRESETS:
                raise ValueError(f"unknown preset {preset!r}; choose one of {sorted(PRESETS)} or pass a JaxWaterPreset")
            preset = PRESETS[preset]
        self.preset = dataclasses.replace(preset, **preset_overrides) if preset_overrides else preset
        self.statistics = statistics
        self.observed_kind = observed_kind
        self._observed = jnp.asarray(OBSERVED_KINDS[observed_kind])
        self.base_model = get_model(model)
        self.dtype = dtype
        p = self.preset
        npt = p.ensemble == "npt"
        atoms, box = _start(p, self.base_model, gmx)
        self.engine = RigidWater(
            atoms.shape[0],
            box,
            self.base_model,
            ReactionField(p.cutoff_nm, p.epsilon_rf),
            dt_ps=p.timestep_ps,
            neighbor_list=False if npt else p.neighbor_list,
            dtype=dtype,
            capacity_multiplier=p.neighbor_capacity_multiplier,
        )
        self.barostat = None
        if npt:
            self.barostat = MonteCarloBarostat(
                self.engine, p.pressure_bar, p.temperature_k, p.barostat_interval_steps, tau_t_ps=p.tau_t_ps
            )
        # g(r) range: half the fixed box in NVT; in NPT the cut-off, which the barostat keeps
        # below half of every box edge.
        self._r_max_nm = p.cutoff_nm if npt else 0.5 * float(np.min(box))
        self.initial_body = self.engine.bodies(atoms, box)
        self._neighbor_ladder: dict[int, Any] = {}
        self.initial_neighbors = self._neighbors(0)
        self.neighbor_reallocations = 0
        self._batch = jax.jit(jax.vmap(self.pure, in_axes=(0, 0, None)))
        # The host path runs the trajectory and the analysis as two compiled programs, so code
        # that needs only the frames (checks, criticism) reuses the first.
        self._frames = jax.jit(self.frames)
        self._finish = jax.jit(self.finish)

    def __repr__(self) -> str:
        return (
            f"JaxWaterSimulator(preset={self.preset.name!r}, ensemble={self.preset.ensemble!r}, "
            f"observed_kind={self.observed_kind!r}, molecules={self.engine.num_molecules}, "
            f"neighbor_list={self.engine.use_neighbor_list})"
        )

    def model(self, theta: jax.Array) -> WaterModel:
        """The force field for ``theta`` (traced entries allowed); the rest from ``model``."""
        base = WaterModel(*(jnp.asarray(v, self.dtype) for v in self.base_model))
        return base.with_theta(jnp.asarray(theta, self.dtype))

    def _neighbors(self, level: int) -> Any:
        """The neighbour list of reallocation ``level`` (host; None without a list)."""
        if level not in self._neighbor_ladder:
            extra = (self.preset.neighbor_extra_capacity + 8) * 2**level - 8
            self._neighbor_ladder[level] = self.engine.allocate_neighbors(self.initial_body, extra_capacity=extra)
        return self._neighbor_ladder[level]

    def frames(self, key: jax.Array, theta: jax.Array, neighbor=None) -> tuple[Frames, jax.Array]:
        """The recorded frames and the engine's status for one parameter vector (pure JAX).

        ``neighbor``: the list to run with (default the first of the ladder).
        """
        p = self.preset
        if self.barostat is not None:
            interval = p.barostat_interval_steps
            return self.barostat.run_frames(
                key,
                self.model(theta),
                self.initial_body,
                p.equilibration_steps // interval,
                p.num_frames,
                p.frame_interval_steps // interval,
            )
        return self.engine.run_nvt(
            key,
            self.model(theta),
            self.initial_body,
            p.temperature_k,
            num_frames=p.num_frames,
            steps_per_frame=p.frame_interval_steps,
            equilibration_steps=p.equilibration_steps,
            tau_t_ps=p.tau_t_ps,
            neighbor=self.initial_neighbors if neighbor is None else neighbor,
        )

    def pure(self, key: jax.Array, theta: jax.Array, neighbor=None) -> tuple[jax.Array, jax.Array]:
        """``(summaries (9,), status ())``, pure JAX: jit it, ``vmap`` it over keys and thetas.

        Summaries are NaN where ``status != 0``; unobserved ones (``observed_kind="xray"``) are 0.
        An overflowing neighbour list is reported, not reallocated (that needs the host).
        """
        return self.finish(*self.frames(key, theta, neighbor))

    def finish(self, frames: Frames, status: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Summaries and final status of recorded frames (the second half of :meth:`pure`)."""
        p = self.preset
        if self.barostat is not None:
            density = jnp.mean(self.density_kg_m3(frames))
            status = (
                status
                | jnp.where(density < p.min_density_kg_m3, STATUS_VAPORISED, 0)
                | jnp.where(density > p.max_density_kg_m3, STATUS_COLLAPSED, 0)
            )
        summaries = summaries_from_frames(frames, frames.box_nm, p.frame_interval_ps, p.bin_width_nm, self._r_max_nm)
        no_extremum = ~jnp.all(jnp.isfinite(summaries))
        status = status | jnp.where(no_extremum & (status == 0), STATUS_NO_EXTREMUM, 0)
        summaries = jnp.where(status == 0, summaries, jnp.nan)
        return jnp.where(self._observed, summaries, 0.0), status.astype(jnp.int32)

    def density_kg_m3(self, frames: Frames) -> jax.Array:
        """Mass density of each frame (kg/m^3), shape (num_frames,)."""
        return density_kg_m3(jnp.prod(frames.box_nm, axis=-1), self.engine.num_molecules)

    def _run_host(self, keys: jax.Array, thetas: jax.Array) -> tuple[np.ndarray, np.ndarray]:
        """Batched runs, each rerun up the neighbour-list ladder while it overflows."""
        summaries, status = (np.asarray(a) for a in self._batch(keys, thetas, self._neighbors(0)))
        summaries, status = np.array(summaries, np.float64), np.array(status)
        for level in range(1, self.preset.neighbor_reallocations + 1):
            redo = np.flatnonzero(status & STATUS_NEIGHBOR_OVERFLOW) if self.engine.use_neighbor_list else []
            if len(redo) == 0:
                break
            self.neighbor_reallocations += len(redo)
            again, again_status = self._batch(keys[redo], thetas[redo], self._neighbors(level))
            summaries[redo], status[redo] = np.asarray(again, np.float64), np.asarray(again_status)
        return summaries, status

    def batch(self, keys: jax.Array, thetas: jax.Array) -> tuple[np.ndarray, np.ndarray]:
        """Many parameter vectors at once (one compiled ``vmap``).

        Parameters
        ----------
        keys : array, shape (b, 2) or typed keys (b,)
        thetas : array, shape (b, d), 2 <= d <= 4

        Returns
        -------
        summaries : np.ndarray, shape (b, 9)
        status : np.ndarray of int32, shape (b,)
            0 where fine; else bits (see :func:`failure_reason`).  Members whose neighbour
            list overflowed are rerun with larger lists first.
        """
        thetas = jnp.asarray(thetas, self.dtype)
        if thetas.ndim != 2 or not 2 <= thetas.shape[1] <= 4:
            raise ValueError(f"thetas must have shape (batch, 2..4), got {thetas.shape}")
        return self._run_host(jnp.asarray(keys), thetas)

    def simulate_batch(self, keys: jax.Array, thetas: jax.Array) -> tuple[np.ndarray, np.ndarray]:
        """``(summaries (b, 9), ok (b,))``: :meth:`batch` in the form ``jaxabc``'s vmap executor calls.

        With ``executor=jaxabc.VmapExecutor()`` every algorithm runs a population as one
        compiled batch (with neighbour-list reallocation); the failure bits behind ``ok`` are in
        :meth:`batch`'s status, and the host path (``__call__``) raises with the reason.
        """
        summaries, status = self.batch(keys, thetas)
        return summaries, status == 0

    def __call__(self, key: jax.Array, theta) -> np.ndarray:
        """S1..S9 for one particle, shape (9,), float64; raises SimulationFailure with the reason."""
        theta = np.asarray(theta, dtype=np.float64).reshape(-1)
        if not 2 <= theta.size <= 4 or not np.all(np.isfinite(theta)):
            raise ValueError(
                "theta must hold 2 to 4 finite numbers (sigma_OW nm, epsilon_OW kJ/mol[, q_H e"
                f"[, d_OM nm]]), got {theta}"
            )
        theta_j = jnp.asarray(theta, self.dtype)
        for level in range(self.preset.neighbor_reallocations + 1):
            summaries, status = self._finish(*self._frames(jnp.asarray(key), theta_j, self._neighbors(level)))
            if not (self.engine.use_neighbor_list and int(status) & STATUS_NEIGHBOR_OVERFLOW):
                break
            if level < self.preset.neighbor_reallocations:
                self.neighbor_reallocations += 1
        if int(status):
            raise SimulationFailure(f"{failure_reason(int(status))} (theta={theta.tolist()})")
        return np.asarray(summaries, np.float64)


def make_simulator(
    preset: str | JaxWaterPreset = "quick",
    statistics: str = "robust",
    observed_kind: str = "simulated",
    **options,
) -> JaxWaterSimulator:
    """Build the in-process simulator; see :class:`JaxWaterSimulator`.

    Examples
    --------
    >>> simulate = make_simulator("quick")                            # doctest: +SKIP
    >>> simulate(jax.random.PRNGKey(0), (0.315365, 0.64852))          # doctest: +SKIP
    >>> summaries, status = simulate.batch(keys, thetas)              # doctest: +SKIP
    """
    return JaxWaterSimulator(preset, statistics, observed_kind, **options)
