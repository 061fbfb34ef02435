"""Write the neon and argon "measured" data files from CoolProp's reference equations of state.

Run ``python -m md.fluids.generate`` (needs ``pip install jaxabc[fluids]``); it rewrites
``md/fluids/data/<fluid>/*.csv`` and ``PROVENANCE.md``.  The values are those of the reference
Helmholtz-energy equations, which are fitted to measurements; the uncertainties attached are
the ones documented in :data:`FLUIDS` (see each PROVENANCE.md for which are stated by the
equation's authors and which are conservative assumptions).
"""

from __future__ import annotations

import csv
from pathlib import Path

DATA = Path(__file__).with_name("data")

# Grids and uncertainties per fluid.  Relative uncertainties are fractions.
FLUIDS: dict[str, dict] = {
    "neon": dict(
        coolprop="Neon",
        equation="Thol, Beckmueller, Weiss, Harvey, Lemmon, Jacobsen & Span (2019), Helmholtz-energy "
        "equation of state for neon (CoolProp key Thol-JPCRD-2019-Neon)",
        liquid_isotherms_k=[26.0, 30.0, 34.0, 38.0, 42.0],
        supercritical_isotherms_k=[50.0, 60.0],
        compression=[1.00, 1.03, 1.06],  # rho / rho_sat_liquid(T) on liquid isotherms
        supercritical_density_ratio=[2.0, 2.2, 2.4],  # rho / rho_c on supercritical isotherms
        saturation_k=[25.0, 26.0, 28.0, 30.0, 32.0, 34.0, 36.0, 38.0, 40.0, 42.0, 43.0],
        b2_k=[25.0, 27.0, 30.0, 35.0, 40.0, 50.0, 70.0, 100.0, 150.0, 200.0, 300.0],
        u_rho=0.002,
        u_energy=0.01,
        u_b2_rel=0.01,
        u_b2_abs=0.5e-6,
        potentials=(
            "Reference pair potentials (used by `md.fluids.pair_b2`, coded there from the published "
            "parameters, not from files):\n\n"
            "- Tang & Toennies, J. Chem. Phys. 118, 4976 (2003), Ne2: A = 199.5 hartree, b = 2.458 / bohr, "
            "C6 = 6.383, C8 = 90.34, C10 = 1536 (atomic units); well depth 42.37 K at 3.090 Angstrom "
            "(computed here).\n"
            "- Aziz & Slaman, Chem. Phys. 130, 187 (1989), Ne2 HFD-B: eps / k = 42.25 K, r_m = 3.091 Angstrom, "
            "A* = 895717.95, alpha* = 13.86434671, beta* = -0.12993822, C6 = 1.21317545, C8 = 0.53222749, "
            "C10 = 0.24570703, D = 1.36.\n\n"
            "The B2 points at 25 and 27 K lie just above the triple point (24.56 K), where gas-phase "
            "measurements are few; the 1 % uncertainty there is an assumption, not the equation authors' "
            "statement."
        ),
    ),
    "argon": dict(
        coolprop="Argon",
        equation="Tegeler, Span & Wagner (1999), J. Phys. Chem. Ref. Data 28, 779: reference "
        "equation of state for argon (CoolProp key Tegeler-JPCRD-1999)",
        liquid_isotherms_k=[90.0, 100.0, 110.0, 120.0, 130.0, 140.0],
        supercritical_isotherms_k=[160.0, 200.0],
        compression=[1.00, 1.03, 1.06],
        supercritical_density_ratio=[2.0, 2.2, 2.4],
        saturation_k=[85.0, 90.0, 100.0, 110.0, 120.0, 130.0, 140.0, 145.0],
        b2_k=[90.0, 110.0, 130.0, 160.0, 200.0, 300.0, 400.0, 600.0],
        u_rho=0.001,
        u_energy=0.005,
        u_b2_rel=0.01,
        u_b2_abs=0.5e-6,
        potentials=(
            "Literature values used beside these data (in code, not files):\n\n"
            "- Lennard-Jones 12-6 at the gas-data parameters of Hirschfelder, Curtiss & Bird, Molecular "
            "Theory of Gases and Liquids (1954), table I-A: sigma = 3.405 Angstrom, epsilon / k = 119.8 K "
            "(`md.fluids.LITERATURE_LJ`; prior centres and the B2 design's LJ, not truths).\n"
            "- Axilrod-Teller triple-dipole coefficient C9 = 521 hartree bohr^9 (Kumar & Meath, Mol. Phys. "
            "54, 823 (1985), dipole oscillator-strength distributions; `md.fluids.simulator.C9_ATOMIC`): the "
            "value the refitted three-body term is compared with."
        ),
    ),
}


