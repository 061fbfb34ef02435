"""Model criticism finds hidden effects, names them, and shows a held-out gain.

Simulator: the analytic LJ-liquid stand-in :func:`md.criticism_catalogue.make_lj_surrogate`
(same summary layout as the jax-md engine's ``reduced_liquid`` preset: 25 g(r) bins, D, P, U/N,
and the same exact scalings, so temperature and epsilon are confusable in g(r)).  The engine
itself needs minutes per batch on 2 cores, far beyond a test budget of hundreds of ABC
simulations per case; an engine smoke test is marked ``slow``.

Protocol for a hidden effect: the truth is (sigma, epsilon) drawn from a seed, plus one effect at
a magnitude chosen by the seed so that its signature, *after the base parameters absorbed what
they can*, moves the most affected summary by 6 to 9 of its noise standard deviations (checked
>= 5).  The pipeline sees only the data.
"""

from __future__ import annotations

import zlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxabc
from jaxabc.criticism import Catalogue, Effect, critique
from jaxabc.criticism.causes import sensitivities
from jaxabc.criticism.misfit import adjust_pvalues, refit_operator
from jaxabc.criticism.predictive import shrunk_covariance
from md.criticism_catalogue import lj_catalogue, make_lj_surrogate

SETUP = make_lj_surrogate()
CATALOGUE = SETUP.catalogue
K = len(CATALOGUE)
S = len(SETUP.names)
# Held out: every third g(r) bin from the first peak on, D and U (fitted: the rest of g(r) and P).
HELD_OUT = np.zeros(S, bool)
HELD_OUT[np.arange(10, 25, 3)] = True
HELD_OUT[[25, 27]] = True
PRIOR = jaxabc.Uniform([0.9, 0.8], [1.1, 1.2], names=("sigma_nm", "epsilon_kj_mol"), units=("nm", "kJ/mol"))
EXECUTOR = jaxabc.VmapExecutor()
_REPS = np.asarray(jax.vmap(SETUP.simulate, (0, None))(
    jax.random.split(jax.random.key(9), 200), jnp.asarray([1.0, 1.0] + [0.0] * K)))
_SD = _REPS.std(0)
FIT_INDEX = np.flatnonzero(~HELD_OUT & (_SD > 0))
FIT_DISTANCE = jaxabc.distances.standardized_euclidean(jnp.asarray(_SD[FIT_INDEX], jnp.float32))
CRITIQUE_OPTIONS = dict(summary_names=SETUP.names, groups=SETUP.groups, num_draws=100, num_replicates=100,
                        executor=EXECUTOR, extend_options=dict(num_particles=400, acceptance_cutoff=0.03))


def base_simulate(key, theta):
    """The base model the user calibrated: effects at null, fitted summaries only."""
    return SETUP.simulate(key, jnp.concatenate([theta, jnp.zeros(K, theta.dtype)]))[FIT_INDEX]


def fit_base(observed: np.ndarray, seed: int, algorithm: str = "rejection") -> jaxabc.ABCResult:
    options = dict(quantile=0.05) if algorithm == "rejection" else dict(acceptance_cutoff=0.05)
    return jaxabc.run(algorithm, base_simulate, PRIOR, observed[FIT_INDEX], num_particles=200,
                      distance=FIT_DISTANCE, seed=seed, executor=EXECUTOR, **options)


def observe(theta_full: np.ndarray, seed: int) -> np.ndarray:
    return np.asarray(jax.jit(SETUP.simulate)(jax.random.key(10_000 + seed), jnp.asarray(theta_full, jnp.float32)),
                      np.float64)


