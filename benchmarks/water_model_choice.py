"""ABC model choice among five published rigid water models on joint measured data.

Models: TIP4P, TIP4P/2005, TIP4P-Ew, SPC/E and TIP3P (:mod:`md.water.models`), each with its
published charges and geometry and its O-O Lennard-Jones pair calibrated under a uniform prior
around the published values (:func:`md.water.models.model_prior`; ``--prior-width wide`` lets
epsilon run from 0.6x to 2.5x the published value).  Data: the joint measured summaries of
:mod:`md.water.joint_data` (g(r) statistics of the X-ray or neutron data including the second
shell of g_OO, self-diffusion, enthalpy of vaporisation); only the summaries the data file marks
*fitted* enter the distance, the held-out ones (the density) stay in the cache for criticism.
GROMACS runs at the data's temperature (295.15 K for the X-ray data, whose scalars are then
taken at 295.15 K), and the simulated D is Yeh-Hummer corrected to an infinite box
(:mod:`md.water.finite_size`).

Method ``--method surrogate`` (the default): :func:`jaxabc.run` over the five models with
``method="surrogate"``: one GP-surrogate calibration per model on ``--budget-per-model`` GROMACS
runs, model probabilities from the synthetic-likelihood evidences
(:mod:`jaxabc.surrogate.evidence`).  The data's measurement errors
(:func:`md.water.joint_data.observation_sd`: each summary's stated error, or a documented
estimate, with the curves' pointwise errors propagated as a floor) go to ``jaxabc.run(...,
observation_error=sd)``: added analytically to the surrogate's likelihood, as noisy ABC
(Wilkinson 2013) for ABC-SMC, so a summary is fitted within its measurement error, not within
the simulation's much smaller noise.  ``--discrepancy`` adds a model-discrepancy sd per group
of summaries (:class:`jaxabc.Discrepancy`, :func:`discrepancy_for`), inferred with the
parameters under a uniform prior on ``[0, max_sd]``: ``--discrepancy-bounds fixed`` (the default)
takes :data:`DISCREPANCY_GROUPS`' bounds, ``published`` the largest misfit a published rigid model
makes in each group at its own parameters (:mod:`benchmarks._published_bounds`, from
``water_published_predictive.json``).  Each model checkpoints to ``--checkpoint-dir/<model>``;
``--resume`` continues model by model.

Method ``--method abc_smc``: :func:`jaxabc.run` over the five ``(name, simulate, prior)`` models
(:mod:`jaxabc.model_choice`), each simulation one GROMACS run
(:class:`md.water.model_simulator.WaterModelSimulator`) in a process pool; distance: mean
absolute difference of the fitted summaries, each scaled by its median absolute deviation
over ``--pilot`` prior-predictive runs per model (pooled over the models, so no model's spread
sets its own scale).

Resumable: every simulation's output (or failure) is stored under ``--cache-dir`` keyed by the
model, protocol, particle key and theta.  A run is a deterministic function of its seed, so
rerunning the same command after an interruption replays the finished simulations from the
cache and continues where it stopped; its ``wall_time_s`` adds up every sitting
(:class:`jaxabc.executors.progress.SittingClock`, ``<cache-dir>/sittings.json``).

Usage (from the repository root)::

    python -m benchmarks.water_model_choice --data xray --workers 2          # hours of GROMACS
    python -m benchmarks.water_model_choice --data xray --continue           # continue it, or start
    python -m benchmarks.water_model_choice --data xray --prior-width wide --discrepancy --workers 2
    python -m benchmarks.water_model_choice --tiny                           # smoke test, minutes

``--tiny`` runs 2 ps simulations (the surrogate on 50 per model; ABC-SMC on 3 pilot runs and
4 particles per model for 2 generations) and writes
``benchmarks/results/quick/water_model_choice.json``: it shows that the pipeline starts and
saves, its probabilities mean nothing.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxabc
from benchmarks._common import RESULTS, RUNS, command_line, guard_resume, relative, write_result
from benchmarks._published_bounds import PUBLISHED, published_model_bounds
from benchmarks._water_data import DATA_FILES
from jaxabc.executors.progress import SittingClock
from jaxabc.model_choice import Model
from md.water.finite_size import MODEL_VISCOSITY_298K, model_viscosity_mpa_s
from md.water.joint_data import JointData, joint_observed, joint_record, observation_sd
from md.water.model_simulator import CachedSummaries, WaterModelSimulator
from md.water.models import MODELS, WIDE_EPSILON_FACTORS, get_model, model_prior, polarisation_correction_kj_mol

ROOT = Path(__file__).resolve().parents[1]


def parse_arguments(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--data", choices=("xray", "neutron"), default="xray")
    parser.add_argument("--method", choices=("surrogate", "abc_smc"), default="surrogate")
    parser.add_argument("--budget-per-model", type=int, default=200, help="surrogate: GROMACS runs per model")
    parser.add_argument("--checkpoint-dir", type=Path, default=None, help="surrogate: default runs/.../surrogate")
    parser.add_argument("--resume", action="store_true", help="surrogate: continue from --checkpoint-dir")
    parser.add_argument(
        "--continue",
        dest="continue_run",
        action="store_true",
        help="surrogate: resume when --checkpoint-dir holds checkpoints, else start (one command for a run "
        "that spans sittings)",
    )
    parser.add_argument("--predictive", type=int, default=20, help="posterior-predictive runs per model (0: none)")
    parser.add_argument("--preset", choices=("quick", "paper"), default="quick")
    parser.add_argument("--particles", type=int, default=100, help="accepted particles per model and generation")
    parser.add_argument("--steps", type=int, default=8, help="maximum generations, the prior sample included")
    parser.add_argument("--pilot", type=int, default=20, help="prior-predictive runs per model for the scales")
    parser.add_argument("--quantile", type=float, default=0.5)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-simulations", type=int, default=None)
    parser.add_argument("--max-hours", type=float, default=None, help="stop after this wall time (resumable)")
    parser.add_argument("--md-steps", type=int, default=None, help="override the preset's NPT steps (smoke only)")
    parser.add_argument("--cache-dir", type=Path, default=None, help="default runs/cache/water_model_choice/<variant>")
    parser.add_argument(
        "--result-dir",
        type=Path,
        default=None,
        help="per-model posteriors and figures (default benchmarks/results/water_model_choice/<variant>)",
    )
    parser.add_argument("--name", default="water_model_choice", help="result JSON name (a variant's own)")
    parser.add_argument(
        "--prior-width",
        default="default",
        help="'default' (sigma +-5 %%, epsilon +-40 %%), 'wide' (sigma +-5 %%, epsilon x[0.6, 2.5]), "
        "'S,E' (half-widths as fractions), 'S,LOW,HIGH' (sigma half-width, epsilon bounds as factors) or "
        "'SLOW,SHIGH,ELOW,EHIGH' (sigma and epsilon bounds as factors)",
    )
    parser.add_argument(
        "--model-prior",
        action="append",
        default=[],
        metavar="MODEL=WIDTH",
        help="one model's box in --prior-width's terms, replacing it for that model (repeatable), e.g. "
        "TIP3P=0.08,0.35,2.5 where its posterior piles on a bound of the common box",
    )
    parser.add_argument(
        "--discrepancy",
        action="store_true",
        help="infer a model-discrepancy sd per group of summaries (g_OO heights, g_OO lengths, D, hvap)",
    )
    parser.add_argument(
        "--discrepancy-bounds",
        choices=("fixed", "published"),
        default="fixed",
        help="with --discrepancy, each group's max_sd: 'fixed' (DISCREPANCY_GROUPS) or 'published' (the largest "
        "misfit a published rigid model makes in the group, from water_published_predictive.json)",
    )
    parser.add_argument(
        "--emulator-variance",
        default="gp",
        help="surrogate: the emulator's variance, 'gp', 'calibrated' (from failed validations' held-out runs, "
        "with the budget of a second validation kept) or a factor >= 1 (jaxabc.run(emulator_variance=...))",
    )
    parser.add_argument(
        "--hold-out",
        action="append",
        default=[],
        metavar="SUMMARY",
        help="move a fitted summary to the held-out ones (repeatable), e.g. r_oo_max2_nm, whose window maximum "
        "is discontinuous in the parameters where a model's second shell is flat (water_emulator_failures)",
    )
    parser.add_argument("--tiny", action="store_true", help="smoke test: tiny budgets, 2 ps runs, quick JSON")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    if args.tiny:
        args.particles, args.steps, args.pilot = 4, 2, 3
        args.md_steps = args.md_steps or 1000
        args.budget_per_model, args.predictive = 50, 2
    args.model_prior = model_priors(args.model_prior)
    suffix = f"{args.data}_{args.preset}" + ("_tiny" if args.tiny else "")
    variant = (
        suffix
        + ("" if args.prior_width == "default" else f"_{args.prior_width}")
        + "".join(f"_{slug}{width.replace(',', '-')}" for slug, (width, _) in sorted(args.model_prior.items()))
        + ("_discrepancy" if args.discrepancy else "")
        + ("_dbounds-published" if args.discrepancy and args.discrepancy_bounds == "published" else "")
        + ("" if args.seed == 0 else f"_seed{args.seed}")
        + ("" if args.emulator_variance == "gp" else f"_emulator_variance_{args.emulator_variance}")
        + "".join(f"_holdout-{name}" for name in sorted(args.hold_out))
    )
    if args.emulator_variance not in ("gp", "calibrated"):
        args.emulator_variance = float(args.emulator_variance)
    # Simulations and checkpoints are a cache (runs/ is not tracked); the posteriors a page shows
    # are results.
    args.cache_dir = args.cache_dir or RUNS / "cache" / "water_model_choice" / variant
    args.result_dir = args.result_dir or (
        args.cache_dir / "result" if args.tiny else ROOT / "benchmarks" / "results" / "water_model_choice" / variant
    )
    args.checkpoint_dir = args.checkpoint_dir or args.cache_dir / "surrogate"
    if args.continue_run and any(args.checkpoint_dir.glob("*/checkpoint.npz")):
        args.resume = True
    args.prior_options = prior_options(args.prior_width)
    # The data's temperature (295.15 K for X-ray), the temperature the simulations run at.
    args.temperature_k = joint_observed(args.data).temperature_k
    return args


def prior_options(width: str) -> dict:
    """``model_prior`` keyword arguments for ``--prior-width``."""
    if width == "default":
        return {}
    if width == "wide":
        return {"epsilon_factors": WIDE_EPSILON_FACTORS}
    try:
        values = [float(v) for v in width.split(",")]
    except ValueError:
        values = []
    if len(values) == 2:
        return {"relative_half_width": tuple(values)}
    if len(values) == 3:
        return {"relative_half_width": (values[0], 0.4), "epsilon_factors": tuple(values[1:])}
    if len(values) == 4:
        return {"sigma_factors": tuple(values[:2]), "epsilon_factors": tuple(values[2:])}
    raise SystemExit(
        f"--prior-width must be 'default', 'wide', 'S,E', 'S,LOW,HIGH' or 'SLOW,SHIGH,ELOW,EHIGH', got {width!r}"
    )


def box_prior(model, options: dict) -> jaxabc.Uniform:
    """:func:`model_prior` with ``options``; ``sigma_factors`` (an asymmetric sigma box, as
    multiples of the published sigma) replaces sigma's half-width."""
    options = dict(options)
    sigma = options.pop("sigma_factors", None)
    prior = model_prior(model, **options)
    if sigma is None:
        return prior
    if not 0 < sigma[0] < 1 < sigma[1]:
        raise ValueError(f"sigma factors must satisfy 0 < low < 1 < high, got {sigma!r}")
    # Copies: under x64 np.asarray is a read-only view of the prior's bounds.
    low, high = np.array(prior.low, np.float64), np.array(prior.high, np.float64)
    low[0], high[0] = get_model(model).lj[0] * np.asarray(sigma)
    return jaxabc.Uniform(low=low.tolist(), high=high.tolist(), names=prior.names, units=prior.units)


