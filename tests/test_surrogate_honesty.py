"""The surrogate says what it does not know: a step it smooths over, the emulator's share of
the Monte Carlo error, data no parameter reproduces, and simulator noise that grows with theta.

Exact answers: the step's posterior is U(0.5, 5) (mean 2.75); the conjugate Gaussian's
N(0.7, 1); the heteroscedastic problem's by quadrature of its exact (synthetic) likelihood.
The multi-seed versions are ``slow`` (``pytest -m slow tests/test_surrogate_honesty.py``).
"""

from __future__ import annotations

import subprocess
import sys
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxabc
from benchmarks.surrogate_honesty import CASES
from jaxabc.surrogate import diagnostics, emulator

# The problems, and their exact posteriors, are the surrogate_honesty benchmark's.
step_simulate, _, _, _exact_step, _, _ = CASES["step"]
STEP_MEAN = float(_exact_step()[0][0])  # the exact posterior U(0.5, 5)
gaussian_simulate = CASES["conjugate"][0]
growing_noise_simulate, _, _, _exact_growing_noise, _, _ = CASES["heteroscedastic"]
banana_simulate, _, _, _exact_banana, _, _ = CASES["banana"]


def run_quiet(*args, **kwargs) -> jaxabc.ABCResult:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return jaxabc.run("surrogate", *args, num_particles=1000, **kwargs)


def posterior_mean(r: jaxabc.ABCResult) -> float:
    return float(r.weights @ r.particles[:, 0])


def check_step(seed: int) -> None:
    prior = jaxabc.Uniform([-5.0], [5.0], names=("t",))
    r = run_quiet(step_simulate, prior, np.array([3.0]), max_simulations=200, seed=seed)
    validated = bool(r.diagnostics["validated"])
    assert r.stop_reason.startswith("emulator validated") == validated
    if validated:
        # A validated posterior's error is within its reported MCSE (which now holds the
        # emulator's error): before, seeds 0-2 were "validated" 4-9 MCSE off.
        assert abs(posterior_mean(r) - STEP_MEAN) <= 3.0 * r.mcse()[0], (posterior_mean(r), r.mcse())
    else:
        assert r.stop_reason.startswith("NOT VALIDATED")
        assert r.diagnostics["failure"] in r.stop_reason


def test_step_not_validated_where_the_emulator_smooths_it():
    check_step(1)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 2, 3, 4])
def test_step_seeds(seed):
    check_step(seed)


def conjugate_z(seed: int) -> tuple[float, jaxabc.ABCResult]:
    prior = jaxabc.Uniform([-10.0], [10.0], names=("t",))
    r = run_quiet(gaussian_simulate, prior, np.array([0.7]), max_simulations=200, seed=seed)
    return (posterior_mean(r) - 0.7) / float(r.mcse()[0]), r


def test_mcse_holds_the_emulator_error():
    z, r = conjugate_z(3)
    d = r.diagnostics
    assert d["mcse_emulator"][0] > d["mcse_sampling"][0] > 0
    assert np.isclose(r.mcse()[0] ** 2, d["mcse_sampling"][0] ** 2 + d["mcse_emulator"][0] ** 2)
    assert abs(z) < 4.0
    # A model that fits: no misfit verdict in front of the stop reason.
    assert not r.stop_reason.startswith("MISFIT") and "warning" not in d


@pytest.mark.slow
def test_mcse_over_ten_seeds():
    # Before the emulator term, 3 of 10 seeds were beyond 4 MCSE (rms z 3.8).
    zs = np.array([conjugate_z(seed)[0] for seed in range(10)])
    assert np.all(np.abs(zs) < 4.0), zs
    assert np.sqrt(np.mean(zs**2)) < 2.0, zs


def banana_exact_sd() -> np.ndarray:
    """The exact posterior sds of ``x = (a, b + a^2) + (1, 0.3) z`` at ``x = (0, 0.5)`` on
    U(-5, 5)^2, by an 801^2 grid (b's posterior is a ridge 0.3 wide about ``0.5 - a^2``)."""
    return _exact_banana()[1]


def banana_sd_ratio(seed: int) -> np.ndarray:
    prior = jaxabc.Uniform([-5.0, -5.0], [5.0, 5.0], names=("a", "b"))
    r = run_quiet(banana_simulate, prior, np.array([0.0, 0.5]), max_simulations=200, seed=seed)
    x, w = np.asarray(r.particles), np.asarray(r.weights)
    m = w @ x
    return np.sqrt(w @ (x - m) ** 2) / banana_exact_sd()


def test_the_early_stop_on_a_banana_is_not_overconfident():
    # Seed 4 stopped at 148 of 200 simulations with sds 0.83 and 0.76 of exact.  One seed's
    # design path is sensitive to any change upstream (0.90/0.90 after the NUTS step rule
    # alone, 0.81/0.77 once the GP was also padded to fewer rows at the box centre); the
    # five-seed test below is the check of bias, this one a quick guard against a collapse.
    ratio = banana_sd_ratio(4)
    assert np.all(ratio > 0.85), ratio