def absorbed_signal(theta_full: np.ndarray, effect: str, num: int = 400) -> tuple[float, dict[str, float]]:
    """Oracle: noise-sd size of d E[s]/d eta after the base parameters absorb what they can.

    Returns the largest shift of one summary per unit of the effect parameter, in units of that
    summary's null standard deviation after the refit, and each group's largest shift.
    """
    keys = jax.random.split(jax.random.key(77), num)
    reps = np.asarray(jax.vmap(SETUP.simulate, (0, None))(keys, jnp.asarray(theta_full, jnp.float32)), float)
    act = reps.std(0) > 0
    cov = shrunk_covariance(reps[:, act])
    eff = CATALOGUE[effect]
    k = CATALOGUE.index(effect)
    pts = [(0, theta_full[0] - 0.005, theta_full[0] + 0.005), (1, theta_full[1] - 0.02, theta_full[1] + 0.02),
           (2 + k, *eff.finite_difference_points())]
    sens = sensitivities(SETUP.simulate, theta_full, keys[:128], pts, EXECUTOR)[act]
    a = refit_operator(sens[:, :2], cov, ~HELD_OUT[act])
    c = a @ cov @ a.T
    u = a @ sens[:, 2]
    load = np.abs(u) / np.sqrt(np.maximum(np.diag(c), 1e-300))
    idx = np.flatnonzero(act)
    share = {g: float(np.max(load[np.isin(idx, ii)], initial=0.0)) for g, ii in SETUP.groups.items()}
    return float(load.max()), share


def hidden_case(effect: str, seed: int) -> tuple[np.ndarray, float, float, list[str]]:
    """Truth with ``effect`` injected at a seed-chosen 6-9 sd after absorption."""
    rng = np.random.default_rng(seed)
    theta = np.array([rng.uniform(0.97, 1.03), rng.uniform(0.92, 1.08)] + [0.0] * K)
    eff = CATALOGUE[effect]
    per_unit, share = absorbed_signal(theta, effect)
    sign = eff.one_sided or rng.choice([-1.0, 1.0])
    target = rng.uniform(6.0, 9.0)
    bound = eff.high if sign > 0 else eff.low
    eta = float(np.clip(eff.null + sign * target / per_unit, min(eff.null, 0.9 * bound), max(eff.null, 0.9 * bound)))
    theta[2 + CATALOGUE.index(effect)] = eta
    snr = abs(eta - eff.null) * per_unit
    top_groups = sorted(share, key=lambda g: -share[g])[:2]
    return theta, eta, snr, top_groups


def flagged_groups(report) -> set[str]:
    idx = set()
    for m in report.misfits:
        idx |= set(np.asarray(m.indices).tolist())
    return {g for g, ii in SETUP.groups.items() if idx & set(ii.tolist())}


# -- units --------------------------------------------------------------------------------------


def test_adjust_pvalues_holm_and_bh():
    p = np.array([0.01, 0.04, 0.03, 0.005])
    np.testing.assert_allclose(adjust_pvalues(p, "holm"), [0.03, 0.06, 0.06, 0.02])
    np.testing.assert_allclose(adjust_pvalues(p, "bh"), [0.02, 0.04, 0.04, 0.02])
    with pytest.raises(ValueError, match="holm"):
        adjust_pvalues(p, "bonf")


def test_effect_validation_and_catalogue():
    with pytest.raises(ValueError, match="null"):
        Effect("x", 0.1, 1.0, 0.0)
    with pytest.raises(ValueError, match="unique"):
        Catalogue([Effect("x", 0.0, 1.0), Effect("x", 0.0, 2.0)])
    cat = lj_catalogue()
    assert cat.names[0] == "temperature_offset"
    assert all(e.separated_by for e in cat)
    assert cat["qmax_ripple"].kind == "measurement"


def test_simulator_is_vmappable_and_nulls_reproduce_base():
    keys = jax.random.split(jax.random.key(0), 4)
    thetas = jnp.tile(jnp.asarray([1.0, 1.0] + [0.0] * K), (4, 1))
    out = jax.vmap(SETUP.simulate)(keys, thetas)
    assert out.shape == (4, S)
    np.testing.assert_allclose(out[:, FIT_INDEX], jax.vmap(base_simulate)(keys, thetas[:, :2]), rtol=1e-6)


def test_temperature_and_epsilon_are_exactly_confusable_in_g_of_r():
    th = np.array([1.0, 1.0] + [0.0] * K)
    th_t = th.copy()
    th_t[2] = 0.05  # T -> 1.05 T
    th_e = th.copy()
    th_e[1] = 1.0 / 1.05  # eps -> eps / 1.05
    key = jax.random.key(3)
    a, b = (np.asarray(SETUP.simulate(key, jnp.asarray(t, jnp.float32))) for t in (th_t, th_e))
    np.testing.assert_allclose(a[:25], b[:25], atol=1e-5)  # same g(r)
    assert abs(a[26] - b[26]) > 0.1  # the pressure tells them apart


