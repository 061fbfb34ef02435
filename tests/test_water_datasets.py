"""Measured water data: units, the published vectors in the right order, diffusion values."""

from __future__ import annotations

import numpy as np
import pytest

from md.water import datasets


def test_xray_curve_units_and_peak():
    curve = datasets.xray_goo()
    assert curve.r_nm.shape == curve.g.shape == curve.error.shape == (2000,)
    assert curve.r_nm[-1] == pytest.approx(1.999)
    top = np.argmax(curve.g)
    assert curve.r_nm[top] == pytest.approx(0.280, abs=1e-9)
    assert curve.g[top] == pytest.approx(2.5752, abs=1e-4)
    assert curve.temperature_k == pytest.approx(295.15)


def test_neutron_curves_units_and_peaks():
    curves = datasets.neutron_curves()
    assert set(curves) == {"OO", "OH", "HH"}
    oo, oh = curves["OO"], curves["OH"]
    assert oo.r_nm[-1] == pytest.approx(2.499)
    assert oo.r_nm[np.argmax(oo.g)] == pytest.approx(0.279, abs=1e-9)
    assert oo.g.max() == pytest.approx(2.4953, abs=1e-4)
    # intermolecular g_OH: nothing at the 0.0957 nm bond, hydrogen-bond peak near 0.186 nm
    assert oh.g[oh.r_nm < 0.11].max() < 1e-3
    first = (oh.r_nm > 0.15) & (oh.r_nm < 0.22)
    assert oh.r_nm[first][np.argmax(oh.g[first])] == pytest.approx(0.186, abs=2e-3)


def test_neutron_vector_is_loaded_by_its_stored_order():
    raw = np.load(datasets.DATA_DIR / "dutta2018_abcpy-models_exp_data.npy").reshape(-1)
    vector = datasets.published_statistics("neutron")
    # stored [S1, S2, S3, S4, S7, S8, S5, S6, D]
    assert vector[6] == raw[4] == pytest.approx(2.69200747)  # S7 first-peak height
    assert vector[7] == raw[5] == pytest.approx(0.275)  # S8 first-peak position
    assert vector[4] == raw[6] == pytest.approx(0.33)  # S5 first-minimum position
    assert vector[5] == raw[7] == pytest.approx(0.13006526)  # S6 integral to the minimum
    assert vector[3] == raw[3] == pytest.approx(0.86349557)  # S4 mean
    np.testing.assert_array_equal(vector[[0, 1, 2, 8]], raw[[0, 1, 2, 8]])
    # physical sanity of the reordering: height > 1, the peak before the minimum
    assert vector[6] > 2 and vector[7] < vector[4]


def test_xray_and_simulated_vectors():
    xray = datasets.published_statistics("xray")
    assert np.all(np.isnan(xray[:3]))
    np.testing.assert_allclose(xray[3:], [0.98028612, 0.347, 0.14146359, 2.571316, 0.281, 0.023])
    simulated = datasets.published_statistics("simulated")
    assert np.isnan(simulated[7])  # the published obs_data has no S8
    assert simulated[6] == pytest.approx(2.987) and simulated[3] == pytest.approx(1.02948497)


def test_diffusion_values():
    assert datasets.diffusion_statistic_value("robust") == pytest.approx(2.30)
    assert datasets.diffusion_statistic_value("paper") == pytest.approx(0.0138)
    assert datasets.diffusion_statistic_value("paper", "paper_stored") == 0.023
    assert datasets.diffusion_statistic_value("robust", "paper_text") == pytest.approx(1.3)
    with pytest.raises(ValueError, match="diffusion"):
        datasets.diffusion_statistic_value("robust", "1.3e-5")


@pytest.mark.parametrize("variant", ["paper", "robust"])
@pytest.mark.parametrize("kind", ["xray", "neutron"])
def test_observed_statistics_complete(kind, variant):
    vector = datasets.observed_statistics(kind, variant)
    assert vector.shape == (9,) and np.all(np.isfinite(vector))
    if kind == "xray":
        np.testing.assert_array_equal(vector[:3], 0.0)


def test_observed_paper_recomputed_equals_published_for_xray():
    published = datasets.observed_statistics("xray", "paper", "paper_stored")
    recomputed = datasets.observed_statistics("xray", "paper", "paper_stored", "recomputed")
    np.testing.assert_allclose(recomputed, published, atol=5e-9)


def test_published_posteriors():
    for kind in ("simulated", "neutron", "xray"):
        table = datasets.published_posterior(kind)
        assert table.shape == (100, 3)
        assert table[:, 2].sum() == pytest.approx(1.0, abs=1e-6)
        assert np.all((table[:, 0] > 0.28) & (table[:, 0] < 0.531))
