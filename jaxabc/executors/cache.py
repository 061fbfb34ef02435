"""A disk cache that replays identical simulations, for expensive host simulators.

A calibration with a simulator of minutes per call (GROMACS, LAMMPS) often spans several
sittings: a run is stopped, or killed, in the middle of a batch, and resumed from its last
checkpoint.  The checkpoint holds finished *iterations* only, so the resumed run repeats the
simulations of the unfinished batch.  :class:`RunCache` wraps the simulator and stores every
finished simulation on disk under a digest of (simulator identity, key, theta); a rerun with the
same seed asks for the same (key, theta) pairs and gets them back from disk, bit for bit, without
calling the simulator.

Usage::

    from jaxabc.executors.cache import RunCache

    cached = RunCache(simulate, "runs/water-cache")
    result = jaxabc.run("apmcabc", cached, prior, observed, ..., executor="process_pool")
    RunCache.stats("runs/water-cache")  # {"hits": ..., "misses": ..., ...}

The wrapper is picklable (it travels to process-pool and MPI workers as any simulator does) and
keeps no shared state: each call reads or writes one file, and its hit or miss is appended as one
line to a log in the folder, which :meth:`RunCache.stats` counts.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
import time
import warnings
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from jaxabc.errors import SimulationFailure

__all__ = ["CACHE_SUFFIX", "STATS_FILE", "RunCache", "RunCacheWarning", "run_digest", "source_digest"]

#: Suffix of one cached simulation (a NumPy ``.npz`` archive).
CACHE_SUFFIX = ".npz"
#: The append-only log of hits and misses in a cache folder, one word a line.
STATS_FILE = "runcache-stats.log"
#: Hex digits of the digest in a file name: 96 bits, no collision among any feasible run count.
_NAME_DIGITS = 24
#: The words of the stats log.
_EVENTS = ("hit", "miss", "corrupt")


class RunCacheWarning(UserWarning):
    """A cache file could not be read (truncated, not an archive, missing fields): it is
    treated as a miss, the simulation is run again and the file replaced."""


def _key_data(key: Any) -> np.ndarray:
    """Raw ``uint32`` key data of a typed JAX key or of raw key data (as host executors pass)."""
    dtype = getattr(key, "dtype", None)
    if dtype is not None and not isinstance(dtype, np.dtype):
        # Only a typed JAX key has a non-NumPy dtype; import JAX only then (host workers may
        # never need it).
        import jax
        import jax.numpy as jnp

        if jnp.issubdtype(dtype, jax.dtypes.prng_key):
            key = jax.random.key_data(key)
    return np.ascontiguousarray(np.asarray(key), dtype=np.uint32)


def _identity_bytes(identity: Any) -> bytes:
    """The bytes an identity enters the digest as.

    A string enters as its UTF-8 bytes, anything else as sorted, compact JSON, so that equal
    descriptions give equal digests whatever their dict order.  (A string identity hashes as
    ``benchmarks/water_calibration.py``'s cache did, so its existing folders stay readable.)
    """
    if isinstance(identity, str):
        return identity.encode()
    try:
        return json.dumps(identity, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()
    except (TypeError, ValueError) as exc:
        raise TypeError(f"identity must be a string or JSON-serialisable (finite numbers), got: {exc}") from exc


def run_digest(identity: Any, key: Any, theta: Any) -> str:
    """SHA-256 (hex) of one simulation: the simulator's identity, the key and theta.

    Parameters
    ----------
    identity : str or JSON-serialisable
        The simulator's identity (see :class:`RunCache`).
    key : array_like of uint32, shape (2,), or typed JAX key
        Raw key data (as the host executors pass) or a typed key, converted with
        :func:`jax.random.key_data`; both give the same digest.
    theta : array_like, shape (d,)
        Parameters; they enter as float64 bytes, so a float32 theta and its float64 value
        give the same digest.
    """
    return _digest(_identity_bytes(identity), key, theta)


def _digest(identity: bytes, key: Any, theta: Any) -> str:
    digest = hashlib.sha256(identity)
    digest.update(_key_data(key).tobytes())
    digest.update(np.ascontiguousarray(np.asarray(theta, dtype=np.float64).reshape(-1)).tobytes())
    return digest.hexdigest()


def source_digest(*paths: str | os.PathLike) -> str:
    """SHA-256 (hex) of Python sources: files, and the ``*.py`` files under folders (recursively).

    For an ``identity`` that changes when the simulator's code does (the default identity names a
    module-level function by ``module:qualname`` only, and does not see edits of its body)::

        RunCache(simulate, folder, identity={"simulator": describe_callable(simulate),
                                             "code": source_digest("md/water")})

    Files enter in sorted order with their names relative to the path given, so the digest does
    not depend on where the checkout lives.

    Raises
    ------
    FileNotFoundError
        A path that does not exist.
    """
    digest = hashlib.sha256()
    for path in map(Path, paths):
        if not path.exists():
            raise FileNotFoundError(path)
        files = sorted(path.rglob("*.py")) if path.is_dir() else [path]
        for file in files:
            name = file.relative_to(path) if path.is_dir() else Path(file.name)
            digest.update(str(name.as_posix()).encode() + b"\0")
            digest.update(file.read_bytes() + b"\0")
    return digest.hexdigest()


def _default_identity(simulate: Callable) -> Any:
    """:func:`jaxabc.checkpoint.describe_callable` of ``simulate``, refused when a part of it
    cannot be described (a replay could then mix two different simulators)."""
    from jaxabc.checkpoint import describe_callable, unfingerprintable_parts

    try:
        description = describe_callable(simulate)
        problems = unfingerprintable_parts(description)
        _identity_bytes(description)
    except (TypeError, ValueError) as exc:
        problems = [str(exc)]
    if problems:
        raise ValueError(
            "RunCache cannot tell this simulator from another one (parts that cannot be "
            f"described: {'; '.join(problems)}); pass identity='...', any string or JSON value "
            "that changes whenever the simulator's results would"
        )
    return description


def _append_line(path: Path, line: str) -> None:
    """Append one line with a single ``write`` on an ``O_APPEND`` descriptor: lines from
    concurrent processes do not interleave on a local file system.  Never raises: bookkeeping
    must not fail a simulation."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, (line + "\n").encode())
        finally:
            os.close(fd)


