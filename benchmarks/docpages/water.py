"""The water calibrations page and the generated blocks of ``md/water/README.md``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks._common import RESULTS, ROOT, RUNS
from benchmarks.docpages.common import f, figure, load, retired, source, sourced_table, table
from benchmarks.registry import paper_preset_cache
from benchmarks.status import format_cost
from jaxabc.surrogate.diagnostics import MISFIT_P_VALUE

WATER_LABELS = {
    "simulated": "simulated at TIP4P",
    "xray": "X-ray g_OO (Skinner 2013)",
    "neutron": "neutron g_OO, g_OH (Soper 2013 EPSR)",
}

_VALIDATION_HEADER = ["parameters", "density (kg/m3)", "kappa_T (1e-6/bar)", "C_p (J/mol/K)", "epsilon"]


def _validation_rows() -> tuple[list[list[Any]], list[str]]:
    """The paper's Table 2 properties at each calibration's estimate and at TIP4P, then experiment;
    and the results they come from."""
    rows: list[list[Any]] = []
    names: list[str] = []
    exp_row = None
    for data in ("simulated", "xray", "neutron"):
        name = f"water_{data}_surrogate"
        d = load(name) or {}
        for stats in ("robust", "paper"):
            v = (d.get(stats) or {}).get("validation")
            if not v:
                continue
            names.append(name)
            for point in ("bayes_estimate", "tip4p"):
                p = v[point]
                rows.append(
                    [
                        f"{data} {stats} {point.replace('_', ' ')} ({f(p['theta'][0], 4)}, {f(p['theta'][1])})",
                        f"{p['density_kg_m3']:.1f} +- {p['density_se']:.1f}",
                        f"{p['compressibility_per_bar'] * 1e6:.0f} +- {p['compressibility_se'] * 1e6:.0f}",
                        f"{p['heat_capacity_j_mol_k']:.1f} +- {p['heat_capacity_se']:.1f}",
                        f"{p['dielectric_constant']:.0f}",
                    ]
                )
            x = v["experiment"]
            exp_row = [
                "experiment (298 K)",
                x["density_kg_m3"],
                f"{x['compressibility_per_bar'] * 1e6:.1f}",
                x["heat_capacity_j_mol_k"],
                x["dielectric_constant"],
            ]
    return ([*rows, exp_row] if exp_row else rows), sorted(set(names))


def page_water() -> str:
    out = """# Water calibrations (GROMACS TIP4P, quick preset)

