"""ABCResult: safe files, clear load errors, Monte Carlo errors from the honest ESS, ArviZ export."""

from __future__ import annotations

import json
import math
import os
import zipfile

import numpy as np
import pytest

import jaxabc
from jaxabc.results import ABCResult

PRIOR = jaxabc.Uniform(low=[-10.0, 0.0], high=[10.0, 5.0], names=("sigma", "epsilon"))


def _result(seed: int = 0, n: int = 200) -> ABCResult:
    rng = np.random.default_rng(seed)
    particles = np.column_stack([rng.normal(1.0, 0.5, n), rng.uniform(1.0, 2.0, n)])
    result = ABCResult.from_sample(particles, rng.uniform(0.5, 1.5, n), PRIOR, algorithm="apmcabc")
    result.distances = rng.uniform(0.0, 1.0, n)
    result.metadata = {"observed": [0.1, 0.2, 0.3]}
    result.records = {
        "theta": particles,
        "distance": result.distances,
        "status": np.zeros(n, np.int32),
        "reasons": [""] * n,
    }
    return result


def _chain_result(num_chains: int = 40, chain_length: int = 5, distinct_chains: int = 40, seed: int = 0) -> ABCResult:
    """An ABCsubsim-like population: ``num_chains`` AR(0.5) chains, step-major like the state."""
    rng = np.random.default_rng(seed)
    x = np.zeros((num_chains, chain_length, 2))
    x[:, 0] = rng.normal(size=(num_chains, 2))
    for t in range(1, chain_length):
        x[:, t] = 0.5 * x[:, t - 1] + math.sqrt(0.75) * rng.normal(size=(num_chains, 2))
    x = x[np.arange(num_chains) % distinct_chains]
    n = num_chains * chain_length
    return ABCResult(
        particles=x.swapaxes(0, 1).reshape(n, 2),
        weights=np.full(n, 1.0 / n),
        distances=np.arange(n, dtype=float),
        thresholds=np.array([np.inf, 1.0, 0.5]),
        simulations_per_step=np.array([n, n, n]),
        acceptance_rates=np.array([1.0, 0.4, 0.3]),
        ess=np.array([n, n, n], float),
        num_simulations=3 * n,
        algorithm="abcsubsim",
        settings={
            "num_particles": n,
            "p0": 1.0 / chain_length,
            "chain_length": chain_length,
            "num_chains": num_chains,
            "final_threshold": 0.0,
            "acceptance_floor": 0.0,
        },
        prior=PRIOR,
        seed=seed,
        check=False,
    )


# -- save ---------------------------------------------------------------------------------------


def test_save_appends_npz_to_dotted_names(tmp_path):
    """'run_alpha0.1' and 'run_alpha0.2' are two files (main wrote both to run_alpha0.npz)."""
    a, b = _result(1), _result(2)
    path_a = a.save(tmp_path / "run_alpha0.1")
    path_b = b.save(tmp_path / "run_alpha0.2")
    assert path_a.name == "run_alpha0.1.npz" and path_b.name == "run_alpha0.2.npz"
    np.testing.assert_array_equal(jaxabc.load(path_a).particles, a.particles)
    np.testing.assert_array_equal(jaxabc.load(path_b).particles, b.particles)
    assert a.save(tmp_path / "named.npz").name == "named.npz"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["named.npz", "run_alpha0.1.npz", "run_alpha0.2.npz"]


def test_save_never_overwrites_unless_asked(tmp_path):
    first, second = _result(1), _result(2)
    path = first.save(tmp_path / "run")
    with pytest.raises(FileExistsError, match="overwrite=True"):
        second.save(tmp_path / "run")
    np.testing.assert_array_equal(jaxabc.load(path).particles, first.particles)
    second.save(tmp_path / "run.npz", overwrite=True)
    np.testing.assert_array_equal(jaxabc.load(path).particles, second.particles)


def test_save_is_atomic(tmp_path, monkeypatch):
    """A save that fails midway leaves the old file whole and no temporary file behind."""
    first = _result(1)
    path = first.save(tmp_path / "run")

    def broken(fh, **arrays):
        fh.write(b"PK\x03\x04 half a zip")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", broken)
    with pytest.raises(OSError, match="disk full"):
        _result(2).save(path, overwrite=True)
    assert [p.name for p in tmp_path.iterdir()] == ["run.npz"]
    np.testing.assert_array_equal(jaxabc.load(path).particles, first.particles)


