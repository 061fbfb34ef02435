"""Checkpoints: arrays + JSON, the problem fingerprint, refusals that say what to do."""

import json
import pickle
import re
import zipfile
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxabc
from jaxabc import checkpoint
from jaxabc.algorithms import ABCAlgorithm, Info, Proposal
from jaxabc.checkpoint import CheckpointError

KW = dict(num_particles=100, num_steps=3, distance="euclidean", seed=1)


def _partial(tmp_path, problem, algorithm="apmcabc", iterations=2, **kw):
    prior, simulate, observed = problem
    return jaxabc.run(
        algorithm, simulate, prior, observed, checkpoint_dir=tmp_path, stop_after_iterations=iterations, **{**KW, **kw}
    )


def test_checkpoint_is_arrays_and_json_and_resumes_every_algorithm(tmp_path, gaussian_problem):
    """A run stopped mid-generation (PMC refill rounds, subsim chain steps, rejection rounds)
    resumes from a file that loads without pickle to the uninterrupted run's result."""
    prior, simulate, observed = gaussian_problem
    cases = {
        "pmcabc": dict(num_steps=3),
        "abcsubsim": dict(num_steps=3),
        "rejection": dict(num_steps=None, threshold=1.0, max_simulations=5000),
    }
    for name, opts in cases.items():
        folder = tmp_path / name
        kw = {**KW, **opts}
        full = jaxabc.run(name, simulate, prior, observed, **kw)
        _partial(folder, gaussian_problem, name, iterations=3, **opts)
        with np.load(folder / "checkpoint.npz", allow_pickle=False) as data:
            header = json.loads(str(data["header"]))
            assert header["version"] == checkpoint.FORMAT_VERSION
            assert all(k.startswith(("state/", "posterior/", "records/", "header")) for k in data.files)
        assert header["fingerprint"]["algorithm"] == name
        rest = jaxabc.run(name, simulate, prior, observed, checkpoint_dir=folder, resume=True, **kw)
        np.testing.assert_array_equal(full.particles, rest.particles)
        np.testing.assert_array_equal(full.records["theta"], rest.records["theta"])
        assert full.num_simulations == rest.num_simulations


@pytest.mark.parametrize(
    "change, field",
    [
        (dict(observed=jnp.array([0.5])), "observed"),
        (dict(prior=jaxabc.Uniform([-10.0], [12.0], names=("mu",))), "prior"),
        (dict(prior=jaxabc.Uniform([-10.0], [10.0], names=("nu",))), "prior"),
        (dict(distance="mean_abs"), "distance"),
        (dict(simulate=lambda key, theta: theta + jax.random.normal(key, theta.shape)), "simulator"),
        (dict(seed=2), "seed"),
        (dict(alpha=0.2), "settings"),
        (dict(dtype="float64"), "dtype"),
    ],
)
def test_resume_refuses_a_changed_problem(tmp_path, gaussian_problem, change, field):
    prior, simulate, observed = gaussian_problem
    _partial(tmp_path, gaussian_problem)
    args = dict(prior=prior, simulate=simulate, observed=observed, **KW)
    args.update(change)
    with pytest.raises(
        CheckpointError, match=rf"fields differ:\n  {field}\b[^\n]*: (checkpoint|the values differ)"
    ) as err:
        jaxabc.run("apmcabc", checkpoint_dir=tmp_path, resume=True, **args)
    assert str(tmp_path) in str(err.value)


def test_simulator_id_keeps_the_identity_of_a_closure(tmp_path, gaussian_problem):
    prior, _, observed = gaussian_problem

    def make(scale):
        return lambda key, theta: theta + scale * jax.random.normal(key, theta.shape)

    kw = dict(KW, simulator_id="gaussian-noise-v1")
    full = jaxabc.run("apmcabc", make(1.0), prior, observed, **kw)
    jaxabc.run("apmcabc", make(1.0), prior, observed, checkpoint_dir=tmp_path, stop_after_iterations=2, **kw)
    rest = jaxabc.run("apmcabc", make(1.0), prior, observed, checkpoint_dir=tmp_path, resume=True, **kw)
    np.testing.assert_array_equal(full.particles, rest.particles)
    assert rest.metadata["simulator"] == "gaussian-noise-v1"