TIP4P's oxygen Lennard-Jones parameters (sigma_OW, epsilon_OW) calibrated on the simulated,
X-ray and neutron data of the paper through the GP surrogate (`--algorithm surrogate`, at most
300 GROMACS runs each), `robust` statistics (pilot-MAD-scaled) and the paper's own.  Which
water model the joint measured data prefer, with stated errors and a discrepancy term, is
[the model choice page](water_model_choice.md).
"""
    out += _water_surrogate_section()
    out += _water_paper_preset_section()
    out += _water_side_by_side()
    out += _paper_samples_section()
    validation, _ = _validation_rows()
    if validation:
        out += "\n## Validation properties (the paper's Table 2)\n\n" + table(_VALIDATION_HEADER, validation) + "\n"
    gone = retired(["water_simulated:", "water_xray:", "water_neutron:"])
    if gone:
        out += (
            "\n## Retired\n\nThe APMCABC calibrations of these data were saved before results recorded "
            "their provenance and kept 5-10 particles; they are no longer shown:\n\n" + gone + "\n"
        )
    return out


_SURROGATE_HEADER = [
    "data",
    "statistics",
    "sigma_OW (nm)",
    "epsilon_OW (kJ/mol)",
    "corr.",
    "GROMACS runs (failed)",
    "validated",
    "held-out cov. / MSSE / joint",
    "min_feasibility (posterior below design level)",
    "replicate runs (nugget test)",
    "observed misfit p (largest residual)",
    "truth in 50 % HPD",
    "posterior mass at a prior bound",
    "wall time",
    "GROMACS time (sum over runs)",
]


def _replicates(sur: dict) -> str:
    """Replicate runs of a surrogate result and whether the fitted nuggets agree with their
    scatter ("-" for results made before the diagnostics listed the groups)."""
    groups = sur.get("design_replicate_group")
    if groups is None:
        return "-"
    n = sum(g >= 0 for g in groups)
    if not n:
        return "none"
    return f"{n} ({'agree' if sur.get('lack_of_fit_ok', True) else '**disagree**'})"


def _worst_residual(entry: dict, misfit: dict) -> str:
    """The summary furthest from the emulated prediction, in noise sd (e.g. ``S4 -80.8 sd``)."""
    residuals = misfit["standardised_residuals"]
    worst = max((i for i, r in enumerate(residuals) if r is not None), key=lambda i: abs(residuals[i]))
    name = f"PC {worst + 1}" if misfit["projected"] else entry["statistic_names"][worst].split()[0]
    return f"{name} {residuals[worst]:+.1f} sd"


def _misfit(entry: dict) -> str:
    """The posterior predictive p-value of the observed summaries and the summary that misses
    most ("-" for results made before the check existed)."""
    m = entry["surrogate"].get("observed_misfit")
    return f"{m['p_value']:.1g} ({_worst_residual(entry, m)})" if m else "-"


def _prior_edge(entry: dict) -> str:
    """Each parameter bound that holds more than the limit of the posterior mass within the
    edge width (``ABCResult.prior_edge_mass``), e.g. ``epsilon_OW upper 100 %``; "none" below
    it, "-" for results made before the diagnostic existed."""
    edge = entry["surrogate"].get("prior_edge")
    if not edge:
        return "-"
    hits = [
        f"**{('sigma_OW', 'epsilon_OW')[i]} {side} {m:.0%}**"
        for i, pair in enumerate(edge["mass"])
        for side, m in zip(("lower", "upper"), pair, strict=True)
        if m > edge["limit"]
    ]
    return ", ".join(hits) or "none"


def _feasibility_level(entry: dict) -> str:
    """The posterior's feasibility level and its weight below the design level ("-" for results
    made before the diagnostic existed)."""
    share = entry["surrogate"].get("posterior_share_below_design_level")
    level = f(entry.get("settings", {}).get("min_feasibility"), 2)
    known = share is not None and np.isfinite(share)
    return f"{level} ({f'{share:.0%}' if known else '-'})"


def _water_surrogate_section() -> str:
    """The GP-surrogate calibrations (``--algorithm surrogate``) beside the APMCABC ones."""
    rows, sources = [], []
    for data in ("simulated", "xray", "neutron"):
        d = load(f"water_{data}_surrogate")
        for stats, e in (d or {}).items():
            if stats not in ("robust", "paper") or not e:
                continue
            ci, sur = e["credible_interval_95"], e["surrogate"]
            truth = ""
            if "truth_in_50pct_hpd" in e:
                level = e["truth_credibility"]
                level = level["hpd_level"] if isinstance(level, dict) else level
                truth = f"{'yes' if e['truth_in_50pct_hpd'] else 'no'} (HPD level {f(level, 2)})"
            rows.append(
                [
                    WATER_LABELS[data],
                    stats,
                    f"{f(e['bayes_estimate'][0], 4)} [{f(ci[0][0], 4)}, {f(ci[0][1], 4)}]",
                    f"{f(e['bayes_estimate'][1])} [{f(ci[1][0])}, {f(ci[1][1])}]",
                    f(e["correlation"], 3),
                    f"{e['num_simulations']} ({e['num_failures']})",
                    "yes" if sur["validated"] else "**no**",
                    f"{f(sur['holdout_coverage_95'], 2)} / {f(sur['holdout_mean_squared_error'], 2)} / "
                    + (
                        f(sur["holdout_joint_mean_squared_error"], 2)
                        if "holdout_joint_mean_squared_error" in sur
                        else "-"
                    ),
                    _feasibility_level(e),
                    _replicates(sur),
                    _misfit(e),
                    truth or "-",
                    _prior_edge(e),
                    _wall_time(e),
                    _gromacs_seconds(data, stats),
                ]
            )
            sources.append(f"- {source(f'water_{data}_surrogate', stats, d)}")
    if not rows:
        return ""
    return f"""
## GP-surrogate calibrations

