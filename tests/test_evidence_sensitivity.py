"""How model probabilities move with the prior boxes, the verdict, and per-model prior edges.

Analytic case: summaries ``s = theta + sigma e`` (one per parameter), ``theta`` uniform on a box,
distance ``max_j |s_j - y_j|`` and tolerance ``eps``.  The ABC evidence factorises over the
parameters,

    Z = prod_j  integral_{a_j}^{b_j} [Phi((y_j + eps - t) / sigma) - Phi((y_j - eps - t) / sigma)] dt / (b_j - a_j),

and with ``G(x) = x Phi(x) + phi(x)`` (an antiderivative of ``Phi``) each integral is
``sigma [G((c - a) / sigma) - G((c - b) / sigma)]`` for ``c = y + eps`` minus the same for
``c = y - eps``.  So the exact model probabilities are known for every box, narrowed or widened.
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import norm

import jaxabc
from jaxabc.model_choice import (
    STATUS_NEEDS_SIMULATIONS,
    STATUS_REUSED,
    Model,
    interval_leader,
    load_model_choice,
    with_boxes,
)

SIGMA, EPS, Y = 0.05, 0.05, 0.2


def simulate(key, theta):
    return theta + SIGMA * jax.random.normal(key, theta.shape)


def max_abs(observed, simulated):
    return jnp.max(jnp.abs(observed - simulated))


def _g(x):
    return x * norm.cdf(x) + norm.pdf(x)


def log_evidence(low, high, sigma=SIGMA):
    """The exact ABC evidence of one model with a uniform prior on [low, high]."""
    total = 0.0
    for a, b in zip(np.atleast_1d(low), np.atleast_1d(high), strict=True):
        inner = 0.0
        for c, sign in ((Y + EPS, 1.0), (Y - EPS, -1.0)):
            inner += sign * sigma * (_g((c - a) / sigma) - _g((c - b) / sigma))
        total += np.log(inner / (b - a))
    return total


def exact_probabilities(boxes, sigma=SIGMA):
    log_z = np.array([log_evidence(lo, hi, sigma) for lo, hi in boxes])
    p = np.exp(log_z - log_z.max())
    return p / p.sum()


def uniform(low, high):
    return jaxabc.Uniform(low, high, names=tuple(f"mu{j}" for j in range(len(low))))


OPTIONS = dict(num_particles=400, final_threshold=EPS, num_steps=20, distance=max_abs, seed=0)
NEAR = Model("near", simulate, uniform([-1.0], [1.0]))
FAR = Model("far", simulate, uniform([-8.0], [8.0]))


def _run(models, observed=(Y,), **kw):
    return jaxabc.run(models, observed=list(observed), **{**OPTIONS, **kw})


@pytest.fixture(scope="module")
def separated():
    """near U(-1, 1) against far U(-8, 8), data at 0.2: Bayes factor about 8 for near."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = _run([NEAR, FAR])
    return result, [w for w in caught if issubclass(w.category, jaxabc.PriorEdgeWarning)]


def _boxes(result, row):
    out = []
    for name, post in zip(result.names, result.posteriors, strict=True):
        low, high = row.boxes.get(name, [np.asarray(post.prior.low), np.asarray(post.prior.high)])
        out.append((np.asarray(low, np.float64), np.asarray(high, np.float64)))
    return out


def test_narrowed_boxes_match_the_exact_probabilities(separated):
    r, _ = separated
    assert r.threshold == EPS
    truth = exact_probabilities([(-1.0, 1.0), (-8.0, 8.0)])
    assert np.all(np.abs(r.probabilities - truth) < 4 * r.standard_errors), (r.probabilities, truth)
    labels = [row.label for row in r.sensitivity_table]
    assert labels == [
        "near box x0.5",
        "far box x0.5",
        "all boxes x0.5",
        "near box x2",
        "far box x2",
        "all boxes x2",
    ]
    computed = [row for row in r.sensitivity_table if row.computed]
    assert len(computed) == 3
    for row in computed:
        assert row.status == STATUS_REUSED
        exact = exact_probabilities(_boxes(r, row))
        assert np.all(np.abs(row.probabilities - exact) < 4 * row.standard_errors), (
            row.label,
            row.probabilities,
            exact,
        )
        assert np.all((row.intervals[:, 0] <= row.probabilities) & (row.probabilities <= row.intervals[:, 1]))
    # Halving far's box doubles its evidence: the probability of near drops from ~0.89 to ~0.80.
    half_far = r.sensitivity_table[1]
    assert half_far.probabilities[0] < r.probabilities[0] - 0.05
    # The same box reproduces the run, errors included (the restricted estimator is the run's).
    table = list(r.sensitivity_table)
    (same,) = r.sensitivity(scales=(1.0,))[-1:]
    r.sensitivity_table = table  # the other tests read the run's own table
    np.testing.assert_allclose(same.probabilities, r.probabilities, rtol=1e-12)
    np.testing.assert_allclose(same.standard_errors, r.standard_errors, rtol=1e-9)


