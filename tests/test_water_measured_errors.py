"""Measured water data: stated errors, Yeh-Hummer correction, temperature, second shell, priors.

Fast: no GROMACS runs (the simulator's finite-size step is tested on a stand-in).
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from md.water import datasets
from md.water.finite_size import (
    correct_diffusion,
    model_viscosity_mpa_s,
    water_viscosity_mpa_s,
    yeh_hummer_shift,
)
from md.water.joint_data import JOINT_NAMES, joint_observed, joint_record, observation_sd
from md.water.model_simulator import JOINT_SUMMARY_NAMES, WaterModelSimulator
from md.water.models import MODELS, WIDE_EPSILON_FACTORS, get_model, model_prior
from md.water.protocol import get_protocol
from md.water.statistics import SECOND_SHELL_NAMES, SECOND_SHELL_WINDOW_NM, second_shell_statistics

ROOT = Path(__file__).resolve().parents[1]
CURVE_RECORD = {"xray": "xray_goo", "neutron": "neutron_goo_goh"}
SCALAR_RECORD = {
    "S9": "self_diffusion_1e-5_cm2_s",
    "density_kg_m3": "density_kg_m3",
    "hvap_kj_mol": "hvap_kj_mol",
}


def test_names_agree_and_second_shell_is_appended():
    assert JOINT_NAMES == JOINT_SUMMARY_NAMES
    assert JOINT_NAMES[:11] == (*(f"S{i}" for i in range(1, 10)), "density_kg_m3", "hvap_kj_mol")
    assert JOINT_NAMES[11:] == SECOND_SHELL_NAMES


def test_xray_first_peak_height_carries_skinners_stated_error():
    record = joint_record()
    entry = record["curves"]["xray_goo"]["statistic_errors"]["S7"]
    assert entry["error"] >= 0.05  # Skinner et al. 2013: g_max = 2.57(5)
    assert record["curves"]["xray_goo"]["statistic_errors"]["S8"]["error"] >= 0.001  # r_max = 2.80(1) A
    data = joint_observed("xray")
    assert data.errors[JOINT_NAMES.index("S7")] >= 0.05
    assert data.errors[JOINT_NAMES.index("S8")] >= 0.001
    # The stated error wins over the (4x smaller) pointwise propagation.
    assert data.propagated[JOINT_NAMES.index("S7")] < 0.05


@pytest.mark.parametrize("kind", ["xray", "neutron"])
def test_every_fitted_summary_has_a_positive_error_with_source_and_meaning(kind):
    record = joint_record()
    data = joint_observed(kind)
    curve_errors = record["curves"][CURVE_RECORD[kind]]["statistic_errors"]
    for name in np.array(data.names)[data.fitted]:
        if name in SCALAR_RECORD:
            entry = record["scalars"][SCALAR_RECORD[name]]
            if abs(entry["temperature_k"] - data.temperature_k) > 1e-6:
                entry = entry["by_temperature_k"][f"{data.temperature_k:g}"]
        else:
            entry = curve_errors[name]
        assert entry["error"] > 0, name
        assert entry["error_meaning"].strip() and entry["source"].strip(), name
    # The adopted error is never below the file's error nor the pointwise propagation.
    i = data.fitted
    assert np.all(data.errors[i] > 0) and np.all(np.isfinite(data.errors[i]))
    finite = np.isfinite(data.propagated)
    assert np.all(data.errors[finite] >= data.propagated[finite])
    for name, entry in curve_errors.items():
        assert data.errors[JOINT_NAMES.index(name)] >= entry["error"]


@pytest.mark.parametrize("kind", ["xray", "neutron"])
def test_observation_sd_is_the_fitted_errors(kind):
    data = joint_observed(kind)
    sd = observation_sd(kind)
    assert sd.shape == (int(data.fitted.sum()),) == data.observed[data.fitted].shape
    np.testing.assert_array_equal(sd, data.errors[data.fitted])
    assert np.all(sd > 0)


def test_yeh_hummer_shift_against_a_hand_value():
    # TIP4P in the quick box: xi k_B T / (6 pi eta L) with L = 1.86 nm, eta = 0.494 mPa s, 298.15 K:
    # 2.837297 * 1.380649e-23 * 298.15 = 1.16796e-20 J; 6 pi * 0.494e-3 * 1.86e-9 = 1.73197e-11;
    # ratio 6.7434e-10 m^2/s = 0.67434e-5 cm^2/s.
    assert yeh_hummer_shift(1.86, 0.494, 298.15) == pytest.approx(0.67434, rel=1e-4)
    d_inf, shift = correct_diffusion(3.0, 1.86, 0.494, 298.15)
    assert shift == pytest.approx(0.67434, rel=1e-4) and d_inf == pytest.approx(3.67434, rel=1e-4)
    # Water's viscosity (IAPWS 2008: 0.8900 mPa s at 298.15 K, 0.9544 at 295.15 K) and the models'.
    assert water_viscosity_mpa_s(298.15) == pytest.approx(0.8900, rel=2e-3)
    assert water_viscosity_mpa_s(295.15) == pytest.approx(0.9544, rel=2e-3)
    assert model_viscosity_mpa_s("TIP4P", 298.0) == pytest.approx(0.494)
    assert model_viscosity_mpa_s("TIP4P", 295.15) > 0.494
    for name in MODELS:
        assert 0.2 < model_viscosity_mpa_s(name, 298.0) < 1.0


def test_simulator_applies_the_correction_to_s9_and_records_it():
    # The finite-size step alone, on a stand-in (no gmx needed).
    simulate = WaterModelSimulator.__new__(WaterModelSimulator)
    simulate.model = MODELS["TIP3P"]
    simulate.protocol = get_protocol("quick", temperature_k=295.15)
    simulate.statistics = "robust"
    simulate.finite_size_correction = True
    statistics = np.arange(9.0)
    box = np.full((5, 3), 1.9)
    corrected, record = simulate._finite_size(statistics, box)
    eta = model_viscosity_mpa_s("TIP3P", 295.15)
    expected = yeh_hummer_shift(1.9, eta, 295.15)
    assert record["shift"] == pytest.approx(expected) and record["box_nm"] == pytest.approx(1.9)
    assert record["d_box"] == 8.0 and corrected[8] == pytest.approx(8.0 + expected)
    np.testing.assert_array_equal(corrected[:8], statistics[:8])
    assert statistics[8] == 8.0  # the input is not modified
    simulate.finite_size_correction = False
    same, record = simulate._finite_size(statistics, box)
    assert same[8] == 8.0 and record["shift"] == 0.0


def test_xray_data_are_compared_at_their_own_temperature():
    xray, neutron = joint_observed("xray"), joint_observed("neutron")
    assert xray.temperature_k == 295.15 and neutron.temperature_k == 298.15
    assert datasets.xray_goo().temperature_k == xray.temperature_k
    i = {n: JOINT_NAMES.index(n) for n in ("S9", "density_kg_m3", "hvap_kj_mol")}
    # Water at 295.15 K: slower (Holz et al. 2000 fit), denser, higher enthalpy (IAPWS-95).
    assert xray.observed[i["S9"]] == pytest.approx(2.13, abs=0.005)
    assert neutron.observed[i["S9"]] == pytest.approx(2.30)
    assert xray.observed[i["density_kg_m3"]] == pytest.approx(997.77, abs=0.01)
    assert xray.observed[i["hvap_kj_mol"]] == pytest.approx(44.12, abs=0.01)
    assert neutron.observed[i["hvap_kj_mol"]] == pytest.approx(43.99)


def _analytic_goo(r):
    """A water-like g_OO: an onset, a first peak at 0.28, a dip, a broad second peak near 0.45 nm."""
    onset = 1.0 / (1.0 + np.exp(-(r - 0.255) / 0.004))
    shells = (
        1.0
        + 1.6 * np.exp(-0.5 * ((r - 0.28) / 0.016) ** 2)
        - 0.25 * np.exp(-0.5 * ((r - 0.345) / 0.025) ** 2)
        + 0.15 * np.exp(-0.5 * ((r - 0.45) / 0.035) ** 2)
    )
    return onset * shells


def _true_extremum(fine_r, fine_g, lo, hi, maximum):
    inside = (fine_r >= lo) & (fine_r <= hi)
    j = np.argmax(np.where(inside, fine_g if maximum else -fine_g, -np.inf))
    return fine_r[j], fine_g[j]


def test_second_shell_statistics_recover_an_analytic_curve():
    r = np.linspace(0.0, 1.0, 1001)  # 0.001 nm, as the X-ray file
    values = second_shell_statistics(r, _analytic_goo(r))
    fine_r = np.linspace(0.2, 0.8, 600_001)
    fine_g = _analytic_goo(fine_r)
    r_peak, _ = _true_extremum(fine_r, fine_g, 0.2, 0.8, True)
    _, g_min = _true_extremum(fine_r, fine_g, r_peak, 1.6 * r_peak, False)
    r2, g2 = _true_extremum(fine_r, fine_g, *SECOND_SHELL_WINDOW_NM, True)
    assert 0.43 < r2 < 0.47 and 1.1 < g2 < 1.2  # the curve is what the test means it to be
    # Within the 0.002 nm grid for positions; heights within the smoothing's bias on broad shells.
    assert values[1] == pytest.approx(r2, abs=0.002)
    assert values[2] == pytest.approx(g2, abs=0.003)
    assert values[0] == pytest.approx(g_min, abs=0.01)


def test_second_shell_without_a_second_peak_is_finite_at_the_window_edge():
    # A TIP3P-like curve whose tail decays monotonically: no turning point in the window.
    r = np.linspace(0.0, 1.0, 1001)
    onset = 1.0 / (1.0 + np.exp(-(r - 0.255) / 0.004))
    g = onset * (1.0 + 1.6 * np.exp(-0.5 * ((r - 0.28) / 0.016) ** 2) - 0.15 * np.exp(-(((r - 0.36) / 0.03) ** 2)))
    g = g + onset * 0.05 * np.exp(-(r - 0.40) / 0.05) * (r > 0.40)
    values = second_shell_statistics(r, g)
    assert np.all(np.isfinite(values))
    assert SECOND_SHELL_WINDOW_NM[0] <= values[1] <= SECOND_SHELL_WINDOW_NM[1]


def test_measured_second_shell_is_physical_and_resolved():
    data = joint_observed("xray")
    g_min1, r_max2, g_max2 = (data.observed[JOINT_NAMES.index(n)] for n in SECOND_SHELL_NAMES)
    assert 0.44 <= r_max2 <= 0.46  # Skinner 2013: second peak near 4.5 A
    assert 1.1 <= g_max2 <= 1.2
    assert 0.8 <= g_min1 <= 0.9
    errors = [data.errors[JOINT_NAMES.index(n)] for n in SECOND_SHELL_NAMES]
    propagated = datasets.second_shell_errors("xray")[0]
    assert np.all(np.isfinite(propagated)) and np.all(propagated > 0)
    # Resolved: each well inside its window / far from 1 compared with its error.
    assert errors[1] < 0.02 and (g_max2 - 1.0) / errors[2] > 5 and (1.0 - g_min1) / errors[0] > 3
    for name in SECOND_SHELL_NAMES:
        assert data.fitted[JOINT_NAMES.index(name)]
    # Neutron (Soper 2013) agrees on the second shell within the adopted errors.
    neutron = datasets.second_shell_observed("neutron")
    assert abs(neutron[1] - r_max2) < 2 * errors[1] and abs(neutron[2] - g_max2) < 2 * errors[2]


def test_model_prior_default_and_wide():
    m = MODELS["TIP4P"]
    default = model_prior("TIP4P")
    np.testing.assert_allclose(default.low, [m.sigma_oo_nm * 0.95, m.epsilon_oo_kj_mol * 0.6])
    np.testing.assert_allclose(default.high, [m.sigma_oo_nm * 1.05, m.epsilon_oo_kj_mol * 1.4])
    wide = model_prior("TIP4P", epsilon_factors=WIDE_EPSILON_FACTORS)
    np.testing.assert_allclose(wide.low[0], default.low[0])
    np.testing.assert_allclose([wide.low[1], wide.high[1]], m.epsilon_oo_kj_mol * np.array(WIDE_EPSILON_FACTORS))
    assert wide.high[1] > default.high[1]
    for bad in [(1.5, 1.0), (0.0, 2.0), (0.5,)]:
        with pytest.raises(ValueError, match="epsilon_factors"):
            model_prior("TIP4P", epsilon_factors=bad)


def _benchmark():
    path = ROOT / "benchmarks" / "water_model_choice.py"
    spec = importlib.util.spec_from_file_location("_water_model_choice_under_test", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_benchmark_priors_and_discrepancy_groups():
    bench = _benchmark()
    assert bench.prior_options("default") == {}
    assert bench.prior_options("wide") == {"epsilon_factors": WIDE_EPSILON_FACTORS}
    assert bench.prior_options("0.05,0.8") == {"relative_half_width": (0.05, 0.8)}
    assert bench.prior_options("0.05,0.6,2.0") == {"relative_half_width": (0.05, 0.4), "epsilon_factors": (0.6, 2.0)}
    with pytest.raises(SystemExit):
        bench.prior_options("huge")
    # One model's box replaced: the others keep --prior-width's.
    args = bench.parse_arguments(["--prior-width", "wide", "--model-prior", "tip3p=0.95,1.08,0.35,2.5", "--tiny"])
    assert args.model_prior == {
        "tip3p": ("0.95,1.08,0.35,2.5", {"sigma_factors": (0.95, 1.08), "epsilon_factors": (0.35, 2.5)})
    }
    assert "_tip3p0.95-1.08-0.35-2.5" in str(args.cache_dir)
    tip3p, tip4p = bench.prior_of(args, get_model("TIP3P")), bench.prior_of(args, get_model("TIP4P"))
    published3, published4 = get_model("TIP3P").lj, get_model("TIP4P").lj
    assert math.isclose(float(tip3p.low[1]), 0.35 * published3[1], rel_tol=1e-6)
    assert math.isclose(float(tip3p.high[0]), 1.08 * published3[0], rel_tol=1e-6)
    assert math.isclose(float(tip3p.low[0]), 0.95 * published3[0], rel_tol=1e-6)
    assert math.isclose(float(tip3p.high[1]), 2.5 * published3[1], rel_tol=1e-6)
    assert math.isclose(float(tip4p.low[1]), WIDE_EPSILON_FACTORS[0] * published4[1], rel_tol=1e-6)
    assert math.isclose(float(tip4p.high[0]), 1.05 * published4[0], rel_tol=1e-6)
    assert "tip3p.prior=0.95,1.08,0.35,2.5" in bench.simulator_id(args)
    # Under x64 the prior's bounds are float64 and np.asarray views of them read-only: the
    # sigma box is built on copies.
    with jax.enable_x64(True):
        assert np.allclose(bench.prior_of(args, get_model("TIP3P")).low, tip3p.low)
    assert bench.parse_arguments(["--model-prior", "TIP3P=0.08,0.4,2"]).model_prior["tip3p"][1] == {
        "relative_half_width": (0.08, 0.4),
        "epsilon_factors": (0.4, 2.0),
    }
    for bad in ("TIP3P=huge", "TIP3P=0.05,2,1", "nosuch=0.05,0.4,2", "TIP3P=1.5,0.4", "TIP3P=1.01,1.1,0.4,2"):
        with pytest.raises(SystemExit):
            bench.parse_arguments(["--model-prior", bad])
    with pytest.raises(SystemExit, match="twice"):
        bench.parse_arguments(["--model-prior", "TIP3P=wide", "--model-prior", "tip3p=default"])
    for kind in ("xray", "neutron"):
        data = joint_observed(kind)
        names = [n for n, f in zip(data.names, data.fitted, strict=True) if f]
        groups = bench.discrepancy_for(names).groups
        covered = sorted(i for idx in groups.values() for i in idx)
        assert covered == list(range(len(names)))  # every fitted summary in exactly one group
        assert math.isclose(bench.discrepancy_for(names).max_sd[list(groups).index("gOO_heights")], 1.0)


@pytest.mark.parametrize("discrepancy", [False, True])
def test_benchmark_passes_the_stated_errors_to_jaxabc_run(discrepancy):
    import argparse

    import jaxabc

    bench = _benchmark()
    data = joint_observed("xray")
    options = bench.noise_options(argparse.Namespace(data="xray", discrepancy=discrepancy), data)
    np.testing.assert_array_equal(options["observation_error"], observation_sd("xray"))
    assert ("discrepancy" in options) == discrepancy
    if discrepancy:
        assert isinstance(options["discrepancy"], jaxabc.Discrepancy)


def test_benchmark_holds_out_a_fitted_summary():
    """``--hold-out`` moves a fitted summary to the held-out ones everywhere the run reads them
    (the observed vector, its errors, the discrepancy groups, the cache and resume identity),
    refuses a name that is not fitted, and leaves the default run as it was."""
    bench = _benchmark()
    default = bench.parse_arguments(["--tiny"])
    full = joint_observed("xray")
    plain = bench.model_choice_data(default)
    np.testing.assert_array_equal(plain.fitted, full.fitted)
    np.testing.assert_array_equal(bench.fitted_sd(default, plain), observation_sd("xray"))

    args = bench.parse_arguments(["--tiny", "--discrepancy", "--hold-out", "r_oo_max2_nm"])
    data = bench.model_choice_data(args)
    names = list(data.names)
    i = names.index("r_oo_max2_nm")
    assert not data.fitted[i] and data.held_out[i] and data.held_out[names.index("density_kg_m3")]
    assert int(data.fitted.sum()) == int(full.fitted.sum()) - 1
    full_names = [n for n, f in zip(full.names, full.fitted, strict=True) if f]
    expected = np.delete(observation_sd("xray"), full_names.index("r_oo_max2_nm"))
    np.testing.assert_array_equal(bench.fitted_sd(args, data), expected)
    options = bench.noise_options(args, data)
    fitted_names = [n for n, f in zip(names, data.fitted, strict=True) if f]
    covered = sorted(j for idx in options["discrepancy"].groups.values() for j in idx)
    assert covered == list(range(len(fitted_names)))
    assert "_holdout-r_oo_max2_nm" in str(args.cache_dir)
    assert ":held_out=r_oo_max2_nm" in bench.simulator_id(args)
    assert ":held_out=" not in bench.simulator_id(default)
    for bad in ("density_kg_m3", "nosuch"):
        with pytest.raises(ValueError, match="not a fitted summary"):
            bench.model_choice_data(bench.parse_arguments(["--tiny", "--hold-out", bad]))


def test_published_discrepancy_bounds_set_each_groups_prior(tmp_path, monkeypatch):
    """``--discrepancy-bounds published``: each group's ``max_sd`` is the largest misfit a published
    model makes in it (the saved ``water_published_predictive``), reaches ``jaxabc.run``'s
    discrepancy and the cache folder's name; the default keeps the fixed bounds; a bound for a
    group that does not exist and a missing published result are refused."""
    import json

    bench = _benchmark()
    args = bench.parse_arguments(
        ["--tiny", "--discrepancy", "--discrepancy-bounds", "published", "--hold-out", "r_oo_max2_nm"]
    )
    data = bench.model_choice_data(args)
    names = [n for n, f in zip(data.names, data.fitted, strict=True) if f]
    published = json.loads((bench.RESULTS / "water_published_predictive.json").read_text())
    k = published["summary_names"].index("S9")
    expected = max(abs(m["mean"][k] - published["observed"][k]) for m in published["models"].values())
    bounds = bench.discrepancy_bounds(args, names)
    assert math.isclose(bounds["D"], expected, rel_tol=1e-12)
    assert set(bounds) == set(bench.discrepancy_groups(names))
    disc = bench.noise_options(args, data)["discrepancy"]
    assert math.isclose(disc.max_sd[list(disc.groups).index("D")], expected, rel_tol=1e-12)
    assert "_dbounds-published" in str(args.cache_dir)
    default = bench.parse_arguments(["--tiny", "--discrepancy"])
    assert bench.discrepancy_bounds(default, names) is None and "_dbounds" not in str(default.cache_dir)
    fixed = bench.discrepancy_for(names)
    assert math.isclose(fixed.max_sd[list(fixed.groups).index("D")], bench.DISCREPANCY_GROUPS["D"][1])
    with pytest.raises(ValueError, match="not a group with a fitted summary"):
        bench.discrepancy_for(names, {"nosuch": 1.0})
    monkeypatch.setattr(bench, "RESULTS", tmp_path)
    with pytest.raises(FileNotFoundError, match="water_published_predictive"):
        bench.discrepancy_bounds(args, names)
