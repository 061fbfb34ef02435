"""The water calibration script's multi-sitting support: the run cache, progress and the sitting clock.

The script composes jaxabc's :class:`~jaxabc.executors.cache.RunCache`,
:class:`~jaxabc.executors.progress.ProgressLog` and :class:`~jaxabc.executors.progress.SittingClock`
(``logged_simulator``, ``run_cache_identity``, ``sitting_clock``); these tests check the
behaviour the script relies on through those functions.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time

import numpy as np
import pytest

from benchmarks import water_calibration as wc
from jaxabc.checkpoint import describe_callable
from jaxabc.errors import SimulationFailure
from jaxabc.executors.progress import SittingClock, read_progress


class _Simulator:
    """Two summaries from theta; vapour (a SimulationFailure) for theta[0] < 0, a crash for > 9."""

    protocol = "protocol-a"

    def __init__(self) -> None:
        self.calls = 0

    def __repr__(self) -> str:
        return "stand-in"

    def __call__(self, key, theta):
        self.calls += 1
        if theta[0] < 0:
            raise SimulationFailure("vapour")
        if theta[0] > 9:
            raise RuntimeError("killed")
        return np.array([theta[0], float(key[1])])


def test_the_run_cache_replays_runs_and_failures_but_not_crashes(tmp_path):
    inner = _Simulator()
    progress = tmp_path / ".run.progress"
    counted = wc.logged_simulator(inner, progress, tmp_path / "runs")
    assert describe_callable(counted) == describe_callable(inner)  # checkpoints see the simulator
    key = np.array([0, 5], np.uint32)
    first = counted(key, np.array([0.5, 1.0]))
    np.testing.assert_array_equal(first, [0.5, 5.0])
    with pytest.raises(SimulationFailure, match="vapour"):
        counted(key, np.array([-1.0, 1.0]))
    with pytest.raises(RuntimeError, match="killed"):
        counted(key, np.array([10.0, 1.0]))
    assert inner.calls == 3
    # A new wrapper on the same folder (the next sitting) replays what finished.
    again = wc.logged_simulator(inner, progress, tmp_path / "runs")
    np.testing.assert_array_equal(again(key, np.array([0.5, 1.0])), first)
    with pytest.raises(SimulationFailure, match="vapour"):
        again(key, np.array([-1.0, 1.0]))
    assert inner.calls == 3
    with pytest.raises(RuntimeError):  # a crash says nothing about (key, theta): run again
        again(key, np.array([10.0, 1.0]))
    assert inner.calls == 4
    # Another key or protocol is another simulation.
    again(np.array([0, 6], np.uint32), np.array([0.5, 1.0]))
    inner.protocol = "protocol-b"
    wc.logged_simulator(inner, progress, tmp_path / "runs")(key, np.array([0.5, 1.0]))
    assert inner.calls == 6
    # One progress line per call, replays included (the bar counts them), in call order.
    lines = read_progress(progress)
    assert [e["status"] for e in lines] == ["ok", "failed", "error", "ok", "failed", "error", "ok", "ok"]
    assert [e["replayed"] for e in lines] == [False, False, False, True, True, False, False, False]
    assert lines[1]["reason"] == "vapour"
    # Without a cache every call simulates, and is still logged.
    plain = wc.logged_simulator(inner, progress)
    plain(key, np.array([0.5, 1.0]))
    plain(key, np.array([0.5, 1.0]))
    assert inner.calls == 8
    assert len(read_progress(progress)) == 10


def test_runs_of_other_simulator_code_are_not_replayed(tmp_path, monkeypatch):
    inner = _Simulator()
    key, theta = np.array([0, 5], np.uint32), np.array([0.5, 1.0])
    wc.logged_simulator(inner, tmp_path / ".p.progress", tmp_path / "runs")(key, theta)
    identity = wc.run_cache_identity(inner)
    assert "md/water/gromacs.py" in identity and "protocol-a" in identity
    monkeypatch.setattr(wc, "code_hash", lambda path: "edited")  # every md/water module changed
    assert wc.run_cache_identity(inner) != identity
    wc.logged_simulator(inner, tmp_path / ".p.progress", tmp_path / "runs")(key, theta)
    assert inner.calls == 2


def test_a_run_cache_written_before_the_move_to_runcache_is_replayed(tmp_path):
    """The script's own cache (before jaxabc's RunCache) named files by the SHA-256 of (identity
    string, key as uint32, theta as float64) and stored ``summaries`` and ``reason``."""
    inner = _Simulator()
    key = np.array([0, 5], np.uint32)
    folder = tmp_path / "runs"
    folder.mkdir()
    for theta, summaries, reason in (([0.5, 1.0], np.array([7.0, 8.0]), ""), ([-1.0, 1.0], np.zeros(0), "vapour")):
        digest = hashlib.sha256(wc.run_cache_identity(inner).encode())
        digest.update(key.tobytes())
        digest.update(np.asarray(theta, np.float64).tobytes())
        np.savez(folder / f"{digest.hexdigest()[:24]}.npz", summaries=summaries, reason=np.array(reason))
    counted = wc.logged_simulator(inner, tmp_path / ".p.progress", folder)
    np.testing.assert_array_equal(counted(key, np.array([0.5, 1.0])), [7.0, 8.0])
    with pytest.raises(SimulationFailure, match="vapour"):
        counted(key, np.array([-1.0, 1.0]))
    assert inner.calls == 0


def _clock(tmp_path, resuming: bool, run_cache=None, heartbeat_s: float = 30.0) -> SittingClock:
    """The clock of a run checkpointed to ``tmp_path/ckpt``, as ``main`` makes it."""
    args = argparse.Namespace(checkpoint_dir=tmp_path / "ckpt", run_cache=run_cache)
    clock = wc.sitting_clock(args, "run", resuming, heartbeat_s)
    assert clock is not None
    return clock


def test_the_sitting_clock_adds_sittings_and_keeps_a_killed_one(tmp_path):
    path = tmp_path / "ckpt" / "run.sittings.json"
    assert wc.sitting_clock(argparse.Namespace(checkpoint_dir=None, run_cache=None), "run", False) is None
    with _clock(tmp_path, resuming=False, heartbeat_s=0.05):
        time.sleep(0.2)
    first = json.loads(path.read_text())["sittings"]
    assert len(first) == 1 and first[0]["elapsed_s"] >= 0.2
    # A sitting killed without closing it still counts up to its last heartbeat.
    killed = _clock(tmp_path, resuming=True, heartbeat_s=0.05).start()
    time.sleep(0.3)
    killed._stop.set()  # the process dies: no more heartbeats, nobody closes the sitting
    assert killed._thread is not None
    killed._thread.join()
    second = json.loads(path.read_text())["sittings"]
    assert len(second) == 2 and second[1]["elapsed_s"] >= 0.2
    time.sleep(0.2)  # the time between the crash and the restart is no sitting
    with _clock(tmp_path, resuming=True) as clock:
        pass
    assert clock.num_sittings == 3
    stored = json.loads(path.read_text())["sittings"]
    assert stored[1]["elapsed_s"] == second[1]["elapsed_s"] and "heartbeat" in stored[1]["closed"]
    # What the script writes as wall_time_s.
    assert clock.total_seconds() == pytest.approx(sum(s["elapsed_s"] for s in stored))
    assert 0.4 <= clock.total_seconds() < 0.4 + 1.0
    # A run started over, but with a run cache holding runs, keeps its sittings (they paid for
    # the runs it replays) ...
    runs = tmp_path / "runs"
    wc.logged_simulator(_Simulator(), tmp_path / ".p.progress", runs)(np.array([0, 1], np.uint32), np.ones(2))
    with _clock(tmp_path, resuming=False, run_cache=runs) as clock:
        pass
    assert clock.num_sittings == 4
    # ... and without one it forgets the earlier sittings.
    with _clock(tmp_path, resuming=False, run_cache=tmp_path / "empty") as clock:
        pass
    assert clock.num_sittings == 1 and len(json.loads(path.read_text())["sittings"]) == 1


def test_a_sittings_file_of_the_scripts_old_clock_is_continued(tmp_path):
    path = tmp_path / "ckpt" / "run.sittings.json"
    path.parent.mkdir()
    # The old clock wrote a start and the seconds so far, with no "open" flag (a killed sitting
    # looks like a closed one).
    old = [{"started_utc": f"2026-01-0{day}T00:00:00Z", "elapsed_s": s} for day, s in ((1, 100.0), (2, 50.0))]
    path.write_text(json.dumps({"sittings": old}))
    with _clock(tmp_path, resuming=True) as clock:
        pass
    assert clock.num_sittings == 3
    assert 150.0 <= clock.total_seconds() < 151.0


def test_resuming_checkpoints_of_other_code_is_refused(tmp_path):
    from benchmarks import _common

    _common.guard_resume(tmp_path, resuming=True)  # nothing to resume yet: no refusal
    _common.guard_resume(tmp_path, resuming=False, modules=("jaxabc.surrogate",))
    (tmp_path / "model_a").mkdir()
    (tmp_path / "model_a" / "checkpoint.npz").write_bytes(b"")
    stamp = json.loads((tmp_path / _common.CODE_STAMP).read_text())["files"]
    assert "jaxabc/surrogate/design.py" in stamp  # lazily imported modules are stamped too
    _common.guard_resume(tmp_path, resuming=True)  # the same code
    stamp["jaxabc/surrogate/design.py"] = "0" * 16
    (tmp_path / _common.CODE_STAMP).write_text(json.dumps({"files": stamp}))
    with pytest.raises(SystemExit, match=r"jaxabc/surrogate/design\.py"):
        _common.guard_resume(tmp_path, resuming=True)
    (tmp_path / _common.CODE_STAMP).unlink()
    with pytest.raises(SystemExit, match="without a code stamp"):
        _common.guard_resume(tmp_path, resuming=True)
