"""Joint measured data for ambient water: g(r) summaries, density, diffusion, enthalpy.

The values, their stated errors, conditions, sources and the corrections behind them live in
``data/joint_water_298K.json`` (data, not code), as does the split of the summaries into
*fitted* (used by the ABC distance) and *held out* (kept for criticism).  This module reads it
and returns vectors in the order of :data:`md.water.model_simulator.JOINT_SUMMARY_NAMES`:
S1..S9 (:func:`md.water.datasets.observed_statistics`, ``robust`` variant), the density
(kg/m3), the enthalpy of vaporisation (kJ/mol) and the second-shell summaries of g_OO
(:func:`md.water.statistics.second_shell_statistics`).

Errors: every measured summary carries the error its source states or, where it states none, a
documented estimate (``error_meaning`` in the file); for the g(r) statistics the curves'
pointwise errors propagated by :mod:`md.water.datasets` are a floor.  The scalars are taken at
the temperature the data kind is simulated at (``simulation_temperature_k``: 295.15 K for the
X-ray data).  :func:`observation_sd` gives the sd vector of the fitted summaries for
``jaxabc.run(..., observation_error=sd)``.

>>> data = joint_observed("xray")                   # doctest: +SKIP
>>> data.observed[data.fitted]                      # the vector the ABC distance sees
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from md.water.datasets import (
    DATA_DIR,
    observed_statistics,
    second_shell_errors,
    second_shell_observed,
    statistic_errors,
)
from md.water.finite_size import YEH_HUMMER_XI, yeh_hummer_shift
from md.water.statistics import SECOND_SHELL_NAMES

__all__ = [
    "JOINT_DATA_FILE",
    "JOINT_NAMES",
    "YEH_HUMMER_XI",
    "JointData",
    "joint_observed",
    "joint_record",
    "observation_sd",
    "yeh_hummer_shift",
]

JOINT_DATA_FILE = DATA_DIR / "joint_water_298K.json"
#: Same order as :data:`md.water.model_simulator.JOINT_SUMMARY_NAMES` (tested).  The
#: second-shell summaries come last so the first 11 positions keep their meaning.
JOINT_NAMES: tuple[str, ...] = (
    *(f"S{i}" for i in range(1, 10)),
    "density_kg_m3",
    "hvap_kj_mol",
    *SECOND_SHELL_NAMES,
)
_CURVE_RECORD = {"xray": "xray_goo", "neutron": "neutron_goo_goh"}


class JointData(NamedTuple):
    """Observed joint summaries and their roles.

    Attributes
    ----------
    kind : str
        ``"xray"`` or ``"neutron"`` (which g(r) data give S1..S8 and the second shell).
    names : tuple of str, length 14
    observed : np.ndarray, shape (14,)
        Unused entries (S1..S3 for X-ray) are 0.0, as the simulator returns them.
    errors : np.ndarray, shape (14,)
        Adopted one-sigma errors: for the g(r) statistics the larger of the file's stated error
        (or documented estimate) and the curves' pointwise errors propagated by
        :mod:`md.water.datasets`; for the scalars the file's error at ``temperature_k``; NaN
        where the data measure nothing.
    fitted, held_out : np.ndarray of bool, shape (14,)
        Disjoint masks, from the data file's ``roles``.
    temperature_k : float
        The temperature to simulate at and at which the scalars are given.
    propagated : np.ndarray, shape (14,)
        The pointwise-error propagation alone (NaN for the scalars and unmeasured entries).
    """

    kind: str
    names: tuple[str, ...]
    observed: np.ndarray
    errors: np.ndarray
    fitted: np.ndarray
    held_out: np.ndarray
    temperature_k: float = 298.15
    propagated: np.ndarray | None = None


def _record(path: Path) -> dict[str, Any]:
    # Not cached: the file is small and read once per run.
    return json.loads(path.read_text())


def joint_record(path: str | Path = JOINT_DATA_FILE) -> dict[str, Any]:
    """The data file as a dict (values, errors, sources, corrections, roles)."""
    return _record(Path(path))


def _scalar_at(entry: dict[str, Any], temperature_k: float) -> tuple[float, float]:
    """(value, error) of a scalar record at ``temperature_k`` (its own or a ``by_temperature_k`` entry)."""
    if abs(entry["temperature_k"] - temperature_k) < 1e-6:
        return float(entry["value"]), float(entry["error"])
    for t, other in entry.get("by_temperature_k", {}).items():
        if abs(float(t) - temperature_k) < 1e-6:
            return float(other["value"]), float(other["error"])
    raise ValueError(f"the data file gives no value at {temperature_k} K for {entry.get('source', entry)}")


def joint_observed(kind: str = "xray", path: str | Path = JOINT_DATA_FILE) -> JointData:
    """The observed joint summaries for ``kind`` ``"xray"`` or ``"neutron"``.

    Raises
    ------
    ValueError
        Unknown ``kind``, a data file whose roles name unknown summaries or overlap, a fitted
        g(r) statistic without an error record, or a scalar without a value at the kind's
        simulation temperature.
    """
    record = _record(Path(path))
    roles = record["roles"]
    if kind not in roles:
        raise ValueError(f"kind must be one of {sorted(roles)}, got {kind!r}")
    temperature = float(record.get("simulation_temperature_k", {}).get(kind, record["conditions"]["temperature_k"]))
    scalars = record["scalars"]
    d, d_error = _scalar_at(scalars["self_diffusion_1e-5_cm2_s"], temperature)
    rho, rho_error = _scalar_at(scalars["density_kg_m3"], temperature)
    hvap, hvap_error = _scalar_at(scalars["hvap_kj_mol"], temperature)
    statistics = observed_statistics(kind, "robust")
    # S9 (robust) is D in 1e-5 cm^2/s; the data file is the single source of its value.
    statistics[8] = d
    observed = np.concatenate([statistics, [rho, hvap], second_shell_observed(kind)])
    propagated = np.full(len(JOINT_NAMES), np.nan)
    propagated[:8] = statistic_errors(kind)[0][:8]
    propagated[11:] = second_shell_errors(kind)[0]
    stated = np.full(len(JOINT_NAMES), np.nan)
    for name, entry in record["curves"][_CURVE_RECORD[kind]].get("statistic_errors", {}).items():
        if name not in JOINT_NAMES:
            raise ValueError(f"{path}: statistic_errors names unknown summary {name!r}")
        stated[JOINT_NAMES.index(name)] = float(entry["error"])
    errors = np.fmax(stated, propagated)  # NaN only where both are NaN
    errors[8], errors[9], errors[10] = d_error, rho_error, hvap_error

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
    curve_summaries = (*JOINT_NAMES[:8], *SECOND_SHELL_NAMES)
    missing = [
        n for n, f, e in zip(JOINT_NAMES, fitted, stated, strict=True) if f and n in curve_summaries and np.isnan(e)
    ]
    if missing:
        raise ValueError(f"{path}: fitted g(r) summaries {missing} have no error record (statistic_errors)")
    return JointData(kind, JOINT_NAMES, observed, errors, fitted, held_out, temperature, propagated)


def observation_sd(kind: str = "xray", path: str | Path = JOINT_DATA_FILE) -> np.ndarray:
    """One-sigma measurement error of each *fitted* summary, in the fitted order.

    The vector for ``jaxabc.run(..., observation_error=sd)`` (or
    :class:`jaxabc.noise.MeasurementError`), matching ``data.observed[data.fitted]``.

    Raises
    ------
    ValueError
        A fitted summary without a finite, positive error.
    """
    data = joint_observed(kind, path)
    sd = np.asarray(data.errors, np.float64)[data.fitted]
    bad = [n for n, e in zip(np.array(data.names)[data.fitted], sd, strict=True) if not (np.isfinite(e) and e > 0)]
    if bad:
        raise ValueError(f"fitted summaries {bad} have no finite positive error")
    return sd
