"""Published rigid, non-polarisable water models: parameters, GROMACS topologies, priors.

Five models, each a frozen :class:`WaterModel` with its citation:

========== ======= ============ ========== ========= ============ =============== ==========
model      sites   q_H (e)      r_OH (nm)  HOH (deg) d_OM (nm)    sigma_OO (nm)   eps (kJ/mol)
========== ======= ============ ========== ========= ============ =============== ==========
TIP4P      4       0.52         0.09572    104.52    0.015        0.315365        0.648520
TIP4P/2005 4       0.5564       0.09572    104.52    0.01546      0.31589         0.774908
TIP4P-Ew   4       0.52422      0.09572    104.52    0.0125       0.316435        0.680946
SPC/E      3       0.4238       0.1        109.47    (on O)       0.316557        0.650194
TIP3P      3       0.417        0.09572    104.52    (on O)       0.315061        0.636386
========== ======= ============ ========== ========= ============ =============== ==========

Only the oxygens carry Lennard-Jones.  TIP3P as published (Jorgensen et al. 1983) and as in
GROMACS's ``oplsaa.ff/tip3p.itp`` has none on H; the CHARMM variant's H LJ is a different model
and is not used here.  The negative charge sits on the massless M site of the 4-site models and
on the oxygen of the 3-site ones (``q_M`` or ``q_O = -2 q_H``).

Topologies: the 4-site models use the project's own TIP4P topology
(:func:`md.water.topology.topology_text`), whose charge, M-site and geometry macros take each
model's values, so they run through the frozen :class:`md.water.simulator.TIP4PSimulator`
unchanged.  The 3-site models get :func:`three_site_topology_text`, the same self-contained
layout without the M site (checked against GROMACS's ``oplsaa.ff/spce.itp`` and ``tip3p.itp``
in ``tests/test_water_models.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from md.water.topology import TIP4PParameters, topology_text

__all__ = [
    "MODELS",
    "MODEL_NAMES",
    "PAPER_TIP4P_ESTIMATES",
    "WIDE_EPSILON_FACTORS",
    "WaterModel",
    "get_model",
    "model_prior",
    "polarisation_correction_kj_mol",
    "three_site_defines",
    "three_site_topology_text",
    "topology_for",
]

#: Debye per (e nm): 1 e nm = 1.602176634e-28 C m and 1 D = 3.33564e-30 C m.
DEBYE_PER_E_NM = 1.602176634e-28 / 3.33564095e-30
#: Dipole moment of an isolated water molecule (D), as used by Berendsen et al. (1987).
GAS_DIPOLE_DEBYE = 1.85
#: Polarisability of water (F m^2), as used by Berendsen et al. (1987): 4 pi eps0 x 1.444 A^3.
POLARISABILITY_F_M2 = 1.608e-40
_AVOGADRO = 6.02214076e23


@dataclass(frozen=True)
class WaterModel:
    """One published rigid water model.

    Attributes
    ----------
    name : str
        Display name, e.g. ``"TIP4P/2005"``.
    num_sites : {3, 4}
        3: charges on O and H; 4: charges on H and a massless M site on the HOH bisector.
    charge_h_e : float
        Hydrogen charge (e); the O (3 sites) or M (4 sites) carries ``-2 charge_h_e``.
    oh_distance_nm : float
    hoh_angle_deg : float
    om_distance_nm : float
        O-M distance (nm) along the bisector; 0.0 for 3-site models.
    sigma_oo_nm, epsilon_oo_kj_mol : float
        Oxygen-oxygen Lennard-Jones parameters; no other site has Lennard-Jones.
    citation : str
    """

    name: str
    num_sites: int
    charge_h_e: float
    oh_distance_nm: float
    hoh_angle_deg: float
    om_distance_nm: float
    sigma_oo_nm: float
    epsilon_oo_kj_mol: float
    citation: str

    def __post_init__(self) -> None:
        if self.num_sites not in (3, 4):
            raise ValueError(f"{self.name}: num_sites must be 3 or 4, got {self.num_sites!r}")
        for field in ("charge_h_e", "oh_distance_nm", "hoh_angle_deg", "sigma_oo_nm", "epsilon_oo_kj_mol"):
            value = getattr(self, field)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{self.name}: {field} must be finite and > 0, got {value!r}")
        if self.num_sites == 4 and not self.om_distance_nm > 0:
            raise ValueError(f"{self.name}: a 4-site model needs om_distance_nm > 0, got {self.om_distance_nm!r}")
        if self.num_sites == 3 and self.om_distance_nm != 0.0:
            raise ValueError(f"{self.name}: a 3-site model has no M site; set om_distance_nm=0.0")

    @property
    def hh_distance_nm(self) -> float:
        """H-H distance (nm) from r_OH and the HOH angle (SETTLE needs it)."""
        return 2.0 * self.oh_distance_nm * math.sin(math.radians(self.hoh_angle_deg) / 2.0)

    @property
    def dipole_debye(self) -> float:
        """Dipole moment of the rigid molecule (D), from the charges and geometry."""
        bisector = self.oh_distance_nm * math.cos(math.radians(self.hoh_angle_deg) / 2.0)
        return 2.0 * self.charge_h_e * (bisector - self.om_distance_nm) * DEBYE_PER_E_NM

    @property
    def lj(self) -> tuple[float, float]:
        """``(sigma_OO nm, epsilon_OO kJ/mol)``, the calibrated pair; the prior's centre."""
        return (self.sigma_oo_nm, self.epsilon_oo_kj_mol)

    @property
    def slug(self) -> str:
        """File-name-safe name, e.g. ``"tip4p2005"``."""
        return "".join(c for c in self.name.lower() if c.isalnum())

    def with_lj(self, sigma_oo_nm: float, epsilon_oo_kj_mol: float) -> WaterModel:
        """The same model with other oxygen Lennard-Jones parameters."""
        return replace(self, sigma_oo_nm=float(sigma_oo_nm), epsilon_oo_kj_mol=float(epsilon_oo_kj_mol))

    def tip4p_parameters(self) -> TIP4PParameters:
        """The frozen TIP4P topology's parameters for this 4-site model.

        Raises
        ------
        ValueError
            For a 3-site model (use :func:`three_site_topology_text`).
        """
        if self.num_sites != 4:
            raise ValueError(f"{self.name} has 3 sites; the TIP4P topology needs an M site")
        return TIP4PParameters(
            sigma_ow_nm=self.sigma_oo_nm,
            epsilon_ow_kj_mol=self.epsilon_oo_kj_mol,
            charge_h_e=self.charge_h_e,
            om_distance_nm=self.om_distance_nm,
            oh_distance_nm=self.oh_distance_nm,
            hh_distance_nm=round(self.hh_distance_nm, 5),
        )