`--algorithm surrogate`: `jaxabc.run("surrogate", ...)` (a GP emulator of S1..S9, sequential
design, a success classifier for the runs that vaporise or collapse, held-out runs checked
before a posterior is reported; see the [surrogate coverage study](surrogate_coverage.md)), same
prior, same GROMACS preset.  Bayes estimate [95 % interval] from the emulator's synthetic
likelihood; real GROMACS runs (failed); whether the held-out check passed, with the held-out 95 %
coverage / mean squared standardised error / the joint one (Mahalanobis distance under the noise
correlation, divided by the number of statistics; 1 when the correlation is right); the level of
the success classifier below which the posterior is cut, and the posterior weight between it and the
design level, where no design run goes (docs/guide/surrogate.md); the replicate
runs at two liquid design points and whether the GP nuggets agree with their scatter; the
posterior predictive check of the observed summaries (`observed_misfit`: the chi-square tail
probability, and the summary furthest from the emulated prediction in noise sd; below 1e-3 no
parameter value reproduces the data within the simulator noise, and the interval is that of the
best fit of a misspecified model, conditional on it); for simulated data whether TIP4P's own
parameters lie in the 50 % HPD region; the posterior mass within 2 % of the range from a bound of
the paper's prior box where it exceeds 5 % (`prior_edge_mass`: the estimate and interval of such
a parameter are those of the box, not of the data).

{table(_SURROGATE_HEADER, rows)}

{chr(10).join(sources)}
"""


_MISFIT_POINTS = {
    "surrogate_estimate": "the surrogate's estimate",
    "paper_estimate": "the paper's estimate",
    "tip4p": "TIP4P",
}


_FIT_LABELS = {
    "sampled": "the draws' fit (warm-started from the run's last hyper-parameters)",
    "refit": "the refit from the default starts (held-out check, evidence)",
}


#: Posterior sds (the draws' fit's) beyond which the two fits' posteriors count as apart.
_FITS_APART_SD = 3.0


def _fits_apart(fits: dict[str, Any]) -> float:
    """How far apart the two fits' posterior means are, in the draws' fit's sds (the largest over
    the parameters)."""
    s, r = fits["sampled"], fits["refit"]
    sd = np.maximum(np.asarray(s["posterior_sd"]), 1e-12)
    return float(np.max(np.abs(np.asarray(r["posterior_mean"]) - np.asarray(s["posterior_mean"])) / sd))


def _two_fits(d: dict[str, Any]) -> str:
    """The subsection comparing the fit the run sampled with the refit its checks used."""
    fits = d.get("fits")
    if not fits:
        return ""
    rows = [
        [
            label,
            f(fits[key]["gp_objective"], 1),
            f"{f(fits[key]['posterior_mean'][0], 4)} +- {f(fits[key]['posterior_sd'][0], 4)}",
            f"{f(fits[key]['posterior_mean'][1], 3)} +- {f(fits[key]['posterior_sd'][1], 3)}",
            *(f(fits[key]["log_posterior"][p], 1) for p in _MISFIT_POINTS),
        ]
        for key, label in _FIT_LABELS.items()
    ]
    header = [
        "fit",
        "GP objective",
        "sigma_OW (nm)",
        "epsilon_OW (kJ/mol)",
        *(f"log posterior at {label}" for label in _MISFIT_POINTS.values()),
    ]
    s, r = fits["sampled"], fits["refit"]
    apart = _fits_apart(fits)
    gap = r["gp_objective"] - s["gp_objective"]
    better = "the draws' fit" if gap > 0 else "the refit"
    if apart > _FITS_APART_SD:
        verdict = (
            f"The two fits of the same rows reach different optima of the GP's hyper-parameters, {better} "
            f"scoring {abs(gap):.1f} better, and put the posterior up to {apart:.0f} of the draws' sds apart. "
            "The held-out check that passed judged the refit, not the emulator the reported draws came from: "
            "this estimate is conditional on the optimum the design loop's warm start found, and the "
            "run's `validated` does not vouch for it."
        )
    else:
        verdict = (
            f"The two fits put the posterior within {apart:.1f} of the draws' sds of each other, so the held-out "
            "check on the refit speaks for the reported draws too."
        )
    return f"""
### Which emulator: the draws' fit and the checks' refit

This run predates the one-fit rule (the [surrogate guide](../guide/surrogate.md)): its design loop
warm-started each GP fit from the last one's hyper-parameters, and its held-out check, posterior-shift
test and evidence refitted the same design rows from the default starts alone.
Each fit's GP objective (negative log marginal likelihood plus the hyper-prior, over the
outputs; lower is better), its posterior mean +- sd from an importance sample over the prior box,
and its log posterior at the three points above:

{table(header, rows)}

