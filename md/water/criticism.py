"""Criticism catalogue for rigid water: q_H scaling, M-site shift, O-H contamination of g_OO.

The effects and the GROMACS-backed simulator that takes them as extra parameters; the
Lennard-Jones catalogue is in :mod:`md.criticism_catalogue`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from jaxabc.criticism import Catalogue, Effect

__all__ = ["WaterSimulatorWithEffects", "make_water_simulator_with_effects", "water_catalogue"]


def water_catalogue() -> Catalogue:
    """The water catalogue: q_H scaling, M-site shift, O-H contamination of X-ray g_OO."""
    return Catalogue(
        [
            Effect(
                "charge_scale",
                -0.05,
                0.1,
                0.0,
                "relative",
                "Hydrogen charge q_H -> q_H (1 + eta), q_M = -2 q_H: the molecular dipole "
                "(TIP4P 0.52 e -> TIP4P/2005 0.5564 e is eta = +0.07).",
                "physical",
                "the dielectric constant or enthalpy of vaporisation; density maximum",
                ("msite_shift",),
            ),
            Effect(
                "msite_shift",
                -0.005,
                0.005,
                0.0,
                "nm",
                "M-site distance d_OM -> d_OM + eta (TIP4P 0.015 nm, TIP4P/2005 0.01546 nm): the quadrupole.",
                "physical",
                "g_OH/g_HH (neutron) besides g_OO; the temperature of maximum density",
                ("charge_scale",),
            ),
            Effect(
                "oh_contamination",
                0.0,
                0.1,
                0.0,
                "weight",
                "X-ray g_OO contaminated by O-H correlations: g_meas = (1 - w) g_OO + w g_OH.",
                "measurement",
                "neutron g_OO from isotope substitution (no H weighting issue)",
            ),
        ],
        name="water (TIP4P)",
        notes=(
            "Charge scaling and M-site distance both change the electrostatics and largely move the "
            "same g_OO features; neutron g_OH/g_HH and thermodynamic data (density, heat of vaporisation) "
            "separate them.  O-H contamination is a measurement effect on the X-ray g_OO only."
        ),
    )


class WaterSimulatorWithEffects:
    """Picklable host simulator ``simulate(key, theta_full (5,)) -> S1..S9`` for criticism.

    ``theta_full = (sigma_OW, epsilon_OW, charge_scale, msite_shift, oh_contamination)``; returns
    S1..S9 and, with ``with_density``, the mean density (kg/m^3) as a tenth summary.  The
    physical effects go to :func:`md.water.make_simulator`'s 4-entry theta (sigma, epsilon, q_H,
    d_OM); the contamination mixes the simulated g_OH into g_OO before S4..S8 are computed.
    Run it with ``executor="process_pool"`` (GROMACS is a host program).
    """

    def __init__(
        self,
        preset: str = "quick",
        statistics: str = "robust",
        observed_kind: str = "xray",
        with_density: bool = True,
        **options: Any,
    ):
        from md.water import make_simulator

        self.inner = make_simulator(preset, statistics, observed_kind, **options)
        self.statistics = statistics
        self.observed_kind = observed_kind
        self.with_density = with_density

    #: Names of the returned summaries (the density, kg/m^3, is appended when ``with_density``).
    NAMES = (
        "S1 mean g_OH",
        "S2 g_OH first minimum r",
        "S3 g_OH area",
        "S4 mean g_OO",
        "S5 g_OO first minimum r",
        "S6 g_OO area",
        "S7 g_OO first peak height",
        "S8 g_OO first peak r",
        "S9 self-diffusion D",
        "density kg/m3",
    )

    def __call__(self, key, theta_full) -> np.ndarray:
        from md.water.analysis import WaterCurves
        from md.water.simulator import OBSERVED_KINDS
        from md.water.statistics import summary_statistics

        theta_full = np.asarray(theta_full, np.float64)
        base = self.inner.base_parameters
        theta = [
            theta_full[0],
            theta_full[1],
            base.charge_h_e * (1.0 + theta_full[2]),
            base.om_distance_nm + theta_full[3],
        ]
        out = self.inner.run(key, theta)
        w = float(theta_full[4])
        stats = out.statistics
        if w != 0.0:
            c: WaterCurves = out.curves
            g_oh = np.interp(c.r_oo_nm, c.r_oh_nm, c.g_oh)
            stats = summary_statistics(c._replace(g_oo=(1.0 - w) * c.g_oo + w * g_oh), self.statistics)
        stats = np.where(OBSERVED_KINDS[self.observed_kind], stats, 0.0)
        if self.with_density:
            stats = np.append(stats, out.curves.density_kg_m3)
        return stats


def make_water_simulator_with_effects(
    preset: str = "quick", statistics: str = "robust", observed_kind: str = "xray", **options: Any
) -> WaterSimulatorWithEffects:
    """Build :class:`WaterSimulatorWithEffects` (needs GROMACS ``gmx``)."""
    return WaterSimulatorWithEffects(preset, statistics, observed_kind, **options)
