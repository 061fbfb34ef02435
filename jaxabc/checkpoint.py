"""Checkpoints of a running calibration: arrays plus a JSON header, never a pickle.

A checkpoint is one ``.npz`` file (written without pickling, read with ``allow_pickle=False``):

``header``
    JSON text: the format version, the problem's fingerprint (see :func:`fingerprint`), the loop
    counters, the generation history and the records' failure reasons.
``state/<path>``
    One array per leaf of the algorithm's state, named by its ``jax.tree_util.keystr`` path.
``posterior/<name>``, ``records/<name>``
    The last completed generation's posterior and every simulation's record.

It is written atomically (temporary file, ``fsync``, ``os.replace``), so a run killed at any
moment leaves either the previous checkpoint or the new one.  Resuming checks that the problem
is the same as the one that wrote it and names every field that differs.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "CHECKPOINT_NAME",
    "FORMAT_VERSION",
    "LEGACY_CHECKPOINT_NAME",
    "Checkpoint",
    "CheckpointError",
    "CheckpointExists",
    "check_fingerprint",
    "fingerprint",
    "load",
    "load_records",
    "prepare_folder",
    "restore_state",
    "save",
]

CHECKPOINT_NAME = "checkpoint.npz"
LEGACY_CHECKPOINT_NAME = "checkpoint.pkl"
FORMAT_VERSION = 1
_RECORD_KEYS = ("theta", "distance", "status", "wall_time", "cpu_time", "worker", "iteration")


class CheckpointError(ValueError):
    """A checkpoint that cannot be used: corrupt, foreign, too old, or of another problem."""


class CheckpointExists(CheckpointError, FileExistsError):
    """A fresh run was asked to write into a folder that holds an earlier run's checkpoint."""


@dataclass
class Checkpoint:
    """Everything the driver needs to continue a run.

    Attributes
    ----------
    fingerprint : dict
        The problem's identity (:func:`fingerprint`).
    state_leaves : dict of str to numpy.ndarray
        The algorithm's state, flat, keyed by ``keystr`` paths.
    counters : dict
        ``iteration``, ``num_sims``, ``sims_this_generation``, ``stop_reason``.
    history : dict of str to list
        Per-generation threshold, simulations, acceptance, ESS and wall time.
    records : list of dict
        The recorder's chunks (one per iteration that simulated).
    last_posterior : tuple of numpy.ndarray or None
        ``(particles, log_weights, distances)`` of the last completed generation.
    """

    fingerprint: dict
    state_leaves: dict[str, np.ndarray]
    counters: dict
    history: dict[str, list]
    records: list[dict[str, Any]] = field(default_factory=list)
    last_posterior: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None


def _callable_id(obj: Any) -> str:
    """A stable name for a function: ``module:qualname`` (of its class for callable objects)."""
    if isinstance(obj, str):
        return obj
    target = obj.func if hasattr(obj, "func") and hasattr(obj, "args") else obj  # functools.partial
    if not hasattr(target, "__qualname__"):
        target = type(target)
    return f"{getattr(target, '__module__', '?')}:{getattr(target, '__qualname__', repr(target))}"


def _jsonable(value: Any) -> Any:
    """JSON-normal form (tuples to lists, NumPy scalars to Python), so a round trip compares equal."""
    return json.loads(json.dumps(value, default=lambda o: np.asarray(o).tolist()))


def fingerprint(
    *,
    algorithm: str,
    settings: dict,
    prior: Any,
    observed: np.ndarray,
    distance: Any,
    simulator_id: str,
    seed: int,
    num_particles: int | None,
    dtype: str,
) -> dict:
    """The identity of a calibration problem, JSON-serialisable.

    Observed values enter as a SHA-256 of their float64 bytes (and their shape); the prior as
    its class, bounds and names; the distance and the simulator by name (``module:qualname``).
    """
    obs = np.ascontiguousarray(observed, dtype=np.float64)
    return _jsonable(
        {
            "algorithm": algorithm,
            "settings": settings,
            "prior": {
                "class": _callable_id(type(prior)),
                "low": np.asarray(prior.low, np.float64).tolist(),
                "high": np.asarray(prior.high, np.float64).tolist(),
                "names": list(getattr(prior, "names", ())),
            },
            "observed": {"shape": list(obs.shape), "sha256": hashlib.sha256(obs.tobytes()).hexdigest()},
            "distance": _callable_id(distance),
            "simulator": simulator_id,
            "seed": int(seed),
            "num_particles": None if num_particles is None else int(num_particles),
            "dtype": dtype,
        }
    )


