"""Host-side bookkeeping of :mod:`jaxabc.driver.fused`: records, history and stop reasons of a chunk."""

from __future__ import annotations

import time
from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxabc.algorithms.base import ABCAlgorithm, Info
from jaxabc.driver.context import BAD_DISTANCE_REASON
from jaxabc.driver.options import Stopping
from jaxabc.errors import STATUS_BAD_DISTANCE, STATUS_NONFINITE, STATUS_OK

__all__ = [
    "RUNNING",
    "STOP_ALGORITHM",
    "STOP_BUDGET",
    "STOP_STEPS",
    "STOP_THRESHOLD",
    "absorb",
    "from_checkpoint",
    "record_arrays",
    "stop_reason",
    "to_checkpoint",
]

#: Why the compiled loop stopped (its carry's stop code): not yet, the algorithm's own rule,
#: ``num_steps``, ``final_threshold``, ``max_simulations``.
RUNNING, STOP_ALGORITHM, STOP_STEPS, STOP_THRESHOLD, STOP_BUDGET = range(5)


def absorb(
    block: dict, first_iteration: int, records: list, history: dict, t_start: float, algorithm: str, bar: Any
) -> None:
    """Move one chunk's per-iteration outputs (leading axis: iteration) into the host record."""
    ran = np.flatnonzero(block["ran"])
    if not np.all(block["ok"][ran]):
        raise RuntimeError(
            f"{algorithm}: the truncated perturbation kernel could not reach the prior's "
            "support from some particles (no draw inside the box in 10,000 tries). The "
            "posterior is piled against a prior bound: widen the prior there"
        )
    now = time.perf_counter() - t_start
    for j, i in enumerate(ran):
        active = block["active"][i]
        records.append(
            {
                "theta": block["thetas"][i][active],
                "distance": block["distances"][i][active],
                "finite": block["finite"][i][active],
                "bad": block["bad"][i][active],
                "active": active[active],
                "iteration": np.full(int(active.sum()), first_iteration + j, np.int32),
                **({"summaries": block["summaries"][i][active]} if "summaries" in block else {}),
            }
        )
        if block["done"][i]:
            history["threshold"].append(float(block["threshold"][i]))
            history["sims"].append(int(block["generation_sims"][i]))
            history["acceptance"].append(float(block["acceptance"][i]))
            history["ess"].append(float(block["ess"][i]))
            history["wall"].append(now)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(
                    threshold=f"{float(block['threshold'][i]):.4g}", acceptance=f"{float(block['acceptance'][i]):.3f}"
                )


def record_arrays(records: list[dict], keep_summaries: bool) -> dict[str, Any]:
    """The fused records as :attr:`~jaxabc.results.ABCResult.records` (no per-simulation times)."""
    if not records:
        return {}
    finite = np.concatenate([r["finite"] for r in records])
    bad = np.concatenate([r["bad"] for r in records])
    size = finite.shape[0]
    out: dict[str, Any] = {
        "theta": np.concatenate([r["theta"] for r in records]).astype(np.float64),
        "distance": np.concatenate([r["distance"] for r in records]).astype(np.float64),
        "status": np.where(bad, STATUS_BAD_DISTANCE, np.where(finite, STATUS_OK, STATUS_NONFINITE)).astype(np.int32),
        "wall_time": np.full(size, np.nan),
        "cpu_time": np.full(size, np.nan),
        "worker": np.zeros(size, np.int32),
        "iteration": np.concatenate([r["iteration"] for r in records]),
        "reasons": [
            BAD_DISTANCE_REASON if b else "" if f else "simulator returned non-finite summaries"
            for f, b in zip(finite, bad, strict=True)
        ],
    }
    if keep_summaries:
        out["summaries"] = np.concatenate([r["summaries"] for r in records])
    return out


def to_checkpoint(records: list[dict]) -> list[dict[str, Any]]:
    """The fused records as the checkpoint's chunks (the host driver's fields, one per iteration)."""
    chunks = []
    for r in records:
        out = record_arrays([r], "summaries" in r)
        out["summaries"] = out.get("summaries")
        chunks.append(out)
    return chunks


def from_checkpoint(chunks: list[dict[str, Any]]) -> list[dict]:
    """Inverse of :func:`to_checkpoint`."""
    records = []
    for c in chunks:
        status = np.asarray(c["status"])
        finite = status != STATUS_NONFINITE
        r = {
            "theta": np.asarray(c["theta"]),
            "distance": np.asarray(c["distance"]),
            "finite": finite,
            "bad": status == STATUS_BAD_DISTANCE,
            "active": np.ones(finite.shape, bool),
            "iteration": np.asarray(c["iteration"], np.int32),
        }
        if c.get("summaries") is not None:
            r["summaries"] = np.asarray(c["summaries"])
        records.append(r)
    return records


def stop_reason(code: int, algo: ABCAlgorithm, history: dict, stopping: Stopping) -> str:
    """The stop reason of stop code ``code`` (not :data:`RUNNING`), worded as the host driver's."""
    if code == STOP_ALGORITHM:
        done = jnp.asarray(True)
        info = Info(
            generation_done=done,
            stop=done,
            threshold=history["threshold"][-1],
            acceptance_rate=history["acceptance"][-1],
            ess=history["ess"][-1],
        )
        return algo.stop_reason(algo.settings, info)
    if code == STOP_STEPS:
        return f"{stopping.num_steps} steps done"
    if code == STOP_THRESHOLD:
        return f"final threshold {stopping.final_threshold} reached"
    return f"simulation budget {stopping.max_simulations} reached"
