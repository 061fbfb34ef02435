"""RunCache replays identical simulations; ProgressLog and SittingClock track long runs.

The simulators here are host (NumPy) simulators of module-level classes, so that they travel to
spawned worker processes; each call appends a line to a counter file, which counts calls made in
any process.
"""

from __future__ import annotations

import json
import os
import pickle
import time
import warnings
from collections.abc import Iterator
from pathlib import Path

import jax
import numpy as np
import pytest

import jaxabc
from jaxabc.errors import STATUS_FAILED, STATUS_OK, SimulationFailure
from jaxabc.executors.cache import RunCache, RunCacheWarning, run_digest, source_digest
from jaxabc.executors.progress import ProgressLog, SittingClock, read_progress, summarise_progress


class CountingSim:
    """``theta + shift + N(0, 1)`` with the noise seeded by the raw key; counts calls in a file.

    ``theta[0] < fail_below`` raises :class:`SimulationFailure`; ``theta[0] > crash_above``
    raises ``RuntimeError`` (a crash, which the cache must not store).
    """

    def __init__(self, counter: Path, shift: float = 0.0, fail_below: float = -np.inf, crash_above: float = np.inf):
        self.counter = str(counter)
        self.shift = shift
        self.fail_below = fail_below
        self.crash_above = crash_above

    def __call__(self, key, theta):
        fd = os.open(self.counter, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, b"call\n")
        finally:
            os.close(fd)
        theta = np.asarray(theta, dtype=np.float64)
        if theta[0] < self.fail_below:
            raise SimulationFailure(f"theta[0] = {theta[0]:.4f} is below {self.fail_below}: the box vaporised")
        if theta[0] > self.crash_above:
            raise RuntimeError("segfault-like crash")
        rng = np.random.default_rng(np.asarray(key, dtype=np.uint32).tolist())
        return theta + self.shift + rng.normal(size=theta.shape)


def calls(counter: Path) -> int:
    return len(counter.read_text().split()) if counter.exists() else 0


def raw_keys(m: int, seed: int = 0) -> np.ndarray:
    return np.asarray(jax.random.key_data(jax.random.split(jax.random.key(seed), m)))


@pytest.fixture(scope="module")
def pool() -> Iterator[jaxabc.ProcessPoolExecutor]:
    """One two-worker pool for the module: worker start-up (JAX imports) is paid once."""
    ex = jaxabc.ProcessPoolExecutor(max_workers=2)
    yield ex
    ex.close()


# ----------------------------------------------------------------------------- RunCache


def test_each_distinct_simulation_runs_once_and_replays_identically(tmp_path: Path) -> None:
    counter = tmp_path / "calls"
    cache = RunCache(CountingSim(counter), tmp_path / "cache")
    keys, thetas = raw_keys(3), np.array([[0.1, 1.0], [0.2, 2.0], [0.3, 3.0]], np.float32)
    first = [cache(k, t) for k, t in zip(keys, thetas, strict=True)]
    assert calls(counter) == 3 and cache.last_hit is False
    second = [cache(k, t) for k, t in zip(keys, thetas, strict=True)]
    assert calls(counter) == 3 and cache.last_hit is True
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a, b)
        assert a.dtype == b.dtype and a.shape == b.shape
    # A typed JAX key and a float64 theta name the same simulation as raw key data and float32.
    typed = jax.random.wrap_key_data(keys[0])
    np.testing.assert_array_equal(cache(typed, thetas[0].astype(np.float64)), first[0])
    assert cache.path(typed, thetas[0]) == cache.path(keys[0], thetas[0].astype(np.float64))
    assert calls(counter) == 3
    # Another theta or key is another simulation.
    cache(keys[0], thetas[1])
    assert calls(counter) == 4
    assert RunCache.stats(tmp_path / "cache") == {"hits": 4, "misses": 4, "corrupt": 0, "entries": 4}
    assert cache.counts() == RunCache.stats(cache.folder)


