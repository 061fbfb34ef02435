"""Surrogate calibration (jaxabc.surrogate): analytic posteriors, design, failures, validation."""

from __future__ import annotations

import json
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats
from jax.tree_util import keystr, tree_flatten_with_path

from jaxabc.diagnostics import chain_ess
from jaxabc.executors import SerialExecutor, VmapExecutor, mark_nonfinite
from jaxabc.priors import Uniform

pytest.importorskip("tinygp", reason="jaxabc.surrogate needs the 'surrogate' extra")
pytest.importorskip("blackjax", reason="jaxabc.surrogate needs the 'surrogate' extra")

from jaxabc.surrogate import EmulatorFailure, build, design, diagnostics, emulator

# A linear-Gaussian simulator s = A theta + noise: under a wide uniform prior the posterior is
# N(A^-1 s_obs, (A^T S^-1 A)^-1), correlated through A.
A = np.array([[1.0, 0.6], [0.0, 1.0]])
NOISE_SD = np.array([0.3, 0.2])
OBSERVED = np.array([0.5, -0.7])
PRIOR = Uniform([-4.0, -4.0], [4.0, 4.0])


def linear_gaussian(key, theta):
    return jnp.asarray(A) @ theta + jnp.asarray(NOISE_SD) * jax.random.normal(key, (2,))


def exact_posterior() -> tuple[np.ndarray, np.ndarray]:
    cov = np.linalg.inv(A.T @ np.diag(NOISE_SD**-2) @ A)
    return np.linalg.solve(A, OBSERVED), cov


def _drive(algorithm, simulate, executor, seed: int = 0, max_iterations: int = 100, observed=OBSERVED):
    """The protocol's host loop (propose -> simulate -> init/update), exposing the states.

    ``jaxabc.run`` drives the same functions (``test_run_surrogate_*``); this loop lets the tests
    inspect intermediate states and proposals.  Returns ``(state, info, num_simulations,
    proposals)``.
    """
    root = jax.random.key(seed)
    state, info, num_sims, proposals = None, None, 0, []
    for iteration in range(max_iterations):
        k_prop, k_sim, k_upd = jax.random.split(jax.random.fold_in(root, iteration), 3)
        proposal = algorithm.initial_proposal(k_prop) if state is None else algorithm.propose(k_prop, state)
        thetas, active = np.asarray(proposal.thetas), np.asarray(proposal.active)
        proposals.append(thetas[active])
        keys = np.asarray(jax.random.key_data(jax.random.split(k_sim, thetas.shape[0])))
        batch = mark_nonfinite(executor.map(simulate, keys[active], thetas[active]))
        summaries = np.full((thetas.shape[0], *np.shape(observed)), np.nan)
        summaries[active] = batch.summaries
        flat = summaries.reshape(thetas.shape[0], -1)
        distances = np.where(
            np.all(np.isfinite(flat), axis=1), np.linalg.norm(flat - np.ravel(observed), axis=1), np.inf
        )
        num_sims += int(active.sum())
        if state is None:
            state, info = algorithm.init(k_upd, proposal, distances, summaries)
        else:
            state, info = algorithm.update(k_upd, state, proposal, distances, summaries)
        if bool(info.stop):
            break
    return state, info, num_sims, proposals


@pytest.fixture(scope="module")
def gaussian_run():
    algorithm = build(PRIOR, 2000, observed=OBSERVED, max_simulations=200)
    state, info, num_sims, _ = _drive(algorithm, linear_gaussian, VmapExecutor())
    return algorithm, state, info, num_sims


def test_gaussian_posterior_matches_the_analytic_one(gaussian_run):
    algorithm, state, info, num_sims = gaussian_run
    assert bool(info.stop) and num_sims <= 200
    particles, log_weights = algorithm.posterior(state)
    assert particles.shape == (2000, 2) and np.all(log_weights == log_weights[0])
    mean, cov = exact_posterior()
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(particles.mean(axis=0) - mean) < 0.2 * sd), (particles.mean(axis=0), mean)
    assert np.all(np.abs(particles.std(axis=0) / sd - 1) < 0.15), (particles.std(axis=0), sd)
    rho = cov[0, 1] / np.prod(sd)
    assert abs(np.corrcoef(particles.T)[0, 1] - rho) < 0.1
    assert algorithm.stop_reason(algorithm.settings, info).startswith("emulator validated")


def test_finalize_reports_design_and_validation(gaussian_run):
    algorithm, state, _, num_sims = gaussian_run
    extras = algorithm.finalize(state)
    diag = extras["diagnostics"]
    json.dumps(extras)  # result files store it as JSON
    assert diag["validated"] and diag["num_simulations"] == num_sims
    assert len(diag["design_points"]) == num_sims
    assert diag["num_holdout"] == algorithm.settings["num_holdout"]
    assert diag["num_design"] + diag["num_holdout"] == num_sims
    group = np.asarray(diag["design_replicate_group"])
    assert np.sum(group >= 0) == algorithm.settings["num_replicates"] + 2
    lo, hi = diagnostics.holdout_bounds(diag["num_holdout"] * 2)
    assert lo <= diag["holdout_coverage_95"] and diag["holdout_mean_squared_error"] <= hi
    assert max(diag["nuts_split_rhat"]) < 1.05
    assert diag["posterior_share_below_design_level"] == 0.0  # no run failed: p = 1 everywhere
    # The data came from the model: the posterior predictive holds them.
    assert diag["observed_misfit"]["dof"] == 2
    assert diag["observed_misfit"]["p_value"] > diagnostics.MISFIT_P_VALUE
    # The NUTS draws carry equal weights, but their ESS is the chains' (ArviZ), not the count.
    chains = np.asarray(state.draws).reshape(algorithm.settings["num_chains"], -1, 2)
    assert extras["ess"] == pytest.approx(chain_ess(chains))
    assert 1 <= extras["ess"] <= len(state.draws)


def test_restore_state_round_trips_a_checkpoint(gaussian_run):
    algorithm, state, _, _ = gaussian_run
    flat = {keystr(p): np.asarray(v) for p, v in tree_flatten_with_path(state)[0]}
    restored = algorithm.restore_state(flat)
    for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(restored), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    del flat[".draws"]
    with pytest.raises(ValueError, match="draws"):
        algorithm.restore_state(flat)


