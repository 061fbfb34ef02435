"""The driver: resume after a real kill, executors, failures, bad inputs, result files, CLI."""

import contextlib
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxabc
from jaxabc import examples
from jaxabc.algorithms import ABCAlgorithm, Info, Proposal
from jaxabc.errors import (
    STATUS_FAILED,
    STATUS_NONFINITE,
    STATUS_OK,
    STATUS_TIMEOUT,
    STATUS_WORKER_DIED,
)

HERE = Path(__file__).parent


def test_stop_after_iterations_then_resume_in_process(tmp_path, gaussian_problem):
    prior, simulate, observed = gaussian_problem
    kw = dict(num_particles=400, num_steps=5, seed=1, distance="euclidean")
    full = jaxabc.run("abcsubsim", simulate, prior, observed, **kw)
    part = jaxabc.run("abcsubsim", simulate, prior, observed, checkpoint_dir=tmp_path, stop_after_iterations=6, **kw)
    assert "resumable" in part.stop_reason
    rest = jaxabc.run("abcsubsim", simulate, prior, observed, checkpoint_dir=tmp_path, resume=True, **kw)
    np.testing.assert_array_equal(full.particles, rest.particles)
    assert full.log_evidence == rest.log_evidence
    with pytest.raises(jaxabc.checkpoint.CheckpointError, match="seed: checkpoint 1, this run 2"):
        jaxabc.run("abcsubsim", simulate, prior, observed, checkpoint_dir=tmp_path, resume=True, **{**kw, "seed": 2})


def test_host_executors_identical_whatever_the_workers(gaussian_problem):
    prior, _, observed = gaussian_problem
    kw = dict(num_particles=200, num_steps=3, seed=4, distance="euclidean")
    results = [
        jaxabc.run("apmcabc", examples.host_gaussian_simulate, prior, observed, executor=ex, **kw)
        for ex in (
            jaxabc.SerialExecutor(),
            jaxabc.ProcessPoolExecutor(max_workers=1),
            jaxabc.ProcessPoolExecutor(max_workers=3),
        )
    ]
    for r in results[1:]:
        np.testing.assert_array_equal(results[0].particles, r.particles)
        np.testing.assert_array_equal(results[0].weights, r.weights)
    assert set(np.unique(results[2].records["worker"])) > {0}


def test_vmap_and_host_executors_simulate_the_same_draws():
    keys = np.asarray(jax.random.key_data(jax.random.split(jax.random.key(0), 50)))
    thetas = np.linspace(-1, 1, 50, dtype=np.float32)[:, None]
    a = jaxabc.VmapExecutor(chunk_size=16).map(examples.gaussian_simulate, keys, thetas)
    b = jaxabc.SerialExecutor().map(examples.gaussian_simulate, keys, thetas)
    # Same keys give the same draws; XLA's vectorised and scalar code may round the last bit.
    np.testing.assert_allclose(a.summaries, b.summaries, rtol=1e-6, atol=1e-6)


def test_failures_are_recorded_and_the_run_goes_on():
    jaxabc.Uniform([0.0], [1.0], names=("t",))
    ex = jaxabc.ProcessPoolExecutor(max_workers=2, timeout=3.0)
    keys = np.asarray(jax.random.key_data(jax.random.split(jax.random.key(0), 6)))
    thetas = np.array([[0.05], [0.15], [0.22], [0.27], [0.5], [0.9]])
    batch = ex.map(examples.flaky_simulate, keys, thetas)
    assert list(batch.status) == [
        STATUS_FAILED,
        STATUS_NONFINITE,
        STATUS_TIMEOUT,
        STATUS_WORKER_DIED,
        STATUS_OK,
        STATUS_OK,
    ]
    assert "vaporised" in batch.reasons[0]
    assert "non-finite" in batch.reasons[1]
    assert "timeout" in batch.reasons[2]
    assert "died" in batch.reasons[3]
    assert np.all(np.isnan(batch.summaries[:4])) and np.all(np.isfinite(batch.summaries[4:]))
    # The pool replaced its dead workers and still works.
    again = ex.map(examples.flaky_simulate, keys[4:], thetas[4:])
    np.testing.assert_array_equal(again.summaries, batch.summaries[4:])
    # A whole run over the flaky prior: 30% fail, the run completes and records them.
    result = jaxabc.run(
        "rejection",
        examples.flaky_simulate,
        jaxabc.Uniform([0.0], [1.0]),
        np.array([0.6]),
        num_particles=20,
        quantile=0.5,
        executor=jaxabc.ProcessPoolExecutor(max_workers=2, timeout=2.0),
        seed=0,
    )
    status = result.records["status"]
    assert np.sum(status != STATUS_OK) > 0 and result.particles.min() >= 0.3
    assert len(result.records["reasons"]) == status.size
    ex.close()