# -- load ---------------------------------------------------------------------------------------


def _truncated(path):
    data = _result().save(path.with_name("whole")).read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _garbage(path):
    path.write_bytes(os.urandom(3000))


def _foreign(path):
    with open(path, "wb") as fh:
        np.savez(fh, x=np.arange(3), y=np.ones(2))


def _npy(path):
    with open(path, "wb") as fh:
        np.save(fh, np.arange(3))


def _pickled(path):
    with open(path, "wb") as fh:
        np.savez(fh, metadata=np.array([{"a": 1}], dtype=object))


def _bad_json(path):
    with open(path, "wb") as fh:
        np.savez(fh, metadata="{not json")


def _other_format(path):
    with open(path, "wb") as fh:
        np.savez(fh, metadata=json.dumps({"format": "pyabc-7"}))


def _missing_arrays(path):
    meta = _result().to_metadata()
    with open(path, "wb") as fh:
        np.savez(fh, metadata=json.dumps(meta), particles=np.zeros((3, 2)))


def _bad_member(path):
    _result().save(path.with_name("whole"))
    with zipfile.ZipFile(path.with_name("whole.npz")) as src, zipfile.ZipFile(path, "w") as dst:
        for info in src.infolist():
            data = src.read(info)
            dst.writestr(info, data[:10] if info.filename == "particles.npy" else data)


@pytest.mark.parametrize(
    "make, message",
    [
        (_truncated, "corrupt or truncated"),
        (_garbage, "not a jaxabc result file"),
        (_foreign, "without jaxabc metadata"),
        (_npy, "single .npy array"),
        (_pickled, "not a jaxabc result file"),
        (_bad_json, "not valid JSON"),
        (_other_format, "pyabc-7"),
        (_missing_arrays, "missing weights, distances"),
        (_bad_member, "corrupt or truncated|not a jaxabc result file"),
    ],
)
def test_load_explains_what_is_wrong_with_a_file(tmp_path, make, message):
    path = tmp_path / "bad.npz"
    make(path)
    with pytest.raises(ValueError, match=message) as info:
        jaxabc.load(path)
    assert str(path) in str(info.value)


