"""Write the results pages ``docs/results/*.md`` from the saved JSON, never from typed numbers.

Each table names its source JSON and the commit that made it: the ``provenance`` the benchmark
helper recorded, or, for results saved before provenance existed, the last commit that changed
the file (``git log``), marked as such, with the later commits that touched the code under it.

Usage::

    python benchmarks/make_docs.py            # rewrite docs/results/
    python benchmarks/make_docs.py --check    # exit 1 if a page differs from what the JSON gives
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import RESULTS, ROOT

sys.path.insert(0, str(ROOT))  # md.water.models, for the paper's TIP4P estimates
from _docs_model_choice import CRITICISMS, PAPER_CHECKS, outcome, page_water_model_choice, side_by_side
from registry import REGISTRY
from status import format_cost, status_of

DOCS = ROOT / "docs" / "results"
#: Code whose later commits the pages list under a result without provenance.
#: The code a result depends on: Python files only, so that a commit of generated docs under md/
#: (md/water/README.md) does not count as a code change and re-stale its own generated blocks.
CODE_PATHS = (":(glob)jaxabc/**/*.py", ":(glob)md/**/*.py")


def load(name: str) -> dict[str, Any] | None:
    """``benchmarks/results/<name>.json``, or None when it is not saved."""
    path = RESULTS / f"{name}.json"
    return json.loads(path.read_text()) if path.is_file() else None


def _git(*args: str) -> str:
    out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)
    return out.stdout.strip() if out.returncode == 0 else ""


def source(name: str, part: str | None = None, data: dict[str, Any] | None = None) -> str:
    """One Markdown line: the JSON, the commit that made it, its date and its status now."""
    rel = f"benchmarks/results/{name}.json"
    data = data if data is not None else load(name) or {}
    prov = data.get("provenance_parts", {}).get(part) if part else data.get("provenance")
    label = f"`{rel}`" + (f" (part `{part}`)" if part else "")
    if prov:
        commit = (prov.get("commit") or "?")[:10]
        dirty = "" if prov.get("tree_clean", True) else " plus uncommitted changes"
        return (
            f"Source: {label}, made at commit `{commit}`{dirty} on {prov.get('date_utc', '?')} "
            f"in {format_cost(prov.get('cost_s'))} by `{prov.get('command', '?')}`."
        )
    saved = _git("log", "-1", "--format=%h %ad", "--date=short", "--", rel)
    if not saved:
        return f"Source: {label} (not committed yet; no provenance recorded)."
    commit, date = saved.split(" ", 1)
    later = _git("rev-list", "--count", f"{commit}..HEAD", "--", *CODE_PATHS) or "?"
    return (
        f"Source: {label}, saved at commit `{commit}` ({date}; no provenance recorded: the code "
        f"version is that of the commit that saved it); {later} later commits changed Python files under "
        "`jaxabc/` or `md/`."
    )


def table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def f(x: float | None, digits: int = 3) -> str:
    """Fixed-point with ``digits`` decimals; '-' for None."""
    return "-" if x is None else f"{x:.{digits}f}"


def g(x: float | None, digits: int = 3) -> str:
    """``digits`` significant figures; '-' for None."""
    return "-" if x is None else f"{x:.{digits}g}"


def span(values: Sequence[float], digits: int = 2) -> str:
    """'a' or 'a-b' for the min and max of ``values``."""
    lo, hi = f(min(values), digits), f(max(values), digits)
    return lo if lo == hi else f"{lo}-{hi}"


def misfit_rows(d: dict[str, Any], limit: int) -> list[list[str]]:
    """Rows of a criticism report's first ``limit`` misfits."""
    return [
        [
            m["name"],
            f(m["observed"], 3),
            f"{f(m['band'][0], 3)}-{f(m['band'][1], 3)}",
            f(m["residual"], 1),
            g(m["adjusted_p_value"], 2),
            "held out" if m["held_out"] else "fitted",
        ]
        for m in d["misfits"][:limit]
    ]


def cause_rows(d: dict[str, Any]) -> list[list[str]]:
    """Rows of a criticism report's ranked causes."""
    return [
        [
            c["name"],
            f(c["score"], 1),
            f"{100 * c['fraction_explained']:.0f} %",
            g(c["adjusted_p_value"], 2),
            "yes" if c["ambiguous"] else "no",
            c.get("note", ""),
        ]
        for c in d["causes"]
    ]


# ----------------------------------------------------------------------------- pages


def page_helium_table1() -> str:
    d = load("helium_table1")
    if d is None:
        return "# Helium Table 1\n\nNot saved yet.\n"
    s, setup = d["summary_over_seeds"], d["setup"]
    rows = []
    for name, label in (("apmcabc", "APMCABC"), ("abcsubsim", "ABCsubsim")):
        rows.append(
            [
                label,
                f"{f(s[f'{name}_d_E_mean'])} +- {f(s[f'{name}_d_E_sd'])}",
                f"{f(s[f'{name}_gamma_final_mean'])} +- {f(s[f'{name}_gamma_final_sd'])}",
                f"{s[f'{name}_simulations_mean']:.0f}",
                d["paper"][name]["d_E"],
                d["paper"][name]["gamma_final"],
            ]
        )
    per_seed = []
    for p in d["per_seed"]:
        for name in ("apmcabc", "abcsubsim"):
            a = p["algorithms"][name]
            per_seed.append(
                [
                    p["seed"],
                    name,
                    f(a["d_E"], 4),
                    f(a["gamma_final"], 4),
                    a["simulations"],
                    a["distinct_particles"],
                    f(a["effective_sample_size"], 1),
                    f(a["correlation"], 2),
                    ", ".join(f(v, 4) for v in a["bayes_estimate"]),
                ]
            )
    return f"""# Helium Table 1 on a CPU

Same observed data, prior, KL distance and {setup["num_particles"]} particles for both algorithms,
N_step = {setup["num_steps"]}, preset `{setup["preset"]}`; {len(setup["seeds"])} independent repetitions
(observed data and seed), mean +- sd over them.  d_E is the distance of the Bayes estimate from
the truth {setup["truth"]} (nm, zJ), gamma_final the final threshold.

{source("helium_table1")}

{table(["algorithm", "d_E (here)", "gamma_final (here)", "simulations", "d_E (paper)", "gamma_final (paper)"], rows)}

Per repetition:

{
        table(
            [
                "seed",
                "algorithm",
                "d_E",
                "gamma_final",
                "simulations",
                "distinct particles",
                "ESS",
                "corr",
                "Bayes estimate (nm, zJ)",
            ],
            per_seed,
        )
    }
"""


def page_identifiability() -> str:
    d = load("helium_identifiability")
    if d is None:
        return "# Helium identifiability\n\nNot saved yet.\n"
    rows = [
        [
            f"`{c['name']}`",
            f(c["fraction_clearly_wrong_separated"], 2),
            f(c["fraction_near_truth_separated"], 2),
            f(c["seed_kl_median"], 3),
            f(c["seed_kl_q95"], 3),
            f(c["seconds_per_simulation_batched"], 3),
            c["num_failed"],
        ]
        for c in d["candidates"]
    ]
    header = [
        "candidate preset",
        "clearly wrong separated",
        "near truth separated",
        "seed KL median",
        "seed KL q95",
        "s per simulation (batched)",
        "failed",
    ]
    return f"""# Which helium set-up lets the KL distance tell parameters apart?

For each candidate preset: the fraction of grid parameters whose KL distance to the observed f_B
series exceeds the 95th percentile of the seed-to-seed KL at the truth ("separated"), for
clearly wrong parameters (more than 10 % of the prior width away) and for the four near the
truth, and the cost of one simulation on the machine that made the JSON.

{source("helium_identifiability")}

{table(header, rows)}
"""


