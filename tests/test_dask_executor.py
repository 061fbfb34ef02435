"""DaskExecutor on a local dask.distributed cluster of two worker processes (skipped without dask)."""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Iterator

import jax
import numpy as np
import pytest

import jaxabc
from jaxabc import examples
from jaxabc.errors import STATUS_FAILED, STATUS_NONFINITE, STATUS_OK, STATUS_TIMEOUT, STATUS_WORKER_DIED
from jaxabc.executors import DaskExecutor, SerialExecutor, get_executor

distributed = pytest.importorskip("distributed")


def _keys(m: int, seed: int = 0) -> np.ndarray:
    return np.asarray(jax.random.key_data(jax.random.split(jax.random.key(seed), m)))


@pytest.fixture(scope="module")
def client() -> Iterator[object]:
    import dask

    # Isolation starts a process from each worker, which daemonic workers may not do; the
    # nannies read the setting at every (re)start of a worker, so it holds for the whole module.
    with dask.config.set({"distributed.worker.daemon": False}):
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
        client = distributed.Client(cluster)
        yield client
        client.close()
        cluster.close()


def test_same_summaries_as_serial_whatever_worker_ran_them(client) -> None:
    keys, thetas = _keys(8, seed=2), np.linspace(-1.0, 1.0, 16).reshape(8, 2)
    batch = DaskExecutor(client).map(examples.host_gaussian_simulate, keys, thetas)
    serial = SerialExecutor().map(examples.host_gaussian_simulate, keys, thetas)
    assert np.all(batch.status == STATUS_OK)
    np.testing.assert_array_equal(batch.summaries, serial.summaries)
    assert set(batch.worker.tolist()) <= {0, 1, 2, 3}


def test_failures_become_statuses(client) -> None:
    # flaky_simulate: < 0.1 raises, 0.1-0.2 returns NaN, 0.25-0.3 kills its process.
    thetas = np.array([[0.05], [0.15], [0.27], [0.95]])
    batch = DaskExecutor(client).map(examples.flaky_simulate, _keys(4), thetas)
    assert batch.status.tolist() == [STATUS_FAILED, STATUS_NONFINITE, STATUS_WORKER_DIED, STATUS_OK]
    assert "vaporised" in batch.reasons[0] and "non-finite" in batch.reasons[1]
    assert "died (exit code 9)" in batch.reasons[2]
    timed = DaskExecutor(client, timeout=2.0).map(examples.sleep_simulate, _keys(2), np.array([[30.0], [0.0]]))
    assert timed.status.tolist() == [STATUS_TIMEOUT, STATUS_OK]
    assert "ran longer than 2.0 s" in timed.reasons[0]
    # Every task failed: NaN summaries of the shape the executor learnt.
    ex = DaskExecutor(client, summary_shape=(3,))
    assert ex.map(examples.flaky_simulate, _keys(2), np.full((2, 3), 0.05)).summaries.shape == (2, 3)


@pytest.mark.slow
def test_a_run_equals_the_serial_run(client) -> None:
    prior = jaxabc.Uniform([-5.0], [5.0], names=("mu",))
    kwargs = dict(num_particles=30, num_steps=2, seed=5)
    serial = jaxabc.run("apmcabc", examples.host_gaussian_simulate, prior, np.array([0.3]), executor="serial", **kwargs)
    dask_run = jaxabc.run(
        "apmcabc",
        examples.host_gaussian_simulate,
        prior,
        np.array([0.3]),
        executor=DaskExecutor(client, order="longest_first"),
        **kwargs,
    )
    np.testing.assert_array_equal(dask_run.particles, serial.particles)
    np.testing.assert_array_equal(dask_run.weights, serial.weights)
    assert dask_run.metadata["executor"] == "dask"


@pytest.mark.slow
def test_a_worker_killed_mid_run_costs_no_result(client) -> None:
    """SIGKILL one worker while it runs a task: the scheduler reruns its tasks elsewhere."""
    thetas = np.full((6, 1), 1.0)
    pids = client.run(os.getpid)

    def kill_a_busy_worker() -> None:
        deadline = time.time() + 120
        while time.time() < deadline:
            busy = [a for a, tasks in client.processing().items() if tasks and a in pids]
            if busy:
                os.kill(pids[busy[0]], signal.SIGKILL)
                return
            time.sleep(0.05)

    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    batch = DaskExecutor(client).map(examples.sleep_simulate, _keys(6), thetas)
    killer.join()
    assert batch.status.tolist() == [STATUS_OK] * 6, batch.reasons
    np.testing.assert_array_equal(batch.summaries[:, 0], thetas[:, 0])


def test_bad_options_and_the_name() -> None:
    with pytest.raises(ValueError, match="isolate=True"):
        DaskExecutor(timeout=1.0, isolate=False)
    with pytest.raises(ValueError, match="n_workers"):
        DaskExecutor(n_workers=0)
    assert isinstance(get_executor("dask", n_workers=1), DaskExecutor)
