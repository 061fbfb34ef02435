"""Fault injection: every fault ends in a correct result or a clear error, with nothing lost.

Crashing, hanging and NaN-returning simulators, NaN distances, a driver killed with SIGKILL and
resumed, and a write interrupted half-way.
"""

import functools
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxabc
from jaxabc import checkpoint, examples
from jaxabc.errors import (
    STATUS_BAD_DISTANCE,
    STATUS_FAILED,
    STATUS_NONFINITE,
    STATUS_OK,
    SimulationFailure,
)

HERE = Path(__file__).parent


def crashing_simulate(key, theta):
    """x = theta + N(0, 1), but raises for theta < -6 and returns NaN for theta > 6."""
    t = float(theta[0])
    if t < -6:
        raise SimulationFailure(f"theta {t:.2f} < -6: the box vaporised")
    if t > 6:
        return np.full(1, np.nan)
    return examples.host_gaussian_simulate(key, theta)


def nan_beyond_three(observed, simulated):
    """|x - y|, but NaN when x > 3 (a distance undefined for part of the summary space)."""
    return jnp.where(simulated[0] > 3.0, jnp.nan, jnp.abs(simulated[0] - observed[0]))


def always_nan_distance(observed, simulated):
    return jnp.full((), jnp.nan) * simulated[0]


def test_crashing_and_nan_simulators_are_recorded_and_the_posterior_is_right():
    prior = jaxabc.Uniform([-10.0], [10.0])
    r = jaxabc.run(
        "apmcabc",
        crashing_simulate,
        prior,
        np.zeros(1),
        num_particles=200,
        num_steps=3,
        executor="serial",
        distance="euclidean",
        seed=0,
    )
    theta, status = r.records["theta"][:, 0], r.records["status"]
    assert len(theta) == r.num_simulations == 200 + 2 * 180  # every simulation recorded
    np.testing.assert_array_equal(status == STATUS_FAILED, theta < -6)
    np.testing.assert_array_equal(status == STATUS_NONFINITE, theta > 6)
    assert all("vaporised" in why for why, s in zip(r.records["reasons"], status, strict=True) if s == STATUS_FAILED)
    assert np.all(np.abs(r.particles) <= 6)
    var_exact = examples.gaussian_abc_variance(float(r.thresholds[-1]))
    assert abs(r.bayes_estimate()[0]) < 4 * np.sqrt(var_exact / r.effective_sample_size())


def test_nan_distances_are_failures_with_a_reason(gaussian_problem):
    prior, simulate, observed = gaussian_problem
    r = jaxabc.run(
        "apmcabc", simulate, prior, observed, num_particles=200, num_steps=3, distance=nan_beyond_three, seed=0
    )
    bad = r.records["status"] == STATUS_BAD_DISTANCE
    assert bad.sum() > 0 and np.all(np.isinf(r.records["distance"][bad]))
    np.testing.assert_array_equal(bad, r.records["summaries"][:, 0] > 3.0)
    assert "NaN" in r.records["reasons"][int(np.flatnonzero(bad)[0])]
    assert np.sum(r.records["status"] != STATUS_OK) == bad.sum()  # the only failures here
    with pytest.raises(jaxabc.TooManyFailures, match="all 200 simulations failed"):
        jaxabc.run(
            "apmcabc",
            simulate,
            prior,
            observed,
            num_particles=200,
            num_steps=3,
            distance=always_nan_distance,
            max_failure_fraction=1.0,
            seed=0,
        )


def test_every_simulation_failing_is_an_error_even_at_failure_fraction_one(gaussian_problem):
    prior, _, observed = gaussian_problem
    with pytest.raises(jaxabc.TooManyFailures, match="all 100 simulations failed"):
        jaxabc.run(
            "apmcabc",
            lambda key, theta: jnp.full((1,), jnp.nan),
            prior,
            observed,
            num_particles=100,
            num_steps=3,
            max_failure_fraction=1.0,
            seed=0,
        )


