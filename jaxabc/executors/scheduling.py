"""Task order for dynamic allocation, and the makespan maths that judges a schedule.

A free worker pulling the next task (greedy list scheduling) finishes a batch of ``m`` tasks on
``n`` workers within ``2 - 1/n`` of the optimal makespan in the worst case; when one long task is
pulled last, every other worker idles while it runs.  Handing out the longest tasks first (LPT,
Graham 1969) tightens the worst case to ``4/3 - 1/(3n)``.

Durations are not known before a simulation runs, but they are predictable from its parameters
(a water model whose parameters vaporise the liquid finishes sooner than one that stays liquid).
A :class:`NearestNeighbourCost` learns the log of the task cost (:func:`jaxabc.executors.task_durations`)
from the tasks an executor has already run and predicts new ones from their ``k`` nearest
neighbours in standardised parameter space, by default *pessimistically*: the longest of the
neighbours, because a long task mistaken for a short one is queued last and lengthens the makespan
by its whole duration, while a short task queued early costs almost nothing.
``benchmarks/speedup.py`` measures the orders against the bounds below.

The order changes only *when* a task runs, never its key or its result: the same seed gives the
same posterior with or without it, on any number of workers.

Makespans and bounds (all durations in seconds, one batch of independent tasks on ``n``
identical workers): :func:`dynamic_makespan` (greedy list scheduling, as the dynamic executors
do), :func:`static_makespan` (equal contiguous chunks, ``MPIExecutor("static")``),
:func:`lower_bound` and :func:`tight_lower_bound` (no schedule beats them), and
:func:`longest_predicted_first` (the queue order of ``order="longest_first"``).
"""

from __future__ import annotations

import heapq
from typing import Protocol

import numpy as np

__all__ = [
    "CostModel",
    "NearestNeighbourCost",
    "dispatch_order",
    "dynamic_makespan",
    "get_cost_model",
    "longest_predicted_first",
    "lower_bound",
    "static_makespan",
    "tight_lower_bound",
]


class CostModel(Protocol):
    """What a dynamic executor needs to order its tasks."""

    def predict(self, thetas: np.ndarray) -> np.ndarray | None:
        """Predicted relative cost per task, or ``None`` while there is too little history."""

    def observe(self, thetas: np.ndarray, durations: np.ndarray) -> None:
        """Learn from tasks that ran (``durations``: :func:`jaxabc.executors.task_durations`)."""


class NearestNeighbourCost:
    """k-nearest-neighbour prediction of a task's cost (log seconds) from its parameters.

    Parameters
    ----------
    k : int
        Neighbours per prediction.
    aggregate : {"max", "mean"}
        How the neighbours' log costs combine: ``"max"`` (default) ranks a task by the longest
        of its neighbours, a pessimistic estimate suited to longest-first ordering (see the
        module notes); ``"mean"`` is the plain k-NN regression.
    min_history : int
        Tasks that must have run before predictions are made (until then, tasks keep their
        order).
    max_history : int
        Most recent tasks kept (memory and cost of a prediction are ``O(m * max_history)``).

    Notes
    -----
    Parameters are standardised by the standard deviation of the history, so parameters in
    different units (nm and kJ/mol) count alike.  Durations below one millisecond are clipped
    before the logarithm: a task that fails instantly is short, not infinitely short.
    """

    def __init__(self, k: int = 5, min_history: int = 16, max_history: int = 20_000, aggregate: str = "max"):
        if k < 1 or min_history < 1 or max_history < min_history:
            raise ValueError("need k >= 1 and 1 <= min_history <= max_history")
        if aggregate not in ("max", "mean"):
            raise ValueError(f"aggregate must be 'max' or 'mean', got {aggregate!r}")
        self.k, self.min_history, self.max_history = int(k), int(min_history), int(max_history)
        self.aggregate = aggregate
        self._x = np.zeros((0, 0))
        self._y = np.zeros(0)

    @property
    def history_size(self) -> int:
        return int(self._y.size)

    def observe(self, thetas: np.ndarray, durations: np.ndarray) -> None:
        x = np.asarray(thetas, np.float64).reshape(len(durations), -1)
        y = np.log(np.maximum(np.asarray(durations, np.float64), 1e-3))
        keep = np.all(np.isfinite(x), axis=1) & np.isfinite(y)
        x, y = x[keep], y[keep]
        if self._y.size and self._x.shape[1] != x.shape[1]:
            self._x, self._y = np.zeros((0, x.shape[1])), np.zeros(0)  # a different model: start over
        self._x = np.concatenate([self._x.reshape(-1, x.shape[1]), x])[-self.max_history :]
        self._y = np.concatenate([self._y, y])[-self.max_history :]

    def predict(self, thetas: np.ndarray) -> np.ndarray | None:
        if self._y.size < self.min_history:
            return None
        x = np.asarray(thetas, np.float64).reshape(-1, self._x.shape[1])
        scale = self._x.std(axis=0)
        scale = np.where(scale > 0, scale, 1.0)
        a, b = x / scale, self._x / scale
        d2 = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * a @ b.T
        k = min(self.k, self._y.size)
        nearest = np.argpartition(d2, k - 1, axis=1)[:, :k]
        logs = self._y[nearest]
        return np.exp(logs.max(axis=1) if self.aggregate == "max" else logs.mean(axis=1))


