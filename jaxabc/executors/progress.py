"""Progress of long runs: a line per finished simulation, and wall time over several sittings.

The executors report a batch only once all of it is done; with simulations of minutes and
batches of hundreds, the driver's bar stands still for an hour.  :class:`ProgressLog` wraps the
simulator so that whichever worker process (or MPI rank) ran a simulation appends one JSON line
for it to a file; :func:`summarise_progress` reads that file (count, failures, rate, ETA) and
:class:`ProgressMonitor` shows it as a live bar.  :class:`SittingClock` adds up a run's wall time
over the sittings of a run that is stopped and resumed.

Usage::

    from jaxabc.executors.progress import ProgressLog, ProgressMonitor, SittingClock

    logged = ProgressLog(simulate, "runs/water")
    with SittingClock("runs/water/sittings.json") as clock, ProgressMonitor(logged.path, total=500):
        result = jaxabc.run("apmcabc", logged, prior, observed, ..., executor="process_pool")
    print(clock.total_seconds())
"""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from jaxabc.errors import SimulationFailure

__all__ = [
    "PROGRESS_FILE",
    "ProgressLog",
    "ProgressMonitor",
    "SittingClock",
    "read_progress",
    "summarise_progress",
]

#: Default name of the progress file in its folder (JSON lines).
PROGRESS_FILE = "progress.jsonl"
#: Characters of a failure reason kept in a progress line: one line must stay one short write.
_REASON_CHARS = 200


def _append_line(path: str | os.PathLike, line: str) -> bool:
    """Append ``line`` with one ``write`` on an ``O_APPEND`` descriptor; False on an ``OSError``.

    On a local file system the kernel positions and writes each such call as a whole, so lines
    from concurrent processes never interleave (on NFS, ``O_APPEND`` is not atomic across hosts).
    """
    data = (line + "\n").encode()
    try:
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    except OSError:
        return False
    try:
        return os.write(fd, data) == len(data)
    except OSError:
        return False
    finally:
        os.close(fd)


class ProgressLog:
    """``simulate(key, theta)`` that appends a JSON line to a progress file after every call.

    Keys, parameters, results and exceptions pass through unchanged; the line is written after
    the simulation, whether it succeeded or raised.  Picklable when ``simulate`` is.

    Parameters
    ----------
    simulate : callable ``(key, theta) -> summaries``
    folder : str or path-like
        Where the progress file goes; created if missing.  Kept as an absolute path, so workers
        with another working directory write to the same file.
    filename : str
        The progress file's name in ``folder``.

    Notes
    -----
    Each line is a JSON object: ``time`` (UNIX seconds at the end of the call), ``theta`` (list
    of floats), ``status`` (``"ok"``; ``"nonfinite"``: summaries with NaN or inf;
    ``"failed"``: :class:`jaxabc.SimulationFailure`; ``"error"``: any other exception, e.g. a
    timeout), ``wall_s`` (seconds the call took), ``pid`` (the worker process), ``reason``
    (failures only, at most 200 characters) and ``replayed`` (when ``simulate`` is a
    :class:`jaxabc.executors.cache.RunCache`: whether the call was a replay).

    Each line goes out in one ``write`` on an ``O_APPEND`` descriptor, so lines from concurrent
    workers on one machine (or MPI ranks writing to a local disk) do not interleave.  A worker
    killed in the middle of that write may leave a torn last line, which the readers skip.  A
    file that cannot be written never fails a simulation: progress is a nicety.

    A run that is checkpointed sees the wrapped simulator's identity (``__wrapped__``), so
    adding or removing the log does not invalidate a checkpoint.
    """

    def __init__(self, simulate: Callable[[Any, Any], Any], folder: str | os.PathLike, filename: str = PROGRESS_FILE):
        if not callable(simulate):
            raise TypeError(f"simulate must be callable, got {type(simulate).__name__}")
        self.simulate = simulate
        self.path = str(Path(folder).resolve() / filename)
        self.__wrapped__ = simulate  # describe_callable follows it: checkpoints see the simulator
        Path(self.path).parent.mkdir(parents=True, exist_ok=True)

    def __repr__(self) -> str:
        return f"ProgressLog({self.simulate!r}, {self.path!r})"

    def _log(self, theta: Any, status: str, wall_s: float, reason: str = "") -> None:
        entry: dict[str, Any] = {
            "time": time.time(),
            "theta": np.asarray(theta, dtype=np.float64).reshape(-1).tolist(),
            "status": status,
            "wall_s": wall_s,
            "pid": os.getpid(),
        }
        if reason:
            entry["reason"] = reason[:_REASON_CHARS]
        replayed = getattr(self.simulate, "last_hit", None)
        if isinstance(replayed, bool):
            entry["replayed"] = replayed
        # allow_nan: a NaN theta must still give a line (Python's json reads NaN back).
        _append_line(self.path, json.dumps(entry, separators=(",", ":")))

    def __call__(self, key: Any, theta: Any) -> Any:
        start = time.perf_counter()
        try:
            out = self.simulate(key, theta)
        except SimulationFailure as failure:
            self._log(theta, "failed", time.perf_counter() - start, str(failure) or type(failure).__name__)
            raise
        except BaseException as exc:
            self._log(theta, "error", time.perf_counter() - start, f"{type(exc).__name__}: {exc}")
            raise
        wall_s = time.perf_counter() - start
        try:
            finite = bool(np.all(np.isfinite(np.asarray(out, dtype=np.float64))))
        except (TypeError, ValueError):  # not numbers: the executor will say so
            finite = False
        self._log(theta, "ok" if finite else "nonfinite", wall_s)
        return out


