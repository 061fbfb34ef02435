"""Executors: the same draws on every backend, failures as statuses, timeouts, set-up errors."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import jax
import numpy as np
import pytest

import jaxabc
from jaxabc import examples
from jaxabc.errors import STATUS_FAILED, STATUS_NONFINITE, STATUS_OK, STATUS_TIMEOUT, STATUS_WORKER_DIED
from jaxabc.executors import (
    EXECUTOR_NAMES,
    ProcessPoolExecutor,
    SerialExecutor,
    VmapExecutor,
    get_executor,
)

ROOT = Path(__file__).parents[1]


def _keys(m: int, seed: int = 0) -> np.ndarray:
    return np.asarray(jax.random.key_data(jax.random.split(jax.random.key(seed), m)))


class _UnpicklesBadly:
    """Pickles fine, fails to unpickle (``int("not a number")``): a worker cannot load it."""

    def __reduce__(self) -> tuple:
        return int, ("not a number",)

    def __call__(self, key: np.ndarray, theta: np.ndarray) -> np.ndarray:
        return theta


@pytest.fixture(scope="module")
def pool() -> Iterator[ProcessPoolExecutor]:
    """One two-worker pool for the module: workers are reused across simulators (and tests)."""
    ex = ProcessPoolExecutor(max_workers=2)
    yield ex
    ex.close()


@pytest.fixture(params=["serial", "process_pool", "vmap"])
def executor(request: pytest.FixtureRequest, pool: ProcessPoolExecutor) -> jaxabc.executors.Executor:
    return {"serial": SerialExecutor(), "process_pool": pool, "vmap": VmapExecutor()}[request.param]


def test_same_keys_give_the_same_summaries_on_every_executor(executor) -> None:
    keys, thetas = _keys(9, seed=4), np.linspace(-2.0, 2.0, 18, dtype=np.float32).reshape(9, 2)
    batch = executor.map(examples.gaussian_simulate, keys, thetas)
    # The reference: each task in this process, task i with key i.
    expected = np.stack(
        [
            np.asarray(examples.gaussian_simulate(jax.random.wrap_key_data(k), t))
            for k, t in zip(keys, thetas, strict=True)
        ]
    )
    assert batch.summaries.shape == (9, 2)
    assert np.all(batch.status == STATUS_OK) and batch.reasons == [""] * 9
    # Vectorised and scalar XLA code may round the last bit differently.
    np.testing.assert_allclose(batch.summaries, expected, rtol=1e-6, atol=1e-6)
    assert batch.wall_time.shape == batch.worker.shape == (9,)


@pytest.mark.parametrize("name", ["serial", "process_pool"])
def test_failures_become_statuses_with_reasons(name: str, pool: ProcessPoolExecutor) -> None:
    ex = pool if name == "process_pool" else SerialExecutor()
    # flaky_simulate: < 0.1 raises, 0.1-0.2 returns NaN, 0.25-0.3 kills its process, else succeeds.
    thetas = np.array([[0.05], [0.15], [0.5]] + ([[0.27]] if name == "process_pool" else []))
    batch = ex.map(examples.flaky_simulate, _keys(len(thetas)), thetas)
    expected = [STATUS_FAILED, STATUS_NONFINITE, STATUS_OK] + ([STATUS_WORKER_DIED] if name == "process_pool" else [])
    assert batch.status.tolist() == expected
    assert "vaporised" in batch.reasons[0] and "non-finite" in batch.reasons[1] and batch.reasons[2] == ""
    assert np.all(np.isnan(batch.summaries[[0, 1]])) and np.isfinite(batch.summaries[2, 0])
    if name == "process_pool":
        assert "died (exit code 9) while running it" in batch.reasons[3]
        # The dead worker was replaced: the pool still has two and still works.
        again = ex.map(examples.sleep_simulate, _keys(2), np.array([[0.0], [0.0]]))
        assert np.all(again.status == STATUS_OK) and len(ex._workers) == 2


def test_timeout_stops_a_task_and_the_pool_goes_on(pool: ProcessPoolExecutor) -> None:
    pool.timeout = 1.0
    try:
        batch = pool.map(examples.sleep_simulate, _keys(2), np.array([[30.0], [0.0]]))
    finally:
        pool.timeout = None
    assert batch.status.tolist() == [STATUS_TIMEOUT, STATUS_OK]
    assert "ran longer than 1.0 s" in batch.reasons[0]
    assert 1.0 <= batch.wall_time[0] < 10.0


def test_a_simulator_the_workers_cannot_load_fails_its_tasks(pool: ProcessPoolExecutor) -> None:
    batch = pool.map(_UnpicklesBadly(), _keys(3), np.zeros((3, 1)))
    assert batch.status.tolist() == [STATUS_FAILED] * 3
    assert all("could not load the simulator" in r and "not a number" in r for r in batch.reasons)
    # The same processes load the next simulator.
    assert pool.map(examples.sleep_simulate, _keys(1), np.zeros((1, 1))).status.tolist() == [STATUS_OK]


def test_an_unpicklable_simulator_is_refused_before_any_worker_starts() -> None:
    ex = ProcessPoolExecutor(max_workers=1)
    with pytest.raises(TypeError, match="module-level function"):
        ex.map(lambda key, theta: theta, _keys(1), np.zeros((1, 1)))
    assert ex._workers == []


@pytest.mark.parametrize("name", ["serial", "process_pool"])
def test_a_batch_where_every_task_fails_keeps_the_summary_shape(name: str, pool: ProcessPoolExecutor) -> None:
    thetas_ok = np.full((2, 3), 0.5)
    thetas_bad = np.full((4, 3), 0.05)  # every task raises
    fresh = ProcessPoolExecutor if name == "process_pool" else SerialExecutor
    # Learnt from an earlier successful batch ...
    ex = pool if name == "process_pool" else SerialExecutor()
    ex.summary_shape = None
    assert ex.map(examples.flaky_simulate, _keys(2), thetas_ok).summaries.shape == (2, 3)
    failed = ex.map(examples.flaky_simulate, _keys(4), thetas_bad)
    assert failed.summaries.shape == (4, 3) and np.all(np.isnan(failed.summaries))
    assert np.all(failed.status == STATUS_FAILED)
    # ... or given up front (the driver passes the observed data's shape).
    if name == "serial":
        given = fresh(summary_shape=(3,)).map(examples.flaky_simulate, _keys(4), thetas_bad)
        assert given.summaries.shape == (4, 3)


def test_the_driver_tells_the_executor_the_summary_shape() -> None:
    ex = SerialExecutor()
    prior = jaxabc.Uniform([0.0, 0.0, 0.0], [0.09, 0.09, 0.09])
    # Every simulation raises, so only the driver can have told the executor the shape.
    with pytest.raises(jaxabc.TooManyFailures):
        jaxabc.run(
            "rejection",
            examples.flaky_simulate,
            prior,
            np.zeros(3),
            num_particles=30,
            quantile=0.5,
            executor=ex,
            seed=0,
        )
    assert ex.summary_shape == (3,)


def test_a_script_without_the_main_guard_is_told_so(tmp_path: Path) -> None:
    script = tmp_path / "unguarded.py"
    script.write_text(
        textwrap.dedent("""
        import numpy as np
        import jaxabc
        from jaxabc.examples import sleep_simulate

        ex = jaxabc.ProcessPoolExecutor(max_workers=1)
        ex.map(sleep_simulate, np.zeros((2, 2), np.uint32), np.zeros((2, 1)))
        print("finished")
    """)
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"}
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode != 0 and "finished" not in proc.stdout
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("RuntimeError: the process pool could not start its workers"), proc.stderr[-2000:]
    assert "if __name__ == '__main__':" in last


def test_get_executor_names_and_objects() -> None:
    assert isinstance(get_executor(None), VmapExecutor) and isinstance(get_executor("serial"), SerialExecutor)
    ex = SerialExecutor()
    assert get_executor(ex) is ex
    assert set(EXECUTOR_NAMES) == {"vmap", "serial", "process_pool", "mpi", "mpi_static", "dask"}
    with pytest.raises(ValueError, match="unknown executor 'gpu-cluster'"):
        get_executor("gpu-cluster")
    with pytest.raises(ValueError, match="max_workers"):
        get_executor("process_pool", max_workers=0)


def test_public_names_are_importable_from_the_package_and_from_executors() -> None:
    for name in (
        "ProcessPoolExecutor",
        "SerialExecutor",
        "VmapExecutor",
        "SimulationBatch",
        "MPIExecutor",
        "get_executor",
        "task_durations",
        "mark_nonfinite",
    ):
        assert getattr(jaxabc, name) is getattr(jaxabc.executors, name)
