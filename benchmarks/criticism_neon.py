"""Model criticism of Lennard-Jones neon (or argon) on measured data (issue 16).

The data are values of the reference equations of state (CoolProp; neon: Thol et al. 2019,
argon: Tegeler et al. 1999), which are fitted to measurements -- not raw measurements; see
``md/fluids/data/<fluid>/PROVENANCE.md``.  With the state-point simulator of
:mod:`md.fluids.simulator` (108 atoms per state point, jax-md Langevin, LJ reduced units):

1. calibrate (sigma, epsilon) with APMCABC on a training subset: pressure and residual energy on
   three liquid isotherms (saturated and 6 % compressed liquid) and B2 at four temperatures;
2. :func:`jaxabc.criticism.critique` with :func:`md.fluids.simulator.fluid_catalogue`
   (temperature offset, Axilrod-Teller, Feynman-Hibbs, density error, tail correction);
   held out: the middle compression on the other liquid isotherms, the dense supercritical
   isotherms, and B2 at four other temperatures -- never fitted, the ground of the gain; the
   refits (base and base + top effect) use the GP surrogate with ``--refit-budget`` real
   simulations each (``--refit apmcabc``: APMCABC at the base fit's settings);
3. write ``benchmarks/results/criticism_<fluid>.json`` and the report (Markdown and figures) in
   ``benchmarks/results/criticism_<fluid>/``, with the refitted effect beside its physical value
   (neon: fh_scale 1; argon: nu = C9 / (epsilon sigma^9) from C9 = 521 hartree bohr^9).

Usage::

    python -m benchmarks.criticism_neon                 # under an hour on 2 cores
    python -m benchmarks.criticism_neon --fluid argon   # argon, benchmarks/results/criticism_argon.json
    python -m benchmarks.criticism_neon --tiny          # plumbing smoke test, numbers meaningless
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import jaxabc
from benchmarks._common import QUICK_RESULTS, RESULTS, command_line, declare_input, write_result
from jaxabc.criticism import critique
from md.fluids import DATA, LITERATURE_LJ
from md.fluids.simulator import BASE_NAMES, FluidConfig, fluid_setup
from md.fluids.three_body import c9_reduced

#: Per fluid: training state-point rows, held-out rows, B2 temperatures (fit / held out), prior box.
DESIGN: dict[str, dict[str, Any]] = {
    "neon": dict(
        # rows: 26, 30, 34, 38, 42 K x (1.00, 1.03, 1.06) rho_sat; 50, 60 K x (2.0, 2.2, 2.4) rho_c
        train=[0, 2, 6, 8, 12, 14],
        held=[4, 10, 16, 19],
        b2_train=[30.0, 50.0, 100.0, 200.0],
        b2_held=[40.0, 70.0, 150.0, 300.0],
        prior=([0.262, 30.0], [0.290, 42.0]),
    ),
    "argon": dict(
        # rows: 90 ... 140 K (10 K steps) x (1.00, 1.03, 1.06) rho_sat; 160, 200 K x (2.0, 2.2, 2.4) rho_c
        train=[0, 2, 6, 8, 12, 14],
        held=[4, 10, 16, 19, 22],
        b2_train=[90.0, 130.0, 200.0, 400.0],
        b2_held=[110.0, 160.0, 300.0, 600.0],
        prior=([0.330, 105.0], [0.350, 130.0]),
    ),
}


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--fluid", choices=tuple(DESIGN), default="neon")
    p.add_argument("--num-particles", type=int, default=48, help="APMCABC particles (base fit and refits)")
    p.add_argument("--num-steps", type=int, default=4, help="APMCABC step cap (base fit and refits)")
    p.add_argument("--alpha", type=float, default=0.5, help="APMCABC kept fraction")
    p.add_argument("--num-draws", type=int, default=32)
    p.add_argument("--num-replicates", type=int, default=24)
    p.add_argument("--num-gradient-replicates", type=int, default=8)
    p.add_argument("--num-refit-iterations", type=int, default=2)
    p.add_argument("--pilot", type=int, default=8, help="replicates at the literature parameters (noise scale)")
    p.add_argument(
        "--refit",
        choices=("surrogate", "apmcabc"),
        default="surrogate",
        help="algorithm of the refits (base with the extension's distance, base + effect)",
    )
    p.add_argument("--refit-budget", type=int, default=160, help="real simulations per surrogate refit")
    p.add_argument("--chunk", type=int, default=16, help="simulations per vmapped call")
    p.add_argument(
        "--power",
        type=int,
        default=4,
        help="simulated data sets for the detection power of effects with an expected strength (0: none)",
    )
    p.add_argument(
        "--joint",
        default=None,
        help="comma-separated effects refitted together after the criticism (argon default: "
        "pair_shape,axilrod_teller: the three-body coefficient with the pair shape right)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--tiny", action="store_true", help="smoke run (short MD, tiny budgets) to results/quick/")
    return p.parse_args(argv)


def engine_config(tiny: bool) -> FluidConfig:
    if tiny:
        return FluidConfig(equilibration_steps=200, production_steps=200, three_body_every=5)
    return FluidConfig(equilibration_steps=300, production_steps=500, sample_every=10, three_body_every=5)


class BaseSimulator:
    """Effects at null, the training summaries only (for the base APMCABC fit)."""

    def __init__(self, simulate, num_effects: int):
        self.simulate, self.num_effects = simulate, num_effects

    def __call__(self, key, theta):
        return self.simulate(key, jnp.concatenate([jnp.asarray(theta, jnp.float32), jnp.zeros(self.num_effects)]))


def refit_options(args: argparse.Namespace) -> dict:
    """``critique``'s refits: the GP surrogate (a budget of real simulations), or APMCABC."""
    if args.refit == "surrogate":
        return dict(
            algorithm="surrogate", num_particles=1000, max_simulations=args.refit_budget, max_failure_fraction=0.95
        )
    return dict(num_particles=args.num_particles, num_steps=args.num_steps, alpha=args.alpha, max_failure_fraction=0.95)