_ORPHAN_DRIVER = """
import threading, time, numpy as np, jaxabc
from jaxabc.examples import busy_child_simulate
ex = jaxabc.ProcessPoolExecutor(max_workers=2)
threading.Thread(target=ex.map, args=(busy_child_simulate, np.zeros((2, 2), np.uint32), np.full((2, 1), 60.0)),
                 daemon=True).start()
while len(ex._workers) < 2 or any(w.started is None for w in ex._workers):
    time.sleep(0.05)
print(" ".join(str(w.proc.pid) for w in ex._workers), flush=True)
time.sleep(120)
"""


def _live_in_group(pgid: int) -> list[int]:
    """Processes (not zombies) whose process group is ``pgid``."""
    live = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            live.append(int(entry.name))
    return live


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc (Linux)")
def test_killed_driver_takes_its_workers_and_their_programs_down():
    """Workers sit in process groups of their own, out of reach of a signal to the driver; when
    the driver dies they must stop their simulations (here a busy child process) within seconds,
    not run them to the end."""
    driver = subprocess.Popen([sys.executable, "-c", _ORPHAN_DRIVER], stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(p) for p in driver.stdout.readline().split()]
        assert len(pids) == 2
        time.sleep(1.0)  # let the tasks start their busy children
        assert all(len(_live_in_group(pid)) >= 2 for pid in pids)  # worker + its busy program
    finally:
        driver.kill()
        driver.wait()
    deadline = time.time() + 15.0
    while time.time() < deadline and any(_live_in_group(pid) for pid in pids):
        time.sleep(0.2)
    assert not any(_live_in_group(pid) for pid in pids), [_live_in_group(pid) for pid in pids]


def test_too_many_failures_stop_with_the_reasons():
    def always_nan(key, theta):
        return jnp.full((1,), jnp.nan)

    prior = jaxabc.Uniform([0.0], [1.0])
    with pytest.raises(jaxabc.TooManyFailures, match="all 100 simulations failed"):
        jaxabc.run("apmcabc", always_nan, prior, np.array([0.0]), num_particles=100, seed=0)


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(observed=np.array([np.nan])), ValueError, "NaN or infinite"),
        (dict(observed=np.zeros(2)), ValueError, r"shape \(1,\) but the observed data has shape \(2,\)"),
        (dict(num_particles=0), ValueError, "positive integer"),
        (dict(alpha=1.5), ValueError, r"alpha must lie in \(0, 1\)"),
        (dict(alpha=0.0), ValueError, r"alpha must lie in \(0, 1\)"),
        (dict(algorithm="smc"), ValueError, "unknown algorithm 'smc'"),
        (dict(distance="l7"), ValueError, "unknown distance"),
        (dict(executor="gpu-cluster"), ValueError, "unknown executor"),
        (dict(observed=np.array([])), ValueError, "empty"),
    ],
)
def test_bad_inputs_are_clear_errors(kwargs, error, match, gaussian_problem):
    prior, simulate, observed = gaussian_problem
    args = dict(algorithm="apmcabc", observed=observed, num_particles=100)
    args.update(kwargs)
    algorithm = args.pop("algorithm")
    with pytest.raises(error, match=match):
        jaxabc.run(algorithm, simulate, prior, num_steps=2, **args)


