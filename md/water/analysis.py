"""Trajectory analysis in JAX: site-site radial distribution functions and oxygen MSD.

Reading
    XTC/TRR files are read with **mdtraj** (``mdtraj.formats.XTCTrajectoryFile`` /
    ``TRRTrajectoryFile``).  Why mdtraj rather than MDAnalysis: it returns the whole trajectory as
    one ``(frames, atoms, 3)`` float32 array plus the boxes, which is exactly what the JAX kernels
    take, it needs no topology to read coordinates (our atom order is fixed by the topology we
    write: OW, HW1, HW2, MW per molecule), it installs as one wheel with few dependencies, and it
    was already the tentative dependency in ``pyproject.toml``.  MDAnalysis would add a Universe
    layer and a heavier dependency tree for nothing we use.

Radial distribution functions
    ``g_AB(r)`` is a histogram of minimum-image pair distances in an orthorhombic box, with pairs
    in the same molecule excluded (so the intermolecular ``g_OH`` has no intramolecular O-H peak
    at 0.0957 nm and ``g_OO`` no self pair).  Under NPT the box fluctuates, so each frame is
    normalised by its own ideal-gas expectation and the estimator is the ratio of sums

        g(r_k) = sum_t C_tk / sum_t [(N_A N_B - N_excluded) / V_t * shell_k],

    where ``C_tk`` counts the pairs in bin ``k`` at frame ``t`` and ``shell_k`` is the exact
    shell volume ``4/3 pi (r_{k+1}^3 - r_k^3)``.  With ``normalise_excluded=False`` the
    normalisation is ``N_A N_B`` as in ``gmx rdf`` (its documentation: "exclusions do not affect
    the normalization"), which lowers g by ``(N-1)/N`` for O-O and ``(2N-2)/2N`` for O-H.

Mean-squared displacement
    Positions are unwrapped with the scheme of von Buelow, Bullerjahn & Hummer, J. Chem. Phys.
    153, 021101 (2020), which is correct under a fluctuating box: the wrapped displacement between
    consecutive frames is minimum-imaged with the box of the later frame and accumulated.
    (``gmx msd`` is not used: GROMACS 2022.5 aborts on sub-picosecond frame spacing.)
    The MSD is averaged over all particles and over time origins every ``origin_stride`` frames,
    and the slope is a least-squares line over a stated lag window (see :func:`fit_msd_slope`).
"""

from __future__ import annotations

import math
from functools import partial
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "SITES_PER_MOLECULE",
    "WaterCurves",
    "WaterTrajectory",
    "compute_curves",
    "fit_msd_slope",
    "load_trajectory",
    "mean_squared_displacement",
    "radial_distribution",
    "rdf_oh",
    "rdf_oo",
    "unwrap",
]

#: Atoms per TIP4P molecule in the files the plugin writes: OW, HW1, HW2, MW.
SITES_PER_MOLECULE = 4


class WaterTrajectory(NamedTuple):
    """Oxygen and hydrogen positions of a TIP4P trajectory.

    Attributes
    ----------
    time_ps : np.ndarray, shape (num_frames,)
    oxygen_nm : np.ndarray, shape (num_frames, num_molecules, 3)
        Positions as written by GROMACS (wrapped into the box at neighbour-search steps).
    hydrogen_nm : np.ndarray, shape (num_frames, 2 * num_molecules, 3)
        Hydrogens of molecule ``i`` are rows ``2 i`` and ``2 i + 1``.
    box_nm : np.ndarray, shape (num_frames, 3)
        Edges of the orthorhombic box.
    """

    time_ps: np.ndarray
    oxygen_nm: np.ndarray
    hydrogen_nm: np.ndarray
    box_nm: np.ndarray

    @property
    def num_molecules(self) -> int:
        return int(self.oxygen_nm.shape[1])

    @property
    def frame_interval_ps(self) -> float:
        """Spacing of the frames (ps); they must be evenly spaced for the MSD."""
        if self.time_ps.size < 2:
            raise ValueError("a trajectory needs at least two frames for a time step")
        return float(np.median(np.diff(self.time_ps)))


