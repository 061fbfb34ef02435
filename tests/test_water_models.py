"""Published water models: parameters against GROMACS's own files, topologies through grompp.

The ``gromacs``-marked tests need ``gmx`` and its data files (``share/gromacs/top``); the slow
test runs each model for a few picoseconds.
"""

from __future__ import annotations

import math
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from md.water import models
from md.water.models import MODELS, get_model, model_prior, polarisation_correction_kj_mol, topology_for
from md.water.topology import TIP4P_PARAMETERS

GMX = shutil.which("gmx")
#: GROMACS ships these four models in oplsaa.ff (TIP4P/2005 is not shipped).
SHIPPED = {"TIP4P": "tip4p.itp", "TIP4P-Ew": "tip4pew.itp", "SPC/E": "spce.itp", "TIP3P": "tip3p.itp"}


def _gmx_top() -> Path:
    if GMX is None:
        pytest.skip("needs GROMACS `gmx` (sudo apt-get install -y gromacs)")
    from md.water.gromacs import _gmx_data_dir

    return _gmx_data_dir(GMX)


def _sections(text: str) -> dict[str, list[list[str]]]:
    """Rows of each ``[ section ]`` of an .itp, comments and preprocessor lines dropped.

    Only the rigid branch (``#ifndef FLEXIBLE``) is kept: its ``#else`` part is skipped.
    """
    out: dict[str, list[list[str]]] = {}
    current, skipping = None, False
    for raw in text.splitlines():
        line = raw.split(";")[0].strip()
        if line.startswith("#else"):
            skipping = True
        elif line.startswith("#endif"):
            skipping = False
        if not line or line.startswith("#") or skipping:
            continue
        if line.startswith("["):
            current = line.strip("[] ").lower()
            out.setdefault(current, [])
        elif current is not None:
            out[current].append(line.split())
    return out


def _shipped_parameters(top: Path, itp: str) -> dict[str, float]:
    """Charges, geometry and O LJ of a water model as GROMACS's oplsaa.ff defines it."""
    ff = top / "oplsaa.ff"
    molecule = _sections((ff / itp).read_text())
    types = {row[0]: row for row in _sections((ff / "ffnonbonded.itp").read_text())["atomtypes"]}
    atoms = molecule["atoms"]

    def charge(row: list[str]) -> float:
        # An [ atoms ] row without a charge column takes the atomtype's charge.
        return float(row[6]) if len(row) > 6 else float(types[row[1]][-4])

    o_type = types[atoms[0][1]]
    doh, dhh = (float(v) for v in molecule["settles"][0][2:4])
    out = {
        "charge_h": charge(atoms[1]),
        "charge_neg": charge(atoms[3]) if len(atoms) == 4 else charge(atoms[0]),
        "doh": doh,
        "dhh": dhh,
        "sigma": float(o_type[-2]),
        "epsilon": float(o_type[-1]),
    }
    if "virtual_sites3" in molecule:
        a = float(molecule["virtual_sites3"][0][5])
        half_angle_cos = math.sqrt(1.0 - (dhh / (2 * doh)) ** 2)
        out["d_om"] = a * 2.0 * doh * half_angle_cos
    return out


# ----------------------------------------------------------------------------- no gmx needed


def test_project_tip4p_is_the_published_tip4p():
    tip4p = MODELS["TIP4P"]
    p = TIP4P_PARAMETERS
    assert (p.sigma_ow_nm, p.epsilon_ow_kj_mol) == tip4p.lj
    assert p.charge_h_e == tip4p.charge_h_e
    assert p.om_distance_nm == tip4p.om_distance_nm
    assert p.oh_distance_nm == tip4p.oh_distance_nm
    assert p.hh_distance_nm == pytest.approx(tip4p.hh_distance_nm, abs=5e-6)
    # Jorgensen 1983 give epsilon as 0.155 kcal/mol and sigma as 3.15365 A.
    assert tip4p.epsilon_oo_kj_mol == pytest.approx(0.155 * 4.184, rel=1e-6)