def test_simulator_with_wrong_shape_is_caught(gaussian_problem):
    prior, _, observed = gaussian_problem
    with pytest.raises(ValueError, match=r"returns summaries of shape \(3,\)"):
        jaxabc.run("apmcabc", lambda k, t: jnp.zeros(3), prior, observed, num_particles=100, num_steps=2)
    with pytest.raises(ValueError, match=r"returned summaries of shape \(3,\)"):
        jaxabc.run(
            "rejection", lambda k, t: np.zeros(3), prior, observed, num_particles=10, quantile=0.5, executor="serial"
        )


def test_stopping_rule_required_and_budget(gaussian_problem):
    prior, simulate, observed = gaussian_problem
    with pytest.raises(ValueError, match="needs a stopping rule"):
        jaxabc.run("pmcabc", simulate, prior, observed, num_particles=100)
    r = jaxabc.run(
        "apmcabc",
        simulate,
        prior,
        observed,
        num_particles=500,
        alpha=0.1,
        acceptance_cutoff=0.0,
        max_simulations=2000,
        seed=0,
    )
    assert r.num_simulations <= 2000 and "budget" in r.stop_reason


# This run and the CLI's below share one algorithm configuration (apmcabc, alpha 0.1, 400
# particles, the same prior): the driver's cache compiles it once for both tests.
def test_result_file_roundtrip_and_plot(tmp_path, correlated_problem):
    prior, simulate, observed = correlated_problem
    r = jaxabc.run(
        "apmcabc",
        simulate,
        prior,
        observed,
        num_particles=400,
        num_steps=3,
        distance="euclidean",
        seed=0,
        alpha=0.1,
        metadata={"note": "test"},
    )
    path = r.save(tmp_path / "run")
    back = jaxabc.load(path)
    np.testing.assert_array_equal(back.particles, r.particles)
    np.testing.assert_allclose(back.bayes_estimate(), r.bayes_estimate())
    assert back.settings["alpha"] == 0.1 and back.metadata["note"] == "test"
    assert back.prior.names == ("a", "b") and back.records["theta"].shape == (400 + 2 * 360, 2)
    ci = back.credible_interval(0.9)
    assert np.all(ci[:, 0] < back.bayes_estimate()) and np.all(back.bayes_estimate() < ci[:, 1])
    r.plot_posterior(tmp_path / "post.png", truth=np.zeros(2))
    assert (tmp_path / "post.png").stat().st_size > 10_000