def test_load_of_a_missing_file_or_a_directory(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nothing_here\.npz"):
        jaxabc.load(tmp_path / "nothing_here.npz")
    with pytest.raises(ValueError, match="is a directory"):
        jaxabc.load(tmp_path)


def _write_like_main(result: ABCResult, path) -> None:
    """A result file exactly as the code before this change wrote it (no diagnostics)."""
    meta = result.to_metadata()
    del meta["diagnostics"]
    arrays = {
        k: getattr(result, k)
        for k in ("particles", "weights", "distances", "thresholds", "simulations_per_step", "acceptance_rates", "ess")
    }
    arrays.update({f"record_{k}": np.asarray(v) for k, v in result.records.items() if k != "reasons"})
    np.savez_compressed(path, metadata=json.dumps(meta), **arrays)


def test_old_result_files_still_load_and_get_an_honest_ess(tmp_path):
    old = _result(3)
    _write_like_main(old, tmp_path / "old.npz")
    loaded = jaxabc.load(tmp_path / "old.npz")
    np.testing.assert_allclose(loaded.bayes_estimate(), old.bayes_estimate())
    np.testing.assert_array_equal(loaded.records["status"], old.records["status"])
    # An ABCsubsim file from before stored ESS = N for its chains; loading gives the honest one.
    chains = _chain_result(distinct_chains=10)
    _write_like_main(chains, tmp_path / "subsim.npz")
    loaded = jaxabc.load(tmp_path / "subsim.npz")
    assert loaded.ess[-1] <= loaded.diagnostics["num_distinct"] == 50 < 200
    assert loaded.effective_sample_size() == loaded.ess[-1]


# -- Monte Carlo errors ---------------------------------------------------------------------------


def test_mcse_of_weighted_independent_draws():
    """sd / sqrt(Kish ESS): over independent data sets the estimate's spread matches it."""
    errors, mcses = [], []
    for seed in range(200):
        rng = np.random.default_rng(seed)
        x = rng.normal(0.0, 2.0, size=(100, 2))
        r = ABCResult.from_sample(x, rng.uniform(0.2, 1.0, 100), PRIOR)
        errors.append(r.bayes_estimate())
        mcses.append(r.mcse())
    ratio = np.std(errors, axis=0) / np.mean(mcses, axis=0)
    np.testing.assert_allclose(ratio, 1.0, atol=0.15)


def test_chain_population_uses_the_chain_ess_in_errors_and_summary():
    r = _chain_result(distinct_chains=40)
    r.__post_init__(check=False)
    assert r.effective_sample_size() < 200
    kish_mcse = np.sqrt(np.diag(r.covariance()) / 200)
    assert np.all(r.mcse() > kish_mcse)
    assert "MCSE" in r.summary() and f"ESS {r.effective_sample_size():.1f} of 200" in r.summary()


def test_ess_adjusted_credible_intervals_cover_closer_to_nominal():
    """10 equally weighted draws: the plain 95 % interval is [min, max] (coverage 9/11 for a
    new draw); the ESS-adjusted one is wider and covers more, still nested in the prior-free
    limit (identical for a large ESS)."""
    prior = jaxabc.Uniform(low=[-10.0], high=[10.0], names=("a",))
    rng = np.random.default_rng(0)
    plain = adjusted = 0
    reps = 1500
    for _ in range(reps):
        r = ABCResult.from_sample(rng.normal(size=(10, 1)), np.ones(10), prior)
        truth = rng.normal()
        lo, hi = r.credible_interval(0.95)[0]
        plain += lo <= truth <= hi
        lo, hi = r.credible_interval(0.95, adjust_for_ess=True)[0]
        adjusted += lo <= truth <= hi
    se = math.sqrt(0.9 * 0.1 / reps)
    assert abs(plain / reps - 9 / 11) < 4 * se
    assert adjusted / reps > plain / reps + 4 * se
    big = ABCResult.from_sample(rng.normal(size=(20000, 1)), np.ones(20000), prior)
    np.testing.assert_allclose(big.credible_interval(0.9, adjust_for_ess=True), big.credible_interval(0.9), rtol=0.01)


# -- ArviZ ----------------------------------------------------------------------------------------


def test_to_arviz_resamples_weighted_particles():
    import arviz as az

    r = _result(4, n=500)
    idata = r.to_arviz(num_draws=4000, seed=1)
    assert set(idata.posterior.data_vars) == {"sigma", "epsilon"}
    assert idata.posterior["sigma"].shape == (1, 4000)
    assert "4000 draws resampled by weight" in idata.attrs["draws"]
    assert idata.sample_stats["distance"].shape == (1, 4000)
    np.testing.assert_allclose(idata.observed_data["observed"], [0.1, 0.2, 0.3])
    np.testing.assert_allclose(idata.constant_data["threshold"], r.thresholds)
    summary = az.summary(idata, kind="stats")
    # Resampling adds its own error: within 4 MCSE of the weighted mean plus 4 resampling errors.
    tol = 4 * (r.mcse() + np.sqrt(np.diag(r.covariance()) / 4000))
    np.testing.assert_array_less(np.abs(summary.loc[["sigma", "epsilon"], "mean"].to_numpy() - r.bayes_estimate()), tol)


def test_to_arviz_keeps_abcsubsim_chains():
    import arviz as az

    r = _chain_result(num_chains=40, chain_length=5)
    idata = r.to_arviz()
    assert idata.posterior["sigma"].shape == (40, 5)
    # Chain c of the export is chain c of the population (step-major in the result).
    np.testing.assert_array_equal(idata.posterior["sigma"].values[3], r.particles[3::40, 0])
    np.testing.assert_array_equal(idata.sample_stats["distance"].values[3], r.distances[3::40])
    summary = az.summary(idata)
    np.testing.assert_allclose(summary.loc["sigma", "mean"], r.bayes_estimate()[0], atol=1e-3)
    with pytest.raises(ValueError, match="num_draws"):
        _result().to_arviz(num_draws=0)
