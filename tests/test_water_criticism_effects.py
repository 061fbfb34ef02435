"""The water catalogue's effects reach the simulator as documented (no GROMACS run: the inner
simulator is replaced by a recorder that returns fixed statistics)."""

from __future__ import annotations

import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from md.water.criticism import WaterSimulatorWithEffects, water_catalogue
from md.water.joint_data import yeh_hummer_shift

pytestmark = pytest.mark.skipif(shutil.which("gmx") is None, reason="needs GROMACS (scripts/setup.sh)")

STATS = np.arange(1.0, 10.0)
DENSITY = 990.0


class Recorder:
    """Stands in for a TIP4PSimulator: records (temperature, theta), returns fixed numbers."""

    def __init__(self, protocol, calls):
        self.protocol, self.calls = protocol, calls

    def run(self, key, theta):
        self.calls.append((self.protocol.temperature_k, list(theta)))
        curves = SimpleNamespace(density_kg_m3=DENSITY)
        return SimpleNamespace(statistics=STATS.copy(), curves=curves, run=SimpleNamespace(num_molecules=216))


def simulator(statistics: str, monkeypatch) -> tuple[WaterSimulatorWithEffects, list]:
    """The real wrapper; every inner simulator it builds (one per thermostat) records calls."""
    import md.water

    calls: list = []
    real = md.water.make_simulator

    def recording(preset, *args, **options):
        inner = real(preset, *args, **options)
        recorder = Recorder(inner.protocol, calls)
        recorder.base_parameters = inner.base_parameters
        return recorder

    monkeypatch.setattr(md.water, "make_simulator", recording)
    return WaterSimulatorWithEffects("quick", statistics, "neutron", with_density=False), calls


def test_catalogue_order_matches_the_simulator_and_nulls_change_nothing(monkeypatch):
    names = [e.name for e in water_catalogue()]
    assert names == ["charge_scale", "msite_shift", "temperature_offset", "finite_box_diffusion", "oh_contamination"]
    sim, calls = simulator("robust", monkeypatch)
    out = sim(np.zeros(2, np.uint32), [0.315, 0.65] + [e.null for e in water_catalogue()])
    np.testing.assert_array_equal(out, STATS)
    assert calls[0][0] == sim.inner.protocol.temperature_k


def test_temperature_offset_moves_the_thermostat_and_fluidity_shifts_d_by_yeh_hummer(monkeypatch):
    sim, calls = simulator("robust", monkeypatch)
    out = sim(np.zeros(2, np.uint32), [0.315, 0.65, 0.0, 0.0, -3.0, 1 / 0.494, 0.0])
    assert calls[-1][0] == sim.inner.protocol.temperature_k - 3.0
    box_nm = (216 * 18.01528e-3 / 6.02214076e23 / DENSITY) ** (1 / 3) * 1e9
    expected = yeh_hummer_shift(box_nm, 0.494, sim.inner.protocol.temperature_k - 3.0)
    np.testing.assert_allclose(out[8] - STATS[8], expected, rtol=1e-12)
    np.testing.assert_array_equal(out[:8], STATS[:8])
    # The paper's S9 is the MSD slope in nm^2/ps: 6 D, with 1e-5 cm^2/s = 1e-3 nm^2/ps.
    paper, _ = simulator("paper", monkeypatch)
    shift = paper(np.zeros(2, np.uint32), [0.315, 0.65, 0.0, 0.0, 0.0, 2.0, 0.0])[8] - STATS[8]
    np.testing.assert_allclose(shift, 6e-3 * yeh_hummer_shift(box_nm, 0.5, sim.inner.protocol.temperature_k))


def test_joint_catalogue_drops_the_m_site_for_three_site_models():
    from md.water.joint_criticism import joint_catalogue

    assert "msite_shift" in [e.name for e in joint_catalogue("TIP4P/2005")]
    spce = [e.name for e in joint_catalogue("SPC/E")]
    assert spce == ["charge_scale", "temperature_offset", "finite_box_diffusion", "oh_contamination"]
    assert all("msite_shift" not in e.confusable_with for e in joint_catalogue("SPC/E"))


def test_joint_catalogue_lets_the_m_site_reach_the_oxygen_and_no_further():
    from md.water.joint_criticism import joint_catalogue
    from md.water.models import get_model

    for name in ("TIP4P", "TIP4P-Ew"):
        shift = joint_catalogue(name)["msite_shift"]
        assert shift.low == -get_model(name).om_distance_nm  # d_OM + low == 0: M on O
        assert shift.step == 0.001  # the screening's finite difference of the narrower box


def test_joint_simulator_applies_the_effects_to_model_protocol_and_summaries(monkeypatch):
    from md.water import model_simulator
    from md.water.joint_criticism import WaterModelWithEffects

    calls: list = []

    def run(self, key, theta):
        calls.append((self.model, self.protocol.temperature_k, list(theta)))
        curves = SimpleNamespace(density_kg_m3=DENSITY)
        return SimpleNamespace(
            statistics=STATS.copy(),
            density_kg_m3=DENSITY,
            hvap_kj_mol=44.0,
            curves=curves,
            run=SimpleNamespace(num_molecules=216),
            second_shell=np.array([0.84, 0.45, 1.12]),
        )

    monkeypatch.setattr(model_simulator.WaterModelSimulator, "run", run)
    sim = WaterModelWithEffects("TIP4P/2005", "quick", "robust", "neutron")
    assert sim.effects == [e.name for e in sim.catalogue]
    key = np.zeros(2, np.uint32)
    nulls = sim(key, [0.3159, 0.77, 0.0, 0.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(nulls, np.concatenate([STATS, [DENSITY, 44.0], [0.84, 0.45, 1.12]]))
    assert calls[-1][0] == sim.model and calls[-1][1] == sim.base.protocol.temperature_k

    sim(key, [0.3159, 0.77, 0.05, 0.001, 10.0, 0.0, 0.0])
    model, temperature, theta = calls[-1]
    assert model.charge_h_e == sim.model.charge_h_e * 1.05
    assert model.om_distance_nm == sim.model.om_distance_nm + 0.001
    assert temperature == sim.base.protocol.temperature_k + 10.0 and theta == [0.3159, 0.77]
    with pytest.raises(ValueError, match="theta_full must hold"):
        sim(key, [0.3159, 0.77, 0.0])
