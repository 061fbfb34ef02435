"""In-process execution of a JAX simulator, vectorised with ``jax.vmap`` in chunks."""

from __future__ import annotations

import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.errors import STATUS_NONFINITE, STATUS_OK
from jaxabc.executors.base import SimulationBatch, mark_nonfinite, wrap_keys
from jaxabc.executors.workers import complex_summaries_message

__all__ = ["VmapExecutor"]


def _refuse_complex(summaries: np.ndarray) -> None:
    # The driver casts summaries to real floats for the distances, which would drop the
    # imaginary part without a word.
    if np.iscomplexobj(summaries):
        raise TypeError(complex_summaries_message(summaries.dtype))


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
    boolean mask of members that ran cleanly.  Complex summaries are refused with ``TypeError``:
    distances compare real numbers.
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
            out = fn(wrap_keys(keys), jnp.asarray(thetas))
            out, ok = out if isinstance(out, tuple) else (out, None)
            summaries = np.array(out)
            _refuse_complex(summaries)
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
            out = np.asarray(fn(wrap_keys(keys[pad]), jnp.asarray(thetas[pad])))
            times[start:stop] = (time.perf_counter() - t0) / idx.size
            pieces.append(out[: idx.size])
        summaries = np.concatenate(pieces, axis=0)
        _refuse_complex(summaries)
        batch = SimulationBatch(summaries, np.zeros(m, np.int32), [""] * m, times, np.zeros(m, np.int32))
        return mark_nonfinite(batch)

    def close(self) -> None:
        self._compiled.clear()