{verdict}
"""


def _water_misfit_section() -> str:
    """Why the paper-preset estimate differs from the paper's (``benchmarks/water_misfit.py``)."""
    d = load("water_misfit")
    if not d:
        return ""
    names = d["statistic_names"]
    shown = [i for i, r in enumerate(d["points"]["surrogate_estimate"]["residual_sd"]) if r is not None]
    base = d["points"]["surrogate_estimate"]["synthetic_log_likelihood"]
    rows = []
    for key, label in _MISFIT_POINTS.items():
        p = d["points"][key]
        rows.append(
            [
                label,
                f"{f(p['theta'][0], 4)}, {f(p['theta'][1])}",
                f(p["paper_distance"], 4),
                f(p["synthetic_log_likelihood"] - base, 1),
                f(p["success_probability"], 2),
                *(f"{p['residual_sd'][i]:+.1f}" for i in shown),
            ]
        )
    header = [
        "point",
        "sigma_OW, epsilon_OW",
        "paper's distance",
        "synthetic log-lik. (rel.)",
        "P(run succeeds)",
        *(f"{names[i].split()[0]} (sd)" for i in shown),
    ]
    m = d["observed_misfit"]
    sur, pap = d["points"]["surrogate_estimate"], d["points"]["paper_estimate"]
    each_better = (
        pap["paper_distance"] < sur["paper_distance"]
        and sur["synthetic_log_likelihood"] > pap["synthetic_log_likelihood"]
    )
    verdict = (
        "Here each estimate is the better one under its own measure"
        if each_better
        else "Here the two measures do not split that way (see the table)"
    )
    return f"""
### Why the estimates differ: no parameter reproduces the data

From the emulator the run's draws came from (`benchmarks/water_misfit.py`, no new GROMACS runs): the observed
summaries against the posterior predictive give a squared Mahalanobis distance of
{m["mahalanobis_squared"]:.3g} on {m["dof"]} statistics (p = {m["p_value"]:.1g}).  At three points: the paper's
distance (mean absolute difference of the statistics, as the paper's ABC used it) between the
data and the emulated summaries, the synthetic log-likelihood relative to the surrogate's
estimate, the chance that a run succeeds, and each statistic's residual (data minus emulation)
in units of the simulator noise and the emulator spread:

{table(header, rows)}

A statistic that misses by many sd everywhere is one the model cannot match; the two methods
then trade the others against each other by different weights.  The paper's distance weighs the
statistics in their own units, so the large g(r) values dominate; the synthetic likelihood weighs
them by their noise, so the quietest ones dominate.  {verdict}; the synthetic likelihood's narrow
interval is conditional on a model that does not fit (the `observed_misfit` warning).
{_two_fits(d)}
- {source("water_misfit", None, d)}
"""


def _validated_cell(validated: bool) -> str:
    """The paper preset's "validated" cell: a pass that judged another fit than the draws' says so."""
    if not validated:
        return "**no**"
    fits = (load("water_misfit") or {}).get("fits")
    if fits and _fits_apart(fits) > _FITS_APART_SD:
        return "yes, **on another fit** (see below)"
    return "yes"


