"""The executor interface: what a batch of simulations returns, and helpers every backend shares.

An executor maps a simulator over parameter vectors::

    batch = executor.map(simulate, keys, thetas)

``keys`` has one PRNG key per task (raw ``uint32`` key data, shape (m, 2)), ``thetas`` has shape
(m, d).  Task ``i`` always gets key ``i``, so the summaries do not depend on which worker ran which
task, or in which order: the same seed gives the same result on every executor.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.errors import STATUS_NONFINITE, STATUS_OK
from jaxabc.executors.workers import COMPLEX_SUMMARIES

__all__ = [
    "Executor",
    "SimulationBatch",
    "assemble_batch",
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
        time it does not grow when other work shares the cores.
    """

    summaries: np.ndarray
    status: np.ndarray
    reasons: list[str]
    wall_time: np.ndarray
    worker: np.ndarray
    cpu_time: np.ndarray | None = None


class Executor(Protocol):
    """What the driver needs from an executor.

    ``summary_shape`` (optional attribute): the shape of one task's summaries, used for the NaN
    rows of a batch in which every task failed.  Host executors learn it from their first
    successful task; the driver may set it from the observed data beforehand.
    """

    name: str

    def map(self, simulate: Callable, keys: np.ndarray, thetas: np.ndarray) -> SimulationBatch: ...

    def close(self) -> None: ...


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


def wrap_keys(keys: np.ndarray) -> jax.Array:
    """Typed PRNG keys from raw ``uint32`` key data of shape (m, 2)."""
    return jax.random.wrap_key_data(jnp.asarray(keys, dtype=jnp.uint32))


def assemble_batch(
    outputs: list[Any],
    status: np.ndarray,
    reasons: list[str],
    times: np.ndarray,
    workers: np.ndarray,
    cpu_times: np.ndarray | None = None,
    summary_shape: tuple[int, ...] | None = None,
) -> SimulationBatch:
    """A :class:`SimulationBatch` from per-task outputs (arrays, or ``None`` where a task failed).

    Parameters
    ----------
    summary_shape : tuple of int, optional
        Shape of one task's summaries, used only when every task failed (no output shows it);
        without it such a batch has summaries of shape (m, 1).

    Raises
    ------
    ValueError
        If successful tasks returned summaries of different shapes.
    TypeError
        If the simulator returned complex summaries (a task's reason says so, see
        :func:`jaxabc.executors.workers.run_one`): a mistake in the simulator, not a failed
        simulation, so the run stops instead of recording every task as failed.
    """
    for reason in reasons:
        if reason.startswith(COMPLEX_SUMMARIES):
            raise TypeError(reason)
    shapes = {o.shape for o in outputs if o is not None}
    if len(shapes) > 1:
        raise ValueError(
            f"the simulator returned summaries of different shapes {sorted(shapes)}: it must "
            "return the same shape for every parameter vector"
        )
    if shapes:
        shape = shapes.pop()
    else:
        # Every task failed: no output shows the shape, so use the known one if there is one.
        shape = (1,) if summary_shape is None else tuple(summary_shape)
    summaries = np.full((len(outputs), *shape), np.nan)
    for i, o in enumerate(outputs):
        if o is not None:
            summaries[i] = o
    return mark_nonfinite(SimulationBatch(summaries, status, reasons, times, workers, cpu_times))