class RunCache:
    """``simulate(key, theta)`` that replays identical simulations from files in ``folder``.

    Each call computes a digest of (``identity``, the raw key data as ``uint32`` bytes, theta as
    ``float64`` bytes).  When ``folder`` holds a file of that digest the call returns the stored
    summaries (or raises the stored failure) without calling ``simulate``; otherwise it calls
    ``simulate`` and stores what came out.

    Parameters
    ----------
    simulate : callable ``(key, theta) -> summaries``
        The simulator; picklable when the cache is to travel to worker processes.
    folder : str or path-like
        Where the cache lives; created if missing.  Stored as an absolute path, so workers with
        another working directory find it.  Several runs may share a folder: their identities
        keep them apart.
    identity : str or JSON-serialisable, optional
        What distinguishes this simulator's results from any other's: two simulators with the
        same identity must give the same summaries for the same (key, theta).  Default:
        :func:`jaxabc.checkpoint.describe_callable` of ``simulate`` (class and attributes of a
        callable object, ``module:qualname`` of a module-level function, bound values of a
        partial or closure).  It does not see edits of a function's code, so include a version
        or :func:`source_digest` when the code may change under an existing folder.
    prefix : str
        Prepended to each file name (e.g. a model name, for a readable folder).

    Raises
    ------
    ValueError
        Without ``identity``, when ``describe_callable`` cannot describe part of ``simulate``.
    TypeError
        When ``identity`` is neither a string nor JSON-serialisable.

    Notes
    -----
    What is cached: summaries (as returned, dtype kept, NaN included: non-finite summaries
    replay as such), and :class:`jaxabc.SimulationFailure`, whose reason is stored and raised
    again on replay, so a failed simulation replays as the same failure.  Any other exception (a
    crash, a timeout, ``KeyboardInterrupt``) is not a property of (key, theta): it propagates
    and nothing is stored, so a rerun tries again.

    Files: ``{prefix}{digest[:24]}.npz`` with fields ``summaries``, ``reason`` (empty when the
    simulation succeeded), ``key``, ``theta`` and ``wall_s``.  Each is written to a temporary
    file in the folder and renamed into place (``os.replace``), so a process killed mid-write
    leaves no half file under a cache name (at most a ``.*.tmp`` file, never read).  A file that
    cannot be read anyway (a truncated copy, a full disk) is a miss, with a
    :class:`RunCacheWarning`; the simulation is run again and the file replaced.

    Two workers given the same (key, theta) at once both simulate, and the last rename wins;
    both results are valid.  The cache does not change what a run computes, so a checkpointed
    run sees the wrapped simulator's identity (the wrapper sets ``__wrapped__``, which
    :func:`~jaxabc.checkpoint.describe_callable` follows): wrapping or unwrapping it does not
    invalidate a checkpoint.

    Each call appends ``hit``, ``miss`` or ``corrupt`` (a miss on an unreadable file) to
    :data:`STATS_FILE` in the folder; :meth:`stats` counts them.  ``last_hit`` is whether this
    object's latest call in this process was a replay (for :class:`jaxabc.executors.progress.ProgressLog`).
    """

    def __init__(
        self,
        simulate: Callable[[Any, Any], Any],
        folder: str | os.PathLike,
        identity: Any = None,
        *,
        prefix: str = "",
    ) -> None:
        if not callable(simulate):
            raise TypeError(f"simulate must be callable, got {type(simulate).__name__}")
        if os.sep in prefix or (os.altsep and os.altsep in prefix):
            raise ValueError(f"prefix must not contain a path separator, got {prefix!r}")
        self.simulate = simulate
        self.folder = str(Path(folder).resolve())
        self.identity = _default_identity(simulate) if identity is None else identity
        self._identity = _identity_bytes(self.identity)  # refuses a non-JSON identity now, not in a worker
        self.prefix = prefix
        # describe_callable follows __wrapped__: checkpoints fingerprint the inner simulator.
        self.__wrapped__ = simulate
        self.last_hit: bool | None = None
        Path(self.folder).mkdir(parents=True, exist_ok=True)

    def __repr__(self) -> str:
        return f"RunCache({self.simulate!r}, {self.folder!r})"

    def path(self, key: Any, theta: Any) -> Path:
        """The cache file of one simulation (whether or not it exists)."""
        digest = _digest(self._identity, key, theta)
        return Path(self.folder) / f"{self.prefix}{digest[:_NAME_DIGITS]}{CACHE_SUFFIX}"

    def _load(self, path: Path) -> tuple[np.ndarray, str] | None:
        """``(summaries, reason)`` stored at ``path``; None when absent or unreadable."""
        try:
            with np.load(path, allow_pickle=False) as stored:
                return np.array(stored["summaries"]), str(stored["reason"])
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            warnings.warn(
                f"RunCache: {path} cannot be read ({type(exc).__name__}: {exc}); running the simulation "
                "again and replacing it",
                RunCacheWarning,
                stacklevel=3,
            )
            self._event("corrupt")
            return None

    def _store(self, path: Path, summaries: np.ndarray, reason: str, key: Any, theta: Any, wall_s: float) -> None:
        """Write then rename: no reader ever sees a half-written file under a cache name."""
        Path(self.folder).mkdir(parents=True, exist_ok=True)  # removed since, or another node
        fd, partial = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".tmp", dir=self.folder)
        try:
            with os.fdopen(fd, "wb") as out:
                np.savez(
                    out,
                    summaries=summaries,
                    reason=np.array(reason),
                    key=_key_data(key),
                    theta=np.asarray(theta, dtype=np.float64),
                    wall_s=np.float64(wall_s),
                )
                out.flush()
                os.fsync(out.fileno())  # a crash after the rename must not leave an empty file
            os.replace(partial, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(partial)
            raise

    def _event(self, word: str) -> None:
        _append_line(Path(self.folder) / STATS_FILE, word)

    def __call__(self, key: Any, theta: Any) -> Any:
        """The summaries of ``simulate(key, theta)``, replayed when cached.

        Returns
        -------
        np.ndarray
            On a hit, the stored summaries (a NumPy array of the dtype and shape first
            returned); on a miss, what ``simulate`` returned, unchanged.

        Raises
        ------
        jaxabc.SimulationFailure
            The simulation failed, now or when it was cached (same reason).
        Exception
            Anything else ``simulate`` raised (not cached).
        """
        path = self.path(key, theta)
        stored = self._load(path)
        if stored is not None:
            self.last_hit = True
            self._event("hit")
            summaries, reason = stored
            if reason:
                raise SimulationFailure(reason)
            return summaries
        self.last_hit = False
        self._event("miss")
        start = time.perf_counter()
        try:
            out = self.simulate(key, theta)
        except SimulationFailure as failure:
            # An empty message would read as success: keep the type's name as the reason.
            reason = str(failure) or type(failure).__name__
            self._store(path, np.zeros(0), reason, key, theta, time.perf_counter() - start)
            raise
        self._store(path, np.asarray(out), "", key, theta, time.perf_counter() - start)
        return out

    def counts(self) -> dict[str, int]:
        """:meth:`stats` of this cache's folder."""
        return self.stats(self.folder)

    @staticmethod
    def stats(folder: str | os.PathLike) -> dict[str, int]:
        """Hits, misses and entries of a cache folder, over every process and sitting that used it.

        Returns
        -------
        dict
            ``hits``, ``misses`` (calls that ran the simulator), ``corrupt`` (of those misses,
            how many found an unreadable file), ``entries`` (cache files now in the folder,
            whatever their identity).  Zeros for a folder that does not exist.
        """
        folder = Path(folder)
        counts = dict.fromkeys(_EVENTS, 0)
        with contextlib.suppress(FileNotFoundError):
            for word in (folder / STATS_FILE).read_text().split():
                if word in counts:
                    counts[word] += 1
        # Temporaries start with a dot and end in .tmp: not entries.
        entries = sum(1 for p in folder.glob(f"*{CACHE_SUFFIX}") if not p.name.startswith("."))
        return {"hits": counts["hit"], "misses": counts["miss"], "corrupt": counts["corrupt"], "entries": entries}

    @staticmethod
    def remove_temporaries(folder: str | os.PathLike, older_than_s: float = 86400.0) -> list[Path]:
        """Delete the temporary files writers killed mid-write left in ``folder``.

        Only files older than ``older_than_s`` go, so a write in progress elsewhere is spared.
        Returns the paths removed.
        """
        now, removed = time.time(), []
        for partial in Path(folder).glob(".*.tmp"):
            with contextlib.suppress(OSError):
                if now - partial.stat().st_mtime > older_than_s:
                    partial.unlink()
                    removed.append(partial)
        return removed
