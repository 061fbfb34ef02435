"""Contracts behind whole-run speed: what importing jaxabc costs, PMC-ABC's refill rounds, and
a plain run's silence.  Speed itself is measured in benchmarks/abc_overhead.py, not here."""

import json
import math
import os
import subprocess
import sys
import warnings
from pathlib import Path

import jax
import numpy as np

import jaxabc

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("jax_md", "mdtraj", "matplotlib", "tqdm", "mpi4py")


def _fresh_python(code: str) -> str:
    out = subprocess.run(
        [sys.executable, "-c", code],
        check=True,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONPATH": str(ROOT)},
    )
    return out.stdout.strip().splitlines()[-1]


def test_import_and_version_stamp_skip_heavy_modules():
    """``import jaxabc`` and stamping versions into a result import no simulator or plotting
    package (jax-md alone takes seconds to import)."""
    code = (
        "import sys, json, jaxabc; from jaxabc.results import versions; v = versions(); "
        f"print(json.dumps([[m for m in {HEAVY!r} if m in sys.modules], v]))"
    )
    loaded, stamped = json.loads(_fresh_python(code))
    assert loaded == []
    assert stamped["jax"] == jax.__version__
    assert stamped["jaxabc"] == jaxabc.__version__


def test_lazy_public_names_resolve():
    assert jaxabc.coverage_study.__name__ == "coverage_study"
    assert jaxabc.MPIExecutor.__name__ == "MPIExecutor"
    assert callable(jaxabc.run_fused) and callable(jaxabc.run)
    assert set(jaxabc.__all__) <= set(dir(jaxabc))


def _gaussian(key, theta):
    return theta + jax.random.normal(key, theta.shape)


def test_pmc_refill_takes_few_rounds():
    """Over-proposal fills a generation in a few rounds; one proposal per empty slot needs
    about log(N) / acceptance rounds (dozens here).  The fill keeps accepted proposals in
    order, so every generation still has exactly N distinct accepted particles."""
    prior = jaxabc.Uniform([-10.0], [10.0], names=("mu",))
    n = 2000
    r = jaxabc.run(
        "pmcabc",
        _gaussian,
        prior,
        np.zeros(1),
        num_particles=n,
        num_steps=4,
        distance="euclidean",
        seed=1,
        keep_summaries=False,
    )
    iterations = int(r.records["iteration"].max()) + 1
    rounds = iterations - 1  # generation 0 is one batch of prior draws
    slow_rounds = sum(math.log(n) / a for a in r.acceptance_rates[1:])
    assert rounds <= 3 * 3, (rounds, r.acceptance_rates)
    assert slow_rounds > 3 * rounds
    assert r.particles.shape == (n, 1)
    assert np.all(r.distances <= r.thresholds[-1])
    # Surplus acceptances are discarded: a generation costs about N / acceptance simulations,
    # plus the margin of its rounds (two binomial standard deviations, and the gap between
    # the previous generation's acceptance, which sizes the first round, and its own).
    assert np.all(r.simulations_per_step[1:] < 1.5 * n / r.acceptance_rates[1:])


def test_plain_run_is_silent():
    """A small run with default settings warns about nothing a user could act on."""
    prior = jaxabc.Uniform([-10.0, -10.0], [10.0, 10.0], names=("a", "b"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        jaxabc.run("apmcabc", _gaussian, prior, np.zeros(2), num_particles=100, num_steps=2, distance="euclidean")
    assert [str(w.message) for w in caught] == []
