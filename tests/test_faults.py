"""Fault injection: every fault ends in a correct result or a clear error, with nothing lost.

Crashing, hanging and NaN-returning simulators, NaN distances, a driver killed with SIGKILL and
resumed, and a write interrupted half-way.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

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