def simulator_identity(simulate: Callable, simulator_id: str | None) -> str:
    """``simulator_id`` when given, else the simulator's ``module:qualname``."""
    return simulator_id if simulator_id is not None else _callable_id(simulate)


def check_fingerprint(stored: dict, current: dict, path: Path) -> None:
    """Raise :class:`CheckpointError` naming every field in which the two problems differ."""
    fields = sorted(set(stored) | set(current))
    differ = [k for k in fields if stored.get(k) != current.get(k)]
    if not differ:
        return
    lines = [f"  {k}: checkpoint {stored.get(k)!r}, this run {current.get(k)!r}" for k in differ]
    raise CheckpointError(
        f"the checkpoint {path} belongs to a different problem; these fields differ:\n"
        + "\n".join(lines)
        + "\nresume with the same problem, or start over with overwrite=True (CLI: another "
        "output folder). A simulator renamed but unchanged can keep its identity with "
        "simulator_id='...'"
    )


def save(path: Path, ckpt: Checkpoint) -> None:
    """Write ``ckpt`` to ``path`` atomically (temporary file, fsync, rename)."""
    arrays: dict[str, np.ndarray] = {f"state/{k}": np.asarray(v) for k, v in ckpt.state_leaves.items()}
    if ckpt.last_posterior is not None:
        for name, value in zip(("particles", "log_weights", "distances"), ckpt.last_posterior, strict=True):
            arrays[f"posterior/{name}"] = np.asarray(value)
    chunks = ckpt.records
    reasons: list[str] = []
    summary_shapes: list[list[int] | None] = []
    if chunks:
        for key in _RECORD_KEYS:
            arrays[f"records/{key}"] = np.concatenate([np.asarray(c[key]) for c in chunks])
        for i, c in enumerate(chunks):
            if c["summaries"] is not None:
                # One array per chunk: summary shapes may differ between batches (sample data).
                arrays[f"records/summaries/{i}"] = np.asarray(c["summaries"])
            summary_shapes.append(None if c["summaries"] is None else list(c["summaries"].shape))
            reasons.extend(c["reasons"])
    header = {
        "format": "jaxabc-checkpoint",
        "version": FORMAT_VERSION,
        "fingerprint": ckpt.fingerprint,
        "counters": ckpt.counters,
        "history": ckpt.history,
        "chunk_sizes": [len(c["distance"]) for c in chunks],
        "reasons": reasons,
        "state_keys": sorted(ckpt.state_leaves),
    }
    arrays["header"] = np.asarray(json.dumps(header, default=lambda o: np.asarray(o).tolist()))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)  # pyright: ignore[reportArgumentType]  # numpy stubs: **kwds may bind allow_pickle
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def load(path: Path) -> Checkpoint:
    """Read a checkpoint written by :func:`save`.

    Raises
    ------
    CheckpointError
        For an old pickle checkpoint (never unpickled), a corrupt or truncated file, a foreign
        ``.npz`` or a newer format version; the message names the file.
    """
    path = Path(path)
    if path.suffix == ".pkl":
        raise CheckpointError(
            f"{path} is a checkpoint of an older jaxabc (a pickle, which is never loaded because "
            "unpickling can run code): finish that run with the jaxabc version that started it, "
            "or start over with overwrite=True"
        )
    try:
        with np.load(path, allow_pickle=False) as data:
            header = json.loads(str(data["header"]))
            arrays = {k: data[k] for k in data.files if k != "header"}
    except FileNotFoundError:
        raise
    except (
        OSError,
        ValueError,
        KeyError,
        EOFError,
        zipfile.BadZipFile,
        json.JSONDecodeError,
        UnicodeDecodeError,
    ) as exc:
        raise CheckpointError(
            f"the checkpoint {path} is corrupt or truncated ({type(exc).__name__}: {exc}); "
            "delete it and start over with overwrite=True"
        ) from None
    if header.get("format") != "jaxabc-checkpoint":
        raise CheckpointError(f"{path} is not a jaxabc checkpoint")
    if header.get("version") != FORMAT_VERSION:
        raise CheckpointError(
            f"the checkpoint {path} has format version {header.get('version')}, this jaxabc reads "
            f"version {FORMAT_VERSION}: resume with the jaxabc that wrote it"
        )
    try:
        return _unpack(header, arrays)
    except (KeyError, ValueError, IndexError) as exc:
        raise CheckpointError(
            f"the checkpoint {path} is incomplete ({type(exc).__name__}: {exc}); delete it and "
            "start over with overwrite=True"
        ) from None


