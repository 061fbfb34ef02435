"""The command line: a run, and one clear line (exit code 2, no traceback) for each bad input."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from jaxabc.cli import main

CONFIG = """
[model]
simulator = "jaxabc.examples:host_gaussian_simulate"
[prior]
names = ["mu"]
low = [{low}]
high = [{high}]
[observed]
values = [0.0]
[algorithm]
name = "rejection"
num_particles = 40
quantile = 0.5
seed = 1
[executor]
name = "serial"
[output]
folder = "out"
"""


def _config(tmp_path: Path, text: str | None = None, low: float = -5.0, high: float = 5.0) -> Path:
    path = tmp_path / "run.toml"
    path.write_text(CONFIG.format(low=low, high=high) if text is None else text)
    return path


def _error(capsys: pytest.CaptureFixture, argv: list[str]) -> str:
    """Run the CLI expecting a user error; return its one line."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxabc: error: "), err
    return lines[0]


def test_run_then_show(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["run", str(_config(tmp_path)), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "rejection" in printed
    assert main(["show", str(tmp_path / "out" / "result.npz")]) == 0
    assert capsys.readouterr().out.strip() == (tmp_path / "out" / "summary.txt").read_text().strip()


def test_missing_key_names_the_key_and_the_table(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    text = CONFIG.format(low=0.0, high=1.0).replace("low = [0.0]\n", "")
    line = _error(capsys, ["run", str(_config(tmp_path, text))])
    assert "'low'" in line and "[prior]" in line and "run.toml" in line


def test_missing_table_and_wrong_types(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    text = CONFIG.format(low=0.0, high=1.0)
    no_algorithm = text[: text.index("[algorithm]")] + text[text.index("[executor]") :]
    assert "[algorithm]" in _error(capsys, ["run", str(_config(tmp_path, no_algorithm))])
    bad_options = text.replace("seed = 1", "seed = 1\noptions = 3")
    assert "options" in _error(capsys, ["run", str(_config(tmp_path, bad_options))])


def test_malformed_toml_names_the_file_and_the_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    text = CONFIG.format(low=0.0, high=1.0).replace("quantile = 0.5", "quantile 0.5")
    line = _error(capsys, ["run", str(_config(tmp_path, text))])
    expected = CONFIG.format(low=0.0, high=1.0).splitlines().index("quantile = 0.5") + 1
    assert "run.toml" in line and f"line {expected}" in line


def test_config_path_that_is_missing_or_a_directory(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert "no configuration file" in _error(capsys, ["run", str(tmp_path / "nope.toml")])
    assert "is a directory" in _error(capsys, ["run", str(tmp_path)])


def test_missing_observed_file(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    text = CONFIG.format(low=0.0, high=1.0).replace("values = [0.0]", 'file = "obs.npy"')
    assert "obs.npy" in _error(capsys, ["run", str(_config(tmp_path, text))])


def test_errors_raised_by_the_run_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    # Every simulation of flaky_simulate below 0.1 raises: the driver stops with TooManyFailures.
    text = CONFIG.format(low=0.0, high=0.09).replace("host_gaussian_simulate", "flaky_simulate")
    line = _error(capsys, ["run", str(_config(tmp_path, text)), "--no-progress"])
    assert "vaporised" in line
    unknown = CONFIG.format(low=0.0, high=1.0).replace('name = "rejection"', 'name = "mcmc"')
    assert "mcmc" in _error(capsys, ["run", str(_config(tmp_path, unknown))])
    bad_executor = CONFIG.format(low=0.0, high=1.0).replace('name = "serial"', 'name = "gpu-cluster"')
    assert "unknown executor" in _error(capsys, ["run", str(_config(tmp_path, bad_executor))])


def test_show_refuses_what_is_not_a_result(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert "no result file" in _error(capsys, ["show", str(tmp_path / "missing.npz")])
    assert "is a directory" in _error(capsys, ["show", str(tmp_path)])
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"PK\x03\x04 this is not a zip archive")
    assert "jaxabc result file" in _error(capsys, ["show", str(corrupt)])
    text = tmp_path / "text.npz"
    text.write_text("hello")
    assert "jaxabc result file" in _error(capsys, ["show", str(text)])
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, x=np.arange(3))
    assert "jaxabc result file" in _error(capsys, ["show", str(foreign)])
    array = tmp_path / "array.npz"
    with open(array, "wb") as fh:
        np.save(fh, np.arange(3))
    assert "jaxabc result file" in _error(capsys, ["show", str(array)])
    truncated = tmp_path / "truncated.npz"
    np.savez(truncated, metadata=np.array("{}"))
    truncated.write_bytes(truncated.read_bytes()[:40])
    assert not zipfile.is_zipfile(truncated)
    assert "jaxabc result file" in _error(capsys, ["show", str(truncated)])
