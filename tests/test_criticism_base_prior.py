"""Base parameters that absorb only what their prior allows (``critique(base_prior=...)``).

The linear problem of ``test_criticism_power``: ten summaries ``a + b x + curve x^2 + shift``
(noise sd 0.05).  With ``a`` free, ``shift`` is absorbed entirely and so invisible; with ``a``
known to +-0.01 (a Gaussian prior) a shift of 0.3 is 6 prior sd and must be named.  The
refit and its null covariance are checked against the exact linear-Gaussian answers.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from jaxabc.criticism import critique
from jaxabc.criticism.core import _base_prior_moments
from jaxabc.criticism.misfit import _refit_and_null, refit_operator
from tests.test_criticism_power import OPTIONS, base_result, catalogue, named, observe, simulate

KNOWN_A = ([1.0, 1.0], [0.01, 10.0])  # a known to +-0.01, b effectively free


def test_a_shift_that_free_parameters_absorb_is_named_when_the_prior_pins_them():
    obs = observe(0.0, shift=0.3)
    free = critique(base_result(), simulate, obs, catalogue(None, 0.3), seed=2, **OPTIONS)
    pinned = critique(base_result(), simulate, obs, catalogue(None, 0.3), seed=2, base_prior=KNOWN_A, **OPTIONS)
    assert not named(free, "shift")
    assert named(pinned, "shift") and pinned.causes[0].name == "shift", pinned.verdict
    by = {c.name: c for c in pinned.causes}
    assert by["shift"].power > 0.8, by["shift"].power
    assert pinned.settings["base_prior"] == "gaussian" and free.settings["base_prior"] == "free"


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_a_null_within_the_prior_is_claimed_by_nothing(seed):
    # The truth a = 1.005 lies half a prior sd from the prior centre.
    obs = observe(0.0, seed=seed) + 0.005
    report = critique(
        base_result(), simulate, obs, catalogue(None, None), seed=seed, base_prior=KNOWN_A,
        num_power_replicates=0, **OPTIONS,
    )  # fmt: skip
    assert not report.misfits, report.verdict


def test_uniform_prior_moments_are_its_centre_and_box_variance():
    # Uniform([0.5, 0.5], [1.5, 1.5]): centre 1, variance 1 / 12.
    precision, centre = _base_prior_moments("prior", base_result())
    np.testing.assert_allclose(centre, [1.0, 1.0])
    np.testing.assert_allclose(precision, 12.0 * np.eye(2))
    assert _base_prior_moments("free", base_result()) == (None, None)


def test_refit_operator_with_a_prior_is_the_map_residual():
    rng = np.random.default_rng(0)
    s, d = 8, 2
    jac = rng.normal(size=(s, d))
    cov = np.diag(rng.uniform(0.5, 2.0, s))
    lam = np.diag([4.0, 0.25])
    y = rng.normal(size=s)
    fitted = np.ones(s, bool)
    a = refit_operator(jac, cov, fitted, lam)
    prec = np.linalg.inv(cov)
    theta_map = np.linalg.solve(jac.T @ prec @ jac + lam, jac.T @ prec @ y)
    np.testing.assert_allclose(a @ y, y - jac @ theta_map, atol=1e-10)
    np.testing.assert_allclose(refit_operator(jac, cov, fitted, None), refit_operator(jac, cov, fitted), atol=0)


def test_null_covariance_with_a_prior_matches_monte_carlo():
    # y = J theta* + e with theta* ~ N(t0, L^-1): r_c = y - J theta_MAP has the covariance the
    # analysis uses as its null.  The residual is taken at a point t off the centre, as after a
    # clipped refit: r_c = A r + shift must not depend on t.
    rng = np.random.default_rng(1)
    s, d, reps = 6, 2, 200000
    jac = rng.normal(size=(s, d))
    noise = np.diag(rng.uniform(0.5, 1.5, s))
    lam = np.diag([2.0, 0.5])
    t0 = np.array([0.3, -0.2])
    pred = SimpleNamespace(active=np.ones(s, bool), noise_cov=noise, replicates=SimpleNamespace(shape=(10**9, s)))
    held = np.zeros(s, bool)
    t = np.array([0.5, 0.1])
    a, null, shift = _refit_and_null(pred, jac, held, (lam, t0, t))
    theta = t0 + rng.normal(size=(reps, d)) / np.sqrt(np.diag(lam))
    y = theta @ jac.T + rng.normal(size=(reps, s)) * np.sqrt(np.diag(noise))
    rc = (y - t @ jac.T) @ a.T + shift  # residual at t, refitted
    prec = np.linalg.inv(noise)
    theta_map = np.linalg.solve(jac.T @ prec @ jac + lam, (y @ prec @ jac + t0 @ lam).T).T
    np.testing.assert_allclose(rc, y - theta_map @ jac.T, atol=1e-9)
    emp = np.cov(rc.T)
    se = np.sqrt((emp**2 + np.outer(np.diag(emp), np.diag(emp))) / reps)
    assert np.all(np.abs(emp - null) < 5 * se + 1e-12), np.max(np.abs(emp - null) / se)


@pytest.mark.parametrize(
    "bad, match",
    [
        ("bogus", "base_prior="),
        (([1.0], [0.1]), "shape"),
        (([1.0, 1.0], [0.1, -1.0]), "positive"),
        (([1.0, np.nan], [0.1, 0.1]), "finite"),
        (3.0, "base_prior must be"),
    ],
)
def test_bad_base_prior_is_refused_before_any_simulation(bad, match):
    calls = []

    def counting(key, theta):
        calls.append(1)
        return simulate(key, theta)

    with pytest.raises(ValueError, match=match):
        critique(base_result(), counting, observe(0.0), catalogue(None, None), base_prior=bad, **OPTIONS)
    assert not calls