def load_trajectory(
    path: str | Path,
    start_ps: float = 0.0,
    stop_ps: float | None = None,
    sites_per_molecule: int = SITES_PER_MOLECULE,
) -> WaterTrajectory:
    """Read a GROMACS XTC or TRR file of TIP4P water written by this plugin.

    Parameters
    ----------
    path : path-like
        ``.xtc`` or ``.trr``.
    start_ps, stop_ps : float
        Keep frames with ``start_ps <= t <= stop_ps`` (equilibration is discarded this way).
    sites_per_molecule : int
        Atoms per molecule in the file, O first then the two H (4 for TIP4P, 3 for SPC).

    Raises
    ------
    ValueError
        Non-orthorhombic box, atom count not a multiple of ``sites_per_molecule``, no frames.
    """
    try:
        import mdtraj.formats as mdformats
    except ImportError as exc:  # the optional `water` extra
        raise ImportError("reading GROMACS trajectories needs mdtraj: pip install 'jaxabc[water]'") from exc

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".xtc":
        with mdformats.XTCTrajectoryFile(str(path), "r") as handle:
            xyz, time, _, box = handle.read()
    elif suffix == ".trr":
        with mdformats.TRRTrajectoryFile(str(path), "r") as handle:
            xyz, time, _, box, _ = handle.read()
    else:
        raise ValueError(f"{path}: expected a .xtc or .trr file")
    if xyz.shape[0] == 0:
        raise ValueError(f"{path}: no frames")
    off_diagonal = box - np.einsum("tii->ti", box)[:, :, None] * np.eye(3)
    if np.any(np.abs(off_diagonal) > 1e-6):
        raise ValueError(f"{path}: triclinic boxes are not supported (isotropic NPT is cubic)")
    num_atoms = xyz.shape[1]
    if num_atoms % sites_per_molecule:
        raise ValueError(f"{path}: {num_atoms} atoms is not a multiple of {sites_per_molecule} sites/molecule")
    keep = time >= start_ps - 1e-6
    if stop_ps is not None:
        keep &= time <= stop_ps + 1e-6
    if not np.any(keep):
        raise ValueError(f"{path}: no frames between {start_ps} and {stop_ps} ps")
    xyz = xyz[keep].reshape(int(keep.sum()), -1, sites_per_molecule, 3)
    return WaterTrajectory(
        time_ps=np.asarray(time[keep], dtype=np.float64),
        oxygen_nm=np.ascontiguousarray(xyz[:, :, 0]),
        hydrogen_nm=np.ascontiguousarray(xyz[:, :, 1:3].reshape(xyz.shape[0], -1, 3)),
        box_nm=np.einsum("tii->ti", box[keep]).astype(np.float32),
    )


# --------------------------------------------------------------------------------------------
# Radial distribution functions
# --------------------------------------------------------------------------------------------


@partial(jax.jit, static_argnames=("num_bins", "frames_per_batch"))
def _pair_histogram(
    positions_a: jax.Array,
    positions_b: jax.Array,
    box: jax.Array,
    molecule_a: jax.Array,
    molecule_b: jax.Array,
    bin_width: jax.Array,
    bin_shift: jax.Array,
    num_bins: int,
    frames_per_batch: int,
) -> jax.Array:
    """Histogram of minimum-image distances, summed over frames; shape (num_bins,)."""
    different = molecule_a[:, None] != molecule_b[None, :]

    def one_frame(frame):
        pa, pb, edge = frame
        delta = pa[:, None, :] - pb[None, :, :]
        delta = delta - edge * jnp.round(delta / edge)
        distance = jnp.sqrt(jnp.sum(delta * delta, axis=-1))
        index = jnp.floor((distance + bin_shift) / bin_width).astype(jnp.int32)
        # Excluded pairs and distances beyond the last bin go to an overflow bin, then dropped.
        index = jnp.where(different & (index < num_bins), index, num_bins)
        return jnp.bincount(index.ravel(), length=num_bins + 1)[:num_bins]

    counts = jax.lax.map(one_frame, (positions_a, positions_b, box), batch_size=frames_per_batch)
    return jnp.sum(counts, axis=0)