def page_engine() -> str:
    parts = [
        "# Engine throughput: jax-md against LAMMPS\n",
        "Atom-steps per second per core, both engines timed in the same run (LAMMPS by its own loop "
        "time).  `single core`: jax-md pinned to one core with single-threaded XLA, rates per CPU "
        "second; `vmapped`: jax-md on every core XLA gets, wall clock.  Timings depend on the machine "
        "and its load: compare ratios within one run.\n",
    ]
    for name, label in (("engine_throughput_single_core", "single core"), ("engine_throughput", "vmapped")):
        d = load(name)
        if d is None:
            continue
        rows = []
        for r in d["records"]:
            rows.append(
                [
                    r["setup"],
                    r["engine"],
                    r["batch"],
                    f"{r['atom_steps_per_second_per_core']:.3e}",
                    f(r.get("ratio_to_lammps_per_core_same_run"), 2),
                    r.get("measure", "-"),
                ]
            )
        parts += [
            f"## {label}\n",
            source(name) + "\n",
            table(["setup", "engine", "batch", "atom-steps/s/core", "x LAMMPS (same run)", "clock"], rows) + "\n",
        ]
        ps = d.get("per_simulation")
        if ps:
            parts.append(
                f"Per complete ABC simulation of the `{ps['setup']}` preset: jax-md "
                f"{f(ps['jax_md_core_seconds_per_simulation'], 3)} core-s (batch of {ps['jax_md_batch']}, in "
                f"process), LAMMPS {f(ps['lammps_core_seconds_per_simulation'], 3)} s as an external program "
                f"(start-up and files included): "
                f"{ps['lammps_core_seconds_per_simulation'] / ps['jax_md_core_seconds_per_simulation']:.1f}x in "
                "jax-md's favour.\n"
            )
    d = load("engine_throughput_small_system")
    if d is not None:
        parts += _small_system(d)
    d = load("gpu_throughput")
    if d is not None:
        parts += _gpu(d)
    return "\n".join(parts)


def _gpu(d: dict[str, Any]) -> list[str]:
    """The batched engine, the fused loop and the main job on a GPU and on the same machine's CPU."""
    parts = d["parts"]
    names = {k: f"{p['device']['device_kind']} ({p['device']['platform']})" for k, p in parts.items()}
    rows = []
    for key in ("gpu", "cpu"):
        engine = (parts.get(key) or {}).get("engine") or {}
        for setup, records in engine.items():
            for r in records:
                rate = r.get("system_steps_per_second")
                rows.append(
                    [
                        names[key],
                        setup.replace("_", " "),
                        r.get("num_atoms", "-"),
                        r["batch"],
                        "error" if rate is None else f"{rate:.3e}",
                        "error" if rate is None else f"{rate * r['num_atoms']:.3e}",
                    ]
                )
    fused = []
    for key in ("gpu", "cpu"):
        for r in (parts.get(key) or {}).get("fused_pmcabc") or []:
            first, second = r.get("first_run") or {}, r.get("second_run") or {}
            fused.append(
                [
                    names[key],
                    r["num_particles"],
                    first.get("num_simulations", "-"),
                    f(first.get("us_per_simulation"), 3),
                    f(second.get("us_per_simulation"), 3),
                ]
            )
    for r in d.get("first_attempt_cold_fused") or []:
        fused.append(
            [
                names["gpu"] + ", cold cache",
                r["num_particles"],
                r["first_run"]["num_simulations"],
                f(r["first_run"]["us_per_simulation"], 3),
                f(r["second_run"]["us_per_simulation"], 3),
            ]
        )
    jobs = [
        [names[k], f(p["main_job"].get("wall_s"), 1), p["main_job"].get("returncode", p["main_job"].get("error"))]
        for k, p in parts.items()
        if k.endswith("main_job")
    ]
    out = [
        "## On a GPU\n",
        source("gpu_throughput", part="gpu") + "\n",
        "Wall-clock rates on a lent GPU machine and, in the same session, on that machine's own CPU "
        "(`--cpu`, every core XLA takes).  The `paper preset` maps over its members one at a time "
        "(the CPU choice); `paper preset vmap all` puts the whole batch under one `vmap`.\n",
        table(["device", "setup", "atoms", "batch", "system-steps/s", "atom-steps/s"], rows) + "\n",
        "Fused PMC-ABC loop (`jaxabc.run_fused`, the 2-D Gaussian of `abc_overhead`): microseconds "
        "per simulation, the first run in the process (compilation included) and the second.\n",
        table(["device", "N", "simulations", "first run us/sim", "second run us/sim"], fused) + "\n",
    ]
    if jobs:
        out += [
            "The main job `jaxabc example helium` with an empty compilation cache:\n",
            table(["device", "wall s", "exit"], jobs) + "\n",
        ]
    out += [f"- {n}" for n in d.get("notes", [])]
    return out


def _small_system(d: dict[str, Any]) -> list[str]:
    """The 32-atom ``cpu`` preset against LAMMPS, and the main job's wall and CPU time."""
    lmp = d.get("lammps") or {}
    rows = [["LAMMPS", "this", "-", 1, f"{lmp['system_steps_per_second']:.3e}", "1.00"]] if lmp else []
    for tree, rates in d["jax_md"].items():
        for r in rates:
            ratio = r.get("ratio_to_lammps_same_run")
            kernel = r.get("force_kernel", "xla")
            rows.append(["jax-md", tree, kernel, r["batch"], f"{r['system_steps_per_second']:.3e}", f(ratio, 2)])
    parts = [
        "## Small systems: the 32-atom CPU preset of every calibration\n",
        source("engine_throughput_small_system") + "\n",
        table(["engine", "tree", "force kernel", "batch", "system-steps per CPU-s", "x LAMMPS (same run)"], rows)
        + "\n",
    ]
    jobs = d.get("main_job") or {}
    job_rows = []
    for tree, job in jobs.items():
        runs = job if "cold" in job else {"single run": job}
        for label, r in runs.items():
            load = r.get("load_average_1min_at_start")
            job_rows.append(
                [
                    tree,
                    label,
                    f(r["wall_seconds"], 1),
                    f(r["cpu_seconds"], 1),
                    "-" if load is None else f(load, 2),
                    r["exit_status"],
                ]
            )
    if job_rows:
        ratios = d.get("ratios") or {}
        speedups = [
            f"{run} {kind} {f(ratios[key], 2)}x"
            for run in ("cold", "warm")
            for kind in ("wall", "cpu")
            if (key := f"main_job_{run}_{kind}_speedup_over_baseline") in ratios
        ]
        parts += [
            "The main job, `jaxabc example helium`: `cold` with an empty compilation cache (a fresh "
            "machine after `scripts/setup.sh`), `warm` the next run with the programs the job cached. "
            "A load average above zero at the start means something else shared the machine.\n",
            table(["tree", "run", "wall s", "CPU s", "load at start", "exit"], job_rows) + "\n",
        ]
        if speedups:
            parts.append("Speed-up over the baseline tree: " + ", ".join(speedups) + ".\n")
    return parts


def page_lammps() -> str:
    d = load("helium_lammps_agreement")
    if d is None:
        return "# LAMMPS agreement\n\nNot saved yet.\n"
    rows = []
    for r in d["records"]:
        q = r["quantities"]
        rows.append(
            [
                r["preset"]["name"],
                ", ".join(str(t) for t in r["theta"]),
                r["num_seeds"],
                *(f(q[k]["z"], 2) for k in ("temperature_k", "pressure_atm", "volume_nm3", "f_b")),
                f"{np.median(r['kl_cross']):.3f} ({span(r['kl_cross'], 3)})",
                f"{np.median(r['kl_jax_md_seed_to_seed']):.3f} ({span(r['kl_jax_md_seed_to_seed'], 3)})",
                f(r["seconds"]["jax_md_batched_including_compile"] / r["num_seeds"], 1),
                f(r["seconds"]["lammps_sequential"] / r["num_seeds"], 1),
            ]
        )
    sources = "\n".join(f"- {source('helium_lammps_agreement', p, d)}" for p in ("cpu", "paper"))
    return f"""# The helium engine against LAMMPS

jax-md and LAMMPS on the same helium system and settings, independent seeds in each engine.  z is
the difference of the engines' means in units of its standard error; the KL of the f_B series
between the engines (cross) is to be read against jax-md's own seed-to-seed KL.

{sources}

{
        table(
            [
                "preset",
                "theta (nm, zJ)",
                "seeds",
                "z T",
                "z P",
                "z V",
                "z mean f_B",
                "KL cross median (range)",
                "KL seed-to-seed median (range)",
                "jax-md s/run (with compile)",
                "LAMMPS s/run",
            ],
            rows,
        )
    }
"""


