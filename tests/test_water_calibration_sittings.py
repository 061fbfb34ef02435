"""The water calibration script's multi-sitting support: the run cache and the sitting clock."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from benchmarks import water_calibration as wc
from jaxabc.errors import SimulationFailure


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
    progress = tmp_path / "progress"
    counted = wc.CountingSimulator(inner, progress, tmp_path / "runs")
    key = np.array([0, 5], np.uint32)
    first = counted(key, np.array([0.5, 1.0]))
    with pytest.raises(SimulationFailure, match="vapour"):
        counted(key, np.array([-1.0, 1.0]))
    with pytest.raises(RuntimeError):
        counted(key, np.array([10.0, 1.0]))
    assert inner.calls == 3
    # A new wrapper on the same folder (the next sitting) replays what finished.
    again = wc.CountingSimulator(inner, progress, tmp_path / "runs")
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
    wc.CountingSimulator(inner, progress, tmp_path / "runs")(key, np.array([0.5, 1.0]))
    assert inner.calls == 6
    assert progress.read_text().split() == ["ok", "failed", "failed", "ok", "failed", "failed", "ok", "ok"]
    # Without a cache every call simulates.
    plain = wc.CountingSimulator(inner, progress)
    plain(key, np.array([0.5, 1.0]))
    plain(key, np.array([0.5, 1.0]))
    assert inner.calls == 8


def test_the_sitting_clock_adds_sittings_and_keeps_a_killed_one(tmp_path):
    path = tmp_path / "run.sittings.json"
    with wc.SittingClock(path, fresh=True, interval_s=0.05):
        time.sleep(0.2)
    first = json.loads(path.read_text())["sittings"]
    assert len(first) == 1 and first[0]["elapsed_s"] >= 0.2
    # A sitting killed without __exit__ still counts up to its last tick.
    killed = wc.SittingClock(path, fresh=False, interval_s=0.05)
    killed.__enter__()
    time.sleep(0.3)
    killed._stop.set()
    killed._thread.join()
    second = json.loads(path.read_text())["sittings"]
    assert len(second) == 2 and second[1]["elapsed_s"] >= 0.2
    with wc.SittingClock(path, fresh=False) as clock:
        pass
    assert len(clock.sittings) == 3
    assert clock.total_s == pytest.approx(sum(s["elapsed_s"] for s in clock.sittings), abs=0.05)
    assert clock.total_s >= 0.4
    # A run started over forgets the earlier sittings.
    with wc.SittingClock(path, fresh=True) as clock:
        pass
    assert len(json.loads(path.read_text())["sittings"]) == 1


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