def model_priors(items: list[str]) -> dict[str, tuple[str, dict]]:
    """``--model-prior`` values (``MODEL=WIDTH``) as ``{slug: (width, model_prior options)}``."""
    out: dict[str, tuple[str, dict]] = {}
    for item in items:
        name, _, width = item.partition("=")
        try:
            slug = get_model(name).slug
        except ValueError as error:
            raise SystemExit(f"--model-prior wants MODEL=WIDTH with a known model, got {item!r}: {error}") from None
        if slug in out:
            raise SystemExit(f"--model-prior names {name!r} twice")
        out[slug] = (width, prior_options(width))
        try:  # a bad width fails here, not after hours of simulations
            box_prior(slug, out[slug][1])
        except ValueError as error:
            raise SystemExit(f"--model-prior {item!r}: {error}") from None
    return out


def prior_of(args, model) -> jaxabc.Uniform:
    """A model's prior: ``--model-prior``'s box for it, else ``--prior-width``'s."""
    width = args.model_prior.get(model.slug)
    return box_prior(model, args.prior_options if width is None else width[1])


def protocol_overrides(args) -> dict:
    overrides = {"temperature_k": args.temperature_k}
    if args.md_steps is None:
        return overrides
    # Keep the last 80 % of a shortened run, as water_calibration.py does.
    return {**overrides, "num_steps": args.md_steps, "analysis_start_ps": 0.2 * args.md_steps * 0.002}


