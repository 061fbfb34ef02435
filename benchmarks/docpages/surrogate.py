"""Surrogate pages: SBC coverage, helium against APMCABC, the peers BOLFI and pyABC, and the
success classifier replayed on the water runs."""

from __future__ import annotations

from typing import Any

import numpy as np

from benchmarks.docpages.common import f, g, load, source, sources_by_part, span, table


def page_surrogate_coverage() -> str:
    d = load("surrogate_coverage")
    if d is None:
        return "# Coverage of the surrogate posterior\n\nNot saved yet.\n"
    rows = []
    for key, label in (("surrogate", "surrogate (GP synthetic likelihood)"), ("apmcabc_reference", "APMCABC")):
        c = d[key]
        h, iv = c["hpd_coverage"], c["interval_coverage"]["0.95"]
        sims = c.get("simulations_per_dataset", {})
        pooled = c.get("interval_coverage_pooled", {}).get("0.95")
        rows.append(
            [
                label,
                f"{sims['median']:.0f} (max {sims['max']})" if sims else "-",
                *(f"{h[q][0]:.2f} +- {h[q][1]:.2f}" for q in ("0.5", "0.9", "0.95")),
                " / ".join(f"{v:.2f}" for v in iv[0]),
                f"{pooled[0]:.2f} +- {pooled[1]:.2f}" if pooled else "-",
                c["num_datasets"],
            ]
        )
    return f"""# Coverage of the surrogate posterior

Simulation-based calibration of `jaxabc.run("surrogate", ...)` on the correlated Gaussian problem
({d["problem"]}), beside APMCABC on the same data sets: how often each region holds the truth.
Errors are binomial standard errors over the data sets; the pooled 95 % interval coverage counts
both parameters (its error is a lower bound: the two intervals of one data set are correlated).

{source("surrogate_coverage")}

{
        table(
            [
                "run",
                "simulations per data set (median)",
                "HPD 50 %",
                "HPD 90 %",
                "HPD 95 %",
                "95 % intervals (per parameter)",
                "95 % intervals pooled",
                "data sets",
            ],
            rows,
        )
    }
"""


def _noise_grid_section(noise: dict) -> str:
    """The grid posteriors of surrogate_helium_noise, one ingredient of the likelihood changed at a time."""
    grid = noise.get("grid")
    if not grid:
        return "The grid decomposition is missing from this result (rerun the benchmark).\n\n"
    post = grid["posteriors"]
    labels = [
        (
            "surrogate_log_likelihood",
            "the surrogate's own (emulated mean, model noise, emulator variance)",
        ),
        ("emulated_mean_model_covariance_no_emulator_variance", "the same without the emulator's variance"),
        (
            "replicate_mean_model_covariance",
            "replicate means for the emulated one, the model's noise covariance",
        ),
        (
            "replicate_mean_pooled_covariance",
            "replicate means, covariance pooled over the grid (as the reference)",
        ),
        (
            "replicate_mean_local_covariance",
            f"replicate means, covariance local to each point ({grid['local_covariance_neighbourhood']}^2 "
            "neighbouring points) with its log-determinant (Wood 2010)",
        ),
    ]
    rows = [
        [
            text,
            " / ".join(g(x, 3) for x in post[key]["mean"]),
            " / ".join(g(x, 3) for x in post[key]["sd"]),
            f(post[key]["correlation"], 2),
            g(post[key]["weight_on_edge"], 2),
        ]
        for key, text in labels
    ]
    sur = noise["surrogate"]["posterior_sd"]
    local = post["replicate_mean_local_covariance"]["sd"]
    pooled = post["replicate_mean_pooled_covariance"]["sd"]
    own = post["surrogate_log_likelihood"]["sd"]
    sampler = max(abs(a / b - 1) for a, b in zip(sur, own, strict=True))
    ratio_local = " / ".join(f(a / b, 2) for a, b in zip(sur, local, strict=True))
    ratio_pooled = " / ".join(f(a / b, 2) for a, b in zip(sur, pooled, strict=True))
    error = grid["emulated_mean_rms_error_in_noise_sd"]
    return (
        f"Exact posteriors on a {grid['points_per_parameter']}x{grid['points_per_parameter']} grid over the "
        f"surrogate's posterior mean +- {g(grid['half_width_in_surrogate_sd'], 2)} of its sd, "
        f"{grid['replicates_per_point']} runs per point ({grid['simulations']} simulations), one ingredient "
        "of the likelihood changed at a time (mean / sd: sigma / epsilon):\n\n"
        + table(["likelihood", "mean", "sd", "corr", "weight on the grid's edge"], rows)
        + "\n\n"
        + _sampler_sentence(sampler, noise["surrogate"])
        + "  Its sd over that of the synthetic likelihood whose covariance varies "
        f"with theta: {ratio_local}; over the pooled one: {ratio_pooled}.  The emulated mean's error where the "
        f"posterior lies is {g(min(error), 2)}-{g(max(error), 2)} noise sd per output.\n\n"
    )


def _sampler_sentence(sampler: float, sur: dict[str, Any]) -> str:
    """How far the run's draws are from its own likelihood on the grid (largest relative sd difference)."""
    text = f"The surrogate's draws have the sd of its own likelihood on the grid to within {f(100 * sampler, 0)} %"
    if sampler <= 0.05:
        text += " (the sampler is not the cause)."
    else:
        text += (
            ": more than the draws' Monte Carlo error, so the sampler, or a final fit other than the one refitted "
            "here from the checkpoint, accounts for part of the width."
        )
    if not sur.get("validated", True):
        text += "  This surrogate run was NOT validated (its own held-out check failed)."
    return text