def _water_paper_preset_section() -> str:
    """The paper's own protocol through the surrogate: the result, or the progress of a run that
    spans sittings (its checkpoint, sitting clock and run cache live under ``runs/cache/``)."""
    folder = RESULTS / "water_paper_preset"
    d = load("water_paper_preset/water_xray_surrogate")
    head = """
## The paper's preset (515 molecules, 100 ps), X-ray data, paper statistics

The calibration the paper itself made, through the GP surrogate (`water_xray_surrogate_paper_preset`
in `benchmarks/registry.py`), resumable across sittings.
"""
    if d and d.get("paper"):
        e = d["paper"]
        ci, sur, paper = e["credible_interval_95"], e["surrogate"], e["paper"]
        row = [
            f"{f(e['bayes_estimate'][0], 4)} [{f(ci[0][0], 4)}, {f(ci[0][1], 4)}]",
            f"{f(e['bayes_estimate'][1])} [{f(ci[1][0])}, {f(ci[1][1])}]",
            f(e["correlation"], 3),
            f"{e['num_simulations']} ({e['num_failures']})",
            _validated_cell(sur["validated"]),
            _wall_time(e),
            f"{f(paper['bayes_estimate'][0], 4)}, {f(paper['bayes_estimate'][1])}",
        ]
        header = [
            "sigma_OW (nm)",
            "epsilon_OW (kJ/mol)",
            "corr.",
            "GROMACS runs (failed)",
            "validated",
            "wall time",
            "paper's estimate",
        ]
        detail = (
            f"The design ran {sur['num_design']} simulations and the validation {sur['num_holdout']} held-out "
            f"ones at the surrogate posterior ({sur['num_failed_simulations']} of the {sur['num_simulations']} "
            f"failed); the design stopped at an emulator-to-noise variance of "
            f"{f(sur['emulator_to_noise_variance'], 3)} (tolerance {f(e['settings'].get('tolerance'), 2)}). "
            f"Held out: 95 % predictive coverage {f(sur['holdout_coverage_95'], 2)}, mean squared "
            f"standardised error {f(sur['holdout_mean_squared_error'], 2)}. "
            + (
                f"The wall time adds up the run's {e['sittings']} sittings; a simulation cut off at the end of "
                "one ran again in the next, so it bounds this design's cost from above. "
                if e.get("sittings", 1) > 1
                else ""
            )
            + "The quick preset's estimate on the same data and statistics is in the side-by-side table below."
        )
        return (
            head
            + "\n"
            + table(header, [row])
            + "\n\n"
            + detail
            + "\n\n"
            + "\n\n".join(
                figure(f"water_paper_preset/water_xray_paper_surrogate_{kind}.png", f"paper preset, X-ray: {kind}")
                for kind in ("posterior", "predictive")
                if (folder / f"water_xray_paper_surrogate_{kind}.png").is_file()
            )
            + "\n\n- "
            + source("water_paper_preset/water_xray_surrogate", "paper", d)
            + "\n"
            + _water_misfit_section()
        )
    runs = sorted((RUNS / paper_preset_cache("run_cache", "xray")).glob("*.npz"))
    checkpoints = RUNS / paper_preset_cache("checkpoint", "xray")
    clock = checkpoints / "water_xray_paper_surrogate.sittings.json"
    if not runs and not clock.exists():
        return head + "\nNot run yet.\n"
    failed = 0
    for path in runs:
        with np.load(path) as z:
            failed += bool(str(z["reason"])) or not bool(np.all(np.isfinite(z["summaries"])))
    sittings = json.loads(clock.read_text())["sittings"] if clock.exists() else []
    seconds = sum(s["elapsed_s"] for s in sittings)
    checkpoint = checkpoints / "checkpoint.npz"
    design = "no checkpoint yet (the first comes after the start batch)"
    if checkpoint.exists():
        # The design's own runs; the cache may also hold runs an earlier design made.
        with np.load(checkpoint) as z:
            n = int(z["state/.count"]) if "state/.count" in z else None
            ok = np.asarray(z["state/.ok"])[:n] if n is not None and "state/.ok" in z else None
        if n is not None and ok is not None:
            design = f"the checkpoint's design holds {n} of them ({int(np.sum(~ok.astype(bool)))} failed)"
        else:
            design = "a checkpoint holds the design so far"
    return (
        head
        + f"""
In progress: {len(runs)} GROMACS runs cached ({failed} failed; at most 200 in the design) in
{len(sittings)} sitting(s), {format_cost(seconds)} of wall time; {design}.
`python -m benchmarks.regenerate --only water_xray_surrogate_paper_preset:paper --budget 12h` continues it.
"""
    )


def _predictive_figures() -> str:
    """The saved posterior-predictive g_OO bands of the quick-preset calibrations."""
    paths = sorted(RESULTS.glob("water_*_predictive.png"))
    return "\n\n".join(figure(p.name, p.stem.removesuffix("_predictive").replace("_", " ")) for p in paths)


_MEASURED_GOO = {
    "xray": ("md/water/data/skinner2013_gOO_295K_nm.csv", "X-ray 295 K"),
    "neutron": ("md/water/data/soper2013_gOO_gOH_gHH_nm.csv", "neutron EPSR"),
}


def _first_peak(r: np.ndarray, g: np.ndarray) -> tuple[int, float, float]:
    """Index, position (nm) and height of the g_OO maximum in 0.25-0.32 nm."""
    window = np.flatnonzero((r >= 0.25) & (r <= 0.32))
    i = int(window[np.argmax(g[window])])
    return i, float(r[i]), float(g[i])


def _predictive_peak(e: dict[str, Any]) -> str:
    """First peak of the posterior-predictive median g_OO, with the quartiles of g there."""
    bands = e.get("predictive_goo")
    if not bands:
        return "-"
    if not bands["num_curves"]:
        return f"- (all {bands['num_failed']} runs failed)"
    r, median = np.asarray(bands["r_nm"]), np.asarray(bands["median"])
    i, r_peak, g_peak = _first_peak(r, median)
    return (
        f"{f(r_peak, 3)} nm, {f(g_peak, 2)} [{f(bands['q25'][i], 2)}, {f(bands['q75'][i], 2)}] "
        f"({bands['num_curves']} runs)"
    )