def main(argv=None, fluid: str | None = None) -> dict:
    args = parse_args(argv)
    fluid = str(fluid or args.fluid)
    design = DESIGN[fluid]
    cfg = engine_config(args.tiny)
    if args.tiny:
        args.num_particles, args.num_steps, args.num_draws, args.num_replicates = 16, 2, 10, 12
        args.num_gradient_replicates, args.num_refit_iterations, args.pilot = 4, 1, 8
        args.power, args.refit_budget = min(args.power, 2), min(args.refit_budget, 48)
    executor = jaxabc.VmapExecutor(chunk_size=args.chunk)
    rows = np.array(design["train"] + design["held"])
    b2_t = design["b2_train"] + design["b2_held"]
    setup = fluid_setup(fluid, rows, sorted(b2_t), cfg)
    num_sp = rows.size
    held = np.zeros(setup.observed.size, bool)
    is_held_sp = np.isin(rows, design["held"])
    held[:num_sp] = is_held_sp
    held[num_sp : 2 * num_sp] = is_held_sp
    held[2 * num_sp :] = np.isin(setup.b2_temperature_k, design["b2_held"])
    train_setup = fluid_setup(fluid, design["train"], design["b2_train"], cfg, setup.catalogue)
    k = len(setup.catalogue)
    lo, hi = design["prior"]
    prior = jaxabc.Uniform(lo, hi, names=BASE_NAMES, units=("nm", "K"))
    lit = LITERATURE_LJ[fluid]
    theta_lit = np.array([lit["sigma_m"] * 1e9, lit["epsilon_k"]])
    t0 = time.perf_counter()

    # Noise scale of the training summaries (simulation + measurement) at the literature values.
    base_sim = BaseSimulator(train_setup.simulate, k)
    keys = np.asarray(jax.random.key_data(jax.random.split(jax.random.key(args.seed + 101), args.pilot)))
    pilot = executor.map(base_sim, keys, np.repeat(theta_lit[None], args.pilot, 0)).summaries
    scale = np.sqrt(np.nanvar(pilot, axis=0, ddof=1) + train_setup.uncertainty**2)
    base = jaxabc.run(
        "apmcabc",
        base_sim,
        prior,
        train_setup.observed,
        num_particles=args.num_particles,
        num_steps=args.num_steps,
        distance=jaxabc.distances.standardized_euclidean(scale),
        seed=args.seed,
        executor=executor,
        alpha=args.alpha,
        max_failure_fraction=0.95,
    )
    t_base = time.perf_counter() - t0
    report = critique(
        base,
        setup.simulate,
        setup.observed,
        setup.catalogue,
        held_out=held,
        seed=args.seed,
        summary_names=setup.names,
        groups=setup.groups,
        num_draws=args.num_draws,
        num_replicates=args.num_replicates,
        num_gradient_replicates=args.num_gradient_replicates,
        num_refit_iterations=args.num_refit_iterations,
        executor=executor,
        extend_options=refit_options(args),
        num_power_replicates=args.power,
    )
    default_joint = ["pair_shape", "axilrod_teller"] if fluid == "argon" else []
    joint_names = args.joint.split(",") if args.joint else default_joint
    joint = joint_refit(report, setup, held, joint_names, args, executor) if joint_names else None
    folder = QUICK_RESULTS if args.tiny else RESULTS
    out_dir = folder / f"criticism_{fluid}"
    report.write(out_dir)
    try:
        summary = physical_comparison(report, setup, fluid)
        figure = misfit_figure(report, setup, held, out_dir / "state_points.png")
        with open(out_dir / "report.md", "a") as fh:
            fh.write(physical_markdown(summary, fluid, figure))
    except Exception as exc:  # the criticism itself is saved whatever happens here
        summary = {"error": repr(exc)}
    payload = {
        "benchmark": f"criticism_{fluid}",
        "fluid": fluid,
        "data": "reference equation of state values (fitted to measurements), see md/fluids/data/"
        f"{fluid}/PROVENANCE.md",
        "engine": {
            "num_atoms": cfg.num_atoms,
            "equilibration_steps": cfg.equilibration_steps,
            "production_steps": cfg.production_steps,
            "dt_reduced": cfg.dt,
            "cutoff_sigma": cfg.cutoff,
            "triple_cutoff_sigma": cfg.triple_cutoff,
            "note": "tiny smoke run, numbers meaningless" if args.tiny else "",
        },
        "state_points": {
            "train": [n for n, h in zip(setup.names, held, strict=True) if not h],
            "held_out": [n for n, h in zip(setup.names, held, strict=True) if h],
        },
        "prior": {"low": lo, "high": hi, "names": list(BASE_NAMES)},
        "base_fit": {
            "bayes_estimate": base.bayes_estimate().tolist(),
            "ci95": [list(map(float, c)) for c in base.credible_interval(0.95)],
            "num_simulations": int(base.num_simulations),
            "literature": theta_lit.tolist(),
        },
        "budget": {
            k: getattr(args, k)
            for k in (
                "num_particles",
                "num_steps",
                "alpha",
                "num_draws",
                "num_replicates",
                "num_gradient_replicates",
                "num_refit_iterations",
                "pilot",
                "refit",
                "refit_budget",
                "power",
            )
        },
        "physical_comparison": summary,
        "joint_refit": joint,
        "wall_time_base_fit_s": t_base,
        "wall_time_s": time.perf_counter() - t0,
        **report.to_dict(),
    }
    declare_input(DATA / fluid)
    write_result(
        folder / f"criticism_{fluid}.json",
        payload,
        command=command_line([__file__, *(argv if argv is not None else sys.argv[1:])]),
    )
    print(report.verdict)
    print(summary)
    return payload