@pytest.mark.slow
def test_the_banana_sd_over_five_seeds():
    # The sd of 1000 NUTS draws (ESS 200-300) itself scatters by about 5-7 % here.
    ratios = np.array([banana_sd_ratio(seed) for seed in range(5)])
    assert np.all(ratios > 0.8), ratios
    assert abs(np.exp(np.mean(np.log(ratios))) - 1.0) < 0.1, ratios


def test_misfit_is_part_of_the_result(tmp_path):
    prior = jaxabc.Uniform([-3.0], [3.0], names=("t",))

    def saturating(key, theta):
        return 5.0 * jnp.tanh(theta) + 0.1 * jax.random.normal(key, theta.shape)

    r = run_quiet(saturating, prior, np.array([100.0]), max_simulations=60, seed=0)
    assert r.stop_reason.startswith("MISFIT: ")
    assert "MISFIT" in r.summary()
    assert "posterior predictive" in r.diagnostics["warning"]
    path = r.save(tmp_path / "misfit")
    assert jaxabc.load(path).stop_reason == r.stop_reason
    shown = subprocess.run(
        [sys.executable, "-m", "jaxabc.cli", "show", str(path)], capture_output=True, text=True, check=True
    ).stdout
    assert "MISFIT" in shown


def growing_noise_run(seed: int, noise_model: str) -> tuple[float, float]:
    """Posterior mean error and sd ratio against the exact posterior (quadrature)."""
    prior = jaxabc.Uniform([0.0], [10.0], names=("t",))
    (mean,), (sd,) = _exact_growing_noise()  # quadrature of the exact synthetic likelihood
    r = run_quiet(
        growing_noise_simulate, prior, np.array([5.0]), max_simulations=200, seed=seed, noise_model=noise_model
    )
    x, w = r.particles[:, 0], r.weights
    m = w @ x
    return (m - mean) / sd, np.sqrt(w @ (x - m) ** 2) / sd


def test_heteroscedastic_noise_matches_the_exact_synthetic_likelihood():
    err, ratio = growing_noise_run(1, "auto")
    # Homoscedastic noise puts the mean 0.42-0.48 sd low on seeds 0-2 (the slow test checks it).
    assert abs(err) < 0.2 and abs(ratio - 1) < 0.15, (err, ratio)


@pytest.mark.slow
def test_heteroscedastic_over_seeds_and_against_homoscedastic():
    auto = np.array([growing_noise_run(seed, "auto") for seed in range(3)])
    flat = np.array([growing_noise_run(seed, "homoscedastic") for seed in range(3)])
    assert np.all(np.abs(auto[:, 0]) < 0.2) and np.all(np.abs(auto[:, 1] - 1) < 0.15), auto
    assert np.all(flat[:, 0] < -0.3), flat


def test_noise_profile_recovers_a_known_slope():
    rng = np.random.default_rng(0)
    n = 4000
    u = rng.uniform(size=(n, 1))
    log_var = -1.0 + 2.0 * (u[:, 0] - 0.5)
    r = np.exp(0.5 * log_var)[:, None] * rng.standard_normal((n, 1))
    coef, p = emulator.fit_noise_profile(u, r)
    # Slope 2 per unit; the log chi2_1 noise (variance pi^2/2) gives a standard error of
    # about sqrt(4.93 / (n var(u))) ~ 0.12 for the slope (the quadratic term widens it a little).
    assert abs(coef[0, 1] - 2.0) < 4 * 0.15, coef
    assert p[0] < 1e-10
    flat = rng.standard_normal((n, 1))
    _, p_flat = emulator.fit_noise_profile(u, flat)
    assert p_flat[0] > 1e-3


def test_heteroscedastic_fit_with_padded_rows_finds_the_noise_level():
    # The design loop pads the emulator's rows; a profile that grows with x (a positive quadratic
    # term) once overflowed at the padding inputs and turned the gradient to NaN, so the fit
    # stopped at its start.  Known level: the rows' mean log noise sd (the profile is centred).
    rng = np.random.default_rng(3)
    n, size = 150, 256
    u = rng.uniform(size=(n, 1))
    log_var = 2.0 * (-1.5) + 6.0 * (u[:, 0] - 0.5) + 8.0 * (u[:, 0] - 0.5) ** 2
    z = np.sin(3 * u) + np.exp(0.5 * log_var)[:, None] * rng.standard_normal((n, 1))
    coef, p = emulator.fit_noise_profile(u, z - np.sin(3 * u))
    assert p[0] < 1e-6 and coef[0, 2] > 0, (coef, p)
    x = np.full((size, 1), 0.5)
    zf = np.zeros((size, 1))
    x[:n], zf[:n] = u, z
    mask = np.arange(size) < n
    emu = emulator.fit(x, zf, mask, noise_coef=coef)
    # Up to the estimation error of 150 residuals' mean log sd (sd of a mean log chi2_1 over 2,
    # about 0.09) and of the profile's shape.
    level = 0.5 * log_var.mean()
    assert abs(float(emu.log_noise[0]) - level) < 0.3, (emu.log_noise, level)
    assert np.all(np.isfinite(np.asarray(emu.alpha)))