def test_a_restored_checkpoint_continues_identically(tmp_path):
    algorithm = build(PRIOR, 1000, observed=OBSERVED, max_simulations=200)
    state, _, _, _ = _drive(algorithm, linear_gaussian, VmapExecutor(), seed=5, max_iterations=1)
    np.savez(tmp_path / "state.npz", **{keystr(p): np.asarray(v) for p, v in tree_flatten_with_path(state)[0]})
    with np.load(tmp_path / "state.npz") as data:
        restored = build(PRIOR, 1000, observed=OBSERVED, max_simulations=200).restore_state(dict(data))
    key = jax.random.key(9)
    proposal = algorithm.propose(key, state)
    np.testing.assert_array_equal(proposal.thetas, algorithm.propose(key, restored).thetas)
    keys = jax.random.split(jax.random.key(10), proposal.thetas.shape[0])
    summaries = np.asarray(jax.vmap(linear_gaussian)(keys, jnp.asarray(proposal.thetas)))
    distances = np.zeros(proposal.thetas.shape[0])
    a, _ = algorithm.update(key, state, proposal, distances, summaries)
    b, _ = algorithm.update(key, restored, proposal, distances, summaries)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_same_seed_gives_the_same_design_on_any_executor():
    runs = []
    for executor in (VmapExecutor(), SerialExecutor()):
        algorithm = build(PRIOR, 1000, observed=OBSERVED, max_simulations=200)
        _, _, _, proposals = _drive(algorithm, linear_gaussian, executor, seed=3, max_iterations=2)
        runs.append(np.concatenate(proposals))
    np.testing.assert_allclose(runs[0], runs[1], rtol=1e-6, atol=1e-9)
    algorithm = build(PRIOR, 1000, observed=OBSERVED, max_simulations=200)
    other = np.asarray(algorithm.initial_proposal(jax.random.key(4)).thetas)
    assert not np.allclose(other, runs[0][: other.shape[0]])


def failing_for_large_theta0(key, theta):
    # A "gas phase": no summaries when theta0 > 1.
    s = linear_gaussian(key, theta)
    return jnp.where(theta[0] > 1.0, jnp.nan, s)


def test_failed_simulations_inform_the_design():
    # Untruncated, P(theta0 > 1 | data) = 0.11; runs there fail, so the posterior must avoid it.
    observed = np.array([0.6, 0.0])
    algorithm = build(PRIOR, 1000, observed=observed, max_simulations=200)
    # The Sobol start, the replicates, then two acquisition batches.
    state, _, _, proposals = _drive(
        algorithm, failing_for_large_theta0, VmapExecutor(), max_iterations=4, observed=observed
    )
    c = int(state.count)
    failed = ~state.ok[:c]
    assert failed.any() and np.all(state.thetas[:c][failed, 0] > 1.0)
    assert np.all(np.isnan(state.summaries[:c][failed]))
    assert np.all(proposals[1][:, 0] < 1.0), "replicates at successful runs"
    later = np.concatenate(proposals[2:])  # the acquisition batches
    assert np.mean(later[:, 0] > 1.0) < 0.1
    particles, _ = algorithm.posterior(state)
    # The classifier's boundary is soft after 2 acquisition batches (it sharpens as runs gather there): the
    # mass beyond it shrinks from 0.11, it does not vanish.
    assert np.mean(particles[:, 0] > 1.0) < 0.08
    assert np.mean(particles[:, 0] > 0.6) > 0.2  # truncated, not pushed away


@pytest.mark.slow  # default-suite time: 25-75 s on 2 cores
def test_a_misspecified_model_does_not_chase_the_failing_region():
    """Data no feasible theta reproduces (s0 = 5 needs theta0 ~ 4.4, where runs fail): the
    emulator knows nothing beyond the boundary, and without the feasibility cut its variance
    there outbid every liquid-side fit and drew the design into failures (water on X-ray data,
    most of its runs).  With it the posterior and the design stay on the feasible side."""
    observed = np.array([5.0, -0.7])
    algorithm = build(PRIOR, 1000, observed=observed, max_simulations=120, batch_size=4)
    state, info, num_sims, proposals = _drive(
        algorithm, failing_for_large_theta0, VmapExecutor(), max_iterations=60, observed=observed
    )
    assert bool(info.stop) and num_sims <= 120
    # Without the cut (and with the old, soft classifier) every run after the start went to
    # theta0 in 1.5-4 and the posterior mean to 3.3.  Now runs probe the boundary, no further:
    # the classifier's 1 % level lies a little beyond the last success.
    start = len(proposals[0])
    later = np.asarray(state.thetas[start : int(state.count)])
    assert np.all(later[:, 0] < 1.5), later
    particles, _ = algorithm.posterior(state)
    assert np.mean(particles[:, 0] > 1.5) < 0.01
    assert 0.5 < particles[:, 0].mean() < 1.3  # the best feasible fit, at the boundary
    # Against the boundary the posterior collapses; the penalty radius had collapsed with it
    # and about half the later runs repeated an earlier failure (within 0.5 % of the box).
    unit = (np.asarray(state.thetas[: int(state.count)]) - PRIOR.low) / (PRIOR.high - PRIOR.low)
    failed = ~np.asarray(state.ok[: int(state.count)])
    near = [
        np.min(np.linalg.norm(unit[:i][failed[:i]] - unit[i], axis=1)) < 0.005
        for i in range(start, int(state.count))
        if failed[:i].any()
    ]
    assert np.mean(near) < 0.2, np.mean(near)
    # The posterior presses against the boundary.  With the quadratic classifier alone it sat
    # just past it (soft there), nearly every held-out run failed and too few succeeded to check
    # the emulator; with the GP classifier beside it enough succeed.
    succeeded = int(np.sum(np.any(np.isfinite(state.holdout_errors), axis=1)))
    assert succeeded >= diagnostics.MIN_HOLDOUT_RUNS
    # The result says that no theta reproduces the data, and which summary misses.
    with pytest.warns(RuntimeWarning, match="outside the model's posterior predictive"):
        misfit = algorithm.finalize(state)["diagnostics"]["observed_misfit"]
    assert misfit["p_value"] < 1e-6
    residuals = misfit["standardised_residuals"]
    assert residuals[0] > 3 and abs(residuals[0]) > abs(residuals[1])  # s0 = 5 lies above every fit


def test_the_misfit_weighs_the_draws(gaussian_run):
    """Zero-weight draws drop out; equal weights are the plain posterior predictive."""
    from jaxabc.surrogate import evidence

    algorithm, state, _, _ = gaussian_run
    low, high = np.asarray(PRIOR.low), np.asarray(PRIOR.high)
    with jax.enable_x64(True):
        transform, model = evidence.likelihood_from_state(state, low, high, OBSERVED, algorithm.settings)
        x = (np.asarray(state.draws) - low) / (high - low)
        far = np.clip(x + 0.3, 0.0, 1.0)  # draws whose predictions miss the data
        plain = evidence.observed_misfit(model, transform, x)
        masked = evidence.observed_misfit(
            model, transform, np.concatenate([x, far]), np.r_[np.ones(len(x)), np.zeros(len(x))]
        )
        shifted = evidence.observed_misfit(model, transform, far)
        with pytest.raises(ValueError, match="weights"):
            evidence.observed_misfit(model, transform, x, np.zeros(len(x)))
    assert masked["mahalanobis_squared"] == pytest.approx(plain["mahalanobis_squared"], rel=1e-9)
    assert shifted["mahalanobis_squared"] > 10 * plain["mahalanobis_squared"]