def test_cli_runs_a_toml_config_and_resumes(tmp_path, capsys):
    """``jaxabc run`` writes its outputs and a checkpoint, ``--resume`` continues from it, a fresh
    run into the same folder is refused; in-process through ``main`` (as the installed script
    calls it), with the ``python -m jaxabc.cli`` entry point checked once in a child process."""
    from jaxabc.cli import main

    cfg = tmp_path / "gauss.toml"
    cfg.write_text("""
[model]
simulator = "jaxabc.examples:correlated_simulate"
[prior]
names = ["a", "b"]
low = [-10.0, -10.0]
high = [10.0, 10.0]
[observed]
values = [0.0, 0.0]
[algorithm]
name = "apmcabc"
num_particles = 400
num_steps = 3
distance = "euclidean"
seed = 3
options = { alpha = 0.1 }
[output]
folder = "out"
""")
    argv = ["run", str(cfg), "--no-progress"]
    # 400 particles, then two generations that keep 40 and simulate 360 each.
    assert main(argv) == 0
    assert "apmcabc: 1120 simulations" in capsys.readouterr().out
    for name in ("result.npz", "posterior.png", "summary.txt", "checkpoint.npz"):
        assert (tmp_path / "out" / name).exists()
    assert main([*argv, "--resume"]) == 0
    assert "1120 simulations" in capsys.readouterr().out
    assert main(argv) == 2
    assert "--resume" in capsys.readouterr().err
    env = {**os.environ, "PYTHONPATH": str(HERE.parent)}
    bad = subprocess.run(
        [sys.executable, "-m", "jaxabc.cli", "run", str(tmp_path / "nope.toml")],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert bad.returncode == 2 and "no configuration file" in bad.stderr


FLOAT64_CASES = {
    "rejection": dict(num_particles=1000, quantile=0.02),
    "pmcabc": dict(num_particles=500, num_steps=4),
    "apmcabc": dict(num_particles=1000, num_steps=5, alpha=0.1),
    "abcsubsim": dict(num_particles=2000, p0=0.2, final_threshold=0.4, num_steps=10),
}


# Each algorithm compiles its whole run twice more in float64: the default suite checks the
# default algorithm, the other three run under `slow`.
@pytest.mark.parametrize(
    "algorithm",
    [name if name == "apmcabc" else pytest.param(name, marks=pytest.mark.slow) for name in sorted(FLOAT64_CASES)],
)
def test_float64_works_for_every_algorithm_and_does_not_leak(algorithm, gaussian_problem):
    """Double precision gives the analytic ABC posterior (mean 0, variance 1 + eps^2 / 3 within
    4 Monte Carlo standard errors), and the next float32 run is the float32-only run."""
    prior, simulate, observed = gaussian_problem
    kw = dict(FLOAT64_CASES[algorithm], distance="euclidean", seed=3)
    before = jax.config.jax_enable_x64
    single = jaxabc.run(algorithm, simulate, prior, observed, **kw)
    r = jaxabc.run(algorithm, simulate, prior, observed, dtype="float64", **kw)
    assert jax.config.jax_enable_x64 == before
    x = r.particles
    assert r.metadata["dtype"] == "float64" and np.any(x.astype(np.float32).astype(np.float64) != x)
    eps = float(r.thresholds[-1])
    var_exact = examples.gaussian_abc_variance(eps)
    ess = r.effective_sample_size()
    if algorithm == "abcsubsim":
        # Chains: neither the seeds nor the distinct particles are independent; take the
        # smaller as a generous effective size.
        ess = min(ess, 0.2 * kw["num_particles"], np.unique(x).size)
    assert abs(r.bayes_estimate()[0]) < 4 * np.sqrt(var_exact / ess)
    assert abs(r.covariance()[0, 0] - var_exact) < 4 * var_exact * np.sqrt(2 / ess)
    after = jaxabc.run(algorithm, simulate, prior, observed, **kw)
    np.testing.assert_array_equal(after.particles, single.particles)
    np.testing.assert_array_equal(after.thresholds, single.thresholds)


def _posterior(particles, weights):
    """An ABCResult around a given weighted sample (only the posterior summaries are used)."""
    return jaxabc.ABCResult.from_sample(
        particles, weights, jaxabc.Uniform([-9.0] * particles.shape[1], [9.0] * particles.shape[1])
    )


def _in_sample_kde_level(post, point):
    """The biased estimate: each particle's KDE density includes its own kernel."""
    x, w = post.particles, post.weights
    bw_inv = np.linalg.inv(post.covariance() * (1.0 / np.sum(w**2)) ** (-1.0 / 3.0))

    def density(y):
        return np.sum(w * np.exp(-0.5 * np.einsum("ij,jk,ik->i", x - y, bw_inv, x - y)))

    return np.sum(w[np.array([density(xi) for xi in x]) > density(point)])


@pytest.mark.parametrize("num, spread", [(10, 1.0), (30, 1.2)])
def test_credible_level_of_an_exchangeable_truth_is_uniform(num, spread):
    """A truth drawn from the same posterior as the particles sits at a uniform credible level.

    Posterior N(0, C) with correlation -0.93 (the water posterior's shape); the particles are
    equally weighted draws from it, or draws from the wider N(0, 1.44 C) importance-weighted back
    to it.  Over 600 such samples the mean level must be 1/2 within 4 Monte Carlo standard
    errors (sd of U(0,1) is 0.289): 0.047.  With equal weights the truth's rank among the n + 1
    points is uniform, so it is inside the 50 % region (level < 1/2) with probability exactly
    5/11 at n = 10; with weights, 1/2.  The plain in-sample KDE level, the estimator this
    replaces, fails the mean check at 10 particles (its mean is ~0.7): the check can fail.
    """
    rng = np.random.default_rng(7)
    cov = np.array([[1.0, -0.93], [-0.93, 1.0]])
    chol, prec = np.linalg.cholesky(cov), np.linalg.inv(cov)
    levels, in_sample = [], []
    for _ in range(600):
        x = spread * rng.standard_normal((num, 2)) @ chol.T
        q = np.einsum("ij,jk,ik->i", x, prec, x)
        post = _posterior(x, np.exp(-0.5 * q * (1.0 - 1.0 / spread**2)))
        truth = rng.standard_normal(2) @ chol.T
        levels.append(post.credible_level(truth))
        in_sample.append(_in_sample_kde_level(post, truth))
    levels = np.array(levels)
    tolerance = 4 * np.sqrt(1 / 12 / 600)
    assert abs(levels.mean() - 0.5) < tolerance, levels.mean()
    inside = 5 / 11 if spread == 1.0 else 0.5
    assert abs(np.mean(levels < 0.5) - inside) < 4 * np.sqrt(inside * (1 - inside) / 600), np.mean(levels < 0.5)
    if num == 10:
        assert np.mean(in_sample) - 0.5 > tolerance, np.mean(in_sample)


def test_credible_level_rejects_bad_points():
    post = _posterior(np.random.default_rng(0).standard_normal((20, 2)), np.ones(20))
    with pytest.raises(ValueError, match="2 parameters"):
        post.credible_level([0.0, 0.0, 0.0])
    assert post.credible_level([50.0, 50.0]) == 1.0
    assert post.credible_level(post.bayes_estimate()) < 0.3


# ----------------------------------------------------------------- algorithm objects, retracing

_TRACES = {"propose": 0}


class _BestOfState(NamedTuple):
    particles: jax.Array  # (n, d): the n closest draws so far
    distances: jax.Array  # (n,)
    rounds: jax.Array  # ()


def _best_of(prior, n: int, rounds: int) -> ABCAlgorithm:
    """A user's rejection-like algorithm: keep the n closest of ``rounds`` batches of n prior
    draws, i.e. rejection ABC with acceptance rate 1 / rounds."""

    def first(key):
        return Proposal(prior.sample(key, n), jnp.ones((n,), bool), jnp.bool_(True))

    def info(state):
        return Info(
            jnp.bool_(True),
            state.rounds >= rounds,
            state.distances[-1],
            jnp.asarray(1.0 / rounds),
            jnp.asarray(float(n)),
        )

    def init(key, proposal, distances):
        order = jnp.argsort(distances)
        state = _BestOfState(proposal.thetas[order], distances[order], jnp.int32(1))
        return state, info(state)

    def propose(key, state):
        _TRACES["propose"] += 1  # runs only while JAX traces
        return first(key)

    def update(key, state, proposal, distances):
        x = jnp.concatenate([state.particles, proposal.thetas])
        d = jnp.concatenate([state.distances, distances])
        order = jnp.argsort(d)[:n]
        new = _BestOfState(x[order], d[order], state.rounds + 1)
        return new, info(new)

    def posterior(state):
        return state.particles, jnp.zeros((n,), state.particles.dtype)

    return ABCAlgorithm(
        "best_of",
        first,
        init,
        propose,
        update,
        posterior,
        {"rounds": rounds},
        stop_reason=lambda settings, info: f"best of {settings['rounds']} batches",
        finalize=lambda state: {"log_evidence": -np.log(rounds), "rounds_done": int(state.rounds)},
    )


@contextlib.contextmanager
def _compile_events():
    """The XLA compilations that happen inside the block."""
    events: list[str] = []

    def listener(name, *args, **kwargs):
        if "backend_compile" in name:
            events.append(name)

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield events
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)