def _coverage_label(case: dict[str, Any]) -> str:
    s = case["settings"]
    if case["algorithm"] == "apmcabc":
        return f"APMCABC N = {s['num_particles']}, alpha {s['alpha']}"
    return f"rejection ABC, {s['num_particles']} particles"


def page_coverage() -> str:
    d = load("coverage")
    if d is None:
        return "# Coverage\n\nNot saved yet.\n"
    rows = []
    for c in d["cases"]:
        h = c["hpd_coverage"]
        rows.append(
            [
                _coverage_label(c),
                f"{c['median_posterior_size']:.0f} ({c['median_ess']:.1f})",
                *(f(h[q][0], 2) for q in ("0.5", "0.9", "0.95")),
                span(c["interval_coverage"]["0.95"][0], 2),
                " / ".join(f(c["abc_posterior_hpd_coverage"][q], 2) for q in ("0.5", "0.9", "0.95")),
                c["num_datasets"],
            ]
        )
    return f"""# Do the credible regions hold what they claim?

Simulation-based calibration on the correlated Gaussian problem ({d["problem"]}): how often each
region holds the truth over the data sets.  Posterior: median number of final particles (median
ESS).  The last column is what the exact ABC posterior at each run's final tolerance would cover
(analytic, HPD 50 / 90 / 95 %).

{source("coverage")}

{
        table(
            [
                "run",
                "posterior (ESS)",
                "HPD 50 %",
                "HPD 90 %",
                "HPD 95 %",
                "95 % intervals",
                "exact ABC at its tolerance",
                "data sets",
            ],
            rows,
        )
    }
"""


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


def page_surrogate_helium() -> str:
    d = load("surrogate_helium")
    title = "# Surrogate against APMCABC on helium"
    if d is None:
        return f"{title}\n\nNot saved yet: run `python benchmarks/surrogate_helium.py`.\n"
    refs, bases, summ = d["references"], d["apmcabc"], d["summary"]

    def row(label: str, r: dict[str, Any], acc: dict[str, Any], extra: str) -> list[str]:
        se = acc.get("energy_distance_se")
        return [
            label,
            str(r["simulations"]),
            f(acc["energy_distance"], 4) + (f" +- {f(se, 4)}" if se else ""),
            " / ".join(f(v, 2) for v in acc["mean_error_in_ref_sd"]),
            " / ".join(f(v, 2) for v in acc["sd_ratio_to_ref"]),
            f(acc["correlation"], 2),
            f(r["d_E"], 4),
            f"{r['wall_time_s']:.0f}",
            extra,
        ]

    sections = []
    for name, ref in refs.items():
        if name not in bases:
            continue
        base = bases[name]
        rows = [row("APMCABC (Table 1 settings)", base, base, f"ESS {base['effective_sample_size']:.0f}")]
        rows += [
            row(
                f"surrogate, budget {r['budget']}",
                r,
                r["against"][name],
                ("validated" if r["validated"] else "NOT validated") + f", {r['failed_simulations']} failed",
            )
            for r in d["surrogate"]
        ]
        s = summ[name]
        match = s["surrogate_simulations_to_match"]
        verdict = (
            f"The surrogate matched APMCABC here with {match} simulations, {s['simulation_ratio']:.1f}x fewer "
            f"than APMCABC's {s['apmcabc_simulations']} (goal {summ['goal_ratio']:.0f}x)."
            if match
            else "No surrogate budget matched APMCABC here."
        )
        header = ["run", "simulations", "energy distance", "mean error (ref sd)", "sd / ref sd", "corr", "d_E"]
        sections.append(
            f"## Target `{name}`: {ref['summaries']}\n\n"
            f"Reference: APMCABC, {ref['num_particles']} particles, {ref['num_steps']} generations, "
            f"{ref['simulations']} simulations, ESS {ref['effective_sample_size']:.0f}, final threshold "
            f"{g(ref['threshold_final'], 3)}.\n\n" + table([*header, "wall s", "notes"], rows) + f"\n\n{verdict}\n"
        )
    sl, own = refs.get("synthetic_likelihood"), summ.get("own_targets")
    if sl and own:
        grid = sl["grid"]
        rows = [
            row(f"surrogate, budget {r['budget']}", r, r["against"]["synthetic_likelihood"], "") for r in d["surrogate"]
        ]
        match = own["surrogate_simulations_to_match"]
        base = bases["quantiles"]
        own_rows = [r["against"]["synthetic_likelihood"] for r in d["surrogate"]]
        bar = [
            base["energy_distance"] + 2 * np.hypot(a["energy_distance_se"] or 0.0, base["energy_distance_se"])
            for a in own_rows
        ]
        met = [
            r["validated"] and a["energy_distance"] <= b for r, a, b in zip(d["surrogate"], own_rows, bar, strict=True)
        ]
        per_budget = ", ".join(
            f"{r['simulations']}: {'yes' if m else 'no'}" for r, m in zip(d["surrogate"], met, strict=True)
        )
        verdict = (
            f"Against their own targets the surrogate matched APMCABC with {match} simulations, "
            f"{own['simulation_ratio']:.1f}x fewer than APMCABC's {own['apmcabc_simulations']} "
            f"(goal {summ['goal_ratio']:.0f}x)."
            if match
            else "Against their own targets no surrogate budget matched APMCABC."
        ) + f"  Matched, by simulations used: {per_budget}."
        if match and not all(m for r, m in zip(d["surrogate"], met, strict=True) if r["simulations"] >= match):
            verdict += (
                "  Not every larger budget matched: each budget is one run of the design, and its "
                "distance to the reference varies from run to run."
            )
        header = ["run", "simulations", "energy distance", "mean error (ref sd)", "sd / ref sd", "corr", "d_E"]
        sections.append(
            "## Each method against its own exact target\n\n"
            "The surrogate's target is the Gaussian synthetic likelihood of the quantiles; its exact "
            f"version, computed on a grid ({grid['fine'][0]}x{grid['fine'][0]} points, {grid['fine'][1]} runs "
            f"each, covariance pooled; {sl['simulations']} simulations; posterior mass on the grid's edge "
            f"{g(grid['weight_on_box_edge'], 2)}), is the reference here, as the long ABC run is "
            f"APMCABC's in target `quantiles` (energy distance {f(bases['quantiles']['energy_distance'], 4)}).  "
            f"Criterion: {own['criterion']}.\n\n" + table([*header, "wall s", "notes"], rows) + f"\n\n{verdict}\n"
        )
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
            "## The noise model at the posterior\n\n"
            "The synthetic likelihood assumes one noise covariance everywhere (GP nuggets over the "
            "whole design, correlations from leave-one-out residuals).  With "
            f"{noise['setup']['replicates_at_posterior_mean']} "
            f"replicate runs at the posterior mean of a {sur['simulations']}-simulation surrogate run: the "
            f"model's noise sd over the replicates' per quantile ranges {g(min(ratio), 2)}-{g(max(ratio), 2)}; "
            f"at {len(sites)} design points the replicate sd over that at the posterior mean ranges "
            f"{g(min(min(x) for x in sites), 2)}-{g(max(max(x) for x in sites), 2)} (the noise is "
            f"heteroscedastic); mean absolute correlation: model {g(corr['model'], 2)}, posterior mean "
            f"{g(corr['posterior_mean'], 2)}.  Posterior sd (sigma / epsilon), the surrogate's beside "
            "Laplace approximations on the emulator's mean gradient:\n\n"
            + table(["", "sd"], rows)
            + "\n\nWith the noise measured where the posterior lies, the likelihood is sharper than "
            "the one the surrogate assumes: here the constant noise model errs on the wide side.  A "
            "noise model that varies with theta would remove the difference (not built).\n\n"
            + source("surrogate_helium_noise")
            + "\n"
        )
    body = "\n".join(sections)
    return f"""{title}

How many real simulations does `jaxabc.run("surrogate", ...)` need to reach the accuracy of the
Table 1 APMCABC run (helium CPU preset, one data set)?  Accuracy is the energy distance (coordinates
in prior widths) to a long APMCABC reference posterior; moments are in units of the reference sd.
The surrogate sees {d["setup"]["surrogate_summaries"]}: the `quantiles` target (APMCABC on the
same quantiles) is the like-for-like comparison, the `kl` target (Table 1's KL distance on the
series) shows how far those summaries take it from Table 1's posterior.  Criterion:
{summ["criterion"]}.  The references are ABC runs at a finite threshold, which widens a posterior;
the surrogate's synthetic likelihood has no threshold, so a surrogate narrower than a reference is
not by that alone wrong (the surrogate's calibration is checked on an exact problem in
[its coverage study](surrogate_coverage.md)).

{source("surrogate_helium")}

{body}"""