def _water_npz(data: str, stats: str) -> Path:
    """The saved posterior of a surrogate water calibration (``water_calibration.py`` names it so)."""
    return RESULTS / f"water_{data}_{stats}_surrogate.npz"


def _wall_time(entry: dict) -> str:
    """A water calibration's wall time: over every sitting where recorded, else its last one."""
    if "sittings" not in entry:
        return f"{format_cost(entry['wall_time_s'])} (last sitting)"
    n = entry["sittings"]
    return format_cost(entry["wall_time_s"]) + (f" ({n} sittings)" if n > 1 else "")


def _gromacs_seconds(data: str, stats: str) -> str:
    """Summed wall time of a surrogate run's GROMACS runs, over every sitting (a resumed run's
    own wall time covers only its last one)."""
    path = _water_npz(data, stats)
    if not path.exists():
        return "-"
    with np.load(path, allow_pickle=True) as z:
        key = "record_wall_time"
        return format_cost(float(np.nansum(z[key]))) if key in z.files else "-"


def _posterior_draws(data: str, stats: str) -> str:
    """Number of posterior draws and their effective sample size, from the saved result."""
    path = _water_npz(data, stats)
    if not path.exists():
        return "-"
    with np.load(path, allow_pickle=True) as z:
        w = np.asarray(z["weights"], np.float64)
        # The run's own ESS (NUTS chains: ArviZ's, below the count of equal weights).
        ess = float(np.asarray(z["ess"])[-1]) if "ess" in z.files else None
    w = w / w.sum()
    return f"{w.size} (ESS {1.0 / np.sum(w**2) if ess is None else ess:.0f})"


def _method_label(method: str, entry: dict, validated: bool) -> str:
    """The side-by-side method, flagged when the emulator failed validation or when no parameter
    reproduces the data (the ``observed_misfit`` check below ``MISFIT_P_VALUE``)."""
    if not validated:
        return f"{method} (NOT VALIDATED: {entry['surrogate'].get('failure', '')})"
    misfit = (entry.get("surrogate") or {}).get("observed_misfit")
    if misfit and misfit["p_value"] < MISFIT_P_VALUE:
        worst = _worst_residual(entry, misfit)
        return f"{method} (MISFIT: p = {misfit['p_value']:.1g}, {worst}; interval conditional on the model)"
    return method


_SIDE_BY_SIDE_HEADER = [
    "data",
    "statistics",
    "method",
    "sigma_OW (nm)",
    "epsilon_OW (kJ/mol)",
    "corr.",
    "GROMACS runs (failed)",
    "draws (ESS)",
]


def _water_side_by_side_rows() -> tuple[list[list[Any]], list[list[Any]]]:
    """Rows of the measured-data calibrations (surrogate, paper) and of their predictive peaks."""
    rows, peaks = [], []
    for data in ("xray", "neutron"):
        sur = load(f"water_{data}_surrogate") or {}
        csv, label = _MEASURED_GOO[data]
        measured = np.loadtxt(ROOT / csv, delimiter=",", comments="#")
        _, r_m, g_m = _first_peak(measured[:, 0], measured[:, 1])
        for stats in ("robust", "paper"):
            e = sur.get(stats)
            if not e:
                continue
            paper = e["paper"]
            pe = paper["bayes_estimate"]
            rows.append(
                [WATER_LABELS[data], stats, "paper (Dutta et al. 2018)", pe[0], pe[1], paper["correlation"], "-", "-"]
            )
            ci = e["credible_interval_95"]
            # A surrogate posterior whose emulator failed its held-out check says so here.
            validated = (e.get("surrogate") or {}).get("validated", True)
            rows.append(
                [
                    WATER_LABELS[data],
                    stats,
                    _method_label("GP surrogate", e, validated),
                    f"{f(e['bayes_estimate'][0], 4)} [{f(ci[0][0], 4)}, {f(ci[0][1], 4)}]",
                    f"{f(e['bayes_estimate'][1])} [{f(ci[1][0])}, {f(ci[1][1])}]",
                    f(e["correlation"], 3),
                    f"{e['num_simulations']} ({e['num_failures']})",
                    _posterior_draws(data, stats),
                ]
            )
            measured_peak = f"{f(r_m, 3)} nm, {f(g_m, 2)} ({label})"
            peaks.append([WATER_LABELS[data], stats, "GP surrogate", _predictive_peak(e), measured_peak])
    return rows, peaks


