"""Model criticism page of neon and argon (water's is on the model-choice page)."""

from __future__ import annotations

from benchmarks._common import RESULTS
from benchmarks.docpages.common import (
    MISFIT_NOTE,
    cause_rows,
    extension_edges,
    f,
    figure,
    g,
    load,
    misfit_rows,
    saved_extension,
    source,
    table,
)
from benchmarks.status import format_cost

_FIGURES = (
    ("misfits", "standardised misfit of each summary"),
    ("causes", "score of each candidate cause"),
    ("state_points", "misfit at each state point"),
    ("extension", "posterior of the extended model"),
    ("gain", "held-out predictive density, base against extended"),
)


def _figures(name: str) -> str:
    """The criticism's saved figures (``benchmarks/results/<name>/*.png``), those that exist."""
    shown = [
        figure(f"{name}/{kind}.png", f"{name}: {what}")
        for kind, what in _FIGURES
        if (RESULTS / name / f"{kind}.png").is_file()
    ]
    return "\n\n".join(shown) + "\n" if shown else ""


def seen_by_data(c: dict) -> str:
    """Whether the design could have detected a cause: its power where it has an expected
    strength, else whether its largest signal over its prior clears the visibility threshold."""
    if "power" not in c:
        return "not assessed: this run predates detection power"
    if c.get("power") is not None:
        verdict = "detectable" if c.get("detectable") else "not detectable"
        return f"{verdict} (power {f(c['power'], 2)} at its expected strength)"
    if c.get("invisible"):
        return "no: invisible to these data"
    return "yes: visible over its prior (no expected strength, no power)"


def _fluid_cause_rows(d: dict) -> list[list[str]]:
    """Cause rows of a fluids criticism with the column "could these data see it"."""
    return [[*row[:5], seen_by_data(c), row[5]] for row, c in zip(cause_rows(d), d["causes"], strict=True)]


def _b2_row(r: dict) -> list[str]:
    """One row of a B2 table: a (potential, scale box, base prior) analysis."""
    box = r["scale_box"]["high"]
    fh = r["power"].get("feynman_hibbs") or {}
    ext = r.get("extension")
    top = r["causes"][0]
    refit = "-"
    if ext:
        refit = (
            f"{ext['effect']} {g(ext['estimate'], 3)} [{g(ext['ci95'][0], 3)}, {g(ext['ci95'][1], 3)}]"
            f"{' (contains 1)' if ext['expected_inside_ci95'] else (' (excludes 1)' if ext['expected'] else '')}"
        )
    gain = r.get("gain") or {}
    power = "-"
    if fh:
        power = f"{f(fh['power'], 2)} [{f(fh['interval'][0], 2)}, {f(fh['interval'][1], 2)}] of {fh['num_datasets']}"
    return [
        r["potential"],
        f"+-{100 * (box[0] - 1):.2g} % / +-{100 * (box[1] - 1):.2g} %",
        r["base_prior"],
        f"{g(r['base_fit']['bayes_estimate'][0], 4)}, {g(r['base_fit']['bayes_estimate'][1], 4)}",
        ", ".join(r["flagged"][:2]) or "nothing",
        f"{top['name']} ({f(top['score'], 1)})",
        power,
        refit,
        f"{f(gain['delta_lpd'], 1)} +- {f(gain['delta_lpd_se'], 1)}" if gain else "-",
    ]


def _b2_reading(r: dict) -> str:
    """One generated sentence on what an analysis of a B2 table shows."""
    box = r["scale_box"]["high"]
    label = f"{r['potential']}, box +-{100 * (box[0] - 1):.2g} % / +-{100 * (box[1] - 1):.2g} %, {r['base_prior']}"
    fh = r["power"].get("feynman_hibbs") or {}
    power = f"power of Feynman-Hibbs {f(fh.get('power'), 2)}" if fh else "no power estimate"
    edge = max(max(m) for m in r["base_fit"]["prior_edge_mass"])
    ext = r.get("extension")
    if not r["flagged"] and r["base_prior"] == "free" and fh and fh.get("power", 1.0) < 0.5:
        return f"({label}) nothing flagged: with the scales free the correction is absorbed ({power})."
    if not r["flagged"]:
        why = (
            f"; the base fit puts up to {100 * edge:.0f} % of its mass on the box edge, and the power is "
            "computed there, where the classical potential is furthest from a quantum one"
            if edge > 0.05
            else ""
        )
        return f"({label}) nothing flagged, {power}{why}."
    if ext and ext["effect"] == "feynman_hibbs":
        verdict = "contains" if ext["expected_inside_ci95"] else "excludes"
        return f"({label}) Feynman-Hibbs named, {power}; the refit's 95 % interval {verdict} 1."
    if ext and ext.get("repulsive_exponent") is not None:
        lo, hi = (12.0 + c for c in ext["ci95"])
        return (
            f"({label}) the pair shape named: repulsive exponent {g(ext['repulsive_exponent'], 3)} "
            f"[{g(lo, 3)}, {g(hi, 3)}] against LJ's 12; {power}."
        )
    return f"({label}) flagged; top cause {r['causes'][0]['name']}, {power}."