def read_progress(path: str | os.PathLike) -> list[dict[str, Any]]:
    """The entries of a progress file, in file order; torn or malformed lines are skipped.

    A missing file reads as no entries.
    """
    try:
        text = Path(path).read_text()
    except FileNotFoundError:
        return []
    entries = []
    for line in text.splitlines():
        try:
            entry = json.loads(line)
        except ValueError:  # a line torn by a worker killed mid-write
            continue
        if isinstance(entry, dict) and "status" in entry and "time" in entry:
            entries.append(entry)
    return entries


def summarise_progress(path: str | os.PathLike, budget: int | None = None, now: float | None = None) -> dict[str, Any]:
    """Count, failures, rate and ETA of the simulations in a progress file.

    Parameters
    ----------
    path : str or path-like
        A file written by :class:`ProgressLog`.
    budget : int, optional
        Simulations planned in all; gives ``remaining`` and ``eta_s``.
    now : float, optional
        UNIX time the rate is measured up to (default: the time of the last line).

    Returns
    -------
    dict
        ``count`` (lines), ``ok``, ``failures`` (every status but ``"ok"``), ``replayed``,
        ``workers`` (distinct pids), ``mean_wall_s`` (of the simulations actually run, NaN when
        none), ``elapsed_s`` (from the start of the first simulation to ``now``),
        ``rate_per_minute`` (finished simulations per minute over ``elapsed_s``, all workers
        together; NaN before any), and, with ``budget``, ``remaining`` and ``eta_s`` (seconds at
        the rate so far; NaN without a rate, 0 once the budget is reached).

    Notes
    -----
    Replays count at the rate they came, so an ETA right after a resumed run replayed its cache
    is optimistic until new simulations dominate the file.
    """
    entries = read_progress(path)
    count = len(entries)
    ok = sum(e["status"] == "ok" for e in entries)
    replayed = sum(bool(e.get("replayed")) for e in entries)
    run_walls = [float(e.get("wall_s", 0.0)) for e in entries if not e.get("replayed")]
    summary: dict[str, Any] = {
        "count": count,
        "ok": ok,
        "failures": count - ok,
        "replayed": replayed,
        "workers": len({e.get("pid") for e in entries}),
        "mean_wall_s": float(np.mean(run_walls)) if run_walls else float("nan"),
        "elapsed_s": 0.0,
        "rate_per_minute": float("nan"),
    }
    if entries:
        # The first simulation started wall_s before its line was written.
        first = min(float(e["time"]) - float(e.get("wall_s", 0.0)) for e in entries)
        end = max(float(e["time"]) for e in entries) if now is None else float(now)
        summary["elapsed_s"] = max(end - first, 0.0)
        if summary["elapsed_s"] > 0:
            summary["rate_per_minute"] = 60.0 * count / summary["elapsed_s"]
    if budget is not None:
        remaining = max(int(budget) - count, 0)
        rate = summary["rate_per_minute"]
        summary["remaining"] = remaining
        summary["eta_s"] = 0.0 if remaining == 0 else (60.0 * remaining / rate if rate > 0 else float("nan"))
    return summary