def test_another_identity_is_a_miss(tmp_path: Path) -> None:
    counter, folder = tmp_path / "calls", tmp_path / "cache"
    key, theta = raw_keys(1)[0], np.array([0.5])
    RunCache(CountingSim(counter), folder, identity="model v1")(key, theta)
    RunCache(CountingSim(counter), folder, identity="model v1")(key, theta)
    assert calls(counter) == 1
    RunCache(CountingSim(counter), folder, identity="model v2")(key, theta)
    assert calls(counter) == 2
    # The default identity (describe_callable) sees the simulator's attributes.
    RunCache(CountingSim(counter, shift=0.0), folder)(key, theta)
    RunCache(CountingSim(counter, shift=0.0), folder)(key, theta)
    assert calls(counter) == 3
    out = RunCache(CountingSim(counter, shift=1.0), folder)(key, theta)
    assert calls(counter) == 4
    np.testing.assert_allclose(out, CountingSim(tmp_path / "other", shift=1.0)(key, theta))
    # A JSON identity hashes independently of dict order.
    assert run_digest({"a": 1, "b": [2]}, key, theta) == run_digest({"b": [2], "a": 1}, key, theta)


def test_identity_is_required_when_the_simulator_cannot_be_described(tmp_path: Path) -> None:
    class NoAttributes:
        __slots__ = ()

        def __call__(self, key, theta):
            return theta

    with pytest.raises(ValueError, match="identity="):
        RunCache(NoAttributes(), tmp_path)
    RunCache(NoAttributes(), tmp_path, identity="no-attributes v1")  # accepted with one
    with pytest.raises(TypeError, match="JSON"):
        RunCache(NoAttributes(), tmp_path, identity={"x": object()})


def test_a_failure_replays_as_the_same_failure_and_a_crash_is_not_stored(tmp_path: Path) -> None:
    counter = tmp_path / "calls"
    cache = RunCache(CountingSim(counter, fail_below=0.0, crash_above=10.0), tmp_path / "cache")
    key = raw_keys(1)[0]
    with pytest.raises(SimulationFailure) as first:
        cache(key, np.array([-1.0]))
    with pytest.raises(SimulationFailure) as replay:
        cache(key, np.array([-1.0]))
    assert str(replay.value) == str(first.value) and "vaporised" in str(first.value)
    assert calls(counter) == 1
    for _ in range(2):
        with pytest.raises(RuntimeError, match="crash"):
            cache(key, np.array([11.0]))
    assert calls(counter) == 3  # tried again: a crash is not a property of (key, theta)


def test_a_corrupt_file_is_a_miss_with_a_warning_and_is_replaced(tmp_path: Path) -> None:
    counter = tmp_path / "calls"
    cache = RunCache(CountingSim(counter), tmp_path / "cache")
    key, theta = raw_keys(1)[0], np.array([0.25, -0.5])
    expected = cache(key, theta)
    path = cache.path(key, theta)
    path.write_bytes(path.read_bytes()[:40])  # truncated, as by a full disk
    with pytest.warns(RunCacheWarning, match="cannot be read"):
        again = cache(key, theta)
    np.testing.assert_array_equal(again, expected)
    assert calls(counter) == 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the replaced file reads cleanly
        np.testing.assert_array_equal(cache(key, theta), expected)
    assert calls(counter) == 2
    assert RunCache.stats(cache.folder) == {"hits": 1, "misses": 2, "corrupt": 1, "entries": 1}
    assert not list(Path(cache.folder).glob(".*.tmp"))


