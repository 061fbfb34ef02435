"""Where the surrogate's paper-preset X-ray estimate leaves the paper's, and why.

The GP-surrogate calibration of the paper's preset (``water_xray_surrogate_paper_preset`` in
``benchmarks/registry.py``) keeps its checkpoint under ``runs/cache`` (untracked).  This takes the
finished run's surrogate state from it into the results folder (or, without the checkpoint, uses
the state kept there), restores it, refits the emulator its reported draws came from (the design
loop's fit, warm-started from the run's last hyper-parameters, ``state.hyper``) and reports

- the posterior predictive check of the observed summaries
  (:func:`jaxabc.surrogate.evidence.observed_misfit`, over the saved posterior draws);
- at the surrogate's Bayes estimate, the paper's estimate and TIP4P's own parameters: the
  emulated summaries, each summary's residual ``(observed - emulated) / sd`` with ``sd`` the
  simulator noise and emulator spread, the synthetic log-likelihood and the chance that a run
  succeeds there, and the paper's own distance (mean absolute difference of the statistics,
  with the run's scales) between the observed and the emulated summaries;
- the two fits of the same design rows: that one, and the refit from the default starts that
  the held-out check and the evidence use (:func:`jaxabc.surrogate.evidence.likelihood_from_state`):
  each one's GP objective (negative log marginal likelihood plus the hyper-prior, summed over
  the outputs), length scales, log posterior at the three points, and the posterior mean and sd
  of an importance sample over the box.  Where the two optima score alike but put the posterior
  in different places, the estimate is conditional on which optimum the fit found.

No GROMACS run is made: everything comes from the saved design.

Usage::

    python -m benchmarks.water_misfit
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks._common import RUNS, machine, relative, write_result
from benchmarks.registry import paper_preset_cache
from jaxabc.priors import Uniform
from jaxabc.surrogate import build, design, emulator, evidence, sampling
from md.water.gromacs import TIP4P_PARAMETERS

ROOT = Path(__file__).resolve().parents[1]

FOLDER = ROOT / "benchmarks" / "results" / "water_paper_preset"
#: The run's checkpoint (untracked, where the registry's command keeps it).
CHECKPOINT = RUNS / paper_preset_cache("checkpoint", "xray") / "checkpoint.npz"
RESULT = FOLDER / "water_xray_surrogate.json"
RECORD = FOLDER / "water_xray_paper_surrogate.npz"
#: The finished run's surrogate state, taken from its checkpoint and kept beside its result, so
#: that this study reruns without the checkpoint.
STATE = FOLDER / "water_xray_paper_surrogate_state.npz"
#: Settings of the saved run that shape its fit (the rest only steer the design).
_FIT_SETTINGS = ("num_initial", "num_replicates", "batch_size", "num_holdout", "max_outputs", "min_feasibility")
#: Importance points per fit for the posterior moments (the run's own candidate count), and their seed.
_POOL, _POOL_SEED = 4096, 0


def _restore(entry: dict, low: np.ndarray, high: np.ndarray):
    settings = entry["settings"]
    algorithm = build(
        Uniform(low, high),
        settings["num_particles"],
        observed=np.asarray(entry["observed"], np.float64),
        max_simulations=settings["max_simulations"],
        **{k: settings[k] for k in _FIT_SETTINGS},
    )
    with np.load(STATE, allow_pickle=False) as data:
        flat = {k: data[k] for k in data.files}
    return algorithm, algorithm.restore_state(flat)


def take_state(checkpoint: Path, record: Path, state: Path) -> bool:
    """Copy the surrogate state of ``checkpoint`` to ``state`` when the checkpoint is the saved
    run's (its posterior draws and simulation records equal ``record``'s); False when there is no
    checkpoint.  A checkpoint of another run exits (``SystemExit``) rather than mix the two."""
    if not checkpoint.is_file():
        return False
    if not record.is_file():
        raise SystemExit(
            f"{relative(record)} is missing: the checkpoint {relative(checkpoint)} can only be taken "
            "once its run has finished and saved its result"
        )
    with np.load(checkpoint, allow_pickle=False) as c, np.load(record, allow_pickle=False) as r:
        same = (
            "posterior/particles" in c.files
            and np.array_equal(c["posterior/particles"], r["particles"])
            and np.array_equal(c["records/theta"], r["record_theta"])
        )
        if not same:
            raise SystemExit(
                f"{relative(checkpoint)} is not the checkpoint of the run saved in {relative(record)} "
                "(its posterior draws or simulations differ): finish that run, or remove the checkpoint to "
                f"use the state kept in {relative(state)}"
            )
        flat = {k.removeprefix("state/"): c[k] for k in c.files if k.startswith("state/")}
    np.savez_compressed(state, **flat)
    return True


def at_point(model, transform, x: np.ndarray, observed: np.ndarray, scale: np.ndarray) -> dict:
    """Emulated summaries and residuals at one unit-box point ``x (d,)``."""
    mean, _ = emulator.predict(model.emulator, jnp.asarray(x[None, :]))
    z = np.asarray(mean[0], np.float64)
    rotation = np.asarray(transform.rotation, np.float64)
    t_scale, t_mean = np.asarray(transform.scale, np.float64), np.asarray(transform.mean, np.float64)
    emulated = t_mean + t_scale * (z @ rotation.T)
    loglik, _ = sampling.log_likelihood_terms(model, jnp.asarray(x[None, :]))
    return {
        "emulated_summaries": emulated.tolist(),
        # The predictive check at one draw: this point's residuals in noise-plus-emulator sd.
        "residual_sd": evidence.observed_misfit(model, transform, x[None, :])["standardised_residuals"],
        "synthetic_log_likelihood": float(loglik[0]),
        "success_probability": float(sampling.feasibility(model.feasible, jnp.asarray(x[None, :]))[0]),
        "paper_distance": float(np.mean(np.abs(observed - emulated) / scale)),
    }


def sampled_fit(state, low: np.ndarray, high: np.ndarray, observed: np.ndarray, settings: dict):
    """``(transform, emulator, model)`` of the fit the run's draws came from: started from
    ``state.hyper`` (and the default starts, :func:`jaxabc.surrogate.evidence.likelihood_from_state`)."""
    transform, model = evidence.likelihood_from_state(state, low, high, observed, settings)
    return transform, model.emulator, model


def fit_summary(emu, model, low: np.ndarray, high: np.ndarray, points: dict[str, np.ndarray]) -> dict:
    """One fit's objective, length scales, log posterior at ``points`` and posterior moments."""

    def evaluate(x: np.ndarray) -> tuple[np.ndarray]:
        return (np.asarray(sampling.log_posterior(model, jnp.asarray(x)), np.float64),)

    pool, (lp,) = design.importance_pool(np.random.default_rng(_POOL_SEED), len(low), _POOL, evaluate)
    log_w = lp - pool.log_q
    w = np.exp(log_w - np.max(log_w))
    w /= w.sum()
    theta = low + pool.x * (high - low)
    mean = w @ theta
    return {
        "gp_objective": emulator.objective(emu),
        "length_scales": np.exp(np.asarray(emu.log_ls, np.float64)).tolist(),
        "log_posterior": {
            name: float(evaluate(((theta_p - low) / (high - low))[None, :])[0][0]) for name, theta_p in points.items()
        },
        "posterior_mean": mean.tolist(),
        "posterior_sd": np.sqrt(w @ (theta - mean) ** 2).tolist(),
        "importance_ess": float(1.0 / np.sum(w**2)),
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument(
        "--checkpoint", type=Path, default=CHECKPOINT, help="the run's checkpoint (default: the registry's)"
    )
    args = parser.parse_args(argv)
    if take_state(args.checkpoint, RECORD, STATE):
        print(f"took the surrogate state of {relative(args.checkpoint)} into {relative(STATE)}")
    elif not STATE.is_file():
        raise SystemExit(f"no checkpoint at {relative(args.checkpoint)} and no saved state at {relative(STATE)}")
    with jax.enable_x64(True):  # scoped: a caller's process keeps its precision
        entry = json.loads(RESULT.read_text())["paper"]
        with np.load(RECORD, allow_pickle=False) as rec:
            prior = json.loads(str(rec["metadata"]))["prior"]
        low, high = np.asarray(prior["low"], np.float64), np.asarray(prior["high"], np.float64)
        algorithm, state = _restore(entry, low, high)
        observed = np.asarray(entry["observed"], np.float64)
        scale = np.asarray(entry["scale"], np.float64)
        transform, emu, model = sampled_fit(state, low, high, observed, algorithm.settings)
        lw = np.asarray(state.log_weights, np.float64)
        x_draws = (np.asarray(state.draws, np.float64) - low) / (high - low)
        misfit = evidence.observed_misfit(model, transform, x_draws, np.exp(lw - np.max(lw)))
        points = {
            "surrogate_estimate": np.asarray(entry["bayes_estimate"], np.float64),
            "paper_estimate": np.asarray(entry["paper"]["bayes_estimate"], np.float64),
            "tip4p": np.array([TIP4P_PARAMETERS.sigma_ow_nm, TIP4P_PARAMETERS.epsilon_ow_kj_mol]),
        }
        _, refit_model = evidence.likelihood_from_state(state, low, high, observed, algorithm.settings)
        refit_emu = refit_model.emulator
        at = {
            name: {"theta": theta.tolist()} | at_point(model, transform, (theta - low) / (high - low), observed, scale)
            for name, theta in points.items()
        }
        payload = {
            "machine": machine(),
            "source": relative(RESULT),
            "statistics": entry["statistics"],
            "statistic_names": entry["statistic_names"],
            "observed": observed.tolist(),
            "noise_sd": (np.exp(np.asarray(model.emulator.log_noise)) * np.asarray(transform.scale)).tolist()
            if transform.rotation.shape[0] == transform.rotation.shape[1]
            else None,
            "observed_misfit": misfit,
            "points": at,
            "fits": {
                "sampled": {"description": "the design loop's fit, warm-started from state.hyper: the draws' own"}
                | fit_summary(emu, model, low, high, points),
                "refit": {"description": "refitted from the default starts: the held-out check's and the evidence's"}
                | fit_summary(refit_emu, refit_model, low, high, points),
            },
        }
    out = write_result("water_misfit", payload, inputs=[STATE, RESULT, RECORD])
    print(json.dumps({k: payload[k] for k in ("observed_misfit", "points", "fits")}, indent=1))
    print(f"wrote {relative(out)}")
    return payload


if __name__ == "__main__":
    main()
