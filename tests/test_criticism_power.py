"""Detection power at expected strengths, and design advice (jaxabc.criticism.power).

A cheap linear problem: ten summaries ``a + b x + curve x^2 + shift + noise`` on x in [0, 1]
(noise sd 0.05), base parameters (a, b).  ``curve`` is partly absorbed by the line (its
unabsorbed signal is about 4.7 noise sd per unit); ``shift`` is entirely absorbed by ``a``
(invisible whatever its strength).  The candidate observables: ``absorbed`` = 10 (a + shift)
(responds 10x more strongly than ``direct`` to the shift, but only the way ``a`` does),
``irrelevant`` = b, ``direct`` = shift; each with noise sd 0.05.

The base calibration is a Gaussian sample around the truth (no ABC run: the power and its
pipeline start from the calibration's Bayes estimate and refit locally).
"""

from __future__ import annotations

import json
import pickle

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxabc
from jaxabc.criticism import CandidateObservables, Catalogue, Cause, Effect, critique
from jaxabc.criticism.power import wilson_interval

X = jnp.linspace(0.0, 1.0, 10)
NOISE = 0.05
PRIOR = jaxabc.Uniform([0.5, 0.5], [1.5, 1.5], names=("a", "b"))
EXECUTOR = jaxabc.VmapExecutor()
OPTIONS = dict(groups={"all": slice(0, 10)}, num_draws=50, num_replicates=100, extend=False, executor=EXECUTOR)
CANDIDATE_NAMES = ["absorbed", "irrelevant", "direct"]


def simulate(key, theta):
    return theta[0] + theta[1] * X + theta[2] * X**2 + theta[3] + NOISE * jax.random.normal(key, (10,))


def candidate_simulate(key, theta):
    e = NOISE * jax.random.normal(key, (3,))
    return jnp.stack([10.0 * (theta[0] + theta[3]) + e[0], theta[1] + e[1], theta[3] + e[2]])


def catalogue(curve_expected: float | None, shift_expected: float | None = 0.5) -> Catalogue:
    return Catalogue(
        [
            Effect("curve", -3.0, 3.0, 0.0, expected=curve_expected),
            Effect("shift", -1.0, 1.0, 0.0, separated_by="a direct offset measurement", expected=shift_expected),
        ]
    )


def base_result(theta=(1.0, 1.0), seed: int = 0, n: int = 300) -> jaxabc.ABCResult:
    p = np.asarray(theta)[None] + 0.02 * np.random.default_rng(seed).normal(size=(n, 2))
    return jaxabc.ABCResult.from_sample(p, np.ones(n), PRIOR)


def observe(curve: float, shift: float = 0.0, seed: int = 5) -> np.ndarray:
    theta = jnp.asarray([1.0, 1.0, curve, shift], jnp.float32)
    return np.asarray(simulate(jax.random.key(seed), theta), float)


def named(report, effect: str) -> bool:
    return bool(report.misfits) and effect in report.cause_analysis.needed


def test_effect_at_a_strength_with_power_near_one_is_named_and_its_power_is_high(tmp_path):
    report = critique(base_result(), simulate, observe(2.0), catalogue(2.0), seed=1, **OPTIONS)
    curve = next(c for c in report.causes if c.name == "curve")
    assert report.causes[0].name == "curve" and named(report, "curve"), report.verdict
    assert curve.power > 0.8 and curve.detectable, (curve.power, curve.power_se)
    assert curve.power_se == pytest.approx(np.sqrt(curve.power * (1 - curve.power) / 20))
    assert report.power["curve"]["num_datasets"] == 20
    assert "curve (power" not in report.verdict  # not listed among the unseen
    report.write(tmp_path, figures=False)
    saved = json.loads((tmp_path / "report.json").read_text())
    assert saved["power"]["curve"]["power"] == curve.power
    assert next(c for c in saved["causes"] if c["name"] == "curve")["power_se"] == curve.power_se
    assert "Detection power" in (tmp_path / "report.md").read_text()


def test_effect_at_a_strength_with_power_near_zero_is_not_detectable_not_absent():
    report = critique(base_result(), simulate, observe(0.05), catalogue(0.05), seed=2, **OPTIONS)
    curve = next(c for c in report.causes if c.name == "curve")
    assert not named(report, "curve")
    assert curve.power < 0.2 and curve.detectable is False, (curve.power, curve.note)
    assert curve.note.startswith(f"not detectable with these data (power {curve.power:.2f} ± {curve.power_se:.2f}")
    assert "no evidence against it" in curve.note
    assert "not detectable with these data, so not ruled out: curve (power" in report.verdict
    assert "curve" in [c.name for c in report.undetectable]
    assert report.to_dict()["undetectable"] == ["curve", "shift"]