def test_hanging_simulator_is_stopped_by_the_pool_timeout():
    """flaky_simulate sleeps 60 s on [0.2, 0.25): every task times out after 1 s."""
    ex = jaxabc.ProcessPoolExecutor(max_workers=2, timeout=1.0)
    t0 = time.perf_counter()
    try:
        with pytest.raises(jaxabc.TooManyFailures, match="all 2 simulations failed") as err:
            jaxabc.run(
                "rejection",
                examples.flaky_simulate,
                jaxabc.Uniform([0.2], [0.25]),
                np.array([0.22]),
                num_particles=2,
                quantile=1.0,
                executor=ex,
                max_failure_fraction=1.0,
                seed=0,
            )
    finally:
        ex.close()
    assert "timeout" in str(err.value) and time.perf_counter() - t0 < 50


def _job(folder, mode, method="apmcabc"):
    return subprocess.Popen(
        [sys.executable, str(HERE / "_resume_job.py"), str(folder), mode, method],
        env={**os.environ, "PYTHONPATH": str(HERE.parent)},
    )


def _kill_at_iteration(job, ckpt: Path, first: int) -> int:
    """SIGKILL ``job`` once its checkpoint records iteration ``first`` or later."""
    deadline = time.time() + 300
    iteration = 0
    while time.time() < deadline:
        if ckpt.exists():
            # Written atomically: a reader never sees a half-written file.
            iteration = checkpoint.load(ckpt).counters["iteration"]
            if iteration >= first:
                break
        assert job.poll() is None, "the run finished before it could be killed"
        time.sleep(0.05)
    job.send_signal(signal.SIGKILL)
    job.wait()
    assert job.returncode == -signal.SIGKILL
    return iteration


def test_resume_after_sigkill_equals_uninterrupted_run(tmp_path):
    plain = _job(tmp_path, "plain")
    killed = _job(tmp_path, "ckpt")
    iteration = _kill_at_iteration(killed, tmp_path / checkpoint.CHECKPOINT_NAME, 3)
    assert 3 <= iteration < 7
    assert not (tmp_path / "result-ckpt-apmcabc.npz").exists()
    assert _job(tmp_path, "resume").wait(timeout=600) == 0
    assert plain.wait(timeout=600) == 0
    a = jaxabc.load(tmp_path / "result-plain-apmcabc.npz")
    b = jaxabc.load(tmp_path / "result-resume-apmcabc.npz")
    np.testing.assert_array_equal(a.particles, b.particles)
    np.testing.assert_array_equal(a.weights, b.weights)
    np.testing.assert_array_equal(a.thresholds, b.thresholds)
    assert a.num_simulations == b.num_simulations == 300 + 6 * 270
    np.testing.assert_array_equal(a.records["theta"], b.records["theta"])


@pytest.mark.slow  # default-suite time: 25-75 s on 2 cores
def test_surrogate_resume_after_sigkill_equals_uninterrupted_run(tmp_path):
    """A host simulator through the surrogate's design, killed after its second batch."""
    plain = _job(tmp_path, "plain", "surrogate")
    killed = _job(tmp_path, "ckpt", "surrogate")
    iteration = _kill_at_iteration(killed, tmp_path / checkpoint.CHECKPOINT_NAME, 2)
    assert iteration >= 2
    assert not (tmp_path / "result-ckpt-surrogate.npz").exists()
    assert _job(tmp_path, "resume", "surrogate").wait(timeout=600) == 0
    assert plain.wait(timeout=600) == 0
    a = jaxabc.load(tmp_path / "result-plain-surrogate.npz")
    b = jaxabc.load(tmp_path / "result-resume-surrogate.npz")
    assert a.num_simulations == b.num_simulations <= 60 and a.particles.shape[0] >= 1000
    np.testing.assert_array_equal(a.records["theta"], b.records["theta"])  # the same design
    np.testing.assert_array_equal(a.particles, b.particles)
    np.testing.assert_array_equal(a.weights, b.weights)
    assert a.stop_reason == b.stop_reason


