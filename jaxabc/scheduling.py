"""Task order for dynamic allocation: longest predicted task first.

A free worker pulling the next task (greedy list scheduling) finishes a batch of ``m`` tasks on
``n`` workers within ``2 - 1/n`` of the optimal makespan in the worst case; when one long task is
pulled last, every other worker idles while it runs.  Handing out the longest tasks first (LPT,
Graham 1969) tightens the worst case to ``4/3 - 1/(3n)`` and is within a few percent of optimal
for the duration distributions of MD simulations (``benchmarks/speedup.py`` measures it).

Durations are not known before a simulation runs, but they are predictable from its parameters:
a water model whose parameters vaporise the liquid finishes in a fraction of the time of one that
stays liquid, and a dense LJ state costs more neighbour-list work than a dilute one.  A
:class:`NearestNeighbourCost` learns the log of the task cost (CPU time, or wall time for a task
that waits: :func:`jaxabc.executors.task_durations`) from the tasks an executor has already run
(its own history, across the ABC iterations of a run) and predicts new ones from their ``k``
nearest neighbours in standardised parameter space, by default *pessimistically*: the longest
of the neighbours.  The ranking is asymmetric: a long task mistaken for a short one is queued
last and lengthens the makespan by its whole duration, while a short task queued early costs
almost nothing.  In ``benchmarks/results/speedup.json`` (event model over the 820 CPU-time
records of the neutron water calibration, durations 0.1-12 s, bimodal: vapour ~2 s, liquid
~9-11 s) the worst whole-run makespan over the lower bound is, APMCABC / ABCsubsim, 1.23 / 1.38
in arrival order, 1.12 / 1.23 longest-first by the neighbours' maximum and 1.04 / 1.08 with
perfect foresight; on a second run's 640 records, with the model left as chosen on the first,
1.20 / 1.36, 1.11 / 1.19 and 1.04 / 1.09 (``speedup_model_simulated_records.json``).
(A probe on the run's first 190 records, not saved, ranked by the
neighbours' *mean*: no better than arrival order.)

The order changes only *when* a task runs, never its key or its result: the same seed gives the
same posterior with or without it, on any number of workers.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

__all__ = ["CostModel", "NearestNeighbourCost", "dispatch_order", "get_cost_model"]


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
        self._x = np.concatenate([self._x.reshape(-1, x.shape[1]), x])[-self.max_history:]
        self._y = np.concatenate([self._y, y])[-self.max_history:]

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