def test_a_fit_that_cannot_be_evaluated_is_an_error_not_its_start():
    # A NaN output makes the marginal likelihood non-finite everywhere: the fit once returned its
    # start as if it had converged.  With a warm start it also tries the default starts first.
    rng = np.random.default_rng(0)
    x = rng.uniform(size=(20, 2))
    z = np.sin(3 * x[:, :1])
    z[4, 0] = np.nan
    mask = np.ones(20, bool)
    with pytest.raises(FloatingPointError, match="not finite at any start"):
        emulator.fit(x, z, mask)
    with pytest.raises(FloatingPointError, match="not finite at any start"):
        emulator.fit(x, z, mask, init=np.zeros((1, 4)))
    emu = emulator.fit(x, np.nan_to_num(z), mask, init=np.zeros((1, 4)))
    assert np.all(np.isfinite(np.asarray(emu.alpha)))


def _two_optima() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A wiggle in noise (25 rows): from an "all noise" start (long length scale, noise sd
    0.9) L-BFGS-B stops at a local optimum that the default starts beat by ~12 units."""
    rng = np.random.default_rng(2)
    x = rng.uniform(size=(25, 1))
    z = np.sin(12 * x) + 0.3 * rng.normal(size=(25, 1))
    z = (z - z.mean()) / z.std()
    return x, z, np.ones(25, bool), np.array([[0.0, np.log(5.0), np.log(0.9)]])


def test_a_warm_start_cannot_keep_a_fit_at_a_worse_optimum():
    # The design loop warm-starts each fit from the last one.  A warm start alone once kept a
    # run's fit at a worse optimum than the checks' default-start refit reached, so the checks
    # judged another emulator than the one the draws came from.
    x, z, mask, noise_start = _two_optima()
    stuck = emulator.fit(x, z, mask, init=noise_start, starts=())
    fresh = emulator.fit(x, z, mask)
    assert emulator.objective(stuck) > emulator.objective(fresh) + 5  # the case has two optima
    warm = emulator.fit(x, z, mask, init=noise_start)
    assert emulator.objective(warm) == pytest.approx(emulator.objective(fresh), abs=1e-6)
    # A fit warm-started from its own result is that result: the draws' fit and the checks'.
    hyper = np.column_stack([fresh.log_amp, fresh.log_ls, fresh.log_noise])
    again = emulator.fit(x, z, mask, init=hyper)
    np.testing.assert_allclose(np.column_stack([again.log_amp, again.log_ls, again.log_noise]), hyper, atol=1e-4)
    with pytest.raises(ValueError, match="no start"):
        emulator.fit(x, z, mask, starts=())


def test_noise_profile_needs_enough_rows():
    coef, p = emulator.fit_noise_profile(np.random.default_rng(0).uniform(size=(5, 2)), np.ones((5, 1)))
    assert np.all(coef == 0) and np.all(np.isnan(p))


def test_local_check_bounds():
    assert diagnostics.local_check(np.zeros((0, 2))).passed
    assert diagnostics.local_check(np.full((3, 1), 0.5)).passed
    assert not diagnostics.local_check(np.array([[0.1], [6.0], [0.2]])).passed


def test_bad_noise_model_is_refused():
    prior = jaxabc.Uniform([-10.0], [10.0])
    with pytest.raises(ValueError, match="noise_model"):
        jaxabc.run("surrogate", gaussian_simulate, prior, np.array([0.7]), max_simulations=60, noise_model="robust")


def test_nan_log_density_points_get_no_weight_and_a_warning(monkeypatch: pytest.MonkeyPatch) -> None:
    """A NaN somewhere in the box (an emulator not evaluable far from every run) must not poison the
    importance weights: the water ABC run on simulated data crashed in numpy's SVD on such a pool."""
    from types import SimpleNamespace

    from jaxabc.surrogate import _posterior

    def log_density(model, x):  # N(0.5, 0.1^2) in each coordinate, NaN beyond x0 = 0.9
        lp = -0.5 * np.sum(((x - 0.5) / 0.1) ** 2, axis=1)
        return np.where(x[:, 0] > 0.9, np.nan, lp), np.zeros(len(x))

    monkeypatch.setattr(_posterior, "log_posterior_terms", log_density)
    settings = SimpleNamespace(num_candidates=1024, box=SimpleNamespace(num_sampled=2))
    with pytest.warns(RuntimeWarning, match="NaN at some candidate points"):
        sample = _posterior.importance_sample(settings, np.random.default_rng(0), None)
    w = sample.weights
    assert np.all(np.isfinite(w)) and np.all(w[sample.points[:, 0] > 0.9] == 0.0)
    ess = 1.0 / np.sum(w**2)
    mean = w @ sample.points
    # Exact mean 0.5 (the NaN region lies 4 sd out); tolerance 4 Monte Carlo standard errors.
    assert np.all(np.abs(mean - 0.5) < 4 * 0.1 / np.sqrt(ess)), (mean, ess)