def test_pickled_cache_in_a_process_pool_matches_serial_and_hits_on_rerun(
    tmp_path: Path, pool: jaxabc.ProcessPoolExecutor
) -> None:
    counter = tmp_path / "calls"
    cache = RunCache(CountingSim(counter, fail_below=-1.5), tmp_path / "cache")
    copy = pickle.loads(pickle.dumps(cache))
    keys, thetas = raw_keys(12, seed=5), np.linspace(-2.0, 2.0, 24).reshape(12, 2)
    assert copy.path(keys[0], thetas[0]) == cache.path(keys[0], thetas[0])

    serial = jaxabc.SerialExecutor().map(CountingSim(tmp_path / "serial-calls", fail_below=-1.5), keys, thetas)
    first = pool.map(cache, keys, thetas)
    assert calls(counter) == 12
    second = pool.map(cache, keys, thetas)
    assert calls(counter) == 12  # every task replayed, in whichever worker it landed
    for batch in (first, second):
        np.testing.assert_array_equal(batch.status, serial.status)
        assert batch.reasons == serial.reasons
        np.testing.assert_array_equal(batch.summaries, serial.summaries)
    assert (serial.status == STATUS_FAILED).sum() == 2 and (serial.status == STATUS_OK).sum() == 10
    assert RunCache.stats(cache.folder) == {"hits": 12, "misses": 12, "corrupt": 0, "entries": 12}


def test_a_rerun_with_the_same_seed_makes_no_new_simulations(tmp_path: Path, pool: jaxabc.ProcessPoolExecutor) -> None:
    counter = tmp_path / "calls"
    cached = RunCache(CountingSim(counter), tmp_path / "cache")
    options = dict(num_particles=20, num_steps=3, seed=3, executor=pool)
    prior = jaxabc.Uniform([-3.0], [3.0])
    first = jaxabc.run("pmcabc", cached, prior, np.array([0.5]), **options)
    made = calls(counter)
    assert made == first.num_simulations > 0
    second = jaxabc.run("pmcabc", cached, prior, np.array([0.5]), **options)
    assert calls(counter) == made  # zero new simulator calls
    np.testing.assert_array_equal(second.particles, first.particles)
    np.testing.assert_array_equal(second.weights, first.weights)
    assert RunCache.stats(cached.folder)["hits"] == second.num_simulations


def test_the_cache_does_not_change_the_checkpoint_identity(tmp_path: Path) -> None:
    from jaxabc.checkpoint import describe_callable

    sim = CountingSim(tmp_path / "calls")
    assert describe_callable(RunCache(sim, tmp_path / "cache")) == describe_callable(sim)
    assert describe_callable(ProgressLog(RunCache(sim, tmp_path / "cache"), tmp_path)) == describe_callable(sim)


def test_source_digest_follows_the_code(tmp_path: Path) -> None:
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "a.py").write_text("x = 1\n")
    before = source_digest(tmp_path / "pkg")
    (tmp_path / "pkg" / "notes.txt").write_text("not code")
    assert source_digest(tmp_path / "pkg") == before
    (tmp_path / "pkg" / "a.py").write_text("x = 2\n")
    assert source_digest(tmp_path / "pkg") != before
    with pytest.raises(FileNotFoundError):
        source_digest(tmp_path / "missing")


# ----------------------------------------------------------------------------- progress


def test_progress_lines_from_two_worker_processes_are_intact_json(
    tmp_path: Path, pool: jaxabc.ProcessPoolExecutor
) -> None:
    logged = ProgressLog(RunCache(CountingSim(tmp_path / "calls", fail_below=-0.9), tmp_path / "cache"), tmp_path)
    # Long theta vectors make long lines: a torn or interleaved write would show.
    m = 60
    keys, thetas = raw_keys(m, seed=9), np.linspace(-1.0, 1.0, m * 40).reshape(m, 40)
    batch = pool.map(logged, keys, thetas)
    pool.map(logged, keys, thetas)  # replays
    lines = Path(logged.path).read_text().splitlines()
    assert len(lines) == 2 * m
    entries = [json.loads(line) for line in lines]  # every line is whole JSON
    assert {e["status"] for e in entries} <= {"ok", "failed"}
    assert sum(e["status"] == "failed" for e in entries) == 2 * int((batch.status == STATUS_FAILED).sum()) > 0
    assert sum(e["replayed"] for e in entries) == m
    assert all(len(e["theta"]) == 40 and e["wall_s"] >= 0 for e in entries)
    assert 1 <= len({e["pid"] for e in entries}) <= 2 and os.getpid() not in {e["pid"] for e in entries}
    summary = summarise_progress(logged.path, budget=3 * m)
    assert summary["count"] == 2 * m and summary["replayed"] == m
    assert summary["failures"] == summary["count"] - summary["ok"]
    assert summary["remaining"] == m and summary["rate_per_minute"] > 0 and summary["eta_s"] > 0


