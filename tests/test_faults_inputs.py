"""Inputs that cannot make a calibration are refused at the boundary, with a message naming them.

Distances that cannot be distances (a KL density of a constant series, negative values), a
tampered result file, ``save()`` into a folder, seeds JAX would mangle, an observed value beyond
float32, complex summaries, and process-pool workers recycled after a number of tasks.
"""

import os
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxabc
from jaxabc import examples
from jaxabc.distances import kl_divergence
from jaxabc.driver.fused import run_fused
from jaxabc.executors import ProcessPoolExecutor, SerialExecutor, VmapExecutor

PRIOR = jaxabc.Uniform([-3.0], [3.0])
OBSERVED = np.array([0.5])
# The two drivers: the default fused program (a JAX simulator and distance) and the host driver.
DRIVERS = [None, "vmap"]


def _run(executor=None, simulate=examples.gaussian_simulate, observed=OBSERVED, **options):
    settings = {"num_particles": 50, "num_steps": 2, "distance": "euclidean", "seed": 0, **options}
    return jaxabc.run("apmcabc", simulate, PRIOR, observed, executor=executor, **settings)


def noisy_series(key, theta):
    """A series of 20 draws around theta (what a KL distance compares)."""
    return theta[0] + jax.random.normal(key, (20,))


def signed_difference(observed, simulated):
    """mean(observed - simulated): the abs() forgotten, so half the prior is 'closer than exact'."""
    return jnp.mean(observed - simulated)


def constant_simulate(key, theta):
    """Ignores theta: every distance is the same, and the posterior is (rightly) the prior."""
    return jnp.zeros((1,))


def complex_simulate(key, theta):
    return theta * (1.0 + 1.0j)


def host_complex_simulate(key, theta):
    return np.asarray(theta) * (1.0 + 1.0j)


def pid_simulate(key, theta):
    """``(pid of the worker, the Gaussian simulator's draw)``: which process ran the task."""
    return np.concatenate([[float(os.getpid())], examples.host_gaussian_simulate(key, theta)])


# -- distances that cannot be distances ---------------------------------------------------------


@pytest.mark.parametrize("observed", [np.full(30, 2.0), np.array([1.0])], ids=["constant", "one-element"])
def test_kl_of_an_observed_series_without_spread_is_nan_as_documented(observed):
    """It returned 0 for every simulation: threshold 0 and the prior as 'posterior'."""
    simulated = jnp.linspace(0.0, 4.0, 40)
    assert np.isnan(float(kl_divergence(jnp.asarray(observed), simulated)))
    # A well-posed pair is still finite and non-negative.
    assert 0.0 <= float(kl_divergence(simulated, simulated + 0.3)) < np.inf


@pytest.mark.parametrize("executor", DRIVERS)
@pytest.mark.parametrize(
    ("observed", "why"),
    [(np.full(30, 2.0), "zero spread"), (np.array([2.0]), "1 element")],
    ids=["constant", "one-element"],
)
def test_kl_with_an_observed_series_without_spread_is_refused_before_simulating(executor, observed, why):
    with pytest.raises(ValueError, match=f"(?s)kl.*{why}"):
        _run(executor, noisy_series, observed, distance="kl")


@pytest.mark.parametrize("executor", DRIVERS)
def test_a_distance_with_negative_values_is_refused(executor):
    with pytest.raises(ValueError, match=r"the distance returned negative values \(min -"):
        _run(executor, distance=signed_difference)


def per_summary_difference(observed, simulated):
    """|observed - simulated| per summary: the reduction to one number forgotten."""
    return jnp.abs(observed - simulated)


@pytest.mark.parametrize("executor", [*DRIVERS, "serial"])
def test_a_distance_that_returns_a_vector_is_refused(executor):
    """It failed with NumPy's or JAX's broadcasting error from inside the algorithm."""
    simulate = examples.host_gaussian_simulate if executor == "serial" else examples.gaussian_simulate
    with pytest.raises(ValueError, match=r"one number per simulation, but it returned shape \(1,\)"):
        _run(executor, simulate, distance=per_summary_difference)


@pytest.mark.parametrize("executor", DRIVERS)
def test_a_distance_that_does_not_tell_parameters_apart_warns_but_runs(executor):
    """A simulator that ignores theta is a legitimate (if useless) model: its posterior is the
    prior.  The run says so instead of refusing."""
    with pytest.warns(UserWarning, match="all 50 distances of the first population equal"):
        result = _run(executor, constant_simulate)
    assert np.all(result.distances == 0.5)


def test_a_distance_that_does_not_tell_parameters_apart_warns_on_the_host_executors():
    with pytest.warns(UserWarning, match="posterior will be the prior"):
        _run("serial", lambda key, theta: np.zeros(1), num_particles=20)


@pytest.mark.parametrize("executor", DRIVERS)
def test_ordinary_runs_do_not_warn(executor):
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        _run(executor)


# -- result files -------------------------------------------------------------------------------


def _saved_result(tmp_path):
    return _run("serial", examples.host_gaussian_simulate, num_particles=20).save(tmp_path / "r.npz")