def _noise_model_sentence(sur: dict[str, Any]) -> str:
    """What noise model the measured surrogate run used (results before the noise profile: constant)."""
    if "noise_sd_varies_with_theta" not in sur:
        return (
            "This result was made before the surrogate had a noise model that varies with theta: its "
            "synthetic likelihood assumed one noise covariance everywhere (GP nuggets over the whole design, "
            "correlations from leave-one-out residuals)."
        )
    chosen = (
        "a noise sd that varies with theta (a log-linear profile per output)"
        if sur["noise_sd_varies_with_theta"]
        else "one noise sd everywhere"
    )
    return (
        f"The surrogate run (`noise_model={sur['noise_model_setting']!r}`) chose {chosen}, with correlations "
        "from leave-one-out residuals; the model's covariance below is the one at the posterior mean (and, on "
        "the grid, at each point)."
    )


def page_surrogate_helium() -> str:
    d = load("surrogate_helium")
    title = "# Surrogate against APMCABC on helium"
    if d is None or "per_seed" not in d:
        return f"{title}\n\nNot saved yet: run `python -m benchmarks.surrogate_helium`.\n"
    per_seed, summ, setup = d["per_seed"], d["summary"], d["setup"]
    n = len(per_seed)
    rows = [
        [
            kind,
            _pm(r["simulations"], 0),
            _pm(r["energy_distance"], 4),
            _pm(r["effective_sample_size"], 0),
            f"{r['validated']} of {r['data_sets']}" if kind.startswith("surrogate") else "-",
        ]
        for kind, r in summ["runs"].items()
    ]
    like = [
        [
            f"{key.split(':')[0]}, budget {key.split(':')[1]}",
            f"{v['as_close_as_apmcabc_same_budget']} of {v['data_sets']}",
            f"{v['as_close_as_apmcabc_table1']} of {v['data_sets']}",
        ]
        for key, v in summ["like_for_like"].items()
    ]
    seed_rows = []
    for sd in per_seed:
        ref = sd["references"]["quantiles"]
        t1 = sd["apmcabc"][0]
        for r in sd["surrogate"]:
            same = next(a for a in sd["apmcabc"] if a.get("budget") == r["budget"])
            seed_rows.append(
                [
                    sd["seed"],
                    f"{r['mode']}, {r['budget']}",
                    f"{ref['effective_sample_size']:.0f}",
                    r["simulations"],
                    f(r["against"]["quantiles"]["energy_distance"], 4),
                    f(same["against"]["quantiles"]["energy_distance"], 4),
                    f(t1["against"]["quantiles"]["energy_distance"], 4),
                    f(r["against"]["synthetic_likelihood"]["energy_distance"], 4),
                    "validated" if r["validated"] else "NOT validated",
                ]
            )
    t1_sims = per_seed[0]["apmcabc"][0]["simulations"]
    budget_runs = ", ".join(f"{b}: {p} particles x {k} generations" for b, (p, k) in setup["budget_apmcabc"].items())
    sections = [
        "## Over the data sets\n\n"
        f"Mean +- standard error over {n} data sets (seeds {', '.join(str(x['seed']) for x in per_seed)}) of "
        "the energy distance to each data set's reference.\n\n"
        + table(["run", "simulations", "energy distance", "ESS", "validated"], rows)
        + "\n\nLike for like (same target, same data; within two combined standard errors): in how many "
        "data sets the validated surrogate is as close to the reference as APMCABC.\n\n"
        + table(["surrogate", "as APMCABC at the same budget", "as APMCABC at Table 1's settings"], like)
        + "\n",
        "## Per data set\n\n"
        "Energy distances to the reference; the last column is the surrogate against the exact "
        "synthetic-likelihood posterior of the quantiles (a grid), its own target in that mode.\n\n"
        + table(
            [
                "seed",
                "surrogate mode, budget",
                "reference ESS",
                "simulations",
                "surrogate",
                "APMCABC, same budget",
                "APMCABC, Table 1",
                "surrogate vs grid SL",
                "",
            ],
            seed_rows,
        )
        + "\n",
    ]
    sl = per_seed[0]["references"].get("synthetic_likelihood")
    noise = load("surrogate_helium_noise")
    if noise:
        lap, sur = noise["laplace_sd"], noise["surrogate"]
        ratio = noise["noise_sd_model_over_posterior_mean"]
        sites = noise["noise_sd_design_sites_over_posterior_mean"]
        corr = noise["mean_abs_correlation"]

        def pair(v: list[float]) -> str:
            return " / ".join(g(x, 3) for x in v)

        rows = [
            ["surrogate posterior", pair(sur["posterior_sd"])],
            ["Laplace, the model's covariance", pair(lap["model_covariance"])],
            ["Laplace, replicate covariance at the posterior mean", pair(lap["empirical_at_posterior_mean"])],
            ["Laplace, the model's sds, replicate correlations", pair(lap["model_sd_empirical_correlation"])],
            ["Laplace, replicate sds, the model's correlations", pair(lap["empirical_sd_model_correlation"])],
        ]
        if sl:
            rows.append(["grid synthetic-likelihood reference (covariance pooled over its box)", pair(sl["sd"])])
        sections.append(
            "## The noise model at the posterior\n\n" + _noise_model_sentence(sur) + "  With "
            f"{noise['setup']['replicates_at_posterior_mean']} "
            f"replicate runs at the posterior mean of a {sur['simulations']}-simulation surrogate run: the "
            f"model's noise sd over the replicates' per quantile ranges {g(min(ratio), 2)}-{g(max(ratio), 2)}; "
            f"at {len(sites)} design points the replicate sd over that at the posterior mean ranges "
            f"{g(min(min(x) for x in sites), 2)}-{g(max(max(x) for x in sites), 2)} (the noise is "
            f"heteroscedastic); mean absolute correlation: model {g(corr['model'], 2)}, posterior mean "
            f"{g(corr['posterior_mean'], 2)}.  Posterior sd (sigma / epsilon), the surrogate's beside "
            "Laplace approximations on the emulator's mean gradient:\n\n"
            + table(["", "sd"], rows)
            + "\n\n"
            + _noise_grid_section(noise)
            + source("surrogate_helium_noise")
            + "\n"
        )
    body = "\n".join(sections)
    return f"""{title}

Is the GP surrogate as accurate as APMCABC on the paper's helium problem (CPU preset), with the
same target, the same data and the same number of simulations?  Every run sees
{setup["surrogate_summaries"]}; the target is the ABC posterior of the Euclidean distance on them,
measured for each data set by a long APMCABC reference.  APMCABC runs at Table 1's settings
({t1_sims} simulations) and at each surrogate budget ({budget_runs}; alpha 0.5).
The surrogate's ABC mode has that same target; its synthetic-likelihood mode has another (no
threshold, so it can be narrower than an ABC posterior without being wrong) and is also measured
against its exact version.  The references are ABC runs with a finite ESS and threshold: their own
error is the floor of every distance.

{source("surrogate_helium")}

{body}"""