def test_summary_skips_torn_lines_and_computes_rate_and_eta(tmp_path: Path) -> None:
    path = tmp_path / "progress.jsonl"
    lines = [
        {"time": 100.0, "theta": [0.1], "status": "ok", "wall_s": 10.0, "pid": 1},
        {"time": 110.0, "theta": [0.2], "status": "failed", "wall_s": 20.0, "pid": 2, "reason": "gas"},
        {"time": 130.0, "theta": [0.3], "status": "ok", "wall_s": 20.0, "pid": 1},
    ]
    path.write_text("".join(json.dumps(e) + "\n" for e in lines) + '{"time": 131.0, "the')
    assert len(read_progress(path)) == 3
    summary = summarise_progress(path, budget=7)
    # First start at 90 s, last end at 130 s: 3 in 40 s.
    assert summary["elapsed_s"] == 40.0 and summary["rate_per_minute"] == pytest.approx(4.5)
    assert summary["failures"] == 1 and summary["workers"] == 2
    assert summary["remaining"] == 4 and summary["eta_s"] == pytest.approx(4 * 40.0 / 3)
    assert summary["mean_wall_s"] == pytest.approx(50.0 / 3)
    empty = summarise_progress(tmp_path / "missing.jsonl", budget=5)
    assert empty["count"] == 0 and np.isnan(empty["rate_per_minute"]) and np.isnan(empty["eta_s"])


# ----------------------------------------------------------------------------- SittingClock


def test_sitting_clock_adds_up_two_sittings(tmp_path: Path) -> None:
    path = tmp_path / "run" / "sittings.json"
    with SittingClock(path) as clock:
        time.sleep(0.1)
    first = clock.total_seconds()
    assert 0.1 <= first < 5.0
    with SittingClock(path) as clock:
        time.sleep(0.1)
        assert clock.total_seconds() > first  # the open sitting counts up to now
    assert clock.num_sittings == 2
    assert first + 0.1 <= clock.total_seconds() < first + 5.0
    assert SittingClock.read_total(path) == pytest.approx(clock.total_seconds())
    stored = json.loads(path.read_text())["sittings"]
    assert [s["open"] for s in stored] == [False, False]
    with SittingClock(path, fresh=True) as clock:
        pass
    assert clock.num_sittings == 1 and clock.total_seconds() < first


def test_a_sitting_left_open_by_a_killed_process_counts_to_its_last_heartbeat(tmp_path: Path) -> None:
    path = tmp_path / "sittings.json"
    dead = SittingClock(path, heartbeat_s=0.05).start()
    time.sleep(0.3)
    # The process "dies": its heartbeat stops, nobody closes the sitting.
    dead._stop.set()
    dead._thread.join()
    stored = json.loads(path.read_text())["sittings"]
    assert stored[-1]["open"] is True and stored[-1]["elapsed_s"] >= 0.05  # heartbeats were written
    at_last_beat = stored[-1]["elapsed_s"]
    time.sleep(0.2)  # time between the crash and the restart is no sitting
    with SittingClock(path) as clock:
        pass
    sittings = json.loads(path.read_text())["sittings"]
    assert len(sittings) == 2 and not sittings[0]["open"] and "heartbeat" in sittings[0]["closed"]
    assert sittings[0]["elapsed_s"] == at_last_beat
    assert at_last_beat <= clock.total_seconds() < at_last_beat + 1.0


def test_sitting_clock_refuses_a_foreign_file(tmp_path: Path) -> None:
    path = tmp_path / "other.json"
    path.write_text('{"something": 1}')
    with pytest.raises(ValueError, match="not a SittingClock file"):
        SittingClock(path)
