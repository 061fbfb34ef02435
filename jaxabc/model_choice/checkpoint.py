"""Checkpoints of a model-choice run, in the driver's file format (:mod:`jaxabc.checkpoint`).

One ``checkpoint.npz`` after every generation: each model's population as state arrays
(``<i>/particles``, ``<i>/log_weights``, ``<i>/distances``), its scalars and histories in the
JSON header, and every model's simulation records, model after model.  A generation draws
only from ``fold_in(fold_in(key(seed), t), m)`` and the saved state, so a resumed run gives the
result of the uninterrupted one.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from jaxabc import checkpoint as _ckpt
from jaxabc.model_choice.smc import ALGORITHM_NAME, HISTORY_KEYS, ModelTrack, Population, Settings

__all__ = ["problem_fingerprint", "restore", "save"]

_SCALARS = ("population_threshold", "died_at", "efficiency", "predicted_fraction", "num_simulations")


def problem_fingerprint(
    tracks: Sequence[ModelTrack],
    settings: Settings,
    model_prior: np.ndarray,
    observed: np.ndarray,
    distance: Any,
    seed: int,
    dtype: str,
    simulator_id: str | None,
) -> dict:
    """The identity of a model-choice problem: every model's name, prior and simulator."""
    models = [
        {
            "name": t.name,
            # to_dict names the distributions of an Independent prior too, not only its box.
            "prior": t.prior.to_dict() if hasattr(t.prior, "to_dict") else repr(t.prior),
            "simulator": _ckpt.simulator_identity(t.simulate, None),
        }
        for t in tracks
    ]
    return _ckpt.fingerprint(
        algorithm=ALGORITHM_NAME,
        settings={**settings._asdict(), "models": models, "model_prior": np.asarray(model_prior).tolist()},
        prior=tracks[0].prior,
        observed=observed,
        distance=distance,
        simulator_id=simulator_id if simulator_id is not None else [m["simulator"] for m in models],
        seed=seed,
        num_particles=settings.num_particles,
        dtype=dtype,
    )


def save(
    path: Path, fingerprint: dict, tracks: Sequence[ModelTrack], thresholds: list[float], stop_reason: str
) -> None:
    """Write the run's state after a generation (atomically)."""
    state: dict[str, np.ndarray] = {}
    history: dict[str, list] = {}
    scalars = []
    records: list[dict[str, Any]] = []
    for i, t in enumerate(tracks):
        if t.population is not None:
            for name, value in zip(Population._fields, t.population, strict=True):
                state[f"{i}/{name}"] = np.asarray(value)
        history.update({f"{i}/{key}": list(t.history[key]) for key in HISTORY_KEYS})
        scalars.append({**{k: getattr(t, k) for k in _SCALARS}, "num_chunks": len(t.recorder.chunks)})
        records.extend(t.recorder.chunks)
    counters = {"thresholds": list(thresholds), "stop_reason": stop_reason, "models": scalars}
    _ckpt.save(path, _ckpt.Checkpoint(fingerprint, state, counters, history, records))


def restore(path: Path, fingerprint: dict, tracks: Sequence[ModelTrack]) -> tuple[list[float], str]:
    """Load the checkpoint into ``tracks``; returns the tolerances so far and the stop reason.

    Raises
    ------
    jaxabc.checkpoint.CheckpointError
        The checkpoint belongs to another problem (the message names what differs), or is
        unreadable.
    """
    ck = _ckpt.load(path)
    _ckpt.check_fingerprint(ck.fingerprint, fingerprint, path)
    start = 0
    for i, (t, scalars) in enumerate(zip(tracks, ck.counters["models"], strict=True)):
        for k in _SCALARS:
            setattr(t, k, scalars[k])
        if f"{i}/particles" in ck.state_leaves:
            t.population = Population(*(ck.state_leaves[f"{i}/{name}"] for name in Population._fields))
        t.history = {key: list(ck.history[f"{i}/{key}"]) for key in HISTORY_KEYS}
        t.recorder.chunks = ck.records[start : start + scalars["num_chunks"]]
        start += scalars["num_chunks"]
    return [float(v) for v in ck.counters["thresholds"]], ck.counters["stop_reason"]
