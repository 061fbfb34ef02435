"""Measured water data: X-ray and neutron g(r), the paper's published vectors, self-diffusion.

All files are in ``md/water/data/``; see ``PROVENANCE.md`` there for sources and checks.

Curves (r in nm, g dimensionless)
    * :func:`xray_goo`: Skinner et al., J. Chem. Phys. 138, 074506 (2013), X-ray g_OO of water
      at 22.0 C (295.15 K), r = 0..1.999 nm in 0.001 nm steps, with its error column.
    * :func:`neutron_curves`: Soper, ISRN Phys. Chem. 2013, 279463 (EPSR fit to neutron and
      X-ray data), intermolecular g_OO, g_OH, g_HH of ambient water, r = 0..2.499 nm.
      The paper used Soper (2000) neutron data, which are not in any public repository we found;
      Soper (2013) is the same group's later analysis of ambient water.

Published summary vectors (Dutta et al. 2018, ``eth-cscs/abcpy-models``)
    Returned by :func:`published_statistics` in this package's order S1..S9
    (:mod:`md.water.statistics`).  The stored files use other orders:

    * neutron ``exp_data.npy`` is stored as ``[S1, S2, S3, S4, S7, S8, S5, S6, D]``, while the
      published model (``TIP4PGromacsOOOH``) returned ``[S1, S2, S3, S7, S8, S4, S5, S6, D]``.
      The published run therefore compared the simulated peak height (~2.9) with the observed
      mean (0.86), the peak position with the height, and the mean with the peak position;
      that is why its neutron calibration stalled at threshold 0.36.  We load it by its stored
      order, so S4 = 0.8635, S5 = 0.33, S6 = 0.1301, S7 = 2.692, S8 = 0.275.
    * X-ray ``exp_data_2.npy`` is ``[S7, S8, S4, S5, S6, D]`` (the order of ``TIP4PGromacsOO``,
      consistent); S1..S3 are not measured.
    * "simulated observed" ``obs_data.npy`` is ``[S1, S2, S3, S7, S4, S5, S6, D]``: eight values,
      S8 is missing.

Self-diffusion of water
    * :data:`DIFFUSION_298K_CM2_S` = 2.30e-5 cm^2/s at 298.15 K (Holz, Heil & Sacco, Phys.
      Chem. Chem. Phys. 2, 4740 (2000): 2.299e-9 m^2/s at 25 C), the default here.
    * :data:`PAPER_DIFFUSION_CM2_S` = 1.3e-5 cm^2/s is what the paper's text quotes; it is
      water's self-diffusion near 278 K, not 298 K.
    * :data:`PAPER_STORED_SLOPE_NM2_PS` = 0.023 nm^2/ps is the S9 entry actually stored in both
      published experimental vectors: it equals TIP4P's own simulated MSD slope (0.02298 in
      ``obs_data.npy``), i.e. D = 3.8e-5 cm^2/s, neither of the above.
      For reference, 6 x 2.30e-5 cm^2/s = 0.0138 nm^2/ps.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import NamedTuple

import numpy as np

from md.water.statistics import (
    paper_oh_statistics,
    paper_oo_statistics,
    robust_oh_statistics,
    robust_oo_statistics,
    second_shell_statistics,
)

__all__ = [
    "DATA_DIR",
    "DIFFUSION_298K_CM2_S",
    "ERROR_CORRELATION_LENGTHS_NM",
    "NEUTRON_STORED_ORDER",
    "PAPER_DIFFUSION_CM2_S",
    "PAPER_STORED_SLOPE_NM2_PS",
    "SIMULATED_STORED_ORDER",
    "XRAY_STORED_ORDER",
    "ExperimentalCurve",
    "diffusion_statistic_value",
    "neutron_curves",
    "observed_statistics",
    "published_posterior",
    "published_statistics",
    "second_shell_errors",
    "second_shell_observed",
    "statistic_errors",
    "xray_goo",
]

DATA_DIR = Path(__file__).resolve().parent / "data"

DIFFUSION_298K_CM2_S = 2.30e-5
PAPER_DIFFUSION_CM2_S = 1.3e-5
PAPER_STORED_SLOPE_NM2_PS = 0.023

#: Statistic (1-based S index) held at each position of the stored files; 9 stands for D.
NEUTRON_STORED_ORDER = (1, 2, 3, 4, 7, 8, 5, 6, 9)
XRAY_STORED_ORDER = (7, 8, 4, 5, 6, 9)
SIMULATED_STORED_ORDER = (1, 2, 3, 7, 4, 5, 6, 9)


class ExperimentalCurve(NamedTuple):
    """A measured radial distribution function.

    Attributes
    ----------
    r_nm : np.ndarray, shape (num_points,)
    g : np.ndarray, shape (num_points,)
        Dimensionless, intermolecular.
    error : np.ndarray, shape (num_points,)
        One-sigma error estimate given by the source.
    temperature_k : float
    source : str
        Citation.
    """

    r_nm: np.ndarray
    g: np.ndarray
    error: np.ndarray
    temperature_k: float
    source: str


@cache
def _skinner() -> np.ndarray:
    # The original file: tab separated, CRLF, 10 comment + 2 header lines, r in Angstrom.
    table = np.genfromtxt(
        DATA_DIR / "skinner2013_Ambient_water_xray_data.txt", delimiter="\t", skip_header=12, usecols=(3, 4, 5)
    )
    return table[~np.isnan(table[:, 0])]


def xray_goo() -> ExperimentalCurve:
    """Skinner 2013 X-ray g_OO(r) at 295.15 K, r converted from Angstrom to nm."""
    table = _skinner()
    return ExperimentalCurve(
        r_nm=table[:, 0] / 10.0,
        g=table[:, 1],
        error=table[:, 2],
        temperature_k=295.15,
        source="L. B. Skinner et al., J. Chem. Phys. 138, 074506 (2013), doi:10.1063/1.4790861",
    )


@cache
def _soper() -> np.ndarray:
    return np.loadtxt(DATA_DIR / "soper2013_dist_funcs.txt", comments="#")


def neutron_curves() -> dict[str, ExperimentalCurve]:
    """Soper 2013 intermolecular ``{"OO", "OH", "HH"}`` g(r) of ambient water, r in nm."""
    table = _soper()
    source = "A. K. Soper, ISRN Physical Chemistry 2013, 279463 (2013), doi:10.1155/2013/279463 (EPSR, ambient water)"
    return {
        pair: ExperimentalCurve(table[:, 0] / 10.0, table[:, column], table[:, column + 1], 298.0, source)
        for pair, column in (("OO", 1), ("OH", 3), ("HH", 5))
    }


def _reorder(stored: np.ndarray, order: tuple[int, ...]) -> np.ndarray:
    vector = np.full(9, np.nan)
    vector[np.asarray(order) - 1] = stored
    return vector


def published_statistics(kind: str) -> np.ndarray:
    """The paper's stored vector for ``kind`` in this package's order S1..S9.

    Parameters
    ----------
    kind : {"neutron", "xray", "simulated"}

    Returns
    -------
    np.ndarray, shape (9,)
        Units of the ``paper`` variant (S9 = MSD slope in nm^2/ps); NaN where the file has no
        value (X-ray S1..S3, simulated S8).
    """
    files = {
        "neutron": ("dutta2018_abcpy-models_exp_data.npy", NEUTRON_STORED_ORDER),
        "xray": ("dutta2018_abcpy-models_exp_data_2.npy", XRAY_STORED_ORDER),
        "simulated": ("dutta2018_abcpy-models_obs_data.npy", SIMULATED_STORED_ORDER),
    }
    if kind not in files:
        raise ValueError(f"kind must be one of {sorted(files)}, got {kind!r}")
    name, order = files[kind]
    return _reorder(np.load(DATA_DIR / name).reshape(-1), order)


def published_posterior(kind: str) -> np.ndarray:
    """Last APMCABC generation of the paper: shape (100, 3), columns sigma (nm), epsilon
    (kJ/mol), normalised weight; ``kind`` in {"simulated", "neutron", "xray"}."""
    if kind not in ("simulated", "neutron", "xray"):
        raise ValueError(f"kind must be 'simulated', 'neutron' or 'xray', got {kind!r}")
    path = DATA_DIR / f"dutta2018_abcpy-models_posterior_{kind}_final_generation.csv"
    return np.loadtxt(path, delimiter=",", comments="#", ndmin=2)


def diffusion_statistic_value(variant: str, diffusion: str = "experiment") -> float:
    """Observed S9.

    Parameters
    ----------
    variant : {"robust", "paper"}
        ``robust``: D in 1e-5 cm^2/s; ``paper``: MSD slope 6 D in nm^2/ps.
    diffusion : {"experiment", "paper_text", "paper_stored"}
        ``experiment``: 2.30e-5 cm^2/s (298 K, default); ``paper_text``: 1.3e-5 cm^2/s (the
        paper's quoted value, 278 K); ``paper_stored``: the 0.023 nm^2/ps actually stored.
    """
    if diffusion == "paper_stored":
        slope = PAPER_STORED_SLOPE_NM2_PS
    elif diffusion in ("experiment", "paper_text"):
        d_cm2_s = DIFFUSION_298K_CM2_S if diffusion == "experiment" else PAPER_DIFFUSION_CM2_S
        slope = 6.0 * d_cm2_s * 1e2  # 1 cm^2/s = 1e14 nm^2 / 1e12 ps = 1e2 nm^2/ps
    else:
        raise ValueError(f"diffusion must be 'experiment', 'paper_text' or 'paper_stored', got {diffusion!r}")
    if variant == "paper":
        return slope
    if variant == "robust":
        return slope / 6.0 * 1e3  # nm^2/ps -> D in 1e-5 cm^2/s
    raise ValueError(f"variant must be 'robust' or 'paper', got {variant!r}")


def observed_statistics(
    kind: str,
    variant: str = "robust",
    diffusion: str = "experiment",
    source: str | None = None,
) -> np.ndarray:
    """The observed S1..S9 to calibrate against, matching :class:`TIP4PSimulator`'s output.

    Parameters
    ----------
    kind : {"xray", "neutron"}
        For ``"xray"`` the unmeasured S1..S3 are 0.0, as the simulator returns them for
        ``observed_kind="xray"``.
    variant : {"robust", "paper"}
    diffusion : str
        See :func:`diffusion_statistic_value`; default the 298 K experimental value.
    source : {"published", "recomputed"}, optional
        ``paper`` variant only: ``"published"`` (default) uses the stored vector (correctly
        ordered) for S1..S8; ``"recomputed"`` applies the paper's rules to the curves here
        (identical for X-ray; Soper 2013 instead of Soper 2000 for neutron).  The ``robust``
        variant is always computed from the curves.

    Returns
    -------
    np.ndarray, shape (9,)
    """
    if kind not in ("xray", "neutron"):
        raise ValueError(
            f"kind must be 'xray' or 'neutron', got {kind!r} (for simulated data, run the "
            "simulator at md.water.gromacs.TIP4P_PARAMETERS)"
        )
    if variant == "paper":
        source = source or "published"
        if source == "published":
            vector = published_statistics(kind)
        elif source == "recomputed":
            vector = _from_curves(kind, paper_oh_statistics, paper_oo_statistics)
        else:
            raise ValueError(f"source must be 'published' or 'recomputed', got {source!r}")
    elif variant == "robust":
        if source not in (None, "recomputed"):
            raise ValueError("the robust variant is always recomputed from the curves")
        vector = _from_curves(kind, robust_oh_statistics, robust_oo_statistics)
    else:
        raise ValueError(f"variant must be 'robust' or 'paper', got {variant!r}")
    vector = vector.copy()
    vector[8] = diffusion_statistic_value(variant, diffusion)
    if kind == "xray":
        vector[:3] = 0.0
    return vector


def _from_curves(kind: str, oh_statistics, oo_statistics) -> np.ndarray:
    vector = np.full(9, np.nan)
    if kind == "xray":
        curve = xray_goo()
        vector[3:8] = oo_statistics(curve.r_nm, curve.g)
    else:
        curves = neutron_curves()
        vector[0:3] = oh_statistics(curves["OH"].r_nm, curves["OH"].g)
        vector[3:8] = oo_statistics(curves["OO"].r_nm, curves["OO"].g)
    return vector


#: Correlation lengths (nm) of the curves' pointwise errors that :func:`statistic_errors` tries:
#: independent points, errors correlated over about a tenth of the first peak, one common shift.
ERROR_CORRELATION_LENGTHS_NM: tuple[float, ...] = (0.0, 0.01, float("inf"))


@cache
def statistic_errors(kind: str, num_draws: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Errors of the robust S1..S8 propagated from the measured curves' stated pointwise errors.

    The sources state an error per point but not how the points' errors are correlated, and
    the statistics respond very differently (a common shift moves S4 and S7, independent
    noise moves the extrema's positions).  So the curves are redrawn ``num_draws`` times as
    ``g + error * z`` under each correlation of :data:`ERROR_CORRELATION_LENGTHS_NM` (Gaussian
    kernel in r; z standard normal) and, per statistic, the largest of the resulting standard
    deviations is adopted: a conservative error, not a measured one.

    Parameters
    ----------
    kind : {"xray", "neutron"}
    num_draws : int
    seed : int
        Fixed: the errors are part of the data definition.

    Returns
    -------
    adopted : np.ndarray, shape (9,)
        NaN where the data measure nothing (S1..S3 of X-ray) and for S9 (not from a curve).
    by_assumption : np.ndarray, shape (len(ERROR_CORRELATION_LENGTHS_NM), 9)
    """
    if kind not in ("xray", "neutron"):
        raise ValueError(f"kind must be 'xray' or 'neutron', got {kind!r}")
    rng = np.random.default_rng(seed)
    curves = {"OO": xray_goo()} if kind == "xray" else neutron_curves()
    targets = [("OO", slice(3, 8), robust_oo_statistics)]
    if kind == "neutron":
        targets.append(("OH", slice(0, 3), robust_oh_statistics))
    by_assumption = np.full((len(ERROR_CORRELATION_LENGTHS_NM), 9), np.nan)
    for a, length in enumerate(ERROR_CORRELATION_LENGTHS_NM):
        for pair, where, statistics in targets:
            curve = curves[pair]
            z = _correlated_normals(rng, curve.r_nm, length, num_draws)
            values = np.array([np.asarray(statistics(curve.r_nm, curve.g + curve.error * zi)) for zi in z])
            by_assumption[a, where] = np.nanstd(values, axis=0, ddof=1)
    return np.max(by_assumption, axis=0), by_assumption


def second_shell_observed(kind: str) -> np.ndarray:
    """Measured ``[g at the first g_OO minimum, r (nm) and g of the second maximum]``
    (:func:`md.water.statistics.second_shell_statistics`) of the X-ray or neutron g_OO."""
    if kind not in ("xray", "neutron"):
        raise ValueError(f"kind must be 'xray' or 'neutron', got {kind!r}")
    curve = xray_goo() if kind == "xray" else neutron_curves()["OO"]
    return np.asarray(second_shell_statistics(curve.r_nm, curve.g), np.float64)


@cache
def second_shell_errors(kind: str, num_draws: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Errors of :func:`second_shell_observed` from the curve's pointwise errors.

    Propagated exactly as :func:`statistic_errors` (the largest sd over the correlation
    assumptions of :data:`ERROR_CORRELATION_LENGTHS_NM`, ``num_draws`` redraws each).

    Returns
    -------
    adopted : np.ndarray, shape (3,)
    by_assumption : np.ndarray, shape (len(ERROR_CORRELATION_LENGTHS_NM), 3)
    """
    if kind not in ("xray", "neutron"):
        raise ValueError(f"kind must be 'xray' or 'neutron', got {kind!r}")
    rng = np.random.default_rng(seed)
    curve = xray_goo() if kind == "xray" else neutron_curves()["OO"]
    by_assumption = np.full((len(ERROR_CORRELATION_LENGTHS_NM), 3), np.nan)
    for a, length in enumerate(ERROR_CORRELATION_LENGTHS_NM):
        z = _correlated_normals(rng, curve.r_nm, length, num_draws)
        values = np.array([np.asarray(second_shell_statistics(curve.r_nm, curve.g + curve.error * zi)) for zi in z])
        by_assumption[a] = np.nanstd(values, axis=0, ddof=1)
    return np.max(by_assumption, axis=0), by_assumption


def _correlated_normals(rng: np.random.Generator, r_nm: np.ndarray, length: float, n: int) -> np.ndarray:
    """(n, len(r)) standard normals, correlated with a Gaussian kernel of ``length`` nm in r
    (0: independent; inf: one value per draw), on the window the statistics read."""
    if length == 0.0:
        return rng.standard_normal((n, len(r_nm)))
    if np.isinf(length):
        return np.repeat(rng.standard_normal((n, 1)), len(r_nm), axis=1)
    window = np.flatnonzero((r_nm >= 0.15) & (r_nm <= 0.85))
    x = r_nm[window]
    kernel = np.exp(-0.5 * ((x[:, None] - x[None, :]) / length) ** 2) + 1e-6 * np.eye(len(x))
    z = np.zeros((n, len(r_nm)))
    z[:, window] = rng.standard_normal((n, len(x))) @ np.linalg.cholesky(kernel).T
    return z
