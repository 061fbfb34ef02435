"""Dask executor: host simulators on the workers of a ``dask.distributed`` cluster.

For machines and clusters without a working MPI: a local cluster, or through dask-jobqueue a
SLURM/PBS allocation, with the same guarantees as the other executors::

    ex = jaxabc.DaskExecutor()                      # a local cluster, started on the first map
    ex = jaxabc.DaskExecutor(Client(cluster))       # any cluster: dask-jobqueue, Kubernetes, ...
    result = jaxabc.run("apmcabc", simulate, prior, observed, 1000, executor=ex)

One future per task, so a free worker pulls the next task (dynamic allocation).  Task ``i``
always gets key ``i``: the result is the same whatever the number of workers.  With
``isolate=True`` (default) each worker thread runs the simulator in a child process of its own
(:class:`jaxabc.executors.workers.WorkerProcess`), so a crash costs its task only
(``STATUS_WORKER_DIED``) and ``timeout`` stops a task that runs too long (``STATUS_TIMEOUT``).
A worker lost mid-run (killed, its node gone) has its tasks rerun elsewhere by the scheduler;
a task that keeps killing workers ends as ``STATUS_WORKER_DIED`` with the reason.

Isolation starts child processes from the worker, which dask forbids in daemonic workers (its
default): while the local cluster this executor starts is open, ``distributed.worker.daemon``
is false in this process (the nannies read it at every worker restart); for a cluster of your
own, set it (``DASK_DISTRIBUTED__WORKER__DAEMON=False``) or use
``isolate=False``.  Install with ``pip install "dask[distributed]"`` (extra ``jaxabc[dask]``).
"""

from __future__ import annotations

import multiprocessing as mp
import threading
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np

from jaxabc.errors import STATUS_FAILED, STATUS_OK, STATUS_WORKER_DIED
from jaxabc.executors.base import SimulationBatch, assemble_batch, task_durations
from jaxabc.executors.scheduling import CostModel, dispatch_order, get_cost_model
from jaxabc.executors.workers import TaskRunner, pickle_simulator

__all__ = ["DaskExecutor", "dask_available"]

_INSTALL_HINT = 'jaxabc\'s Dask executor needs dask.distributed: pip install "dask[distributed]"'


def _import_distributed() -> Any:
    """Import dask.distributed lazily: ``import jaxabc`` must work without it."""
    try:
        import distributed
    except ImportError as exc:
        raise ImportError(f"{_INSTALL_HINT} ({exc})") from exc
    return distributed


def dask_available() -> bool:
    """Whether ``dask.distributed`` can be imported."""
    try:
        _import_distributed()
    except ImportError:
        return False
    return True


# ---------------------------------------------------------------------------------------------
# Worker side: module-level so that dask pickles it by reference.

# Per worker thread: what runs its tasks (the unpickled simulator or its isolation child).
_THREAD_STATE = threading.local()


def _dask_task(
    payload: bytes, isolate: bool, timeout: float | None, key: np.ndarray, theta: np.ndarray
) -> tuple[Any, int, str, float, float, str]:
    """Run one task on a dask worker; returns ``(out, status, reason, seconds, cpu_seconds, worker)``.

    Never raises for a simulator's failure; a simulator that cannot be loaded fails its task.
    """
    from distributed import get_worker

    address = get_worker().address
    try:
        if isolate and mp.current_process().daemon:
            raise RuntimeError(
                "this dask worker is a daemonic process and cannot start the simulator's isolation "
                "process: start the workers with distributed.worker.daemon = False "
                "(DASK_DISTRIBUTED__WORKER__DAEMON=False) or use DaskExecutor(isolate=False)"
            )
        runners = _THREAD_STATE.__dict__.setdefault("runners", {})
        runner = runners.setdefault(isolate, TaskRunner(isolate))
        return (*runner.run(payload, key, theta, timeout), address)
    except Exception as exc:
        last = traceback.format_exception_only(type(exc), exc)[-1].strip()
        return None, STATUS_FAILED, f"dask worker {address} could not run the simulator: {last}", 0.0, np.nan, address


# ---------------------------------------------------------------------------------------------
# Driver side.