def test_run_accepts_a_user_written_algorithm_and_does_not_retrace_it(gaussian_problem):
    """A user's algorithm object runs through the driver: its stop reason and extras reach the
    result, its posterior is the analytic ABC posterior, a checkpointed run resumes to the same
    result, and a second run compiles nothing (no retrace, no backend compile)."""
    prior, simulate, observed = gaussian_problem
    algo = _best_of(prior, 400, rounds=25)
    kw = dict(distance="euclidean", seed=2)
    r = jaxabc.run(algo, simulate, prior, observed, num_particles=400, **kw)
    assert r.algorithm == "best_of" and r.stop_reason == "best of 25 batches"
    assert r.num_simulations == 25 * 400 and r.metadata["rounds_done"] == 25
    assert r.log_evidence == pytest.approx(-np.log(25))
    var_exact = examples.gaussian_abc_variance(float(r.thresholds[-1]))
    assert abs(r.bayes_estimate()[0]) < 4 * np.sqrt(var_exact / 400)
    assert abs(r.covariance()[0, 0] - var_exact) < 4 * var_exact * np.sqrt(2 / 400)
    traces = _TRACES["propose"]
    with _compile_events() as compiles:
        again = jaxabc.run(algo, simulate, prior, observed, num_particles=400, **kw)
    assert _TRACES["propose"] == traces and compiles == []
    np.testing.assert_array_equal(again.particles, r.particles)