def make_models(args, fitted: np.ndarray) -> list[Model]:
    models = []
    for model in MODELS.values():
        simulate = WaterModelSimulator(model, args.preset, "robust", args.data, **protocol_overrides(args))
        cached = CachedSummaries(simulate, fitted, args.cache_dir)
        models.append(Model(model.name, cached, prior_of(args, model)))
    return models


#: Discrepancy groups by unit: g values, lengths (nm: positions and the S3/S6 integrals), D,
#: enthalpy; and each group's prior bound, several times the largest misfit the first model
#: choice found (S7 0.4, S5 0.05 nm, D 2.7e-5 cm2/s, hvap 5 kJ/mol; water_model_choice.json).
DISCREPANCY_GROUPS = {
    "gOO_heights": (("S1", "S4", "S7", "g_oo_min1", "g_oo_max2"), 1.0),
    "gOO_lengths_nm": (("S2", "S3", "S5", "S6", "S8", "r_oo_max2_nm"), 0.2),
    "D": (("S9",), 10.0),
    "hvap": (("hvap_kj_mol",), 20.0),
}


def discrepancy_groups(fitted_names: list[str]) -> dict[str, list[int]]:
    """Each group of :data:`DISCREPANCY_GROUPS` with a fitted summary, as indices into the fitted vector."""
    groups = {}
    for group, (names, _) in DISCREPANCY_GROUPS.items():
        idx = [fitted_names.index(n) for n in names if n in fitted_names]
        if idx:
            groups[group] = idx
    return groups