def _kelvin_to_kj_mol(epsilon_over_k: float) -> float:
    return epsilon_over_k * 1.380649e-23 * _AVOGADRO / 1e3


MODELS: dict[str, WaterModel] = {
    m.name: m
    for m in (
        WaterModel(
            "TIP4P",
            4,
            0.52,
            0.09572,
            104.52,
            0.015,
            0.315365,
            0.648520,  # 0.155 kcal/mol
            "Jorgensen, Chandrasekhar, Madura, Impey & Klein 1983, J. Chem. Phys. 79, 926",
        ),
        WaterModel(
            "TIP4P/2005",
            4,
            0.5564,
            0.09572,
            104.52,
            0.01546,
            0.31589,
            _kelvin_to_kj_mol(93.2),  # published as epsilon/k = 93.2 K
            "Abascal & Vega 2005, J. Chem. Phys. 123, 234505",
        ),
        WaterModel(
            "TIP4P-Ew",
            4,
            0.52422,
            0.09572,
            104.52,
            0.0125,
            0.316435,
            0.680946,  # 0.16275 kcal/mol
            "Horn, Swope, Pitera, Madura, Dick, Hura & Head-Gordon 2004, J. Chem. Phys. 120, 9665",
        ),
        WaterModel(
            "SPC/E",
            3,
            0.4238,
            0.1,
            109.47,
            0.0,
            0.316557,
            0.650194,
            "Berendsen, Grigera & Straatsma 1987, J. Phys. Chem. 91, 6269",
        ),
        WaterModel(
            "TIP3P",
            3,
            0.417,
            0.09572,
            104.52,
            0.0,
            0.315061,
            0.636386,  # 0.1521 kcal/mol
            "Jorgensen, Chandrasekhar, Madura, Impey & Klein 1983, J. Chem. Phys. 79, 926",
        ),
    )
}
MODEL_NAMES: tuple[str, ...] = tuple(MODELS)

