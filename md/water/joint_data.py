"""Joint measured data for ambient water: g(r) summaries, density, diffusion, enthalpy.

The values, their stated errors, conditions, sources and the corrections behind them live in
``data/joint_water_298K.json`` (data, not code), as does the split of the summaries into
*fitted* (used by the ABC distance) and *held out* (kept for criticism).  This module reads it
and returns vectors in the order of :data:`md.water.model_simulator.JOINT_SUMMARY_NAMES`:
S1..S9 (:func:`md.water.datasets.observed_statistics`, ``robust`` variant), the density
(kg/m3) and the enthalpy of vaporisation (kJ/mol).

>>> data = joint_observed("xray")                   # doctest: +SKIP
>>> data.observed[data.fitted]                      # the vector the ABC distance sees
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from md.water.datasets import DATA_DIR, observed_statistics, statistic_errors

__all__ = [
    "JOINT_DATA_FILE",
    "JOINT_NAMES",
    "YEH_HUMMER_XI",
    "JointData",
    "joint_observed",
    "joint_record",
    "yeh_hummer_shift",
]

JOINT_DATA_FILE = DATA_DIR / "joint_water_298K.json"
#: Same order as :data:`md.water.model_simulator.JOINT_SUMMARY_NAMES` (tested).
JOINT_NAMES: tuple[str, ...] = (*(f"S{i}" for i in range(1, 10)), "density_kg_m3", "hvap_kj_mol")


class JointData(NamedTuple):
    """Observed joint summaries and their roles.

    Attributes
    ----------
    kind : str
        ``"xray"`` or ``"neutron"`` (which g(r) data give S1..S8).
    names : tuple of str, length 11
    observed : np.ndarray, shape (11,)
        Unused entries (S1..S3 for X-ray) are 0.0, as the simulator returns them.
    errors : np.ndarray, shape (11,)
        Stated error of density, S9 and the enthalpy; for S1..S8, the curves' stated pointwise
        errors propagated by :func:`md.water.datasets.statistic_errors` (conservative); NaN
        where the data measure nothing.
    fitted, held_out : np.ndarray of bool, shape (11,)
        Disjoint masks, from the data file's ``roles``.
    """

    kind: str
    names: tuple[str, ...]
    observed: np.ndarray
    errors: np.ndarray
    fitted: np.ndarray
    held_out: np.ndarray


def _record(path: Path) -> dict[str, Any]:
    # Not cached: the file is small and read once per run.
    return json.loads(path.read_text())


def joint_record(path: str | Path = JOINT_DATA_FILE) -> dict[str, Any]:
    """The data file as a dict (values, errors, sources, corrections, roles)."""
    return _record(Path(path))


def joint_observed(kind: str = "xray", path: str | Path = JOINT_DATA_FILE) -> JointData:
    """The observed joint summaries for ``kind`` ``"xray"`` or ``"neutron"``.

    Raises
    ------
    ValueError
        Unknown ``kind``, or a data file whose roles name unknown summaries or overlap.
    """
    record = _record(Path(path))
    roles = record["roles"]
    if kind not in roles:
        raise ValueError(f"kind must be one of {sorted(roles)}, got {kind!r}")
    scalars = record["scalars"]
    d = scalars["self_diffusion_1e-5_cm2_s"]
    statistics = observed_statistics(kind, "robust")
    # S9 (robust) is D in 1e-5 cm^2/s; the data file is the single source of its value.
    statistics[8] = d["value"]
    observed = np.concatenate([statistics, [scalars["density_kg_m3"]["value"], scalars["hvap_kj_mol"]["value"]]])
    errors = np.full(len(JOINT_NAMES), np.nan)
    errors[:8] = statistic_errors(kind)[0][:8]
    errors[8] = d["error"]
    errors[9] = scalars["density_kg_m3"]["error"]
    errors[10] = scalars["hvap_kj_mol"]["error"]

    def mask(names: list[str]) -> np.ndarray:
        unknown = sorted(set(names) - set(JOINT_NAMES))
        if unknown:
            raise ValueError(f"{path}: roles[{kind!r}] names unknown summaries {unknown}; known: {JOINT_NAMES}")
        return np.array([n in names for n in JOINT_NAMES])

    fitted, held_out = mask(roles[kind]["fitted"]), mask(roles[kind]["held_out"])
    if np.any(fitted & held_out):
        raise ValueError(
            f"{path}: roles[{kind!r}] lists {np.array(JOINT_NAMES)[fitted & held_out]} as both fitted and held out"
        )
    return JointData(kind, JOINT_NAMES, observed, errors, fitted, held_out)


#: Yeh & Hummer's (2004) constant for a cubic periodic lattice.
YEH_HUMMER_XI = 2.837297
_BOLTZMANN_J_K = 1.380649e-23


def yeh_hummer_shift(box_nm: float, viscosity_mpa_s: float, temperature_k: float = 298.15) -> float:
    """Finite-size deficit of the self-diffusion coefficient in a cubic box, in 1e-5 cm^2/s.

    ``D_infinite = D_box + xi k_B T / (6 pi eta L)`` (Yeh & Hummer 2004, J. Phys. Chem. B 108,
    15873), ``xi = 2.837297``.  ``eta`` must be the *model's* shear viscosity: the
    hydrodynamic self-interaction that slows diffusion in the box is that of the simulated
    liquid, not of real water.

    Raises
    ------
    ValueError
        Non-positive or non-finite input.
    """
    values = np.array([box_nm, viscosity_mpa_s, temperature_k], dtype=float)
    if not np.all(np.isfinite(values) & (values > 0)):
        raise ValueError(f"box_nm, viscosity_mpa_s and temperature_k must be finite and > 0, got {values}")
    shift_m2_s = YEH_HUMMER_XI * _BOLTZMANN_J_K * temperature_k / (6 * np.pi * viscosity_mpa_s * 1e-3 * box_nm * 1e-9)
    return float(shift_m2_s * 1e4 * 1e5)  # m^2/s -> cm^2/s -> 1e-5 cm^2/s