def _water_side_by_side() -> str:
    """The measured-data calibrations through the surrogate side by side with the paper."""
    rows, peaks = _water_side_by_side_rows()
    if not rows:
        return ""
    return f"""
## Measured data: the surrogate and the paper side by side

Bayes estimate [95 % interval], correlation, real GROMACS runs (failed) and the posterior draws
with their effective sample size.  The paper's runs used its own preset (515 molecules, 100 ps);
these use the quick preset.

{table(_SIDE_BY_SIDE_HEADER, rows)}

Posterior-predictive g_OO: the first peak of the median of `--predictive` GROMACS runs at posterior
draws (position, height [quartiles of the height there]), beside the measured curve's first peak.
{table(["data", "statistics", "method", "predictive first peak", "measured first peak"], peaks)}

{_predictive_figures()}
"""


def block_water_calibrations() -> str:
    """The measured-data calibrations beside the paper's, for ``md/water/README.md``."""
    rows, _ = _water_side_by_side_rows()
    if not rows:
        return (
            "Not run yet: `python -m benchmarks.regenerate --only water_xray_surrogate water_neutron_surrogate "
            "--budget 4h`."
        )
    names = [f"water_{d}_surrogate" for d in ("xray", "neutron") if load(f"water_{d}_surrogate")]
    return sourced_table(names, _SIDE_BY_SIDE_HEADER, rows)


def block_water_validation() -> str:
    """The validation properties, for ``md/water/README.md``."""
    rows, names = _validation_rows()
    if not rows:
        return (
            "Not run yet on a kept calibration (the earlier Table-2 runs were at the estimates of the retired "
            "APMCABC calibrations; `water_paper_samples` has the density at the paper's estimates).  "
            "`python -m benchmarks.water_calibration --data xray --statistics paper --algorithm surrogate "
            "--validation-only benchmarks/results/water_xray_paper_surrogate.npz --validation-ps 500` adds them "
            "to a surrogate calibration."
        )
    return sourced_table(names, _VALIDATION_HEADER, rows)


def _prior_range_row(label: str, runs: list[dict]) -> list[str]:
    """One (model, factor) point of the epsilon scan: means over its runs that gave summaries."""
    ok = [r for r in runs if r["status"] == "ok"]

    def mean(key: str, digits: int) -> str:
        return f(float(np.mean([r[key] for r in ok])), digits) if ok else "-"

    liquid = sum(r["liquid"] for r in runs)
    undefined = sum(r["status"] == "summaries undefined" and r["liquid"] for r in runs)
    failed = [r for r in runs if r["status"] == "failed"]
    note = (
        f"{liquid}/{len(runs)}"
        + (f" ({undefined} without the g_OO extrema the summaries read)" if undefined else "")
        + (f" ({len(failed)} failed: {failed[0].get('reason', '')})" if failed else "")
    )
    dense = [r["density_kg_m3"] for r in runs if "density_kg_m3" in r]
    return [
        label,
        f(float(np.mean(dense)), 0) if dense else "-",
        mean("S9", 2),
        mean("hvap_kj_mol", 1),
        mean("g_oo_min1", 2),
        f"{mean('r_oo_max2_nm', 3)}, {mean('g_oo_max2', 2)}",
        note,
    ]


def block_water_prior_range() -> str:
    """The epsilon scan behind the wide prior, for ``md/water/README.md``."""
    d = load("water_prior_range")
    if d is None:
        return "Not run yet: `python -m benchmarks.water_prior_range --workers 2`."
    low = load("water_prior_range_low")
    below = [] if low is None else ["Below the box:", _prior_range_block(low, "water_prior_range_low")]
    return "\n\n".join([_prior_range_block(d, "water_prior_range"), *below])


def _prior_range_block(d: dict[str, Any], name: str) -> str:
    points: dict[str, list[dict]] = {}
    for r in [*d["scan"], *d["long_runs"]]:
        length = f", {r['length_ps']:g} ps" if "length_ps" in r else ""
        points.setdefault(f"{r['model']} x{r['epsilon_factor']:g}{length}", []).append(r)
    rows = [_prior_range_row(label, runs) for label, runs in points.items()]
    header = [
        "model x epsilon",
        "density (kg/m3)",
        "D (1e-5 cm2/s)",
        "H_vap (kJ/mol)",
        "g_OO 1st min",
        "2nd max r (nm), g",
        "liquid runs",
    ]
    lo, hi = d["liquid_density_kg_m3"]
    return "\n\n".join(
        [
            source(name, data=d),
            table(header, rows),
            f"Means over {d['seeds']} runs per point (the runs that gave summaries).  Liquid: GROMACS "
            f"finishes, density in [{lo:g}, {hi:g}] kg/m3 and D >= {d['min_diffusion_1e5_cm2_s']:g} "
            f"(Yeh-Hummer corrected) at {d['temperature_k']:g} K.  " + d["verdict"],
        ]
    )