class ProgressMonitor:
    """A thread that shows a progress file as a bar (count, failures, rate, ETA) while a run goes.

    Parameters
    ----------
    path : str or path-like
        The progress file (:attr:`ProgressLog.path`).
    total : int
        Simulations expected (e.g. the budget); the bar's ETA assumes the rate so far.
    description : str
    interval_s : float
        Seconds between reads of the file.
    fresh : bool
        Empty the file on start, so that the bar counts this sitting only (default).  With
        False it continues from the lines already there.

    Use as a context manager around the run.  ``done`` and ``failed`` hold the last counts.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        total: int,
        description: str = "simulations",
        interval_s: float = 1.0,
        fresh: bool = True,
    ) -> None:
        self.path = Path(path)
        self.total = int(total)
        self.description = description
        self.interval_s = float(interval_s)
        self.fresh = fresh
        self.done = 0
        self.failed = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _watch(self) -> None:
        from tqdm.auto import tqdm

        # position=1: below the driver's own per-iteration bar.
        with tqdm(total=self.total, desc=self.description, unit="sim", position=1, smoothing=0.0) as bar:
            while True:
                stopping = self._stop.wait(self.interval_s)
                summary = summarise_progress(self.path, now=time.time())
                self.done, self.failed = summary["count"], summary["failures"]
                if self.done > bar.n:
                    bar.update(self.done - bar.n)
                bar.set_postfix(failed=self.failed)
                if stopping:
                    return

    def __enter__(self) -> ProgressMonitor:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.fresh:
            self.path.write_text("")
        self._thread = threading.Thread(target=self._watch, name="simulation-progress", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)


def _utc(seconds: float) -> str:
    return datetime.datetime.fromtimestamp(seconds, datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


class SittingClock:
    """Wall time of a run that spans several sittings, kept in a JSON file.

    Each sitting (one ``with`` block, or :meth:`start` to :meth:`stop`) is one entry of the
    file; :meth:`total_seconds` adds them up.  A heartbeat thread rewrites the open sitting's
    entry every ``heartbeat_s`` seconds.

    Parameters
    ----------
    path : str or path-like
        The JSON file; created (with its folder) on the first start.
    heartbeat_s : float
        Seconds between rewrites of the open sitting; a crash loses at most this much.
    fresh : bool
        Forget the sittings already in the file (a run started over) on the first start.

    Notes
    -----
    Crash handling: a sitting left open by a killed process (``"open": true`` in the file) is
    closed, on the next start, *at its last heartbeat*: it counts the elapsed seconds its last
    write recorded, not the time until the file's modification time or until now (the time
    between the crash and the restart was no sitting).  So a killed sitting is undercounted by
    less than ``heartbeat_s``.

    Durations come from ``time.monotonic`` within a sitting, so a change of the system clock
    does not bend them; the UNIX times in the file are for people.  One process at a time may
    hold a clock on a file (a second would close the first's open sitting as crashed).

    Raises
    ------
    ValueError
        From the constructor or :meth:`start`, when the file exists but is not a sitting clock's JSON.
    """

    def __init__(self, path: str | os.PathLike, heartbeat_s: float = 30.0, fresh: bool = False) -> None:
        if heartbeat_s <= 0:
            raise ValueError(f"heartbeat_s must be positive, got {heartbeat_s}")
        self.path = Path(path)
        self.heartbeat_s = float(heartbeat_s)
        self.fresh = fresh
        self.sittings: list[dict[str, Any]] = self._read() if self.path.exists() else []
        self._started: float | None = None  # time.monotonic() of the open sitting's start
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _read(self) -> list[dict[str, Any]]:
        try:
            sittings = json.loads(self.path.read_text())["sittings"]
            if not isinstance(sittings, list) or not all("elapsed_s" in s for s in sittings):
                raise TypeError("sittings must be a list of entries with elapsed_s")
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{self.path} is not a SittingClock file ({exc})") from exc
        return sittings

    def _write(self) -> None:
        """Atomically (temp file + rename): a crash mid-write keeps the previous version."""
        with self._lock:
            if self._started is not None:
                now = time.time()
                self.sittings[-1]["elapsed_s"] = time.monotonic() - self._started
                self.sittings[-1]["last_unix"] = now
                self.sittings[-1]["last_utc"] = _utc(now)
            self.path.parent.mkdir(parents=True, exist_ok=True)
            partial = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
            partial.write_text(json.dumps({"sittings": self.sittings}, indent=1))
            os.replace(partial, self.path)

    def _beat(self) -> None:
        while not self._stop.wait(self.heartbeat_s):
            with contextlib.suppress(OSError):  # a full disk must not stop the run
                self._write()

    def start(self) -> SittingClock:
        """Open a sitting (closing, at their last heartbeat, any a crashed process left open)."""
        if self._started is not None:
            raise RuntimeError("this SittingClock already has an open sitting")
        self.sittings = [] if self.fresh else (self._read() if self.path.exists() else [])
        self.fresh = False  # a later start in this process continues
        for sitting in self.sittings:
            if sitting.get("open"):
                sitting["open"] = False
                sitting["closed"] = "at last heartbeat (the process ended without closing it)"
        now = time.time()
        self.sittings.append(
            {
                "started_unix": now,
                "started_utc": _utc(now),
                "elapsed_s": 0.0,
                "open": True,
                "pid": os.getpid(),
            }
        )
        self._started = time.monotonic()
        self._write()
        self._stop.clear()
        self._thread = threading.Thread(target=self._beat, name="sitting-clock", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> float:
        """Close the open sitting and write the file; returns :meth:`total_seconds`."""
        if self._started is None:
            raise RuntimeError("this SittingClock has no open sitting")
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
        self._write()  # the final elapsed time, before the sitting is marked closed
        with self._lock:
            self._started = None
            self.sittings[-1]["open"] = False
            self.sittings[-1]["closed"] = "stopped"
        self._write()
        return self.total_seconds()

    def __enter__(self) -> SittingClock:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def total_seconds(self) -> float:
        """Seconds over every sitting, the open one up to now."""
        with self._lock:
            closed = self.sittings[:-1] if self._started is not None else self.sittings
            total = sum(float(s["elapsed_s"]) for s in closed)
            if self._started is not None:
                total += time.monotonic() - self._started
        return total

    @property
    def num_sittings(self) -> int:
        """Sittings so far, the open one included."""
        return len(self.sittings)

    @staticmethod
    def read_total(path: str | os.PathLike) -> float:
        """Seconds recorded in a clock file without starting a sitting (an open one counts up to
        its last heartbeat); 0.0 when the file does not exist."""
        path = Path(path)
        if not path.exists():
            return 0.0
        return sum(float(s["elapsed_s"]) for s in SittingClock(path)._read())
