"""The command line: a run, and one clear line (exit code 2, no traceback) for each bad input."""

from __future__ import annotations

import gc
import itertools
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

import jaxabc
from jaxabc import checkpoint, cli
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


HOST = "jaxabc.examples:host_gaussian_simulate"


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


# ------------------------------------------------------------------ faults a CLI user meets

#: A module of simulators written next to a test's config and put on sys.path.
SIMULATORS = """
import os
import threading
import time

import jax
import numpy as np


def returns_none(key, theta):
    return None


def slow(key, theta):
    time.sleep(float(os.environ.get("CLI_SIMS_SLEEP", "0")))
    return np.asarray(theta, np.float64)


def make(scale=1.0):
    def simulate(key, theta):
        return scale * theta + jax.random.normal(key, theta.shape, theta.dtype)

    return simulate
"""


def _simulators(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "cli_sims.py").write_text(SIMULATORS)
    monkeypatch.syspath_prepend(str(tmp_path))


def test_ctrl_c_on_run_is_one_line_that_says_how_to_resume(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A real SIGINT to ``python -m jaxabc.cli run`` (a traceback before), then the resume it names."""
    _simulators(tmp_path, monkeypatch)
    text = CONFIG.format(low=0.0, high=1.0).replace("jaxabc.examples:host_gaussian_simulate", "cli_sims:slow")
    text = text.replace('name = "rejection"', 'name = "pmcabc"\nnum_steps = 5').replace("quantile = 0.5\n", "")
    text = text.replace("num_particles = 40", "num_particles = 4")
    cfg = _config(tmp_path, text)
    path = os.pathsep.join([str(tmp_path), str(Path(__file__).parents[1])])
    env = {**os.environ, "PYTHONPATH": path, "CLI_SIMS_SLEEP": "0.3"}
    # ``python -m jaxabc.cli``, with Python's own SIGINT handler restored first: a shell without
    # job control starts background jobs (such as this test run) with SIGINT ignored.
    launch = (
        "import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
        "sys.argv[0] = 'jaxabc'; runpy.run_module('jaxabc.cli', run_name='__main__', alter_sys=True)"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", launch, "run", str(cfg), "--no-progress"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    ckpt = tmp_path / "out" / checkpoint.CHECKPOINT_NAME
    deadline = time.monotonic() + 120
    while not ckpt.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxabc: interrupted"), err
    assert f"jaxabc run {cfg} --no-progress --resume" in lines[0]
    assert not checkpoint.load(ckpt).counters["stop_reason"]
    # The command it names finishes the run.
    assert main(["run", str(cfg), "--no-progress", "--resume"]) == 0


def _interrupting_run(monkeypatch: pytest.MonkeyPatch, after: int) -> None:
    """``jaxabc.run`` that stops after ``after`` iterations, as a Ctrl-C there would."""
    real = jaxabc.run

    def run(*args, **kwargs):
        real(*args, **kwargs, stop_after_iterations=after)
        raise KeyboardInterrupt

    monkeypatch.setattr(jaxabc, "run", run)


def test_example_refuses_an_interrupted_run_and_resumes_it(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "gauss"
    argv = ["example", "gaussian", "--output", str(out)]
    with monkeypatch.context() as m:
        _interrupting_run(m, after=2)
        assert main(argv) == 130
    err = capsys.readouterr().err
    # The progress bar, then one line.
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("jaxabc: interrupted"), err
    assert f"jaxabc example gaussian --output {out} --resume" in err.strip().splitlines()[-1]
    interrupted = (out / checkpoint.CHECKPOINT_NAME).read_bytes()
    # A plain rerun would delete the interrupted run: refused, and the checkpoint is untouched.
    line = _error(capsys, argv)
    assert "--resume" in line and "--overwrite" in line and str(out) in line
    assert (out / checkpoint.CHECKPOINT_NAME).read_bytes() == interrupted
    assert "--resume and --overwrite" in _error(capsys, [*argv, "--resume", "--overwrite"])
    assert main([*argv, "--resume"]) == 0
    resumed = capsys.readouterr().out
    assert "apmcabc: 12800 simulations" in resumed
    # A finished run is the example's own output: running the example again reproduces it.
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert "apmcabc: 12800 simulations" in captured.out and "finished run" in captured.err
    assert main([*argv, "--overwrite"]) == 0
    assert "apmcabc: 12800 simulations" in capsys.readouterr().out


def test_ctrl_c_swallowed_by_a_gc_callback_still_ends_the_command(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch, request: pytest.FixtureRequest
) -> None:
    """A Ctrl-C raised inside a garbage-collection callback (JAX has one) is only printed by
    Python, and the run went on: the command raises it again where it can stop."""

    def callback(phase: str, info: dict) -> None:
        raise KeyboardInterrupt  # as a Ctrl-C landing while the callback runs

    def run(*args, **kwargs):
        gc.callbacks.append(callback)
        try:
            gc.collect()
        finally:
            gc.callbacks.remove(callback)
        for _ in range(1000):  # the run going on, for 10 s at most: the interrupt must come here
            time.sleep(0.01)
        raise AssertionError("the Ctrl-C was lost")

    started: list[float] = []

    class CountedTimer(threading.Timer):
        def start(self) -> None:
            started.append(time.monotonic())
            super().start()

    monkeypatch.setattr(jaxabc, "run", run)
    monkeypatch.setattr(cli.threading, "Timer", CountedTimer)
    monkeypatch.setattr(cli._ReraiseInterrupt, "delay", 0.5)  # after every callback has run
    # Python's own SIGINT handler, as in a terminal: a shell without job control starts background
    # jobs (such as a CI run) with SIGINT ignored, and then no Ctrl-C can reach the command at all.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    request.addfinalizer(lambda: signal.signal(signal.SIGINT, previous))
    assert main(["example", "gaussian", "--output", str(tmp_path / "gauss")]) == 130
    err = capsys.readouterr().err
    assert "Exception ignored" not in err and err.strip().startswith("jaxabc: interrupted"), err
    # The callbacks (this one at the start and at the end, then JAX's) each swallowed the Ctrl-C:
    # one interrupt is pending at a time (another only once it has fired, when a slow collection
    # swallowed it again), and none lands after the command has returned.
    assert started and all(b - a >= 0.45 for a, b in itertools.pairwise(started))
    try:
        time.sleep(0.2)
    except KeyboardInterrupt:
        pytest.fail("a second interrupt landed after the command returned")


def test_example_with_resume_but_nothing_to_resume(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    line = _error(capsys, ["example", "gaussian", "--output", str(tmp_path / "none"), "--resume"])
    assert "no checkpoint" in line


def test_simulator_returning_none_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    _simulators(tmp_path, monkeypatch)
    text = CONFIG.format(low=0.0, high=1.0).replace("jaxabc.examples:host_gaussian_simulate", "cli_sims:returns_none")
    no_executor = text[: text.index("[executor]")] + text[text.index("[output]") :]
    line = _error(capsys, ["run", str(_config(tmp_path, no_executor)), "--no-progress"])
    assert "returns_none" in line and "None" in line and "array of summaries" in line


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ("quantile = 0.5", 'options = { quantile = "0.5" }', "[algorithm] options.quantile must be a number"),
        ("seed = 1", 'seed = "1"', "[algorithm] seed must be an integer"),
        ("num_particles = 40", "num_particles = 40.5", "[algorithm] num_particles must be an integer"),
        ("seed = 1", 'seed = 1\nmax_wall_time = "10"', "[algorithm] max_wall_time must be a number"),
        ("low = [0.0]", 'low = ["0.0"]', "[prior] low must be a list of numbers"),
        ("values = [0.0]", "values = [true]", "[observed] values must be a list of numbers"),
        ('names = ["mu"]', "names = [1]", "[prior] names must be a list of strings"),
        ('folder = "out"', "folder = 3", "[output] folder must be a string"),
        ('name = "serial"', "name = 1", "[executor] name must be a string"),
        (f'simulator = "{HOST}"', f'simulator = ["{HOST}"]', "[model] simulator must be a string"),
    ],
)
def test_wrong_toml_types_name_the_key_and_the_type(
    tmp_path: Path, capsys: pytest.CaptureFixture, old: str, new: str, expected: str
) -> None:
    text = CONFIG.format(low=0.0, high=1.0)
    assert old in text
    text = text.replace(old, new, 1)
    line = _error(capsys, ["run", str(_config(tmp_path, text)), "--no-progress"])
    assert expected in line and "run.toml" in line, line


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ("[executor]", "[exector]", "unknown table [exector] in {path}; did you mean [executor]?"),
        (
            'names = ["mu"]',
            'names = ["mu"]\nunit = ["nm"]',
            "unknown key 'unit' in the [prior] table of {path}; did you mean 'units'?",
        ),
        (
            "seed = 1",
            "seed = 1\nnum_step = 3",
            "unknown key 'num_step' in the [algorithm] table of {path}; did you mean 'num_steps'?",
        ),
        ("seed = 1", "seed = 1\nquantle = 0.3", "did you mean 'quantile'?"),
        (
            "seed = 1",
            "seed = 1\noptions = { quantle = 0.3 }",
            "unknown key 'options.quantle' in the [algorithm] table of {path}; did you mean 'quantile'?",
        ),
        ('folder = "out"', 'folder = "out"\nfolders = "x"', "unknown key 'folders' in the [output] table"),
        (
            "[model]",
            "seed = 2\n[model]",
            "unknown top-level key 'seed' in {path}; did you mean 'seed' in the [algorithm] table?",
        ),
    ],
)
def test_unknown_tables_and_keys_name_the_nearest(
    tmp_path: Path, capsys: pytest.CaptureFixture, old: str, new: str, expected: str
) -> None:
    text = CONFIG.format(low=0.0, high=1.0)
    assert old in text
    path = _config(tmp_path, text.replace(old, new, 1))
    assert expected.format(path=path) in _error(capsys, ["run", str(path), "--no-progress"])


FACTORY_CONFIG = """
[model]
factory = "cli_sims:make"
options = {{ scale = {scale} }}
{extra}
[prior]
low = [-5.0]
high = [5.0]
[observed]
values = [0.0]
[algorithm]
name = "apmcabc"
num_particles = 100
num_steps = 3
[output]
folder = "out"
"""


def test_factory_options_are_the_simulator_identity(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A factory's closure resumes only with the same options; ``simulator_id`` overrides."""
    _simulators(tmp_path, monkeypatch)
    cfg = _config(tmp_path, FACTORY_CONFIG.format(scale=1.0, extra=""))
    assert main(["run", str(cfg), "--no-progress"]) == 0
    stored = checkpoint.load(tmp_path / "out" / checkpoint.CHECKPOINT_NAME).fingerprint["simulator"]
    options = json.dumps({"scale": 1.0}, sort_keys=True, separators=(",", ":"))
    assert re.fullmatch(re.escape(f"cli_sims:make({options})") + r"#[0-9a-f]{16}", stored), stored
    changed = _config(tmp_path, FACTORY_CONFIG.format(scale=2.0, extra=""))
    line = _error(capsys, ["run", str(changed), "--no-progress", "--resume"])
    assert "different problem" in line and "simulator" in line
    named = _config(tmp_path, FACTORY_CONFIG.format(scale=2.0, extra='simulator_id = "scaled-v1"'))
    assert main(["run", str(named), "--no-progress", "--overwrite"]) == 0
    assert checkpoint.load(tmp_path / "out" / checkpoint.CHECKPOINT_NAME).fingerprint["simulator"] == "scaled-v1"


def test_registered_example_runs_through_its_entry_point(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    import jaxabc.cli as cli

    # The repository's md package registers helium in pyproject.toml; jaxabc names no simulator.
    assert cli.registered_examples()["helium"].value == "md.helium_calibration:example"
    calls = []

    class Point:
        value = "tests:fake"

        def load(self):
            return lambda folder, quick, resume: calls.append((Path(folder), quick, resume))

    monkeypatch.setattr(cli, "registered_examples", lambda: {"toy": Point()})
    assert main(["example", "toy", "--output", str(tmp_path / "toy"), "--quick"]) == 0
    assert calls == [(tmp_path / "toy", True, False)]
    with pytest.raises(SystemExit) as exc:
        main(["example", "nonesuch", "--output", str(tmp_path / "x")])
    assert exc.value.code == 2
    assert "'toy'" in capsys.readouterr().err
