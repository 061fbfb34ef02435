"""MPI executors on real Open MPI ranks (oversubscribed), against the serial executor.

Two launches of ``tests/_mpi_job.py`` under ``mpiexec -n K python -m mpi4py.futures``: K = 3 (two
workers: dynamic, static and serial calibrations plus the failure cases) and K = 4 (three
workers: dynamic and static).  About 30-50 s on two busy cores, most of it JAX start-up and
compilation; the launches share a JAX compilation cache.
"""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from jaxabc.errors import STATUS_FAILED, STATUS_NONFINITE, STATUS_OK, STATUS_TIMEOUT, STATUS_WORKER_DIED
from jaxabc.executors.mpi import chunk_indices

HERE = Path(__file__).parent
ROOT_FLAGS = {
    "OMPI_ALLOW_RUN_AS_ROOT": "1",
    "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
    "OMPI_MCA_rmaps_base_oversubscribe": "1",
}


def _launch(num_ranks: int, out: Path, cache: Path, *extra: str) -> dict:
    # The jaxabc under test, not whichever copy is installed.
    path = os.pathsep.join(p for p in (str(HERE.parent), os.environ.get("PYTHONPATH")) if p)
    env = {**os.environ, **ROOT_FLAGS, "JAX_PLATFORMS": "cpu", "JAXABC_TEST_JAX_CACHE": str(cache), "PYTHONPATH": path}
    cmd = [
        "mpiexec",
        "--allow-run-as-root",
        "--oversubscribe",
        "-n",
        str(num_ranks),
        sys.executable,
        "-m",
        "mpi4py.futures",
        str(HERE / "_mpi_job.py"),
        str(out),
        *extra,
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=240, cwd=HERE.parent)
    assert proc.returncode == 0, f"mpiexec failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    with open(out) as fh:
        return json.load(fh)


@pytest.fixture(scope="module")
def launches(tmp_path_factory: pytest.TempPathFactory) -> dict[int, dict]:
    tmp = tmp_path_factory.mktemp("mpi")
    # One after the other: the second reuses the first's compiled programs, and two concurrent
    # jobs would only compete for the same cores.
    return {
        2: _launch(3, tmp / "two.json", tmp / "jax-cache", "--flaky"),
        3: _launch(4, tmp / "three.json", tmp / "jax-cache", "--longest-first"),
    }


def test_chunk_indices_are_equal_contiguous_chunks() -> None:
    chunks = chunk_indices(10, 3)
    assert [c.tolist() for c in chunks] == [[0, 1, 2, 3], [4, 5, 6], [7, 8, 9]]
    assert [c.tolist() for c in chunk_indices(2, 4)] == [[0], [1]]
    with pytest.raises(ValueError, match="at least 1"):
        chunk_indices(3, 0)


def test_jaxabc_import_does_not_import_mpi4py() -> None:
    code = "import sys, jaxabc, jaxabc.executors; assert 'mpi4py' not in sys.modules"
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONPATH": str(HERE.parent)}
    subprocess.run([sys.executable, "-c", code], check=True, env=env)


def test_missing_mpi4py_message(monkeypatch: pytest.MonkeyPatch) -> None:
    from jaxabc.executors.mpi import MPIExecutor

    monkeypatch.setitem(sys.modules, "mpi4py", None)
    with pytest.raises(ImportError, match=r"pip install mpi4py.*apt-get install openmpi-bin libopenmpi-dev"):
        MPIExecutor()


def test_bad_arguments() -> None:
    from jaxabc.executors.mpi import MPIExecutor

    with pytest.raises(ValueError, match="allocation"):
        MPIExecutor(allocation="greedy")
    with pytest.raises(ValueError, match="timeout"):
        MPIExecutor(timeout=0)


@pytest.mark.mpi
def test_pool_sizes(launches: dict[int, dict]) -> None:
    assert launches[2]["num_workers"] == 2
    assert launches[3]["num_workers"] == 3


@pytest.mark.mpi
@pytest.mark.parametrize("workers", [2, 3])
@pytest.mark.parametrize("executor", ["mpi", "mpi_static"])
def test_same_result_as_serial_whatever_the_ranks(launches: dict[int, dict], workers: int, executor: str) -> None:
    serial = launches[2]["serial"]
    got = launches[workers][executor]
    assert got["executor"] == executor
    # Bit for bit: task i always uses key i, whichever rank ran it.
    np.testing.assert_array_equal(got["particles"], serial["particles"])
    np.testing.assert_array_equal(got["weights"], serial["weights"])
    ranks = set(got["worker"])
    assert ranks <= set(range(1, workers + 1)), f"tasks ran on ranks {ranks}, expected 1..{workers}"
    assert len(ranks) > 1, "every task ran on one rank: the pool did not spread the work"


@pytest.mark.mpi
def test_longest_first_order_gives_the_same_result(launches: dict[int, dict]) -> None:
    """Queueing tasks longest-predicted-first changes when they run, never what they return."""
    got, serial = launches[3]["mpi_longest_first"], launches[2]["serial"]
    assert got["history"] > 0, "the cost model never saw a finished task"
    np.testing.assert_array_equal(got["particles"], serial["particles"])
    np.testing.assert_array_equal(got["weights"], serial["weights"])


@pytest.mark.mpi
@pytest.mark.parametrize("workers", [2, 3])
def test_static_allocation_is_contiguous_equal_chunks(launches: dict[int, dict], workers: int) -> None:
    rec = launches[workers]["mpi_static"]
    worker, iteration = np.asarray(rec["worker"]), np.asarray(rec["iteration"])
    for it in np.unique(iteration):
        w = worker[iteration == it]
        # Each rank's tasks form one block, and block sizes differ by at most one.
        blocks = [w[0]] + [b for a, b in itertools.pairwise(w) if a != b]
        assert len(blocks) == len(set(blocks)) == min(workers, w.size), f"iteration {it}: ranks {w.tolist()}"
        sizes = [int(np.sum(w == b)) for b in blocks]
        assert max(sizes) - min(sizes) <= 1


@pytest.mark.mpi
def test_failures_become_statuses(launches: dict[int, dict]) -> None:
    flaky = launches[2]["flaky"]
    # theta = 0.05 raises, 0.15 returns NaN, 0.27 kills its process, 0.22 hangs, 0.5 and 0.7 succeed.
    assert flaky["status"] == [
        STATUS_FAILED,
        STATUS_NONFINITE,
        STATUS_WORKER_DIED,
        STATUS_TIMEOUT,
        STATUS_OK,
        STATUS_OK,
    ]
    reasons = flaky["reasons"]
    assert "vaporised" in reasons[0]
    assert "non-finite" in reasons[1]
    assert "died (exit code 9)" in reasons[2]
    assert "timeout" in reasons[3]
    assert reasons[4] == reasons[5] == ""
    assert flaky["summaries"][0] == [None] and flaky["summaries"][4][0] == pytest.approx(0.5, abs=0.5)
    # The crashed and the timed-out children were replaced: the same pool keeps working.
    assert flaky["again_status"] == [STATUS_OK] * 6
    # A whole run over the flaky prior finished with each kind of failure recorded.
    kinds = set(flaky["run_status"])
    assert {STATUS_OK, STATUS_FAILED, STATUS_NONFINITE} <= kinds, kinds
    assert all(r for r, s in zip(flaky["run_reasons"], flaky["run_status"], strict=True) if s != STATUS_OK)
