"""MPI executors: dynamic (pull one task at a time) and static (equal chunks) allocation.

Both run a host simulator ``simulate(key, theta) -> summaries`` on the worker processes of an
:class:`mpi4py.futures.MPIPoolExecutor` and follow the interface of :mod:`jaxabc.executors`::

    ex = jaxabc.MPIExecutor(allocation="dynamic")    # or jaxabc.run(..., executor="mpi")
    batch = ex.map(simulate, keys, thetas)           # SimulationBatch

``allocation="dynamic"`` (``executor="mpi"``)
    One future per task: a worker that finishes asks for the next single task.  This is the
    paper's *dynamic allocation* (Dutta et al. 2018, section "Time imbalance and dynamic
    allocation for MPI"), Graham's greedy list scheduling, whose makespan is at most
    ``total / n + longest task``.
``allocation="static"`` (``executor="mpi_static"``)
    The ``m`` tasks are split up front into ``n`` contiguous chunks of equal size (sizes differ
    by at most one), one per worker, each run serially: the straightforward scheme the paper
    compares against.  Kept for the comparison; it loses badly when simulation times vary.

Task ``i`` always gets key ``i``, and host simulators derive their seeds from that key
(:func:`jaxabc.seed_from_key`), so a run gives the same result whatever the number of ranks and
whichever rank ran which task.

Launching
---------
Start the script under ``mpiexec`` through ``mpi4py.futures``, which makes rank 0 run the script
and ranks ``1 .. K-1`` serve as the pool's workers::

    mpiexec -n K python -m mpi4py.futures your_script.py

Open MPI refuses to run as root and to start more ranks than there are cores unless told::

    mpiexec --allow-run-as-root --oversubscribe -n K python -m mpi4py.futures your_script.py
    # or, equivalently, in the environment:
    export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
    export OMPI_MCA_rmaps_base_oversubscribe=1

The script itself needs nothing MPI-specific besides the executor name::

    if __name__ == "__main__":      # required: workers import the main module
        result = jaxabc.run("apmcabc", simulate, prior, observed, 1000, executor="mpi")

Without ``mpiexec`` (plain ``python your_script.py``) the pool *spawns* ``max_workers`` worker
processes with ``MPI_Comm_spawn`` (one worker when ``max_workers`` is not given and MPI does not
report a universe size).  Install with ``pip install mpi4py`` and an MPI library
(``apt-get install openmpi-bin libopenmpi-dev``, or ``pip install mpi4py mpich``).

Failures
--------
A task whose simulator raises (or returns NaN) becomes a failure record with the reason, as in
every executor; the run goes on.  With ``isolate=True`` (the default) each worker rank runs the
simulator in a child process of its own (:class:`jaxabc.executors.workers.WorkerProcess`,
started once and reused), so
a simulator that crashes its process (segfault, ``os._exit``, out-of-memory kill) costs only its
task (``STATUS_WORKER_DIED``, and the child is replaced) and ``timeout`` stops a task that runs too
long (``STATUS_TIMEOUT``).  The MPI rank itself never runs simulator code then, which matters
because an MPI job cannot lose a rank: under ``mpiexec`` Open MPI aborts the whole job when any
rank dies, and a spawned pool waits forever for the dead rank's answer.

With ``isolate=False`` the simulator runs inside the rank (no child process: cheaper, for
simulators that cannot crash, such as the benchmarks' sleeping tasks).  A rank that dies then
aborts the job under ``mpiexec`` (``mpiexec`` names the rank and its exit code); with a
``timeout`` the driver side stops waiting for a task that has run longer than ``timeout``
seconds (a hung or dead rank), marks it ``STATUS_TIMEOUT`` and every unfinished task
``STATUS_WORKER_DIED``, and refuses further work with a clear error, because a lost rank cannot be
replaced.  Without a timeout a dead spawned rank would hang the run, so give one.
"""

from __future__ import annotations

import concurrent.futures
import time
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np

from jaxabc.errors import STATUS_FAILED, STATUS_OK, STATUS_TIMEOUT, STATUS_WORKER_DIED
from jaxabc.executors.base import SimulationBatch, assemble_batch, task_durations
from jaxabc.executors.scheduling import CostModel, dispatch_order, get_cost_model
from jaxabc.executors.workers import TaskRunner, pickle_simulator

__all__ = ["ALLOCATIONS", "MPIExecutor", "chunk_indices", "mpi_available"]