def discrepancy_for(fitted_names: list[str], bounds: dict[str, float] | None = None) -> jaxabc.Discrepancy:
    """A :class:`jaxabc.Discrepancy` over the fitted summaries (indices into the fitted vector);
    ``bounds`` replaces the fixed ``max_sd`` of the groups it names.

    Raises
    ------
    ValueError
        ``bounds`` names a group that is not one of :data:`DISCREPANCY_GROUPS` with a fitted summary.
    """
    groups = discrepancy_groups(fitted_names)
    unknown = sorted(set(bounds or {}) - set(groups))
    if unknown:
        raise ValueError(f"discrepancy bounds for {unknown}: not a group with a fitted summary ({list(groups)})")
    max_sd = [(bounds or {}).get(group, DISCREPANCY_GROUPS[group][1]) for group in groups]
    return jaxabc.Discrepancy(max_sd, groups)


def discrepancy_bounds(args, fitted_names: list[str]) -> dict[str, float] | None:
    """``--discrepancy-bounds published``: each group's bound from the published models' runs
    (None for the fixed bounds).

    Raises
    ------
    FileNotFoundError
        ``water_published_predictive.json`` is not saved.
    ValueError
        Those runs are for other data or another temperature, or lack a group's summary.
    """
    if getattr(args, "discrepancy_bounds", "fixed") != "published":
        return None
    path = RESULTS / f"{PUBLISHED}.json"
    if not path.is_file():
        raise FileNotFoundError(f"--discrepancy-bounds published needs {path}: run python -m benchmarks.{PUBLISHED}")
    published = json.loads(path.read_text())
    return published_model_bounds(
        published, fitted_names, discrepancy_groups(fitted_names), args.data, float(args.temperature_k)
    )