def test_tip4p2005_from_its_paper():
    # Abascal & Vega 2005 (not shipped by GROMACS): epsilon/k = 93.2 K, sigma 3.1589 A.
    m = MODELS["TIP4P/2005"]
    assert m.epsilon_oo_kj_mol == pytest.approx(93.2 * 8.314462618e-3, rel=1e-9)
    assert (m.sigma_oo_nm, m.charge_h_e, m.om_distance_nm) == (0.31589, 0.5564, 0.01546)


def test_dipoles_and_berendsen_polarisation_correction():
    # Published dipoles (D): TIP4P 2.18, TIP4P/2005 2.305, SPC/E 2.35 (Berendsen 1987, who
    # give E_pol = 5.22 kJ/mol for SPC/E with mu_gas 1.85 D and alpha 1.608e-40 F m^2).
    assert MODELS["TIP4P"].dipole_debye == pytest.approx(2.18, abs=0.005)
    assert MODELS["TIP4P/2005"].dipole_debye == pytest.approx(2.305, abs=0.001)
    assert MODELS["SPC/E"].dipole_debye == pytest.approx(2.35, abs=0.001)
    assert polarisation_correction_kj_mol(MODELS["SPC/E"]) == pytest.approx(5.22, abs=0.01)
    # A model with the gas-phase dipole needs no correction.
    gas_like = replace(MODELS["SPC/E"], charge_h_e=0.4238 * 1.85 / MODELS["SPC/E"].dipole_debye)
    assert polarisation_correction_kj_mol(gas_like) < 1e-3


def test_four_site_topology_places_m_at_d_om():
    for m in MODELS.values():
        if m.num_sites == 4:
            p = m.tip4p_parameters()
            half = math.radians(m.hoh_angle_deg) / 2
            # virtual_sites3 puts M at O + a (r_OH1 + r_OH2), along the bisector with length
            # a * 2 r_OH cos(theta/2).
            assert p.vsite_coefficient * 2 * m.oh_distance_nm * math.cos(half) == pytest.approx(m.om_distance_nm)
            assert f"SOL {17}" in topology_for(m, 17)
    with pytest.raises(ValueError, match="3 sites"):
        MODELS["SPC/E"].tip4p_parameters()


def test_priors_centred_on_published_values():
    for m in MODELS.values():
        prior = model_prior(m)
        centre = (np.asarray(prior.low) + np.asarray(prior.high)) / 2
        np.testing.assert_allclose(centre, m.lj, rtol=1e-6)
        assert prior.contains(jnp.asarray(m.lj, jnp.float32))
    with pytest.raises(ValueError, match="fractions"):
        model_prior("TIP4P", (0.0, 0.5))


def test_lookup_and_bad_models():
    assert get_model("tip4p2005") is MODELS["TIP4P/2005"]
    assert get_model("spce") is MODELS["SPC/E"]
    with pytest.raises(ValueError, match="choose one of"):
        get_model("TIP5P")
    with pytest.raises(ValueError, match="M site"):
        models.WaterModel("x", 3, 0.4, 0.1, 109.47, 0.01, 0.3, 0.6, "")
    with pytest.raises(ValueError, match="om_distance_nm > 0"):
        models.WaterModel("x", 4, 0.4, 0.1, 109.47, 0.0, 0.3, 0.6, "")


# ------------------------------------------------------------------------------ needs gmx


@pytest.mark.gromacs
@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_parameters_equal_gromacs_shipped_itp(name):
    shipped = _shipped_parameters(_gmx_top(), SHIPPED[name])
    m = MODELS[name]
    assert shipped["charge_h"] == pytest.approx(m.charge_h_e, abs=1e-6)
    assert shipped["charge_neg"] == pytest.approx(-2 * m.charge_h_e, abs=1e-6)
    assert shipped["doh"] == pytest.approx(m.oh_distance_nm, abs=1e-6)
    assert shipped["dhh"] == pytest.approx(m.hh_distance_nm, abs=1e-5)
    assert shipped["sigma"] == pytest.approx(m.sigma_oo_nm, rel=1e-5)
    assert shipped["epsilon"] == pytest.approx(m.epsilon_oo_kj_mol, rel=1e-5)
    if m.num_sites == 4:
        assert shipped["d_om"] == pytest.approx(m.om_distance_nm, abs=2e-6)
    else:
        assert "d_om" not in shipped