ALLOCATIONS = ("dynamic", "static")

_INSTALL_HINT = (
    "jaxabc's MPI executors need mpi4py and an MPI library: `pip install mpi4py` and "
    "`apt-get install openmpi-bin libopenmpi-dev` (or `pip install mpi4py mpich`)"
)

# How often the driver side looks at unfinished futures when it enforces a timeout itself.
_POLL_SECONDS = 0.05


def _import_mpi() -> tuple[Any, Any]:
    """Import mpi4py lazily: ``import jaxabc`` must work on machines without MPI."""
    try:
        from mpi4py import MPI, futures
    except ImportError as exc:
        raise ImportError(f"{_INSTALL_HINT} ({exc})") from exc
    except (OSError, RuntimeError) as exc:  # mpi4py present but libmpi missing or broken
        raise ImportError(f"{_INSTALL_HINT}; mpi4py failed to load MPI: {exc}") from exc
    return MPI, futures


def mpi_available() -> bool:
    """Whether mpi4py and an MPI library can be imported."""
    try:
        _import_mpi()
    except ImportError:
        return False
    return True


def chunk_indices(num_tasks: int, num_workers: int) -> list[np.ndarray]:
    """Static allocation: split ``range(num_tasks)`` into ``num_workers`` contiguous chunks.

    Chunk sizes differ by at most one (the first ``num_tasks % num_workers`` chunks are one
    larger); empty chunks (more workers than tasks) are dropped.

    Returns
    -------
    list of numpy.ndarray of int
        The task indices of each chunk, in order.
    """
    if num_workers < 1:
        raise ValueError(f"num_workers must be at least 1, got {num_workers}")
    return [c for c in np.array_split(np.arange(num_tasks), num_workers) if c.size]


# ---------------------------------------------------------------------------------------------
# Worker side.  These functions run on the MPI worker ranks; they are module-level so that
# mpi4py pickles them by reference.

# Per worker rank and isolation mode: what runs its tasks (the unpickled simulator or its child).
_RUNNERS: dict[bool, TaskRunner] = {}


def _worker_rank() -> int:
    from mpi4py import MPI

    return MPI.COMM_WORLD.Get_rank()


def _run_tasks(
    payload: bytes, isolate: bool, timeout: float | None, indices: np.ndarray, keys: np.ndarray, thetas: np.ndarray
) -> list[tuple[int, Any, int, str, float, float, int]]:
    """Run tasks ``indices`` one after another on this rank.

    Returns one ``(index, summaries or None, status, reason, seconds, cpu_seconds, rank)`` per
    task.  Never
    raises: a simulator that cannot be loaded fails its tasks with the reason.
    """
    rank = _worker_rank()
    out = []
    for j, i in enumerate(indices):
        try:
            runner = _RUNNERS.setdefault(isolate, TaskRunner(isolate, rank))
            summaries, status, reason, seconds, cpu = runner.run(payload, keys[j], thetas[j], timeout)
        except Exception as exc:
            last = traceback.format_exception_only(type(exc), exc)[-1].strip()
            summaries, status, seconds, cpu = None, STATUS_FAILED, 0.0, np.nan
            reason = f"MPI rank {rank} could not run the simulator: {last}"
        out.append((int(i), summaries, int(status), reason, float(seconds), float(cpu), rank))
    return out


# ---------------------------------------------------------------------------------------------
# Driver side.


