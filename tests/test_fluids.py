"""Measured neon/argon data (reference equations via CoolProp) and the B2(T) quadrature."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate

from md.fluids.virial import b2_lj, b2_lj_series, b2_reduced, fh_coefficient, lj_fh_potential


def test_b2_quadrature_matches_the_exact_series_and_tables():
    t = np.array([0.6, 0.8, 1.0, 1.5, 2.5, 5.0, 20.0])
    np.testing.assert_allclose(b2_lj(t), b2_lj_series(t), rtol=1e-8, atol=1e-9)
    # Hirschfelder, Curtiss & Bird, table I-B: B2 / (2 pi N_A sigma^3 / 3) = -2.5381 at T* = 1.
    assert b2_reduced(1.0) / (2 * np.pi / 3) == pytest.approx(-2.5381, abs=1e-4)
    # The Boyle temperature T*_B = 3.4179 (B2 = 0).
    assert b2_reduced(3.41) < 0 < b2_reduced(3.425)


@pytest.mark.parametrize("temperature", [0.8, 1.5, 4.0])
def test_feynman_hibbs_b2_matches_first_order_wigner_kirkwood(temperature):
    """To first order in D*, FH adds (2 pi / T*^2) D* int exp(-u/T*) u'^2 r^2 dr to B2*, the
    Wigner-Kirkwood first quantum correction (HCB eq. 6.5-10 with D = hbar^2 / (12 m k T))."""

    def integrand(r):
        u = lj_fh_potential(r)
        du = 4.0 * (-12.0 * r**-13 + 6.0 * r**-7)
        return np.exp(-u / temperature) * du * du * r * r

    wk = (
        2
        * np.pi
        / temperature**2
        * sum(integrate.quad(integrand, a, b, limit=200)[0] for a, b in ((0.5, 1.0), (1.0, 2.0), (2.0, 20.0)))
    )
    # Richardson extrapolation of the forward difference removes the O(D*) second-order term.
    d, b0 = 1e-5, b2_reduced(temperature, 0.0)
    s1, s2 = (b2_reduced(temperature, d) - b0) / d, (b2_reduced(temperature, 2 * d) - b0) / (2 * d)
    assert 2 * s1 - s2 == pytest.approx(wk, rel=1e-4)
    assert wk > 0  # quantum effects raise B2 (a softer effective attraction)


def test_fh_coefficient_units_and_errors():
    # hbar^2 / (24 (m/2) k T sigma^2) for neon-like m = 20.18 u, sigma = 2.75 A, T = 30 K
    d = fh_coefficient(30.0, 20.18, 2.75e-10)
    expect = (1.054571817e-34) ** 2 / (12 * 20.18 * 1.66053906660e-27 * 1.380649e-23 * 30.0 * (2.75e-10) ** 2)
    assert d == pytest.approx(expect, rel=1e-12)
    assert fh_coefficient(60.0, 20.18, 2.75e-10) == pytest.approx(d / 2)
    with pytest.raises(ValueError, match="positive"):
        fh_coefficient(0.0, 20.18, 2.75e-10)
    with pytest.raises(ValueError, match="d_star"):
        b2_reduced(1.0, -0.1)


# -- the data sets ---------------------------------------------------------------------------------

from md.fluids import LITERATURE_LJ, load  # noqa: E402


@pytest.mark.parametrize("fluid", ["neon", "argon"])
def test_data_load_and_are_thermodynamically_consistent(fluid):
    d = load(fluid)
    sp = d.state_points
    assert len(sp) >= 20 and set(sp["phase"]) == {"liquid", "supercritical"}
    assert np.all(sp["u_P_Pa"] > 0) and np.all(sp["u_U_res_J_mol"] > 0) and np.all(sp["U_res_J_mol"] < 0)
    # On the saturation line (rho = rho_sat,liquid) the pressure is the vapour pressure.
    sl = d.saturated_liquid
    on_line = 0
    for row in sp[sp["phase"] == "liquid"]:
        match = np.isclose(sl["T_K"], row["T_K"]) & np.isclose(sl["rho_liquid_mol_m3"], row["rho_mol_m3"], rtol=1e-8)
        if match.any():
            on_line += 1
            assert abs(row["P_Pa"] - sl["P_sat_Pa"][match][0]) < 0.01 * row["u_P_Pa"]
    assert on_line == len(np.unique(sp["T_K"][sp["phase"] == "liquid"]))
    # Compressing a liquid raises P and lowers U_res along each isotherm.
    for t in np.unique(sp["T_K"]):
        rows = sp[sp["T_K"] == t]
        assert np.all(np.diff(rows["P_Pa"]) > 0) and np.all(np.diff(rows["U_res_J_mol"]) < 0)
    assert "not raw measurements" in d.provenance and "fitted by its authors" in d.provenance


def test_argon_b2_matches_classical_lj_at_gas_temperatures():
    """The HCB argon LJ parameters were fitted to B2: within 3 cm^3/mol of the reference from
    160 to 600 K (the absolute scale of B2 there is 0-80 cm^3/mol), a units check on both."""
    d = load("argon")
    lj = LITERATURE_LJ["argon"]
    hot = d.b2["T_K"] >= 160
    t = d.b2["T_K"][hot]
    b2 = b2_lj(t / lj["epsilon_k"]) * 6.02214076e23 * lj["sigma_m"] ** 3
    np.testing.assert_allclose(b2 * 1e6, d.b2["B2_m3_mol"][hot] * 1e6, atol=3.0)


def test_load_rejects_unknown_fluid():
    with pytest.raises(ValueError, match="available"):
        load("xenon")


def test_committed_files_match_a_regeneration(tmp_path):
    pytest.importorskip("CoolProp")
    from md.fluids.generate import DATA, generate

    for fluid in ("neon", "argon"):
        generate(fluid, tmp_path)
        for name in ("state_points.csv", "saturated_liquid.csv", "b2.csv"):
            new = np.genfromtxt(tmp_path / fluid / name, delimiter=",", names=True, dtype=None, encoding="utf-8")
            old = np.genfromtxt(DATA / fluid / name, delimiter=",", names=True, dtype=None, encoding="utf-8")
            for col in old.dtype.names:
                if old[col].dtype.kind == "f":
                    np.testing.assert_allclose(new[col], old[col], rtol=1e-8)
