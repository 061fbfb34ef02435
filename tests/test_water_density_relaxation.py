"""The pure statistics of ``benchmarks/water_density_relaxation.py`` on synthetic density series.

Synthetic series mimic the GROMACS ones: 0.2 ps frames, AR(1) noise whose correlation time is
about a picosecond (the barostat's volume response), in kg/m3.  No GROMACS here.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

_SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "water_density_relaxation.py"
# Loaded by path: benchmarks/ is a folder of scripts, not a package.
_spec = importlib.util.spec_from_file_location("water_density_relaxation", _SCRIPT)
assert _spec is not None and _spec.loader is not None
relaxation = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = relaxation  # dataclasses look their module up while the script loads
_spec.loader.exec_module(relaxation)

block_average = relaxation.block_average
design = relaxation.design
fit_relaxation = relaxation.fit_relaxation
parameter_points = relaxation.parameter_points
point_summary = relaxation.point_summary
run_statistics = relaxation.run_statistics
window_drift = relaxation.window_drift
window_mean = relaxation.window_mean

FRAME_PS = 0.2
TIMES = np.arange(326) * FRAME_PS  # 0..65 ps, the full run's energy frames
WINDOW, TAIL = (5.0, 20.0), (35.0, 65.0)


def ar1_noise(rng: np.random.Generator, n: int, sd: float, correlation_ps: float) -> np.ndarray:
    """Stationary AR(1) noise of marginal sd ``sd`` and correlation time ``correlation_ps``."""
    phi = np.exp(-FRAME_PS / correlation_ps)
    x = np.empty(n)
    x[0] = rng.normal(0.0, sd)
    innovations = rng.normal(0.0, sd * np.sqrt(1 - phi**2), n)
    for i in range(1, n):
        x[i] = phi * x[i - 1] + innovations[i]
    return x


def test_relaxation_fit_recovers_tau_within_monte_carlo_error() -> None:
    rng = np.random.default_rng(17)
    tau, amplitude, asymptote = 4.0, -40.0, 985.0
    fits = [
        fit_relaxation(TIMES, asymptote + amplitude * np.exp(-TIMES / tau) + ar1_noise(rng, TIMES.size, 6.0, 0.5))
        for _ in range(60)
    ]
    taus = np.array([f.tau_ps for f in fits])
    assert all(f.resolved for f in fits)
    standard_error = taus.std(ddof=1) / np.sqrt(taus.size)
    assert abs(taus.mean() - tau) < 3 * standard_error + 0.02 * tau
    # The per-fit error, inflated for the correlated residuals, matches the scatter of the fits
    # (the sd of 60 fits is itself uncertain by ~10 %).
    assert 0.7 < np.mean([f.tau_se_ps for f in fits]) / taus.std(ddof=1) < 1.4
    asymptotes = np.array([f.asymptote for f in fits])
    assert abs(asymptotes.mean() - asymptote) < 3 * asymptotes.std(ddof=1) / np.sqrt(asymptotes.size)


def test_relaxation_fit_of_a_flat_series_is_not_resolved() -> None:
    rng = np.random.default_rng(3)
    unresolved = [not fit_relaxation(TIMES, 995.0 + ar1_noise(rng, TIMES.size, 6.0, 0.5)).resolved for _ in range(40)]
    # Each flat fit should resolve a relaxation only by chance (about 1 in 100 at 3 SE).
    assert np.mean(unresolved) >= 0.85


def test_window_mean_error_covers_the_truth_for_correlated_noise() -> None:
    rng = np.random.default_rng(5)
    z = []
    for _ in range(200):
        series = 990.0 + ar1_noise(rng, TIMES.size, 8.0, 1.0)
        w = window_mean(TIMES, series, *WINDOW)
        assert w.num_frames == 76
        z.append((w.mean - 990.0) / w.standard_error)
    z = np.abs(np.array(z))
    # ArviZ's ESS from 76 frames with a ~5-frame correlation is itself noisy and covers ~87 %
    # rather than 95 % here (checked on 200 more series); 0.78 is 3.5 Monte Carlo sd below that.
    # A naive error, sd / sqrt(76), is 3 times too small and would cover about half the time.
    assert 0.78 <= np.mean(z < 2.0) <= 0.995


def test_drift_measures_a_linear_trend() -> None:
    rng = np.random.default_rng(11)
    drifts = []
    for _ in range(50):
        series = 1000.0 + 0.8 * TIMES + ar1_noise(rng, TIMES.size, 4.0, 0.5)
        drift, drift_se = window_drift(TIMES, series, *WINDOW)
        assert drift_se > 0
        drifts.append(drift)
    drifts = np.array(drifts)
    assert abs(drifts.mean() - 0.8 * 15.0) < 3 * drifts.std(ddof=1) / np.sqrt(drifts.size)


def test_verdict_tells_a_slow_relaxation_from_a_relaxed_series() -> None:
    rng = np.random.default_rng(23)

    def summary(tau: float) -> dict:
        rows = [
            run_statistics(
                TIMES, 970.0 + 30.0 * np.exp(-TIMES / tau) + ar1_noise(rng, TIMES.size, 6.0, 0.5), WINDOW, TAIL
            )
            for _ in range(3)
        ]
        return point_summary(rows)

    fast = [summary(1.0) for _ in range(12)]
    slow = [summary(12.0) for _ in range(12)]
    # Two tests at 2 SE each: a relaxed point is called relaxed ~90 % of the time; with 12 points
    # and ArviZ's noisy errors on 76 frames, 8 is a generous floor that a biased test would miss.
    assert sum(s["relaxed"] for s in fast) >= 8
    assert not any(s["relaxed"] for s in slow)
    assert all(s["difference"] > 0 and s["drift"] < 0 for s in slow)
    taus = np.array([s["tau_ps"] for s in fast])
    assert abs(taus.mean() - 1.0) < 3 * taus.std(ddof=1) / np.sqrt(taus.size) + 0.05


def test_one_seed_uses_the_window_error_as_the_drift_scale() -> None:
    rng = np.random.default_rng(2)
    row = run_statistics(TIMES, 990.0 + ar1_noise(rng, TIMES.size, 6.0, 0.5), WINDOW, TAIL)
    summary = point_summary([row])
    assert summary["drift_scale"] == row["window_se"]
    assert "one seed" in summary["drift_scale_source"]
    assert np.isnan(summary["window_seed_sd"])


def test_bad_input_is_refused_with_what_to_do() -> None:
    with pytest.raises(ValueError, match="at least 3"):
        design(20.0, 5.0, 2.0)
    with pytest.raises(ValueError, match="lengthen"):
        window_mean(TIMES, TIMES, 5.0, 5.5)
    with pytest.raises(ValueError, match="at least one"):
        point_summary([])
    with pytest.raises(ValueError, match="positive"):
        block_average(TIMES, TIMES, 0.0)


def test_design_and_points() -> None:
    plan = design(20.0, 5.0, 4.0)
    assert plan.window == (5.0, 20.0) and plan.tail == (35.0, 65.0)
    points = parameter_points()
    assert len(points) == 9
    assert (points[0]["sigma_nm"], points[0]["epsilon_kj_mol"]) == (0.315365, 0.64852)
    sigmas = sorted({p["sigma_nm"] for p in points})
    # Centre, central-50 % and outer corners: sigma at TIP4P x (1 -+ 2.5 %) and (1 -+ 5 %).
    np.testing.assert_allclose(sigmas, 0.315365 * np.array([0.95, 0.975, 1.0, 1.025, 1.05]), atol=2e-6)
    assert [p["name"] for p in parameter_points(quick=True)] == [points[0]["name"], "outer: high sigma, low epsilon"]