class MPIExecutor:
    """Run host simulators on MPI worker ranks with dynamic or static allocation.

    Parameters
    ----------
    allocation : {"dynamic", "static"}
        ``"dynamic"``: a free worker pulls the next single task (one future per task).
        ``"static"``: equal contiguous chunks, one per worker, fixed before anything runs.
    max_workers : int, optional
        Workers to spawn when the script was not started under ``mpiexec ... -m mpi4py.futures``
        (there the pool is the other ``K - 1`` ranks).  Default: mpi4py's choice (the MPI
        universe size, else one).
    timeout : float, optional
        Seconds one task may run.  With ``isolate=True`` the worker rank kills the task's process
        group and records ``STATUS_TIMEOUT``; with ``isolate=False`` the driver stops waiting
        (see the module notes: the pool is then unusable).
    isolate : bool
        Run the simulator in a child process of each worker rank (default), so that a crash or
        a timeout costs one task, not the MPI job.  ``False`` runs it in the rank itself.
    order : {"fifo", "longest_first"} or CostModel, optional
        Dynamic allocation only: the order in which tasks are queued for the ranks.
        ``"longest_first"`` queues the longest *predicted* first, learnt from the costs of
        earlier tasks (CPU time, see :func:`jaxabc.executors.task_durations`;
        :mod:`jaxabc.executors.scheduling`); results never depend on it.
    summary_shape : tuple of int, optional
        Shape of one task's summaries, for a batch in which every task fails; learnt from the
        first successful task when not given.

    Attributes
    ----------
    name : str
        ``"mpi"`` (dynamic) or ``"mpi_static"``, the names :func:`jaxabc.run` accepts.
    last_makespan : float
        Wall seconds of the last :meth:`map`, from the first submission to the last result.

    Notes
    -----
    The pool starts on the first :meth:`map` and is reused until :meth:`close`.  ``worker`` in
    the returned batch is the ``MPI.COMM_WORLD`` rank of the process that ran the task (``1 ..
    K-1`` under ``mpiexec -n K``; ``0 .. max_workers-1`` of the spawned world otherwise).  The
    simulator must be picklable (a module-level function or an instance of a module-level class);
    it is pickled once per :meth:`map` and unpickled once per rank.
    """

    def __init__(
        self,
        allocation: str = "dynamic",
        max_workers: int | None = None,
        timeout: float | None = None,
        isolate: bool = True,
        order: str | CostModel | None = None,
        summary_shape: tuple[int, ...] | None = None,
    ):
        if allocation not in ALLOCATIONS:
            raise ValueError(f"allocation must be one of {ALLOCATIONS}, got {allocation!r}")
        if max_workers is not None and max_workers < 1:
            raise ValueError(f"max_workers must be at least 1, got {max_workers}")
        if timeout is not None and timeout <= 0:
            raise ValueError(f"timeout must be positive, got {timeout}")
        self.allocation = allocation
        self.name = "mpi" if allocation == "dynamic" else "mpi_static"
        self.max_workers = max_workers
        self.timeout = timeout
        self.isolate = bool(isolate)
        if order not in (None, "fifo") and allocation != "dynamic":
            raise ValueError("order applies to dynamic allocation only; static chunks are fixed up front")
        self.cost_model = get_cost_model(order)
        self.summary_shape = None if summary_shape is None else tuple(summary_shape)
        self.last_makespan = float("nan")
        self._pool: Any = None
        self._broken: str | None = None
        _import_mpi()  # fail at construction, with the install hint, rather than mid-run

    @property
    def num_workers(self) -> int:
        """Number of worker ranks (starts the pool)."""
        return self._ensure_pool().num_workers

    def _ensure_pool(self) -> Any:
        if self._broken is not None:
            raise RuntimeError(
                f"the MPI pool is unusable: {self._broken}. A lost MPI rank cannot be replaced; "
                "start the job again (and use isolate=True so that simulator crashes and timeouts "
                "cost one task instead of a rank)"
            )
        if self._pool is None:
            _, futures = _import_mpi()
            kwargs = {} if self.max_workers is None else {"max_workers": self.max_workers}
            self._pool = futures.MPIPoolExecutor(**kwargs)
            if self._pool.num_workers < 1:
                raise RuntimeError("the MPI pool has no workers: start with `mpiexec -n K` and K >= 2")
        return self._pool

    def map(self, simulate: Callable, keys: np.ndarray, thetas: np.ndarray) -> SimulationBatch:
        """Run ``simulate(keys[i], thetas[i])`` for every ``i`` on the worker ranks.

        Parameters
        ----------
        simulate : callable ``(key uint32[2], theta (d,)) -> summaries``
        keys : numpy.ndarray of uint32, shape (m, 2)
            Raw key data, one key per task.
        thetas : numpy.ndarray, shape (m, d)

        Returns
        -------
        SimulationBatch
        """
        thetas = np.asarray(thetas)
        keys = np.asarray(keys, np.uint32)
        m = thetas.shape[0]
        if m == 0:
            raise ValueError("nothing to simulate: the batch is empty")
        if keys.shape[0] != m:
            raise ValueError(f"got {keys.shape[0]} keys for {m} parameter vectors: need one each")
        payload = pickle_simulator(simulate)
        pool = self._ensure_pool()
        if self.allocation == "dynamic":
            groups = [np.array([i]) for i in dispatch_order(self.cost_model, thetas)]
        else:
            groups = chunk_indices(m, pool.num_workers)

        outputs: list = [None] * m
        status = np.full(m, STATUS_WORKER_DIED, np.int32)
        reasons = [""] * m
        times, workers, cpu = np.zeros(m), np.full(m, -1, np.int32), np.full(m, np.nan)
        t0 = time.perf_counter()
        futs = {
            pool.submit(_run_tasks, payload, self.isolate, self.timeout, idx, keys[idx], thetas[idx]): idx
            for idx in groups
        }
        finished, late = self._collect(futs)
        self.last_makespan = time.perf_counter() - t0
        for fut, results in finished:
            if isinstance(results, BaseException):
                # _run_tasks never raises, so this is the transport (jaxabc not importable on the
                # worker, arguments that do not unpickle): a failure of these tasks, not of the pool.
                last = traceback.format_exception_only(type(results), results)[-1].strip()
                for i in futs[fut]:
                    status[i], reasons[i] = STATUS_FAILED, f"MPI worker could not run the task: {last}"
                continue
            for i, out, st, reason, seconds, cpu_seconds, rank in results:
                outputs[i], status[i], reasons[i], times[i], workers[i] = out, st, reason, seconds, rank
                cpu[i] = cpu_seconds
        for fut in late:
            for i in futs[fut]:
                status[i], times[i] = STATUS_TIMEOUT, self.timeout
                reasons[i] = (
                    f"timeout: its MPI worker ran longer than {self.timeout} s per task; the rank "
                    "cannot be stopped (isolate=False) and the pool was abandoned"
                )
        answered = {fut for fut, _ in finished} | set(late)
        for fut, idx in futs.items():
            if fut not in answered:
                for i in idx:
                    reasons[i] = f"not run or lost: the MPI pool became unusable ({self._broken})"
        batch = assemble_batch(outputs, status, reasons, times, workers, cpu, self.summary_shape)
        if np.any(batch.status == STATUS_OK):
            self.summary_shape = tuple(batch.summaries.shape[1:])
        if self.cost_model is not None:
            ran = workers >= 0
            self.cost_model.observe(thetas[ran], task_durations(batch.wall_time, batch.cpu_time)[ran])
        return batch

    def _collect(self, futs: dict) -> tuple[list[tuple[Any, Any]], list[Any]]:
        """Wait for every future.

        Returns ``(finished, late)``: ``(future, results or exception)`` for each answered future,
        and the futures abandoned past the driver-side timeout.  A broken pool (a lost worker rank)
        or a late future marks the pool unusable (the next :meth:`map` raises); the futures not
        answered then keep ``STATUS_WORKER_DIED``.
        """
        _, futures = _import_mpi()
        broken_types = (futures.BrokenExecutor, concurrent.futures.BrokenExecutor)
        pending = set(futs)
        started: dict[Any, float] = {}
        # With isolation the rank enforces the timeout itself; the driver only watches for a
        # hung or lost rank when the simulator runs inside the rank.
        watch = self.timeout is not None and not self.isolate
        finished: list[tuple[Any, Any]] = []
        late: list[Any] = []
        while pending and self._broken is None:
            done, pending = concurrent.futures.wait(
                pending,
                timeout=_POLL_SECONDS if watch else None,
                return_when=concurrent.futures.FIRST_COMPLETED,
            )
            for fut in done:
                try:
                    finished.append((fut, fut.result()))
                except broken_types as exc:
                    self._broken = f"a worker rank was lost ({exc})"
                except Exception as exc:
                    finished.append((fut, exc))
            if watch and self._broken is None:
                now = time.perf_counter()
                for fut in pending:
                    if fut.running():
                        started.setdefault(fut, now)
                # A static chunk of k tasks may take k timeouts.
                assert self.timeout is not None  # watch implies a timeout
                late = [f for f in pending if f in started and now - started[f] > self.timeout * len(futs[f])]
                if late:
                    self._broken = (
                        f"{len(late)} future(s) ran past the {self.timeout} s timeout on ranks "
                        "that cannot be stopped (isolate=False)"
                    )
        if self._broken is not None:
            self._abandon(pending)
        return finished, late

    def _abandon(self, pending: set) -> None:
        for fut in pending:
            fut.cancel()
        pool, self._pool = self._pool, None
        if pool is not None:
            # A lost rank never answers: do not wait for it.
            pool.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        """Shut the pool down (the worker ranks stay until the MPI job ends)."""
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True)

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