def test_design_runs_go_where_runs_are_expected_to_succeed():
    p_ok = np.array([0.05, 0.3, 0.6, 0.9])
    assert design.design_level(p_ok) == design.MIN_DESIGN_SUCCESS
    # A simulator that fails often everywhere: the best candidates still qualify.
    assert design.design_level(np.array([0.05, 0.2, 0.3])) == 0.3
    # The posterior peaks far beyond the level (1e4 nats up): the eligible candidates still rank.
    a = design.acquisition(np.array([0.0, -1e4, -1e4 - 1.0]), np.ones(3), np.array([0.2, 0.9, 0.9]))
    np.testing.assert_allclose(a, [0.0, 1.0, np.exp(-1.0)])


def test_a_batch_is_spread_even_when_the_posterior_collapses_onto_one_point():
    # Candidates: 50 copies of the best point, the rest a grid; a posterior sd of 0 would
    # make the penalty radius 0 and the batch 4 copies of one point.
    rng = np.random.default_rng(0)
    x = np.concatenate([np.full((50, 2), 0.3), rng.uniform(size=(500, 2))])
    acquisition = np.exp(-0.5 * np.sum(((x - 0.3) / 0.05) ** 2, axis=1))
    ls = np.array([0.2, 0.4])
    radius = design.penalty_radius(ls, np.zeros(2))
    assert np.allclose(radius, design.MIN_RADIUS_FRACTION * ls)
    assert np.allclose(design.penalty_radius(ls, np.array([0.1, 2.0])), [0.05, 0.4])
    idx = design.select_batch(x, acquisition, radius, 4)
    picked = x[idx]
    gaps = np.linalg.norm(picked[:, None] - picked[None], axis=-1)[np.triu_indices(4, 1)]
    assert np.all(gaps > 0.5 * radius.min()), gaps
    # A failed run at the best point: no pick repeats it.
    idx = design.select_batch(x, acquisition, radius, 4, avoid=np.array([[0.3, 0.3]]))
    assert np.all(np.linalg.norm(x[idx] - 0.3, axis=1) > 0.5 * radius.min())


def test_the_failure_text_counts_held_out_runs_that_failed():
    from types import SimpleNamespace

    from jaxabc.surrogate._report import failure_text

    errors = np.full((20, 3), np.nan)
    errors[:5] = 0.1
    state = SimpleNamespace(
        emulator_ratio=0.0,
        lack_of_fit_ok=True,
        joint_ok=True,
        coverage=np.nan,
        holdout_errors=errors,
        untested_share=np.nan,
    )
    assert "15 of 20 held-out runs failed" in failure_text(state, 1.0)
    assert "too few" not in failure_text(state, 1.0)
    errors[2:5] = np.nan
    assert "18 of 20 held-out runs failed, fewer than 5 succeeded" in failure_text(state, 1.0)
    # The posterior sits where the design never goes: the text names that band and the way out.
    state.untested_share = 0.9
    assert "90% of the posterior lies where the success classifier is below" in failure_text(state, 1.0)
    state.untested_share = 0.1
    assert "below the design level" not in failure_text(state, 1.0)


def test_no_likelihood_outbids_the_feasibility_level():
    from types import SimpleNamespace

    from jaxabc.surrogate import sampling

    # Runs fail beyond x0 = 0.5.  A likelihood rising into the failing region (misspecified data,
    # the emulator extrapolating) outbid a linear cut below the level (water, neutron data, paper
    # statistics).  Below the level the drop is a step, as for the nearest-run cut.
    rng = np.random.default_rng(2)
    x = rng.uniform(size=(80, 2))
    with jax.enable_x64(True):
        feasible = sampling.fit_feasibility(x, x[:, 0] < 0.5)
        model = SimpleNamespace(feasible=feasible, log_min_feasibility=sampling.log_level(0.5))
        grid = jnp.asarray(np.column_stack([np.linspace(0.0, 1.0, 401), np.full(401, 0.5)]))
        lf = np.asarray(sampling.log_feasibility(feasible, grid))
        term = np.asarray(sampling.log_feasibility_term(model, grid))
        knn = np.asarray(sampling.nearest_runs_cut(feasible, grid))
    below = lf < np.log(0.5)
    assert np.any(below & ~knn), "points below the level the nearest-run cut leaves alone"
    assert np.all(term[below] < -1e11)
    np.testing.assert_allclose(term[~below & ~knn], lf[~below & ~knn])


def test_the_untested_share_is_the_posterior_weight_below_the_design_level():
    from types import SimpleNamespace

    from jaxabc.surrogate import sampling
    from jaxabc.surrogate._support import untested_share

    # Runs fail beyond x0 = 0.5 (a sharp phase boundary); the classifier learns it.
    rng = np.random.default_rng(1)
    x = rng.uniform(size=(80, 2))
    feasible = sampling.fit_feasibility(x, x[:, 0] < 0.5)
    model = SimpleNamespace(feasible=feasible)
    cand = rng.uniform(size=(2000, 2))
    draws = np.column_stack([np.linspace(0.05, 0.95, 100), np.full(100, 0.5)])
    # Equal weights: the draws beyond the boundary (x0 > ~0.5) are below the design level.
    share = untested_share(model, cand, draws, np.zeros(100))
    assert 0.4 <= share <= 0.6, share
    # Weight only on the feasible half (-inf pads the rest): nothing is untested.
    log_w = np.where(draws[:, 0] < 0.4, 0.0, -np.inf)
    assert untested_share(model, cand, draws, log_w) == 0.0
    # Weight on the failing half only: all of it is.
    assert untested_share(model, cand, draws, np.where(draws[:, 0] > 0.6, 0.0, -np.inf)) == 1.0


def test_the_nearest_run_cut_is_sharp_for_a_failing_phase_and_blind_to_random_failures():
    from jaxabc.surrogate import sampling

    rng = np.random.default_rng(0)
    x = rng.uniform(size=(400, 2))
    band = (x[:, 0] > 0.3) & (x[:, 0] < 0.45)  # a narrow band of success between two phases
    grid = rng.uniform(size=(2000, 2))
    inside = (grid[:, 0] > 0.3) & (grid[:, 0] < 0.45)
    keep = np.asarray(sampling.nearest_runs_succeed(sampling.fit_feasibility(x, band, size=500), grid))
    # Cut outside the band (but for a margin of about a run spacing), kept inside it.
    margin = (np.abs(grid[:, 0] - 0.3) < 0.05) | (np.abs(grid[:, 0] - 0.45) < 0.05)
    assert np.mean(keep[inside & ~margin]) > 0.99 and np.mean(keep[~inside & ~margin]) < 0.01
    # 15 % of runs failing at random anywhere: P(>= 4 of 5 nearest failed) ~ 2e-3.
    random_ok = rng.uniform(size=400) > 0.15
    keep = np.asarray(sampling.nearest_runs_succeed(sampling.fit_feasibility(x, random_ok), grid))
    assert np.mean(keep) > 0.98


