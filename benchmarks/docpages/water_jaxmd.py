"""The jax-md TIP4P engine against GROMACS, and the quick preset's density relaxation."""

from __future__ import annotations

from typing import Any

from benchmarks.docpages.common import f, g, load, source, span, table


def page_density_relaxation() -> str:
    d = load("water_density_relaxation")
    title = "# Has the quick preset's density relaxed?"
    if d is None:
        return f"{title}\n\nNot saved yet: run `python -m benchmarks.water_density_relaxation --workers 2`.\n"
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
        return "\n".join([*parts, "Not measured yet: run `python -m benchmarks.water_jaxmd_speed`.\n"])
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
