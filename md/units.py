"""Units of the in-process MD engine: nm, ps, amu, kJ/mol, and conversions.

The engine works in a consistent molecular unit system: length nm, time ps, mass amu (g/mol),
energy kJ/mol.  It is consistent because 1 amu nm^2 ps^-2 = 1.66054e-27 kg * 1e-18 m^2 / 1e-24 s^2
= 1.66054e-21 J, which is 1.0000 kJ/mol after multiplying by Avogadro's number; so forces come out
in kJ/mol/nm and no conversion factor appears in the equations of motion.  Temperatures enter as
``k_B T`` in kJ/mol, pressures in kJ/mol/nm^3.

The helium paper (Dutta et al. 2018) quotes epsilon in zJ (LAMMPS ``units nano``): use
:func:`zj_to_kj_mol`.  :class:`ReducedLJUnits` converts to and from Lennard-Jones reduced units
(sigma, epsilon, mass = 1), in which the Johnson-Zollweg-Gubbins equation of state is written.

All constants are derived from the exact 2019 SI values (N_A, k_B, h, e) so they can be checked.
"""

from __future__ import annotations

import dataclasses
import math

__all__ = [
    "AMU_IN_KG",
    "ARGON_MASS_AMU",
    "ATM_IN_KJ_MOL_NM3",
    "AVOGADRO",
    "BAR_IN_KJ_MOL_NM3",
    "BOLTZMANN_KJ_MOL_K",
    "HBAR_KJ_MOL_PS",
    "HELIUM_MASS_AMU",
    "ZJ_IN_KJ_MOL",
    "ReducedLJUnits",
    "atm_to_kj_mol_nm3",
    "kelvin_to_kt",
    "kj_mol_nm3_to_atm",
    "kj_mol_to_zj",
    "zj_to_kj_mol",
]

#: Avogadro constant, 1/mol (exact).
AVOGADRO = 6.02214076e23
#: Boltzmann constant, J/K (exact).
_BOLTZMANN_J_K = 1.380649e-23
#: Boltzmann constant in kJ/mol/K: k_B * N_A / 1000 = 0.00831446 (the gas constant R / 1000).
BOLTZMANN_KJ_MOL_K = _BOLTZMANN_J_K * AVOGADRO / 1000.0
#: One zeptojoule (1e-21 J) per atom in kJ/mol: 1e-21 * N_A / 1000 = 0.602214076.
ZJ_IN_KJ_MOL = 1e-21 * AVOGADRO / 1000.0
#: One standard atmosphere (101325 Pa = J/m^3) in kJ/mol/nm^3: 101325 * 1e-27 * N_A / 1000.
ATM_IN_KJ_MOL_NM3 = 101325.0 * 1e-27 * AVOGADRO / 1000.0
#: One bar (1e5 Pa) in kJ/mol/nm^3.
BAR_IN_KJ_MOL_NM3 = 1e5 * 1e-27 * AVOGADRO / 1000.0
#: Reduced Planck constant in kJ/mol * ps: 1.054571817e-34 J s * N_A / 1000 * 1e12 ps/s.
HBAR_KJ_MOL_PS = 6.62607015e-34 / (2.0 * math.pi) * AVOGADRO / 1000.0 * 1e12
#: Atomic mass unit in kg (CODATA 2018).
AMU_IN_KG = 1.66053906660e-27
#: Helium-4 atomic mass, amu.  The paper gives 6.64e-6 attogram = 3.999 amu; 4.0026 is the
#: standard atomic weight that LAMMPS ``units nano`` reproduces to the quoted precision.
HELIUM_MASS_AMU = 4.0026
#: Argon atomic mass, amu.
ARGON_MASS_AMU = 39.948


def zj_to_kj_mol(energy_zj: float) -> float:
    """Convert a per-atom energy from zJ (1e-21 J) to kJ/mol; works on arrays too."""
    return energy_zj * ZJ_IN_KJ_MOL


