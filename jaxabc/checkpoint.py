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

import dataclasses
import enum
import functools
import hashlib
import json
import os
import re
import socket
import sys
import tempfile
import time
import types
import warnings
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.errors import caller_stacklevel

__all__ = [
    "CHECKPOINT_NAME",
    "FORMAT_VERSION",
    "LEGACY_CHECKPOINT_NAME",
    "Checkpoint",
    "CheckpointError",
    "CheckpointExists",
    "FolderInUse",
    "FolderLock",
    "check_fingerprint",
    "describe_callable",
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


# ----------------------------------------------------------------------------- what a callable is

#: Arrays up to this many elements enter a fingerprint as values (readable differences); larger
#: ones as shape, dtype and SHA-256.
_INLINE_ELEMENTS = 16
#: Nesting below this depth is described by its type alone: such deep objects (a library's
#: internals reached through closures) are not what a user changes between two runs.
_MAX_DEPTH = 8
#: The attribute a user may set on any callable to give it an identity of their choosing.
ID_ATTRIBUTE = "jaxabc_id"
UNFINGERPRINTABLE = "unfingerprintable"


def _code_digest(code: types.CodeType) -> str:
    """SHA-256 of a code object's instructions, constants and names (line numbers left out, so
    an edit of comments or blank lines keeps the identity)."""
    h = hashlib.sha256()

    def feed(c: types.CodeType) -> None:
        h.update(c.co_code)
        h.update(repr(c.co_names).encode())
        h.update(repr(c.co_varnames).encode())
        for const in c.co_consts:
            if isinstance(const, types.CodeType):
                feed(const)
            else:
                h.update(repr(const).encode())

    feed(code)
    return h.hexdigest()


def _is_plain_function(obj: Any) -> bool:
    """A module-level function whose ``module:qualname`` names it uniquely (no closure)."""
    return (
        isinstance(obj, types.FunctionType)
        and obj.__closure__ is None
        and "<" not in obj.__qualname__  # neither a lambda nor a function defined in a function
    )


def _describe(value: Any, depth: int, seen: set[int]) -> Any:
    """A JSON-normal description of a value that changes whenever the value does."""
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        return value if np.isfinite(value) else repr(value)  # NaN != NaN would never compare equal
    if isinstance(value, complex):
        return {"complex": [_describe(value.real, depth, seen), _describe(value.imag, depth, seen)]}
    if isinstance(value, np.generic | np.ndarray | jax.Array):
        return _describe_array(value)
    if isinstance(value, type):
        return _callable_id(value)
    if isinstance(value, types.ModuleType):
        return {"module": value.__name__}
    if isinstance(value, enum.Enum | Path):
        return str(value)
    if depth >= _MAX_DEPTH:
        return {"type": _callable_id(type(value)), "depth": "not followed"}
    if id(value) in seen:
        return {"type": _callable_id(type(value)), "cycle": True}
    seen = seen | {id(value)}
    if callable(value) and not isinstance(value, tuple | list | dict):
        return _describe_callable(value, depth + 1, seen)
    if isinstance(value, tuple) and hasattr(value, "_fields"):  # NamedTuple
        fields = cast(Any, value)._fields
        return {
            "type": _callable_id(type(value)),
            "fields": {f: _describe(getattr(value, f), depth + 1, seen) for f in fields},
        }
    if isinstance(value, list | tuple | set | frozenset):
        items = sorted(value, key=repr) if isinstance(value, set | frozenset) else value
        return [_describe(v, depth + 1, seen) for v in items]
    if isinstance(value, dict):
        return {str(k): _describe(v, depth + 1, seen) for k, v in value.items()}
    if dataclasses.is_dataclass(value):
        fields = {f.name: _describe(getattr(value, f.name), depth + 1, seen) for f in dataclasses.fields(value)}
        return {"type": _callable_id(type(value)), "fields": fields}
    attributes = _attributes(value)
    if attributes is None:
        return {UNFINGERPRINTABLE: _callable_id(type(value))}
    return {
        "type": _callable_id(type(value)),
        "fields": {k: _describe(v, depth + 1, seen) for k, v in attributes.items()},
    }


def _attributes(value: Any) -> dict[str, Any] | None:
    """An object's instance attributes (``__dict__`` and ``__slots__``), or None if it has neither."""
    out: dict[str, Any] = {}
    found = False
    if hasattr(value, "__dict__"):
        out.update(vars(value))
        found = True
    for cls in type(value).__mro__:
        for slot in getattr(cls, "__slots__", ()):
            if slot not in ("__dict__", "__weakref__") and hasattr(value, slot):
                out[slot] = getattr(value, slot)
                found = True
    return out if found else None


def _describe_array(value: Any) -> Any:
    arr = np.asarray(value)
    if arr.dtype == object:
        return {UNFINGERPRINTABLE: "object array"}
    if arr.size <= _INLINE_ELEMENTS:
        return {
            "array": _jsonable(arr.astype(np.complex128).tolist() if np.iscomplexobj(arr) else arr.tolist()),
            "dtype": str(arr.dtype),
        }
    data = np.ascontiguousarray(arr)
    return {"shape": list(arr.shape), "dtype": str(arr.dtype), "sha256": hashlib.sha256(data.tobytes()).hexdigest()}


def _describe_callable(obj: Any, depth: int, seen: set[int]) -> Any:
    own_id = getattr(obj, ID_ATTRIBUTE, None)
    if isinstance(own_id, str):
        return own_id
    if _is_plain_function(obj):
        return _callable_id(obj)
    if isinstance(obj, functools.partial):
        return {
            "partial": _describe(obj.func, depth, seen),
            "args": [_describe(a, depth, seen) for a in obj.args],
            "keywords": {k: _describe(v, depth, seen) for k, v in sorted(obj.keywords.items())},
        }
    wrapped = getattr(obj, "__wrapped__", None)
    if wrapped is not None and not isinstance(obj, types.FunctionType):
        # jax.jit and functools.wraps-style wrappers compute what the wrapped function does.
        return _describe(wrapped, depth, seen)
    if isinstance(obj, types.MethodType):
        return {"method": _callable_id(obj.__func__), "self": _describe(obj.__self__, depth, seen)}
    if isinstance(obj, types.FunctionType):
        out: dict[str, Any] = {"function": _callable_id(obj), "code": _code_digest(obj.__code__)}
        if obj.__closure__:
            cells = {}
            for name, cell in zip(obj.__code__.co_freevars, obj.__closure__, strict=True):
                try:
                    cells[name] = _describe(cell.cell_contents, depth, seen)
                except ValueError:  # an empty cell (a name not yet bound)
                    cells[name] = None
            out["closure"] = cells
        if obj.__defaults__:
            out["defaults"] = [_describe(d, depth, seen) for d in obj.__defaults__]
        if obj.__kwdefaults__:
            out["kwdefaults"] = {k: _describe(v, depth, seen) for k, v in sorted(obj.__kwdefaults__.items())}
        return out
    if isinstance(obj, types.BuiltinFunctionType | np.ufunc):
        return _callable_id(obj) if hasattr(obj, "__qualname__") else f"builtin:{getattr(obj, '__name__', repr(obj))}"
    # A callable object: its class and its attributes.
    attributes = _attributes(obj)
    if attributes is None:
        return {UNFINGERPRINTABLE: _callable_id(type(obj))}
    return {
        "type": _callable_id(type(obj)),
        "fields": {k: _describe(v, depth, seen) for k, v in attributes.items()},
    }


def describe_callable(obj: Any) -> Any:
    """The identity of a simulator or distance, JSON-normal, for checkpoint fingerprints.

    A string stays itself; a module-level function is its ``module:qualname``; a callable with
    a string attribute ``jaxabc_id`` is that string.  Anything else is a dict of what defines
    it: a ``functools.partial``'s function, arguments and keywords; a closure's or lambda's
    code digest, captured values and defaults; a callable object's class and attributes (nested
    up to a depth of 8). Arrays of up to 16 elements enter as values, larger ones as a SHA-256.
    A part that cannot be described (an object with neither ``__dict__`` nor ``__slots__``) is
    marked ``{"unfingerprintable": type}``; see :func:`unfingerprintable_parts`.
    """
    if isinstance(obj, str):
        return obj
    return _jsonable(_describe_callable(obj, 0, {id(obj)}))


def unfingerprintable_parts(description: Any, path: str = "") -> list[str]:
    """Paths (``closure.runner``) of the parts of a description that could not be fingerprinted."""
    if isinstance(description, dict):
        if UNFINGERPRINTABLE in description:
            return [f"{path or '.'} ({description[UNFINGERPRINTABLE]})"]
        return [p for k, v in description.items() for p in unfingerprintable_parts(v, f"{path}.{k}" if path else k)]
    if isinstance(description, list):
        return [p for i, v in enumerate(description) for p in unfingerprintable_parts(v, f"{path}[{i}]")]
    return []


def display_name(description: Any) -> str:
    """A short human name of a described callable (``module:qualname`` where there is one)."""
    if isinstance(description, str):
        return description
    if isinstance(description, dict):
        for key in ("function", "partial", "method", "type"):
            if key in description:
                return display_name(description[key])
    return "?"


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
    simulator_id: Any,
    seed: int,
    num_particles: int | None,
    dtype: str,
) -> dict:
    """The identity of a calibration problem, JSON-serialisable.

    Observed values enter as a SHA-256 of their float64 bytes (and their shape); the prior as
    its class, bounds and names; the distance as :func:`describe_callable` describes it; the
    simulator as ``simulator_id`` (a string, or :func:`simulator_identity`'s description).
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
            "distance": describe_callable(distance),
            "simulator": simulator_id,
            "seed": int(seed),
            "num_particles": None if num_particles is None else int(num_particles),
            "dtype": dtype,
        }
    )


def simulator_identity(simulate: Callable, simulator_id: str | None) -> Any:
    """``simulator_id`` when given, else :func:`describe_callable` of the simulator."""
    return simulator_id if simulator_id is not None else describe_callable(simulate)


def require_fingerprintable(simulate: Callable, simulator_id: str | None, distance: Any) -> None:
    """Refuse a checkpointed run whose simulator or distance cannot be fingerprinted.

    A resume could not tell whether such a model changed, so it could blend two problems.

    Raises
    ------
    ValueError
        Naming the parts that cannot be fingerprinted and the way out (``simulator_id=``, or a
        ``jaxabc_id`` attribute on the distance).
    """
    problems = []
    if simulator_id is None:
        problems += [f"simulator {p}" for p in unfingerprintable_parts(describe_callable(simulate))]
    problems += [f"distance {p}" for p in unfingerprintable_parts(describe_callable(distance))]
    if problems:
        raise ValueError(
            "a checkpointed run must know its problem again on resume, but these parts cannot be "
            "fingerprinted: " + "; ".join(problems) + ". Pass simulator_id='...' (any string that "
            f"changes when the model changes), or set {ID_ATTRIBUTE} = '...' on the distance"
        )


def _differences(stored: Any, current: Any, path: str) -> list[str]:
    """Readable lines for every leaf in which two JSON-normal values differ."""
    if stored == current:
        return []
    if isinstance(stored, dict) and isinstance(current, dict):
        if "sha256" in stored and "sha256" in current and stored.get("shape") == current.get("shape"):
            return [f"  {path}: the values differ (same shape {stored.get('shape')}, other SHA-256)"]
        out = []
        for k in sorted(set(stored) | set(current), key=str):
            sub = f"{path}.{k}" if path else str(k)
            if k not in stored:
                out.append(f"  {sub}: not in the checkpoint, this run {_short(current[k])}")
            elif k not in current:
                out.append(f"  {sub}: checkpoint {_short(stored[k])}, not in this run")
            elif k == "code":
                out.append(f"  {sub}: the function's code differs")
            else:
                out += _differences(stored[k], current[k], sub)
        return out
    if isinstance(stored, list) and isinstance(current, list) and len(stored) == len(current) and len(stored) <= 64:
        return [
            line
            for i, (a, b) in enumerate(zip(stored, current, strict=True))
            for line in _differences(a, b, f"{path}[{i}]")
        ]
    return [f"  {path}: checkpoint {_short(stored)}, this run {_short(current)}"]


def _short(value: Any, limit: int = 120) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


#: What to do when a field differs, where the generic advice does not fit.
_HINTS = {
    "driver": (
        "this checkpoint was written by the compiled program of a JAX simulator (executor=None) "
        "and is resumed by that program only: resume with executor=None (CLI: no [executor] "
        "table), or start over with overwrite=True"
    ),
}


def check_fingerprint(stored: dict, current: dict, path: Path) -> None:
    """Raise :class:`CheckpointError` naming every field in which the two problems differ.

    Nested fields (a partial's keywords, a closure's captured values) are compared leaf by leaf
    and each differing leaf is listed with both values; arrays larger than 16 elements and the
    observed values, which enter as a SHA-256, are reported as differing values.
    """
    if stored == current:
        return
    if stored.get("driver") != current.get("driver"):
        hint = (
            _HINTS["driver"]
            if stored.get("driver")
            else (
                "this checkpoint was written by the host driver (with an executor) and is resumed by "
                "it only: resume with jaxabc.run (the same executor or another), not run_fused"
            )
        )
        raise CheckpointError(f"the checkpoint {path} was written by another driver: {hint}")
    lines = _differences(stored, current, "")
    if len(lines) > 30:
        lines = [*lines[:30], f"  ... and {len(lines) - 30} more"]
    raise CheckpointError(
        f"the checkpoint {path} belongs to a different problem; these fields differ:\n"
        + "\n".join(lines)
        + "\nresume with the same problem, or start over with overwrite=True (CLI: --overwrite). "
        "A simulator renamed but unchanged can keep its identity with simulator_id='...'"
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
    # A name of its own for every write: two writers never share a temporary file, and one left
    # behind by a crash (a full disk) is never in the way of the next write.
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=_TMP_SUFFIX, dir=path.parent)
    tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)  # pyright: ignore[reportArgumentType]  # numpy stubs: **kwds may bind allow_pickle
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


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
    _remove_stale_temporaries(Path(folder))
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


# ----------------------------------------------------------------------------- one run per folder

LOCK_NAME = ".jaxabc.lock"
_TMP_SUFFIX = ".tmp"


class FolderInUse(CheckpointError):
    """Another run (of this or another process) holds the checkpoint folder."""


def _remove_stale_temporaries(folder: Path) -> None:
    """Delete temporary checkpoint files a crashed writer left (called with the folder locked)."""
    if not folder.is_dir():
        return
    for tmp in (*folder.glob(f".{CHECKPOINT_NAME}.*{_TMP_SUFFIX}"), folder / f"{CHECKPOINT_NAME}.tmp"):
        if tmp.is_file():
            tmp.unlink(missing_ok=True)


class FolderLock:
    """An exclusive lock on a checkpoint folder for the duration of one run.

    The lock is ``flock`` on ``<folder>/.jaxabc.lock``: the kernel releases it when the holder
    exits, however it exits (``SIGKILL`` included), so a crashed run never leaves a stale lock.
    The file names the holder (process id, host, start time, command line) for the refusal of a
    second run.  Where ``fcntl`` is missing (Windows) no lock is taken.
    """

    def __init__(self, folder: Path, fd: int | None) -> None:
        self.folder = folder
        self._fd = fd

    @classmethod
    def acquire(cls, folder: str | Path | None) -> FolderLock | None:
        """Lock ``folder`` (created if missing); None when ``folder`` is None.

        Raises
        ------
        FolderInUse
            Another run holds the folder; the message names it.
        """
        if folder is None:
            return None
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX
            return cls(folder, None)
        fd = os.open(folder / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.pread(fd, 4096, 0).decode("utf-8", "replace").strip() or "unknown"
            os.close(fd)
            raise FolderInUse(
                f"{folder} is in use by another run ({_describe_holder(holder)}): two runs in one "
                "checkpoint folder would overwrite each other's checkpoint. Wait for that run to "
                "end, or give this one another folder"
            ) from None
        info = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": time.strftime("%Y-%m-%d %H:%M:%S"),
            "command": " ".join(sys.argv)[:300],
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        return cls(folder, fd)

    def release(self) -> None:
        """Unlock (idempotent).  The lock file stays: deleting it could race with a new holder."""
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor releases the flock
            self._fd = None


def _describe_holder(text: str) -> str:
    try:
        info = json.loads(text)
        return f"process {info['pid']} on {info['host']}, started {info['started']}: {info['command']}"
    except (ValueError, KeyError, TypeError):
        return text[:200]


# ----------------------------------------------------------------------------- resuming an ended run


def reopen(
    stop_reason: str,
    history: dict,
    *,
    num_steps: int | None,
    final_threshold: float | None,
    max_simulations: int | None,
    max_wall_time: float | None,
    path: Path,
) -> str:
    """The stop reason a resumed run starts with: ``""`` to go on, else the stored one.

    A run that ended on one of the run's own stopping rules goes on when this run's rule no
    longer holds (a larger ``num_steps``, a lower ``final_threshold``, a larger budget or wall
    time): every iteration's key depends on the seed and the iteration alone, so the result is
    the one an uninterrupted run with the new rule gives.  A run that ended for any other reason
    (the algorithm's own stopping rule) stays ended, with a warning that nothing was run.
    """
    if not stop_reason:
        return ""
    goes_on = None
    if m := re.fullmatch(r"(\d+) steps done", stop_reason):
        goes_on = num_steps is None or len(history.get("threshold", ())) < num_steps
    elif re.fullmatch(r"final threshold (.+) reached", stop_reason):
        last = history["threshold"][-1] if history.get("threshold") else float("inf")
        goes_on = final_threshold is None or last > final_threshold
    elif m := re.fullmatch(r"simulation budget (\d+) reached", stop_reason):
        goes_on = max_simulations is None or max_simulations > int(m.group(1))
    elif m := re.fullmatch(r"wall time (.+) s reached", stop_reason):
        goes_on = max_wall_time is None or max_wall_time > float(m.group(1))
    if goes_on:
        return ""
    why = (
        "this run's stopping rules would have stopped it there too"
        if goes_on is not None
        else "the algorithm's own stopping rule ended it"
    )
    warnings.warn(
        f"the run in {path.parent} had already ended ({stop_reason}) and {why}: its result is "
        "returned as it was and nothing more was run",
        stacklevel=caller_stacklevel(),
    )
    return stop_reason