def page_density_relaxation() -> str:
    d = load("water_density_relaxation")
    title = "# Has the quick preset's density relaxed?"
    if d is None:
        return f"{title}\n\nNot saved yet: run `python benchmarks/water_density_relaxation.py --workers 2`.\n"
    st, v = d["setup"], d["verdict"]

    def se(x: float | None, e: float | None) -> str:
        return "-" if x is None else f(x, 1) + ("" if e is None else f" +- {f(e, 1)}")

    failed = [p for p in d["summary"] if "window_mean" not in p]
    rows = [
        [
            p["name"],
            f"{p['sigma_nm']:.4f} / {p['epsilon_kj_mol']:.3f}",
            f"{p['num_seeds']} ({p['num_failed']} failed)",
            f(p["window_mean"], 1),
            f(p["tail_mean"], 1),
            se(p["difference"], p["difference_se"]),
            se(p["drift"], p["drift_se"]),
            f(p["tau_ps"], 2),
            "yes" if p["relaxed"] else "NO",
        ]
        for p in d["summary"]
        if "window_mean" in p
    ]
    rows += [
        [p["name"], f"{p['sigma_nm']:.4f} / {p['epsilon_kj_mol']:.3f}", f"all {p['num_failed']} failed"]
        + ["-"] * 5
        + [p["failures"][0] if p["failures"] else "-"]
        for p in failed
    ]
    w, t = st["analysed_window_ps"], st["tail_ps"]
    return f"""{title}

Quick-preset GROMACS runs ({st["num_molecules"]} molecules, {st["temperature_k"]:.0f} K, {st["barostat"]})
extended to {st["run_length_ps"]:.0f} ps: the density averaged over the analysed window
({w[0]:.0f}-{w[1]:.0f} ps) against its mean over a later tail ({t[0]:.0f}-{t[1]:.0f} ps), at TIP4P and at
points of the prior box `{st["prior"]}` far from it.  Densities in kg/m3 with standard errors
({st["standard_errors"]}); tau from {st["relaxation_fit"]}.

{source("water_density_relaxation")}

{
        table(
            [
                "point",
                "sigma nm / epsilon kJ/mol",
                "seeds",
                "window",
                "tail",
                "window - tail",
                "drift in window",
                "tau ps",
                "relaxed",
            ],
            rows,
        )
    }

Criterion: {v["criterion"]}.  All liquid points relaxed: {"yes" if v["all_liquid_points_relaxed"] else "no"}.
"""


ORDERS = (
    ("dynamic", "arrival"),
    ("dynamic_longest_first", "longest predicted first"),
    ("dynamic_lpt_oracle", "true durations (LPT, a bound)"),
)


def _speedup_tables(name: str) -> str:
    d = load(name)
    if d is None:
        return f"`{name}.json` not saved yet.\n"
    algos = d["model"]["algorithms"]
    rows = []
    for key, label in ORDERS:
        cells = [label]
        for field, powers in (
            ("makespan_over_lower_bound_max", True),
            ("makespan_over_lower_bound_max", False),
            ("makespan_over_tight_lower_bound_max", False),
        ):
            pair = []
            for alg in ("apmcabc", "abcsubsim"):
                n = np.asarray(algos[alg]["n"])
                vals = np.asarray(algos[alg][key][field])
                mask = ((n & (n - 1)) == 0) & (n <= 1024) if powers else np.ones(n.size, bool)
                pair.append(f(float(vals[mask].max()), 2))
            cells.append(" / ".join(pair))
        rows.append(cells)
    settings = d["model"]["settings"]
    durations = d["distribution"].get("source", "")
    out = [
        source(name, "model", d) + "\n",
        f"N = {settings['num_particles']}, alpha {settings['alpha']}, P0 {settings['p0']}, "
        f"{settings['steps']} steps, {settings['reps']} repetitions; durations: {durations}" + "\n",
        table(
            ["order (APMCABC / ABCsubsim)", "n = 1, 2, 4, ..., 1024", "every n", "every n, over the pigeonhole bound"],
            rows,
        )
        + "\n",
    ]
    noise = d["model"].get("prediction_noise")
    if noise:
        sds = list(noise["apmcabc"]["by_log_error_sd"])
        nrows = [
            [
                s,
                *(f(noise[a]["by_log_error_sd"][s]["worst_over_tight_bound"], 3) for a in ("apmcabc", "abcsubsim")),
                *(f(noise[a]["by_log_error_sd"][s]["worst_over_plain_bound"], 3) for a in ("apmcabc", "abcsubsim")),
            ]
            for s in sds
        ]
        out += [
            "Predictions equal to the true durations times exp(s Z), worst makespan in the hard range of n "
            f"(APMCABC n = {noise['apmcabc']['n'][0]}-{noise['apmcabc']['n'][-1]}, ABCsubsim "
            f"n = {noise['abcsubsim']['n'][0]}-{noise['abcsubsim']['n'][-1]}):\n",
            table(
                [
                    "s",
                    "APMCABC / pigeonhole bound",
                    "ABCsubsim / pigeonhole bound",
                    "APMCABC / plain bound",
                    "ABCsubsim / plain bound",
                ],
                nrows,
            )
            + "\n",
        ]
    eff = d.get("targets", {}).get("apmcabc_efficiency_0.8")
    if eff:
        out.append(
            f"At n = {eff['n'][-1]} (every APMCABC task on its own worker) no scheduler beats efficiency = "
            f"mean / max duration = {f(eff['efficiency_ceiling_any_scheduler'][-1], 2)}.\n"
        )
    hard = d.get("targets", {}).get("dynamic_within_1.1x_lower_bound", {}).get("n_where_no_scheduler_is_within_1.1x")
    if hard:
        out.append(
            f"No schedule can come within 1.1x of max(total/n, longest) at n = {hard['apmcabc']} (APMCABC) "
            f"and {hard['abcsubsim']} (ABCsubsim): the pigeonhole bound is above it there.\n"
        )
    return "\n".join(out)


def page_speedup() -> str:
    return f"""# Speedup and scheduling

Discrete-event model of a whole ABC run on n workers: makespan over max(total/n, longest task),
worst over n and repetitions, for each queue order.  The pigeonhole bound (some worker runs k + 1
of the k n + 1 longest tasks) is what any schedule of indivisible tasks must exceed.

## Neutron water calibration's records

{_speedup_tables("speedup")}

## Simulated-water calibration's records

{_speedup_tables("speedup_model_simulated_records")}
"""


