"""Neon and argon: measured-data sets (reference equations of state) and pair-potential B2(T).

::

    from md.fluids import load
    data = load("neon")
    data.state_points["P_Pa"], data.b2["B2_m3_mol"], data.saturated_liquid["rho_liquid_mol_m3"]

The values come from the reference Helmholtz-energy equations of state (via CoolProp), which are
fitted to measurements; ``data/<fluid>/PROVENANCE.md`` gives the equation, the state points and
the uncertainties used as measurement errors.  :mod:`md.fluids.virial` computes B2(T) of LJ and
Feynman-Hibbs LJ by quadrature.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from md import _lazy_jax_md  # noqa: F401  (defers jax_md.rigid_body before md.fluids.simulator loads jax_md)

__all__ = ["LITERATURE_LJ", "FluidData", "load"]

DATA = Path(__file__).with_name("data")

# Classical LJ parameters fitted to gas data (Hirschfelder, Curtiss & Bird 1954, table I-A):
# sigma (m), epsilon / k (K), mass (amu).  Starting points and prior centres, not truths.
LITERATURE_LJ = {
    "neon": dict(sigma_m=2.749e-10, epsilon_k=35.6, mass_amu=20.1797),
    "argon": dict(sigma_m=3.405e-10, epsilon_k=119.8, mass_amu=39.948),
}


@dataclass(frozen=True)
class FluidData:
    """One fluid's data: structured arrays with the CSV column names (SI units in the names).

    Attributes
    ----------
    name : str
    state_points : numpy.ndarray
        Fields ``T_K, rho_mol_m3, phase, P_Pa, u_P_Pa, U_res_J_mol, u_U_res_J_mol``.
    saturated_liquid : numpy.ndarray
        Fields ``T_K, rho_liquid_mol_m3, u_rho_mol_m3, P_sat_Pa``.
    b2 : numpy.ndarray
        Fields ``T_K, B2_m3_mol, u_B2_m3_mol``.
    provenance : str
        The dataset's PROVENANCE.md.
    """

    name: str
    state_points: np.ndarray
    saturated_liquid: np.ndarray
    b2: np.ndarray
    provenance: str


def load(fluid: str) -> FluidData:
    """Load ``"neon"`` or ``"argon"``; raises ValueError for another name."""
    folder = DATA / fluid
    if fluid not in LITERATURE_LJ or not folder.is_dir():
        raise ValueError(f"no data for fluid {fluid!r}: available are {sorted(LITERATURE_LJ)}")

    def read(name: str) -> np.ndarray:
        return np.genfromtxt(folder / name, delimiter=",", names=True, dtype=None, encoding="utf-8")

    return FluidData(
        fluid,
        read("state_points.csv"),
        read("saturated_liquid.csv"),
        read("b2.csv"),
        (folder / "PROVENANCE.md").read_text(),
    )