def test_the_gp_classifier_matches_scikit_learn():
    """The JAX predictive of the fitted classifier is scikit-learn's, up to the probit
    approximation (MacKay's here, a mixture of erfs there: they differ by about 0.01)."""
    from sklearn.gaussian_process import GaussianProcessClassifier
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel

    from jaxabc.surrogate import sampling

    rng = np.random.default_rng(0)
    x = rng.uniform(size=(100, 2))
    ok = np.sum((x - 0.5) ** 2, axis=1) > 0.04  # an island of failures
    grid = rng.uniform(size=(1000, 2))
    with jax.enable_x64(True):
        gp = sampling.fit_gp_classifier(x, ok, size=130)  # padded rows must not matter
        p = np.exp(np.asarray(sampling.gp_log_success(gp, jnp.asarray(grid))))
    kernel = ConstantKernel(1.0, sampling.GP_AMP_BOUNDS) * RBF(np.full(2, 0.2), sampling.GP_LS_BOUNDS)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reference = GaussianProcessClassifier(kernel).fit(x, ok.astype(int)).predict_proba(grid)[:, 1]
    assert np.max(np.abs(p - reference)) < 0.03
    assert not bool(sampling.fit_gp_classifier(x, np.ones(100, bool)).active)  # one outcome: off


def test_feasibility_follows_a_curved_failure_boundary():
    """Runs fail above a sine (one period across the box): the quadratic boundary cannot follow
    it, and a design that trusts it places runs where they fail.  With the GP classifier beside
    it, few of the points given an even chance fail; the quadratic's misses (feasible points it
    doubts) remain, as the two must agree."""
    from jaxabc.surrogate import sampling

    def succeeds(x):
        return x[:, 1] < 0.5 + 0.25 * np.sin(2 * np.pi * x[:, 0])

    rng = np.random.default_rng(1)
    x = rng.uniform(size=(200, 2))
    grid = rng.uniform(size=(4000, 2))
    truth = succeeds(grid)
    with jax.enable_x64(True):
        model = sampling.fit_feasibility(x, succeeds(x))
        feasible = np.asarray(sampling.feasibility(model, jnp.asarray(grid))) >= 0.5
        quadratic = np.exp(np.asarray(sampling.quadratic_log_success(model, jnp.asarray(grid)))) >= 0.5
    # Errors of the GP lie in a band about a run spacing (200**-0.5 ~ 0.07) wide along the
    # boundary; the quadratic's misplaced boundary errs well beyond it.
    assert np.mean(~truth[feasible]) < 0.03
    assert np.mean(~truth[quadratic]) > 0.06
    assert np.mean(feasible & ~quadratic) == 0.0  # never more permissive than the quadratic


def test_replicates_count_once_in_the_nearest_run_cut():
    """Eight successful replicates at one site must not outvote the failures around a point: the
    nearest sites of ``p`` are two failures, the replicate site and three more failures."""
    from jaxabc.surrogate import sampling

    p = np.array([0.5, 0.5])
    failed = np.array([[0.51, 0.5], [0.5, 0.51], [0.5, 0.3], [0.7, 0.5], [0.3, 0.5]])
    replicate = np.repeat([[0.5, 0.6]], 8, axis=0)
    far_ok = np.array([[0.05, 0.05], [0.95, 0.95], [0.05, 0.95], [0.95, 0.05]])
    x = np.concatenate([failed, replicate, far_ok])
    ok = np.concatenate([np.zeros(len(failed), bool), np.ones(len(replicate) + len(far_ok), bool)])
    model = sampling.fit_feasibility(x, ok, size=40)
    assert not bool(sampling.nearest_runs_succeed(model, jnp.asarray(p[None]))[0])
    # The replicate site, its nearest four sites failed, is not cut: its own runs succeed.
    assert bool(sampling.nearest_runs_succeed(model, jnp.asarray([[0.5, 0.62]]))[0])
    # A site with two failures among its eight runs counts a quarter.
    ok_mixed = ok.copy()
    ok_mixed[len(failed) : len(failed) + 2] = False
    mixed = sampling.fit_feasibility(x, ok_mixed)
    site = np.flatnonzero(np.all(np.isclose(np.asarray(mixed.runs_x), replicate[0]), axis=1))
    assert site.size == 1 and np.isclose(float(mixed.runs_failed[site[0]]), 0.25)


def constant_extra_summary(key, theta):
    # A third summary the "data set does not measure": the simulator zeroes it, as the water
    # plugin zeroes g_OH statistics for X-ray data.
    return jnp.concatenate([linear_gaussian(key, theta), jnp.zeros(1)])


@pytest.mark.slow  # default-suite time: 25-75 s on 2 cores
def test_a_constant_summary_changes_nothing_and_is_not_checked():
    observed = np.concatenate([OBSERVED, [0.0]])
    algorithm = build(PRIOR, 2000, observed=observed, max_simulations=200)
    state, info, _, _ = _drive(algorithm, constant_extra_summary, VmapExecutor(), observed=observed)
    assert bool(info.stop) and bool(state.validated)
    particles, _ = algorithm.posterior(state)
    mean, cov = exact_posterior()
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(particles.mean(axis=0) - mean) < 0.2 * sd), (particles.mean(axis=0), mean)
    assert np.all(np.abs(particles.std(axis=0) / sd - 1) < 0.15), (particles.std(axis=0), sd)
    errors = np.asarray(state.holdout_errors)
    assert np.all(np.isnan(errors[:, 2])) and np.all(np.isfinite(errors[:, :2]))


def test_lack_of_fit_accepts_a_smooth_simulator_and_rejects_an_inflated_nugget():
    rng = np.random.default_rng(0)
    x, group = design.initial_design(0, 2, 40, 8)
    z = x[:, :1] + 0.3 * x[:, 1:] ** 2 + 0.02 * rng.normal(size=(len(x), 1))
    z = (z - z.mean()) / z.std()
    ok = np.ones(len(x), bool)
    emu = emulator.fit(x, z, ok)
    rep_var, df = diagnostics.replicate_variance(z, group, ok)
    nugget = np.exp(2 * np.asarray(emu.log_noise))
    assert df == 7 and diagnostics.lack_of_fit(nugget, rep_var, df)[0] is True
    # A GP that had swallowed structure as noise: nugget 25 times the replicate scatter.
    assert diagnostics.lack_of_fit(25 * rep_var, rep_var, df)[0] is False
    assert diagnostics.lack_of_fit(nugget, rep_var, 0)[0] is None


def _factor_correlation(q: int, seed: int) -> np.ndarray:
    """Correlation of ``q`` summaries driven by three common factors plus a little independent
    noise: a few fluctuations (density, first-shell order) move all RDF features of a run."""
    loadings = np.random.default_rng(seed).normal(size=(q, 3)) * np.array([1.0, 0.5, 0.35])
    cov = loadings @ loadings.T + 0.05 * np.eye(q)
    sd = np.sqrt(np.diag(cov))
    return cov / np.outer(sd, sd)


