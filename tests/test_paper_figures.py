"""Every script in ``paper_figures/`` redraws its figure from the committed results, quickly.

Each script's ``main(out_dir)`` runs on ``benchmarks/results`` into a temporary directory and
must write a non-empty PNG.  No simulation runs.  A figure is skipped only when its input files
are absent (with the file named in the reason).
"""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path
from types import ModuleType

import matplotlib

matplotlib.use("Agg")
import pytest

ROOT = Path(__file__).resolve().parents[1]
FIGURES = ROOT / "paper_figures"
RESULTS = ROOT / "benchmarks" / "results"

#: Script -> groups of inputs; the figure can be drawn when every file of at least one group exists.
INPUTS: dict[str, list[list[str]]] = {
    "figure_summary_statistics": [["water_example_curves.json"]],
    "figure3_imbalance": [["imbalance.json"]],
    "figure_mpi_workflow": [["speedup.json"], ["water_simulated_robust.npz"]],
    "figure4_speedup": [["speedup.json"]],
    "figure5_helium_posterior": [["helium_table1.json", "helium_table1_apmcabc.npz", "helium_table1_abcsubsim.npz"]],
    "figure_water_posteriors": [
        [f"water_{d}_surrogate.json", f"water_{d}_{v}_surrogate.npz"]
        for d in ("simulated", "neutron", "xray")
        for v in ("robust", "paper")
    ],
    "figure_water_predictive": [[f"water_{d}_surrogate.json"] for d in ("neutron", "xray")],
    "figure_water_model_choice": [["water_model_choice.json"]],
}


def load_script(name: str) -> ModuleType:
    """Import ``paper_figures/<name>.py`` by path."""
    spec = importlib.util.spec_from_file_location(f"paper_figures_{name}", FIGURES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def skip_if_missing(name: str) -> None:
    """Skip unless one input group of ``name`` is complete."""
    groups = INPUTS[name]
    if not any(all((RESULTS / f).exists() for f in group) for group in groups):
        pytest.skip(f"{name}: inputs absent in benchmarks/results: " + " or ".join("+".join(g) for g in groups))


@pytest.mark.parametrize("name", list(INPUTS))
def test_figure_script_writes_png(name: str, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    skip_if_missing(name)
    path = Path(load_script(name).main(tmp_path))
    assert path.parent == tmp_path
    assert path.suffix == ".png"
    assert path.stat().st_size > 10_000
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    capsys.readouterr()


def test_make_all_lists_every_script() -> None:
    scripts = {p.stem for p in FIGURES.glob("figure*.py")}
    assert scripts == set(load_script("make_all").SCRIPTS) == set(INPUTS)


@pytest.mark.parametrize("name", ["figure_water_posteriors", "figure_water_predictive"])
def test_water_figures_skip_a_missing_dataset(
    name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """With only the X-ray results present, neutron (and simulated) are skipped with a message."""
    needed = ["water_xray_surrogate.json", "water_xray_robust_surrogate.npz"]
    if not all((RESULTS / f).exists() for f in needed):
        pytest.skip(f"inputs absent in benchmarks/results: {needed}")
    results = tmp_path / "results"
    results.mkdir()
    for f in needed:
        shutil.copy(RESULTS / f, results / f)
    module = load_script(name)
    monkeypatch.setattr(module, "RESULTS", results)
    monkeypatch.setattr(module, "ROOT", tmp_path)
    path = Path(module.main(tmp_path / "out"))
    assert path.stat().st_size > 10_000
    assert "skipping neutron" in capsys.readouterr().out


def test_water_figures_fail_clearly_without_any_results(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("figure_water_posteriors", "figure_water_predictive"):
        module = load_script(name)
        monkeypatch.setattr(module, "RESULTS", tmp_path)
        monkeypatch.setattr(module, "ROOT", tmp_path.parent)
        with pytest.raises(FileNotFoundError):
            module.main(tmp_path / "out")