def test_null_is_claimed_by_nothing_and_the_invisible_effect_is_not_ruled_out():
    report = critique(base_result(), simulate, observe(0.0, seed=8), catalogue(2.0), seed=3, **OPTIONS)
    assert not report.misfits and not report.cause_analysis.needed, report.verdict
    assert report.verdict.startswith("No misfit")
    by = {c.name: c for c in report.causes}
    assert by["curve"].power > 0.8 and by["curve"].detectable  # the data could have seen it
    assert "the data speak against it" in by["curve"].note
    assert by["shift"].power < 0.2 and by["shift"].detectable is False
    assert "shift (power" in report.verdict and "curve (power" not in report.verdict


def test_power_agrees_with_a_brute_force_count():
    """At an intermediate strength (power about 0.5) the estimate agrees, within its error, with
    the share of fresh data sets (base posterior, effect at that strength) on which critique
    itself, with a fresh seed each, names the effect."""
    res, cat, n = base_result(), catalogue(0.6, None), 40
    report = critique(res, simulate, observe(0.6), cat, seed=2, num_power_replicates=n, **OPTIONS)
    est = report.power_estimates["curve"]
    assert est.num_datasets == n and est.num_failed == 0 and 0.1 < est.power < 0.9, est
    assert est.datasets.shape == (n, 10)
    thetas = np.concatenate([res.resample(n, seed=99), np.tile([0.6, 0.0], (n, 1))], 1)
    keys = jax.random.split(jax.random.key(12345), n)
    data = np.asarray(jax.vmap(simulate)(keys, jnp.asarray(thetas, jnp.float32)), float)
    brute = [
        named(critique(res, simulate, y, cat, seed=100 + i, num_power_replicates=0, **OPTIONS), "curve")
        for i, y in enumerate(data)
    ]
    p_bf = float(np.mean(brute))
    se_bf = np.sqrt(p_bf * (1 - p_bf) / n)
    assert abs(est.power - p_bf) <= 2.5 * np.hypot(est.se, se_bf), (est.power, est.se, p_bf, se_bf)
    lo, hi = est.interval
    assert lo <= est.power <= hi


def test_design_advice_ranks_the_sensitive_candidate_first_not_the_absorbed_one(tmp_path):
    cands = CandidateObservables(candidate_simulate, CANDIDATE_NAMES)
    report = critique(base_result(), simulate, observe(0.0, 0.3), catalogue(2.0), seed=5, candidates=cands, **OPTIONS)
    shift = next(c for c in report.causes if c.name == "shift")
    assert shift.detectable is False
    rows = {r["name"]: r for r in report.design_advice["shift"]}
    assert report.design_advice["shift"][0]["name"] == "direct"
    # The absorbed candidate responds ten times more strongly, but only the way `a` does.
    assert rows["absorbed"]["raw_snr"] > 5 * rows["direct"]["raw_snr"]
    assert rows["absorbed"]["absorbed"] > 0.99 and rows["absorbed"]["gain"] < 0.01 * rows["direct"]["gain"]
    assert rows["direct"]["snr"] > 5.0  # 0.5 / 0.05 noise sd, nothing absorbed
    assert "curve" not in report.design_advice  # detectable: no advice needed
    assert "best added observable direct" in report.verdict and "direct" in shift.note
    report.write(tmp_path, figures=False)
    assert "Design advice" in (tmp_path / "report.md").read_text()


def test_backwards_compatible_effects_and_causes():
    e = Effect("x", 0.0, 1.0, 0.0, "u", "d", "physical", "s", ("y",), 0.1)
    assert e.expected is None and e.step == 0.1
    with pytest.raises(ValueError, match="expected"):
        Effect("x", 0.0, 1.0, expected=2.0)
    old = Cause("x", 1.0, adjusted_p_value=0.5, ambiguous=False, invisible=False)
    again = pickle.loads(pickle.dumps(old))
    assert again.power is None and again.power_se is None and again.detectable is None
    assert wilson_interval(0, 20)[1] == pytest.approx(0.161, abs=1e-3)