class DaskExecutor:
    """Run host simulators on a ``dask.distributed`` cluster, one future per task.

    Parameters
    ----------
    client : distributed.Client, optional
        The cluster to use.  ``None``: a ``LocalCluster`` of ``n_workers`` single-threaded worker
        processes, started on the first :meth:`map` and shut down by :meth:`close`.
    n_workers : int, optional
        Workers of the local cluster (default: the number of cores); ignored with a ``client``.
    timeout : float, optional
        Seconds one task may run before its isolation process is killed (``STATUS_TIMEOUT``).
        Needs ``isolate=True``: a task running in a dask worker's thread cannot be stopped.
    isolate : bool
        Run the simulator in a child process per worker thread (default), so a crash or a
        timeout costs one task.
    order : {"fifo", "longest_first"} or CostModel, optional
        Queue priority of the tasks: ``"longest_first"`` gives the longest *predicted* the
        highest priority (:mod:`jaxabc.executors.scheduling`); results never depend on it.
    summary_shape : tuple of int, optional
        Shape of one task's summaries, for a batch in which every task fails; learnt from the
        first successful task when not given.

    Attributes
    ----------
    name : str
        ``"dask"``, the name :func:`jaxabc.run` accepts.

    Notes
    -----
    ``worker`` in the returned batch numbers the dask workers in the order this executor first
    saw them (a restarted worker has a new address, hence a new number).  The simulator must be
    picklable; it is pickled once per :meth:`map`.
    """

    name = "dask"

    def __init__(
        self,
        client: Any = None,
        n_workers: int | None = None,
        timeout: float | None = None,
        isolate: bool = True,
        order: str | CostModel | None = None,
        summary_shape: tuple[int, ...] | None = None,
    ):
        if n_workers is not None and n_workers < 1:
            raise ValueError(f"n_workers must be at least 1, got {n_workers}")
        if timeout is not None and timeout <= 0:
            raise ValueError(f"timeout must be positive, got {timeout}")
        if timeout is not None and not isolate:
            raise ValueError("a timeout needs isolate=True: a task running inside a dask worker cannot be stopped")
        _import_distributed()  # fail at construction, with the install hint, rather than mid-run
        self.timeout = timeout
        self.isolate = bool(isolate)
        self.n_workers = n_workers
        self.cost_model = get_cost_model(order)
        self.summary_shape = None if summary_shape is None else tuple(summary_shape)
        self._client: Any = client
        self._own_cluster: Any = None
        self._config: Any = None
        self._worker_ids: dict[str, int] = {}

    @property
    def client(self) -> Any:
        """The ``distributed.Client`` (starts the local cluster if there is none)."""
        if self._client is None:
            import dask.config

            distributed = _import_distributed()
            # Isolation starts processes from the workers, which daemonic processes may not do.
            # The nannies read this setting whenever they (re)start a worker, so it stays set
            # until close(), not only while the cluster starts.
            self._config = dask.config.set({"distributed.worker.daemon": False})
            self._own_cluster = distributed.LocalCluster(
                n_workers=self.n_workers, threads_per_worker=1, processes=True, dashboard_address=None
            )
            self._client = distributed.Client(self._own_cluster)
        return self._client

    def map(self, simulate: Callable, keys: np.ndarray, thetas: np.ndarray) -> SimulationBatch:
        """Run ``simulate(keys[i], thetas[i])`` for every ``i`` on the cluster's workers.

        Parameters
        ----------
        simulate : callable ``(key uint32[2], theta (d,)) -> summaries``
        keys : numpy.ndarray of uint32, shape (m, 2)
        thetas : numpy.ndarray, shape (m, d)

        Returns
        -------
        SimulationBatch
        """
        distributed = _import_distributed()
        thetas = np.asarray(thetas)
        keys = np.asarray(keys, np.uint32)
        m = thetas.shape[0]
        if m == 0:
            raise ValueError("nothing to simulate: the batch is empty")
        if keys.shape[0] != m:
            raise ValueError(f"got {keys.shape[0]} keys for {m} parameter vectors: need one each")
        payload = pickle_simulator(simulate)
        client = self.client
        order = dispatch_order(self.cost_model, thetas)
        futures = {}
        for rank, i in enumerate(order):
            fut = client.submit(
                _dask_task, payload, self.isolate, self.timeout, keys[i], thetas[i], pure=False, priority=m - rank
            )
            futures[fut] = int(i)

        outputs: list = [None] * m
        status = np.full(m, STATUS_WORKER_DIED, np.int32)
        reasons, times = [""] * m, np.zeros(m)
        workers, cpu = np.full(m, -1, np.int32), np.full(m, np.nan)
        for fut in distributed.as_completed(list(futures)):
            i = futures[fut]
            try:
                out, status[i], reasons[i], times[i], cpu[i], address = fut.result()
            except distributed.KilledWorker as exc:
                status[i] = STATUS_WORKER_DIED
                reasons[i] = f"the task killed every dask worker that ran it ({exc})"
                continue
            except Exception as exc:  # transport: arguments that do not unpickle, a lost client
                last = traceback.format_exception_only(type(exc), exc)[-1].strip()
                status[i], reasons[i] = STATUS_FAILED, f"dask could not run the task: {last}"
                continue
            outputs[i] = out
            workers[i] = self._worker_ids.setdefault(address, len(self._worker_ids))
        batch = assemble_batch(outputs, status, reasons, times, workers, cpu, self.summary_shape)
        if np.any(batch.status == STATUS_OK):
            self.summary_shape = tuple(batch.summaries.shape[1:])
        if self.cost_model is not None:
            ran = workers >= 0
            self.cost_model.observe(thetas[ran], task_durations(batch.wall_time, batch.cpu_time)[ran])
        return batch

    def close(self) -> None:
        """Shut down the local cluster this executor started (a client passed in stays open)."""
        if self._own_cluster is not None:
            client, cluster = self._client, self._own_cluster
            self._client = self._own_cluster = None
            client.close()
            cluster.close()
            self._config.__exit__(None, None, None)

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