def radial_distribution(
    positions_a: np.ndarray,
    positions_b: np.ndarray,
    box_nm: np.ndarray,
    molecule_a: np.ndarray,
    molecule_b: np.ndarray,
    r_max_nm: float | None = None,
    bin_width_nm: float = 0.002,
    normalise_excluded: bool = True,
    gmx_bins: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Site-site radial distribution function averaged over frames of a fluctuating box.

    Parameters
    ----------
    positions_a : array, shape (num_frames, num_a, 3)
        Reference sites (nm).
    positions_b : array, shape (num_frames, num_b, 3)
        Other sites (nm).
    box_nm : array, shape (num_frames, 3)
        Orthorhombic box edges (nm).
    molecule_a, molecule_b : array of int, shapes (num_a,), (num_b,)
        Molecule index of each site; pairs in the same molecule are excluded.
    r_max_nm : float, optional
        Largest distance. Defaults to half the smallest box edge over the frames (the largest
        radius at which the minimum-image histogram is complete); larger values are refused.
    bin_width_nm : float
        Histogram bin width (nm); 0.002 nm is ``gmx rdf``'s default.
    normalise_excluded : bool
        ``True``: ideal-gas normalisation counts only non-excluded pairs, so g -> 1 at large r in
        a finite system.  ``False``: ``N_A N_B`` as ``gmx rdf`` does.
    gmx_bins : bool
        ``False``: bins ``[k w, (k+1) w)`` reported at their centres.  ``True``: bins centred on
        ``k w`` (the first one ``[0, w/2)``), as ``gmx rdf`` lays them out; used to compare
        with it bin by bin.

    Returns
    -------
    r_nm : np.ndarray, shape (num_bins,)
        Bin centres (nm).
    g : np.ndarray, shape (num_bins,)
        Dimensionless g(r).
    """
    positions_a = np.asarray(positions_a, dtype=np.float32)
    positions_b = np.asarray(positions_b, dtype=np.float32)
    box_nm = np.asarray(box_nm, dtype=np.float32)
    molecule_a = np.asarray(molecule_a)
    molecule_b = np.asarray(molecule_b)
    num_frames, num_a, _ = positions_a.shape
    num_b = positions_b.shape[1]
    if positions_b.shape[0] != num_frames or box_nm.shape != (num_frames, 3):
        raise ValueError(
            f"shapes disagree: positions_a {positions_a.shape}, positions_b {positions_b.shape}, box {box_nm.shape}"
        )
    if molecule_a.shape != (num_a,) or molecule_b.shape != (num_b,):
        raise ValueError("molecule_a and molecule_b must give one molecule index per site")
    half_box = 0.5 * float(box_nm.min())
    if r_max_nm is None:
        r_max_nm = half_box
    elif r_max_nm > half_box * (1 + 1e-6):
        raise ValueError(
            f"r_max_nm={r_max_nm} exceeds half the smallest box edge ({half_box:.4f} nm): the "
            "minimum-image histogram would be incomplete there"
        )
    num_bins = math.floor(r_max_nm / bin_width_nm + 1e-9)
    if num_bins < 1:
        raise ValueError(f"r_max_nm={r_max_nm} is smaller than one bin ({bin_width_nm} nm)")
    # Batches of frames bound memory at ~frames * num_a * num_b * 12 bytes.
    frames_per_batch = max(1, min(num_frames, int(2e7 // max(1, num_a * num_b * 3))))
    counts = np.asarray(
        _pair_histogram(
            jnp.asarray(positions_a),
            jnp.asarray(positions_b),
            jnp.asarray(box_nm),
            jnp.asarray(molecule_a),
            jnp.asarray(molecule_b),
            jnp.float32(bin_width_nm),
            jnp.float32(0.5 * bin_width_nm if gmx_bins else 0.0),
            # Rounded up to 64 bins so that a fluctuating half-box does not recompile each call.
            64 * math.ceil(num_bins / 64),
            frames_per_batch,
        ),
        dtype=np.float64,
    )[:num_bins]
    num_excluded = int(np.sum(molecule_a[:, None] == molecule_b[None, :]))
    num_pairs = num_a * num_b - (num_excluded if normalise_excluded else 0)
    shift = 0.5 * bin_width_nm if gmx_bins else 0.0
    edges = np.maximum(bin_width_nm * np.arange(num_bins + 1, dtype=np.float64) - shift, 0.0)
    shell = 4.0 / 3.0 * np.pi * np.diff(edges**3)
    inverse_volume_sum = float(np.sum(1.0 / np.prod(box_nm.astype(np.float64), axis=1)))
    expected = num_pairs * inverse_volume_sum * shell
    centres = bin_width_nm * np.arange(num_bins) if gmx_bins else 0.5 * (edges[1:] + edges[:-1])
    return centres, counts / expected


def rdf_oo(
    trajectory: WaterTrajectory,
    r_max_nm: float | None = None,
    bin_width_nm: float = 0.002,
    normalise_excluded: bool = True,
    gmx_bins: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Oxygen-oxygen g(r) (self pairs excluded); see :func:`radial_distribution`."""
    molecules = np.arange(trajectory.num_molecules)
    return radial_distribution(
        trajectory.oxygen_nm,
        trajectory.oxygen_nm,
        trajectory.box_nm,
        molecules,
        molecules,
        r_max_nm,
        bin_width_nm,
        normalise_excluded,
        gmx_bins,
    )


def rdf_oh(
    trajectory: WaterTrajectory,
    r_max_nm: float | None = None,
    bin_width_nm: float = 0.002,
    intermolecular: bool = True,
    normalise_excluded: bool = True,
    gmx_bins: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Oxygen-hydrogen g(r); ``intermolecular=False`` keeps the molecule's own O-H pairs.

    ``intermolecular=False`` reproduces what the published pipeline fed its statistics
    (``gmx rdf`` without ``-excl``): a spike of height ~1e3 at the 0.09572 nm O-H bond.
    """
    molecules = np.arange(trajectory.num_molecules)
    hydrogen_molecule = np.repeat(molecules, 2)
    if not intermolecular:
        # Distinct labels for the two sets: nothing is excluded.
        hydrogen_molecule = hydrogen_molecule + trajectory.num_molecules
    return radial_distribution(
        trajectory.oxygen_nm,
        trajectory.hydrogen_nm,
        trajectory.box_nm,
        molecules,
        hydrogen_molecule,
        r_max_nm,
        bin_width_nm,
        normalise_excluded,
        gmx_bins,
    )


# --------------------------------------------------------------------------------------------
# Mean-squared displacement
# --------------------------------------------------------------------------------------------


@jax.jit
def unwrap(positions_nm: jax.Array, box_nm: jax.Array) -> jax.Array:
    """Unwrap positions across periodic boundaries under a fluctuating orthorhombic box.

    Parameters
    ----------
    positions_nm : array, shape (num_frames, num_sites, 3)
    box_nm : array, shape (num_frames, 3)

    Returns
    -------
    jax.Array, shape (num_frames, num_sites, 3)
        ``u_0 = w_0``, ``u_{t+1} = u_t + mi(w_{t+1} - w_t; L_{t+1})`` (von Buelow et al. 2020);
        valid while no site moves more than half a box edge between frames.
    """
    step = positions_nm[1:] - positions_nm[:-1]
    edge = box_nm[1:, None, :]
    step = step - edge * jnp.round(step / edge)
    return jnp.concatenate([positions_nm[:1], positions_nm[:1] + jnp.cumsum(step, axis=0)], axis=0)


@partial(jax.jit, static_argnames=("max_lag", "origin_stride", "remove_drift"))
def _msd(unwrapped: jax.Array, max_lag: int, origin_stride: int, remove_drift: bool) -> jax.Array:
    num_frames = unwrapped.shape[0]
    if remove_drift:
        # The mean oxygen displacement is the (tiny) drift of the whole liquid, not diffusion.
        unwrapped = unwrapped - jnp.mean(unwrapped, axis=1, keepdims=True)
    origins = jnp.arange(num_frames)
    is_origin = (origins % origin_stride) == 0

    def at_lag(lag):
        later = jnp.roll(unwrapped, -lag, axis=0)
        squared = jnp.sum((later - unwrapped) ** 2, axis=-1).mean(axis=1)
        valid = is_origin & (origins + lag < num_frames)
        return jnp.sum(jnp.where(valid, squared, 0.0)) / jnp.maximum(jnp.sum(valid), 1)

    return jax.lax.map(at_lag, jnp.arange(max_lag + 1))


def mean_squared_displacement(
    trajectory: WaterTrajectory,
    origin_interval_ps: float | None = None,
    max_lag_ps: float | None = None,
    remove_drift: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Oxygen mean-squared displacement from unwrapped positions.

    Parameters
    ----------
    trajectory : WaterTrajectory
        Evenly spaced frames.
    origin_interval_ps : float, optional
        Spacing of time origins (default: every frame).
    max_lag_ps : float, optional
        Longest lag (default: the whole trajectory).
    remove_drift : bool
        Subtract the mean oxygen displacement of each frame (centre-of-mass drift).

    Returns
    -------
    lag_ps : np.ndarray, shape (num_lags,)
    msd_nm2 : np.ndarray, shape (num_lags,)
        ``<|r(t0 + lag) - r(t0)|^2>`` averaged over oxygens and origins (nm^2).
    """
    dt = trajectory.frame_interval_ps
    if not np.allclose(np.diff(trajectory.time_ps), dt, rtol=1e-3, atol=1e-6):
        raise ValueError("frames are not evenly spaced in time; the MSD needs a fixed spacing")
    num_frames = trajectory.time_ps.size
    stride = 1 if origin_interval_ps is None else max(1, round(origin_interval_ps / dt))
    max_lag = num_frames - 1 if max_lag_ps is None else min(num_frames - 1, round(max_lag_ps / dt))
    unwrapped = unwrap(jnp.asarray(trajectory.oxygen_nm), jnp.asarray(trajectory.box_nm))
    msd = np.asarray(_msd(unwrapped, int(max_lag), int(stride), remove_drift), dtype=np.float64)
    return dt * np.arange(max_lag + 1), msd


def fit_msd_slope(
    lag_ps: np.ndarray,
    msd_nm2: np.ndarray,
    window_ps: tuple[float, float] | None = None,
    window_fraction: tuple[float, float] = (0.1, 0.5),
) -> float:
    """Least-squares slope of MSD against lag (nm^2/ps; Einstein: slope = 6 D).

    Parameters
    ----------
    lag_ps, msd_nm2 : np.ndarray, shape (num_lags,)
    window_ps : (float, float), optional
        Fit lags in ``[lo, hi]`` ps.
    window_fraction : (float, float)
        Used when ``window_ps`` is None: the window as fractions of the longest lag.  The
        default, 10 % to 50 %, skips the ballistic and cage regime (< ~1 ps in water for runs of
        10 ps or longer) and the long lags, which few time origins reach and which are noisy.
        For the ``quick`` preset (15 ps analysed) that is 1.5-7.5 ps; for ``paper``
        (80 ps analysed) 8-40 ps.
    """
    lag_ps = np.asarray(lag_ps, dtype=np.float64)
    msd_nm2 = np.asarray(msd_nm2, dtype=np.float64)
    if window_ps is None:
        window_ps = (window_fraction[0] * lag_ps[-1], window_fraction[1] * lag_ps[-1])
    mask = (lag_ps >= window_ps[0] - 1e-9) & (lag_ps <= window_ps[1] + 1e-9)
    if mask.sum() < 2:
        raise ValueError(f"fewer than two MSD points in the fit window {window_ps} ps")
    slope, _ = np.polyfit(lag_ps[mask], msd_nm2[mask], 1)
    return float(slope)


# --------------------------------------------------------------------------------------------
# All curves of one trajectory
# --------------------------------------------------------------------------------------------


class WaterCurves(NamedTuple):
    """The curves the statistics S1..S9 are computed from (and model criticism looks at).

    Attributes
    ----------
    r_oo_nm, g_oo : np.ndarray, shape (num_bins_oo,)
    r_oh_nm, g_oh : np.ndarray, shape (num_bins_oh,)
    lag_ps, msd_nm2 : np.ndarray, shape (num_lags,)
        Oxygen MSD; NaN-free.
    density_kg_m3 : float
        Mean density over the analysed frames.
    intermolecular_oh : bool
        Whether ``g_oh`` excludes each molecule's own O-H pairs.
    """

    r_oo_nm: np.ndarray
    g_oo: np.ndarray
    r_oh_nm: np.ndarray
    g_oh: np.ndarray
    lag_ps: np.ndarray
    msd_nm2: np.ndarray
    density_kg_m3: float = float("nan")
    intermolecular_oh: bool = True


def compute_curves(
    trajectory: WaterTrajectory,
    variant: str = "robust",
    r_max_nm: float | None = None,
    bin_width_nm: float = 0.002,
    density_kg_m3: float = float("nan"),
) -> WaterCurves:
    """g_OO, g_OH and the oxygen MSD of a trajectory, as a statistics variant needs them.

    Parameters
    ----------
    trajectory : WaterTrajectory
    variant : {"robust", "paper"}
        ``"robust"``: intermolecular g_OH, normalisation over non-excluded pairs, MSD with time
        origins at every frame and drift removed.  ``"paper"``: what the published scripts
        computed with ``gmx rdf`` / ``gmx msd``: g_OH including the molecule's own O-H pairs,
        ``N_A N_B`` normalisation, time origins every 10 ps (``gmx msd -trestart 10``), no
        drift removal.
    r_max_nm : float, optional
        Default: half the smallest box edge (``gmx rdf``'s default range).
    """
    if variant not in ("robust", "paper"):
        raise ValueError(f"variant must be 'robust' or 'paper', got {variant!r}")
    robust = variant == "robust"
    r_oo, g_oo = rdf_oo(trajectory, r_max_nm, bin_width_nm, normalise_excluded=robust)
    r_oh, g_oh = rdf_oh(trajectory, r_max_nm, bin_width_nm, intermolecular=robust, normalise_excluded=robust)
    lag, msd = mean_squared_displacement(trajectory, origin_interval_ps=None if robust else 10.0, remove_drift=robust)
    return WaterCurves(r_oo, g_oo, r_oh, g_oh, lag, msd, float(density_kg_m3), robust)