def test_widened_boxes_need_simulations_and_give_the_lower_bound(separated):
    r, _ = separated
    for row in r.sensitivity_table:
        if row.scale != 2.0:
            continue
        assert row.status == STATUS_NEEDS_SIMULATIONS and not row.computed
        assert np.all(np.isnan(row.probabilities))
        widened = [row.changed] if row.changed != "all" else list(r.names)
        assert list(row.needs_simulations) == widened
        for name in widened:
            i = r.names.index(name)
            # The run's box lies inside the doubled one: Z' >= Z vol(B) / vol(B') = Z / 2.
            assert row.log_evidence[i] == pytest.approx(r.log_evidence[i] - np.log(2.0), abs=1e-12)
            low, high = row.boxes[name]
            assert log_evidence(low, high) >= row.log_evidence[i] - 4 * row.log_evidence_errors[i]
        assert STATUS_NEEDS_SIMULATIONS in row.describe() and "log Z(" in row.describe()


def test_verdict_prefers_a_clearly_better_model_and_lists_what_is_unchecked(separated):
    r, edge_warnings = separated
    v = r.verdict()
    assert v.status == "preferred" and v.model == "near", v
    # far's wider box could raise its evidence without limit: not checked, and said so.
    assert v.unchecked == ("far box x2", "all boxes x2")
    assert "far box x2" in v.reason and "with_boxes" in v.reason
    # near's wider box halves its evidence at worst, and near stays preferred: decided by the bound.
    assert "known lower bound keeps it so in near box x2" in v.reason
    assert "verdict: preferred: near" in r.summary()
    assert r.prior_edge["near"]["messages"] == [] and r.prior_edge["far"]["messages"] == []
    assert edge_warnings == []


def test_identical_models_are_undecided():
    twin = Model("twin", simulate, NEAR.prior)
    r = _run([NEAR, twin], num_particles=200)
    v = r.verdict()
    assert v.status == "undecided" and v.model is None
    assert "overlaps" in v.reason and "near" in v.reason and "twin" in v.reason
    assert "verdict: undecided" in r.summary()


def test_halving_a_box_flips_the_order_and_the_edge_warning_names_the_model():
    # Two parameters, both measured at 0.2.  A: U(-1, 1)^2.  B: mu0 in [0.2, 0.7] (its box
    # starts at the data: half the likelihood is cut off) and mu1 in [-1, 1].  Z_B / Z_A = 2,
    # but halving A's box (both sides) multiplies Z_A by 4: then A is preferred 2 : 1.
    a = Model("A", simulate, uniform([-1.0, -1.0], [1.0, 1.0]))
    b = Model("B", simulate, uniform([0.2, -1.0], [0.7, 1.0]))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = _run([a, b], observed=(Y, Y), num_particles=300)
    edge = [w for w in caught if issubclass(w.category, jaxabc.PriorEdgeWarning)]
    assert len(edge) == 1, [str(w.message) for w in edge]  # one per model, not one per result as well
    assert "model 'B'" in str(edge[0].message) and "mu0" in str(edge[0].message)
    assert "lower bound 0.2" in str(edge[0].message)
    assert r.prior_edge["B"]["messages"] and not r.prior_edge["A"]["messages"]
    assert np.asarray(r.prior_edge["B"]["mass"])[0, 0] > 0.05
    assert "prior edge, model 'B'" in r.summary()

    truth = exact_probabilities([([-1, -1], [1, 1]), ([0.2, -1], [0.7, 1])])
    assert abs(truth[1] - 2.0 / 3.0) < 0.01
    assert np.all(np.abs(r.probabilities - truth) < 4 * r.standard_errors)
    assert r.best == "B"
    half_a = next(row for row in r.sensitivity_table if row.label == "A box x0.5")
    exact = exact_probabilities(_boxes(r, half_a))
    assert exact[0] > 0.6
    assert np.all(np.abs(half_a.probabilities - exact) < 4 * half_a.standard_errors)
    v = r.verdict()
    assert v.status == "undecided"
    # Decided at the run's boxes, so the reason is the box that flips it, not an overlap.
    assert "the order depends on the prior boxes: with A box x0.5 A is the most probable" in v.reason