def kj_mol_to_zj(energy_kj_mol: float) -> float:
    """Convert an energy from kJ/mol to zJ per atom; works on arrays too."""
    return energy_kj_mol / ZJ_IN_KJ_MOL


def atm_to_kj_mol_nm3(pressure_atm: float) -> float:
    """Convert a pressure from atm to kJ/mol/nm^3 (1 atm = 0.0610193 kJ/mol/nm^3)."""
    return pressure_atm * ATM_IN_KJ_MOL_NM3


def kj_mol_nm3_to_atm(pressure: float) -> float:
    """Convert a pressure from kJ/mol/nm^3 to atm."""
    return pressure / ATM_IN_KJ_MOL_NM3


def kelvin_to_kt(temperature_k: float) -> float:
    """Return k_B T in kJ/mol for a temperature in K."""
    return temperature_k * BOLTZMANN_KJ_MOL_K


@dataclasses.dataclass(frozen=True)
class ReducedLJUnits:
    """Lennard-Jones reduced units for one (sigma, epsilon, mass).

    Parameters
    ----------
    sigma_nm : float
        Length unit sigma, nm.
    epsilon_kj_mol : float
        Energy unit epsilon, kJ/mol.
    mass_amu : float
        Mass unit, amu.

    Notes
    -----
    Reduced quantities: r* = r / sigma, T* = k_B T / epsilon, rho* = rho sigma^3,
    P* = P sigma^3 / epsilon, E* = E / epsilon, t* = t / tau with
    tau = sigma sqrt(m / epsilon) (in ps here, since the base units are consistent).
    """

    sigma_nm: float
    epsilon_kj_mol: float
    mass_amu: float = 1.0

    @classmethod
    def argon(cls) -> ReducedLJUnits:
        """Argon-like LJ: sigma 0.3405 nm, epsilon/k_B 119.8 K, mass 39.948 amu."""
        return cls(0.3405, 119.8 * BOLTZMANN_KJ_MOL_K, ARGON_MASS_AMU)

    @property
    def time_ps(self) -> float:
        """The LJ time unit tau = sigma sqrt(m / epsilon), ps."""
        return self.sigma_nm * math.sqrt(self.mass_amu / self.epsilon_kj_mol)

    def temperature_k(self, temperature_reduced: float) -> float:
        """T in K for a reduced temperature T* = k_B T / epsilon."""
        return temperature_reduced * self.epsilon_kj_mol / BOLTZMANN_KJ_MOL_K

    def reduced_temperature(self, temperature_k: float) -> float:
        """T* = k_B T / epsilon for T in K."""
        return temperature_k * BOLTZMANN_KJ_MOL_K / self.epsilon_kj_mol

    def number_density_nm3(self, density_reduced: float) -> float:
        """Number density in 1/nm^3 for rho* = rho sigma^3."""
        return density_reduced / self.sigma_nm**3

    def reduced_density(self, number_density_nm3: float) -> float:
        """rho* = rho sigma^3 for rho in 1/nm^3."""
        return number_density_nm3 * self.sigma_nm**3

    def pressure_kj_mol_nm3(self, pressure_reduced: float) -> float:
        """Pressure in kJ/mol/nm^3 for P* = P sigma^3 / epsilon."""
        return pressure_reduced * self.epsilon_kj_mol / self.sigma_nm**3

    def reduced_pressure(self, pressure_kj_mol_nm3: float) -> float:
        """P* = P sigma^3 / epsilon for P in kJ/mol/nm^3."""
        return pressure_kj_mol_nm3 * self.sigma_nm**3 / self.epsilon_kj_mol

    def energy_kj_mol(self, energy_reduced: float) -> float:
        """Energy in kJ/mol for E* = E / epsilon."""
        return energy_reduced * self.epsilon_kj_mol

    def reduced_energy(self, energy_kj_mol: float) -> float:
        """E* = E / epsilon for E in kJ/mol."""
        return energy_kj_mol / self.epsilon_kj_mol
