"""Has the water ``quick`` preset's density relaxed inside its analysed window, far from TIP4P?

The ``quick`` preset (:data:`md.water.protocol.PRESETS`) starts every run from GROMACS's
``tip4p.gro``, a box equilibrated for TIP4P's own (sigma, epsilon), minimises it and runs 20 ps of
NPT, of which 5-20 ps are analysed (S1..S9 and the density).  At other parameters the box has to
expand or shrink to its new density first; if that takes longer than the 5 ps discarded, the
analysed statistics belong to a liquid still on its way.  This script measures it.

Protocol: the ``quick`` preset through :func:`md.water.gromacs.run_gromacs` with the same ``.mdp``
apart from ``nsteps``: the NPT production is extended to ``analysis_start + extension x window``
(default x4: 65 ps), and ``gmx energy`` reads the density (and box) every 0.2 ps from the start of
NPT.  The runs go through :class:`jaxabc.ProcessPoolExecutor`, so a run that fails comes back with
its reason; a run whose analysed window fails :func:`md.water.gromacs.check_physical` (vapour,
collapse, box below twice the cut-off) is recorded as the ``quick`` simulator would fail it and
left out of the statistics.  The RDF/MSD analysis is not run (it does not change the density).

Parameter points: the prior the water model-choice calibration uses for TIP4P,
:func:`md.water.models.model_prior` (a box of +-5 % in sigma and +-40 % in epsilon around TIP4P,
which holds every calibrated water estimate in ``md/water/README.md``): its centre (TIP4P itself),
the 4 corners of its central 50 % and its 4 outer corners.

Measured per run (kg/m3):

* the mean density in the analysed window and in the *tail*, the frames from one window length
  after the analysed window to the end (default 35-65 ps), each with its Monte Carlo standard error
  from ArviZ (``arviz.mcse(method="mean")``, an effective-sample-size estimate that allows for the
  autocorrelation of the barostat's volume oscillations);
* the drift inside the window: the least-squares slope times the window length;
* a relaxation time: ``rho(t) = rho_inf + (rho_0 - rho_inf) exp(-t / tau)`` fitted with
  :func:`scipy.optimize.curve_fit` to the density frames from t = 0 (start of NPT).  The
  fit is *resolved* when its amplitude exceeds 3 of its standard errors; a run that starts at its
  own density (TIP4P) has nothing to relax and no resolved tau.

Per point, over the seeds: the window-tail difference and the drift, each with a combined
standard error (the per-run errors propagated), and the seed-to-seed standard deviation of the
window mean.  Verdict: a point is **relaxed** when ``|window - tail| < 2 combined SE`` *and*
``|drift| < max(2 SE of the drift, seed-to-seed sd)``: a drift counts only when it is both
resolved and larger than the scatter between seeds (with one seed, the window mean's own standard
error stands in for the seed sd, and the JSON says so).  The verdict is statistical: it says
whether a bias is resolved by these runs, not whether it matters; the bias itself is in the JSON
beside it.

Usage (from the repository root)::

    nice -n 15 python -m benchmarks.water_density_relaxation --workers 2    # 9 points x 3 seeds
    nice -n 15 python -m benchmarks.water_density_relaxation --quick        # 2 points, 1 seed

Cost: the full run is 27 GROMACS runs of 65 ps (3.25 times a ``quick`` run); the JSON records
its cost and each run's CPU and wall time.  ``--quick`` runs TIP4P and the outer
low-density corner with one seed and extension x3 (50 ps), and writes
``benchmarks/results/quick/water_density_relaxation.json``.  Freezing is not detected (the
simulator's checks cover vapour, collapse and GROMACS failures); at 298 K none of these points is
expected to freeze within 65 ps, and a frozen box would show as a density plateau with no
diffusion, which this script does not measure.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks._common import write_result

ROOT = Path(__file__).resolve().parents[1]

__all__ = [
    "DensitySeries",
    "Design",
    "RelaxationFit",
    "WindowMean",
    "block_average",
    "design",
    "fit_relaxation",
    "parameter_points",
    "point_summary",
    "run_statistics",
    "window_drift",
    "window_mean",
]

#: Width of the blocks of the density series saved in the JSON (for figures; the fit sees every
#: frame, since far from TIP4P the box reaches its new density within a few picoseconds).
SAVED_BLOCK_PS = 1.0
#: A fitted amplitude smaller than this many of its standard errors means nothing relaxed.
RESOLVED_AMPLITUDE_SE = 3.0
#: The window-tail difference is resolved at this many combined standard errors.
DIFFERENCE_SE = 2.0


# ----------------------------------------------------------------------------- statistics


@dataclass(frozen=True)
class WindowMean:
    """Mean of a time series over ``[start_ps, end_ps]`` and its Monte Carlo standard error.

    Attributes
    ----------
    mean, standard_error : float
        In the series' units; the error from ArviZ's effective sample size of the mean.
    num_frames : int
    effective_sample_size : float
    """

    mean: float
    standard_error: float
    num_frames: int
    effective_sample_size: float


def _select(times_ps: np.ndarray, values: np.ndarray, start_ps: float, end_ps: float) -> np.ndarray:
    # A small tolerance so that frames written exactly at the edges count despite rounding.
    inside = (times_ps >= start_ps - 1e-6) & (times_ps <= end_ps + 1e-6)
    return np.asarray(values, dtype=np.float64)[inside]


def window_mean(times_ps: np.ndarray, values: np.ndarray, start_ps: float, end_ps: float) -> WindowMean:
    """Mean and Monte Carlo standard error of ``values`` for ``start_ps <= t <= end_ps``.

    Parameters
    ----------
    times_ps, values : np.ndarray, shape (n,)
        A time series (ps) sampled at increasing times.
    start_ps, end_ps : float

    Raises
    ------
    ValueError
        Fewer than 8 frames in the window (ArviZ's estimate needs a few per split half).
    """
    import arviz

    x = _select(np.asarray(times_ps, dtype=np.float64), values, start_ps, end_ps)
    if x.size < 8:
        raise ValueError(
            f"only {x.size} frames in [{start_ps}, {end_ps}] ps; lengthen the run or the window (need >= 8)"
        )
    chain = x[None, :]
    ess = float(arviz.ess(chain, method="mean"))
    se = float(arviz.mcse(chain, method="mean"))
    return WindowMean(float(x.mean()), se, int(x.size), ess)


def window_drift(times_ps: np.ndarray, values: np.ndarray, start_ps: float, end_ps: float) -> tuple[float, float]:
    """Drift inside ``[start_ps, end_ps]``: least-squares slope times the window length.

    Returns
    -------
    drift, standard_error : float
        In the series' units.  The error is the ordinary least-squares one inflated by
        ``sqrt(n / ESS)`` for the autocorrelation (ESS of the residuals, from ArviZ).
    """
    import arviz

    t = _select(np.asarray(times_ps, dtype=np.float64), times_ps, start_ps, end_ps)
    x = _select(np.asarray(times_ps, dtype=np.float64), values, start_ps, end_ps)
    if x.size < 8:
        raise ValueError(f"only {x.size} frames in [{start_ps}, {end_ps}] ps for a drift (need >= 8)")
    (slope, intercept), cov = np.polyfit(t, x, 1, cov=True)
    residuals = x - (slope * t + intercept)
    ess = max(float(arviz.ess(residuals[None, :], method="mean")), 2.0)
    inflation = np.sqrt(max(x.size / ess, 1.0))
    length = end_ps - start_ps
    return float(slope * length), float(np.sqrt(cov[0, 0]) * inflation * length)


@dataclass(frozen=True)
class RelaxationFit:
    """``rho(t) = asymptote + amplitude * exp(-t / tau_ps)`` fitted to a time series.

    Attributes
    ----------
    tau_ps, tau_se_ps : float
        Relaxation time and its standard error (curve_fit covariance inflated by sqrt(n / ESS)
        of the residuals); NaN when the fit failed.
    asymptote, amplitude : float
        In the series' units; ``amplitude`` is the initial offset ``rho(0) - asymptote``.
    amplitude_se : float
    resolved : bool
        ``|amplitude| > RESOLVED_AMPLITUDE_SE * amplitude_se``: something relaxed.  When False,
        ``tau_ps`` is not a relaxation time.
    message : str
        Empty on success; why the fit failed otherwise.
    """

    tau_ps: float
    tau_se_ps: float
    asymptote: float
    amplitude: float
    amplitude_se: float
    resolved: bool
    message: str = ""


def block_average(times_ps: np.ndarray, values: np.ndarray, block_ps: float) -> tuple[np.ndarray, np.ndarray]:
    """Averages of ``values`` in consecutive blocks of ``block_ps``, at the blocks' mean times.

    The frame at t = 0 forms a block of its own, so the starting density stays visible.
    """
    t = np.asarray(times_ps, dtype=np.float64)
    x = np.asarray(values, dtype=np.float64)
    if block_ps <= 0:
        raise ValueError(f"block_ps must be positive, got {block_ps}")
    first = t <= t[0] + 1e-9
    index = np.ceil((t - t[0]) / block_ps - 1e-9).astype(int)
    index[first] = 0
    labels = np.unique(index)
    return (
        np.array([t[index == k].mean() for k in labels]),
        np.array([x[index == k].mean() for k in labels]),
    )


def _exponential(t: np.ndarray, asymptote: float, amplitude: float, tau: float) -> np.ndarray:
    return asymptote + amplitude * np.exp(-t / tau)


def fit_relaxation(times_ps: np.ndarray, values: np.ndarray, block_ps: float | None = None) -> RelaxationFit:
    """Fit an exponential relaxation to ``values`` from the start of the series.

    Parameters
    ----------
    times_ps, values : np.ndarray, shape (n,)
        The series from t = 0 (start of NPT), e.g. the density in kg/m3.
    block_ps : float, optional
        Average the series in blocks of this width before the fit (default: every frame).

    Returns
    -------
    RelaxationFit
        ``tau_ps`` bounded to ``[0.05 ps, run length]``; a failed fit gives NaNs and a message,
        never an exception.  The errors come from the residual scatter, inflated for its
        autocorrelation; the seed-to-seed spread in the JSON is the check on them.
    """
    import arviz
    from scipy.optimize import curve_fit

    if block_ps is None:
        t, x = np.asarray(times_ps, dtype=np.float64), np.asarray(values, dtype=np.float64)
    else:
        t, x = block_average(times_ps, values, block_ps)
    t = t - t[0]
    if t.size < 5:
        return RelaxationFit(np.nan, np.nan, np.nan, np.nan, np.nan, False, f"only {t.size} points to fit")
    tail = x[t >= 0.5 * t[-1]]
    asymptote0 = float(tail.mean())
    guess = (asymptote0, float(x[0] - asymptote0), 0.05 * float(t[-1]))
    lower = (-np.inf, -np.inf, 0.05)
    upper = (np.inf, np.inf, max(float(t[-1]), 0.1))
    try:
        popt, pcov = curve_fit(_exponential, t, x, p0=guess, bounds=(lower, upper), maxfev=20_000)
    except (RuntimeError, ValueError) as error:
        return RelaxationFit(np.nan, np.nan, np.nan, np.nan, np.nan, False, f"curve_fit failed: {error}")
    # curve_fit's errors assume independent residuals; the barostat makes them correlated over
    # picoseconds, so inflate by sqrt(n / ESS) of the residuals, as for the drift.
    residuals = x - _exponential(t, *popt)
    ess = max(float(arviz.ess(residuals[None, :], method="mean")), 2.0)
    errors = np.sqrt(np.clip(np.diag(pcov), 0.0, np.inf)) * np.sqrt(max(t.size / ess, 1.0))
    resolved = bool(np.isfinite(errors[1]) and abs(popt[1]) > RESOLVED_AMPLITUDE_SE * errors[1])
    return RelaxationFit(float(popt[2]), float(errors[2]), float(popt[0]), float(popt[1]), float(errors[1]), resolved)


def run_statistics(
    times_ps: np.ndarray,
    density: np.ndarray,
    window: tuple[float, float],
    tail: tuple[float, float],
) -> dict[str, Any]:
    """Window and tail means, their difference, the window drift and the relaxation fit of one run.

    Parameters
    ----------
    times_ps, density : np.ndarray, shape (n,)
        Density (kg/m3) from the start of NPT.
    window, tail : (float, float)
        The analysed window and the tail (ps).

    Returns
    -------
    dict
        Keys ``window_mean``, ``window_se``, ``window_ess``, ``tail_mean``, ``tail_se``,
        ``tail_ess``, ``difference`` (window - tail), ``difference_se``, ``drift``,
        ``drift_se``, ``initial``, and the fit's ``tau_ps``, ``tau_se_ps``, ``fit_asymptote``,
        ``fit_amplitude``, ``fit_amplitude_se``, ``fit_resolved``, ``fit_message``.
    """
    w = window_mean(times_ps, density, *window)
    t = window_mean(times_ps, density, *tail)
    drift, drift_se = window_drift(times_ps, density, *window)
    fit = fit_relaxation(times_ps, density)
    return {
        "window_mean": w.mean,
        "window_se": w.standard_error,
        "window_ess": w.effective_sample_size,
        "tail_mean": t.mean,
        "tail_se": t.standard_error,
        "tail_ess": t.effective_sample_size,
        "difference": w.mean - t.mean,
        "difference_se": float(np.hypot(w.standard_error, t.standard_error)),
        "drift": drift,
        "drift_se": drift_se,
        "initial": float(np.asarray(density)[0]),
        "tau_ps": fit.tau_ps,
        "tau_se_ps": fit.tau_se_ps,
        "fit_asymptote": fit.asymptote,
        "fit_amplitude": fit.amplitude,
        "fit_amplitude_se": fit.amplitude_se,
        "fit_resolved": fit.resolved,
        "fit_message": fit.message,
    }


def point_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Combine one parameter point's runs (outputs of :func:`run_statistics`) into its verdict.

    Returns
    -------
    dict
        ``num_seeds``; seed means of the window and tail densities; ``difference`` (mean over
        seeds) with ``difference_se`` (per-run errors propagated) and ``difference_seed_se``
        (seed-to-seed sd / sqrt(n), NaN for one seed); ``drift`` (mean) with ``drift_se``
        (propagated) and ``drift_seed_sd``;
        ``window_seed_sd`` and ``drift_scale`` (the seed sd, or the window's own standard error
        with one seed: ``drift_scale_source`` says which); ``tau_ps`` (mean over resolved fits)
        with ``tau_seed_sd`` and ``num_resolved_fits``; the two tests
        (``difference_unresolved``: ``|difference| < 2 difference_se``; ``drift_negligible``:
        ``|drift| < max(2 drift_se, drift_scale)``) and ``relaxed``, both passed.

    Raises
    ------
    ValueError
        No rows.
    """
    if not rows:
        raise ValueError("a point needs at least one successful run to be summarised")
    n = len(rows)

    def col(key: str) -> np.ndarray:
        return np.array([r[key] for r in rows], dtype=np.float64)

    difference, drift, window = col("difference"), col("drift"), col("window_mean")
    difference_se = float(np.sqrt(np.sum(col("difference_se") ** 2)) / n)
    drift_se = float(np.sqrt(np.sum(col("drift_se") ** 2)) / n)
    if n >= 2:
        window_sd = float(np.std(window, ddof=1))
        drift_scale, source = window_sd, "seed-to-seed sd of the window mean"
    else:
        window_sd = float("nan")
        drift_scale, source = float(col("window_se")[0]), "standard error of the window mean (one seed)"
    resolved = np.array([bool(r["fit_resolved"]) for r in rows])
    taus = col("tau_ps")[resolved]
    mean_difference = float(difference.mean())
    mean_drift = float(drift.mean())
    difference_ok = bool(abs(mean_difference) < DIFFERENCE_SE * difference_se)
    # A drift fails only when it is both resolved from zero and larger than the seed-to-seed
    # spread: a 15 ps window's slope is noisier than its mean, so "below the seed sd" alone
    # would call a relaxed point drifting about half the time.
    drift_ok = bool(abs(mean_drift) < max(DIFFERENCE_SE * drift_se, drift_scale))
    return {
        "num_seeds": n,
        "window_mean": float(window.mean()),
        "tail_mean": float(col("tail_mean").mean()),
        "difference": mean_difference,
        "difference_se": difference_se,
        "difference_seed_se": float(np.std(difference, ddof=1) / np.sqrt(n)) if n >= 2 else float("nan"),
        "difference_in_se": mean_difference / difference_se if difference_se > 0 else float("nan"),
        "drift": mean_drift,
        "drift_se": drift_se,
        "drift_seed_sd": float(np.std(drift, ddof=1)) if n >= 2 else float("nan"),
        "window_seed_sd": window_sd,
        "drift_scale": drift_scale,
        "drift_scale_source": source,
        "initial": float(col("initial").mean()),
        "tau_ps": float(taus.mean()) if taus.size else float("nan"),
        "tau_seed_sd": float(np.std(taus, ddof=1)) if taus.size >= 2 else float("nan"),
        "num_resolved_fits": int(resolved.sum()),
        "difference_unresolved": difference_ok,
        "drift_negligible": drift_ok,
        "relaxed": difference_ok and drift_ok,
    }


# ----------------------------------------------------------------------------- points and runs


def parameter_points(quick: bool = False) -> list[dict[str, Any]]:
    """The (sigma nm, epsilon kJ/mol) points: TIP4P, central-50 % corners, outer corners.

    From :func:`md.water.models.model_prior` for TIP4P.  ``quick``: TIP4P and the outer corner
    of largest sigma and smallest epsilon (the lowest density, the farthest from the start).
    """
    from md.water.models import model_prior

    prior = model_prior("TIP4P")
    # The prior stores float32; 6 decimals give back TIP4P's published values exactly.
    low = np.round(np.asarray(prior.low, dtype=np.float64), 6)
    high = np.round(np.asarray(prior.high, dtype=np.float64), 6)
    centre, half = 0.5 * (low + high), 0.5 * (high - low)
    centre = np.round(centre, 6)
    points = [{"name": "TIP4P (prior centre)", "sigma_nm": float(centre[0]), "epsilon_kj_mol": float(centre[1])}]
    for label, fraction in (("central 50 %", 0.5), ("outer", 1.0)):
        for s_sign, s_word in ((-1, "low"), (1, "high")):
            for e_sign, e_word in ((-1, "low"), (1, "high")):
                theta = np.round(centre + fraction * half * np.array([s_sign, e_sign]), 6)
                points.append(
                    {
                        "name": f"{label}: {s_word} sigma, {e_word} epsilon",
                        "sigma_nm": float(theta[0]),
                        "epsilon_kj_mol": float(theta[1]),
                    }
                )
    if quick:
        return [points[0], next(p for p in points if p["name"] == "outer: high sigma, low epsilon")]
    return points


class DensitySeries:
    """Picklable ``simulate(key, theta) -> (num_frames, 4)``: density (kg/m3) and box edges (nm).

    One NPT run of ``protocol`` through :func:`md.water.gromacs.run_gromacs` and ``gmx energy``
    (``Density``, ``Box-X``, ``Box-Y``, ``Box-Z``) from t = 0.  Raises
    :class:`jaxabc.errors.SimulationFailure` when GROMACS fails or the energy file is short.
    """

    def __init__(self, protocol, gmx: str | None = None) -> None:
        from md.water.gromacs import find_gmx

        self.protocol = protocol
        self.gmx = find_gmx(gmx)
        self.num_frames = protocol.num_steps // protocol.frame_interval_steps + 1

    def __call__(self, key, theta) -> np.ndarray:
        import os
        import subprocess

        from jaxabc.errors import SimulationFailure
        from md.water.gromacs import TIP4PParameters, run_gromacs, seeds_for_key, temporary_run_directory

        sigma, epsilon = (float(v) for v in np.asarray(theta, dtype=np.float64).reshape(2))
        params = TIP4PParameters(sigma_ow_nm=sigma, epsilon_ow_kj_mol=epsilon)
        gen_seed, ld_seed = seeds_for_key(key)
        with temporary_run_directory("jaxabc-density-") as tmp:
            workdir = Path(tmp)
            run = run_gromacs(params, self.protocol, workdir, gen_seed, ld_seed, gmx=self.gmx)
            done = subprocess.run(
                [self.gmx, "energy", "-f", run.energy.name, "-o", "density.xvg"],
                input="Density\nBox-X\nBox-Y\nBox-Z\n\n",
                text=True,
                cwd=workdir,
                capture_output=True,
                timeout=120,
                env=dict(os.environ, GMX_MAXBACKUP="-1"),
            )
            xvg = workdir / "density.xvg"
            if done.returncode != 0 or not xvg.is_file():
                raise SimulationFailure(f"`gmx energy` exited with status {done.returncode}: {done.stdout[-400:]}")
            columns = _xvg_columns(xvg)
        missing = {"Density", "Box-X", "Box-Y", "Box-Z"} - set(columns)
        if missing:
            raise SimulationFailure(f"`gmx energy` gave no {sorted(missing)}")
        table = np.column_stack([columns[k] for k in ("Density", "Box-X", "Box-Y", "Box-Z")])
        if table.shape[0] != self.num_frames:
            raise SimulationFailure(f"energy file has {table.shape[0]} frames, expected {self.num_frames}")
        return table


def _xvg_columns(path: Path) -> dict[str, np.ndarray]:
    """Columns of an ``.xvg`` by legend (``gmx energy`` orders them as the energy file does)."""
    legends = [
        line.split('legend "')[1].rstrip('"\n')
        for line in path.read_text().splitlines()
        if line.startswith("@ s") and 'legend "' in line
    ]
    table = np.loadtxt(path, comments=["#", "@"], ndmin=2)
    return {name: table[:, i + 1] for i, name in enumerate(legends)}


@dataclass(frozen=True)
class Design:
    """Run lengths (ps) derived from the preset and the extension factor."""

    analysis_start_ps: float
    window_end_ps: float
    run_length_ps: float
    tail_start_ps: float

    @property
    def window(self) -> tuple[float, float]:
        return (self.analysis_start_ps, self.window_end_ps)

    @property
    def tail(self) -> tuple[float, float]:
        return (self.tail_start_ps, self.run_length_ps)


def design(preset_length_ps: float, analysis_start_ps: float, extension: float) -> Design:
    """Extended run of ``analysis_start + extension x window``; tail from one window after it.

    Raises
    ------
    ValueError
        ``extension < 3``: the tail would be empty or shorter than nothing after the gap.
    """
    if extension < 3:
        raise ValueError(f"extension must be at least 3 (a gap of one window, then a tail), got {extension}")
    window = preset_length_ps - analysis_start_ps
    return Design(
        analysis_start_ps=analysis_start_ps,
        window_end_ps=preset_length_ps,
        run_length_ps=analysis_start_ps + extension * window,
        tail_start_ps=preset_length_ps + window,
    )


# ----------------------------------------------------------------------------- main


def _json_safe(value: Any) -> Any:
    """``value`` with NaN and infinities as None: an undefined sd or tau, which strict JSON
    readers would otherwise reject."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def parse_arguments(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=3, help="seeds per point (the same seeds at every point)")
    parser.add_argument(
        "--extension", type=float, default=4.0, help="run length = analysis start + extension x analysed window"
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0, help="root seed of the runs' keys")
    parser.add_argument("--quick", action="store_true", help="2 points, 1 seed, extension x3; writes results/quick/")
    args = parser.parse_args(argv)
    if args.quick:
        args.seeds, args.extension = 1, 3.0
    if args.seeds < 1 or args.workers < 1:
        parser.error("--seeds and --workers must be at least 1")
    return args


def main(argv: list[str] | None = None) -> Path:
    import jax

    import jaxabc
    from jaxabc.errors import STATUS_FAILED, STATUS_NAMES, STATUS_OK, SimulationFailure
    from md.water.gromacs import check_physical, get_protocol, seeds_for_key

    args = parse_arguments(argv)
    base = get_protocol("quick")
    plan = design(base.length_ps, base.analysis_start_ps, args.extension)
    num_steps = round(plan.run_length_ps / base.timestep_ps)
    protocol = get_protocol(
        "quick", num_steps=num_steps, timeout_s=base.timeout_s * plan.run_length_ps / base.length_ps
    )
    simulate = DensitySeries(protocol)
    if base.expected_molecules is None:
        raise RuntimeError("the quick preset must fix its molecule count (it copies tip4p.gro)")
    num_molecules = base.expected_molecules
    points = parameter_points(args.quick)

    root = jax.random.PRNGKey(args.seed)
    seed_keys = [
        np.asarray(jax.random.key_data(jax.random.fold_in(root, s)), dtype=np.uint32) for s in range(args.seeds)
    ]
    tasks = [(p, s) for p in range(len(points)) for s in range(args.seeds)]
    keys = np.stack([seed_keys[s] for _, s in tasks])
    thetas = np.array([[points[p]["sigma_nm"], points[p]["epsilon_kj_mol"]] for p, _ in tasks])

    executor = jaxabc.ProcessPoolExecutor(
        max_workers=args.workers, timeout=protocol.timeout_s + 120, summary_shape=(simulate.num_frames, 4)
    )
    try:
        batch = executor.map(simulate, keys, thetas)
    finally:
        executor.close()

    times = np.arange(simulate.num_frames) * protocol.frame_interval_ps
    window_frames = (times >= plan.window[0] - 1e-9) & (times <= plan.window[1] + 1e-9)
    tail_frames = times >= plan.tail[0] - 1e-9
    runs: list[dict[str, Any]] = []
    for i, (p, s) in enumerate(tasks):
        gen_seed, ld_seed = seeds_for_key(keys[i])
        row: dict[str, Any] = {
            "point": points[p]["name"],
            "sigma_nm": points[p]["sigma_nm"],
            "epsilon_kj_mol": points[p]["epsilon_kj_mol"],
            "seed_index": s,
            "gen_seed": gen_seed,
            "ld_seed": ld_seed,
            "wall_time_s": float(batch.wall_time[i]),
            "cpu_time_s": float(batch.cpu_time[i]) if batch.cpu_time is not None else float("nan"),
        }
        status, reason = int(batch.status[i]), batch.reasons[i]
        table = batch.summaries[i]
        if status == STATUS_OK:
            try:
                # Exactly what the quick simulator checks, on its own analysed frames.
                check_physical(table[window_frames, 1:], num_molecules, protocol)
            except SimulationFailure as failure:
                status, reason = STATUS_FAILED, f"analysed window: {failure}"
        if status == STATUS_OK:
            try:
                check_physical(table[tail_frames, 1:], num_molecules, protocol)
                row["tail_physical"] = ""
            except SimulationFailure as failure:
                row["tail_physical"] = str(failure)
            row.update(run_statistics(times, table[:, 0], plan.window, plan.tail))
            blocks_t, blocks_rho = block_average(times, table[:, 0], SAVED_BLOCK_PS)
            row["density_blocks"] = {
                "time_ps": blocks_t.round(3).tolist(),
                "density_kg_m3": blocks_rho.round(3).tolist(),
            }
        row["status"] = STATUS_NAMES.get(status, str(status))
        row["reason"] = reason
        runs.append(row)

    summary = []
    for point in points:
        ok = [r for r in runs if r["point"] == point["name"] and r["status"] == "ok"]
        failed = [r["reason"] for r in runs if r["point"] == point["name"] and r["status"] != "ok"]
        entry: dict[str, Any] = {**point, "num_failed": len(failed), "failures": failed}
        if ok:
            entry.update(point_summary(ok))
        else:
            entry["relaxed"] = None
        summary.append(entry)

    liquid = [e for e in summary if e.get("relaxed") is not None]
    verdict = {
        "criterion": (
            f"relaxed when |window mean - tail mean| < {DIFFERENCE_SE:g} combined SE and "
            f"|drift in the window| < max({DIFFERENCE_SE:g} SE of the drift, seed-to-seed sd of the window mean)"
        ),
        "points_relaxed": [e["name"] for e in liquid if e["relaxed"]],
        "points_not_relaxed": [e["name"] for e in liquid if not e["relaxed"]],
        "points_failed": [e["name"] for e in summary if e.get("relaxed") is None],
        "largest_abs_difference_kg_m3": max((abs(e["difference"]) for e in liquid), default=float("nan")),
        "all_liquid_points_relaxed": bool(liquid) and all(e["relaxed"] for e in liquid),
    }
    payload = {
        "setup": {
            "preset": "quick",
            "num_molecules": num_molecules,
            "temperature_k": protocol.temperature_k,
            "pressure_bar": protocol.pressure_bar,
            "tau_p_ps": protocol.tau_p_ps,
            "barostat": "Parrinello-Rahman, isotropic",
            "timestep_ps": protocol.timestep_ps,
            "energy_interval_ps": protocol.frame_interval_ps,
            "preset_length_ps": base.length_ps,
            "analysed_window_ps": list(plan.window),
            "extension": args.extension,
            "run_length_ps": plan.run_length_ps,
            "tail_ps": list(plan.tail),
            "seeds": args.seeds,
            "root_seed": args.seed,
            "workers": args.workers,
            "prior": "md.water.models.model_prior('TIP4P')",
            "standard_errors": "arviz.mcse(method='mean') per run; per point propagated over seeds",
            "relaxation_fit": (
                "rho_inf + A exp(-t/tau) on every density frame from t = 0 (scipy curve_fit); "
                f"resolved when |A| > {RESOLVED_AMPLITUDE_SE:g} SE(A)"
            ),
            "drift": "least-squares slope in the analysed window x window length",
            "units": {"density": "kg/m3", "time": "ps"},
        },
        "points": points,
        "runs": runs,
        "summary": summary,
        "verdict": verdict,
    }
    path = write_result("water_density_relaxation", _json_safe(payload), quick=args.quick)
    for e in summary:
        if e.get("relaxed") is None:
            print(f"{e['name']:<40} failed: {e['failures']}")
        else:
            print(
                f"{e['name']:<40} window {e['window_mean']:7.1f}  tail {e['tail_mean']:7.1f}  "
                f"diff {e['difference']:+6.1f} +- {e['difference_se']:.1f}  drift {e['drift']:+6.1f}  "
                f"tau {e['tau_ps']:5.2f} ps  relaxed={e['relaxed']}"
            )
    print(f"wrote {path}")
    return path


if __name__ == "__main__":
    main()