def test_user_boxes_save_load_and_rerun(separated, tmp_path):
    r, _ = separated
    inside, straddling = r.sensitivity(scales=(), boxes={"near": [(-0.5, 0.9), (-2.0, 0.5)]})
    assert inside.label == "near box [-0.5, 0.9]" and inside.computed
    exact = exact_probabilities([(-0.5, 0.9), (-8.0, 8.0)])
    assert np.all(np.abs(inside.probabilities - exact) < 4 * inside.standard_errors)
    # Partly outside: the part inside gives the lower bound, nothing is extrapolated.
    assert straddling.status == STATUS_NEEDS_SIMULATIONS
    post = r.posterior("near")
    q = np.sum(post.weights[post.particles[:, 0] <= 0.5])
    assert straddling.log_evidence[0] == pytest.approx(r.log_evidence[0] + np.log(q) + np.log(2.0 / 2.5))
    # The table, the verdict and the edge checks survive a save and load.
    r.save(tmp_path / "choice")
    again = load_model_choice(tmp_path / "choice")
    assert [row.label for row in again.sensitivity_table] == [row.label for row in r.sensitivity_table]
    for a, b in zip(again.sensitivity_table, r.sensitivity_table, strict=True):
        assert a.status == b.status and a.needs_simulations == b.needs_simulations and a.boxes == b.boxes
        np.testing.assert_array_equal(a.probabilities, b.probabilities)
        np.testing.assert_array_equal(a.intervals, b.intervals)
        np.testing.assert_array_equal(a.log_evidence, b.log_evidence)
    assert again.verdict() == r.verdict()
    assert again.prior_edge == r.prior_edge
    # A wider box is computed by running again with it.
    wide = jaxabc.run(with_boxes([NEAR, FAR], {"far": 2.0}), observed=[Y], **OPTIONS)
    assert tuple(np.asarray(wide.posterior("far").prior.high)) == (16.0,)
    truth = exact_probabilities([(-1.0, 1.0), (-16.0, 16.0)])
    assert np.all(np.abs(wide.probabilities - truth) < 4 * wide.standard_errors)
    with pytest.raises(KeyError, match="no model named"):
        with_boxes([NEAR, FAR], {"nowhere": 2.0})


def test_measurement_error_and_discrepancy_reach_every_model():
    # Measurement error sd tau adds to the simulator's noise: the evidence is that of sd
    # sqrt(sigma^2 + tau^2).
    tau = 0.05
    r = _run([NEAR, FAR], observation_error=tau, num_particles=300)
    truth = exact_probabilities([(-1.0, 1.0), (-8.0, 8.0)], sigma=np.hypot(SIGMA, tau))
    assert np.all(np.abs(r.probabilities - truth) < 4 * r.standard_errors)
    assert r.metadata["observation_error"] == [[tau**2]]
    d = _run([NEAR, FAR], discrepancy=jaxabc.Discrepancy(0.1), num_particles=100, num_steps=2)
    for post in d.posteriors:
        assert post.names[0] == "mu0" and post.names[1].startswith("discrepancy_sd")


def test_surrogate_model_choice_gives_measurement_error_to_each_builder(monkeypatch):
    import jaxabc.surrogate

    seen = []

    class Stop(Exception):
        pass

    def build(prior, num_particles, **kw):
        seen.append(kw)
        raise Stop

    monkeypatch.setattr(jaxabc.surrogate, "build", build)
    with pytest.raises(Stop):
        jaxabc.run([NEAR, FAR], observed=[Y], method="surrogate", max_simulations=100, observation_error=0.1)
    assert seen[0]["observation_error"] == 0.1 and "discrepancy" not in seen[0]


def test_interval_leader_is_the_verdict_rule():
    """A model leads only when its interval lies wholly above every other's; touching is not enough."""
    iv = np.array([[0.6, 0.9], [0.05, 0.3], [0.0, 0.2]])
    assert interval_leader(np.array([0.75, 0.15, 0.10]), iv) == 0
    iv[1, 1] = 0.6  # reaches the leader's lower end
    assert interval_leader(np.array([0.75, 0.15, 0.10]), iv) is None
    assert interval_leader(np.array([np.nan, 0.5, 0.5]), iv) is None


def test_sensitivity_rows_name_the_model_their_boxes_would_prefer(separated):
    r, _ = separated
    for row in r.sensitivity_table:
        if not row.computed:
            assert row.preferred is None
            continue
        k = interval_leader(row.probabilities, row.intervals)
        assert row.preferred == (None if k is None else r.names[k])
    # The run's own probabilities under the same rule give the verdict's first step.
    k = interval_leader(r.probabilities, r.probability_intervals())
    if r.verdict().status == "preferred":
        assert r.names[k] == r.verdict().model
