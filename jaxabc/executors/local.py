"""Host simulators on this machine: one task after another, or a pool of worker processes."""

from __future__ import annotations

import multiprocessing as mp
import os
import time
from collections.abc import Callable
from multiprocessing.connection import wait

import numpy as np

from jaxabc.errors import STATUS_OK, STATUS_TIMEOUT, STATUS_WORKER_DIED
from jaxabc.executors.base import SimulationBatch, assemble_batch, task_durations
from jaxabc.executors.scheduling import CostModel, dispatch_order, get_cost_model
from jaxabc.executors.workers import GUARD_HINT, WorkerProcess, pickle_simulator, timed_run

__all__ = ["ProcessPoolExecutor", "SerialExecutor"]


def _learn_shape(known: tuple[int, ...] | None, batch: SimulationBatch) -> tuple[int, ...] | None:
    """The summary shape to remember after ``batch``: its own if any task succeeded."""
    if np.any(batch.status == STATUS_OK):
        return tuple(batch.summaries.shape[1:])
    return known


class SerialExecutor:
    """Run tasks one after another in this process (host simulators, debugging).

    The simulator receives raw key data (``uint32[2]``) and a NumPy parameter vector, exactly
    as in a worker process, so a simulator that works here works in every executor.

    Parameters
    ----------
    summary_shape : tuple of int, optional
        Shape of one task's summaries, for a batch in which every task fails; learnt from the
        first successful task when not given.
    """

    name = "serial"

    def __init__(self, summary_shape: tuple[int, ...] | None = None):
        self.summary_shape = None if summary_shape is None else tuple(summary_shape)

    def map(self, simulate: Callable, keys: np.ndarray, thetas: np.ndarray) -> SimulationBatch:
        m = thetas.shape[0]
        outputs, status, reasons = [], np.zeros(m, np.int32), [""] * m
        times, cpu = np.zeros(m), np.zeros(m)
        for i in range(m):
            out, status[i], reasons[i], times[i], cpu[i] = timed_run(
                simulate, np.asarray(keys[i]), np.asarray(thetas[i])
            )
            outputs.append(out)
        batch = assemble_batch(outputs, status, reasons, times, np.zeros(m, np.int32), cpu, self.summary_shape)
        self.summary_shape = _learn_shape(self.summary_shape, batch)
        return batch

    def close(self) -> None:
        pass


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
        (:func:`~jaxabc.executors.task_durations`) of the tasks this executor already ran
        (:mod:`jaxabc.executors.scheduling`); it never changes a result.
    summary_shape : tuple of int, optional
        Shape of one task's summaries, for a batch in which every task fails; learnt from the
        first successful task when not given.
    max_tasks_per_worker : int, optional
        Replace a worker process with a fresh one after it has run this many tasks (default:
        never), for simulators that leak memory, file handles or threads.  Results do not
        change: a task's key belongs to the task, not to the worker.  Each replacement pays a
        worker's start-up (a Python interpreter and the simulator's imports), so keep it well
        above 1 unless a task takes much longer than that.

    Raises
    ------
    RuntimeError
        From :meth:`map`, when the workers exit before they are ready: most often a script
        that starts the pool without an ``if __name__ == "__main__":`` guard.
    TypeError
        From :meth:`map`, when the simulator cannot be pickled.

    Notes
    -----
    Each worker (:class:`jaxabc.executors.workers.WorkerProcess`) talks to the parent over its
    own pipe, and the parent watches the workers' process sentinels: a worker that dies
    (segfault, ``os._exit``, out-of-memory kill) is seen at once, its task is recorded as
    ``STATUS_WORKER_DIED``, and a new worker is started.  The simulator must be picklable (a
    module-level function or an instance of a module-level class).  Workers are started on the
    first :meth:`map` and reused until :meth:`close`.
    """

    name = "process_pool"

    def __init__(
        self,
        max_workers: int | None = None,
        timeout: float | None = None,
        start_method: str = "spawn",
        order: str | CostModel | None = None,
        summary_shape: tuple[int, ...] | None = None,
        max_tasks_per_worker: int | None = None,
    ):
        if max_workers is not None and max_workers < 1:
            raise ValueError(f"max_workers must be at least 1, got {max_workers}")
        if max_tasks_per_worker is not None and (
            isinstance(max_tasks_per_worker, bool)
            or not isinstance(max_tasks_per_worker, int | np.integer)
            or max_tasks_per_worker < 1
        ):
            raise ValueError(f"max_tasks_per_worker must be a positive integer or None, got {max_tasks_per_worker!r}")
        if timeout is not None and timeout <= 0:
            raise ValueError(f"timeout must be positive, got {timeout}")
        if start_method not in ("spawn", "forkserver"):
            raise ValueError("start_method must be 'spawn' or 'forkserver' (fork is unsafe with JAX)")
        self.max_workers = max_workers or os.cpu_count() or 1
        self.timeout = timeout
        self.start_method = start_method
        self.cost_model = get_cost_model(order)
        self.summary_shape = None if summary_shape is None else tuple(summary_shape)
        self.max_tasks_per_worker = None if max_tasks_per_worker is None else int(max_tasks_per_worker)
        self._workers: list[WorkerProcess] = []
        self._tasks_run: dict[int, int] = {}  # worker id -> tasks it finished
        self._retired: list[WorkerProcess] = []  # asked to exit (max_tasks_per_worker)
        self._simulate: Callable | None = None
        self._payload: bytes | None = None
        self._next_id = 0
        self._any_ready = False

    def _spawn(self) -> WorkerProcess:
        worker = WorkerProcess(self._next_id, self.start_method)
        self._next_id += 1
        assert self._payload is not None, "_start loads the simulator before spawning"
        worker.send_load(self._payload)
        self._workers.append(worker)
        return worker

    def _start(self, simulate: Callable) -> None:
        if getattr(mp.current_process(), "_inheriting", False):
            # This process is a worker being spawned, importing an unguarded main script.
            raise RuntimeError(f"a process pool was started while a worker imported the main module; {GUARD_HINT}")
        if self._simulate is not simulate:
            self._payload = pickle_simulator(simulate)
            self._simulate = simulate
            for worker in self._workers:  # reuse the processes; they load the new simulator
                worker.send_load(self._payload)
        self._reap()
        while len(self._workers) < self.max_workers:
            self._spawn()

    def map(self, simulate: Callable, keys: np.ndarray, thetas: np.ndarray) -> SimulationBatch:
        self._start(simulate)
        m = thetas.shape[0]
        outputs: list = [None] * m
        status = np.full(m, -1, np.int32)
        reasons, times, workers = [""] * m, np.zeros(m), np.full(m, -1, np.int32)
        cpu = np.full(m, np.nan)
        pending = dispatch_order(self.cost_model, thetas).tolist()[::-1]
        done = 0

        def give(worker: WorkerProcess) -> None:
            if pending:
                i = pending.pop()
                worker.send_task(i, np.asarray(keys[i]), np.asarray(thetas[i]))

        for worker in self._workers:
            give(worker)
        while done < m:
            busy = [w for w in self._workers if w.task is not None]
            ready = wait([w.conn for w in busy] + [w.proc.sentinel for w in busy], timeout=0.5)
            now = time.time()
            for worker in busy:
                failure = None
                if worker.conn in ready:
                    try:
                        message = worker.conn.recv()
                    except (EOFError, OSError):
                        failure = STATUS_WORKER_DIED
                    else:
                        finished = worker.handle(message)
                        self._any_ready |= worker.ready
                        if finished is None:
                            continue
                        _, i, outputs[i], status[i], reasons[i], times[i], cpu[i] = finished
                        workers[i] = worker.wid
                        done += 1
                        if self._worn_out(worker):
                            # Retire it; a fresh process takes the next task (if any is left;
                            # otherwise the next map() tops the pool up).
                            self._retire(worker)
                            if pending:
                                give(self._spawn())
                        else:
                            give(worker)
                        continue
                elif worker.proc.sentinel in ready or not worker.proc.is_alive():
                    failure = STATUS_WORKER_DIED
                elif self.timeout is not None and worker.started is not None and now - worker.started > self.timeout:
                    failure = STATUS_TIMEOUT
                if failure is None:
                    continue
                i = worker.task
                worker.kill()
                self._workers.remove(worker)
                self._tasks_run.pop(worker.wid, None)
                if failure == STATUS_WORKER_DIED and not worker.ready and not self._any_ready:
                    # No worker ever started: a set-up error, not a failure of this task.
                    reason = worker.death_reason("starting")
                    self.close()
                    raise RuntimeError(f"the process pool could not start its workers: {reason}")
                status[i], workers[i] = failure, worker.wid
                times[i] = now - worker.started if worker.started is not None else 0.0
                if failure == STATUS_TIMEOUT:
                    reasons[i] = f"timeout: ran longer than {self.timeout} s and was stopped"
                elif worker.ready:
                    reasons[i] = worker.death_reason("running it")
                else:
                    reasons[i] = f"worker process died (exit code {worker.proc.exitcode}) while starting"
                done += 1
                give(self._spawn())
        batch = assemble_batch(outputs, status, reasons, times, workers, cpu, self.summary_shape)
        self.summary_shape = _learn_shape(self.summary_shape, batch)
        if self.cost_model is not None:
            self.cost_model.observe(thetas, task_durations(batch.wall_time, batch.cpu_time))
        return batch

    def _worn_out(self, worker: WorkerProcess) -> bool:
        """Count a finished task; whether the worker has now run ``max_tasks_per_worker``."""
        self._tasks_run[worker.wid] = self._tasks_run.get(worker.wid, 0) + 1
        limit = self.max_tasks_per_worker
        return limit is not None and self._tasks_run[worker.wid] >= limit

    def _retire(self, worker: WorkerProcess) -> None:
        """Ask an idle worker to exit, without waiting for it: the pool goes on meanwhile."""
        self._workers.remove(worker)
        self._tasks_run.pop(worker.wid, None)
        try:
            worker.conn.send(None)
        except (OSError, ValueError):
            pass
        self._retired.append(worker)

    def _reap(self) -> None:
        """Close the retired workers that have exited (``stop`` kills the rest at close)."""
        for worker in [w for w in self._retired if not w.proc.is_alive()]:
            worker.stop(wait_seconds=0.0)
            self._retired.remove(worker)

    def close(self) -> None:
        # Ask every worker first, then wait: they shut down in parallel.
        for worker in self._workers:
            try:
                worker.conn.send(None)
            except (OSError, ValueError):
                pass
        for worker in self._workers + self._retired:
            worker.stop()
        self._workers.clear()
        self._retired.clear()
        self._tasks_run.clear()
        self._simulate = self._payload = None

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