@pytest.mark.parametrize(
    ("field", "change"),
    [
        ("weights", lambda a: a[:-3]),
        ("distances", lambda a: np.concatenate([a, a])),
        ("particles", lambda a: a[:, 0]),
        ("ess", lambda a: a[:-1]),
        ("record_status", lambda a: a[:5]),
    ],
)
def test_a_tampered_result_file_names_the_field_and_the_file(tmp_path, field, change):
    path = _saved_result(tmp_path)
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    arrays[field] = change(arrays[field])
    np.savez_compressed(path, **arrays)
    with pytest.raises(ValueError, match=f"(?s){path}.*{field}"):
        jaxabc.load(path)


def test_save_into_an_existing_folder_writes_result_npz_inside_it(tmp_path):
    """It wrote a sibling ``<folder>.npz`` next to the folder."""
    result = _run("serial", examples.host_gaussian_simulate, num_particles=20)
    folder = tmp_path / "run1"
    folder.mkdir()
    assert result.save(folder) == folder / "result.npz"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run1"]
    np.testing.assert_array_equal(jaxabc.load(folder / "result.npz").particles, result.particles)
    with pytest.raises(FileExistsError):
        result.save(folder)
    # A path ending in a separator names a folder, created if missing.
    assert result.save(f"{tmp_path / 'new'}{os.sep}") == tmp_path / "new" / "result.npz"


# -- seeds --------------------------------------------------------------------------------------

BAD_SEEDS = [2**70, 2**32, -1, "0", 1.5, True, None]


@pytest.mark.parametrize("executor", DRIVERS)
@pytest.mark.parametrize("seed", BAD_SEEDS, ids=repr)
def test_bad_seeds_are_refused_at_the_boundary(executor, seed):
    with pytest.raises((TypeError, ValueError), match=r"seed must be an integer with 0 <= seed < 2\*\*32"):
        _run(executor, seed=seed)


@pytest.mark.parametrize("seed", [2**70, "0", -5])
def test_bad_seeds_are_refused_by_run_fused_and_model_choice(seed):
    match = r"seed must be an integer with 0 <= seed < 2\*\*32"
    with pytest.raises((TypeError, ValueError), match=match):
        run_fused("apmcabc", examples.gaussian_simulate, PRIOR, OBSERVED, 50, 2, seed=seed)
    models = [(examples.gaussian_simulate, PRIOR), (constant_simulate, PRIOR)]
    with pytest.raises((TypeError, ValueError), match=match):
        jaxabc.run(models, observed=OBSERVED, num_particles=50, num_steps=2, seed=seed)


@pytest.mark.parametrize("executor", DRIVERS)
def test_numpy_and_largest_seeds_give_the_keys_of_python_ints(executor):
    """Valid seeds map to the same keys as before: a NumPy integer is its Python value."""
    a = _run(executor, seed=np.int64(7))
    b = _run(executor, seed=7)
    np.testing.assert_array_equal(a.particles, b.particles)
    assert type(a.seed) is int
    top = _run(executor, seed=np.uint32(2**32 - 1), dtype="float64")
    np.testing.assert_array_equal(top.particles, _run(executor, seed=2**32 - 1, dtype="float64").particles)


# -- observed data and summaries ------------------------------------------------------------------


@pytest.mark.parametrize("executor", DRIVERS)
def test_an_observed_value_beyond_float32_is_blamed_on_the_data_not_the_simulator(executor):
    with pytest.raises(ValueError, match=r"(?s)overflows float32.*dtype='float64'"):
        _run(executor, observed=np.array([1e39]))


@pytest.mark.parametrize("executor", DRIVERS)
def test_complex_summaries_from_a_jax_simulator_are_refused(executor):
    with pytest.raises(TypeError, match="complex summaries"):
        _run(executor, complex_simulate)


def test_complex_summaries_from_a_host_simulator_are_refused():
    with pytest.raises(TypeError, match="complex summaries"):
        _run("serial", host_complex_simulate, num_particles=20)


def test_executors_refuse_complex_summaries_themselves():
    keys = np.zeros((3, 2), np.uint32)
    thetas = np.ones((3, 1))
    with pytest.raises(TypeError, match="complex summaries"):
        SerialExecutor().map(host_complex_simulate, keys, thetas)
    with pytest.raises(TypeError, match="complex summaries"):
        VmapExecutor().map(complex_simulate, keys, thetas)


# -- process pool ---------------------------------------------------------------------------------


def test_pool_workers_are_replaced_after_max_tasks_per_worker():
    """Each task in a fresh process (a simulator that leaks memory or file handles gets a clean
    one), and the summaries are the serial executor's to the bit: keys belong to tasks."""
    keys = np.asarray(jax.random.key_data(jax.random.split(jax.random.key(3), 5)))
    thetas = np.linspace(-1.0, 1.0, 5)[:, None]
    ex = ProcessPoolExecutor(max_workers=2, max_tasks_per_worker=1)
    try:
        batch = ex.map(pid_simulate, keys, thetas)
    finally:
        ex.close()
    assert np.all(batch.status == 0), batch.reasons
    assert len(set(batch.summaries[:, 0])) == 5  # five processes for five tasks
    assert len(set(batch.worker.tolist())) == 5
    serial = SerialExecutor().map(pid_simulate, keys, thetas)
    np.testing.assert_array_equal(batch.summaries[:, 1:], serial.summaries[:, 1:])


@pytest.mark.parametrize("value", [0, -1, 1.5])
def test_max_tasks_per_worker_must_be_a_positive_integer(value):
    with pytest.raises(ValueError, match="max_tasks_per_worker"):
        ProcessPoolExecutor(max_workers=1, max_tasks_per_worker=value)