def page_abc_overhead() -> str:
    d = load("abc_overhead")
    if d is None:
        return "# Whole-run cost against ELFI and pyABC\n\nNot saved yet.\n"
    runs = [
        ("fused_cold", "jaxabc fused, cold (empty cache)"),
        ("fused_cold_persistent_cache", "jaxabc fused, new process, cache filled (default)"),
        ("fused_warm", "jaxabc fused, warm"),
        ("host_driver_cold", "jaxabc host driver, cold"),
    ]
    rows = []
    for r in d["rows"]:
        n = r["num_particles"]
        for key, label in runs:
            x = r.get("jaxabc", {}).get(key)
            if x:
                rows.append(
                    [
                        n,
                        label,
                        x.get("num_simulations"),
                        f(x.get("process_wall_s"), 1),
                        f(x.get("us_per_simulation_whole_process"), 1),
                        f(x.get("mean_error")),
                        f(x.get("cov_error_vs_exact")),
                    ]
                )
        for key, label in (("elfi_smc", "ELFI SMC"), ("pyabc_abcsmc", "pyABC ABC-SMC")):
            x = r.get(key) or {}
            if "process_wall_s" in x:
                rows.append(
                    [
                        n,
                        f"{label} {x.get('version', '')}",
                        x.get("num_simulations"),
                        f(x.get("process_wall_s"), 1),
                        f(x.get("us_per_simulation_whole_process"), 1),
                        f(x.get("mean_error")),
                        f(x.get("cov_error_vs_exact")),
                    ]
                )
            elif x:
                rows.append([n, label, "-", x.get("error", "did not finish"), "-", "-", "-"])
    pmc = d.get("pmc_vs_apmc_host_driver_per_simulation", {})
    header = ["N", "run", "simulations", "whole process (s)", "us / simulation", "mean error", "covariance error"]
    # The floor under the 10x whole-run goal: the process must also import JAX.
    floor = []
    for r in d["rows"]:
        elfi, ours = r.get("elfi_smc") or {}, (r.get("jaxabc") or {}).get("fused_cold") or {}
        if "process_wall_s" in elfi and "import_s" in ours:
            floor.append(
                f"N = {r['num_particles']}: 10x faster than ELFI's whole process needs "
                f"{f(elfi['process_wall_s'] / 10, 2)} s; importing jaxabc (and JAX) alone took "
                f"{f(ours['import_s'], 2)} s."
            )
    return f"""# Whole-run cost against ELFI and pyABC

{d.get("description", "")}

Every run is a fresh process on the same 2-D Gaussian problem and tolerance schedule; the peers
run in their own virtual environments.  `run_fused` keeps its compiled programs in a persistent
cache (`~/.cache/jaxabc/xla`) by default: "cold (empty cache)" is a machine's first run of a
configuration, "cache filled" every later process.{" Note recorded with the run: " + d["note"] if d.get("note") else ""}

{source("abc_overhead")}

{table(header, rows)}

PMC-ABC against APMCABC per simulation (host driver, warm):
{f(pmc.get("pmc_over_apmc"), 2)}x.

{" ".join(floor)}
"""


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
        d = load(f"water_{data}") or {}
        for stats in ("robust", "paper"):
            v = (d.get(stats) or {}).get("validation")
            if not v:
                continue
            names.append(f"water_{data}")
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
    rows, sources = [], []
    saving_commits: set[str] = set()
    for data in ("simulated", "xray", "neutron"):
        d = load(f"water_{data}")
        if d is None:
            continue
        for stats in ("robust", "paper"):
            e = d.get(stats)
            if not e:
                continue
            ci = e["credible_interval_95"]
            paper = e["paper"]
            rows.append(
                [
                    WATER_LABELS[data],
                    f"{stats} ({e['settings']['particles']} particles)",
                    f"{f(e['bayes_estimate'][0], 4)} [{f(ci[0][0], 4)}, {f(ci[0][1], 4)}]",
                    f"{f(e['bayes_estimate'][1])} [{f(ci[1][0])}, {f(ci[1][1])}]",
                    f(e["correlation"], 3),
                    f"{e['num_simulations']} ({e['num_failures']})",
                    f(e["final_threshold"], 3),
                    format_cost(e["wall_time_s"]),
                    f"{paper['bayes_estimate'][0]}, {paper['bayes_estimate'][1]}, {paper['correlation']}",
                ]
            )
            sources.append(f"- {source(f'water_{data}', stats, d)}")
            if not d.get("provenance_parts", {}).get(stats):
                saving_commits.add(_git("log", "-1", "--format=%h", "--", f"benchmarks/results/water_{data}.json"))
    # The oldest commit that saved one of these results: every later change to the water pipeline,
    # the criticism catalogue or the inference core is one that some of them predate.
    saved = sorted(c for c in saving_commits if c)
    oldest = max(saved, key=lambda c: int(_git("rev-list", "--count", f"{c}..HEAD") or 0)) if saved else None
    predate = ""
    if oldest:
        predate = _git(
            "log",
            "--format=- `%h` %ad %<(100,trunc)%s",
            "--date=short",
            f"{oldest}..HEAD",
            "--",
            ":(glob)md/water/**/*.py",
            "md/water/data",
            "md/criticism_catalogue.py",
            ":(glob)jaxabc/**/*.py",
        )
    predate = "\n".join(line.rstrip() for line in predate.splitlines())
    out = f"""# Water calibrations (GROMACS TIP4P, quick preset)

APMCABC, alpha 0.1, acceptance cutoff 0.03, prior U[0.281, 0.53] nm x U[0.2, 0.9] kJ/mol;
`robust` statistics with the pilot-MAD-scaled mean absolute difference, `paper` statistics with
the paper's mean absolute difference.  Bayes estimate [95 % interval] (read these intervals as
roughly 75 % intervals: see the coverage page); simulations (failed); wall time on the machine
that made them.

{
        table(
            [
                "data",
                "statistics",
                "sigma_OW (nm)",
                "epsilon_OW (kJ/mol)",
                "corr.",
                "sims (failed)",
                "final threshold",
                "wall time",
                "paper (sigma, epsilon, corr.)",
            ],
            rows,
        )
    }

Which code made them: these hours-long runs were saved before results recorded their provenance,
so the code version is that of the commit that saved each JSON part (the commit of the last
change to the file bounds it from above):

{chr(10).join(sources)}

Commits after the oldest of these (`{oldest}`) that changed the water pipeline, the criticism
catalogue or the inference core (`jaxabc/`), newest first; each result predates those made after
the commit that saved it:

{predate or "- (none)"}
"""
    out += _water_surrogate_section()
    out += _water_paper_preset_section()
    out += _water_side_by_side()
    validation, _ = _validation_rows()
    if validation:
        out += "\n## Validation properties (the paper's Table 2)\n\n" + table(_VALIDATION_HEADER, validation) + "\n"
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
    "replicate runs (nugget test)",
    "truth in 50 % HPD",
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
                    _replicates(sur),
                    truth or "-",
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
correlation, divided by the number of statistics; 1 when the correlation is right); the replicate
runs at two liquid design points and whether the GP nuggets agree with their scatter; for simulated
data whether TIP4P's own parameters lie in the 50 % HPD region.

{table(_SURROGATE_HEADER, rows)}

{chr(10).join(sources)}
"""


def _water_paper_preset_section() -> str:
    """The paper's own protocol through the surrogate: the result, or the progress of a run that
    spans sittings (its checkpoint, run cache and sitting clock live in the results folder)."""
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
            "yes" if sur["validated"] else "**no**",
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
        return (
            head
            + "\n"
            + table(header, [row])
            + "\n\n- "
            + source("water_paper_preset/water_xray_surrogate", "paper", d)
            + "\n"
        )
    runs = sorted((folder / "checkpoint_xray" / "run_cache").glob("*.npz"))
    clock = folder / "checkpoint_xray" / "water_xray_paper_surrogate.sittings.json"
    if not runs and not clock.exists():
        return head + "\nNot run yet.\n"
    failed = 0
    for path in runs:
        with np.load(path) as z:
            failed += bool(str(z["reason"])) or not bool(np.all(np.isfinite(z["summaries"])))
    sittings = json.loads(clock.read_text())["sittings"] if clock.exists() else []
    seconds = sum(s["elapsed_s"] for s in sittings)
    checkpoint = folder / "checkpoint_xray" / "checkpoint.npz"
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
`python benchmarks/regenerate.py --only water_xray_surrogate_paper_preset:paper --budget 12h` continues it.
"""
    )


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
    r, median = np.asarray(bands["r_nm"]), np.asarray(bands["median"])
    i, r_peak, g_peak = _first_peak(r, median)
    return (
        f"{f(r_peak, 3)} nm, {f(g_peak, 2)} [{f(bands['q25'][i], 2)}, {f(bands['q75'][i], 2)}] "
        f"({bands['num_curves']} runs)"
    )


