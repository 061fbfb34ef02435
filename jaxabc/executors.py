"""Where a batch of simulations runs: one interface for every backend.

An executor maps a simulator over parameter vectors::

    batch = executor.map(simulate, keys, thetas)

``keys`` has one PRNG key per task (raw ``uint32`` key data, shape (m, 2)), ``thetas`` has shape
(m, d).  The result, :class:`SimulationBatch`, holds the summaries (NaN where a task failed),
a status code and a reason per task, its wall and CPU time and the worker that ran it.  Task ``i`` always
gets key ``i``, so the summaries do not depend on which worker ran which task, or in which order:
the same seed gives the same result on every executor.

Implementations
---------------
:class:`VmapExecutor`
    In-process, ``jax.jit(jax.vmap(simulate))`` in memory-bounded chunks, for JAX simulators.
:class:`SerialExecutor`
    In-process, one task after another, for host (non-JAX) simulators and debugging.
:class:`ProcessPoolExecutor`
    Local worker processes with dynamic allocation: a free worker pulls the next single task.
    A task that raises, runs past the timeout (the worker is killed and replaced) or kills its
    worker becomes a failure record; the run goes on.
MPI executors (dynamic pull queue and static chunks) live in :mod:`jaxabc.mpi` and follow the
same interface.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import resource
import signal
import threading
import time
import traceback
from collections.abc import Callable
from typing import Any, NamedTuple, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.errors import (
    STATUS_FAILED,
    STATUS_NONFINITE,
    STATUS_OK,
    STATUS_TIMEOUT,
    STATUS_WORKER_DIED,
    SimulationFailure,
)
from jaxabc.scheduling import CostModel, dispatch_order, get_cost_model

__all__ = [
    "Executor",
    "ProcessPoolExecutor",
    "SerialExecutor",
    "SimulationBatch",
    "VmapExecutor",
    "get_executor",
    "mark_nonfinite",
    "task_durations",
]


class SimulationBatch(NamedTuple):
    """Outcome of :meth:`Executor.map` for ``m`` tasks.

    Attributes
    ----------
    summaries : numpy.ndarray, shape (m, *summary_shape)
        NaN where the task failed.
    status : numpy.ndarray of int, shape (m,)
        :mod:`jaxabc.errors` status codes.
    reasons : list of str, length m
        Empty for successes; what went wrong otherwise.
    wall_time : numpy.ndarray, shape (m,)
        Seconds per task (a chunk's time shared equally among its tasks under vmap).
    worker : numpy.ndarray of int, shape (m,)
        Which worker ran the task (0 for in-process executors).
    cpu_time : numpy.ndarray, shape (m,), optional
        CPU seconds per task: the process that ran it plus the programs it started and waited
        for (``getrusage``), NaN where unknown (a killed task, vmap chunks).  Unlike the wall
        time it does not grow when other work shares the cores, so it is the task's cost that
        cost models and the speedup study learn from.
    """

    summaries: np.ndarray
    status: np.ndarray
    reasons: list[str]
    wall_time: np.ndarray
    worker: np.ndarray
    cpu_time: np.ndarray | None = None


def task_durations(wall_time: np.ndarray, cpu_time: np.ndarray | None) -> np.ndarray:
    """Per-task cost in seconds, as cost models and the speedup study use it.

    The CPU time where the task kept a core busy for at least a tenth of its wall time
    (a computation: its wall time grows with the machine's load, its CPU time does not);
    the wall time otherwise (a task that mostly waits -- sleep, I/O, an accelerator -- or
    whose CPU time is unknown).
    """
    wall = np.asarray(wall_time, np.float64)
    if cpu_time is None:
        return wall
    cpu = np.asarray(cpu_time, np.float64)
    busy = np.isfinite(cpu) & (cpu >= 0.1 * wall)
    return np.where(busy, cpu, wall)


class Executor(Protocol):
    """What the driver needs from an executor."""

    name: str

    def map(self, simulate: Callable, keys: np.ndarray, thetas: np.ndarray) -> SimulationBatch: ...

    def close(self) -> None: ...


def mark_nonfinite(batch: SimulationBatch) -> SimulationBatch:
    """Turn successful tasks with NaN/inf summaries into ``STATUS_NONFINITE`` failures."""
    m = batch.summaries.shape[0]
    flat = batch.summaries.reshape(m, -1)
    bad = (batch.status == STATUS_OK) & ~np.all(np.isfinite(flat), axis=1)
    if not np.any(bad):
        return batch
    status = batch.status.copy()
    status[bad] = STATUS_NONFINITE
    reasons = list(batch.reasons)
    for i in np.flatnonzero(bad):
        n_bad = int(np.sum(~np.isfinite(flat[i])))
        reasons[i] = f"simulator returned {n_bad} non-finite summaries of {flat.shape[1]}"
    summaries = batch.summaries.copy()
    summaries[bad] = np.nan
    return batch._replace(summaries=summaries, status=status, reasons=reasons)


def _wrap_keys(keys: np.ndarray) -> jax.Array:
    return jax.random.wrap_key_data(jnp.asarray(keys, dtype=jnp.uint32))


class VmapExecutor:
    """Run a JAX simulator in-process, vectorised with ``jax.vmap`` in chunks.

    Parameters
    ----------
    chunk_size : int, optional
        Largest number of tasks per compiled call (default 1024); bounds memory.  Calls are
        padded (with copies of their first task, discarded afterwards) to a power of two no
        larger than this, so varying batch sizes compile a handful of shapes, not one each.

    Notes
    -----
    A simulator object with a ``simulate_batch(keys, thetas)`` attribute (for engines that
    manage state outside ``jit``, such as jax-md neighbour-list re-allocation) is called through
    it instead of ``jax.vmap``; it returns the summaries, or ``(summaries, ok)`` with ``ok`` a
    boolean mask of members that ran cleanly.
    """

    name = "vmap"

    def __init__(self, chunk_size: int | None = None):
        if chunk_size is not None and chunk_size < 1:
            raise ValueError(f"chunk_size must be at least 1, got {chunk_size}")
        self.chunk_size = chunk_size
        self._compiled: dict[int, Callable] = {}

    def _batched(self, simulate: Callable) -> Callable:
        ident = id(simulate)
        if ident not in self._compiled:
            batch_fn = getattr(simulate, "simulate_batch", None)
            if batch_fn is not None:
                self._compiled[ident] = batch_fn
            else:
                self._compiled[ident] = jax.jit(jax.vmap(simulate))
        return self._compiled[ident]

    def map(self, simulate: Callable, keys: np.ndarray, thetas: np.ndarray) -> SimulationBatch:
        m = thetas.shape[0]
        if m == 0:
            raise ValueError("nothing to simulate: the batch is empty")
        fn = self._batched(simulate)
        if hasattr(simulate, "simulate_batch"):
            # A batch runner pads to its own compiled shape; hand it the tasks as they are.
            t0 = time.perf_counter()
            out = fn(_wrap_keys(keys), jnp.asarray(thetas))
            out, ok = out if isinstance(out, tuple) else (out, None)
            summaries = np.array(out)
            ok = np.ones(m, bool) if ok is None else np.asarray(ok, bool)
            summaries[~ok] = np.nan
            status = np.where(ok, STATUS_OK, STATUS_NONFINITE).astype(np.int32)
            reasons = ["" if o else "the engine flagged the run (overflow, box, or blown up)" for o in ok]
            times = np.full(m, (time.perf_counter() - t0) / m)
            return mark_nonfinite(SimulationBatch(summaries, status, reasons, times, np.zeros(m, np.int32)))
        # Pad every call to a power-of-two size (at most chunk_size) so that batches of varying
        # size (PMC refills, subset-simulation chains) reuse a handful of compiled shapes.
        cap = self.chunk_size or 1024
        size = min(cap, max(64, 1 << max(0, (m - 1).bit_length())))
        pieces, times = [], np.zeros(m)
        for start in range(0, m, size):
            stop = min(start + size, m)
            idx = np.arange(start, stop)
            pad = np.concatenate([idx, np.full(size - idx.size, start)])
            t0 = time.perf_counter()
            out = np.asarray(fn(_wrap_keys(keys[pad]), jnp.asarray(thetas[pad])))
            times[start:stop] = (time.perf_counter() - t0) / idx.size
            pieces.append(out[: idx.size])
        summaries = np.concatenate(pieces, axis=0)
        batch = SimulationBatch(summaries, np.zeros(m, np.int32), [""] * m, times, np.zeros(m, np.int32))
        return mark_nonfinite(batch)

    def close(self) -> None:
        self._compiled.clear()


def _run_one(simulate: Callable, key: np.ndarray, theta: np.ndarray) -> tuple[Any, int, str]:
    try:
        out = np.asarray(simulate(key, theta), dtype=np.float64)
        return out, STATUS_OK, ""
    except SimulationFailure as exc:
        return None, STATUS_FAILED, str(exc)
    except TimeoutError as exc:
        return None, STATUS_TIMEOUT, f"timeout: {exc}"
    except Exception as exc:
        last = traceback.format_exception_only(type(exc), exc)[-1].strip()
        return None, STATUS_FAILED, f"simulator raised {last}"


def _cpu_seconds() -> float:
    """CPU seconds used so far by this process and its waited-for children."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _timed_run(simulate: Callable, key: np.ndarray, theta: np.ndarray) -> tuple[Any, int, str, float, float]:
    """:func:`_run_one` plus its wall and CPU seconds (CPU: this process and the programs it ran)."""
    t0, c0 = time.perf_counter(), _cpu_seconds()
    out, status, reason = _run_one(simulate, key, theta)
    return out, status, reason, time.perf_counter() - t0, _cpu_seconds() - c0


def _assemble(outputs: list, status: np.ndarray, reasons: list[str], times: np.ndarray,
              workers: np.ndarray, cpu_times: np.ndarray | None = None) -> SimulationBatch:
    shapes = {o.shape for o in outputs if o is not None}
    if len(shapes) > 1:
        raise ValueError(
            f"the simulator returned summaries of different shapes {sorted(shapes)}: it must "
            "return the same shape for every parameter vector"
        )
    if not shapes:
        # Every task failed; the shape is unknown, so use one NaN per task and let the driver
        # report the failures.
        summaries = np.full((len(outputs), 1), np.nan)
    else:
        shape = shapes.pop()
        summaries = np.full((len(outputs), *shape), np.nan)
        for i, o in enumerate(outputs):
            if o is not None:
                summaries[i] = o
    return mark_nonfinite(SimulationBatch(summaries, status, reasons, times, workers, cpu_times))


class SerialExecutor:
    """Run tasks one after another in this process (host simulators, debugging).

    The simulator receives raw key data (``uint32[2]``) and a NumPy parameter vector, exactly
    as in a worker process, so a simulator that works here works in every executor.
    """

    name = "serial"

    def map(self, simulate: Callable, keys: np.ndarray, thetas: np.ndarray) -> SimulationBatch:
        m = thetas.shape[0]
        outputs, status, reasons = [], np.zeros(m, np.int32), [""] * m
        times, cpu = np.zeros(m), np.zeros(m)
        for i in range(m):
            out, status[i], reasons[i], times[i], cpu[i] = _timed_run(
                simulate, np.asarray(keys[i]), np.asarray(thetas[i]))
            outputs.append(out)
        return _assemble(outputs, status, reasons, times, np.zeros(m, np.int32), cpu)

    def close(self) -> None:
        pass


def _die_with_parent(poll_seconds: float = 1.0) -> None:
    """Kill this process group (this worker and the programs it started) once its parent is gone.

    Workers sit in process groups of their own (so a timeout can kill a task's programs too),
    which also shields them from the Ctrl-C or ``kill`` aimed at the driver: without this watch a
    killed driver would leave each worker finishing its current simulation, minutes of
    ``gmx mdrun`` with nobody to read the result.
    """
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_seconds)
        os.killpg(0, signal.SIGKILL)

    threading.Thread(target=watch, name="jaxabc-parent-watch", daemon=True).start()


def _isolate_worker_process() -> None:
    """Set up a process that runs host simulators for a driver (pool worker, MPI child)."""
    # Host simulators only; keep JAX (if the simulator imports it) off accelerators.
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    # Own process group: a timeout kills the worker and any program it started (mdrun, lmp).
    os.setpgrp()
    _die_with_parent()  # a lost driver must not leave its simulation running


def _worker_main(conn: Any, simulate: Callable) -> None:
    _isolate_worker_process()
    while True:
        try:
            item = conn.recv()
        except EOFError:
            return
        if item is None:
            return
        index, key, theta = item
        # Acknowledge: the parent's timeout clock starts now, not while this worker was being
        # spawned and importing JAX (which on a loaded machine can take longer than a task).
        conn.send(("started", index))
        conn.send((index, *_timed_run(simulate, key, theta)))


class _Worker:
    def __init__(self, ctx: Any, wid: int, simulate: Callable):
        self.wid = wid
        self.conn, child = ctx.Pipe(duplex=True)
        self.proc = ctx.Process(target=_worker_main, args=(child, simulate), daemon=True)
        self.proc.start()
        child.close()
        self.task: int | None = None
        self.started: float | None = None  # set when the worker acknowledges its task

    def kill(self) -> None:
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            self.proc.kill()
        self.proc.join(timeout=5)
        self.conn.close()


class ProcessPoolExecutor:
    """Local worker processes with dynamic allocation (a free worker gets the next task).

    Parameters
    ----------
    max_workers : int, optional
        Number of worker processes (default: the number of cores).
    timeout : float, optional
        Seconds one task may run.  A task past it has its worker's process group killed (so an
        external program started by the simulator stops too) and gets ``STATUS_TIMEOUT``; a
        fresh worker takes the worker's place.
    start_method : str
        ``"spawn"`` (default) or ``"forkserver"``; never ``"fork"``, which is unsafe once JAX
        threads exist in the parent.
    order : {"fifo", "longest_first"} or CostModel, optional
        Which task a free worker gets next.  ``"fifo"`` (default): task order.
        ``"longest_first"``: the longest *predicted* first, from the costs
        (:func:`task_durations`: CPU time, or wall time for tasks that wait) of the tasks this
        executor already ran (:mod:`jaxabc.scheduling`); it shortens a batch's makespan when
        durations vary with the parameters and never changes a result.

    Notes
    -----
    Each worker talks to the parent over its own pipe, and the parent watches the workers'
    process sentinels: a worker that dies (segfault, ``os._exit``, out-of-memory kill) is seen
    at once, its task is recorded as ``STATUS_WORKER_DIED``, and a new worker is started.  The
    simulator must be picklable (a module-level function or an instance of a module-level
    class).  Workers are started on the first :meth:`map` and reused until :meth:`close`.
    """

    name = "process_pool"

    def __init__(self, max_workers: int | None = None, timeout: float | None = None,
                 start_method: str = "spawn", order: str | CostModel | None = None):
        if max_workers is not None and max_workers < 1:
            raise ValueError(f"max_workers must be at least 1, got {max_workers}")
        if timeout is not None and timeout <= 0:
            raise ValueError(f"timeout must be positive, got {timeout}")
        if start_method not in ("spawn", "forkserver"):
            raise ValueError("start_method must be 'spawn' or 'forkserver' (fork is unsafe with JAX)")
        self.max_workers = max_workers or os.cpu_count() or 1
        self.timeout = timeout
        self._ctx = mp.get_context(start_method)
        self.cost_model = get_cost_model(order)
        self._workers: list[_Worker] = []
        self._simulate: Callable | None = None
        self._next_id = 0

    def _spawn(self) -> _Worker:
        worker = _Worker(self._ctx, self._next_id, self._simulate)
        self._next_id += 1
        self._workers.append(worker)
        return worker

    def _start(self, simulate: Callable) -> None:
        if self._simulate is simulate and self._workers:
            return
        self.close()
        self._simulate = simulate
        for _ in range(self.max_workers):
            self._spawn()

    def map(self, simulate: Callable, keys: np.ndarray, thetas: np.ndarray) -> SimulationBatch:
        from multiprocessing.connection import wait

        self._start(simulate)
        m = thetas.shape[0]
        outputs: list = [None] * m
        status = np.full(m, -1, np.int32)
        reasons, times, workers = [""] * m, np.zeros(m), np.full(m, -1, np.int32)
        cpu = np.full(m, np.nan)
        pending = dispatch_order(self.cost_model, thetas).tolist()[::-1]
        done = 0

        def give(worker: _Worker) -> None:
            if pending:
                i = pending.pop()
                worker.task, worker.started = i, None
                worker.conn.send((i, np.asarray(keys[i]), np.asarray(thetas[i])))

        for worker in self._workers:
            give(worker)
        while done < m:
            busy = [w for w in self._workers if w.task is not None]
            ready = wait([w.conn for w in busy] + [w.proc.sentinel for w in busy], timeout=0.5)
            now = time.time()
            for worker in list(busy):
                failure = None
                if worker.conn in ready:
                    try:
                        message = worker.conn.recv()
                    except (EOFError, OSError):
                        failure = STATUS_WORKER_DIED
                    else:
                        if message[0] == "started":
                            worker.started = time.time()
                            continue
                        i, out, st, reason, dt, cpu[i] = message
                        outputs[i], status[i], reasons[i] = out, st, reason
                        times[i], workers[i] = dt, worker.wid
                        worker.task = None
                        done += 1
                        give(worker)
                        continue
                elif worker.proc.sentinel in ready or not worker.proc.is_alive():
                    failure = STATUS_WORKER_DIED
                elif (self.timeout is not None and worker.started is not None
                      and now - worker.started > self.timeout):
                    failure = STATUS_TIMEOUT
                if failure is None:
                    continue
                i = worker.task
                worker.kill()
                self._workers.remove(worker)
                status[i], workers[i] = failure, worker.wid
                times[i] = now - worker.started if worker.started is not None else 0.0
                reasons[i] = (
                    f"timeout: ran longer than {self.timeout} s and was stopped"
                    if failure == STATUS_TIMEOUT
                    else f"worker process died (exit code {worker.proc.exitcode}) while running it"
                )
                done += 1
                give(self._spawn())
        batch = _assemble(outputs, status, reasons, times, workers, cpu)
        if self.cost_model is not None:
            self.cost_model.observe(thetas, task_durations(batch.wall_time, batch.cpu_time))
        return batch

    def close(self) -> None:
        for worker in self._workers:
            try:
                worker.conn.send(None)
            except (OSError, ValueError, BrokenPipeError):
                pass
        for worker in self._workers:
            worker.proc.join(timeout=2)
            if worker.proc.is_alive():
                worker.kill()
            else:
                worker.conn.close()
        self._workers.clear()
        self._simulate = None

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass


def get_executor(executor: str | Executor | None, **options: Any) -> Executor:
    """Resolve ``"vmap"``, ``"serial"``, ``"process_pool"``, ``"mpi"``, ``"mpi_static"`` or an
    executor object (returned as is)."""
    if executor is None or executor == "vmap":
        return VmapExecutor(**options)
    if isinstance(executor, str):
        if executor == "serial":
            return SerialExecutor()
        if executor == "process_pool":
            return ProcessPoolExecutor(**options)
        if executor in ("mpi", "mpi_static"):
            from jaxabc import mpi

            return mpi.MPIExecutor(allocation="dynamic" if executor == "mpi" else "static", **options)
        raise ValueError(
            f"unknown executor {executor!r}: use 'vmap' (JAX simulators), 'serial', "
            "'process_pool' (external programs), 'mpi' or 'mpi_static', or pass an executor object"
        )
    return executor
