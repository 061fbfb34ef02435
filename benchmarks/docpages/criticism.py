"""Model criticism pages: measured water, and neon and argon."""

from __future__ import annotations

from benchmarks._common import RESULTS
from benchmarks.docpages.common import cause_rows, f, figure, g, load, misfit_rows, source, table
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
            _figures(name),
            f"Refit with the top cause: {est}.  Held-out delta log predictive density "
            f"{f(gain['delta_lpd'], 2)} +- {f(gain['delta_lpd_se'], 2)} (exceeds its uncertainty: "
            f"{'yes' if gain['significant'] else 'no'}); the new parameter's posterior is "
            f"{100 * gain['effect_contraction']:.0f} % narrower than its prior; gain counted: "
            f"{'yes' if gain['significant'] and gain['effect_excludes_null'] else 'no'}.\n",
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
        if gain:
            parts.append(
                f"Held-out delta log predictive density {f(gain['delta_lpd'], 2)} +- "
                f"{f(gain['delta_lpd_se'], 2)} (exceeds its uncertainty: "
                f"{'yes' if gain['significant'] else 'no'}).\n"
            )
    return "\n".join(parts)