def test_bad_inputs_fail_early():
    obs = observe(np.array([1.0, 1.0] + [0.0] * K), 0)
    res = fit_base(obs, 0)
    with pytest.raises(ValueError, match="shape"):
        critique(res, lambda k, t: SETUP.simulate(k, t)[:10], obs, CATALOGUE, **CRITIQUE_OPTIONS)
    with pytest.raises(ValueError, match="NaN"):
        critique(res, SETUP.simulate, np.where(np.arange(S) == 3, np.nan, obs), CATALOGUE, **CRITIQUE_OPTIONS)
    with pytest.raises(TypeError, match="Catalogue"):
        critique(res, SETUP.simulate, obs, ["qmax_ripple"], **CRITIQUE_OPTIONS)
    with pytest.raises(ValueError, match="group"):
        critique(res, SETUP.simulate, obs, CATALOGUE, held_out=["no such group"], **CRITIQUE_OPTIONS)


# -- hidden effects ---------------------------------------------------------------------------

HIDDEN = ["temperature_offset", "axilrod_teller", "qmax_ripple", "rdf_normalisation", "density_error"]


@pytest.mark.parametrize("effect", HIDDEN)
def test_hidden_effect_is_found_named_recovered_and_gains(effect, tmp_path):
    seed = zlib.crc32(effect.encode()) % 10_000
    theta, eta, snr, where = hidden_case(effect, seed)
    assert snr >= 5.0, f"the generator must hide at least 5 sd (got {snr:.2f})"
    obs = observe(theta, seed)
    res = fit_base(obs, seed)
    report = critique(res, SETUP.simulate, obs, CATALOGUE, held_out=HELD_OUT, seed=seed, **CRITIQUE_OPTIONS)
    # 1. the base-only model misses, in a group where the effect shows
    assert report.misfits, "the base-only fit must be flagged"
    assert flagged_groups(report) & set(where), (flagged_groups(report), where)
    # 2. the injected cause ranks first, unambiguously
    top = report.causes[0]
    assert top.name == effect, report.causes
    assert top.significant and not top.ambiguous
    # 3. its parameter is recovered within the 95 % credible interval
    assert report.extension is not None and report.extension.names[-1] == effect
    lo, hi = report.extension.credible_interval(0.95)[-1]
    assert lo <= eta <= hi, (eta, lo, hi)
    # 4. held-out gain larger than two standard errors; the base refit misses the held-out data
    g = report.gain
    assert g["delta_lpd"] > 2.0 * g["delta_lpd_se"], g
    assert g["lpd_base"] < g["lpd_extended"]
    report.write(tmp_path / "report")
    assert (tmp_path / "report" / "report.md").read_text().count(effect) >= 2
    assert (tmp_path / "report" / "causes.png").exists()


def test_finite_box_and_thermostat_are_reported_ambiguous():
    """Both act on D alone: the pipeline must say so and name the data that separate them."""
    seed = 11
    theta, _eta, snr, _ = hidden_case("yeh_hummer", seed)
    assert snr >= 5.0
    obs = observe(theta, seed)
    res = fit_base(obs, seed)
    report = critique(res, SETUP.simulate, obs, CATALOGUE, held_out=HELD_OUT, seed=seed, extend=False,
                      **CRITIQUE_OPTIONS)
    assert report.misfits and report.misfits[0].name == "D_nm2_per_ps"
    top = report.causes[0]
    assert top.name in ("yeh_hummer", "thermostat_damping")
    assert top.ambiguous and "box sizes" in top.note and "cos" in top.note
    assert report.ambiguities