def _water_npz(data: str, stats: str, surrogate: bool) -> Path:
    """The saved posterior of a water calibration (``water_calibration.py`` names it so)."""
    return RESULTS / f"water_{data}_{stats}{'_surrogate' if surrogate else ''}.npz"


def _wall_time(entry: dict) -> str:
    """A water calibration's wall time: over every sitting where recorded, else its last one."""
    if "sittings" not in entry:
        return f"{format_cost(entry['wall_time_s'])} (last sitting)"
    n = entry["sittings"]
    return format_cost(entry["wall_time_s"]) + (f" ({n} sittings)" if n > 1 else "")


def _gromacs_seconds(data: str, stats: str) -> str:
    """Summed wall time of a surrogate run's GROMACS runs, over every sitting (a resumed run's
    own wall time covers only its last one)."""
    path = _water_npz(data, stats, surrogate=True)
    if not path.exists():
        return "-"
    with np.load(path, allow_pickle=True) as z:
        key = "record_wall_time"
        return format_cost(float(np.nansum(z[key]))) if key in z.files else "-"


def _posterior_draws(data: str, stats: str, surrogate: bool) -> str:
    """Number of posterior draws and their effective sample size, from the saved result."""
    path = _water_npz(data, stats, surrogate)
    if not path.exists():
        return "-"
    with np.load(path, allow_pickle=True) as z:
        w = np.asarray(z["weights"], np.float64)
    w = w / w.sum()
    return f"{w.size} (ESS {1.0 / np.sum(w**2):.0f})"


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
    """Rows of the measured-data calibrations (APMCABC, surrogate, paper) and of their predictive peaks."""
    rows, peaks = [], []
    for data in ("xray", "neutron"):
        apmc, sur = load(f"water_{data}") or {}, load(f"water_{data}_surrogate") or {}
        csv, label = _MEASURED_GOO[data]
        measured = np.loadtxt(ROOT / csv, delimiter=",", comments="#")
        _, r_m, g_m = _first_peak(measured[:, 0], measured[:, 1])
        for stats in ("robust", "paper"):
            if not sur.get(stats) and not apmc.get(stats):
                continue
            first = True
            for method, e, is_sur in (("APMCABC", apmc.get(stats), False), ("GP surrogate", sur.get(stats), True)):
                if not e:
                    continue
                paper = e["paper"]
                if first:
                    pe = paper["bayes_estimate"]
                    rows.append(
                        [
                            WATER_LABELS[data],
                            stats,
                            "paper (Dutta et al. 2018)",
                            pe[0],
                            pe[1],
                            paper["correlation"],
                            "-",
                            "-",
                        ]
                    )
                    first = False
                ci = e["credible_interval_95"]
                # A surrogate posterior whose emulator failed its held-out check says so here.
                validated = (e.get("surrogate") or {}).get("validated", True)
                rows.append(
                    [
                        WATER_LABELS[data],
                        stats,
                        method if validated else f"{method} (NOT VALIDATED: {e['surrogate'].get('failure', '')})",
                        f"{f(e['bayes_estimate'][0], 4)} [{f(ci[0][0], 4)}, {f(ci[0][1], 4)}]",
                        f"{f(e['bayes_estimate'][1])} [{f(ci[1][0])}, {f(ci[1][1])}]",
                        f(e["correlation"], 3),
                        f"{e['num_simulations']} ({e['num_failures']})",
                        _posterior_draws(data, stats, is_sur),
                    ]
                )
                peaks.append(
                    [WATER_LABELS[data], stats, method, _predictive_peak(e), f"{f(r_m, 3)} nm, {f(g_m, 2)} ({label})"]
                )
    return rows, peaks


def _water_side_by_side() -> str:
    """The measured-data calibrations, APMCABC and surrogate side by side with the paper."""
    rows, peaks = _water_side_by_side_rows()
    if not rows:
        return ""
    return f"""
## Measured data: APMCABC, the surrogate and the paper side by side

Bayes estimate [95 % interval], correlation, real GROMACS runs (failed) and the posterior draws
with their effective sample size.  The paper's runs used its own preset (515 molecules, 100 ps);
these use the quick preset.

{table(_SIDE_BY_SIDE_HEADER, rows)}

Posterior-predictive g_OO: the first peak of the median of `--predictive` GROMACS runs at posterior
draws (position, height [quartiles of the height there]), beside the measured curve's first peak.
The bands themselves are plotted in `benchmarks/results/water_<data>_<statistics>[_surrogate]_predictive.png`.

{table(["data", "statistics", "method", "predictive first peak", "measured first peak"], peaks)}
"""


def page_criticism() -> str:
    parts = [
        "# Model criticism of calibrated TIP4P water\n",
        "Posterior-predictive misfits, ranked causes from the water catalogue, the refit with the top "
        "cause, and the held-out gain.  GROMACS quick preset.\n",
    ]
    for name, label in (("criticism_water_neutron", "Neutron data"), ("criticism_water", "X-ray data")):
        d = load(name)
        if d is None:
            continue
        misfits, causes = misfit_rows(d, 8), cause_rows(d)
        ext = d["extension"]
        est = ", ".join(
            f"{n} {f(b, 4)} [{f(lo, 4)}, {f(hi, 4)}]"
            for n, b, (lo, hi) in zip(ext["names"], ext["bayes_estimate"], ext["ci95"], strict=True)
        )
        gain = d["gain"]
        parts += [
            f"## {label}\n",
            source(name, data=d) + "\n",
            f"Held out: {', '.join(d['held_out'])}; base fit: {d['base_result']}; wall time "
            f"{format_cost(d['wall_time_s'])}.\n",
            f"Verdict: {d['verdict']}\n",
            table(["misfit", "observed", "predictive 90 % band", "z", "adjusted p", ""], misfits) + "\n",
            table(["cause", "score", "explains", "adjusted p", "ambiguous", "note"], causes) + "\n",
            f"Refit with the top cause: {est}.  Held-out delta log predictive density "
            f"{f(gain['delta_lpd'], 2)} +- {f(gain['delta_lpd_se'], 2)} (exceeds its uncertainty: "
            f"{'yes' if gain['significant'] else 'no'}); the new parameter's posterior is "
            f"{100 * gain['effect_contraction']:.0f} % narrower than its prior; gain counted: "
            f"{'yes' if gain['significant'] and gain['effect_excludes_null'] else 'no'}.\n",
        ]
    return "\n".join(parts)


def engine_comparison_rows(d: dict[str, Any], digits: int) -> list[list[str]]:
    """Rows of a jax-md-against-GROMACS ``comparison`` block: means +- SE and their difference in SE."""
    return [
        [
            name,
            f"{c['jax_md_mean']:.{digits}g} +- {c['jax_md_standard_error']:.2g}",
            f"{c['gromacs_mean']:.{digits}g} +- {c['gromacs_standard_error']:.2g}",
            f(c["difference_in_combined_standard_errors"], 1),
        ]
        for name, c in d["comparison"].items()
    ]


