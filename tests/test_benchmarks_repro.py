"""Reproduction check: every benchmark's quick mode gives the numbers saved in its quick JSON.

For each entry of ``benchmarks/registry.py`` with a quick command, the test reruns the command
(from the repository root), then compares the new JSON with the committed one under
``benchmarks/results/quick/``: every number exactly (same seed, same numbers), except the keys
that hold times, loads and rates (``registry.TIMING_KEYS`` and the entry's ``ignore_keys``), and
the provenance.  The committed file is restored afterwards, so the tree stays as it was.

Exactness holds for the same machine type and library versions: XLA's CPU code (vector width,
fused operations) and a different GROMACS build can change the last bits, which ABC's
thresholds and accept/reject decisions can then amplify.  An entry that must tolerate this says
so with ``compare_tolerance`` and a note.  Numbers saved on another host (CPU name or vector
instruction sets, :func:`benchmarks.verify.cpu_signature`) are skipped, not compared; otherwise
the failure message prints the recorded and current versions and CPU.  Quick modes run in an
empty runs folder (no replayed run caches), their quick inputs made first.

Slow (one quick run each, up to a few minutes on 2 cores): ``python3 -m pytest -m slow
tests/test_benchmarks_repro.py``.  To refresh the saved quick JSONs after an intended change:
``python -m benchmarks.regenerate --quick --budget 1h``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from benchmarks import _common, registry, status, verify
from benchmarks.regenerate import command_argv

ROOT = Path(__file__).resolve().parents[1]

QUICK = [e for e in registry.REGISTRY if e.quick]


@pytest.mark.slow
@pytest.mark.timeout(2400)
@pytest.mark.parametrize("entry", QUICK, ids=[e.name for e in QUICK])
def test_quick_mode_reproduces_saved_json(entry: registry.Entry, tmp_path: Path) -> None:
    missing = [p for p in entry.requires if shutil.which(p) is None]
    if missing:
        pytest.skip(f"{entry.name} needs {', '.join(missing)}")
    saved_path = ROOT / entry.quick_output
    assert saved_path.is_file(), (
        f"{entry.quick_output} is not saved: run `python -m benchmarks.regenerate --quick --only {entry.name} "
        "--budget 1h` and commit it"
    )
    saved_text = saved_path.read_text()
    saved = json.loads(saved_text)
    # An empty runs folder: run caches in the checkout may hold earlier code's simulations.
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAXABC_RUNS_DIR": str(tmp_path)}
    try:
        run = verify.make_quick_inputs(entry, ROOT, env) or subprocess.run(
            command_argv(entry.quick), cwd=ROOT, env=env, capture_output=True, text=True
        )
        assert run.returncode == 0, f"{entry.quick} failed:\n{run.stderr[-3000:]}"
        new = json.loads(saved_path.read_text())
    finally:
        saved_path.write_text(saved_text)
    diffs = status.compare_numbers(
        status.deterministic_view(saved, entry.ignore_keys),
        status.deterministic_view(new, entry.ignore_keys),
        entry.compare_tolerance,
    )
    if diffs and (other := verify._other_cpu(saved, entry.part)):
        # Same CPU name, other vector instruction sets (or another CPU): XLA's sums differ in
        # the last bits and chaotic runs after them; such numbers say nothing about the code.
        pytest.skip(f"{entry.name}: saved on {other}, now on {verify.cpu_signature(_common.machine())}")
    if diffs:
        was = saved.get("provenance", {}).get("machine", {})
        now = _common.machine()
        pytest.fail(
            f"{entry.name}: {len(diffs)} numbers differ from {entry.quick_output}, first: "
            + "; ".join(diffs[:8])
            + f"\nsaved on {was.get('cpu')} {was.get('versions')}\nnow   on {now['cpu']} {now['versions']}"
        )
