"""Running one task, and a child process that runs tasks in isolation (process pool and MPI).

A :class:`WorkerProcess` is a ``spawn``-ed child in a process group of its own that loads a
pickled simulator and runs tasks sent over a pipe.  A simulator that crashes it (segfault,
``os._exit``, out-of-memory kill) costs its task only, and a task past its timeout is stopped by
killing the group (so the programs it started, ``gmx mdrun`` or ``lmp``, stop too).  The process
pool drives many of them at once without blocking (:meth:`WorkerProcess.send_task`); an MPI worker
rank or a Dask worker thread drives one, blocking, through a :class:`TaskRunner`.

Messages, parent to child: ``("load", payload)``, ``("run", index, key, theta)``, ``None`` (exit).
Child to parent: ``("ready", pid)`` once at start, ``("loaded", None)`` or ``("error", reason)``
per load, ``("started", index)`` and ``("done", index, out, status, reason, wall_s, cpu_s)`` per task.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import resource
import signal
import threading
import time
import traceback
from collections.abc import Callable
from multiprocessing.connection import wait
from typing import Any

import numpy as np

from jaxabc.errors import STATUS_FAILED, STATUS_OK, STATUS_TIMEOUT, STATUS_WORKER_DIED, SimulationFailure

__all__ = [
    "COMPLEX_SUMMARIES",
    "GUARD_HINT",
    "STARTUP_LIMIT",
    "TaskRunner",
    "WorkerProcess",
    "complex_summaries_message",
    "pickle_simulator",
    "run_one",
    "timed_run",
]

#: Seconds a worker may take to start (interpreter, imports) or to load a simulator before the
#: blocking :meth:`WorkerProcess.load` gives up; a task's own timeout starts only after that.
STARTUP_LIMIT = 300.0

#: The usual cause of a worker that exits before it is ready.
GUARD_HINT = (
    "the script that started the pool must guard its top level with if __name__ == '__main__': "
    "spawned workers import the main module, and an unguarded script starts a new pool in each worker"
)


#: How a task's reason starts when its simulator returned complex summaries; the parent's
#: :func:`jaxabc.executors.base.assemble_batch` turns it into a ``TypeError`` for the run.
COMPLEX_SUMMARIES = "the simulator returned complex summaries"


def complex_summaries_message(dtype: Any) -> str:
    """Why complex summaries are refused, and what to return instead."""
    return (
        f"{COMPLEX_SUMMARIES} (dtype {np.dtype(dtype).name}): distances compare real numbers, and "
        "casting would drop the imaginary part silently; return real summaries, e.g. both parts "
        "side by side (jnp.concatenate([z.real, z.imag])) or the modulus (jnp.abs(z)), and "
        "observed data to match"
    )


def run_one(simulate: Callable, key: np.ndarray, theta: np.ndarray) -> tuple[Any, int, str]:
    """``(summaries or None, status, reason)`` of one task; never raises.

    Complex summaries fail the task with a reason starting :data:`COMPLEX_SUMMARIES` (a cast to
    float64 would keep only the real part); the executor refuses the batch for them.
    """
    try:
        value = simulate(key, theta)
        raw = np.asarray(value)
        if raw.dtype == object:
            # np.asarray(None, float) is NaN: say what came back instead of a silent failure.
            return (
                None,
                STATUS_FAILED,
                (
                    f"the simulator returned {type(value).__name__}, not an array of numbers: "
                    "simulate(key, theta) must return the summaries"
                ),
            )
        if np.iscomplexobj(raw):
            return None, STATUS_FAILED, complex_summaries_message(raw.dtype)
        out = np.asarray(raw, dtype=np.float64)
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


def timed_run(simulate: Callable, key: np.ndarray, theta: np.ndarray) -> tuple[Any, int, str, float, float]:
    """:func:`run_one` plus its wall and CPU seconds (CPU: this process and the programs it ran)."""
    t0, c0 = time.perf_counter(), _cpu_seconds()
    out, status, reason = run_one(simulate, key, theta)
    return out, status, reason, time.perf_counter() - t0, _cpu_seconds() - c0


def pickle_simulator(simulate: Callable) -> bytes:
    """The simulator as bytes for a worker; ``TypeError`` saying what to do if it cannot be pickled."""
    try:
        return pickle.dumps(simulate, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception as exc:
        raise TypeError(
            f"the simulator cannot be pickled for the worker processes ({exc}); make it a "
            "module-level function or an instance of a module-level class"
        ) from exc


def _die_with_parent(poll_seconds: float = 1.0) -> None:
    """Kill this process group (this worker and the programs it started) once its parent is gone.

    Workers sit in process groups of their own, which also shields them from the Ctrl-C or
    ``kill`` aimed at the driver: without this watch a killed driver would leave each worker
    finishing its current simulation with nobody to read the result.
    """
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_seconds)
        os.killpg(0, signal.SIGKILL)

    threading.Thread(target=watch, name="jaxabc-parent-watch", daemon=True).start()


def _isolate() -> None:
    # Host simulators only; keep JAX off accelerators unless the user chose a platform.  The
    # variable is for programs the worker starts: this process imported jax (reading it) already.
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    import jax

    jax.config.update("jax_platforms", os.environ["JAX_PLATFORMS"])
    # Own process group: a timeout kills the worker and any program it started (mdrun, lmp).
    os.setpgrp()
    _die_with_parent()


def _worker_main(conn: Any) -> None:
    """Body of a worker process: load simulators and run tasks until told to stop."""
    try:
        _serve(conn)
    except (BrokenPipeError, ConnectionResetError):
        return  # the parent is gone (killed, or shut down): nobody to answer


def _serve(conn: Any) -> None:
    _isolate()
    # Host simulators derive their seeds with seed_from_key: compile it while the worker starts,
    # so that the first task's timeout does not pay for it (seconds on a loaded machine).
    from jaxabc.seeding import seed_from_key

    seed_from_key(np.zeros(2, np.uint32))
    conn.send(("ready", os.getpid()))
    simulate: Callable | None = None
    load_error = "no simulator was sent"
    while True:
        try:
            item = conn.recv()
        except EOFError:
            return
        if item is None:
            return
        if item[0] == "load":
            try:
                simulate, load_error = pickle.loads(item[1]), ""
                conn.send(("loaded", None))
            except Exception as exc:
                simulate = None
                load_error = traceback.format_exception_only(type(exc), exc)[-1].strip()
                conn.send(("error", load_error))
            continue
        _, index, key, theta = item
        # Acknowledge: the parent's timeout clock starts now, not while this worker was being
        # spawned and importing JAX (which on a loaded machine can take longer than a task).
        conn.send(("started", index))
        if simulate is None:
            result = (None, STATUS_FAILED, f"the worker could not load the simulator: {load_error}", 0.0, 0.0)
        else:
            result = timed_run(simulate, key, theta)
        conn.send(("done", index, *result))


class WorkerProcess:
    """A spawned child process that runs a simulator's tasks in isolation.

    Parameters
    ----------
    wid : int
        An identifier for the caller's records.
    start_method : {"spawn", "forkserver"}
        Never ``"fork"``, which is unsafe once JAX threads exist in the parent.

    Attributes
    ----------
    ready : bool
        The child has reported that it started (set by :meth:`handle` or :meth:`load`).
    task, started : int or None, float or None
        The task it runs and when it acknowledged it (``time.time()``), for a non-blocking caller.
    """

    def __init__(self, wid: int = 0, start_method: str = "spawn"):
        ctx = mp.get_context(start_method)
        self.wid = wid
        self.conn, child = ctx.Pipe(duplex=True)
        # typeshed declares Process on each concrete context, not on BaseContext.
        self.proc = ctx.Process(  # pyright: ignore[reportAttributeAccessIssue]
            target=_worker_main, args=(child,), daemon=True
        )
        self.proc.start()
        child.close()
        self.ready = False
        self.payload: bytes | None = None
        self.task: int | None = None
        self.started: float | None = None

    def death_reason(self, doing: str) -> str:
        """Why the process is gone, for a task's record (call once it has exited)."""
        code = self.proc.exitcode
        if not self.ready:
            return f"the worker process exited (exit code {code}) before it was ready; {GUARD_HINT}"
        return f"worker process died (exit code {code}) while {doing}"

    # -- non-blocking use (the process pool) ---------------------------------------------------

    def send_load(self, payload: bytes) -> None:
        """Queue a simulator (the child loads it before the next task); no-op if already sent."""
        if payload != self.payload:
            self.conn.send(("load", payload))
            self.payload = payload

    def send_task(self, index: int, key: np.ndarray, theta: np.ndarray) -> None:
        self.task, self.started = index, None
        self.conn.send(("run", index, key, theta))

    def handle(self, message: tuple) -> tuple | None:
        """Book-keep a message from the child; returns it if it is a task's ``"done"``."""
        kind = message[0]
        if kind == "ready":
            self.ready = True
        elif kind == "started":
            self.started = time.time()
        elif kind == "done":
            self.task = None
            return message
        return None

    # -- blocking use (one per MPI worker rank) --------------------------------------------------

    def _reply(self, what: str) -> tuple:
        t0 = time.perf_counter()
        while True:
            while not self.conn.poll(0.2):
                if time.perf_counter() - t0 > STARTUP_LIMIT:
                    self.kill()
                    raise RuntimeError(f"the simulator's process did not {what} within {STARTUP_LIMIT} s")
                if not self.proc.is_alive():
                    self.proc.join(timeout=1)
                    raise RuntimeError(f"{self.death_reason('it was to ' + what)}")
            message = self.conn.recv()
            if message[0] != "ready":
                return message
            self.ready = True

    def load(self, payload: bytes) -> None:
        """Wait until the child is ready and has loaded ``payload``; ``RuntimeError`` otherwise."""
        if payload == self.payload:
            return
        self.payload = None
        self.conn.send(("load", payload))
        kind, info = self._reply("load the simulator")
        if kind == "error":
            raise RuntimeError(f"could not load the simulator: {info}")
        self.payload = payload

    def run(
        self, key: np.ndarray, theta: np.ndarray, timeout: float | None
    ) -> tuple[Any, int, str, float, float, bool]:
        """Run one task after :meth:`load`.

        Returns ``(summaries or None, status, reason, seconds, cpu_seconds, alive)``; CPU seconds
        are NaN and ``alive`` is false when the child was killed (timeout) or died.
        """
        t0 = time.perf_counter()
        self.conn.send(("run", 0, key, theta))
        ready = wait([self.conn, self.proc.sentinel], timeout=timeout)
        if self.conn in ready:
            try:
                message = self.conn.recv()
                if message[0] == "started":  # the task runs now: its timeout starts
                    t0 = time.perf_counter()
                    ready = wait([self.conn, self.proc.sentinel], timeout=timeout)
                    message = self.conn.recv() if self.conn in ready else None
                if message is not None:
                    _, _, out, status, reason, seconds, cpu = message
                    return out, status, reason, seconds, cpu, True
            except (EOFError, OSError):
                ready = [self.proc.sentinel]
        seconds = time.perf_counter() - t0
        self.kill()
        if not ready:
            return (
                None,
                STATUS_TIMEOUT,
                f"timeout: ran longer than {timeout} s and was stopped",
                seconds,
                np.nan,
                False,
            )
        return None, STATUS_WORKER_DIED, self.death_reason("running it"), seconds, np.nan, False

    # -- either ----------------------------------------------------------------------------------

    def kill(self) -> None:
        """Kill the child's process group (the child and the programs it started)."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            self.proc.kill()
        self.proc.join(timeout=5)
        self.conn.close()

    def stop(self, wait_seconds: float = 2.0) -> None:
        """Ask the child to exit; kill it if it does not within ``wait_seconds``."""
        try:
            self.conn.send(None)
        except (OSError, ValueError):
            pass
        self.proc.join(timeout=wait_seconds)
        if self.proc.is_alive():
            self.kill()
        else:
            self.conn.close()


class TaskRunner:
    """Runs the tasks of a remote worker (an MPI rank, a Dask worker thread) one at a time.

    Parameters
    ----------
    isolate : bool
        Run the simulator in a :class:`WorkerProcess` (started once, reused, replaced after a
        crash or a timeout), so that a crash costs one task; ``False`` runs it in this process.
    wid : int
        Identifier given to the child process.

    Notes
    -----
    The simulator arrives as the pickled payload of every task and is unpickled only when it
    changes, so an object simulator (a GROMACS plugin instance) stays one object across tasks.
    """

    def __init__(self, isolate: bool, wid: int = 0):
        self.isolate = isolate
        self.wid = wid
        self.payload: bytes | None = None
        self.simulate: Callable | None = None
        self.child: WorkerProcess | None = None

    def run(
        self, payload: bytes, key: np.ndarray, theta: np.ndarray, timeout: float | None
    ) -> tuple[Any, int, str, float, float]:
        """``(summaries or None, status, reason, seconds, cpu_seconds)`` of one task.

        Raises
        ------
        RuntimeError
            When the simulator cannot be loaded or its process cannot start (the caller fails
            the task with the message).
        """
        if not self.isolate:
            if payload != self.payload:
                self.payload, self.simulate = None, pickle.loads(payload)
                self.payload = payload
            assert self.simulate is not None  # loaded with the payload
            return timed_run(self.simulate, key, theta)
        if self.child is None:
            self.child = WorkerProcess(self.wid)
        try:
            self.child.load(payload)
        except RuntimeError:
            if not self.child.proc.is_alive():  # died or overran the start-up limit; a simulator
                self.child = None  # that does not unpickle leaves a healthy child
            raise
        out, status, reason, seconds, cpu, alive = self.child.run(key, theta, timeout)
        if not alive:
            # Start the replacement now, so that its start-up overlaps the driver's bookkeeping.
            self.child = WorkerProcess(self.wid)
        return out, status, reason, seconds, cpu