def _write(path: Path, header: list[str], rows: list[list]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        for row in rows:
            w.writerow([f"{v:.10g}" if isinstance(v, float) else v for v in row])


def generate(fluid: str, data_dir: Path = DATA) -> dict[str, int | str]:
    """Write one fluid's CSV files and PROVENANCE.md under ``data_dir / fluid``; returns row counts."""
    import CoolProp
    from CoolProp.CoolProp import PropsSI

    cfg = FLUIDS[fluid]
    name = cfg["coolprop"]
    out = Path(data_dir) / fluid
    out.mkdir(parents=True, exist_ok=True)
    state = CoolProp.AbstractState("HEOS", name)  # pyright: ignore[reportPrivateImportUsage] (exported by the compiled module)
    r_gas = state.gas_constant()
    rho_c = PropsSI("rhomolar_critical", name)

    points = [
        (t, f * PropsSI("Dmolar", "T", t, "Q", 0, name), "liquid")
        for t in cfg["liquid_isotherms_k"]
        for f in cfg["compression"]
    ]
    points += [
        (t, f * rho_c, "supercritical")
        for t in cfg["supercritical_isotherms_k"]
        for f in cfg["supercritical_density_ratio"]
    ]
    rows = []
    for t, rho, phase in points:
        state.update(CoolProp.DmolarT_INPUTS, rho, t)
        p = state.p()
        # Residual (configurational) energy: u_res / (R T) = tau * d alpha_r / d tau.
        u_res = r_gas * t * state.tau() * state.dalphar_dTau()
        # A relative density uncertainty u_rho maps to pressure through the isothermal stiffness.
        dp_drho = state.first_partial_deriv(CoolProp.iP, CoolProp.iDmolar, CoolProp.iT)
        rows.append([t, rho, phase, p, rho * dp_drho * cfg["u_rho"], u_res, abs(u_res) * cfg["u_energy"]])
    _write(
        out / "state_points.csv", ["T_K", "rho_mol_m3", "phase", "P_Pa", "u_P_Pa", "U_res_J_mol", "u_U_res_J_mol"], rows
    )

    sat = [
        [
            t,
            PropsSI("Dmolar", "T", t, "Q", 0, name),
            PropsSI("Dmolar", "T", t, "Q", 0, name) * cfg["u_rho"],
            PropsSI("P", "T", t, "Q", 0, name),
        ]
        for t in cfg["saturation_k"]
    ]
    _write(out / "saturated_liquid.csv", ["T_K", "rho_liquid_mol_m3", "u_rho_mol_m3", "P_sat_Pa"], sat)

    b2 = []
    for t in cfg["b2_k"]:
        state.update(CoolProp.DmolarT_INPUTS, 1e-3, t)
        b = state.Bvirial()
        b2.append([t, b, max(cfg["u_b2_rel"] * abs(b), cfg["u_b2_abs"])])
    _write(out / "b2.csv", ["T_K", "B2_m3_mol", "u_B2_m3_mol"], b2)
    (out / "PROVENANCE.md").write_text(_provenance(fluid, cfg, CoolProp.__version__, len(rows)))
    return dict(state_points=len(rows), saturated_liquid=len(sat), b2=len(b2), coolprop=CoolProp.__version__)


def _provenance(fluid: str, cfg: dict, version: str, num_points: int) -> str:
    potentials = f"\n## Potentials and coefficients\n\n{cfg['potentials']}\n" if cfg.get("potentials") else ""
    return f"""# {fluid.capitalize()}: provenance

**What these numbers are.** Values of a reference equation of state, not raw measurements. The
equation is a Helmholtz-energy correlation fitted by its authors to the measured pressure-density-
temperature, caloric, speed-of-sound and phase-equilibrium data of {fluid}; within its stated
uncertainty it represents those measurements. Raw measured points are not redistributed here
(no maintained package ships them in machine-readable form).

- Source: CoolProp {version} (`pip install coolprop`), backend `HEOS`, fluid `{cfg["coolprop"]}`.
- Equation: {cfg["equation"]}.
- Generated by `python -m md.fluids.generate` (this file is rewritten with the data).

## Files and state points

- `state_points.csv` ({num_points} rows): pressure `P_Pa` and residual (configurational) molar
  internal energy `U_res_J_mol = R T tau d(alpha_r)/d(tau)` at fixed (T, rho). Liquid isotherms
  {cfg["liquid_isotherms_k"]} K at rho / rho_sat,liquid(T) = {cfg["compression"]}; dense
  supercritical isotherms {cfg["supercritical_isotherms_k"]} K at rho / rho_c =
  {cfg["supercritical_density_ratio"]}.
- `saturated_liquid.csv`: saturated-liquid density and vapour pressure at {cfg["saturation_k"]} K.
- `b2.csv`: second virial coefficient B2(T) of the equation (its zero-density limit) at
  {cfg["b2_k"]} K.

## Uncertainties used as measurement errors

- Density: relative {100 * cfg["u_rho"]:.2g} % (saturated-liquid density column `u_rho_mol_m3`).
  Pressure at fixed (T, rho): the density uncertainty propagated through the isothermal
  stiffness, `u_P = rho (dP/drho)_T u_rho`; in a liquid this is hundreds of kPa.
- Residual energy: relative {100 * cfg["u_energy"]:.2g} %.
- B2: the larger of {100 * cfg["u_b2_rel"]:.2g} % and {cfg["u_b2_abs"] * 1e6:.2g} cm^3/mol.

These are deliberately conservative round values at or above the uncertainties the equation's
authors state for the liquid and gas regions (the published argon equation claims about 0.02-0.03 %
in liquid density below 30 MPa and 0.2-2 % in heat capacities); they have not been checked line
by line against the papers' uncertainty tables, and the energy and B2 values are assumptions in
the spirit of the caloric and gas-phase uncertainties. The model errors of a 64-500 atom LJ
simulation are far larger than any of them.
{potentials}"""


if __name__ == "__main__":
    for f in FLUIDS:
        print(f, generate(f))
