"""The fused path (jaxabc.run_fused) against the host driver with the vmap executor.

Both use the same keys, kernels and stopping rules, so for a seed they give the same
iterations; the comparison allows float32 rounding, since XLA may fuse the simulator and the
distance differently inside one program (a distance moved by one ulp across a threshold would
change a particle: the checks would then fail loudly rather than pass by tolerance).
"""

import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxabc
from jaxabc.checkpoint import CheckpointError

N = 300
ROOT = Path(__file__).resolve().parents[1]


def _simulate(key, theta):
    return theta + jax.random.normal(key, theta.shape)


@pytest.fixture(scope="module")
def problem():
    return jaxabc.Uniform([-10.0], [10.0], names=("mu",)), np.zeros(1)


def _same_run(host, fast):
    assert host.num_simulations == fast.num_simulations
    assert host.stop_reason == fast.stop_reason
    np.testing.assert_array_equal(host.simulations_per_step, fast.simulations_per_step)
    np.testing.assert_allclose(host.thresholds, fast.thresholds, rtol=1e-5)
    np.testing.assert_allclose(host.particles, fast.particles, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(host.weights, fast.weights, rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(host.acceptance_rates, fast.acceptance_rates, rtol=1e-5)
    for name in ("theta", "iteration", "status"):
        np.testing.assert_allclose(host.records[name], fast.records[name], rtol=1e-5)
    assert set(host.records) == set(fast.records)


@pytest.mark.parametrize(
    "algorithm, options",
    [
        ("apmcabc", dict(num_steps=4)),
        ("pmcabc", dict(num_steps=3)),
    ],
)
def test_fused_equals_host_driver(problem, algorithm, options):
    prior, observed = problem
    kw = dict(num_particles=N, distance="euclidean", seed=3, **options)
    host = jaxabc.run(algorithm, _simulate, prior, observed, executor="vmap", **kw)
    fast = jaxabc.run_fused(algorithm, _simulate, prior, observed, chunk_size=2, **kw)
    _same_run(host, fast)
    assert fast.metadata["executor"] == "fused" and host.metadata["executor"] == "vmap"


def test_fused_simulation_budget_as_host(problem):
    """Stops before the iteration that would exceed the budget, with the last full generation."""
    prior, observed = problem
    kw = dict(num_particles=N, distance="euclidean", seed=4, max_simulations=1000, acceptance_cutoff=0.0)
    host = jaxabc.run("apmcabc", _simulate, prior, observed, executor="vmap", **kw)
    fast = jaxabc.run_fused("apmcabc", _simulate, prior, observed, chunk_size=2, **kw)
    assert host.stop_reason.startswith("simulation budget")
    _same_run(host, fast)


def test_run_defaults_to_the_fused_program_for_jax_simulators(problem):
    """``jaxabc.run`` without an executor runs a JAX simulator fused: the same run as
    ``run_fused``; an explicit executor, a host algorithm or an untraceable simulator keeps the
    host driver."""
    prior, observed = problem
    kw = dict(num_particles=N, distance="euclidean", seed=5, num_steps=3)
    auto = jaxabc.run("apmcabc", _simulate, prior, observed, **kw)
    fused = jaxabc.run_fused("apmcabc", _simulate, prior, observed, **kw)
    assert auto.metadata["executor"] == "fused"
    np.testing.assert_array_equal(auto.particles, fused.particles)
    np.testing.assert_array_equal(auto.records["theta"], fused.records["theta"])

    def host_simulate(key, theta):
        return np.asarray(theta) + np.random.default_rng(int(np.asarray(jax.random.key_data(key))[-1])).normal()

    host = jaxabc.run("apmcabc", host_simulate, prior, observed, executor="serial", **kw)
    assert host.metadata["executor"] == "serial"
    # Untraceable and no executor: the host driver's vmap executor, with its own error.
    with pytest.raises(TypeError, match="could not trace simulate"):
        jaxabc.run("apmcabc", host_simulate, prior, observed, **kw)


def test_fused_checkpoint_resume_equals_the_uninterrupted_run(problem, tmp_path):
    """A fused run stopped part-way (resumably) and resumed from its checkpoint gives the
    uninterrupted run's result, records included; a host checkpoint is resumed on the host."""
    prior, observed = problem
    kw = dict(num_particles=N, distance="euclidean", seed=6, num_steps=5, acceptance_cutoff=0.0)
    whole = jaxabc.run("apmcabc", _simulate, prior, observed, **kw)
    folder = tmp_path / "fused"
    part = jaxabc.run("apmcabc", _simulate, prior, observed, checkpoint_dir=folder, stop_after_iterations=2, **kw)
    assert part.stop_reason.startswith("stopped after 2 iterations") and part.metadata["executor"] == "fused"
    assert len(part.thresholds) == 2
    resumed = jaxabc.run("apmcabc", _simulate, prior, observed, checkpoint_dir=folder, resume=True, **kw)
    assert resumed.metadata["executor"] == "fused" and resumed.stop_reason == whole.stop_reason
    np.testing.assert_array_equal(resumed.particles, whole.particles)
    np.testing.assert_array_equal(resumed.weights, whole.weights)
    np.testing.assert_array_equal(resumed.thresholds, whole.thresholds)
    for name in ("theta", "distance", "iteration", "status", "summaries"):
        np.testing.assert_array_equal(resumed.records[name], whole.records[name])
    # A checkpoint of the host driver: jaxabc.run continues it there; run_fused refuses it.
    host_folder = tmp_path / "host"
    first = dict(executor="vmap", checkpoint_dir=host_folder, stop_after_iterations=2)
    jaxabc.run("apmcabc", _simulate, prior, observed, **first, **kw)
    host = jaxabc.run("apmcabc", _simulate, prior, observed, checkpoint_dir=host_folder, resume=True, **kw)
    assert host.metadata["executor"] == "vmap" and len(host.thresholds) == 5
    with pytest.raises(CheckpointError, match="driver"):
        jaxabc.run_fused("apmcabc", _simulate, prior, observed, checkpoint_dir=host_folder, resume=True, **kw)


def test_fused_run_that_fails_everywhere_is_refused_at_once(problem):
    prior, observed = problem

    def simulate(key, theta):
        return jnp.full(theta.shape, jnp.nan)

    with pytest.raises(jaxabc.TooManyFailures, match="all 50 simulations failed"):
        jaxabc.run("apmcabc", simulate, prior, observed, num_particles=50, num_steps=2)


def test_second_call_does_not_retrace(problem):
    """New observed data, seed and limits reuse the compiled chunk: the simulator is not traced."""
    prior, observed = problem
    traces = []

    def simulate(key, theta):
        traces.append(1)
        return theta + jax.random.normal(key, theta.shape)

    kw = dict(num_particles=100, distance="euclidean", chunk_size=4, acceptance_cutoff=0.0)
    jaxabc.run_fused("apmcabc", simulate, prior, observed, num_steps=3, seed=0, **kw)
    first = len(traces)
    r = jaxabc.run_fused("apmcabc", simulate, prior, observed + 1.0, num_steps=5, seed=1, **kw)
    # One shape check (eval_shape) per call is allowed; nothing is compiled again.
    assert len(traces) - first <= 1
    assert len(r.thresholds) == 5


def test_fused_non_finite_summaries_are_failures(problem):
    prior, observed = problem

    def simulate(key, theta):
        x = theta + jax.random.normal(key, theta.shape)
        return jnp.where(theta > 5.0, jnp.nan, x)

    r = jaxabc.run_fused("apmcabc", simulate, prior, observed, num_particles=200, num_steps=2, distance="euclidean")
    bad = r.records["theta"][:, 0] > 5.0
    assert np.all(r.records["status"][bad] == jaxabc.errors.STATUS_NONFINITE)
    assert np.all(np.isinf(r.records["distance"][bad]))
    assert np.all(r.records["status"][~bad] == 0)


def test_fused_rejects_untraceable_simulator(problem):
    prior, observed = problem

    def simulate(key, theta):
        return np.asarray(theta) + 1.0  # host NumPy: cannot be traced

    with pytest.raises(TypeError, match="process_pool"):
        jaxabc.run_fused("apmcabc", simulate, prior, observed, num_particles=50, num_steps=2)
    with pytest.raises(ValueError, match="chunk_size"):
        jaxabc.run_fused("apmcabc", _simulate, prior, observed, num_particles=50, chunk_size=0)


def _fresh_process(code: str, **env: str) -> str:
    """Run ``code`` in a new interpreter (JAX's cache settings must not leak into other tests),
    without the user's ``JAXABC_COMPILATION_CACHE``; its standard output."""
    base = {k: v for k, v in os.environ.items() if k != "JAXABC_COMPILATION_CACHE"}
    out = subprocess.run(
        [sys.executable, "-c", code],
        check=True,
        timeout=300,
        capture_output=True,
        text=True,
        env={**base, "JAX_PLATFORMS": "cpu", "PYTHONPATH": str(ROOT), **env},
    )
    return out.stdout


def test_enable_compilation_cache(tmp_path):
    """The explicit call stores compiled programs in the folder, even after JAX has already
    compiled something in the process (JAX decides at its first compilation)."""
    _fresh_process(
        "import jax, jax.numpy as jnp, jaxabc; "
        "jax.jit(lambda x: x + 1)(jnp.ones(2)).block_until_ready(); "
        f"jaxabc.enable_compilation_cache({str(tmp_path / 'xla')!r}); "
        "jax.jit(lambda x: jnp.sin(x) * 2)(jnp.ones(3)).block_until_ready()"
    )
    assert any((tmp_path / "xla").iterdir())


_FUSED_RUN = (
    "import jax, numpy as np, jaxabc; "
    "hits = []; "
    "jax.monitoring.register_event_listener("
    "lambda name, **kw: hits.append(1) if name == '/jax/compilation_cache/cache_hits' else None); "
    "jaxabc.run_fused('apmcabc', lambda k, t: t + jax.random.normal(k, t.shape), "
    "jaxabc.Uniform([-5.0], [5.0]), np.zeros(1), num_particles=64, num_steps=2); "
    "print('hits', len(hits))"
)


def _fused_cache_hits(home, **env: str) -> int:
    return int(_fresh_process(_FUSED_RUN, HOME=str(home), **env).split("hits")[-1])


def test_run_fused_caches_its_programs_by_default(tmp_path):
    """Without any setting, a fused run stores its compiled programs under ~/.cache/jaxabc/xla
    and the next process loads them instead of compiling; ``JAXABC_COMPILATION_CACHE=off``
    keeps the cache off."""
    assert _fused_cache_hits(tmp_path / "on") == 0
    assert any((tmp_path / "on" / ".cache" / "jaxabc" / "xla").iterdir())
    assert _fused_cache_hits(tmp_path / "on") >= 2  # the start and chunk programs
    assert _fused_cache_hits(tmp_path / "off", JAXABC_COMPILATION_CACHE="off") == 0
    assert not (tmp_path / "off" / ".cache" / "jaxabc").exists()