def model_choice_data(args) -> JointData:
    """The measured summaries of ``--data`` with the summaries of ``--hold-out`` moved from the
    fitted to the held-out ones.

    Raises
    ------
    ValueError
        A ``--hold-out`` name that is not a fitted summary of the data.
    """
    data = joint_observed(args.data)
    names = list(data.names)
    fitted = np.array(data.fitted, bool)
    held_out = np.array(data.held_out, bool)
    for name in args.hold_out:
        if name not in names or not fitted[names.index(name)]:
            fitted_names = [n for n, f in zip(names, fitted, strict=True) if f]
            raise ValueError(f"--hold-out {name!r}: not a fitted summary of the {args.data} data ({fitted_names})")
        fitted[names.index(name)], held_out[names.index(name)] = False, True
    return data._replace(fitted=fitted, held_out=held_out)


def fitted_sd(args, data: JointData) -> np.ndarray:
    """:func:`md.water.joint_data.observation_sd` of the data's fitted summaries (``--hold-out``
    ones left out), in the fitted order."""
    full = joint_observed(args.data)
    sd = dict(zip(np.array(full.names)[full.fitted], observation_sd(args.data), strict=True))
    return np.array([sd[n] for n, f in zip(data.names, data.fitted, strict=True) if f], np.float64)


#: How the measurement error reaches the likelihood, as the result records it.
NOISE_VIA = "jaxabc.run(observation_error=sd)"


def noise_options(args, data) -> dict:
    """The ``jaxabc.run`` keywords that carry the data's measurement error,
    ``observation_error=sd``, and with ``--discrepancy`` the model discrepancy."""
    sd = fitted_sd(args, data)
    fitted_names = [n for n, f in zip(data.names, data.fitted, strict=True) if f]
    options: dict = {"observation_error": sd}
    if args.discrepancy:
        options["discrepancy"] = discrepancy_for(fitted_names, discrepancy_bounds(args, fitted_names))
    return options


def pilot_scales(args, models: list[Model], executor) -> tuple[np.ndarray, dict]:
    """Median absolute deviation of each fitted summary over the pooled pilot runs."""
    pooled, failures = [], {}
    for index, model in enumerate(models):
        key = jax.random.fold_in(jax.random.key(args.seed + 1_000_003), index)
        thetas = np.asarray(model.prior.sample(key, args.pilot), dtype=np.float64)
        keys = np.asarray(jax.random.key_data(jax.random.split(jax.random.fold_in(key, 1), args.pilot)))
        batch = executor.map(model.simulate, keys, thetas)
        pooled.append(batch.summaries[batch.status == 0])
        failures[model.name] = {"failed": int(np.sum(batch.status != 0)), "reasons": sorted(set(batch.reasons))}
    good = np.concatenate(pooled)
    if good.shape[0] < 3:
        raise RuntimeError(f"only {good.shape[0]} pilot simulations succeeded: {failures}")
    mad = np.median(np.abs(good - np.median(good, axis=0)), axis=0)
    return np.where(mad > 0, mad, 1.0), {"num_runs": int(good.shape[0]), "failures": failures}


def scaled_mean_abs(scale: np.ndarray):
    scale_j = jnp.asarray(scale)

    def distance(observed, simulated):
        return jnp.mean(jnp.abs(jnp.asarray(observed) - jnp.asarray(simulated)) / scale_j)

    return distance


def simulator_id(args) -> str:
    """Names everything a checkpoint's simulations depend on, so a resume cannot mix them."""
    width = ",".join(f"{k}={v}" for k, v in sorted(args.prior_options.items())) or "default"
    width += "".join(f":{slug}.prior={spec}" for slug, (spec, _) in sorted(args.model_prior.items()))
    return (
        f"water_model_choice:{args.data}:{args.preset}:{args.md_steps}:T={args.temperature_k}"
        f":summaries=14:yeh_hummer:prior={width}" + "".join(f":held_out={name}" for name in sorted(args.hold_out))
    )