@pytest.mark.parametrize("seed", range(5))
def test_the_noise_correlation_from_few_runs_keeps_the_likelihood_honest(seed):
    from jaxabc.surrogate._fit import noise_correlation

    # 100 residual vectors of 9 summaries with factor-structured noise.  The expected held-out
    # Mahalanobis distance per output under the estimate R_hat is tr(R_hat^-1 R) / q exactly;
    # it must stay below the validation's bound for 20 held-out runs, or the likelihood is
    # sharper than the noise (the earlier thresholded estimate gave 10-26x here, 5x on water).
    q, n = 9, 100
    true = _factor_correlation(q, 123)
    rng = np.random.default_rng(seed)
    residuals = rng.multivariate_normal(np.zeros(q), true * 0.3**2, size=n)
    estimate = noise_correlation(residuals)
    np.testing.assert_allclose(np.diag(estimate), 1.0)
    assert np.linalg.eigvalsh(estimate).min() > 0
    _, bound = diagnostics.holdout_bounds(20 * q)
    assert np.trace(np.linalg.solve(estimate, true)) / q < bound


def test_the_joint_holdout_check_catches_a_wrong_noise_correlation():
    # Held-out runs whose errors are correlated +0.9 pairwise: with the right correlation the
    # check passes; with the sign wrong the marginal errors still pass but the joint must not.
    q, h = 4, 20
    true = np.kron(np.eye(2), np.array([[1.0, 0.9], [0.9, 1.0]]))
    wrong = np.kron(np.eye(2), np.array([[1.0, -0.9], [-0.9, 1.0]]))
    rng = np.random.default_rng(1)
    z = rng.multivariate_normal(np.zeros(q), true, size=h)
    mean, var, noise_var = np.zeros((h, q)), np.full((h, q), 1e-6), np.ones(q)
    right = diagnostics.holdout_check(z, mean, var, noise_var, true)
    assert right.passed and right.joint_mean_squared < right.mean_squared_max
    bad = diagnostics.holdout_check(z, mean, var, noise_var, wrong)
    assert bad.coverage >= bad.coverage_min and bad.mean_squared <= bad.mean_squared_max
    assert not bad.passed and bad.joint_mean_squared > bad.mean_squared_max
    assert np.isnan(diagnostics.holdout_check(z, mean, var, noise_var).joint_mean_squared)


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"max_simulations": 15}, "no room for validation"),
        ({"max_simulations": 60, "num_initial": 40, "num_holdout": 20}, "no room for validation"),
        ({"max_simulations": 200, "on_failure": "ignore"}, "on_failure"),
        ({"max_simulations": 200, "min_feasibility": 1.0}, "min_feasibility"),
    ],
)
def test_bad_settings_are_refused(options, match):
    with pytest.raises(ValueError, match=match):
        build(PRIOR, 1000, observed=OBSERVED, **options)
    with pytest.raises(ValueError, match="num_particles"):
        build(PRIOR, 500, observed=OBSERVED, max_simulations=200)


def test_design_sizes_follow_a_small_budget_and_keep_given_values():
    from jaxabc.surrogate._settings import design_defaults

    # From ~134 runs (80 d for the start) the fixed sizes; at 50 in 2-D a start, replicates and
    # one validation that leave 26 runs (five batches of five) to the design.
    assert design_defaults(200, 2, None, None, None, None) == (20, 8, 10, 20)
    assert design_defaults(500, 8, None, None, None, None) == (80, 8, 10, 20)
    start, reps, batch, holdout = design_defaults(50, 2, None, None, None, None)
    assert (start, reps, batch, holdout) == (12, 4, 5, 8) and 50 - (start + reps + holdout) >= 5 * batch
    # Five parameters at 50 runs: the start still has 4 d + 4 points and leaves a batch.
    start, reps, batch, holdout = design_defaults(50, 5, None, None, None, None)
    assert start == 24 and 50 - (start + reps + holdout) >= batch
    assert design_defaults(50, 2, 30, 0, 7, 5) == (30, 0, 7, 5)
    assert build(PRIOR, 1000, observed=OBSERVED, max_simulations=50).settings["num_holdout"] == 8


def step_simulator(key, theta):
    noise = 0.02 * jax.random.normal(key, (2,))
    return jnp.stack([theta[0] + 2.0 * (theta[0] > 0), theta[1]]) + noise


def rough_simulator(key, theta):
    # Structure far finer than a 120-run design resolves (a chaotic response).
    noise = 0.02 * jax.random.normal(key, (2,))
    return jnp.stack([theta[0] + 0.5 * jnp.sin(15 * theta[0] + 10 * theta[1]), theta[1]]) + noise


@pytest.mark.slow
@pytest.mark.parametrize("simulator", [step_simulator, rough_simulator])
def test_a_simulator_the_gp_cannot_fit_is_reported_not_silently_fitted(simulator):
    observed = np.array([0.1, 0.3])
    algorithm = build(PRIOR, 1000, observed=observed, max_simulations=120)
    with pytest.warns(RuntimeWarning, match="failed validation"):
        state, info, num_sims, _ = _drive(algorithm, simulator, VmapExecutor(), observed=observed)
    assert bool(info.stop) and num_sims <= 120
    assert algorithm.stop_reason(algorithm.settings, info).startswith("NOT VALIDATED")
    diag = algorithm.finalize(state)["diagnostics"]
    assert not diag["validated"] and diag["failure"]
    strict = build(PRIOR, 1000, observed=observed, max_simulations=120, on_failure="raise")
    with pytest.raises(EmulatorFailure):
        _drive(strict, simulator, VmapExecutor(), observed=observed)


@pytest.mark.slow
@pytest.mark.timeout(1800)  # 60 runs of 200 simulations, ~10 s each on 2 cores
def test_nominal_95_percent_intervals_cover_the_truth():
    # Simulation-based calibration on the linear-Gaussian toy: data first, then the truth from
    # the exact posterior (flat prior; the box is > 10 posterior sds away), so a calibrated
    # method holds the truth in its 95 % equal-tailed intervals 95 % of the time.
    num_datasets = 60
    rng = np.random.default_rng(2024)
    _, cov = exact_posterior()
    inside = []
    for r in range(num_datasets):
        observed = rng.uniform(-1.5, 1.5, size=2)
        truth = rng.multivariate_normal(np.linalg.solve(A, observed), cov)
        algorithm = build(PRIOR, 1000, observed=observed, max_simulations=200)
        state, _, _, _ = _drive(algorithm, linear_gaussian, VmapExecutor(), seed=r, observed=observed)
        particles, _ = algorithm.posterior(state)
        lo, hi = np.quantile(particles, [0.025, 0.975], axis=0)
        inside.append((lo <= truth) & (truth <= hi))
    coverage = float(np.mean(inside))
    print(f"surrogate 95 % interval coverage over {num_datasets} data sets: {coverage:.3f}")
    assert 0.90 <= coverage <= 0.98, coverage