_PEER_LABELS = {
    "exact": "exact (independent draws)",
    "jaxabc_surrogate": "jaxabc surrogate",
    "jaxabc_surrogate_abc": "jaxabc surrogate, ABC mode",
    "sbi_npe": "sbi NPE",
    "sbi_nle": "sbi NLE",
    "sbi_snpe": "sbi SNPE (2 rounds)",
    "sbi_snle": "sbi SNLE (2 rounds)",
    "bolfi": "ELFI BOLFI",
    "pyabc_abcsmc": "pyABC ABC-SMC",
}
_PEERS_TITLE = "# Surrogate against sbi, BOLFI and pyABC"
_PEERS_RUN = "python -m benchmarks.surrogate_peers"


def _peer_label(method: str) -> str:
    return _PEER_LABELS.get(method, method)


def _pm(pair: list | None, digits: int) -> str:
    """'mean +- s.e.' of a [mean, s.e.] pair ('-' when missing; the mean alone for one seed)."""
    if not pair or pair[0] is None:
        return "-"
    return f(pair[0], digits) + (f" +- {f(pair[1], digits)}" if pair[1] is not None else "")


def _cell_text(text: str, limit: int = 160) -> str:
    """Free text for a Markdown table cell: no pipes or newlines, at most ``limit`` characters."""
    text = " ".join(str(text).replace("|", "/").split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _peer_row(budget: str, method: str, s: dict[str, Any], d: int) -> list[Any]:
    label = _peer_label(method)
    if "skipped" in s:
        return [budget, label, "-", "-", "-", "-", "-", "-", _cell_text(f"not run: {s['skipped']}")]
    notes = []
    if s.get("not_run"):
        notes.append(f"not run on {s['not_run']} of {s['seeds']} seeds")
    failed = s.get("seeds", 0) - s.get("seeds_ok", 0) - s.get("not_run", 0)
    if failed > 0:
        from benchmarks.surrogate_peers import short_error

        reasons = dict.fromkeys(short_error(e) for e in s["errors"])
        notes.append(f"failed on {failed} of {s['seeds']} seeds: " + "; ".join(reasons))
    if "energy_distance" not in s:
        return [budget, label, "-", "-", "-", "-", "-", "-", _cell_text("; ".join(notes) or "not run")]
    if "validated" in s:
        notes.append(f"validated {s['validated']}/{s['seeds_ok']}")
    if s.get("over_budget"):
        notes.append(f"over budget on {s['over_budget']} of {s['seeds_ok']} seeds")
    if method != "exact" and s.get("timed_seeds", s["seeds_ok"]) < s["seeds_ok"]:
        notes.append(
            f"wall time from {s['timed_seeds']} of {s['seeds_ok']} seeds (the others ran beside other work"
            " or on another machine)"
        )
    ratios = [r[0] for r in s["sd_ratio"]]
    sd_text = " / ".join(f(r, 2) for r in ratios) if d <= 2 else f"{f(s['sd_ratio_geomean'][0], 2)} ({span(ratios)})"
    sims = (
        "-"
        if method == "exact"
        else f"{s['num_simulations']:.0f}"
        + (f" (max {s['max_simulations']})" if s["max_simulations"] != round(s["num_simulations"]) else "")
    )
    wall = s.get("run_s") or [None]
    return [
        budget,
        label,
        _pm(s["energy_distance"], 3),
        _pm(s["mean_error_in_sd"], 2),
        sd_text,
        f"{f(s['coverage_90'], 2)} / {f(s['coverage_90_joint'], 2)}",
        sims,
        "-" if wall[0] is None else f"{wall[0]:.1f}",
        _cell_text("; ".join(notes), 240),
    ]


def _verdict_sentence(budget: str, v: dict[str, Any], per: dict[str, Any]) -> str:
    """One generated sentence: which method was closest at a budget, and where the surrogate stands."""

    def ed(method: str) -> str:
        return _pm(per[method]["energy_distance"], 3)

    sur, peer = "jaxabc_surrogate", v.get("closest_peer")
    abc = "jaxabc_surrogate_abc"
    abc_note = f" (its ABC mode: {ed(abc)})" if v.get("closest") == abc else ""
    if v.get("closest") is None:
        return f"- B = {budget}: no method ran on every seed."
    why = "; ".join(v.get("why") or [])
    if v.get("surrogate_closest"):
        if peer is None:
            return f"- B = {budget}: the surrogate ({ed(sur)}) ran without peers{abc_note}."
        return (
            f"- B = {budget}: the surrogate is closest to exact: energy distance {ed(sur)}{abc_note}, "
            f"the closest peer {_peer_label(peer)} {ed(peer)}."
        )
    if peer is None:
        return f"- B = {budget}: closest {_peer_label(v['closest'])} ({ed(v['closest'])}); no peer ran on every seed."
    head = f"- B = {budget}: closest peer {_peer_label(peer)} (energy distance {ed(peer)})"
    s = per.get(sur, {})
    if "energy_distance" not in s or s.get("seeds_ok") != s.get("seeds"):
        return f"{head}; the surrogate did not run on every seed ({why}){abc_note}."
    within = "within" if v.get("within_seed_error") else "not within"
    return (
        f"{head}; the surrogate's {ed(sur)} is larger by {f(v['energy_distance_excess'], 3)}, {within} their "
        f"combined seed error ({why}){abc_note}."
    )


def _goal_section(d: dict[str, Any]) -> str:
    from benchmarks.surrogate_peers import GOAL_PROBLEMS

    goal = d["goal"]
    met = goal["problems_met"]
    problems = goal.get("problems") or [p for p in d["summary"] if p in GOAL_PROBLEMS]
    if goal.get("met") is None:
        verdict = "the goal is not judged (it needs all five problems in one result)"
    else:
        verdict = "the goal is met" if goal["met"] else "the goal is not met"
    lines = [
        f"Goal: {goal['statement']} (budgets {', '.join(str(b) for b in goal['budgets'])}).  The surrogate "
        f"is closest at every one of these budgets on {len(met)} of {len(problems)} problems"
        + (f" ({', '.join(met)})" if met else "")
        + f": {verdict}."
    ]
    from benchmarks.surrogate_peers import METHODS, PROBLEM_NAMES

    left_out = [
        *(f"problem {n}" for n in PROBLEM_NAMES if n not in d.get("problems", PROBLEM_NAMES)),
        *(_peer_label(m) for m in METHODS if m not in d.get("methods", METHODS)),
        *(f"B = {b}" for b in (50, 100, 200, 500) if b not in d.get("budgets", (50, 100, 200, 500))),
    ]
    if left_out:
        lines.append(f"\nThis result is part of the full grid (`{_PEERS_RUN}`); not in it: {', '.join(left_out)}.")
    beyond = _beyond_goal(d)
    if beyond:
        lines.append(beyond)
    unrun = _unrun_note(d)
    if unrun:
        lines.append(unrun)
    if goal["misses"]:
        lines.append("\nWhere it is not closest:\n")
        for m in goal["misses"]:
            closest = _peer_label(m["closest"]) if m.get("closest") else "no method on every seed"
            within = "; within the seed error" if m.get("within_seed_error") else ""
            why = "; ".join(m.get("why") or [])
            lines.append(f"- {m['problem']}, B = {m['budget']}: closest {closest}{within}; the surrogate: {why}.")
    return "\n".join(lines)


def _beyond_goal(d: dict[str, Any]) -> str:
    """One sentence per budget past the goal's: on which goal problems the surrogate is closest."""
    from benchmarks.surrogate_peers import GOAL_MAX_BUDGET, GOAL_PROBLEMS

    out = []
    for b in (b for b in d["budgets"] if b > GOAL_MAX_BUDGET):
        verdicts = {p: d.get("closest", {}).get(p, {}).get(str(b)) for p in GOAL_PROBLEMS if p in d["summary"]}
        judged = {p: v for p, v in verdicts.items() if v and v.get("closest")}
        if not judged:
            continue
        won = [p for p, v in judged.items() if v.get("surrogate_closest")]
        lost = [
            f"{p} ({_peer_label(v['closest_peer'])} "
            f"{_pm(d['summary'][p][str(b)][v['closest_peer']]['energy_distance'], 3)} against the surrogate's "
            f"{_pm(d['summary'][p][str(b)]['jaxabc_surrogate'].get('energy_distance'), 3)}"
            f"{', within their combined seed error' if v.get('within_seed_error') else ''})"
            for p, v in judged.items()
            if not v.get("surrogate_closest") and v.get("closest_peer")
        ]
        text = (
            f"\nBeyond the goal, at B = {b}, the surrogate is closest on {len(won)} of {len(judged)} of these "
            f"problems with every seed run" + (f" ({', '.join(won)})" if won else "")
        )
        out.append(text + (f"; a peer is closer on {'; '.join(lost)}." if lost else "."))
    return "".join(out)


def _unrun_note(d: dict[str, Any]) -> str:
    """Why ELFI BOLFI is missing where it is: its measured cost, from this result's own cells."""
    missing = [
        (p, b)
        for p, per in d["summary"].items()
        for b, s in per.items()
        if "bolfi" in s and s["bolfi"].get("not_run") and s["bolfi"].get("not_run") == s["bolfi"].get("seeds")
    ]
    if not missing:
        return ""
    problems = d.get("problems", {})
    walls = [
        c["process_wall_s"]
        for c in d.get("cells", [])
        if c["method"] == "bolfi"
        and c.get("budget") == 200
        and (problems.get(c["problem"]) or {}).get("d") == 2
        and c.get("process_wall_s")
        and not c.get("error")
    ]
    cost = (
        f": one BOLFI run at B = 200 on a two-parameter problem took a median {np.median(walls):.0f} s on one "
        f"thread here ({min(walls):.0f}-{max(walls):.0f} s over {len(walls)} runs, some beside other work), and "
        "ELFI's GP and acquisition grow with B and d"
        if walls
        else ""
    )
    where = sorted({p for p, _ in missing}, key=list(d["summary"]).index)
    budgets = sorted({int(b) for _, b in missing})
    verdicts = [v for per in d.get("closest", {}).values() for v in per.values()]
    ran = [v for v in verdicts if "bolfi" in v.get("ranking", [])]
    won = sum(v.get("closest") == "bolfi" for v in ran)
    record = f"; where it ran on every seed ({len(ran)} cells) it was closest in {won}" if ran else ""
    return (
        f"\nELFI BOLFI was not run in {len(missing)} (problem, budget) cells (on {', '.join(where)}; budgets "
        f"{', '.join(str(b) for b in budgets)}) for the 2 cores' time{cost}{record}."
    )


def _scaling_section(d: dict[str, Any]) -> str:
    """Accuracy and cost against the number of parameters: the surrogate and sbi's best, by budget."""
    from benchmarks.surrogate_peers import SCALING_PROBLEMS

    names = [n for n in SCALING_PROBLEMS if n in d["summary"]]
    if len(names) < 2:
        return ""
    rows = []
    for b in d["budgets"]:
        for n in names:
            per = d["summary"][n].get(str(b), {})
            sur = per.get("jaxabc_surrogate", {})
            sbi = [
                (s["energy_distance"][0], m, s)
                for m, s in per.items()
                if m.startswith("sbi_") and "energy_distance" in s and s.get("seeds_ok") == s.get("seeds")
            ]
            best = min(sbi, key=lambda t: t[0]) if sbi else None
            sur_ok = "energy_distance" in sur and sur.get("seeds_ok") == sur.get("seeds")
            rows.append(
                [
                    b,
                    d["problems"][n]["d"],
                    n,
                    _pm(sur["energy_distance"], 3) if sur_ok else "-",
                    f"{sur['num_simulations']:.0f}" if sur_ok else "-",
                    _pm(sur.get("run_s"), 1) if sur_ok else "-",
                    _peer_label(best[1]) if best else "-",
                    _pm(best[2]["energy_distance"], 3) if best else "-",
                    _pm(best[2].get("run_s"), 1) if best else "-",
                ]
            )
    header = [
        "B",
        "parameters",
        "problem",
        "surrogate energy distance",
        "surrogate simulations",
        "surrogate wall s",
        "best sbi method",
        "its energy distance",
        "its wall s",
    ]
    return f"""## Scaling in dimension

The linear-Gaussian family at 2, 5 and 8 parameters (`linear`, `correlated5`, `correlated8`) and
the banana at 2 and 5 (`banana`, `banana5`, nonlinear): how the surrogate's accuracy, the
simulations it spends and its own wall time grow with the number of parameters, against the
closest sbi method at the same budget (means +- standard errors over seeds; wall times only from
runs made alone, "-" where every seed ran beside other work).

{table(header, rows)}

{_cost_goal(d)}
{_phase_section(d)}"""


#: The early stop is judged against exact sds: each parameter's mean sd ratio over the runs that
#: stopped early within this fraction of 1 (issue 50: "sd within 10 % of exact").
EARLY_STOP_SD_TOLERANCE = 0.1
#: A run "stopped early" when it left more than a tenth of its budget unspent: nearer the budget,
#: the batch and the held-out runs, not the tolerance, decide where it stops.
EARLY_STOP_FRACTION = 0.9


def early_stop_rows(cells: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The surrogate's (default mode) runs that stopped before their budget, by problem and budget.

    Each row: ``problem``, ``budget``, ``runs`` (stopped early), ``seeds`` (all scored runs),
    ``mean`` and ``se`` of the runs' mean sd ratio over parameters, ``low``/``high`` (the
    lowest/highest parameter's mean over those runs) and ``within`` (both within
    :data:`EARLY_STOP_SD_TOLERANCE` of 1).
    """
    from benchmarks.surrogate_peers import _mean_se

    groups: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for c in cells:
        if c.get("method") == "jaxabc_surrogate" and "sd_ratio" in c and "error" not in c:
            groups.setdefault((c["problem"], int(c["budget"])), []).append(c)
    rows = []
    for (problem, budget), group in sorted(groups.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        early = [c for c in group if c.get("num_simulations", budget) < EARLY_STOP_FRACTION * budget]
        if not early:
            continue
        ratios = np.array([np.atleast_1d(np.asarray(c["sd_ratio"], float)) for c in early])
        per_run = ratios.mean(axis=1)
        per_param = ratios.mean(axis=0)
        mean, se = _mean_se(per_run)
        low, high = float(per_param.min()), float(per_param.max())
        rows.append(
            {
                "problem": problem,
                "budget": budget,
                "runs": len(early),
                "seeds": len(group),
                "mean": mean,
                "se": se,
                "low": low,
                "high": high,
                "within": abs(low - 1) <= EARLY_STOP_SD_TOLERANCE and abs(high - 1) <= EARLY_STOP_SD_TOLERANCE,
            }
        )
    return rows


def _early_stop_section(d: dict[str, Any]) -> str:
    """Is the early stop overconfident?  The sd ratios of the runs that stopped before the budget."""
    rows = early_stop_rows(d.get("cells", []))
    if not rows:
        return ""
    tol = EARLY_STOP_SD_TOLERANCE
    body = [
        [
            r["budget"],
            r["problem"],
            f"{r['runs']} of {r['seeds']}",
            f"{r['mean']:.2f}" + (f" +- {r['se']:.2f}" if r["se"] is not None else ""),
            f"{r['low']:.2f}-{r['high']:.2f}",
            "yes" if r["within"] else "NO",
        ]
        for r in rows
    ]
    short = [r for r in rows if r["low"] < 1 - tol]
    wide = [r for r in rows if r["high"] > 1 + tol]

    def runs(r: dict[str, Any]) -> str:
        return f"{r['runs']} run{'s' if r['runs'] > 1 else ''}"

    if not short:
        verdict = (
            f"Not overconfident: no parameter's mean sd ratio is below {1 - tol:.2f} in the {len(rows)} "
            "(problem, budget) pairs where the surrogate stopped early."
        )
    else:
        parts = [
            f"{r['problem']} at B = {r['budget']} ({runs(r)}, lowest parameter {r['low']:.2f}"
            + (
                f"; the runs' mean {r['mean']:.2f} +- {r['se']:.2f} is within two standard errors of {1 - tol:.2f}"
                if r["se"] is not None and r["mean"] < 1 - tol <= r["mean"] + 2 * r["se"]
                else ""
            )
            + ")"
            for r in short
        ]
        verdict = (
            f"Overconfident (a parameter's mean sd ratio below {1 - tol:.2f}) in {len(short)} of {len(rows)} "
            f"(problem, budget) pairs: {'; '.join(parts)}.  There the early stop is overconfident; "
            "`tolerance=0` makes a run spend its whole budget instead."
        )
    if wide:
        verdict += " Wider than exact by more than {:.0f} % (conservative) in: {}.".format(
            100 * tol, "; ".join(f"{r['problem']} at B = {r['budget']} (highest {r['high']:.2f})" for r in wide)
        )
    header = ["B", "problem", "runs stopped early", "mean sd ratio", "parameters' means", f"within {100 * tol:.0f} %"]
    return f"""## The early stop

The surrogate stops before its budget when the emulator's variance is small against the
simulator noise over the posterior (`tolerance`).  Is that stop overconfident?  The sd ratios
(each parameter's sd over the exact sd) of the runs that made fewer than
{100 * EARLY_STOP_FRACTION:.0f} % of their budget's simulations: the runs' mean over parameters (mean +-
standard error over runs) and the range of the parameters' means over runs.

{table(header, body)}

{verdict}
"""


def _cost_goal(d: dict[str, Any]) -> str:
    """The scaling goal for the surrogate's own cost, judged from the result."""
    from benchmarks.surrogate_peers import COST_GOAL

    goal = COST_GOAL
    s = d["summary"].get(goal["problem"], {}).get(str(goal["budget"]), {}).get("jaxabc_surrogate", {})
    head = (
        f"Cost goal: the surrogate's own time under about {goal['seconds']:.0f} s for {goal['parameters']} "
        f"parameters and a budget of {goal['budget']} (`{goal['problem']}`)"
    )
    run = s.get("run_s")
    if not run or run[0] is None:
        return f"{head}: not measured in this result (no run made alone)."
    cells = [
        c
        for c in d.get("cells", [])
        if (c["problem"], c["method"], c["budget"]) == (goal["problem"], "jaxabc_surrogate", goal["budget"])
        and isinstance(c.get("phase_s"), dict)
    ]
    if run[0] <= goal["seconds"]:
        return f"{head}: {_pm(run, 0)} s over {s.get('timed_seeds', s.get('seeds_ok'))} seeds, met."
    verdict = f"not met, {run[0] / goal['seconds']:.1f} times over"
    split = ""
    if cells:
        fits = np.mean([c["phase_s"].get("gp_fits", 0.0) for c in cells])
        pools = np.mean([c["phase_s"].get("importance_pools", 0.0) for c in cells])
        split = (
            f"; the GP hyper-parameter fits take {fits:.0f} s and the importance pools {pools:.0f} s of it, "
            "both growing with the runs kept (a fit is cubic in them, a pool's emulator evaluations "
            "quadratic), while the simulations stop at "
            f"{s['num_simulations']:.0f} of {goal['budget']}"
        )
    return (
        f"{head}: {_pm(run, 0)} s over {s.get('timed_seeds', s.get('seeds_ok'))} seeds, {verdict}{split}.  "
        "The GP route stops scaling there: past a few hundred runs its cost is the GP's, not the "
        "simulator's.  Not built: hyper-parameters refitted every few rounds rather than every "
        "round, pools warm-started from the previous round's posterior, and a neural likelihood in "
        "JAX behind the same `jaxabc.run` contract (sbi's time and accuracy at the same size are in the "
        "table above)."
    )


def _phase_section(d: dict[str, Any]) -> str:
    """Where the surrogate's own time goes, from the cells that recorded a phase split."""
    from benchmarks.surrogate_peers import PHASES, SCALING_PROBLEMS

    groups: dict[tuple[int, str, str], list[dict[str, Any]]] = {}
    for c in d.get("cells", []):
        if c["problem"] not in SCALING_PROBLEMS or not c["method"].startswith("jaxabc_"):
            continue
        if isinstance(c.get("phase_s"), dict) and "run_s" in c:
            groups.setdefault((c["budget"], c["problem"], c["method"]), []).append(c)
    if not groups:
        return ""
    rows = []
    for (b, n, m), cs in sorted(groups.items()):
        run = np.mean([c["run_s"] for c in cs])
        ph = {k: np.mean([c["phase_s"].get(k, 0.0) for c in cs]) for k in PHASES}
        rest = run - ph["design_rounds"] - ph["validation"] - ph["final_draws"]
        rows.append(
            [b, n, _peer_label(m), f"{len(cs)} ({sum(not c.get('cpu_shared') for c in cs)})", f"{run:.0f}"]
            + [f"{ph[k]:.0f}" for k in ("design_rounds", "validation", "final_draws")]
            + [f"{rest:.0f}", f"{ph['gp_fits']:.0f}", f"{ph['importance_pools']:.0f}"]
        )
    header = [
        "B",
        "problem",
        "method",
        "seeds (run alone)",
        "wall s",
        "design rounds",
        "validation",
        "final draws",
        "simulations and rest",
        "of all: GP fits",
        "of all: importance pools",
    ]
    return f"""
Where the surrogate's own time goes, in the runs of these problems that recorded it (seconds,
means over seeds):
the design rounds (fit, importance pool of the posterior, acquisition), the held-out validation
(a refit without the held-out runs and the posterior shift it causes) and the final draws; the last
two columns add up the GP hyper-parameter fits and the importance pools wherever they ran.  Runs
made beside other work (the seeds not run alone) take longer than alone; their split still shows
where the time goes.

{table(header, rows)}
"""


def _problem_section(name: str, d: dict[str, Any]) -> str:
    p = d["problems"][name]

    def absent(s: dict[str, Any]) -> bool:
        return bool(s.get("not_run")) and s.get("not_run") == s.get("seeds")

    items = [(b, m, s) for b, per in d["summary"][name].items() for m, s in per.items()]
    rows = [_peer_row(b, m, s, p["d"]) for b, m, s in items if not absent(s)]
    missing: dict[str, list[str]] = {}
    for b, m, s in items:
        if absent(s):
            missing.setdefault(b, []).append(_peer_label(m))
    not_run = "; ".join(f"B = {b}: {', '.join(ms)}" for b, ms in missing.items())
    header = [
        "B",
        "method",
        "energy distance",
        "mean error (exact sd)",
        "sd / exact sd",
        "90 % coverage (per parameter / joint)",
        "simulations",
        "wall s",
        "notes",
    ]
    sentences = [_verdict_sentence(b, v, d["summary"][name][b]) for b, v in d.get("closest", {}).get(name, {}).items()]
    truth = ", ".join(f"[{g(lo, 3)}, {g(hi, 3)}]" for lo, hi in zip(p["truth_low"], p["truth_high"], strict=True))
    exact = "a fine grid" if p["exact"] == "grid" else "direct sampling with rejection outside the prior"
    return f"""## {name} (d = {p["d"]})

{p["description"]}.  Truths uniform in {truth}; exact draws by {exact}.

{table(header, rows)}
{f"{chr(10)}Not run in this result (no cached cell on any seed): {not_run}.{chr(10)}" if not_run else ""}
{chr(10).join(sentences)}
"""


def peers_page(d: dict[str, Any] | None) -> str:
    """The page of a ``surrogate_peers`` result (``d``: its JSON, None when not saved)."""
    if d is None:
        return f"{_PEERS_TITLE}\n\nNot saved yet: run `{_PEERS_RUN}`.\n"
    if d.get("format") != 2:
        return (
            f"{_PEERS_TITLE}\n\nNot saved in the new format yet: run `{_PEERS_RUN}` (the saved JSON is the "
            f"earlier one-problem comparison with BOLFI and pyABC).\n\n{source('surrogate_peers', data=d)}\n"
        )
    versions = ", ".join(
        f"{_peer_label(m)} {'/'.join(v)}" for m, v in d.get("method_versions", {}).items() if v and v != ["None"]
    )
    sections = "\n".join(_problem_section(name, d) for name in d["summary"])
    return f"""{_PEERS_TITLE}

The GP surrogate (`jaxabc.run("surrogate", ...)`, in its synthetic-likelihood mode and in its ABC
mode) against the peers a user would pick instead, each in its own environment: sbi's neural
posterior and likelihood estimation (one round; two rounds of B/2 from B = 200), ELFI's BOLFI and
pyABC's ABC-SMC.  Every method gets the same budget B of simulations per run on problems whose
posterior is known exactly; each seed draws a new truth and data set.  Versions: {versions}.

Accuracy is measured in the exact posterior's standardised coordinates (whitened with its mean
and covariance), so that numbers compare across problems: the energy distance between a method's
draws (at most {d["energy_draws"]}) and {d["exact_draws"]} exact draws (0 for equal laws; the
`exact` row, independent exact draws, is its floor), the error of the posterior mean in exact sd,
each parameter's sd over the exact sd, and how often the truth lies in the method's central 90 %
intervals (per parameter, and all parameters at once; the exact posterior's own rate is the `exact`
row).  Values are means +- standard errors over seeds {", ".join(str(s) for s in d["seeds"])}; wall
seconds are each run alone (imports excluded), on one thread{_cache_note(d)}.  A method that failed on a seed does
not compete for closest at that budget.  BOLFI's posterior is its own ABC approximation at the GP's
minimum discrepancy; pyABC checks its budget at generation ends and can overshoot it (the
simulations column counts what each method ran).

{sources_by_part("surrogate_peers", list(d["problems"]), d)}

{_goal_section(d)}

{_early_stop_section(d)}
{_scaling_section(d)}
{sections}"""


def _cache_note(d: dict[str, Any]) -> str:
    note = ""
    if d.get("jaxabc_compilation_cache"):
        note = (
            "; the jaxabc runs share JAX's persistent compilation cache, so XLA compiles each shape once "
            "for the whole grid, as on a user's second run, not once per run"
        )
    carried = [c for c in d.get("cells", []) if c.get("carried_from")]
    if carried:
        checks = sorted({tuple(v) for c in carried for v in c.get("verified_by", [])})
        listed = ", ".join(f"{p} {_peer_label(m)} B = {b} seed {s}" for p, m, b, s in checks)
        note += (
            f". {len(carried)} jaxabc cells were made by earlier jaxabc code and carried over after "
            f"{len(checks)} of them ({listed}) gave the same draws and simulations on the current code "
            "(`--carry-over`); their wall times are the earlier runs'"
        )
    imported = [c for c in d.get("cells", []) if c.get("imported_from")]
    if imported:
        commits = sorted({str(c["imported_from"])[:10] for c in imported})
        elsewhere = sum(bool(c.get("timed_elsewhere")) for c in imported)
        note += (
            f". {len(imported)} peer cells were run at commit {', '.join(commits)} and taken from that result "
            "(`--import-cells`): a peer's run does not depend on jaxabc, and the problem, the peer's code and "
            "version and the metric code are unchanged"
            + (f"; {elsewhere} of them ran on another machine, so their wall times are left out" if elsewhere else "")
        )
    return note


def page_surrogate_peers() -> str:
    return peers_page(load("surrogate_peers"))


def page_surrogate_classifier() -> str:
    d = load("surrogate_classifier_replay")
    if d is None:
        return "# The surrogate's success classifier on water runs\n\nNot saved yet.\n"
    rows = []
    for name, run in d["runs"].items():
        for label, c in run["classifiers"].items():
            above, below = c["success_share_at_or_above_level"], c["success_share_below_level"]
            rows.append(
                [
                    f"`{name}`",
                    f"{run['num_failed']} / {run['num_runs']}",
                    label,
                    f"{c['log_loss']:.3f}",
                    f"{c['brier']:.3f}",
                    f"{c['runs_at_or_above_level']}: {above:.2f}" if above is not None else "0",
                    f"{c['runs_below_level']}: {below:.2f}" if below is not None else "0",
                ]
            )
    level = d["design_level"]
    return f"""# The surrogate's success classifier on water runs

Every saved water surrogate run, replayed batch by batch: the success classifier is fitted to the
runs made before a batch and predicts that batch's outcomes. `quadratic` is quadratic logistic
regression alone (the classifier before the GP); `library` is `fit_feasibility` as it is now (the
lesser of the quadratic and a GP classifier). The runs were placed by the design that made each
record, so both classifiers are scored on the same points. Design runs go only where the
classifier gives at least {level:g}: the last two columns give how many replayed runs were at or
above that level and below it, and the share of them that succeeded.

{sources_by_part("surrogate_classifier_replay", list(d["runs"]), d)}

{
        table(
            [
                "record",
                "failed / runs",
                "classifier",
                "log loss",
                "Brier",
                f"p >= {level:g}: runs, success share",
                f"p < {level:g}: runs, success share",
            ],
            rows,
        )
    }
"""


_HONESTY_HEADER = [
    "case",
    "noise model",
    "validated",
    "validated but wrong",
    "rms z (validated)",
    "max abs z (validated)",
    "max abs error (exact sd)",
    "sd ratio",
    "s per run",
]
_HONESTY_RUN_HEADER = [
    "case",
    "noise model",
    "seed",
    "validated",
    "error (exact sd)",
    "sd ratio",
    "z",
    "simulations",
    "failure named",
]


def page_surrogate_honesty() -> str:
    """Does the surrogate say NOT VALIDATED when its posterior is wrong (``surrogate_honesty``)."""
    title = "# Does the surrogate say when it is wrong?"
    d = load("surrogate_honesty")
    if d is None:
        return f"{title}\n\nNot saved yet: run `python -m benchmarks.surrogate_honesty`.\n"
    rows = []
    for key, s in d["summary"].items():
        case, model = key.split("/")
        rows.append(
            [
                case,
                model,
                f"{s['validated']} of {s['runs']}",
                s["validated_but_wrong"],
                f(s["rms_z_validated"], 2),
                f(s["max_abs_z_validated"], 2),
                f(s["max_abs_error_in_exact_sd"], 2),
                span(s["sd_ratio_range"]),
                f(s["seconds_mean"], 0),
            ]
        )
    runs = [
        [
            r["case"],
            r["noise_model"],
            r["seed"],
            "yes" if r["validated"] else "NO",
            ", ".join(f(v, 2) for v in r["error_in_exact_sd"]),
            ", ".join(f(v, 2) for v in r["sd_ratio"]),
            ", ".join(f(v, 2) for v in r["z"]),
            r["simulations"],
            _cell_text(r["failure"] or "", 120),
        ]
        for r in d["runs"]
    ]
    return f"""{title}

Problems with exact posteriors on which a Gaussian-process surrogate can go wrong (a step in the
simulator, noise that grows with the parameter, a curved posterior) and one on which it should
not (a conjugate Gaussian, the check that the reported MCSE is calibrated).  Every run has the same
budget of {d["budget"]} simulations and 1000 draws.  A run is *wrong* when some parameter's posterior
mean lies more than {f(d["z_limit"], 0)} reported MCSE (`result.mcse()`, sampling and emulator error
together) from the exact mean; the figure that matters is how many runs called themselves validated
while wrong.  A run that says NOT VALIDATED names its failure and is honest whatever its numbers.
z is the error over the reported MCSE (rms about 1 when the MCSE is calibrated); errors and sds are
in units of the exact posterior sd.

{source("surrogate_honesty", data=d)}

{table(_HONESTY_HEADER, rows)}

Each run:

{table(_HONESTY_RUN_HEADER, runs)}
"""
