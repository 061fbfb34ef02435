"""Unit conversions of md.units checked against independent SI arithmetic."""

from __future__ import annotations

import math

import pytest

from md import units


def test_molecular_units_are_consistent():
    # 1 amu nm^2 / ps^2 must equal 1 kJ/mol for the equations of motion to need no factor.
    joule_per_atom = units.AMU_IN_KG * 1e-18 / 1e-24
    assert joule_per_atom * units.AVOGADRO / 1000.0 == pytest.approx(1.0, rel=1e-8)


def test_constants_against_si_values():
    assert units.BOLTZMANN_KJ_MOL_K == pytest.approx(8.314462618e-3, rel=1e-9)
    assert units.ZJ_IN_KJ_MOL == pytest.approx(0.602214076, rel=1e-12)
    # 1 atm = 101325 J/m^3; 1 m^3 = 1e27 nm^3.
    assert units.ATM_IN_KJ_MOL_NM3 == pytest.approx(0.0610193, rel=1e-6)
    assert units.BAR_IN_KJ_MOL_NM3 == pytest.approx(units.ATM_IN_KJ_MOL_NM3 / 1.01325, rel=1e-12)
    # hbar = 1.054571817e-34 J s.
    assert units.HBAR_KJ_MOL_PS == pytest.approx(1.054571817e-34 * 6.02214076e23 * 1e9, rel=1e-9)
    # The paper's helium mass, 6.64e-6 attogram, is 4.0 amu to its three digits.
    assert 6.64e-24 / (units.AMU_IN_KG * 1e3) == pytest.approx(units.HELIUM_MASS_AMU, rel=2e-3)


def test_conversions_round_trip():
    assert units.kj_mol_to_zj(units.zj_to_kj_mol(0.141)) == pytest.approx(0.141)
    assert units.kj_mol_nm3_to_atm(units.atm_to_kj_mol_nm3(100.0)) == pytest.approx(100.0)
    assert units.kelvin_to_kt(300.0) == pytest.approx(2.494338785, rel=1e-8)


def test_reduced_units_argon():
    ar = units.ReducedLJUnits.argon()
    # The textbook LJ time unit of argon is 2.15 ps.
    assert ar.time_ps == pytest.approx(2.156, abs=2e-3)
    assert ar.temperature_k(1.0) == pytest.approx(119.8)
    assert ar.reduced_temperature(ar.temperature_k(0.72)) == pytest.approx(0.72)
    assert ar.reduced_density(ar.number_density_nm3(0.8)) == pytest.approx(0.8)
    assert ar.reduced_pressure(ar.pressure_kj_mol_nm3(1.3)) == pytest.approx(1.3)
    assert ar.reduced_energy(ar.energy_kj_mol(-5.0)) == pytest.approx(-5.0)
    # rho* = 0.8 for argon is 1.38 g/cm^3-ish: rho [1/nm^3] * m / N_A.
    grams_per_cm3 = ar.number_density_nm3(0.8) * 1e21 * ar.mass_amu / units.AVOGADRO
    assert grams_per_cm3 == pytest.approx(1.3, rel=0.05)
    assert math.isclose(ar.sigma_nm, 0.3405)