def test_run_surrogate_through_the_driver_resumes_identically(tmp_path):
    """``jaxabc.run("surrogate", ...)``: budget respected, >= 1000 draws, resume == uninterrupted."""
    import jaxabc

    kw = dict(max_simulations=80, seed=4, num_particles=1000)
    full = jaxabc.run("surrogate", linear_gaussian, PRIOR, OBSERVED, **kw)
    assert full.num_simulations <= 80 and full.particles.shape == (1000, 2)
    assert any("design" in key for key in full.diagnostics)
    first = jaxabc.run(
        "surrogate", linear_gaussian, PRIOR, OBSERVED, checkpoint_dir=tmp_path, stop_after_iterations=2, **kw
    )
    assert "resumable" in first.stop_reason
    resumed = jaxabc.run("surrogate", linear_gaussian, PRIOR, OBSERVED, checkpoint_dir=tmp_path, resume=True, **kw)
    np.testing.assert_array_equal(resumed.particles, full.particles)
    assert resumed.num_simulations == full.num_simulations
    assert resumed.stop_reason == full.stop_reason


# ----------------------------------------------------------------------------- ABC mode


def test_emulated_draws_carry_emulator_and_simulator_noise():
    """An emulated simulation = emulator mean + emulator sd + simulator noise, in raw units; it
    fails (NaN) where the feasibility classifier says runs fail."""
    from jaxabc.surrogate import abc_mode, sampling

    rng = np.random.default_rng(1)
    x = rng.uniform(size=(40, 2))
    y = np.column_stack([3.0 + 2.0 * x[:, 0], -1.0 + 0.5 * x[:, 1]]) + 0.05 * rng.normal(size=(40, 2))
    ok = np.ones(40, bool)
    with jax.enable_x64(True):
        transform = emulator.fit_transform(y, 16)
        z = np.asarray(transform.apply(jnp.asarray(y)))
        # Fixed hyper-parameters (amplitude 1, length scale 1, noise sd 0.1 per output) instead of
        # emulator.fit: what is tested is the draw, and the fit's compilation costs seconds.
        params = jnp.tile(jnp.array([0.0, 0.0, 0.0, np.log(0.1)]), (2, 1))
        emu = emulator._condition(params, jnp.asarray(x), jnp.asarray(z), jnp.asarray(ok))
        low, high = np.array([-1.0, 0.0]), np.array([1.0, 2.0])
        feasible = sampling.fit_feasibility(x, x[:, 0] < 0.7)  # fails beyond x0 = 0.7
        model = abc_mode.emulated_simulator(emu, transform, jnp.eye(2), feasible, low, high)
        theta = jnp.array([-0.2, 1.0])  # x = (0.4, 0.5): feasible
        n = 4000
        keys = jax.random.split(jax.random.key(0), n)
        batch = jax.jit(jax.vmap(abc_mode.emulated_summaries, in_axes=(None, 0, None)))
        draws = np.asarray(batch(model, keys, theta))
        mean, var = (np.asarray(a)[0] for a in jax.jit(emulator.predict)(emu, jnp.array([[0.4, 0.5]])))
        scale = np.asarray(transform.scale)
        expected_mean = np.asarray(transform.mean) + scale * mean
        expected_var = scale**2 * (var + np.exp(2 * np.asarray(emu.log_noise)))
        p_ok = float(sampling.feasibility(feasible, jnp.array([[0.4, 0.5]]))[0])
        good = np.all(np.isfinite(draws), axis=1)
        # Binomial error of the failure fraction, sampling errors of mean and variance (4 sigma).
        assert abs(good.mean() - p_ok) < 4 * np.sqrt(p_ok * (1 - p_ok) / n) + 1e-3
        m = good.sum()
        assert np.all(np.abs(draws[good].mean(axis=0) - expected_mean) < 4 * np.sqrt(expected_var / m))
        assert np.all(np.abs(draws[good].var(axis=0) / expected_var - 1) < 4 * np.sqrt(2 / m))
        np.testing.assert_allclose(expected_mean, [3.8, -0.75], atol=0.1)  # the simulator's own mean
        # Far inside the failure region almost every draw fails.
        bad = batch(model, keys, jnp.array([0.9, 1.0]))  # same shapes: no second compilation
        assert np.mean(np.isnan(np.asarray(bad[:, 0]))) > 0.9


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"mode": "likelihood"}, "mode must be one of"),
        ({"mode": "abc", "abc_alpha": 0.7}, "abc_alpha=0.7 cannot keep exactly"),
        ({"mode": "abc", "abc_distance": "manhattan"}, "unknown distance"),
    ],
)
def test_bad_abc_settings_are_refused(options, match):
    with pytest.raises(ValueError, match=match):
        build(PRIOR, 1000, observed=OBSERVED, max_simulations=200, **options)


def test_a_checkpoint_from_before_the_abc_mode_restores(gaussian_run):
    algorithm, state, _, _ = gaussian_run
    later = (".log_weights", ".abc_threshold", ".abc_generations", ".abc_emulated")
    flat = {keystr(p): np.asarray(v) for p, v in tree_flatten_with_path(state)[0] if keystr(p) not in later}
    restored = algorithm.restore_state(flat)
    np.testing.assert_array_equal(restored.draws, state.draws)
    assert restored.log_weights.shape == (1000 * 2,) and np.all(restored.log_weights == 0)
    assert np.isnan(restored.abc_threshold) and int(restored.abc_generations) == 0


def abc_posterior_with_tolerance(threshold: float) -> np.ndarray:
    """Covariance of the ABC posterior at Euclidean tolerance ``eps`` on the linear-Gaussian toy.

    Accepting ``|s - s_obs| <= eps`` convolves the likelihood with a uniform disc, whose
    per-coordinate variance is ``eps^2 / 4`` in two dimensions: the noise covariance grows by
    that much, the mean does not move (the disc is symmetric)."""
    noise = np.diag(NOISE_SD**2) + threshold**2 / 4 * np.eye(2)
    return np.linalg.inv(A.T @ np.linalg.inv(noise) @ A)


@pytest.mark.slow
def test_abc_mode_matches_the_analytic_posterior_within_its_tolerance():
    import jaxabc

    result = jaxabc.run(
        "surrogate",
        linear_gaussian,
        PRIOR,
        OBSERVED,
        max_simulations=200,
        seed=0,
        num_particles=2000,
        mode="abc",
        abc_distance="euclidean",
    )
    diag = result.diagnostics
    assert result.num_simulations <= 200 and result.particles.shape == (2000, 2)
    assert diag["validated"] and diag["mode"] == "abc" and len(diag["design_points"]) == result.num_simulations
    assert result.stop_reason.startswith("emulator validated")
    # The predictive check runs on the weighted ABC particles too; the data came from the model.
    assert diag["observed_misfit"]["p_value"] > diagnostics.MISFIT_P_VALUE
    eps = diag["abc_threshold"]
    # APMCABC's acceptance cutoff (0.03) stops below the smaller noise sd: the tolerance then
    # widens the posterior by a few per cent, which the comparison below accounts for.
    assert 0 < eps < NOISE_SD.min()
    mean, cov = exact_posterior()
    cov_eps = abc_posterior_with_tolerance(eps)
    sd, sd_eps = np.sqrt(np.diag(cov)), np.sqrt(np.diag(cov_eps))
    ess = result.effective_sample_size()
    assert ess > 500
    est = result.bayes_estimate()
    post_cov = result.covariance()
    # Mean: 0.2 posterior sd (the bar) is > 4 Monte Carlo standard errors at this ESS.
    assert np.all(np.abs(est - mean) < 0.2 * sd), (est, mean)
    # sd: 15 % of the tolerance-widened sd (MC error of an sd ~ 1 / sqrt(2 ESS), 3 %).
    assert np.all(np.abs(np.sqrt(np.diag(post_cov)) / sd_eps - 1) < 0.15), (np.sqrt(np.diag(post_cov)), sd_eps)
    rho_eps = cov_eps[0, 1] / np.prod(sd_eps)
    # Correlation: within 0.1 (MC error (1 - rho^2) / sqrt(ESS) ~ 0.04).
    assert abs(result.correlation()[0, 1] - rho_eps) < 0.1, (result.correlation()[0, 1], rho_eps)


