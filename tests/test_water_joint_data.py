"""Joint measured water data: values and roles from the data file, Yeh-Hummer size."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from md.water import datasets
from md.water.joint_data import JOINT_DATA_FILE, JOINT_NAMES, joint_observed, joint_record, yeh_hummer_shift
from md.water.model_simulator import JOINT_SUMMARY_NAMES


def test_names_match_the_simulator_output():
    assert JOINT_NAMES == JOINT_SUMMARY_NAMES


@pytest.mark.parametrize("kind", ["xray", "neutron"])
def test_observed_vector_and_roles(kind):
    data = joint_observed(kind)
    record = joint_record()
    assert data.observed.shape == data.errors.shape == data.fitted.shape == (len(JOINT_NAMES),)
    assert not np.any(data.fitted & data.held_out)
    # The data file's values at the kind's simulation temperature, in the simulator's order.
    if kind == "neutron":
        assert data.observed[9] == record["scalars"]["density_kg_m3"]["value"] == 997.0
        assert data.observed[10] == record["scalars"]["hvap_kj_mol"]["value"]
        assert data.observed[8] == pytest.approx(datasets.diffusion_statistic_value("robust"))
    else:
        at = {k: v["by_temperature_k"]["295.15"]["value"] for k, v in record["scalars"].items()}
        assert data.observed[8:11].tolist() == [at["self_diffusion_1e-5_cm2_s"], at["density_kg_m3"], at["hvap_kj_mol"]]
    np.testing.assert_allclose(data.observed[3:8], datasets.observed_statistics(kind, "robust")[3:8])
    assert data.held_out[JOINT_NAMES.index("density_kg_m3")]
    assert np.all(np.isfinite(data.errors[8:])) and np.all(data.errors[8:] > 0)
    if kind == "xray":
        # X-ray data measure no g_OH: S1..S3 are neither fitted nor held out, and 0.0.
        assert not np.any(data.fitted[:3] | data.held_out[:3])
        assert np.all(data.observed[:3] == 0.0)


def test_bad_roles_are_refused(tmp_path):
    record = joint_record()
    record["roles"]["xray"]["held_out"].append("S4")
    path = tmp_path / "joint.json"
    path.write_text(json.dumps(record))
    with pytest.raises(ValueError, match="both fitted and held out"):
        joint_observed("xray", path)
    record["roles"]["xray"]["fitted"].append("S10")
    path.write_text(json.dumps(record))
    with pytest.raises(ValueError, match="unknown summaries"):
        joint_observed("xray", path)
    with pytest.raises(ValueError, match="kind must be one of"):
        joint_observed("simulated")
    assert JOINT_DATA_FILE.is_file()


def test_yeh_hummer_shift_by_hand():
    # xi k_B T / (6 pi eta L) in SI, converted to 1e-5 cm^2/s, for L = 2 nm and eta = 1 mPa s.
    expected = 2.837297 * 1.380649e-23 * 300.0 / (6 * math.pi * 1e-3 * 2e-9) * 1e4 / 1e-5
    assert yeh_hummer_shift(2.0, 1.0, 300.0) == pytest.approx(expected, rel=1e-12)
    # Inversely proportional to the viscosity and to the box edge.
    assert yeh_hummer_shift(1.0, 0.5, 300.0) == pytest.approx(4 * expected, rel=1e-12)
    with pytest.raises(ValueError, match="finite and > 0"):
        yeh_hummer_shift(0.0, 1.0)


@pytest.mark.parametrize("kind", ["xray", "neutron"])
def test_curve_errors_propagate_to_the_statistics(kind):
    adopted, by_assumption = datasets.statistic_errors(kind)
    data = joint_observed(kind)
    measured = slice(3, 8) if kind == "xray" else slice(0, 8)
    # The propagation is a floor; the data file's stated (or estimated) error wins where larger.
    np.testing.assert_array_equal(data.propagated[measured], adopted[measured])
    assert np.all(data.errors[measured] >= adopted[measured])
    assert np.all(np.isfinite(adopted[measured])) and np.all(adopted[measured] > 0)
    assert np.all(adopted[measured] >= by_assumption[:, measured].max(axis=0))
    if kind == "xray":
        assert np.all(np.isnan(data.errors[:3]))
    # S4 (mean of g_OO over the window) is linear in g: under one common shift z * error its
    # sd is |S4(g + error) - S4(g)| exactly; 400 draws estimate an sd within ~3.5 % (1 SE).
    curve = datasets.xray_goo() if kind == "xray" else datasets.neutron_curves()["OO"]
    from md.water.statistics import robust_oo_statistics

    exact = abs(
        float(robust_oo_statistics(curve.r_nm, curve.g + curve.error)[0] - robust_oo_statistics(curve.r_nm, curve.g)[0])
    )
    common = datasets.ERROR_CORRELATION_LENGTHS_NM.index(float("inf"))
    assert by_assumption[common, 3] == pytest.approx(exact, rel=4 * 0.035)