#: TIP4P calibrations of Dutta, Brotzakis & Mira (2018), Figs. 5-7: Bayes estimate
#: (sigma_OO nm, epsilon_OO kJ/mol) and posterior correlation, by dataset.
PAPER_TIP4P_ESTIMATES: dict[str, dict[str, Any]] = {
    "simulated": {"bayes_estimate": [0.3153, 0.646], "correlation": -0.994},
    "neutron": {"bayes_estimate": [0.319, 0.614], "correlation": -0.95},
    "xray": {"bayes_estimate": [0.326, 0.607], "correlation": -0.99},
}


#: Epsilon bounds (multiples of the published value) of the wide prior: every model stays a
#: liquid in the quick preset between them (measured: ``benchmarks/water_prior_range.py``); at the
#: upper bound its g_OO has lost the tetrahedral second shell, so the box spans everything
#: water-like with room to spare.
WIDE_EPSILON_FACTORS: tuple[float, float] = (0.6, 2.5)


def get_model(name: str | WaterModel) -> WaterModel:
    """Look a model up by name (case and punctuation ignored: ``"tip4p2005"`` works)."""
    if isinstance(name, WaterModel):
        return name
    wanted = "".join(c for c in str(name).lower() if c.isalnum())
    for model in MODELS.values():
        if model.slug == wanted:
            return model
    raise ValueError(f"unknown water model {name!r}; choose one of {list(MODEL_NAMES)}")


def polarisation_correction_kj_mol(model: WaterModel) -> float:
    """Berendsen et al.'s (1987) self-polarisation energy ``(mu - mu_gas)^2 / (2 alpha)``.

    A rigid non-polarisable model carries its liquid-phase dipole into the gas phase, so its
    ``-U/N`` overstates the cohesive energy by this amount (kJ/mol); subtract it from the
    model's enthalpy of vaporisation before comparing with experiment.
    """
    delta = (model.dipole_debye - GAS_DIPOLE_DEBYE) * 3.33564095e-30  # C m
    return delta**2 / (2.0 * POLARISABILITY_F_M2) * _AVOGADRO / 1e3


def three_site_topology_text(num_molecules: int, model: WaterModel) -> str:
    """A self-contained GROMACS topology for a 3-site model, LJ and charges as macros.

    The macros ``SIGMA_OW``, ``EPSILON_OW``, ``Q_H`` and ``Q_O`` default to ``model``'s values
    and are overridden per run by the ``define`` line (:func:`three_site_defines`).  Atoms are
    O, H, H per molecule, the order of GROMACS's ``spc216.gro``.
    """
    if model.num_sites != 3:
        raise ValueError(f"{model.name} has {model.num_sites} sites; use topology_for()")
    q_o = -2.0 * model.charge_h_e
    return f"""; jaxabc {model.name} water topology (self-contained; parameters are macros)
; {model.citation}
#ifndef SIGMA_OW
#define SIGMA_OW {model.sigma_oo_nm!r}
#endif
#ifndef EPSILON_OW
#define EPSILON_OW {model.epsilon_oo_kj_mol!r}
#endif
#ifndef Q_H
#define Q_H {model.charge_h_e!r}
#endif
#ifndef Q_O
#define Q_O {q_o!r}
#endif

[ defaults ]
; nbfunc  comb-rule  gen-pairs  fudgeLJ  fudgeQQ
1         2          no         1.0      1.0

[ atomtypes ]
; name  at.num  mass     charge  ptype  sigma     epsilon
OW      8       15.9994  0.0     A      SIGMA_OW  EPSILON_OW
HW      1       1.008    0.0     A      0.0       0.0

[ moleculetype ]
; name  nrexcl
SOL     2

[ atoms ]
; nr  type  resnr  res  atom  cgnr  charge  mass
1     OW    1      SOL  OW    1     Q_O     15.9994
2     HW    1      SOL  HW1   1     Q_H     1.008
3     HW    1      SOL  HW2   1     Q_H     1.008

[ settles ]
; OW  funct  doh  dhh
1     1      {model.oh_distance_nm!r}  {round(model.hh_distance_nm, 5)!r}

[ exclusions ]
1 2 3
2 1 3
3 1 2

[ system ]
{model.name} water

[ molecules ]
SOL {num_molecules}
"""