def mostly_failing(key, theta):
    # Only a quarter of the box (theta0 < -2) gives summaries, as water's prior mostly vaporises.
    return jnp.where(theta[0] < -2.0, linear_gaussian(key, theta), jnp.nan)


def test_replicate_sites_keep_away_from_failures_and_from_each_other():
    x_ok = np.array([[0.5, 0.5], [0.1, 0.1], [0.1, 0.95], [0.9, 0.2]])
    # No failures: the run nearest the centre, then the earliest run half a box from it.
    site, count = design.replicate_sites(x_ok, np.zeros((0, 2)), 7)
    np.testing.assert_array_equal(site, [0, 1])
    np.testing.assert_array_equal(count, [4, 3])
    # Runs failed around the centre: the sites move to the successful runs farthest from them.
    failed = np.array([[0.45, 0.5], [0.55, 0.5], [0.5, 0.6], [0.25, 0.2]])
    site, _ = design.replicate_sites(x_ok, failed, 8)
    assert site[0] == 2 and site[1] == 3, site
    site, count = design.replicate_sites(x_ok[:1], failed, 5)
    np.testing.assert_array_equal(site, [0])
    np.testing.assert_array_equal(count, [5])
    with pytest.raises(ValueError, match="successful run"):
        design.replicate_sites(np.zeros((0, 2)), failed, 4)


def failing_centre(key, theta):
    # Runs fail over the middle of the box (the start's old replicate site) and beyond it.
    return jnp.where(theta[0] > -1.0, jnp.nan, linear_gaussian(key, theta))


def test_replicates_go_where_runs_succeed_and_measure_the_noise():
    observed = np.array([-2.5, -0.7])
    algorithm = build(PRIOR, 1000, observed=observed, max_simulations=120, num_replicates=8, batch_size=4)
    state, _, _, proposals = _drive(algorithm, failing_centre, VmapExecutor(), max_iterations=2, observed=observed)
    c = int(state.count)
    group, ok = np.asarray(state.group[:c]), np.asarray(state.ok[:c])
    assert len(proposals[0]) == algorithm.settings["num_initial"], "no replicates in the start"
    np.testing.assert_array_equal(np.unique(group[group >= 0]), [0, 1])
    assert np.sum(group >= 0) == 8 + 2  # the repeats and their two sites
    assert np.all(ok[group >= 0]), "every replicate succeeded"
    for g in (0, 1):
        np.testing.assert_array_equal(np.unique(state.thetas[:c][group == g], axis=0).shape, (1, 2))
    # The pooled within-group variance estimates the simulator's noise: 8 degrees of freedom,
    # so the ratio lies between the chi-square 0.1 % and 99.9 % points over 8 (0.107, 3.27).
    s = np.asarray(state.summaries[:c])
    resid = np.concatenate([s[group == g] - s[group == g].mean(axis=0) for g in (0, 1)])
    ratio = np.sum(resid**2, axis=0) / 8 / NOISE_SD**2
    assert np.all((ratio > 0.107) & (ratio < 3.27)), ratio


def test_too_few_successes_explore_where_runs_succeed():
    algorithm = build(PRIOR, 1000, observed=OBSERVED, max_simulations=200, num_initial=8, num_replicates=0)
    key = jax.random.key(0)
    proposal = algorithm.initial_proposal(key)
    keys = jax.random.split(key, proposal.thetas.shape[0])
    summaries = np.asarray(jax.vmap(mostly_failing)(keys, jnp.asarray(proposal.thetas)))
    ok = np.all(np.isfinite(summaries), axis=1)
    assert 0 < ok.sum() < 3, "the toy needs a start with too few successes for an emulator"
    state, info = algorithm.init(key, proposal, np.zeros(len(ok)), summaries)
    assert not bool(info.stop)
    batch = algorithm.propose(key, state).thetas
    assert batch.shape == (algorithm.settings["batch_size"], 2)
    # The success classifier sends most of the batch into the quarter of the box that works.
    assert np.mean(batch[:, 0] < -2.0) > 0.5, batch
    # No point repeats a run already made.
    gaps = np.linalg.norm(batch[:, None] - np.asarray(proposal.thetas)[None], axis=-1)
    assert gaps.min() > 0.05


@pytest.mark.slow  # default-suite time: 25-75 s on 2 cores
def test_a_two_mode_posterior_is_weighed_by_its_mass_not_by_where_chains_start():
    import jaxabc

    # s = theta^2 + noise with s_obs = 1: modes at theta = -1 and +1 of equal mass.  NUTS chains
    # do not cross the valley at 0, so the reported draws must come from the importance sample,
    # and the result's ESS must be that of those draws, not the 2000 rows.
    prior = Uniform(np.array([-2.0]), np.array([2.0]))

    def simulate(key, theta):
        return theta[0] ** 2 + 0.05 * jax.random.normal(key, (2,))

    result = jaxabc.run("surrogate", simulate, prior, np.array([1.0, 1.0]), max_simulations=150, seed=0)
    assert result.diagnostics["posterior_sampler"].startswith("importance resampling")
    ess = result.effective_sample_size()
    assert 50 <= ess <= len(result.weights) and ess == pytest.approx(float(result.ess[-1]))
    x, w = result.particles[:, 0], result.weights
    assert np.all(np.abs(np.abs(x) - 1.0) < 0.2)
    # Equal masses: the share of +1 is 1/2 up to its Monte Carlo error at this ESS.
    assert abs(w[x > 0].sum() - 0.5) < 4.0 * np.sqrt(0.25 / ess)


@pytest.mark.slow  # default-suite time: 25-75 s on 2 cores
def test_the_result_ess_of_nuts_draws_is_the_chains_not_the_rows():
    import jaxabc

    prior = Uniform(np.array([-3.0]), np.array([3.0]))

    def simulate(key, theta):
        return theta[0] + 0.2 * jax.random.normal(key, (2,))

    result = jaxabc.run("surrogate", simulate, prior, np.array([0.3, 0.5]), max_simulations=100, seed=1)
    assert result.diagnostics["posterior_sampler"] == "NUTS"
    assert result.effective_sample_size() == pytest.approx(float(result.ess[-1]))
    assert result.effective_sample_size() < len(result.weights)