def _sample_row(kind: str, label: str, m: dict, diff: str, ratio: str, ed: str) -> list[str]:
    """One row of the paper-samples table: draws, weighted mean +- sd, correlation, comparisons."""
    return [
        WATER_LABELS[kind],
        label,
        f"{m['draws']} ({m['ess']:.0f})",
        f"{f(m['mean'][0], 4)} +- {f(m['sd'][0], 4)}",
        f"{f(m['mean'][1])} +- {f(m['sd'][1])}",
        f(m["correlation"], 2),
        diff,
        ratio,
        ed,
    ]


def _paper_samples_section() -> str:
    """Our paper-statistics posteriors against the paper's final generation, and Table 2's density."""
    d = load("water_paper_samples")
    if d is None:
        return ""
    rows, verdicts = [], []
    for kind, e in d["samples"].items():
        p = e["paper"]
        rows.append(_sample_row(kind, "paper's final generation", p, "-", "-", "-"))
        for o in e["ours"].values():
            diff = ", ".join(f(v, 2) for v in o["mean_difference_in_paper_sd"])
            ratio = ", ".join(f(v, 2) for v in o["sd_ratio"])
            null = o["null_energy_distance"]
            ed = f"{f(o['energy_distance'], 3)} (null {f(null['median'], 3)} [95 %: {f(null['q95'], 3)}])"
            flags = ("; NOT VALIDATED" if o.get("validated") is False else "") + (
                f"; MISFIT p = {o['misfit_p_value']:.1g}"
                if o.get("misfit_p_value") is not None and o["misfit_p_value"] < MISFIT_P_VALUE
                else ""
            )
            rows.append(_sample_row(kind, o["label"] + flags, o, diff, ratio, ed))
            if o["paper_target"]:
                verdicts.append(
                    f"- {WATER_LABELS[kind]}: {o['label']} is "
                    f"{'consistent with' if o['within_null_q95'] else 'distinguishable from'} the paper's "
                    f"{p['draws']} particles (ESS {p['ess']:.0f}): energy distance {f(o['energy_distance'], 3)} "
                    f"against the 95 % point {f(null['q95'], 3)} of its null."
                )
    dens = []
    for kind, points in d["density"].items():
        for label, v in points.items():
            paper = d["paper_table2_density_kg_m3"].get("TIP4P" if label == "TIP4P" else kind)
            se = f" +- {f(v['standard_error'], 1)}" if v["standard_error"] is not None else ""
            got = f"{f(v['density_kg_m3'], 1)}{se} ({v['runs']} runs)" if v["density_kg_m3"] is not None else "failed"
            table2 = f"{paper:g}" if label in ("paper estimate", "TIP4P") and paper is not None else "-"
            dens.append(
                [
                    WATER_LABELS[kind] if label != "TIP4P" else "-",
                    label,
                    f"({f(v['theta'][0], 4)}, {f(v['theta'][1])})",
                    got,
                    table2,
                ]
            )
    header = [
        "data",
        "sample",
        "draws (ESS)",
        "sigma_OW (nm)",
        "epsilon_OW (kJ/mol)",
        "corr.",
        "mean - paper (paper sds)",
        "sd / paper sd",
        "energy distance (paper-sd units)",
    ]
    return f"""
## Against the paper's own samples (its statistics)

{source("water_paper_samples", data=d)}

The paper's final APMCABC generation (100 weighted particles, `md.water.datasets.published_posterior`)
beside our posteriors of the same statistics: weighted mean +- sd, correlation, the mean
difference and sd ratio in the paper's sds, and the energy distance after scaling by the paper's
sds, beside its null (median [95th percentile]): the distance when the paper's particles are
replaced by as many draws from our posterior carrying the paper's weights, i.e. what a sample of
the paper's effective size can resolve.  Only the ABC
row on the paper's distance aims at the paper's posterior; the synthetic likelihood weighs each
statistic by its noise, a different target.

{table(header, rows)}

{chr(10).join(verdicts) if verdicts else "No posterior of the paper's own target (ABC on its distance) is saved yet."}

Density of liquid water at 298 K, {d["density_protocol"]}, beside the paper's Table 2:

{table(["data", "point", "(sigma_OW, epsilon_OW)", "density here (kg/m3)", "Table 2 (kg/m3)"], dens)}
"""