def run_surrogate(args, data, models: list[Model], executor):
    """Model choice by surrogate evidence, with the data's measurement errors."""
    options = noise_options(args, data)
    guard_resume(args.checkpoint_dir, args.resume, modules=("jaxabc.surrogate", "jaxabc.model_choice"))
    return jaxabc.run(
        models,
        observed=data.observed[data.fitted],
        method="surrogate",
        max_simulations=args.budget_per_model * len(models),
        num_particles=2000,
        seed=args.seed,
        executor=executor,
        checkpoint_dir=args.checkpoint_dir,
        resume=args.resume,
        # A smoke test (and the quick-mode check) starts over: its simulations stay cached.
        overwrite=args.tiny and not args.resume,
        simulator_id=simulator_id(args),
        progress=not args.no_progress,
        batch_size=2 * args.workers,
        # Only when asked for: the default's checkpoints keep their fingerprints.
        **({} if args.emulator_variance == "gp" else {"emulator_variance": args.emulator_variance}),
        **options,
    )


def run_abc_smc(args, data, models: list[Model], executor):
    scales, pilot = pilot_scales(args, models, executor)
    options = noise_options(args, data)
    result = jaxabc.run(
        models,
        observed=data.observed[data.fitted],
        num_particles=args.particles,
        num_steps=args.steps,
        distance=scaled_mean_abs(scales),
        seed=args.seed,
        executor=executor,
        quantile=args.quantile,
        max_simulations=args.max_simulations,
        max_wall_time=None if args.max_hours is None else 3600.0 * args.max_hours,
        progress=not args.no_progress,
        dtype="float64",
        **options,
    )
    return result, scales, pilot


def model_rows(result) -> dict:
    """Per model: posterior against the published pair, cost, and (surrogate) validation."""
    rows = {}
    intervals = result.metadata.get("probability_interval_95")
    for i, (name, post) in enumerate(zip(result.names, result.posteriors, strict=True)):
        diag = post.diagnostics
        rows[name] = {
            "probability": float(result.probabilities[i]),
            "probability_interval_95": None if intervals is None else intervals[i],
            "bayes_estimate": post.bayes_estimate().tolist(),
            "credible_interval_95": post.credible_interval(0.95).tolist(),
            "correlation": float(post.correlation()[0, 1]),
            "num_simulations": post.num_simulations,
            "num_failures": post.num_failures,
            "validated": diag.get("validated"),
            "validation_failure": diag.get("failure"),
            "holdout_coverage_95": diag.get("holdout_coverage_95"),
            "holdout_mean_squared_error": diag.get("holdout_mean_squared_error"),
            "log_evidence_importance_se": diag.get("log_evidence_importance_se"),
            "log_evidence_jackknife_se": diag.get("log_evidence_jackknife_se"),
            "observed_misfit": diag.get("observed_misfit"),
        }
    return rows


def _predictive_run(task) -> dict | None:
    """Worker: one posterior-predictive run of a model (cached in ``path``; None if it failed)."""
    name, preset, data, overrides, seed, theta, path = task
    path = Path(path)
    if path.is_file():
        with np.load(path) as stored:
            return None if bool(stored["failed"]) else {k: stored[k] for k in stored.files if k != "failed"}
    from jaxabc.errors import SimulationFailure
    from md.water.model_simulator import WaterModelSimulator
    from md.water.statistics import ROBUST_GRID_NM

    simulate = WaterModelSimulator(name, preset, "robust", data, **overrides)
    try:
        out = simulate.run(np.array([3, seed], np.uint32), theta)
    except SimulationFailure:
        np.savez(path.with_suffix(".tmp.npz"), failed=True)
        os.replace(path.with_suffix(".tmp.npz"), path)
        return None
    c = out.curves
    values = {
        "g_oo": np.interp(ROBUST_GRID_NM, c.r_oo_nm, c.g_oo),
        "g_oh": np.interp(ROBUST_GRID_NM, c.r_oh_nm, c.g_oh),
        "scalars": np.array([out.statistics[8], out.density_kg_m3, out.hvap_kj_mol]),
    }
    np.savez(path.with_suffix(".tmp.npz"), failed=False, **values)
    os.replace(path.with_suffix(".tmp.npz"), path)
    return values


#: The predictive's scalar summaries (robust statistics), in the worker's order.
PREDICTIVE_SCALARS = ("S9 self-diffusion 1e-5 cm2/s", "density kg/m3", "hvap kJ/mol")