_MODES = ((0.3, (0.2, 0.9), (3e-3, 9e-3), 0.8), (0.7, (0.7, 0.3), (6e-3, 3e-3), -0.5))


def _two_narrow_modes(x: np.ndarray) -> tuple[np.ndarray]:
    """Log density (unnormalised) of the mixture ``_MODES`` (share, mean, sds, correlation)."""
    out = []
    for share, mean, sd, rho in _MODES:
        cov = np.array([[sd[0] ** 2, rho * sd[0] * sd[1]], [rho * sd[0] * sd[1], sd[1] ** 2]])
        out.append(np.log(share) + scipy.stats.multivariate_normal(mean, cov).logpdf(x))
    return (np.logaddexp(*out),)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_importance_pool_resolves_narrow_modes(monkeypatch, seed):
    # Two modes about as wide as the spacing of the 16384-point uniform pass, 0.8 apart: the
    # first local Gaussian spans both; the refinements resolve each.
    rng = np.random.default_rng(seed)
    points, (log_density,) = design.importance_pool(rng, 2, 1 << 14, _two_narrow_modes)
    log_w = log_density - points.log_q
    ess = design.kish_ess(log_w)
    assert ess >= (1 << 14) / design.POINTS_PER_ESS
    w = np.exp(log_w - log_w.max())
    w /= w.sum()
    upper = points.x[:, 1] > 0.6
    # Mode shares, means and sds against the exact ones, within 4 Monte Carlo standard errors.
    assert abs(w[upper].sum() - 0.3) < 4 * np.sqrt(0.3 * 0.7 / ess)
    for sel, (share, mean, sd, _) in zip((upper, ~upper), _MODES, strict=True):
        ws = w[sel] / w[sel].sum()
        m = ws @ points.x[sel]
        s = np.sqrt(ws @ (points.x[sel] - m) ** 2)
        n = share * ess
        assert np.all(np.abs(m - mean) < 4 * np.asarray(sd) / np.sqrt(n)), (m, mean)
        assert np.all(np.abs(s / sd - 1) < 4 / np.sqrt(2 * n)), (s, sd)
    # Without the refinements the same pool resolves them with a few dozen effective points.
    monkeypatch.setattr(design, "MAX_REFINEMENTS", 0)
    points, (log_density,) = design.importance_pool(np.random.default_rng(seed), 2, 1 << 14, _two_narrow_modes)
    assert design.kish_ess(log_density - points.log_q) < 100


def test_the_importance_pool_resolves_a_peak_against_the_box_edge():
    # A sharp peak cut by the upper edge (the neutron data's synthetic likelihood): the exact
    # marginal of the second coordinate is a truncated normal.
    sd = np.array([5e-5, 4e-4])
    centre = np.array([0.046, 0.9998])

    def log_density(x):
        return (-0.5 * np.sum(((x - centre) / sd) ** 2, axis=1),)

    points, (lp,) = design.importance_pool(np.random.default_rng(1), 2, 1 << 15, log_density)
    log_w = lp - points.log_q
    ess = design.kish_ess(log_w)
    w = np.exp(log_w - log_w.max())
    w /= w.sum()
    exact = scipy.stats.truncnorm(-np.inf, (1 - centre[1]) / sd[1], loc=centre[1], scale=sd[1])
    assert ess >= (1 << 15) / design.POINTS_PER_ESS
    m = w @ points.x
    assert abs(m[0] - centre[0]) < 4 * sd[0] / np.sqrt(ess)
    assert abs(m[1] - exact.mean()) < 4 * exact.std() / np.sqrt(ess)
    assert abs(np.sqrt(w @ (points.x[:, 1] - m[1]) ** 2) / exact.std() - 1) < 4 / np.sqrt(2 * ess)


def test_a_posterior_of_few_effective_draws_warns(gaussian_run):
    algorithm, state, _, _ = gaussian_run
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert algorithm.finalize(state)["ess"] >= diagnostics.MIN_POSTERIOR_ESS  # no warning
    # The same draws, the weight on five of them: what an importance pool that saw a sharp
    # posterior through a handful of points reports.
    log_weights = np.full(len(state.draws), -np.inf)
    log_weights[:5] = 0.0
    with pytest.warns(RuntimeWarning, match="effective sample size of 5 "):
        extras = algorithm.finalize(state._replace(log_weights=log_weights))
    assert extras["ess"] == pytest.approx(5.0)


@pytest.mark.slow  # default-suite time: 25-75 s on 2 cores
def test_a_sharp_two_mode_posterior_is_resolved_by_thousands_of_draws():
    import jaxabc

    # As the two-mode test, with noise 50 times smaller: each mode is 1e-4 of the box wide, far
    # narrower than the importance pool's uniform spacing.  This checks the sampler (effective
    # draws, the modes' masses and widths), not the emulator's accuracy at the modes' centres.
    noise = 0.001
    prior = Uniform(np.array([-2.0]), np.array([2.0]))

    def simulate(key, theta):
        return theta[0] ** 2 + noise * jax.random.normal(key, (2,))

    result = jaxabc.run("surrogate", simulate, prior, np.array([1.0, 1.0]), max_simulations=150, seed=0)
    ess = result.effective_sample_size()
    assert ess >= 500
    x, w = result.particles[:, 0], result.weights
    assert abs(w[x > 0].sum() - 0.5) < 4.0 * np.sqrt(0.25 / ess)
    # theta^2 ~ N(1, noise^2 / 2) at each mode: theta's sd is noise / (2 sqrt 2).
    exact_sd = noise / (2 * np.sqrt(2))
    for sel in (x > 0, x < 0):
        ws = w[sel] / w[sel].sum()
        sd = np.sqrt(ws @ (x[sel] - ws @ x[sel]) ** 2)
        assert abs(sd / exact_sd - 1) < 0.15, (sd, exact_sd)


def test_padded_rows_double_to_256_then_step_by_64_within_the_budget():
    from jaxabc.surrogate._fit import padded_rows

    assert [padded_rows(n, 500) for n in (3, 64, 65, 129, 256)] == [64, 64, 128, 256, 256]
    # Past 256 a doubling would pad 268 rows to the budget (up to 8x the cubic cost).
    assert [padded_rows(n, 500) for n in (257, 268, 321, 460)] == [320, 320, 384, 500]
    assert [padded_rows(n, 100) for n in (65, 100)] == [100, 100]


def test_tolerance_zero_spends_the_budget():
    """``tolerance=0`` turns the early stop off (the remedy the peers page names where it is
    overconfident): the design runs until the budget cannot pay another batch.  With the default
    tolerance this run stops at 158 of 200 simulations."""
    import jaxabc

    budget = 200
    settings = build(PRIOR, 1000, observed=OBSERVED, max_simulations=budget, tolerance=0.0).settings
    run = jaxabc.run(
        "surrogate", linear_gaussian, PRIOR, OBSERVED, max_simulations=budget, seed=3, num_particles=1000, tolerance=0.0
    )
    assert budget - settings["batch_size"] <= run.num_simulations <= budget