def three_site_defines(model: WaterModel) -> str:
    """The ``.mdp`` ``define`` line for :func:`three_site_topology_text`."""
    return (
        f"-DSIGMA_OW={model.sigma_oo_nm!r} -DEPSILON_OW={model.epsilon_oo_kj_mol!r} "
        f"-DQ_H={model.charge_h_e!r} -DQ_O={-2.0 * model.charge_h_e!r}"
    )


def topology_for(model: WaterModel | str, num_molecules: int) -> str:
    """The GROMACS topology of ``num_molecules`` waters of ``model`` (3 or 4 sites)."""
    model = get_model(model)
    if model.num_sites == 4:
        return topology_text(num_molecules, model.tip4p_parameters())
    return three_site_topology_text(num_molecules, model)


def model_prior(
    model: WaterModel | str,
    relative_half_width: tuple[float, float] = (0.05, 0.4),
    epsilon_factors: tuple[float, float] | None = None,
):
    """A uniform prior on ``(sigma_OO, epsilon_OO)`` around the model's published values.

    Parameters
    ----------
    model : WaterModel or str
    relative_half_width : (float, float)
        Half-widths as fractions of the published sigma and epsilon; each in (0, 1).  The
        default keeps every model's box inside the range where the quick preset stays liquid
        for TIP4P (the paper's prior U[0.281, 0.53] x U[0.2, 0.9] is mostly vapour).
    epsilon_factors : (float, float), optional
        Bounds of epsilon as multiples of the published value, e.g. ``(0.6, 2.5)``; replaces
        the epsilon half-width (an asymmetric box: epsilon cannot go below 0, and the
        calibrations pile against +40 %).  :data:`WIDE_EPSILON_FACTORS` is the range measured
        to stay liquid in the quick preset (``benchmarks/results/water_prior_range.json``).

    Returns
    -------
    jaxabc.Uniform
        Names ``("sigma_OO", "epsilon_OO")``, units ``("nm", "kJ/mol")``.
    """
    from jaxabc import Uniform

    model = get_model(model)
    widths = np.asarray(relative_half_width, dtype=float)
    if widths.shape != (2,) or not np.all((widths > 0) & (widths < 1)):
        raise ValueError(f"relative_half_width must be two fractions in (0, 1), got {relative_half_width!r}")
    centre = np.asarray(model.lj)
    low, high = centre * (1 - widths), centre * (1 + widths)
    if epsilon_factors is not None:
        factors = np.asarray(epsilon_factors, dtype=float)
        if factors.shape != (2,) or not (np.all(np.isfinite(factors)) and 0 < factors[0] < factors[1]):
            raise ValueError(f"epsilon_factors must be (low, high) with 0 < low < high, got {epsilon_factors!r}")
        low[1], high[1] = centre[1] * factors
    return Uniform(
        low=low.tolist(),
        high=high.tolist(),
        names=("sigma_OO", "epsilon_OO"),
        units=("nm", "kJ/mol"),
    )