def predictive_bands(args, result) -> dict:
    """Per model: 5/25/50/75/95 % points of g_OO, g_OH and the scalars over ``--predictive``
    runs at posterior draws (the simulated quantities, without measurement error)."""
    import concurrent.futures
    import multiprocessing

    from md.water.statistics import ROBUST_GRID_NM

    folder = args.cache_dir / "predictive"
    folder.mkdir(parents=True, exist_ok=True)
    tasks, owners = [], []
    for name, post in zip(result.names, result.posteriors, strict=True):
        draws = post.resample(args.predictive, seed=args.seed)
        stem = name.replace("/", "_")
        for i, draw in enumerate(draws):
            # The model's own parameters (sigma_OO, epsilon_OO); a discrepancy's sds are not
            # simulated: the bands are the simulator's, without measurement error or discrepancy.
            theta = np.asarray(draw, np.float64)[:2]
            # Keyed by theta and the simulator too: a rerun with another posterior or protocol
            # must not replay these runs.
            digest = hashlib.sha256(np.asarray(theta, np.float64).tobytes() + simulator_id(args).encode()).hexdigest()[
                :12
            ]
            path = folder / f"{stem}-{args.seed}-{i}-{digest}.npz"
            tasks.append((name, args.preset, args.data, protocol_overrides(args), i, theta, str(path)))
            owners.append(name)
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(args.workers, mp_context=context) as pool:
        outputs = list(pool.map(_predictive_run, tasks))
    levels = [0.05, 0.25, 0.5, 0.75, 0.95]
    bands = {"r_nm": ROBUST_GRID_NM.tolist(), "levels": levels, "scalar_names": list(PREDICTIVE_SCALARS), "models": {}}
    for name in result.names:
        runs = [o for o, owner in zip(outputs, owners, strict=True) if owner == name and o is not None]
        entry = {"num_runs": len(runs), "num_failed": owners.count(name) - len(runs)}
        if runs:
            for key in ("g_oo", "g_oh", "scalars"):
                entry[key] = np.quantile(np.array([r[key] for r in runs]), levels, axis=0).tolist()
        bands["models"][name] = entry
    return bands


