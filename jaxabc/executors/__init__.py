"""Where a batch of simulations runs: one interface for every backend.

An executor maps a simulator over parameter vectors::

    batch = executor.map(simulate, keys, thetas)

``keys`` has one PRNG key per task (raw ``uint32`` key data, shape (m, 2)), ``thetas`` has shape
(m, d).  The result, :class:`SimulationBatch`, holds the summaries (NaN where a task failed),
a status code and a reason per task, its wall and CPU time and the worker that ran it.  Task ``i``
always gets key ``i``, so the same seed gives the same result on every executor.

Implementations
---------------
:class:`VmapExecutor` (:mod:`~jaxabc.executors.vmap`)
    In-process, ``jax.jit(jax.vmap(simulate))`` in memory-bounded chunks, for JAX simulators.
:class:`SerialExecutor` (:mod:`~jaxabc.executors.local`)
    In-process, one task after another, for host (non-JAX) simulators and debugging.
:class:`ProcessPoolExecutor` (:mod:`~jaxabc.executors.local`)
    Local worker processes with dynamic allocation: a free worker pulls the next single task.
    A task that raises, runs past the timeout or kills its worker becomes a failure record.
:class:`MPIExecutor` (:mod:`~jaxabc.executors.mpi`)
    MPI worker ranks, dynamic pull queue or static chunks.
:class:`DaskExecutor` (:mod:`~jaxabc.executors.dask`)
    The workers of a ``dask.distributed`` cluster (local, or SLURM/PBS through dask-jobqueue).

The pool, MPI and Dask isolate the simulator in child processes through one module,
:mod:`~jaxabc.executors.workers`.
"""

from __future__ import annotations

from typing import Any

from jaxabc.executors.base import Executor, SimulationBatch, mark_nonfinite, task_durations
from jaxabc.executors.dask import DaskExecutor
from jaxabc.executors.local import ProcessPoolExecutor, SerialExecutor
from jaxabc.executors.mpi import MPIExecutor
from jaxabc.executors.vmap import VmapExecutor

__all__ = [
    "EXECUTOR_NAMES",
    "DaskExecutor",
    "Executor",
    "MPIExecutor",
    "ProcessPoolExecutor",
    "SerialExecutor",
    "SimulationBatch",
    "VmapExecutor",
    "get_executor",
    "mark_nonfinite",
    "task_durations",
]

#: The names :func:`get_executor` (and :func:`jaxabc.run`'s ``executor=``) accept.
EXECUTOR_NAMES = ("vmap", "serial", "process_pool", "mpi", "mpi_static", "dask")


def get_executor(executor: str | Executor | None, **options: Any) -> Executor:
    """Resolve an executor name (:data:`EXECUTOR_NAMES`) or object (returned as is).

    ``options`` go to the executor's constructor; ``None`` means ``"vmap"``.

    Raises
    ------
    ValueError
        For an unknown name.
    """
    if executor is None or executor == "vmap":
        return VmapExecutor(**options)
    if isinstance(executor, str):
        if executor == "serial":
            return SerialExecutor(**options)
        if executor == "process_pool":
            return ProcessPoolExecutor(**options)
        if executor in ("mpi", "mpi_static"):
            return MPIExecutor(allocation="dynamic" if executor == "mpi" else "static", **options)
        if executor == "dask":
            return DaskExecutor(**options)
        raise ValueError(
            f"unknown executor {executor!r}: use 'vmap' (JAX simulators), 'serial', "
            "'process_pool' (external programs), 'mpi', 'mpi_static' or 'dask', or pass an executor "
            "object"
        )
    return executor