def _unpack(header: dict, arrays: dict[str, np.ndarray]) -> Checkpoint:
    state = {k: arrays[f"state/{k}"] for k in header["state_keys"]}
    post = None
    if "posterior/particles" in arrays:
        post = (arrays["posterior/particles"], arrays["posterior/log_weights"], arrays["posterior/distances"])
    chunks: list[dict[str, Any]] = []
    start = 0
    for i, size in enumerate(header["chunk_sizes"]):
        chunk: dict[str, Any] = {k: arrays[f"records/{k}"][start : start + size] for k in _RECORD_KEYS}
        chunk["summaries"] = arrays.get(f"records/summaries/{i}")
        chunk["reasons"] = header["reasons"][start : start + size]
        chunks.append(chunk)
        start += size
    return Checkpoint(header["fingerprint"], state, header["counters"], header["history"], chunks, post)


def load_records(path: Path) -> dict[str, np.ndarray]:
    """The simulation records of a checkpoint as concatenated arrays (for a run still going)."""
    chunks = load(path).records
    if not chunks:
        return {}
    return {k: np.concatenate([c[k] for c in chunks]) for k in _RECORD_KEYS}


def flatten_state(state: Any) -> dict[str, np.ndarray]:
    """``{keystr path: numpy array}`` of a state's leaves."""
    leaves, _ = jax.tree_util.tree_flatten_with_path(state)
    return {jax.tree_util.keystr(p): np.asarray(v) for p, v in leaves}


def restore_state(flat: dict[str, np.ndarray], template: Any, path: Path) -> Any:
    """Rebuild a state from its flat leaves and a template of the same structure.

    ``template`` is typically ``jax.eval_shape`` of the algorithm's ``init``.  Raises
    :class:`CheckpointError` when the leaves do not match the template's paths and shapes.
    """
    leaves, treedef = jax.tree_util.tree_flatten_with_path(template)
    out = []
    for p, spec in leaves:
        key = jax.tree_util.keystr(p)
        if key not in flat or tuple(flat[key].shape) != tuple(spec.shape):
            raise CheckpointError(
                f"the checkpoint {path} holds no state leaf {key} of shape {tuple(spec.shape)}: "
                "it was written by another version of the algorithm; start over with "
                "overwrite=True"
            )
        out.append(jnp.asarray(flat[key], spec.dtype))
    return jax.tree_util.tree_unflatten(treedef, out)


def prepare_folder(folder: str | Path | None, resume: bool, overwrite: bool) -> Path | None:
    """The checkpoint path, after refusing to clobber an existing checkpoint by accident."""
    if folder is None:
        if resume:
            raise ValueError("resume=True needs checkpoint_dir= (the folder of the checkpoint)")
        return None
    path = Path(folder) / CHECKPOINT_NAME
    legacy = Path(folder) / LEGACY_CHECKPOINT_NAME
    if resume and overwrite:
        raise ValueError("resume=True and overwrite=True contradict each other: choose one")
    if overwrite:
        path.unlink(missing_ok=True)
        legacy.unlink(missing_ok=True)
    elif resume:
        if not path.exists():
            if legacy.exists():
                load(legacy)  # raises the clear refusal of old pickles
            raise FileNotFoundError(f"no checkpoint at {path}: run without resume=True to start afresh")
    else:
        existing = path if path.exists() else legacy if legacy.exists() else None
        if existing is not None:
            raise CheckpointExists(
                f"{existing} holds the checkpoint of an earlier run: continue it with "
                "resume=True (CLI: --resume), or start over with overwrite=True, which deletes "
                "it (CLI: --overwrite)"
            )
    return path