def plot_predictive(bands: dict, data: str, path: Path) -> None:
    """g_OO median and 5-95 % band per model over the measured curve."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from md.water import datasets

    r = np.array(bands["r_nm"])
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, (name, entry) in enumerate(bands["models"].items()):
        if "g_oo" not in entry:
            continue
        q = np.array(entry["g_oo"])
        ax.fill_between(r, q[0], q[-1], color=f"C{i}", alpha=0.2)
        ax.plot(r, q[2], color=f"C{i}", lw=1, label=name)
    curve = datasets.xray_goo() if data == "xray" else datasets.neutron_curves()["OO"]
    ax.plot(curve.r_nm, curve.g, "k-", lw=1.5, label=f"measured ({data})")
    ax.set_xlim(0.22, 0.8)
    ax.set_xlabel("r [nm]")
    ax.set_ylabel("g_OO(r)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> None:
    args = parse_arguments(argv)
    # Wall time over every sitting of a resumed run; a run started over forgets earlier sittings.
    clock = SittingClock(args.cache_dir / "sittings.json", fresh=not args.resume)
    with clock:
        payload = run(args)
        payload["wall_time_s"] = clock.total_seconds()
        payload["wall_time_sittings"] = clock.num_sittings
    inputs = DATA_FILES[args.data]
    if args.discrepancy and args.discrepancy_bounds == "published":
        inputs = [*inputs, RESULTS / f"{PUBLISHED}.json"]
    path = write_result(args.name, payload, quick=args.tiny, inputs=inputs, command=command_line(argv))
    print(f"wrote {path}")


def run(args) -> dict:
    """The model choice of ``args``, its posteriors saved; the result's payload (no wall time)."""
    data = model_choice_data(args)
    models = make_models(args, data.fitted)
    timeout_s = models[0].simulate.simulate.protocol.timeout_s + 60
    executor = jaxabc.ProcessPoolExecutor(max_workers=args.workers, timeout=timeout_s)
    scales, pilot = None, None
    noise_kwargs = noise_options(args, data)
    try:
        if args.method == "surrogate":
            result = run_surrogate(args, data, models, executor)
        else:
            result, scales, pilot = run_abc_smc(args, data, models, executor)
    finally:
        executor.close()
    print(result.summary())
    # The per-model posteriors (npz) beside the simulations: the criticism of the preferred
    # model starts from them (benchmarks/criticism_water_joint.py).
    saved = result.save(args.result_dir, overwrite=True)
    verdict = result.verdict()
    print(f"verdict: {verdict.status}{' ' + verdict.model if verdict.model else ''}: {verdict.reason}")
    bands = predictive_bands(args, result) if args.predictive else None
    if bands is not None:
        plot_predictive(bands, args.data, saved.parent / "predictive_goo.png")
    fitted_names = [n for n, f in zip(data.names, data.fitted, strict=True) if f]
    payload = {
        "data": args.data,
        "preset": args.preset,
        "tiny": args.tiny,
        "method": args.method,
        "settings": {
            "budget_per_model": args.budget_per_model if args.method == "surrogate" else None,
            "particles": args.particles,
            "steps": args.steps,
            "pilot_per_model": args.pilot,
            "quantile": args.quantile,
            "seed": args.seed,
            "md_steps": args.md_steps,
            "workers": args.workers,
            "temperature_k": args.temperature_k,
            "prior_width": args.prior_width,
            "prior_options": {k: list(v) for k, v in args.prior_options.items()},
            "model_prior_width": {
                m.name: args.model_prior[m.slug][0] for m in MODELS.values() if m.slug in args.model_prior
            },
            "discrepancy": None if "discrepancy" not in noise_kwargs else noise_kwargs["discrepancy"].describe(),
        }
        | ({} if args.emulator_variance == "gp" else {"emulator_variance": args.emulator_variance})
        | ({"held_out_from_fitted": sorted(args.hold_out)} if args.hold_out else {}),
        "summaries": {
            "names": list(data.names),
            "observed": data.observed.tolist(),
            "stated_errors": [None if np.isnan(e) else float(e) for e in data.errors],
            "fitted": fitted_names,
            "held_out": [n for n, h in zip(data.names, data.held_out, strict=True) if h],
            "distance_scales": None
            if scales is None
            else dict(zip(fitted_names, np.asarray(scales).tolist(), strict=True)),
            "observation_sd": dict(zip(fitted_names, fitted_sd(args, data).tolist(), strict=True)),
            "observation_error_via": NOISE_VIA,
            "propagated_pointwise_errors": [
                None if np.isnan(e) else float(e) for e in np.asarray(data.propagated, np.float64)
            ],
        },
        "finite_size": {
            "method": "Yeh & Hummer 2004: D_inf = D_box + xi kB T / (6 pi eta L), xi = 2.837297; L the run's mean box "
            "edge; eta the model's published 298 K viscosity scaled by water's eta(T)/eta(298 K)",
            "viscosity_mpa_s_at_temperature": {
                name: model_viscosity_mpa_s(name, args.temperature_k) for name in MODELS
            },
            "viscosity_298K_sources": {name: v["source"] for name, v in MODEL_VISCOSITY_298K.items()},
        },
        "data_record": joint_record(),
        "pilot": pilot,
        "models": {
            m.name: {
                "citation": m.citation,
                "num_sites": m.num_sites,
                "charge_h_e": m.charge_h_e,
                "om_distance_nm": m.om_distance_nm,
                "published_lj": list(m.lj),
                "prior_low": np.asarray(prior_of(args, m).low).tolist(),
                "prior_high": np.asarray(prior_of(args, m).high).tolist(),
                "dipole_debye": m.dipole_debye,
                "polarisation_correction_kj_mol": polarisation_correction_kj_mol(m),
            }
            for m in MODELS.values()
        },
        "model_choice": result.to_dict(),
        "verdict": {"status": verdict.status, "model": verdict.model, "reason": verdict.reason},
        "sensitivity": [
            {
                "label": row.label,
                "status": row.status,
                "probabilities": np.asarray(row.probabilities, np.float64).tolist(),
                "intervals": np.asarray(row.intervals, np.float64).tolist(),
            }
            for row in result.sensitivity_table
        ],
        "prior_edge": result.prior_edge,
        "per_model": model_rows(result),
        "predictive": bands,
        "cache_dir": relative(args.cache_dir),
        "saved_result": relative(saved.parent),
    }
    return payload


if __name__ == "__main__":
    main()
