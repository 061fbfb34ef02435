"""The tail analysis of benchmarks/water_emulator_failures.py against known error laws."""

import numpy as np
import scipy.stats

from benchmarks.water_emulator_failures import _tails

NAMES = [f"y{j}" for j in range(10)]


def test_normal_errors_look_normal_and_rarely_fail_the_checks() -> None:
    e = np.random.default_rng(1).standard_normal((4000, 10))
    t = _tails(e, NAMES, draws=4000)
    assert t["student_t"]["df"] > 30
    # The checks are built for about 0.1 % each under a normal; 4000 draws resolve 1 %.
    assert t["chance_fail_under_t"]["either"] < 0.01
    assert abs(t["share_beyond"]["3"]["observed"] - t["share_beyond"]["3"]["normal"]) < 4 * np.sqrt(0.0027 / 40000)


def test_student_t_errors_are_recognised_and_fail_the_gaussian_checks_often() -> None:
    e = np.random.default_rng(2).standard_t(4.0, size=(4000, 10)) / np.sqrt(2.0)  # unit variance
    t = _tails(e, NAMES, draws=4000)
    assert 3.0 < t["student_t"]["df"] < 5.5
    # The targeted check fails at least when one of its 2 x 10 errors passes its Bonferroni
    # bound; for the fitted t that chance is analytic (the mean-square part only adds to it).
    df, scale = t["student_t"]["df"], t["student_t"]["scale"]
    bound = scipy.stats.norm.ppf(1 - 1e-3 / 40)
    p_max = 1 - (1 - 2 * scipy.stats.t.sf(bound / scale, df)) ** 20
    se = np.sqrt(p_max * (1 - p_max) / 4000)
    assert t["chance_fail_under_t"]["targeted"] >= p_max - 4 * se
    assert t["chance_fail_under_t"]["targeted"] <= p_max + 0.03  # the mean-square part adds little
    assert all(k > 1.0 for k in t["excess_kurtosis_by_summary"].values())


def test_replicate_moments_find_heavy_tails_and_not_in_normal_noise() -> None:
    from benchmarks.water_summary_noise import moments, null_pooled_kurtosis

    rng = np.random.default_rng(3)
    normal = moments(rng.standard_normal(400), rng)
    heavy = moments(rng.standard_t(4.0, size=400), rng)
    assert normal["excess_kurtosis_95"][0] < 0.0 < normal["excess_kurtosis_95"][1]
    assert heavy["excess_kurtosis_95"][0] > 0.0
    # Normal groups standardised by their own sd: the pooled kurtosis sits just below 0 (by
    # about -6 / (n + 1) for groups of n) within its sampling error, sqrt(24 / 200) ~ 0.35.
    low, high = null_pooled_kurtosis([40] * 5, rng, draws=2000)
    assert low < -6 / 41 < high
    assert 0.8 < high - low < 2.0