def joint_refit(report, setup, held: np.ndarray, effects: list[str], args, executor) -> dict:
    """Refit the base model with several effects at once on the fitted summaries (argon: the pair
    shape with the three-body term), and the three-body coefficient in hartree bohr^9."""
    from jaxabc.criticism.extend import refit

    pred = report.predictive
    fitted = pred.active & ~held
    t0 = time.perf_counter()
    options = refit_options(args)
    if options.get("algorithm") == "surrogate":
        options["max_simulations"] = int(args.refit_budget * (1 + len(effects)) // 2)
    res = refit(
        report.base_result, setup.simulate, setup.observed, setup.catalogue, effects, fitted, pred.noise_cov,
        seed=args.seed + 7, executor=executor, **options,
    )  # fmt: skip
    est, ci = res.bayes_estimate(), res.credible_interval(0.95)
    out = {
        "effects": effects,
        "names": list(res.names),
        "bayes_estimate": est.tolist(),
        "ci95": [list(map(float, c)) for c in ci],
        "num_simulations": int(res.num_simulations),
        "prior_edge_mass": res.prior_edge_mass(0.02).tolist(),
        "wall_time_s": time.perf_counter() - t0,
    }
    if "axilrod_teller" in effects:
        draws = res.resample(2000, seed=args.seed)
        col = list(res.names).index("axilrod_teller")
        # nu = C9 / (epsilon sigma^9): C9 per draw at that draw's sigma and epsilon.
        c9 = np.array([row[col] / c9_reduced(1.0, float(row[1]), float(row[0]) * 1e-9) for row in draws])
        lo, hi = np.quantile(c9, [0.025, 0.975])
        lit = setup.physical["c9_hartree_bohr9"]
        out["c9_hartree_bohr9"] = {
            "mean": float(c9.mean()),
            "ci95": [float(lo), float(hi)],
            "literature": lit,
            "literature_inside_ci95": bool(lo <= lit <= hi),
        }
    if "pair_shape" in effects:
        col = list(res.names).index("pair_shape")
        out["repulsive_exponent"] = {"mean": 12.0 + float(est[col]), "ci95": [12.0 + ci[col][0], 12.0 + ci[col][1]]}
    return out


def physical_comparison(report, setup, fluid: str) -> dict:
    """The refitted effect (if any) beside its physical value, with the unit conversion."""
    out: dict = {"physical_values": {"feynman_hibbs": 1.0, "axilrod_teller_c9_hartree_bohr9": 0.0}}
    out["physical_values"]["axilrod_teller_c9_hartree_bohr9"] = setup.physical["c9_hartree_bohr9"]
    ext = report.extension
    if ext is None:
        out["extension"] = None
        return out
    effect = ext.names[-1]
    est = ext.bayes_estimate()
    ci = ext.credible_interval(0.95)[-1]
    entry = {"effect": effect, "estimate": float(est[-1]), "ci95": [float(ci[0]), float(ci[1])]}
    sigma_m, eps_k = float(est[0]) * 1e-9, float(est[1])
    if effect == "axilrod_teller":
        c9 = setup.physical["c9_hartree_bohr9"]
        nu = c9_reduced(c9, eps_k, sigma_m)
        entry["physical"] = nu
        entry["conversion"] = (
            f"nu = C9 / (epsilon sigma^9) with C9 = {c9} hartree bohr^9 (4.3597e-18 J x (5.2918e-11 m)^9) "
            f"at the extension's sigma = {sigma_m:.4e} m, epsilon / k_B = {eps_k:.2f} K: {nu:.4f}"
        )
    elif effect == "feynman_hibbs":
        entry["physical"] = 1.0
        entry["conversion"] = "fh_scale multiplies hbar^2 / (24 mu k T); the physical value is 1"
    else:
        entry["physical"] = None
        entry["conversion"] = "no physical value: the top cause is not the expected one"
    entry["physical_inside_ci95"] = entry["physical"] is not None and ci[0] <= entry["physical"] <= ci[1]
    entry["extension_base_estimate"] = {"sigma_nm": float(est[0]), "epsilon_k": eps_k}
    out["extension"] = entry
    return out


def misfit_figure(report, setup, held: np.ndarray, path: Path) -> str | None:
    """Observed minus predictive mean in noise sd, per summary: base and extension."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    obs = setup.observed
    noise = np.sqrt(np.diag(report.predictive.noise_cov))
    fig, ax = plt.subplots(figsize=(10, 4))
    x = np.arange(obs.size)
    for draws, label, marker in ((report.predictive.draws, "base (LJ)", "o"),):
        ax.plot(x, (obs - np.nanmean(draws, 0)) / noise, marker, label=label)
    if getattr(report, "extension_draws", None) is not None and report.extension is not None:
        ax.plot(x, (obs - np.nanmean(report.extension_draws, 0)) / noise, "s", label=f"+ {report.extension.names[-1]}")
    for i in np.flatnonzero(held):
        ax.axvspan(i - 0.5, i + 0.5, color="0.9", zorder=0)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xticks(x, setup.names, rotation=90, fontsize=6)
    ax.set_ylabel("(observed - predictive mean) / noise sd")
    ax.set_title("Misfit per state point (grey: held out)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name


def physical_markdown(summary: dict, fluid: str, figure: str | None) -> str:
    lines = ["", f"## {fluid.capitalize()}: the refitted effect against its physical value", ""]
    lines.append(
        "The observed values are reference equations of state fitted to measurements (CoolProp), "
        f"not raw measurements: see md/fluids/data/{fluid}/PROVENANCE.md."
    )
    ext = summary.get("extension")
    if ext is None:
        lines.append("\nNo extension was fitted (nothing flagged or no visible cause).")
    else:
        lines.append(
            f"\n- effect `{ext['effect']}`: estimate {ext['estimate']:.4g}, 95 % interval "
            f"[{ext['ci95'][0]:.4g}, {ext['ci95'][1]:.4g}]; physical value "
            f"{'none' if ext['physical'] is None else format(ext['physical'], '.4g')} "
            f"({'inside' if ext['physical_inside_ci95'] else 'outside'} the interval)"
        )
        lines.append(f"- conversion: {ext['conversion']}")
    if figure:
        lines.append(f"\n![misfit per state point]({figure})")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
