"""Engine and run-cost pages: engine throughput (CPU, small systems, GPU), speedup, whole-run overhead."""

from __future__ import annotations

from typing import Any

import numpy as np

from benchmarks._common import RESULTS
from benchmarks.docpages.common import f, figure, load, source, table


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


def _gpu_against_lammps(best: dict[str, dict[str, float]]) -> list[str]:
    """The paper's 1000-atom system on the GPU against LAMMPS's one-rank rate in engine_throughput."""
    gpu = max((v.get("gpu", 0.0) for k, v in best.items() if k.startswith("paper_preset")), default=0.0)
    e = load("engine_throughput")
    lmp = [
        r
        for r in (e or {}).get("records", [])
        if r.get("engine") == "lammps"
        and r.get("setup") == "paper_1000_atoms_1atm"
        and r.get("system_steps_per_second")
    ]
    if not gpu or not lmp:
        return []
    rate = max(r["system_steps_per_second"] for r in lmp)
    cpu = e["provenance"]["machine"].get("cpu", "another machine")
    return [
        f"The paper's 1000-atom system: the GPU's best rate, {gpu:.3e} system-steps/s, is {gpu / rate:.0f} times "
        f"LAMMPS with one MPI rank ({rate:.3e} system-steps/s, `engine_throughput.json`, on {cpu}).  That is a "
        "rate per CPU core on another machine, not a like-for-like speed-up: LAMMPS would need about "
        f"{gpu / rate:.0f} such cores, running independent simulations, to match one GPU."
    ]


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
    # Best rate per device and setup; a system's setups are "<system>" and "<system>_vmap_all".
    best: dict[str, dict[str, float]] = {}
    for key in ("gpu", "cpu"):
        for setup, records in ((parts.get(key) or {}).get("engine") or {}).items():
            rates = [r["system_steps_per_second"] for r in records if r.get("system_steps_per_second")]
            if rates:
                best.setdefault(setup, {})[key] = max(rates)
    ratio_lines = []
    paper, paper_all = best.get("paper_preset", {}).get("gpu"), best.get("paper_preset_vmap_all", {}).get("gpu")
    if paper and paper_all:
        ratio_lines.append(
            f"On the GPU the paper preset's CPU setting (members one at a time) reaches at best "
            f"{paper / paper_all:.3f} of the rate with the whole batch under one `vmap`: on a GPU use "
            "`md.helium.get_preset('paper', vmap_width=None)`."
        )
    speedups = []
    for system in ("cpu_preset", "paper_preset"):
        rates = {dev: max(v.get(dev, 0.0) for k, v in best.items() if k.startswith(system)) for dev in ("gpu", "cpu")}
        if rates["gpu"] and rates["cpu"]:
            speedups.append(f"{system.replace('_', ' ')} {rates['gpu'] / rates['cpu']:.1f}")
    if speedups:
        ratio_lines.append(
            "Best GPU rate over the best rate of the same machine's CPU (any setting): " + ", ".join(speedups) + "."
        )
    ratio_lines += _gpu_against_lammps(best)
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
        *[line + "\n" for line in ratio_lines],
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
            "The jobs run one at a time; the 1-minute load average at each start still carries the job "
            "before it.\n",
            table(["tree", "run", "wall s", "CPU s", "load at start", "exit"], job_rows) + "\n",
        ]
        if speedups:
            parts.append("Speed-up over the baseline tree: " + ", ".join(speedups) + ".\n")
    return parts


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
    plot = f"{name}.png"
    out = [
        source(name, "model", d) + "\n",
        *(
            [figure(plot, f"{name}: makespan over the bound for each queue order") + "\n"]
            if (RESULTS / plot).is_file()
            else []
        ),
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


def _real_runs() -> str:
    """The real GROMACS part of the speed-up study: makespans at n = 1 and 2 workers."""
    d = (load("speedup") or {}).get("real")
    if not d or "runs" not in d:
        return "Not saved yet.\n"
    runs = d["runs"]
    rows = []
    for n, allocations in (("1", ("dynamic",)), ("2", ("dynamic", "static"))):
        r = runs.get(n, {})
        if "error" in r:
            rows.append([n, "-", "failed to launch", "-", "-"])
            continue
        for a in allocations:
            if a in r:
                ok = sum(s == 0 for s in r[a]["status"])
                rows.append(
                    [
                        n,
                        a,
                        f(r[a]["makespan_s"], 3),
                        f(float(np.sum(r[a]["task_wall_s"])), 3),
                        f"{ok} of {len(r[a]['status'])}",
                    ]
                )
    lines = [
        source("speedup", part="real"),
        "",
        f"{d['num_tasks']} runs of {d['simulator']}; parameters from the {d.get('theta_source', 'prior')}.\n",
        table(["workers", "allocation", "makespan s", "summed task s", "succeeded"], rows) + "\n",
    ]
    if "speedup" in d:
        lines.append(
            "Speed-up at n = 2 (dynamic / static): "
            f"{f(d['speedup']['dynamic'], 3)} / {f(d['speedup']['static'], 3)}; the summed task time at n = 2 "
            f"over that at n = 1: {f(d['task_time_inflation_n2']['dynamic'], 3)} / "
            f"{f(d['task_time_inflation_n2']['static'], 3)} (two concurrent runs on this machine's 2 shared "
            "cores); makespan over max(total/n, longest): "
            f"{f(d['makespan_over_lower_bound_n2']['dynamic'], 3)} / "
            f"{f(d['makespan_over_lower_bound_n2']['static'], 3)}.\n"
        )
    return "\n".join(lines)


def page_speedup() -> str:
    return f"""# Speedup and scheduling

Discrete-event model of a whole ABC run on n workers: makespan over max(total/n, longest task),
worst over n and repetitions, for each queue order.  The pigeonhole bound (some worker runs k + 1
of the k n + 1 longest tasks) is what any schedule of indivisible tasks must exceed.

## Neutron water calibration's records

{_speedup_tables("speedup")}

## Simulated-water calibration's records

{_speedup_tables("speedup_model_simulated_records")}

## Real GROMACS runs on 1 and 2 MPI workers

{_real_runs()}
"""


PEER_LABELS = (("elfi_smc", "ELFI SMC"), ("pyabc_abcsmc", "pyABC ABC-SMC"), ("abcpy_pmcabc", "ABCpy PMCABC"))


def page_abc_overhead() -> str:
    d = load("abc_overhead")
    if d is None:
        return "# Whole-run cost against ELFI, pyABC and ABCpy\n\nNot saved yet.\n"
    runs = [
        ("fused_cold", "jaxabc.run (fused), cold (empty cache)"),
        ("fused_cold_persistent_cache", "jaxabc.run (fused), new process, cache filled (default)"),
        ("fused_warm", "jaxabc.run (fused), warm"),
        ("fused_cold_fast_compile", "run_fused(fast_compile=True), cold (no cache)"),
        ("host_driver_cold", "jaxabc host driver (executor='vmap'), cold"),
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
        for key, label in PEER_LABELS:
            x = r.get(key) or {}
            if "num_simulations" in x:
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
    # Whole-process ratios, peer over jaxabc; a peer that did not finish gives a lower bound.
    ratio_rows = []
    for r in d["rows"]:
        ratios = r.get("ratios", {})
        for key, label in PEER_LABELS:
            cells = []
            for mode in ("fused_cold", "fused_cold_persistent_cache"):
                exact = ratios.get(f"{key}_over_jaxabc_{mode}_whole_run")
                bound = ratios.get(f"{key}_over_jaxabc_{mode}_whole_run_at_least")
                cells.append(f(exact, 1) if exact is not None else f">= {f(bound, 1)}" if bound is not None else "-")
            if any(c != "-" for c in cells):
                ratio_rows.append([r["num_particles"], label, *cells])
    pmc = d.get("pmc_vs_apmc_host_driver_per_simulation", {})
    header = ["N", "run", "simulations", "whole process (s)", "us / simulation", "mean error", "covariance error"]
    floor_rows = []
    for r in d["rows"]:
        fl = r.get("compiled_step_floor") or {}
        jx = r.get("jaxabc") or {}
        warm = (jx.get("fused_warm") or {}).get("run_s")
        fixed = {
            key: jx[key]["process_wall_s"] - warm
            for key in ("fused_cold", "fused_cold_persistent_cache")
            if warm is not None and "process_wall_s" in (jx.get(key) or {})
        }
        peers = {k: (r.get(k) or {}).get("process_wall_s") for k in ("elfi_smc", "pyabc_abcsmc")}
        for mode, label in (("default", "default"), ("fast", "fast compile")):
            x = fl.get(mode) or {}
            if "process_wall_s" not in x:
                continue
            floor_rows.append(
                [
                    r["num_particles"],
                    label,
                    f(x["import_jax_s"] + x["import_jaxabc_s"], 2),
                    f(x["trace_lower_s"], 2),
                    f(x["compile_s"], 2),
                    f(x["process_wall_s"], 2),
                    f(peers["elfi_smc"] / 10, 2) if peers["elfi_smc"] else "-",
                    f(peers["pyabc_abcsmc"] / 10, 2) if peers["pyabc_abcsmc"] else "-",
                    f(fixed.get("fused_cold"), 1) if mode == "default" else "",
                    f(fixed.get("fused_cold_persistent_cache"), 1) if mode == "default" else "",
                ]
            )
    floor = ""
    if floor_rows:
        floor = (
            "## The compiled-step floor\n\n"
            "The least a fresh process pays, with no persistent cache, before it can run one PMC-ABC "
            "iteration as a compiled JAX program: interpreter start, `import jax, jaxabc`, tracing and "
            "lowering one `make_jax_step` step (propose, the vmapped simulator and update in a single "
            "jit, with no records, loop or initial generation) and compiling it (medians of three "
            "processes).  A whole run ten times faster than a peer must finish inside a tenth of that "
            "peer's process; where the floor exceeds that tenth no JAX-compiled run can reach it on this "
            "machine, whatever the rest of the library does.  The last two columns are jaxabc's own "
            "fixed cost: the cold process minus the warm run (the run itself).\n\n"
            + table(
                [
                    "N",
                    "compilation",
                    "imports (s)",
                    "trace + lower (s)",
                    "compile (s)",
                    "floor process (s)",
                    "ELFI / 10 (s)",
                    "pyABC / 10 (s)",
                    "fixed, empty cache (s)",
                    "fixed, cache filled (s)",
                ],
                floor_rows,
            )
            + "\n"
        )
    return f"""# Whole-run cost against ELFI, pyABC and ABCpy

{d.get("description", "")}

Every run is a fresh process on the same 2-D Gaussian problem and tolerance schedule; the peers
run in their own virtual environments.  For a JAX simulator `jaxabc.run` runs the fused program
(`run_fused`), which keeps its compiled programs in a persistent cache (`~/.cache/jaxabc/xla`)
by default: "cold (empty cache)" is a machine's first run of a configuration, "cache filled"
every later process.{" Note recorded with the run: " + d["note"] if d.get("note") else ""}

{source("abc_overhead")}

{table(header, rows)}

How many times faster jaxabc's whole process is than each peer's (the peer's process time over
jaxabc's; the goal is 10x; ">=" where the peer did not finish):

{table(["N", "peer", "jaxabc cold, empty cache", "jaxabc cold, cache filled"], ratio_rows)}

PMC-ABC against APMCABC per simulation (host driver, warm):
{f(pmc.get("pmc_over_apmc"), 2)}x.

{floor}"""