def _joint_line(j: dict) -> str:
    """The joint refit of several effects (argon: pair shape and three-body) as a sentence."""
    est = ", ".join(
        f"{n} {g(b, 4)} [{g(lo, 4)}, {g(hi, 4)}]"
        for n, b, (lo, hi) in zip(j["names"], j["bayes_estimate"], j["ci95"], strict=True)
    )
    line = f"Joint refit with {', '.join(f'`{e}`' for e in j['effects'])} ({j['num_simulations']} simulations): {est}."
    c9 = j.get("c9_hartree_bohr9")
    if c9:
        line += (
            f"  Three-body coefficient C9 = {g(c9['mean'], 3)} [{g(c9['ci95'][0], 3)}, {g(c9['ci95'][1], 3)}] "
            f"hartree bohr^9 (95 %), literature {g(c9['literature'], 3)} "
            f"({'inside' if c9['literature_inside_ci95'] else 'outside'} the interval)."
        )
    for name, (lo, hi) in zip(j["names"], j["prior_edge_mass"], strict=True):
        side, mass = ("lower", lo) if lo >= hi else ("upper", hi)
        if mass > 0.05:
            line += (
                f"  {100 * mass:.0f} % of {name}'s posterior lies within 2 % of its {side} prior bound: "
                "a wider box could move the estimates that depend on it."
            )
    return line + "\n"


_B2_HEADER = [
    "potential",
    "scale box (length / energy)",
    "base prior",
    "base fit (length, energy)",
    "flagged",
    "top cause (score)",
    "power of FH at 1 [95 %]",
    "refit, 95 %",
    "held-out gain (lpd)",
]


def _b2_section(fluid: str) -> list[str]:
    """B2-only criticism of ``fluid`` (issue 47): reference potentials for neon, LJ for argon."""
    name = f"criticism_{fluid}_b2"
    d = load(name)
    title = (
        "Neon: a design that can see the quantum correction"
        if fluid == "neon"
        else "Argon: the pair shape, from B2 alone"
    )
    parts = [f"## {title}\n", source(name, data=d) + "\n"]
    if d is None:
        return [*parts, "Not saved yet.\n"]
    goal, main = d["goal"], d["main"]
    rows = list(d["analyses"]) + ([d["second_potential"]] if "second_potential" in d else [])
    parts.append(
        "B2 of the reference equation at "
        f"{', '.join(g(t, 3) for t in d['train_k'])} K (fitted) and {', '.join(g(t, 3) for t in d['held_out_k'])} K "
        "(held out), no MD (`md/fluids/pair_b2.py`; sources in "
        f"`md/fluids/data/{fluid}/PROVENANCE.md`).  A reference potential's length and energy scales move only "
        "within a stated box, which the criticism's base parameters respect (`base_prior=\"prior\"`); LJ's "
        "box is a search range (free).  Power: the share of data sets, simulated from the base posterior with "
        "`fh_scale = 1`, in which the whole pipeline names Feynman-Hibbs "
        f"({d['budget']['power_datasets']} data sets each).  APMCABC with {d['budget']['num_particles']} "
        "particles for the base fit and the refits.\n"
    )
    if fluid == "neon":
        parts.append(
            f"Main design ({main['potential']}, box +-{100 * (main['scale_box']['high'][0] - 1):.2g} % / "
            f"+-{100 * (main['scale_box']['high'][1] - 1):.2g} %): power {f(goal['power'], 2)} (95 % Wilson "
            f"interval {f(goal['power_interval'][0], 2)}-{f(goal['power_interval'][1], 2)}, {goal['num_datasets']} "
            f"data sets; goal 0.8: {'met' if goal['power_met'] else 'not met'}); the refitted scale's 95 % "
            f"interval {'contains' if goal['interval_contains_1'] else 'does not contain'} 1.\n"
        )
    else:
        parts.append(
            f"Named: `{goal['named']}`; held-out gain counted: {'yes' if goal['gain_significant'] else 'no'}.\n"
        )
    parts += [
        f"Verdict: {main['verdict']}\n",
        "Could the main design see each cause: "
        + "; ".join(f"`{c['name']}` {seen_by_data(c)}" for c in main["causes"])
        + ".\n",
        table(_B2_HEADER, [_b2_row(r) for r in rows]) + "\n",
        " ".join(_b2_reading(r) for r in rows) + "\n",
    ]
    return parts


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
        misfits, causes = misfit_rows(d, 10), _fluid_cause_rows(d)
        base = d["base_fit"]
        parts += [
            f"Base fit (APMCABC, {base['num_simulations']} simulations): sigma "
            f"{f(base['bayes_estimate'][0], 4)} nm, epsilon / k_B {f(base['bayes_estimate'][1], 2)} K "
            f"(literature {f(base['literature'][0], 4)} nm, {f(base['literature'][1], 1)} K).  Wall time "
            f"{format_cost(d['wall_time_s'])}.  Expected cause: `{expected}`.\n",
            f"Verdict: {d['verdict']}\n",
            table(["misfit", "observed", "predictive 90 % band", "z", "adjusted p", ""], misfits) + "\n",
            MISFIT_NOTE + "\n",
            table(["cause", "score", "explains", "adjusted p", "ambiguous", "could these data see it", "note"], causes)
            + "\n",
            _figures(name),
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
            edges = extension_edges(saved_extension(RESULTS / name / "extension.npz"))
            if edges:
                parts.append(
                    "Prior edges of the refit: "
                    + "; ".join(edges)
                    + ".  The effect's size, and the gain, depend on where that box was cut.\n"
                )
        if gain:
            parts.append(
                f"Held-out delta log predictive density {f(gain['delta_lpd'], 2)} +- "
                f"{f(gain['delta_lpd_se'], 2)} (exceeds its uncertainty: "
                f"{'yes' if gain['significant'] else 'no'}).\n"
            )
        joint = d.get("joint_refit")
        if joint:
            parts.append(_joint_line(joint))
        parts += _b2_section("neon" if name == "criticism_neon" else "argon")
    return "\n".join(parts)