def page_water_jaxmd() -> str:
    parts = [
        "# In-process rigid TIP4P (jax-md) against GROMACS\n",
        "## Speed\n",
        "The same 216-molecule box (GROMACS's `tip4p.gro`), NVT at 298 K, 2 fs, reaction field with "
        "r_c 0.85 nm; jax-md on one XLA thread (float32, all pairs, batches under `vmap`), GROMACS "
        "`mdrun -ntmpi 1 -ntomp 1`.  ns/day per core from CPU time, the fastest of interleaved repeats "
        "(all are in the JSON).  The potential energies are one "
        "short run each from GROMACS's equilibrated start, not an equilibrium comparison, and jax-md's "
        "leaves out the constant reaction-field terms of excluded pairs that GROMACS's includes (the "
        "agreement table below adds them).  See "
        "[the engine's page](../water_jaxmd.md).\n",
    ]
    d = load("water_jaxmd_speed")
    if d is None:
        return "\n".join([*parts, "Not measured yet: run `python benchmarks/water_jaxmd_speed.py`.\n"])
    rows = [
        [
            f"jax-md, batch {r['batch']}",
            d.get("jax_device", "-"),
            r["num_steps"],
            g(r["ns_per_day_per_core"], 3),
            g(r["ms_per_step_per_system"], 3),
            f(r["mean_potential_kj_mol_per_molecule"], 2),
        ]
        for r in d["jax"]
    ]
    gm = d["gromacs"]
    rows.append(
        [
            "GROMACS 2022 (mixed precision)",
            "CPU",
            gm["num_steps"],
            g(gm["ns_per_day_per_core"], 3),
            g(gm["ms_per_step"], 3),
            f(gm["mean_potential_kj_mol_per_molecule"], 2),
        ]
    )
    parts += [
        source("water_jaxmd_speed") + "\n",
        table(["engine", "device", "steps", "ns/day/core", "ms/step/system", "mean U/N (kJ/mol)"], rows) + "\n",
        f"GROMACS is {d['ratio_gromacs_over_jax_batch1']:.1f}x faster per core than one jax-md system.\n",
    ]
    for name in ("water_jaxmd_agreement", "water_jaxmd_agreement_1fs"):
        agreement = load(name)
        if agreement is None:
            continue
        rows = engine_comparison_rows(agreement, 4)
        step_fs = 1000 * agreement.get("timestep_ps", 0.002)
        parts += [
            f"## Same state point against GROMACS, {step_fs:g} fs steps\n",
            f"{agreement['state_point']}; `quick` timing (5 ps equilibration, 15 ps analysed); mean +- "
            f"standard error over {agreement['seeds']} seeds per engine; T is the kinetic temperature "
            "(6N - 3 degrees of freedom); robust S1..S9 (S9 = D in "
            "1e-5 cm^2/s; jax-md's U/N includes GROMACS's constant reaction-field terms of excluded pairs).  "
            "The last column is (jax-md - GROMACS) / combined standard error.\n",
            source(name) + "\n",
            table(["statistic", "jax-md", "GROMACS", "difference / s.e."], rows) + "\n",
        ]
    two, one = load("water_jaxmd_agreement"), load("water_jaxmd_agreement_1fs")
    if two is not None and one is not None and "U/N kJ/mol" in two["comparison"]:
        a, b = two["comparison"]["U/N kJ/mol"], one["comparison"]["U/N kJ/mol"]

        def shift(engine: str) -> str:
            d = a[f"{engine}_mean"] - b[f"{engine}_mean"]
            se = (a[f"{engine}_standard_error"] ** 2 + b[f"{engine}_standard_error"] ** 2) ** 0.5
            return f"{d:+.3f} +- {se:.3f} kJ/mol"

        z2, z1 = a["difference_in_combined_standard_errors"], b["difference_in_combined_standard_errors"]
        verdict = (
            "so the 2 fs gap in U/N is a time-step error of jax-md's rigid-body integrator, not the force field"
            if abs(z2) > 2 and abs(z1) < 2
            else "so the time step does not explain the gap"
            if abs(z1) >= 2
            else "the engines agree at both steps"
        )
        parts.append(
            "Halving the step moves U/N (2 fs minus 1 fs) by "
            f"{shift('jax_md')} in jax-md and {shift('gromacs')} in GROMACS; the engines differ by "
            f"{f(z2, 1)} standard errors at 2 fs and {f(z1, 1)} at 1 fs, {verdict}.\n"
        )
    density = load("water_jaxmd_density")
    if density is not None:
        rows = engine_comparison_rows(density, 5)
        b, jm = density["barostats"], density["jax_md"]
        parts += [
            "## NPT: density against GROMACS\n",
            f"{density['state_point']}.  jax-md: {b['jax_md']} (volume acceptance "
            f"{span(jm['acceptance_rate'])}); GROMACS: {b['gromacs']}.  {density['seeds']} seeds per "
            f"engine, {density['equilibration_steps']} equilibration and {density['production_steps']} "
            "production steps; mean +- standard error over seeds (jax-md's U/N includes GROMACS's "
            "constant reaction-field terms of excluded pairs).  The last column is (jax-md - GROMACS) / "
            "combined standard error.\n",
            source("water_jaxmd_density") + "\n",
            table(["statistic", "jax-md", "GROMACS", "difference / s.e."], rows) + "\n",
        ]
    return "\n".join(parts)


def page_criticism_fluids() -> str:
    parts = [
        "# Model criticism of Lennard-Jones neon and argon on measured data\n",
        "The data are reference equations of state fitted to measurements (CoolProp; see "
        "`md/fluids/data/<fluid>/PROVENANCE.md`), not raw measurements.  108-atom state points, "
        "jax-md Langevin; the protocol is on the [fluids page](../fluids.md).\n",
    ]
    for name, label, expected in (
        ("criticism_neon", "Neon", "feynman_hibbs"),
        ("criticism_argon", "Argon", "axilrod_teller"),
    ):
        d = load(name)
        parts.append(f"## {label}\n")
        parts.append(source(name, data=d) + "\n")
        if d is None:
            parts.append("Not saved yet.\n")
            continue
        misfits, causes = misfit_rows(d, 10), cause_rows(d)
        base = d["base_fit"]
        parts += [
            f"Base fit (APMCABC, {base['num_simulations']} simulations): sigma "
            f"{f(base['bayes_estimate'][0], 4)} nm, epsilon / k_B {f(base['bayes_estimate'][1], 2)} K "
            f"(literature {f(base['literature'][0], 4)} nm, {f(base['literature'][1], 1)} K).  Wall time "
            f"{format_cost(d['wall_time_s'])}.  Expected cause: `{expected}`.\n",
            f"Verdict: {d['verdict']}\n",
            table(["misfit", "observed", "predictive 90 % band", "z", "adjusted p", ""], misfits) + "\n",
            table(["cause", "score", "explains", "adjusted p", "ambiguous", "note"], causes) + "\n",
        ]
        ext = (d.get("physical_comparison") or {}).get("extension")
        gain = d.get("gain") or {}
        if ext:
            phys = "-" if ext["physical"] is None else g(ext["physical"], 3)
            refit = d.get("budget", {}).get("refit", "apmcabc")
            sims = (d.get("extension") or {}).get("num_simulations")
            how = "GP surrogate" if refit == "surrogate" else "APMCABC"
            parts.append(
                f"Refit with `{ext['effect']}` ({how}, {sims} simulations): "
                f"{g(ext['estimate'], 3)} [{g(ext['ci95'][0], 3)}, "
                f"{g(ext['ci95'][1], 3)}] (95 %); physical value {phys} "
                f"({'inside' if ext['physical_inside_ci95'] else 'outside'} the interval).  "
                f"Conversion: {ext['conversion']}.\n"
            )
        if gain:
            parts.append(
                f"Held-out delta log predictive density {f(gain['delta_lpd'], 2)} +- "
                f"{f(gain['delta_lpd_se'], 2)} (exceeds its uncertainty: "
                f"{'yes' if gain['significant'] else 'no'}).\n"
            )
    return "\n".join(parts)