def get_cost_model(order: str | CostModel | None) -> CostModel | None:
    """Resolve an executor's ``order`` option: ``None``/``"fifo"``, ``"longest_first"`` or a model."""
    if order is None or order == "fifo":
        return None
    if order == "longest_first":
        return NearestNeighbourCost()
    if isinstance(order, str):
        raise ValueError(f"unknown task order {order!r}: use 'fifo', 'longest_first' or a CostModel")
    if not (hasattr(order, "predict") and hasattr(order, "observe")):
        raise TypeError("order must be 'fifo', 'longest_first' or an object with predict() and observe()")
    return order


def dispatch_order(cost_model: CostModel | None, thetas: np.ndarray) -> np.ndarray:
    """Indices of the tasks in the order a dynamic executor should hand them out.

    Longest predicted first; ties (and the whole batch while the model has no history) keep
    their original order, so the order is deterministic.
    """
    m = np.asarray(thetas).shape[0]
    if cost_model is None:
        return np.arange(m)
    cost = cost_model.predict(np.asarray(thetas))
    if cost is None:
        return np.arange(m)
    return np.argsort(-np.asarray(cost, np.float64), kind="stable")


def _durations(durations: np.ndarray, n: int) -> np.ndarray:
    d = np.asarray(durations, np.float64).reshape(-1)
    if d.size == 0:
        raise ValueError("need at least one task duration")
    if n < 1:
        raise ValueError(f"need at least one worker, got n={n}")
    return d


def dynamic_makespan(durations: np.ndarray, n: int, overhead: float = 0.0) -> float:
    """Makespan of greedy list scheduling in task order: the earliest-free worker takes the next task.

    Parameters
    ----------
    durations : array, shape (m,)
        Seconds per task, in the order the tasks are queued.
    n : int
        Workers.
    overhead : float
        Seconds added to every task (an executor's round trip per task).
    """
    d = _durations(durations, n) + overhead
    if n >= d.size:
        return float(d.max())
    finish = [0.0] * n
    for t in d:
        heapq.heapreplace(finish, finish[0] + t)
    return float(max(finish))


def static_makespan(durations: np.ndarray, n: int, overhead: float = 0.0) -> float:
    """Makespan of equal contiguous chunks, one per worker (:func:`jaxabc.executors.mpi.chunk_indices`).

    ``overhead`` (seconds) is paid once per chunk: the executor sends each chunk as one message.
    """
    d = _durations(durations, n)
    return float(max(c.sum() for c in np.array_split(d, min(n, d.size)))) + overhead


def lower_bound(durations: np.ndarray, n: int) -> float:
    """``max(total / n, longest)``: no schedule of independent tasks on ``n`` workers is shorter."""
    d = _durations(durations, n)
    return float(max(d.sum() / n, d.max()))


def tight_lower_bound(durations: np.ndarray, n: int) -> float:
    """The pigeonhole bound, never below :func:`lower_bound` and never above the optimal makespan.

    With durations sorted longest first, ``max(total / n, longest, max_k (p_(kn-k+1) + ... +
    p_(kn+1)))``: with more than ``k n`` tasks some worker runs ``k + 1`` of the ``k n + 1``
    longest, and no ``k + 1`` of them sum to less than the ``k + 1`` shortest of them.  Where it
    exceeds :func:`lower_bound`, no scheduler can reach the latter.
    """
    d = np.sort(_durations(durations, n))[::-1]
    lb = lower_bound(d, n)
    csum = np.concatenate([[0.0], np.cumsum(d)])
    k = np.arange(1, (d.size - 1) // n + 1)
    if k.size:  # sum of d[kn-k .. kn] (0-based) for every k with kn + 1 <= m
        lb = max(lb, float(np.max(csum[k * n + 1] - csum[k * n - k])))
    return float(lb)


def longest_predicted_first(durations: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """``durations`` reordered by decreasing ``predicted`` (stable: ties keep their order).

    The queue a dynamic executor with ``order="longest_first"`` hands out, for
    :func:`dynamic_makespan`; with ``predicted = durations`` it is LPT with perfect foresight.
    """
    d = np.asarray(durations, np.float64).reshape(-1)
    p = np.asarray(predicted, np.float64).reshape(-1)
    if d.shape != p.shape:
        raise ValueError(f"need one prediction per duration, got {p.size} for {d.size}")
    return d[np.argsort(-p, kind="stable")]
