"""Which discrepancy sds the data decide, and which prior boxes move a model choice.

Exact cases.  One summary ``s = theta + sigma e`` with a flat prior on ``theta`` much wider than
the noise: the data say nothing about a discrepancy sd ``delta`` of that summary, since
``integral N(y; theta, sigma^2 + delta^2) dtheta = 1`` for every ``delta``, so its posterior is
its prior U[0, M] (half its mass in [M/2, M]).  K values of one group: ``delta`` is pinned near
the truth, and the exact posterior (grid integration) puts a known, small share above M/2.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest
from _misspecified import K, grid_posterior, k_values, mean_and_sd, observed

import jaxabc
from jaxabc.diagnostics import PRIOR_LIKE_SHARE, discrepancy_identification
from jaxabc.model_choice import Model

SIGMA, M = 0.1, 1.0
M_K = 2.0


def one_value(key, theta):
    return theta + SIGMA * jax.random.normal(key, theta.shape)


def _share_se(n_eff: float) -> float:
    return float(np.sqrt(0.25 / n_eff))


def test_a_discrepancy_of_one_summary_follows_its_prior_and_is_named():
    prior = jaxabc.Uniform([-10.0], [10.0], names=("theta",))
    r = jaxabc.run(
        "rejection",
        one_value,
        prior,
        [0.3],
        num_particles=1000,
        quantile=0.01,
        discrepancy=jaxabc.Discrepancy(M, {"y": [0]}),
        seed=1,
    )
    shares, messages = r.discrepancy_identification()
    assert list(shares) == ["discrepancy_sd[y]"]
    # Exact: 0.5.  Monte Carlo error of a share from 1000 draws: sqrt(0.25 / 1000) = 0.016.
    assert abs(shares["discrepancy_sd[y]"] - 0.5) < 4 * _share_se(r.effective_sample_size())
    assert len(messages) == 1 and "discrepancy_sd[y]" in messages[0] and "max_sd" in messages[0]
    assert "discrepancy: " in r.summary()


def _grid_share(y: np.ndarray) -> float:
    """Exact posterior share of delta in [M_K / 2, M_K] for y_j ~ N(theta, S_DISC^2 + delta^2)."""
    _, d, p = grid_posterior(y, (-1.0, 3.0), M_K, (801, 801))
    return float(p[d > 0.5 * M_K].sum())


def test_a_discrepancy_of_many_summaries_is_decided_by_the_data():
    y = observed(7)
    prior = jaxabc.Uniform([-1.0], [3.0], names=("theta",))
    r = jaxabc.run(
        "rejection",
        k_values,
        prior,
        y,
        num_particles=1000,
        quantile=0.005,
        distance=mean_and_sd,
        discrepancy=jaxabc.Discrepancy(M_K, {"all": list(range(K))}),
        seed=3,
    )
    shares, messages = r.discrepancy_identification()
    exact = _grid_share(y)
    assert exact < PRIOR_LIKE_SHARE  # the case is one the data decide
    # Monte Carlo error plus the tolerance's blur (a few hundredths, as for the moments).
    assert abs(shares["discrepancy_sd[all]"] - exact) < 4 * _share_se(r.effective_sample_size()) + 0.03
    assert messages == []


def test_the_diagnostic_needs_proper_weights_and_ignores_other_columns():
    x = np.column_stack([np.linspace(0, 1, 11), np.linspace(0, 1, 11)])
    names = ("theta", "discrepancy_sd[g]")
    shares, _ = discrepancy_identification(x, None, names, [0.0, 0.0], [1.0, 1.0])
    assert shares == {"discrepancy_sd[g]": pytest.approx(5 / 11)}
    assert discrepancy_identification(x, None, ("a", "b"), [0.0, 0.0], [1.0, 1.0]) == ({}, [])
    with pytest.raises(ValueError, match="weights"):
        discrepancy_identification(x, -np.ones(11), names, [0.0, 0.0], [1.0, 1.0])


def _simulate(key, theta):
    return theta + 0.05 * jax.random.normal(key, theta.shape)


def test_split_sensitivity_scales_the_force_field_and_the_discrepancy_apart():
    near = Model("near", _simulate, jaxabc.Uniform([-1.0], [1.0], names=("mu",)))
    far = Model("far", _simulate, jaxabc.Uniform([-8.0], [8.0], names=("mu",)))
    r = jaxabc.run(
        [near, far],
        observed=[0.2],
        num_particles=300,
        final_threshold=0.05,
        num_steps=20,
        seed=0,
        discrepancy=jaxabc.Discrepancy(0.4),
    )
    rows = {row.label: row for row in r.sensitivity(scales=(0.5,), split_discrepancy=True)}
    assert {"near parameters x0.5", "near discrepancy x0.5", "all discrepancy x0.5"} <= set(rows)
    for i, name in enumerate(r.names):
        post = r.posteriors[i]
        low, high = np.asarray(post.prior.low), np.asarray(post.prior.high)
        params = rows[f"{name} parameters x0.5"].boxes[name]
        disc = rows[f"{name} discrepancy x0.5"].boxes[name]
        centre, half = 0.5 * (low[0] + high[0]), 0.25 * (high[0] - low[0])
        assert params == [[centre - half, low[1]], [centre + half, high[1]]]
        assert disc == [[low[0], 0.0], [high[0], 0.5 * high[1]]]
        # The reuse identity: Z' = Z P(delta <= max_sd / 2 | data) * 2 (a uniform prior's
        # volume ratio), from the model's own weights.
        w = np.asarray(post.weights) / np.sum(post.weights)
        inside = float(w @ (np.asarray(post.particles)[:, 1] <= 0.5 * high[1]))
        change = rows[f"{name} discrepancy x0.5"].log_evidence[i] - r.log_evidence[i]
        assert change == pytest.approx(np.log(2.0 * inside), abs=1e-9)
    plain = {row.label for row in r.sensitivity(scales=(0.5,))}
    assert not any("discrepancy" in label for label in plain)