def test_null_flags_nothing_in_95_percent_of_seeds():
    """No effect: at most 2 of 40 seeds may flag anything (>= 95 % clean)."""
    flagged = []
    for seed in range(40):
        rng = np.random.default_rng(1000 + seed)
        theta = np.array([rng.uniform(0.97, 1.03), rng.uniform(0.9, 1.1)] + [0.0] * K)
        obs = observe(theta, seed)
        report = critique(fit_base(obs, seed), SETUP.simulate, obs, CATALOGUE, held_out=HELD_OUT, seed=seed,
                          extend=False, **CRITIQUE_OPTIONS)
        if report.misfits:
            flagged.append((seed, [m.name for m in report.misfits]))
    assert len(flagged) <= 2, flagged


def test_command_line_writes_a_report(tmp_path):
    """``python -m jaxabc.criticism config.py --out DIR`` on a null case (no extension)."""
    from jaxabc.criticism.__main__ import main

    obs = observe(np.array([1.0, 1.0] + [0.0] * K), 3)
    result_path = fit_base(obs, 3).save(tmp_path / "base.npz")
    np.save(tmp_path / "obs.npy", obs)
    config = tmp_path / "config.py"
    config.write_text(
        "import numpy as np\n"
        "from md.criticism_catalogue import make_lj_surrogate\n"
        "def setup():\n"
        "    s = make_lj_surrogate()\n"
        f"    return dict(result={str(result_path)!r}, simulate_with_effects=s.simulate,\n"
        f"                observed=np.load({str(tmp_path / 'obs.npy')!r}), catalogue=s.catalogue,\n"
        "                held_out=['self-diffusion', 'potential energy'], summary_names=s.names, groups=s.groups,\n"
        "                num_draws=50, num_replicates=64, extend=False)\n"
    )
    assert main([str(config), "--out", str(tmp_path / "out")]) == 0
    text = (tmp_path / "out" / "report.md").read_text()
    assert "What it gets wrong" in text and "ranked causes" in text
    assert (tmp_path / "out" / "misfits.png").exists()


@pytest.mark.slow
def test_engine_hidden_measurement_effect(tmp_path):
    """The jax-md engine (64 atoms, short runs) with Q_max ripples injected into its g(r).

    With 600 production steps the per-bin g(r) noise is ~0.04, so a ripple of 0.1 is only ~2.5
    sd per bin: the per-summary tests may stay silent, the matched filter over all bins must not.
    About 5 minutes on 2 shared cores.
    """
    from md.criticism_catalogue import make_lj_simulator_with_effects

    setup = make_lj_simulator_with_effects("reduced_liquid", num_atoms=64, cutoff_reduced=2.0,
                                           equilibration_steps=200, production_steps=600, sample_every=20)
    cat = setup.catalogue
    k = len(cat)
    theta = np.array([1.0, 1.0] + [0.0] * k)
    theta[2 + cat.index("qmax_ripple")] = 0.1
    obs = np.asarray(jax.jit(setup.simulate)(jax.random.key(5), jnp.asarray(theta, jnp.float32)), float)
    reps = np.asarray(jax.vmap(setup.simulate, (0, None))(jax.random.split(jax.random.key(6), 32),
                                                          jnp.asarray([1.0, 1.0] + [0.0] * k, jnp.float32)))
    sd = reps.std(0)
    held = np.zeros(obs.size, bool)
    held[[obs.size - 3, obs.size - 1]] = True  # D and U held out
    fit = np.flatnonzero(~held & (sd > 0))

    def base(key, th):
        return setup.simulate(key, jnp.concatenate([th, jnp.zeros(k, th.dtype)]))[fit]

    res = jaxabc.run("rejection", base, PRIOR, obs[fit], num_particles=60, seed=0, executor=EXECUTOR, quantile=0.1,
                     distance=jaxabc.distances.standardized_euclidean(jnp.asarray(sd[fit], jnp.float32)))
    report = critique(res, setup.simulate, obs, cat, held_out=held, seed=0, summary_names=setup.names,
                      groups=setup.groups, num_draws=64, num_replicates=64, num_gradient_replicates=32,
                      num_refit_iterations=2, executor=EXECUTOR, extend=False)
    top = report.causes[0]
    assert top.name == "qmax_ripple" and top.significant, report.causes
    report.write(tmp_path / "engine_report")