def test_second_run_of_a_builtin_algorithm_compiles_nothing(gaussian_problem):
    prior, simulate, observed = gaussian_problem
    kw = dict(num_particles=100, num_steps=3, distance="euclidean")
    jaxabc.run("pmcabc", simulate, prior, observed, seed=0, **kw)
    shifted = np.asarray(observed) + 0.5
    # Another seed and other observed values: both are arguments, not compiled constants.
    with _compile_events() as compiles:
        jaxabc.run("pmcabc", simulate, prior, shifted, seed=1, **kw)
    assert compiles == []


def test_algorithm_object_rejects_builder_options(gaussian_problem):
    prior, simulate, observed = gaussian_problem
    with pytest.raises(TypeError, match="cannot be applied to an algorithm object"):
        jaxabc.run(_best_of(prior, 10, 2), simulate, prior, observed, num_particles=10, alpha=0.1)


# ----------------------------------------------------------------- scalars, budgets, stopping rules


def test_scalar_simulator_with_scalar_observation(gaussian_problem):
    prior, _, _ = gaussian_problem
    r = jaxabc.run(
        "rejection",
        lambda key, theta: theta[0] + jax.random.normal(key),
        prior,
        0.0,
        num_particles=500,
        quantile=0.05,
        distance="euclidean",
        seed=0,
    )
    var_exact = examples.gaussian_abc_variance(float(r.thresholds[-1]))
    assert abs(r.bayes_estimate()[0]) < 4 * np.sqrt(var_exact / 500)
    assert r.records["summaries"].shape == (10_000,)


def test_unbounded_rejection_is_refused_and_a_budget_ends_it_with_what_it_has(gaussian_problem):
    prior, simulate, observed = gaussian_problem
    with pytest.raises(ValueError, match="needs a stopping rule"):
        jaxabc.run("rejection", simulate, prior, observed, num_particles=50, threshold=1e-4)
    # P(|x| < 0.01) is about 0.001 per draw: 20 rounds of 50 accept a few, not 50.
    r = jaxabc.run(
        "rejection",
        simulate,
        prior,
        observed,
        num_particles=50,
        threshold=0.01,
        max_simulations=1000,
        distance="euclidean",
        seed=0,
    )
    accepted = r.records["distance"] <= 0.01
    assert r.metadata["incomplete"] and "incomplete" in r.stop_reason and "budget" in r.stop_reason
    assert 0 < len(r.particles) == accepted.sum() < 50 and r.num_simulations <= 1000
    np.testing.assert_array_equal(np.sort(r.particles[:, 0]), np.sort(r.records["theta"][accepted, 0]))
    with pytest.raises(jaxabc.errors.NoPosterior, match="without accepting any particle"):
        jaxabc.run(
            "rejection",
            simulate,
            prior,
            observed,
            num_particles=50,
            threshold=1e-7,
            max_simulations=200,
            distance="euclidean",
            seed=0,
        )