def test_write_interrupted_half_way_leaves_the_previous_checkpoint(tmp_path, gaussian_problem):
    """A kill during a write leaves a partial temporary file beside the last good checkpoint;
    resuming ignores it and equals the uninterrupted run."""
    prior, simulate, observed = gaussian_problem
    kw = dict(num_particles=100, num_steps=4, distance="euclidean", seed=3)
    full = jaxabc.run("pmcabc", simulate, prior, observed, **kw)
    jaxabc.run("pmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, stop_after_iterations=3, **kw)
    good = (tmp_path / checkpoint.CHECKPOINT_NAME).read_bytes()
    (tmp_path / (checkpoint.CHECKPOINT_NAME + ".tmp")).write_bytes(good[: len(good) // 3])
    rest = jaxabc.run("pmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, resume=True, **kw)
    np.testing.assert_array_equal(full.particles, rest.particles)
    np.testing.assert_array_equal(full.records["theta"], rest.records["theta"])


# ----------------------------------------------------------------------------- resume: same problem


def shifted_simulate(key, theta, shift=0.0):
    """x = theta + shift + N(0, 1): the shift is what a partial or a factory binds."""
    return theta + shift + jax.random.normal(key, theta.shape)


def make_shifted(shift):
    def simulate(key, theta):
        return theta + shift + jax.random.normal(key, theta.shape)

    return simulate


RESUME_KW = dict(num_particles=100, num_steps=4, distance="euclidean", seed=2)


def _stop_then_resume(tmp_path, first, second, distance_first="euclidean", distance_second="euclidean"):
    prior = jaxabc.Uniform([-10.0], [10.0], names=("mu",))
    kw = dict(RESUME_KW)
    kw.pop("distance")
    jaxabc.run(
        "apmcabc", first, prior, jnp.zeros(1), checkpoint_dir=tmp_path, stop_after_iterations=2,
        distance=distance_first, **kw,
    )  # fmt: skip
    return jaxabc.run(
        "apmcabc", second, prior, jnp.zeros(1), checkpoint_dir=tmp_path, resume=True, distance=distance_second, **kw
    )


@pytest.mark.parametrize(
    "first, second, field",
    [
        (
            functools.partial(shifted_simulate, shift=0.0),
            functools.partial(shifted_simulate, shift=5.0),
            r"simulator\.keywords\.shift: checkpoint 0\.0, this run 5\.0",
        ),
        (make_shifted(0.0), make_shifted(5.0), r"simulator\.closure\.shift: checkpoint 0\.0, this run 5\.0"),
        (
            lambda key, theta: theta + jax.random.normal(key, theta.shape),
            lambda key, theta: theta + 5.0 + jax.random.normal(key, theta.shape),
            r"simulator\.code: the function's code differs",
        ),
    ],
    ids=["partial", "factory-closure", "lambda"],
)
def test_resume_refuses_a_simulator_with_other_bound_values(tmp_path, first, second, field):
    """A partial, a closure or a lambda with the same name but other meaning is another model: a
    resume that blended the two would silently answer neither (issue: shift 0 -> 5 resumed to
    theta 0.07, where a fresh run gives -4.6)."""
    with pytest.raises(checkpoint.CheckpointError, match=field):
        _stop_then_resume(tmp_path, first, second)


def test_resume_refuses_a_distance_with_another_scale(tmp_path):
    from jaxabc.distances import standardized_euclidean

    with pytest.raises(
        checkpoint.CheckpointError, match=r"distance\.closure\.scale\.array\[0\]: checkpoint 1\.0, this run 2\.0"
    ):
        _stop_then_resume(
            tmp_path,
            gaussian_simulate_for_resume,
            gaussian_simulate_for_resume,
            distance_first=standardized_euclidean(jnp.array([1.0])),
            distance_second=standardized_euclidean(jnp.array([2.0])),
        )


def gaussian_simulate_for_resume(key, theta):
    return theta + jax.random.normal(key, theta.shape)


def test_resume_accepts_the_same_partial_and_closure_and_equals_the_uninterrupted_run(tmp_path):
    prior = jaxabc.Uniform([-10.0], [10.0], names=("mu",))
    for i, make in enumerate((lambda: functools.partial(shifted_simulate, shift=1.0), lambda: make_shifted(1.0))):
        full = jaxabc.run("apmcabc", make(), prior, jnp.zeros(1), **RESUME_KW)
        rest = _stop_then_resume(tmp_path / str(i), make(), make())
        np.testing.assert_array_equal(full.particles, rest.particles)


def test_a_simulator_that_cannot_be_fingerprinted_needs_an_id_to_checkpoint(tmp_path):
    prior = jaxabc.Uniform([-10.0], [10.0])
    handle = object()

    def simulate(key, theta):
        assert handle is not None
        return theta + jax.random.normal(key, theta.shape)

    with pytest.raises(
        ValueError, match=r"cannot be fingerprinted: simulator closure\.handle \(builtins:object\).*simulator_id="
    ):
        jaxabc.run("apmcabc", simulate, prior, jnp.zeros(1), checkpoint_dir=tmp_path, **RESUME_KW)
    r = jaxabc.run(
        "apmcabc", simulate, prior, jnp.zeros(1), checkpoint_dir=tmp_path / "b", simulator_id="handle-v1", **RESUME_KW
    )
    assert r.metadata["simulator"] == "handle-v1"


def test_fused_checkpoint_resumed_with_an_executor_says_what_to_do(tmp_path, gaussian_problem):
    prior, simulate, observed = gaussian_problem
    kw = dict(num_particles=100, num_steps=4, distance="euclidean", seed=3)
    jaxabc.run("apmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, stop_after_iterations=2, **kw)
    with pytest.raises(checkpoint.CheckpointError, match=r"resume with executor=None \(CLI: no \[executor\] table\)"):
        jaxabc.run("apmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, resume=True, executor="serial", **kw)


# ----------------------------------------------------------------------------- one run per folder

_HOLD_LOCK = """
import sys, time
from jaxabc.checkpoint import FolderLock
lock = FolderLock.acquire(sys.argv[1])
print("locked", flush=True)
time.sleep(600)
"""


def test_a_second_run_in_a_locked_folder_is_refused_naming_the_holder(tmp_path, gaussian_problem):
    prior, simulate, observed = gaussian_problem
    kw = dict(num_particles=100, num_steps=3, distance="euclidean", seed=1)
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLD_LOCK, str(tmp_path)], stdout=subprocess.PIPE, text=True, cwd=HERE.parent
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "locked"
        for executor in (None, "serial"):
            with pytest.raises(checkpoint.FolderInUse, match=rf"in use by another run \(process {holder.pid} on "):
                jaxabc.run("apmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, executor=executor, **kw)
        assert not (tmp_path / checkpoint.CHECKPOINT_NAME).exists()
    finally:
        holder.send_signal(signal.SIGKILL)  # a killed holder leaves no stale lock
        holder.wait()
    r = jaxabc.run("apmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, **kw)
    assert r.stop_reason == "3 steps done"


_RACE = """
import sys
import jaxabc
from jaxabc.checkpoint import FolderInUse
from tests.conftest import gaussian_simulate
import jax.numpy as jnp
try:
    r = jaxabc.run("apmcabc", gaussian_simulate, jaxabc.Uniform([-10.0], [10.0], names=("mu",)), jnp.zeros(1),
                   num_particles=200, num_steps=6, distance="euclidean", seed=int(sys.argv[2]),
                   executor="serial", checkpoint_dir=sys.argv[1], simulator_id="gaussian")
    print("done", r.seed)
except FolderInUse as exc:
    print("refused", exc)
"""


def test_two_runs_started_together_in_one_folder_lose_nothing(tmp_path, gaussian_problem):
    """The issue's race: two runs into one folder; one finishes with an intact checkpoint, the
    other is refused at once (before the lock, 5 of 5 tries crashed one and kept the other's)."""
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _RACE, str(tmp_path), str(seed)], stdout=subprocess.PIPE, text=True, cwd=HERE.parent
        )
        for seed in (1, 2)
    ]
    outs = [p.communicate(timeout=300)[0] for p in procs]
    assert all(p.returncode == 0 for p in procs), outs
    done = [o for o in outs if o.startswith("done")]
    refused = [o for o in outs if o.startswith("refused")]
    assert len(done) == 1 and len(refused) == 1, outs
    seed = int(done[0].split()[1])
    ck = checkpoint.load(tmp_path / checkpoint.CHECKPOINT_NAME)
    assert ck.fingerprint["seed"] == seed and "resumable" not in ck.counters["stop_reason"]
    assert not list(tmp_path.glob("*.tmp"))
    kw = dict(
        num_particles=200, num_steps=6, distance="euclidean", seed=seed, executor="serial", simulator_id="gaussian"
    )
    prior, simulate, observed = gaussian_problem
    fresh = jaxabc.run("apmcabc", simulate, prior, observed, **kw)
    with pytest.warns(UserWarning, match="had already ended"):
        kept = jaxabc.run("apmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, resume=True, **kw)
    np.testing.assert_array_equal(fresh.particles, kept.particles)


def test_a_write_that_fails_leaves_no_temporary_and_a_stale_one_does_not_block(tmp_path, gaussian_problem, monkeypatch):
    """A full disk: the failed write removes its temporary file, the previous checkpoint stays,
    and a stale temporary of any name (even one that is a folder) does not block the resume."""
    prior, simulate, observed = gaussian_problem
    kw = dict(num_particles=100, num_steps=4, distance="euclidean", seed=3, executor="serial")
    full = jaxabc.run("pmcabc", simulate, prior, observed, **kw)
    jaxabc.run("pmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, stop_after_iterations=2, **kw)
    good = (tmp_path / checkpoint.CHECKPOINT_NAME).read_bytes()

    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(checkpoint.np, "savez", disk_full)
    with pytest.raises(OSError, match="No space left"):
        jaxabc.run("pmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, resume=True, **kw)
    monkeypatch.undo()
    assert (tmp_path / checkpoint.CHECKPOINT_NAME).read_bytes() == good
    assert [p.name for p in tmp_path.iterdir() if "tmp" in p.name] == []
    (tmp_path / (checkpoint.CHECKPOINT_NAME + ".tmp")).mkdir()  # the old fixed name, unwritable
    (tmp_path / f".{checkpoint.CHECKPOINT_NAME}.stale{os.getpid()}.tmp").write_bytes(good[:100])
    rest = jaxabc.run("pmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, resume=True, **kw)
    np.testing.assert_array_equal(full.particles, rest.particles)


# ----------------------------------------------------------------------------- stopping rules on resume


@pytest.mark.parametrize("executor", [None, "serial"], ids=["fused", "host"])
def test_an_ended_run_resumed_with_more_steps_goes_on_to_the_longer_runs_result(tmp_path, gaussian_problem, executor):
    prior, simulate, observed = gaussian_problem
    kw = dict(num_particles=100, distance="euclidean", seed=3, executor=executor)
    longer = jaxabc.run("apmcabc", simulate, prior, observed, num_steps=5, checkpoint_dir=tmp_path / "a", **kw)
    short = jaxabc.run("apmcabc", simulate, prior, observed, num_steps=3, checkpoint_dir=tmp_path / "b", **kw)
    assert short.stop_reason == "3 steps done"
    with pytest.warns(UserWarning, match=r"had already ended \(3 steps done\).*nothing more was run"):
        same = jaxabc.run(
            "apmcabc", simulate, prior, observed, num_steps=3, checkpoint_dir=tmp_path / "b", resume=True, **kw
        )
    np.testing.assert_array_equal(same.particles, short.particles)
    more = jaxabc.run(
        "apmcabc", simulate, prior, observed, num_steps=5, checkpoint_dir=tmp_path / "b", resume=True, **kw
    )
    assert more.stop_reason == "5 steps done" and len(more.thresholds) == 5
    np.testing.assert_array_equal(more.particles, longer.particles)
    np.testing.assert_array_equal(more.records["theta"], longer.records["theta"])


@pytest.mark.parametrize("executor", [None, "serial"], ids=["fused", "host"])
def test_a_budget_below_the_first_population_is_refused_before_simulating(gaussian_problem, executor):
    """Before: the first population ran in full and overshot max_simulations (100 of 50)."""
    prior, simulate, observed = gaussian_problem
    with pytest.raises(ValueError, match=r"max_simulations=50 is below the 100 simulations of apmcabc's first"):
        jaxabc.run(
            "apmcabc", simulate, prior, observed, num_particles=100, max_simulations=50, executor=executor, seed=0
        )
    r = jaxabc.run("apmcabc", simulate, prior, observed, num_particles=100, max_simulations=250, executor=executor)
    assert r.num_simulations <= 250