@pytest.mark.gromacs
@pytest.mark.parametrize("name", list(MODELS))
def test_written_topology_passes_grompp(name, tmp_path):
    from md.water.models import three_site_defines
    from md.water.protocol import get_protocol, mdp_text

    top = _gmx_top()
    assert GMX is not None
    m = MODELS[name]
    conf = "tip4p.gro" if m.num_sites == 4 else "spc216.gro"
    shutil.copyfile(top / conf, tmp_path / "conf.gro")
    (tmp_path / "topol.top").write_text(topology_for(m, 216))
    mdp = mdp_text(get_protocol("quick"), models.TIP4PParameters(), "em")
    if m.num_sites == 3:
        mdp = "\n".join(
            f"define = {three_site_defines(m)}" if line.startswith("define ") else line for line in mdp.splitlines()
        )
    (tmp_path / "em.mdp").write_text(mdp + "\n")
    done = subprocess.run(
        [GMX, "grompp", "-f", "em.mdp", "-c", "conf.gro", "-p", "topol.top", "-o", "em.tpr"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    # grompp reports the net charge; every model is neutral.
    assert "non-zero total charge" not in done.stderr


@pytest.mark.slow
@pytest.mark.gromacs
@pytest.mark.parametrize("name", list(MODELS))
def test_each_model_runs_a_few_ps(name):
    from md.water.model_simulator import JOINT_SUMMARY_NAMES, WaterModelSimulator

    _gmx_top()
    m = MODELS[name]
    simulate = WaterModelSimulator(m, "quick", num_steps=2000, analysis_start_ps=1.0)
    summaries = simulate(np.array([0, 7], np.uint32), m.lj)
    assert summaries.shape == (len(JOINT_SUMMARY_NAMES),)
    assert np.all(np.isfinite(summaries))
    # At its published parameters every model is a liquid near 1 g/cm3 with a g_OO first peak
    # near 0.28 nm and a cohesive energy near water's (bands much wider than 4 ps of noise and
    # than the models' known deviations, narrow enough to catch a wrong charge or geometry).
    density, hvap = summaries[9], summaries[10]
    assert 900 < density < 1100
    assert 0.26 < summaries[7] < 0.30  # S8, first g_OO peak position (nm)
    assert 35 < hvap < 50


class _CountingSimulator:
    """Stands in for WaterModelSimulator: 11 summaries from theta, fails for theta[0] < 0, and
    crashes (a timeout, say) while ``crash`` is set."""

    model = MODELS["TIP4P"]
    protocol = "protocol-a"

    def __init__(self) -> None:
        self.calls = 0
        self.crash = False

    def __repr__(self) -> str:
        return "counting"

    def __call__(self, key, theta):
        from jaxabc.errors import SimulationFailure

        self.calls += 1
        if self.crash:
            raise RuntimeError("timeout: killed")
        if theta[0] < 0:
            raise SimulationFailure("vapour")
        return np.arange(11.0) + theta[0]


def test_cached_summaries_replays_results_and_failures(tmp_path):
    from jaxabc.checkpoint import describe_callable
    from jaxabc.errors import SimulationFailure
    from jaxabc.executors.cache import RunCache
    from md.water.model_simulator import CachedSummaries

    fitted = np.zeros(11, bool)
    fitted[[3, 10]] = True
    inner = _CountingSimulator()
    cached = CachedSummaries(inner, fitted, tmp_path)
    key = np.array([0, 5], np.uint32)
    first = cached(key, np.array([0.5, 1.0]))
    np.testing.assert_array_equal(first, [3.5, 10.5])
    with pytest.raises(SimulationFailure, match="vapour"):
        cached(key, np.array([-1.0, 1.0]))
    assert inner.calls == 2
    # A new wrapper on the same folder (a resumed run) simulates nothing again.
    again = CachedSummaries(inner, fitted, tmp_path)
    np.testing.assert_array_equal(again(key, np.array([0.5, 1.0])), first)
    with pytest.raises(SimulationFailure, match="vapour"):
        again(key, np.array([-1.0, 1.0]))
    assert inner.calls == 2
    np.testing.assert_array_equal(again.full(key, np.array([0.5, 1.0])), np.arange(11.0) + 0.5)
    # jaxabc's RunCache keeps the files (named by the model) and counts the replays.
    assert cached.cache_path(key, np.array([0.5, 1.0])).name.startswith("tip4p-")  # type: ignore[union-attr]
    assert RunCache.stats(tmp_path) == {"hits": 3, "misses": 2, "corrupt": 0, "entries": 2}
    # Its checkpoint identity is the simulator, the mask and the folder, as before RunCache.
    assert set(describe_callable(cached)["fields"]) == {"simulate", "fitted", "cache_dir"}
    # Another key, theta or protocol is another simulation.
    again(np.array([0, 6], np.uint32), np.array([0.5, 1.0]))
    inner.protocol = "protocol-b"
    again(key, np.array([0.5, 1.0]))
    assert inner.calls == 4
    # A crash or timeout is not a property of (key, theta): not stored, run again.
    inner.crash = True
    for _ in range(2):
        with pytest.raises(RuntimeError, match="timeout"):
            again(key, np.array([2.0, 1.0]))
    assert inner.calls == 6
    # Without a cache every call simulates.
    plain = CachedSummaries(inner, fitted)
    inner.crash = False
    plain(key, np.array([0.5, 1.0]))
    plain(key, np.array([0.5, 1.0]))
    assert inner.calls == 8 and plain.cache is None
    with pytest.raises(ValueError, match="boolean mask"):
        CachedSummaries(inner, np.zeros(11, bool))


def test_cached_summaries_never_replay_other_simulator_code(tmp_path, monkeypatch):
    """A simulation cached by other code (an analysis edited between sittings, or a folder written
    before the code entered the identity) is run again, never replayed: replays of such files made
    the tiny model choice's quick check give other numbers than a fresh run."""
    import hashlib

    from md.water import model_simulator as ms

    inner = _CountingSimulator()
    fitted = np.zeros(11, bool)
    fitted[[3, 10]] = True
    key, theta = np.array([0, 5], np.uint32), np.array([0.5, 1.0])
    # Named as before the code entered the identity: sha256 of repr((simulate, protocol)), key, theta.
    digest = hashlib.sha256(repr((inner, inner.protocol)).encode())
    digest.update(key.tobytes())
    digest.update(theta.tobytes())
    np.savez(tmp_path / f"tip4p-{digest.hexdigest()[:24]}.npz", summaries=np.full(11, 99.0), reason=np.array(""))
    cached = ms.CachedSummaries(inner, fitted, tmp_path)
    np.testing.assert_array_equal(cached(key, theta), [3.5, 10.5])
    assert inner.calls == 1
    np.testing.assert_array_equal(cached(key, theta), [3.5, 10.5])  # the same code: replayed
    assert inner.calls == 1
    # The digest covers the simulation modules and the runner's own file.
    module = Path(ms.__file__)
    assert all((module.parent / name).is_file() for name in ms._SIMULATION_CODE)
    assert len(ms.simulation_code_digest()) == 16
    assert ms.simulation_code_digest(__file__) != ms.simulation_code_digest()
    # The code that makes the summaries changed: simulated again.
    monkeypatch.setattr(ms, "simulation_code_digest", lambda runner_source=None: "0" * 16)
    cached(key, theta)
    assert inner.calls == 2
