"""The probe runner of benchmarks/reliability_probes.py: an interrupt probe whose run finished
before the signal is tried again, and never classified as what an uninterrupted run does."""

from __future__ import annotations

from pathlib import Path

from benchmarks._common import ROOT
from benchmarks.reliability_probes import DEFAULT_SIGINT, INTERRUPT, INTERRUPT_TRIES, Probe, _run_one


def test_a_run_that_beats_its_interrupt_is_tried_again(tmp_path: Path) -> None:
    count = tmp_path / "tries"
    # Finished before the signal on the first two tries, interrupted on the third.
    cli = (
        f"n=$(( $(cat {count} 2>/dev/null || echo 0) + 1 )); echo $n > {count}; "
        "if [ $n -lt 3 ]; then echo 'RACE the run finished before the interrupt'; exit 75; fi; "
        "echo 'OK interrupted'"
    )
    out = _run_one(Probe("race", 4, "race", cli=cli), ROOT, timeout=30)
    assert out["outcome"] == "correct" and count.read_text().strip() == "3"


def test_a_run_that_always_beats_its_interrupt_is_not_exercised(tmp_path: Path) -> None:
    count = tmp_path / "tries"
    cli = f"echo x >> {count}; echo 'RACE the run finished before the interrupt'; exit 75"
    out = _run_one(Probe("race", 4, "race", cli=cli), ROOT, timeout=30)
    assert out["outcome"] == "not exercised"
    assert len(count.read_text().split()) == INTERRUPT_TRIES


def test_the_interrupt_line_reports_a_finished_run_and_passes_an_interrupted_one(tmp_path: Path) -> None:
    """The real shell line: a command that ends at once (exit 0) races; one that runs until the
    signal (interrupted, non-zero exit) lets the line go on.  The long command writes its own
    checkpoint once running, as the probed runs do, so the signal cannot land before it starts."""
    import subprocess
    import sys

    def run(command: str) -> subprocess.CompletedProcess:
        line = f"{INTERRUPT.format(command=command, folder='f')}echo went-on"
        # Started as the probes are (SIGINT back to its default): pytest itself may run with
        # SIGINT ignored, in the background of a CI shell.
        return subprocess.run(
            [*DEFAULT_SIGINT, "bash", "-c", line], cwd=tmp_path, capture_output=True, text=True, timeout=60
        )

    # Finishes whenever the signal lands (it ignores SIGINT): never interrupted, so a RACE.
    fast = run("bash -c \"trap '' INT; mkdir -p f; touch f/checkpoint.npz\"")
    assert fast.returncode == 75 and fast.stdout.startswith("RACE")
    slow = run(
        f"{sys.executable} -c \"import os, time; os.makedirs('f', exist_ok=True); "
        "open('f/checkpoint.npz', 'w').close(); time.sleep(30)\""
    )
    assert slow.returncode == 0 and "went-on" in slow.stdout and "RACE" not in slow.stdout, slow.stdout


def test_the_interrupt_reaches_the_run_when_the_runner_ignores_sigint(tmp_path: Path) -> None:
    """A runner started in the background of a shell inherits SIGINT ignored; the probe's
    process gets it back, so its Ctrl-C still interrupts (no RACE, the line goes on)."""
    import signal
    import sys

    command = (
        f"{sys.executable} -c \"import os, time; os.makedirs('f', exist_ok=True); "
        "open('f/checkpoint.npz', 'w').close(); time.sleep(20)\""
    )
    cli = INTERRUPT.format(command=command, folder="f") + "echo 'OK interrupted'"
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        out = _run_one(Probe("ignored", 4, "ignored", cli=cli), ROOT, timeout=60)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert out["outcome"] == "correct", out
    assert out["seconds"] < 15
