"""A factor on the emulator's variance (``emulator_variance``): its maximum-likelihood estimate
from held-out errors against the exact factor that made them, its standard error against the
Monte Carlo spread, and where the factor goes (the emulator's prediction, the evidence's refit,
the settings record, the result)."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxabc
from jaxabc.surrogate import emulator
from jaxabc.surrogate._fit import ROLE_DESIGN, fit_likelihood
from jaxabc.surrogate._state import LATER_FIELDS
from jaxabc.surrogate.evidence import likelihood_from_state


def held_out(rng: np.random.Generator, factor: float, shape=(60, 4)) -> tuple[np.ndarray, ...]:
    """Errors of an emulator whose variance ``v`` is ``factor`` times too small."""
    v = rng.uniform(0.05, 4.0, shape)
    n = rng.uniform(0.5, 1.5, shape)
    r = rng.normal(size=shape) * np.sqrt(factor * v + n)
    return r, v, n


@pytest.mark.parametrize("factor", [1.5, 3.0, 10.0, 40.0])
def test_mle_recovers_the_factor(factor: float) -> None:
    rng = np.random.default_rng(int(factor * 10))
    c, se, num = emulator.variance_scale_mle(*held_out(rng, factor))
    assert num == 240
    assert np.isfinite(se) and se > 0
    assert abs(np.log(c) - np.log(factor)) < 4 * se, (c, se)


def test_standard_error_matches_the_spread_over_data_sets() -> None:
    # 400 data sets at a fixed seed: the sd of log c over them has a relative Monte Carlo error
    # of about 1 / sqrt(2 * 400) = 3.5 %; the observed-information se must match it.
    rng = np.random.default_rng(7)
    logs, ses = [], []
    for _ in range(400):
        c, se, _ = emulator.variance_scale_mle(*held_out(rng, 4.0))
        logs.append(np.log(c))
        ses.append(se)
    spread, mean_se = np.std(logs, ddof=1), np.mean(ses)
    assert abs(spread / mean_se - 1.0) < 4 * 0.035, (spread, mean_se)
    assert abs(np.mean(logs) - np.log(4.0)) < 4 * spread / np.sqrt(400)


def test_errors_smaller_than_the_gp_says_keep_its_variance() -> None:
    rng = np.random.default_rng(1)
    c, se, _ = emulator.variance_scale_mle(*held_out(rng, 0.3))
    assert c == 1.0 and se == np.inf  # never shrunk: the bound, where no se is defined


def test_non_finite_entries_are_skipped_and_empty_input_is_one() -> None:
    rng = np.random.default_rng(2)
    r, v, n = held_out(rng, 5.0)
    full = emulator.variance_scale_mle(r, v, n)
    r2 = np.concatenate([r, np.full((3, 4), np.nan)])
    v2, n2 = np.concatenate([v, np.ones((3, 4))]), np.concatenate([n, np.ones((3, 4))])
    assert emulator.variance_scale_mle(r2, v2, n2) == full
    assert emulator.variance_scale_mle(np.full((2, 2), np.nan), np.ones((2, 2)), np.ones((2, 2)))[0] == 1.0


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError, match="shapes differ"):
        emulator.variance_scale_mle(np.zeros((3, 2)), np.ones((3, 2)), np.ones((2, 2)))
    with pytest.raises(ValueError, match="non-negative"):
        emulator.variance_scale_mle(np.zeros((3, 2)), -np.ones((3, 2)), np.ones((3, 2)))


def linear(key: jax.Array, theta: jax.Array) -> jax.Array:
    return jnp.stack([theta[0] + theta[1], theta[0] - theta[1]]) + 0.2 * jax.random.normal(key, (2,))


PRIOR = jaxabc.Uniform([-2.0, -2.0], [2.0, 2.0], names=("a", "b"))


@pytest.mark.parametrize("bad", ["wide", 0.5, float("nan"), -2.0, [2.0]])
def test_bad_setting_is_refused(bad) -> None:
    with pytest.raises(ValueError, match="emulator_variance"):
        jaxabc.run("surrogate", linear, PRIOR, np.zeros(2), max_simulations=60, emulator_variance=bad)


class _State:
    def __init__(self, thetas, summaries, variance_scale=None):
        self.thetas, self.summaries = thetas, summaries
        self.role = np.full(len(thetas), ROLE_DESIGN)
        self.ok = np.ones(len(thetas), bool)
        if variance_scale is not None:
            self.variance_scale = variance_scale


def test_a_factor_scales_the_predicted_variance_and_reaches_the_evidence_refit() -> None:
    rng = np.random.default_rng(0)
    thetas = rng.uniform(-2, 2, (30, 2))
    summaries = np.column_stack([thetas.sum(1), thetas[:, 0] - thetas[:, 1]]) + 0.2 * rng.normal(size=(30, 2))
    low, high = np.full(2, -2.0), np.full(2, 2.0)
    x = jnp.asarray(rng.uniform(0, 1, (7, 2)))
    with jax.enable_x64(True):
        args = (low, high, np.zeros(2), 16, 30, jnp.asarray(-np.inf))
        _, emu1, _, _ = fit_likelihood(_State(thetas, summaries), *args)
        _, emu3, model3, _ = fit_likelihood(_State(thetas, summaries), *args, variance_scale=3.0)
        m1, v1 = emulator.predict(emu1, x)
        m3, v3 = emulator.predict(emu3, x)
        assert emu1.var_scale is None  # the default emulator is the one fitted, unchanged
        np.testing.assert_array_equal(np.asarray(m1), np.asarray(m3))
        np.testing.assert_allclose(np.asarray(v3), 3.0 * np.asarray(v1), rtol=1e-12)
        settings = {"max_outputs": 16, "max_simulations": 30, "min_feasibility": 0.0}
        _, refit = likelihood_from_state(_State(thetas, summaries, 3.0), low, high, np.zeros(2), settings)
        assert float(refit.emulator.var_scale) == 3.0
        _, plain = likelihood_from_state(_State(thetas, summaries), low, high, np.zeros(2), settings)
        assert plain.emulator.var_scale is None
    assert model3.emulator.var_scale is not None


def test_new_state_fields_restore_from_older_checkpoints() -> None:
    for name in ("variance_scale", "judged_residual", "judged_emulator_var", "judged_noise_var"):
        assert f".{name}" in LATER_FIELDS


def run(**kwargs) -> jaxabc.ABCResult:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return jaxabc.run(
            "surrogate", linear, PRIOR, np.array([0.5, -0.3]), max_simulations=80, num_particles=1000, seed=0, **kwargs
        )


def test_the_factor_is_recorded_only_when_asked_for_and_a_fixed_one_is_used() -> None:
    plain, fixed = run(), run(emulator_variance=2.0)
    assert "emulator_variance" not in plain.settings  # default runs keep their fingerprints
    assert not any(k.startswith("emulator_variance") for k in plain.diagnostics)
    assert fixed.settings["emulator_variance"] == 2.0
    d = fixed.diagnostics
    assert d["emulator_variance_scale"] == 2.0
    # Every held-out run judged, each output: the estimate's data.
    assert d["emulator_variance_scale_estimate_errors"] == 2 * int(np.sum(np.asarray(d["design_role"]) >= 1))
    assert "emulator variance: x2" in fixed.summary()
    # The doubled variance reaches the posterior: the design stops later or the draws differ.
    assert not np.array_equal(plain.particles, fixed.particles)


@pytest.mark.parametrize("left", [60, 15, 14, 0])
def test_a_failed_validation_calibrates_the_factor_only_when_design_goes_on(monkeypatch, left) -> None:
    from jaxabc.surrogate import algorithm
    from jaxabc.surrogate._state import PHASE_VALIDATING, budget_allows_batch, empty_state

    algo = algorithm.build(PRIOR, 1000, observed=np.zeros(2), max_simulations=100, emulator_variance="calibrated")
    settings = algo.update.args[0]
    assert settings.num_holdout == 15 and settings.batch_size == 10
    fresh = empty_state(settings)
    # Before any validation the design keeps the runs of two: a batch and 2 x 15 held out.
    assert budget_allows_batch(settings, fresh._replace(count=np.int64(60)))
    assert not budget_allows_batch(settings, fresh._replace(count=np.int64(61)))
    rng = np.random.default_rng(3)
    r, v, n = held_out(rng, 6.0, (100, 2))
    state = fresh._replace(count=np.int64(100 - left), phase=np.int64(PHASE_VALIDATING), lack_of_fit_ok=np.bool_(True))
    budget_left = left >= settings.num_holdout  # a second validation is paid for

    def failed_check(settings, key, state):
        return state._replace(judged_residual=r, judged_emulator_var=v, judged_noise_var=n), False

    monkeypatch.setattr(algorithm, "check_holdout", failed_check)
    monkeypatch.setattr(algorithm, "design_step", lambda settings, key, state: state)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = algorithm.validate(settings, jax.random.key(0), state)
    expected = emulator.variance_scale_mle(r, v, n)[0] if budget_left else 1.0
    assert float(out.variance_scale) == expected
    assert (expected > 3.0) == budget_left


@pytest.mark.slow
def test_calibrated_variance_on_a_step() -> None:
    # The step the GP smooths over (tests/test_surrogate_honesty.py): at this seed a first
    # validation fails, its runs measure the GP's variance several times too small, and a
    # second validation judges the scaled emulator (with the GP's variance the run ends
    # unvalidated).
    from benchmarks.surrogate_honesty import CASES

    prior = jaxabc.Uniform([-5.0], [5.0], names=("t",))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = jaxabc.run(
            "surrogate",
            CASES["step"][0],
            prior,
            np.array([3.0]),
            max_simulations=200,
            seed=1,
            num_particles=1000,
            emulator_variance="calibrated",
        )
    d = r.diagnostics
    assert d["rounds"] > 1 and d["emulator_variance_scale"] > 2.0
    if d["validated"]:
        mean = float(r.weights @ r.particles[:, 0])
        assert abs(mean - 2.75) <= 3.0 * r.mcse()[0]