def page_surrogate_peers() -> str:
    d = load("surrogate_peers")
    title = "# Surrogate against BOLFI and pyABC"
    if d is None:
        return f"{title}\n\nNot saved yet: run `python benchmarks/surrogate_peers.py`.\n"
    labels = {"jaxabc_surrogate": "jaxabc surrogate", "bolfi": "ELFI BOLFI", "pyabc_abcsmc": "pyABC ABC-SMC"}
    rows = []
    for r in d["rows"]:
        for key, label in labels.items():
            o = r.get(key, {})
            if "error" in o or not o:
                rows.append([r["budget"], r["seed"], label, "-", o.get("error", "not run"), "", "", "", "", ""])
                continue
            note = o.get("version", "")
            if "validated" in o:
                note = "validated" if o["validated"] else "NOT validated"
            if "generations" in o:
                note = f"{o['generations']} generations"
            rows.append(
                [
                    r["budget"],
                    r["seed"],
                    label,
                    o["num_simulations"],
                    f(o["energy_distance"], 4),
                    f(o["mean_error_in_sd"], 2),
                    " / ".join(f(v, 2) for v in o["sd_ratio"]),
                    f(o["correlation"], 2),
                    f"{o['run_s']:.0f}",
                ]
                + ([note] if note else [""])
            )
    header = ["budget", "seed", "method", "simulations", "energy distance", "mean error (sd)", "sd / exact sd"]
    return f"""{title}

The same exact problem ({d["problem"]}; observed {d["observed"]}) and the same simulation budgets for
the GP surrogate and for the peers a user would pick instead: ELFI's BOLFI and pyABC's ABC-SMC, each
in its own environment.  Accuracy against the exact posterior: energy distance to exact draws (0 for
equal laws), the posterior mean's error in exact-posterior sd, each sd over the exact sd (1), the
correlation (exact 0.8).  Wall seconds are the run alone (imports excluded).  Goal: {d["goal"]}.
BOLFI's posterior is its own approximation, an ABC posterior at the GP's minimum discrepancy,
wider than the exact one by construction; pyABC checks its budget at generation ends and can
overshoot it (the simulations column counts what each method ran).

{source("surrogate_peers")}

{table([*header, "corr", "wall s", "notes"], rows)}
"""


_MODEL_CHOICE_LINK = " and [which water model the data prefer](water_model_choice.md)"


def page_index() -> str:
    rows = []
    for e in REGISTRY:
        st = status_of(e)
        rows.append(
            [
                f"`{e.name}`",
                st.state,
                format_cost(st.cost_s) + ("" if st.cost_source == "recorded" else " (est.)"),
                ", ".join(st.changed[:3]) + (" ..." if len(st.changed) > 3 else ""),
            ]
        )
    return f"""# Results

Every number on these pages is read from `benchmarks/results/*.json` by `benchmarks/make_docs.py`;
each table names its JSON and the commit that made it.  `python benchmarks/status.py` says which
results the current code still produces, `python benchmarks/regenerate.py --budget 1h` reruns the
stale ones that fit, and `python3 -m pytest -m slow tests/test_benchmarks_repro.py` checks that
every benchmark's quick mode reproduces its saved numbers.

- [Helium Table 1](helium_table1.md) and [the choice of the CPU preset](helium_identifiability.md)
- [Engine throughput](engine_throughput.md) and [agreement with LAMMPS](lammps_agreement.md)
- [Coverage of credible regions](coverage.md) and [of the surrogate posterior](surrogate_coverage.md)
- [Surrogate against APMCABC on helium](surrogate_helium.md) and [against BOLFI and pyABC](surrogate_peers.md)
- [Speedup and scheduling](speedup.md)
- [Cost of an ABC step](abc_overhead.md)
- [Water calibrations](water_calibrations.md) and [the quick preset's density relaxation](water_density_relaxation.md)
- [Model criticism of water](criticism.md){_MODEL_CHOICE_LINK if "water_model_choice.md" in PAGES else ""}
- [Model criticism of neon and argon](criticism_fluids.md)

Status when these pages were generated:

{table(["result", "state", "cost", "changed since"], rows)}
"""


PAGES: dict[str, Callable[[], str]] = {
    "index.md": page_index,
    "helium_table1.md": page_helium_table1,
    "helium_identifiability.md": page_identifiability,
    "engine_throughput.md": page_engine,
    "lammps_agreement.md": page_lammps,
    "coverage.md": page_coverage,
    "surrogate_coverage.md": page_surrogate_coverage,
    "surrogate_helium.md": page_surrogate_helium,
    "surrogate_peers.md": page_surrogate_peers,
    "speedup.md": page_speedup,
    "abc_overhead.md": page_abc_overhead,
    "water_calibrations.md": page_water,
    "water_density_relaxation.md": page_density_relaxation,
    "criticism.md": page_criticism,
    "water_jaxmd.md": page_water_jaxmd,
    "criticism_fluids.md": page_criticism_fluids,
}
if (RESULTS / "water_model_choice.json").is_file():
    # Hours of GROMACS: a page once there is a result to show (every page names its JSON).
    PAGES["water_model_choice.md"] = lambda: page_water_model_choice(load, source, table, f, misfit_rows, cause_rows)


def block_water_model_choice() -> str:
    """The side-by-side table of the water model choice, for ``md/water/README.md``."""
    d = load("water_model_choice")
    if d is None:
        return "Not run yet: `python benchmarks/regenerate.py --only water_model_choice --budget 4h`."
    return "\n\n".join([source("water_model_choice", data=d), side_by_side(d, table)])


def block_water_model_outcome() -> str:
    """What the model choice, the paper-preset check and the criticism found, for ``md/water/README.md``."""
    d = load("water_model_choice")
    if d is None:
        return "Not run yet."
    crits = {name: load(name) for name in CRITICISMS}
    checks = {name: load(name) for name in PAPER_CHECKS}
    return outcome(d, checks, crits, source, table, f)


def block_water_calibrations() -> str:
    """The measured-data calibrations beside the paper's, for ``md/water/README.md``."""
    rows, _ = _water_side_by_side_rows()
    if not rows:
        return "Not run yet: `python benchmarks/regenerate.py --only water_xray water_neutron --budget 8h`."
    names = [n for d in ("xray", "neutron") for n in (f"water_{d}", f"water_{d}_surrogate") if load(n)]
    return _sourced_table(names, _SIDE_BY_SIDE_HEADER, rows)


def block_water_validation() -> str:
    """The validation properties, for ``md/water/README.md``."""
    rows, names = _validation_rows()
    if not rows:
        return "Not run yet: `--validation-ps 500` with a calibration."
    return _sourced_table(names, _VALIDATION_HEADER, rows)


def _sourced_table(names: Sequence[str], header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A generated block: the source line of each result, then the table."""
    return "\n\n".join([*(source(n) for n in names), table(header, rows)])


#: Generated blocks inside hand-written Markdown: ``<!-- generated: NAME -->`` ... ``<!-- /generated -->``.
BLOCKS: dict[str, tuple[str, Callable[[], str]]] = {
    "water_model_choice": ("md/water/README.md", block_water_model_choice),
    "water_model_outcome": ("md/water/README.md", block_water_model_outcome),
    "water_calibrations": ("md/water/README.md", block_water_calibrations),
    "water_validation": ("md/water/README.md", block_water_validation),
}


def fill_blocks(text: str, path: str) -> str:
    """``text`` with every generated block of ``path`` re-rendered (ValueError: a marker is missing)."""
    for name, (where, render) in BLOCKS.items():
        if where != path:
            continue
        start, end = f"<!-- generated: {name} -->", "<!-- /generated -->"
        i = text.find(start)
        j = text.find(end, i + 1)
        if i < 0 or j < 0:
            raise ValueError(f"{path} lacks the markers of the generated block {name!r}")
        text = text[: i + len(start)] + "\n" + render().rstrip() + "\n" + text[j:]
    return text


def main(argv: list[str] | None = None) -> int:
    """Write (or with ``--check`` compare) every page and generated block; exit 1 when one differs."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="compare instead of writing")
    parser.add_argument("--out", type=Path, default=DOCS)
    args = parser.parse_args(argv)
    differ = []
    for name, render in PAGES.items():
        text = render().rstrip() + "\n"
        path = args.out / name
        if args.check:
            if not path.is_file() or path.read_text() != text:
                differ.append(name)
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for rel in sorted({where for where, _ in BLOCKS.values()}) if args.out == DOCS else []:
        path = ROOT / rel
        old = path.read_text()
        new = fill_blocks(old, rel)
        if args.check:
            if new != old:
                differ.append(rel)
        elif new != old:
            path.write_text(new)
    if differ:
        print(f"out of date: {', '.join(differ)} (run python benchmarks/make_docs.py)")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