def test_fresh_run_into_a_checkpoint_folder_is_refused(tmp_path, gaussian_problem):
    prior, simulate, observed = gaussian_problem
    _partial(tmp_path, gaussian_problem)
    before = (tmp_path / "checkpoint.npz").read_bytes()
    with pytest.raises(FileExistsError, match=r"resume=True \(CLI: --resume\).*overwrite=True"):
        jaxabc.run("apmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, **KW)
    assert (tmp_path / "checkpoint.npz").read_bytes() == before
    fresh = jaxabc.run(
        "apmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, overwrite=True, **{**KW, "seed": 5}
    )
    plain = jaxabc.run("apmcabc", simulate, prior, observed, **{**KW, "seed": 5})
    np.testing.assert_array_equal(fresh.particles, plain.particles)


class _Trap:
    """Unpickling this creates a file: proof that a checkpoint was unpickled."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def test_old_pickle_checkpoint_is_refused_never_unpickled(tmp_path, gaussian_problem):
    prior, simulate, observed = gaussian_problem
    marker = tmp_path / "unpickled"
    (tmp_path / "checkpoint.pkl").write_bytes(pickle.dumps({"state": _Trap(marker)}))
    with pytest.raises(CheckpointError, match=r"checkpoint\.pkl is a checkpoint of an older jaxabc"):
        jaxabc.run("apmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, resume=True, **KW)
    with pytest.raises(FileExistsError, match=r"checkpoint\.pkl holds the checkpoint"):
        jaxabc.run("apmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, **KW)
    assert not marker.exists()


@pytest.mark.parametrize("damage", ["truncate", "garbage", "foreign", "directory", "no_state"])
def test_corrupt_checkpoint_is_a_clear_error_naming_the_file(tmp_path, gaussian_problem, damage):
    prior, simulate, observed = gaussian_problem
    _partial(tmp_path, gaussian_problem)
    path = tmp_path / "checkpoint.npz"
    data = path.read_bytes()
    if damage == "truncate":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "garbage":
        path.write_bytes(b"\x00" * 200)
    elif damage == "foreign":
        np.savez(path, particles=np.zeros(3))
    elif damage == "directory":
        path.unlink()
        path.mkdir()
    else:  # a well-formed file that lost a state leaf
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files if not k.startswith("state/")}
        with zipfile.ZipFile(path, "w") as zf:
            for k, v in arrays.items():
                with zf.open(k + ".npy", "w") as fh:
                    np.lib.format.write_array(fh, v)
    with pytest.raises(CheckpointError, match=re.escape(str(path))):
        jaxabc.run("apmcabc", simulate, prior, observed, checkpoint_dir=tmp_path, resume=True, **KW)


class _HostState(NamedTuple):
    particles: np.ndarray  # (n, d)
    distances: np.ndarray  # (n,)
    summary_means: np.ndarray  # (rounds,): mean summary of each batch, from `summaries`


def _host_best_of(prior, n: int, rounds: int) -> ABCAlgorithm:
    """A NumPy algorithm that reads the summaries: the n closest of ``rounds`` prior batches."""

    def first(key):
        return Proposal(np.asarray(prior.sample(key, n)), np.ones(n, bool), True)

    def info(state):
        done = len(state.summary_means) >= rounds
        return Info(True, done, state.distances[-1], 1.0 / rounds, float(n))

    def init(key, proposal, distances, summaries):
        order = np.argsort(distances, kind="stable")
        state = _HostState(proposal.thetas[order], distances[order], np.array([np.nanmean(summaries)]))
        return state, info(state)

    def update(key, state, proposal, distances, summaries):
        x = np.concatenate([state.particles, proposal.thetas])
        d = np.concatenate([state.distances, distances])
        order = np.argsort(d, kind="stable")[:n]
        means = np.append(state.summary_means, np.nanmean(summaries))
        state = _HostState(x[order], d[order], means)
        return state, info(state)

    def restore(flat):
        return _HostState(flat[".particles"], flat[".distances"], flat[".summary_means"])

    return ABCAlgorithm(
        "host_best_of",
        first,
        init,
        lambda key, state: first(key),
        update,
        lambda state: (state.particles, np.zeros(n)),
        {"rounds": rounds},
        host=True,
        uses_summaries=True,
        restore_state=restore,
        finalize=lambda state: {"summary_means": state.summary_means.tolist()},
    )


def test_host_algorithm_with_summaries_resumes_through_restore_state(tmp_path, gaussian_problem):
    prior, simulate, observed = gaussian_problem
    kw = dict(num_particles=50, distance="euclidean", seed=4)
    full = jaxabc.run(_host_best_of(prior, 50, 6), simulate, prior, observed, **kw)
    # Each batch's mean summary is the mean of its simulated x = theta + noise.
    per_batch = full.records["summaries"][:, 0].reshape(6, 50).mean(axis=1)
    np.testing.assert_allclose(full.metadata["summary_means"], per_batch, rtol=1e-5)
    jaxabc.run(
        _host_best_of(prior, 50, 6), simulate, prior, observed, checkpoint_dir=tmp_path, stop_after_iterations=3, **kw
    )
    rest = jaxabc.run(
        _host_best_of(prior, 50, 6), simulate, prior, observed, checkpoint_dir=tmp_path, resume=True, **kw
    )
    np.testing.assert_array_equal(full.particles, rest.particles)
    assert rest.metadata["summary_means"] == full.metadata["summary_means"]
