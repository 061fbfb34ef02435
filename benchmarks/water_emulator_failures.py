"""Where the water model choice's emulators fail validation, and why.

Reads every saved repeat of the model choice (:data:`benchmarks._water_repeats.REPEATS`)
and makes no GROMACS run.  For each repeat and model it reports which validation checks failed
and the summary, the parameters and the side of the network break of the worst-predicted
held-out run.  Pooling each model's runs over the repeats, it maps where the hydrogen-bond network
of the quick-preset liquid breaks:

- a run is *broken* when its first g_OO minimum (S5) lies at or beyond :data:`BROKEN_S5_NM`;
  the simulated S5 is bimodal (modes near the measured 0.347 nm and near 0.44 nm, the counts in
  between are reported), so the threshold separates two structures, not two ends of a scale;
- the share of broken runs by ``sigma / published`` at high epsilon, and the summaries' means
  on each side next to the boundary, in units of their stated measurement error;
- each run's posterior share whose nearest design runs (:data:`NEIGHBOURS` in the unit box) are
  all broken (beyond the break) or mixed (on it).

Then where the held-out errors' tails sit (:func:`refit_errors`): each emulator refitted as at its
last validation (the library's own fit on the saved design; it reproduces the saved held-out
errors), its design rows' leave-one-out standardised errors as the reference, and the held-out
errors split by how the run was placed (random or targeted, where the emulator is least sure) and
by the emulator-to-noise variance ratio at the run, in :data:`RATIO_QUANTILES` bins.

Last, the library's calibrated emulator variance (``emulator_variance="calibrated"``): the
factor each emulator's held-out runs measure, judged on runs it was not estimated from
(:func:`calibrated_errors`), and each repeat's evidences, probabilities and verdict with the
GP's variance and with that factor (:func:`calibrated_verdicts`).

Usage::

    python -m benchmarks.water_emulator_failures [--quick]
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path
from typing import Any

import numpy as np
import scipy.stats

from benchmarks._common import RESULTS, ROOT, machine, relative, write_result
from benchmarks._water_repeats import REPEATS, made_with_gp_variance
from jaxabc.surrogate import emulator
from jaxabc.surrogate._fit import ROLE_DESIGN, ROLE_HOLDOUT
from jaxabc.surrogate._validation import num_targeted
from jaxabc.surrogate.diagnostics import holdout_bounds, lack_of_fit, local_check, replicate_variance
from jaxabc.surrogate.evidence import likelihood_from_state

#: First-minimum position (nm) from which a run counts as broken: between the simulated modes.
BROKEN_S5_NM = 0.40
#: Design runs whose labels decide where a posterior draw lies.
NEIGHBOURS = 5
#: Epsilon (as a multiple of the published value) from which both structures occur.
HIGH_EPSILON = 1.15
#: ``sigma / published`` bins of the boundary table.
SIGMA_BINS = (0.0, 0.985, 1.0, 1.01, 1.03, np.inf)
#: Level of the library's lack-of-fit test (Bonferroni over the outputs), as in its validation.
LACK_OF_FIT_LEVEL = 1e-3
#: Held-out standardised errors counted as misses.
MISS_SD = 3.0
#: Quantiles of the emulator-to-noise variance ratio that bin the held-out errors.
RATIO_QUANTILES = (0.0, 0.25, 0.5, 0.75, 0.9, 1.0)
#: Importance-sampling points per evidence of :func:`calibrated_verdicts`.
VERDICT_SAMPLES = 1 << 13
#: Factors on the emulator's variance (not the noise's) for :func:`inflation_checks`.
INFLATION = (1.0, 1.5, 2.0, 3.0, 4.0, 8.0)


def inflation_checks(refits: list[dict[str, np.ndarray]], factors=INFLATION) -> list[dict[str, Any]]:
    """The marginal and targeted validation checks of every refitted emulator with its variance
    multiplied by each factor ``c``: ``e_c = e sqrt((1 + r) / (1 + c r))`` for the emulator-to-noise
    ratio ``r`` (the same error over a wider predictive sd).  Factor 1 is the run's own check.
    What it does not show: the posterior under the wider emulator, and the other checks."""
    out = []
    for c in factors:
        marginal = targeted = either = 0
        sd_targeted = []
        for r in refits:
            e = r["held_out"] * np.sqrt((1.0 + r["ratio"]) / (1.0 + c * r["ratio"]))
            ok = np.isfinite(e)
            cov_min, msq_max = holdout_bounds(int(ok.sum()))
            m_fail = not (np.mean(np.abs(e[ok]) <= 1.96) >= cov_min and np.mean(e[ok] ** 2) <= msq_max)
            t_fail = not local_check(e[r["targeted"]]).passed
            marginal, targeted, either = marginal + m_fail, targeted + t_fail, either + (m_fail or t_fail)
            sd_targeted.append(e[r["targeted"]].ravel())
        t = np.concatenate(sd_targeted)
        out.append(
            {
                "factor": float(c),
                "marginal_failed": int(marginal),
                "targeted_failed": int(targeted),
                "either_failed": int(either),
                "emulators": len(refits),
                "targeted_sd": float(np.nanstd(t)),
            }
        )
    return out


def refit_errors(meta: dict, arrays: dict[str, np.ndarray], observed: np.ndarray) -> dict[str, np.ndarray]:
    """Refit a saved surrogate's emulator as at its last validation: the last ``num_holdout``
    held-out rows held out, every other successful row in the design.

    Returns ``residual``, ``emulator_var`` and ``noise_var`` (held-out rows x active outputs:
    output minus the emulator's mean, the GP's and the noise's variance there), ``loo`` (design
    rows x active outputs: leave-one-out errors over their predictive sd, noise included),
    ``held_out`` (held-out rows x active outputs), ``targeted`` (bool, held-out rows) and
    ``ratio`` (held-out rows x active outputs: emulator variance over noise variance).
    """
    import jax
    import jax.numpy as jnp

    diag, settings = meta["diagnostics"], meta["settings"]
    theta, summaries = arrays["record_theta"][:, :2], arrays["record_summaries"]
    n = len(theta)
    role = np.asarray(diag["design_role"])[:n]
    ok = np.asarray(diag["design_ok"], bool)[:n] & np.all(np.isfinite(summaries), axis=1)
    last = np.flatnonzero(role >= ROLE_HOLDOUT)[-int(settings["num_holdout"]) :]
    role = np.where(role >= ROLE_HOLDOUT, ROLE_DESIGN, role)
    role[last] = ROLE_HOLDOUT
    low = np.asarray(meta["prior"]["low"][:2], np.float64)
    high = np.asarray(meta["prior"]["high"][:2], np.float64)
    state = _State(theta, summaries, role, ok)
    with jax.enable_x64(True):
        # The library's refit of a finished run from its saved settings (the evidence's too).
        transform, model = likelihood_from_state(state, low, high, observed, settings)
        emu = model.emulator
        z_all = np.asarray(transform.apply(jnp.asarray(np.nan_to_num(summaries))))
        on = np.asarray(model.active, bool)
        chol, alpha, mask = np.asarray(emu.chol), np.asarray(emu.alpha), np.asarray(emu.mask, bool)
        loo = []
        for j in range(chol.shape[0]):
            k_inv = np.linalg.inv(chol[j] @ chol[j].T)
            # r_i = alpha_i / [K^-1]_ii over its sd 1 / sqrt([K^-1]_ii)
            loo.append(alpha[j] / np.sqrt(np.diag(k_inv)))
        rows = last[ok[last]]
        x = jnp.asarray((theta[rows] - low) / (high - low))
        mean, var = (np.asarray(a, np.float64) for a in emulator.predict(emu, x))
        noise_var = np.asarray(emulator.noise_sd(emu, x), np.float64) ** 2
    targeted = np.isin(rows, last[len(last) - num_targeted(len(last)) :])
    return {
        "residual": (z_all[rows] - mean)[:, on],
        "emulator_var": var[:, on],
        "noise_var": noise_var[:, on],
        "loo": np.asarray(loo).T[mask][:, on],
        "held_out": ((z_all[rows] - mean) / np.sqrt(var + noise_var))[:, on],
        "targeted": targeted,
        "ratio": (var / noise_var)[:, on],
        "active": on,
    }


def calibrated_errors(refits: list[dict[str, np.ndarray]]) -> dict[str, Any]:
    """The library's calibrated emulator variance (:func:`jaxabc.surrogate.emulator.variance_scale_mle`)
    on the refitted emulators, judged on runs it was not estimated from.

    Each emulator's factor from all its held-out runs (what ``emulator_variance="calibrated"``
    would take after that failed validation), and leave-one-run-out errors: each held-out run
    standardised with the factor estimated from the emulator's other held-out runs.  With those
    errors, the marginal and targeted checks are rerun (the held-out runs of an emulator judged
    each by a factor it did not inform, as a fresh validation would be).
    """
    factors, honest, marginal, targeted, either = [], [], 0, 0, 0
    honest_targeted = []
    for r in refits:
        res, v, n = r["residual"], r["emulator_var"], r["noise_var"]
        factors.append(emulator.variance_scale_mle(res, v, n)[0])
        e = np.full(res.shape, np.nan)
        for i in range(len(res)):
            others = np.arange(len(res)) != i
            c = emulator.variance_scale_mle(res[others], v[others], n[others])[0]
            e[i] = res[i] / np.sqrt(c * v[i] + n[i])
        honest.append(e.ravel())
        honest_targeted.append(e[r["targeted"]].ravel())
        ok = np.isfinite(e)
        cov_min, msq_max = holdout_bounds(int(ok.sum()))
        m_fail = not (np.mean(np.abs(e[ok]) <= 1.96) >= cov_min and np.mean(e[ok] ** 2) <= msq_max)
        t_fail = not local_check(e[r["targeted"]]).passed
        marginal, targeted, either = marginal + m_fail, targeted + t_fail, either + (m_fail or t_fail)
    f = np.asarray(factors)
    return {
        "factor_quantiles": dict(
            zip(("0", "0.25", "0.5", "0.75", "1"), np.quantile(f, [0, 0.25, 0.5, 0.75, 1]).tolist(), strict=True)
        ),
        "factor_at_one": int(np.sum(f == 1.0)),
        "factors": f.tolist(),
        "leave_one_run_out": {
            "all": _beyond(np.concatenate(honest)),
            "targeted": _beyond(np.concatenate(honest_targeted)),
            "marginal_failed": int(marginal),
            "targeted_failed": int(targeted),
            "either_failed": int(either),
            "emulators": len(refits),
        },
    }


def calibrated_verdicts(cases: list[dict[str, Any]], seed: int = 0) -> list[dict[str, Any]]:
    """What a calibrated emulator variance does to each repeat's model probabilities.

    Per repeat and model, the emulator refitted on every run (design and held-out, as after a
    failed validation) twice: with the GP's variance and with the factor its held-out runs
    measure (:func:`calibrated_errors`).  For each, the library's evidence
    (:mod:`jaxabc.surrogate.evidence`'s importance-sampling estimate on
    :data:`VERDICT_SAMPLES` points, its standard error that estimate's and the run's own
    jackknife, ``jackknife_se``, in quadrature) and the posterior mean and sd of theta
    (importance weights on the same points).
    Then the probabilities, their intervals and the verdict rule of the model choice
    (:func:`jaxabc.model_choice.result.interval_leader`) for both.
    """
    import jax

    from jaxabc.model_choice import interval_leader, probabilities_with_errors, probability_bounds
    from jaxabc.surrogate.evidence import _estimate, _log_density, _points

    out = []
    for case in cases:
        rows: dict[str, list] = {"gp": [], "calibrated": []}
        moments: dict[str, list] = {"gp": [], "calibrated": []}
        for m in case["models"]:
            for label, c in (("gp", 1.0), ("calibrated", m["factor"])):
                state = _State(m["theta"], m["summaries"], m["role"], m["ok"], c)
                with jax.enable_x64(True):
                    transform, model = likelihood_from_state(state, m["low"], m["high"], m["observed"], m["settings"])
                    # The library's evidence estimate without its jackknife (9 refits per evidence,
                    # 80 evidences): the design's part of the error is the run's own jackknife, on
                    # nearly the same rows.  The same importance points give the posterior moments.
                    pts = _points(model, np.random.default_rng(seed), VERDICT_SAMPLES)
                    log_z, importance_se = _estimate(model, transform, pts)
                    lw = _log_density(model, pts.x) - pts.log_q
                w = np.exp(lw - np.max(lw))
                w /= w.sum()
                x = m["low"] + pts.x[:, :2] * (m["high"] - m["low"])
                mean = w @ x
                rows[label].append((log_z, float(np.hypot(importance_se, m["jackknife_se"]))))
                moments[label].append((mean, np.sqrt(w @ (x - mean) ** 2)))
        prior = np.asarray(case["model_prior"], np.float64)
        entry: dict[str, Any] = {"result": case["result"], "factors": [m["factor"] for m in case["models"]]}
        for label in ("gp", "calibrated"):
            log_z, se = (np.array(a) for a in zip(*rows[label], strict=True))
            p, _ = probabilities_with_errors(log_z, np.zeros_like(log_z), prior)
            iv = probability_bounds(log_z, se, prior)
            leader = interval_leader(p, iv)
            entry[label] = {
                "log_evidence": log_z.tolist(),
                "log_evidence_se": se.tolist(),
                "probabilities": p.tolist(),
                "intervals": iv.tolist(),
                "preferred": None if leader is None else case["names"][leader],
                "most_probable": case["names"][int(np.argmax(p))],
                "posterior_mean": [mu.tolist() for mu, _ in moments[label]],
                "posterior_sd": [sd.tolist() for _, sd in moments[label]],
            }
        (m0, s0), (m1, s1) = (
            (np.array([a for a, _ in moments[k]]), np.array([b for _, b in moments[k]])) for k in ("gp", "calibrated")
        )
        entry["mean_shift_in_sd"] = ((m1 - m0) / s0).tolist()
        entry["sd_ratio"] = (s1 / s0).tolist()
        out.append(entry)
    return out


class _State:
    """The fields of a surrogate state that :func:`jaxabc.surrogate.evidence.likelihood_from_state` reads."""

    def __init__(
        self, thetas: np.ndarray, summaries: np.ndarray, role: np.ndarray, ok: np.ndarray, variance_scale: float = 1.0
    ) -> None:
        self.thetas, self.summaries, self.role, self.ok = thetas, summaries, role, ok
        self.variance_scale = variance_scale


def _beyond(z: np.ndarray) -> dict[str, Any]:
    """Size, sd and shares beyond 3 and 4 of standardised errors (finite ones), with the normal's."""
    z = np.asarray(z, np.float64).ravel()
    z = z[np.isfinite(z)]
    return {
        "n": int(z.size),
        "sd": float(z.std()) if z.size else None,
        "beyond_3": float(np.mean(np.abs(z) > 3)) if z.size else None,
        "beyond_4": float(np.mean(np.abs(z) > 4)) if z.size else None,
    }


def placement_tails(refits: list[dict[str, np.ndarray]], saved: list[np.ndarray]) -> dict[str, Any]:
    """Where the held-out tails sit, over every refitted emulator: the design's leave-one-out
    errors, the held-out errors of random and of targeted runs, and by emulator-to-noise variance
    ratio (:data:`RATIO_QUANTILES`); ``reproduced_max_abs`` compares the refit's held-out errors
    with the saved ones (``saved``, the same rows and outputs)."""
    held = np.concatenate([r["held_out"].ravel() for r in refits])
    targeted = np.concatenate([np.repeat(r["targeted"], r["held_out"].shape[1]) for r in refits])
    ratio = np.concatenate([r["ratio"].ravel() for r in refits])
    edges = np.quantile(ratio, RATIO_QUANTILES)
    bins = []
    for i, (lo, hi) in enumerate(itertools.pairwise(edges)):
        sel = (ratio >= lo) & ((ratio < hi) if i < len(edges) - 2 else (ratio <= hi))
        bins.append({"ratio_low": float(lo), "ratio_high": float(hi), **_beyond(held[sel])})
    pairs = [(r["held_out"], s) for r, s in zip(refits, saved, strict=True) if s.shape == r["held_out"].shape]
    diffs = [float(np.nanmax(np.abs(a - b))) for a, b in pairs if a.size]
    return {
        "design_loo": _beyond(np.concatenate([r["loo"].ravel() for r in refits])),
        "held_out_random": _beyond(held[~targeted]),
        "held_out_targeted": _beyond(held[targeted]),
        "by_ratio": bins,
        "normal": {"beyond_3": float(2 * scipy.stats.norm.sf(3)), "beyond_4": float(2 * scipy.stats.norm.sf(4))},
        "reproduced_max_abs": max(diffs) if diffs else None,
        "reproduced_emulators": len(diffs),
    }


def lack_of_fit_by_summary(repeats=REPEATS) -> list[dict[str, Any]]:
    """Every emulator of every saved repeat (the calibrated ones too: the test does not involve
    the emulator's variance) that failed the lack-of-fit check, refitted on all its successful
    runs as after its last validation, with the check per summary: the fitted noise variance at
    the replicate sites over the replicates' own variance, and its lower-tail chi-square p
    (:func:`jaxabc.surrogate.diagnostics.lack_of_fit`; failed below ``1e-3`` over the outputs)."""
    import jax
    import jax.numpy as jnp

    out = []
    for name, _ in repeats:
        d = _load_repeat(name)
        if d is None:
            continue
        summaries = d["summaries"]
        fitted = list(summaries["fitted"])
        observed = np.array([summaries["observed"][summaries["names"].index(n)] for n in fitted], np.float64)
        for m in d["per_model"]:
            meta, arr = _posterior(ROOT / d["saved_result"], m)
            diag = meta["diagnostics"]
            if diag.get("lack_of_fit_ok", True):
                continue
            theta, z = arr["record_theta"][:, :2], arr["record_summaries"]
            n = len(theta)
            role = np.asarray(diag["design_role"])[:n]
            role = np.where(role >= ROLE_HOLDOUT, ROLE_DESIGN, role)
            ok = np.asarray(diag["design_ok"], bool)[:n] & np.all(np.isfinite(z), axis=1)
            group = np.asarray(diag["design_replicate_group"])[:n]
            low = np.asarray(meta["prior"]["low"][:2], np.float64)
            high = np.asarray(meta["prior"]["high"][:2], np.float64)
            with jax.enable_x64(True):
                transform, model = likelihood_from_state(
                    _State(theta, z, role, ok), low, high, observed, meta["settings"]
                )
                z_all = np.asarray(transform.apply(jnp.asarray(np.nan_to_num(z))))
                rep_var, df = replicate_variance(z_all, group, ok & (role == ROLE_DESIGN))
                x = jnp.asarray((theta[group >= 0] - low) / (high - low))
                site_var = np.mean(np.asarray(emulator.noise_sd(model.emulator, x), np.float64) ** 2, axis=0)
            passed, p = lack_of_fit(site_var, rep_var, df, LACK_OF_FIT_LEVEL)
            raw_rep_var, _ = replicate_variance(np.nan_to_num(z), group, ok & (role == ROLE_DESIGN))
            failing = [j for j in range(len(fitted)) if p[j] < LACK_OF_FIT_LEVEL / len(fitted)]
            out.append(
                {
                    "result": name,
                    "model": m,
                    "replicate_df": int(df),
                    "passed_on_refit": passed,
                    "by_summary": {
                        fitted[j]: {"noise_over_replicate_variance": float(site_var[j] / rep_var[j]), "p": float(p[j])}
                        for j in range(len(fitted))
                    },
                    "failing": [fitted[j] for j in failing],
                    # In summary units: the replicates' sd against the spread over the runs.
                    "failing_spread": {
                        fitted[j]: {
                            "replicate_sd": float(np.sqrt(raw_rep_var[j])),
                            "runs_5_95": np.percentile(z[ok, j], [5, 95]).tolist(),
                        }
                        for j in failing
                    },
                }
            )
    return out


def _load_repeat(name: str) -> dict[str, Any] | None:
    path = RESULTS / f"{name}.json"
    return json.loads(path.read_text()) if path.is_file() else None


def _posterior_path(folder: Path, model: str) -> Path:
    return folder / f"posterior_{model.replace('/', '_')}.npz"


def _posterior(folder: Path, model: str) -> tuple[dict, dict[str, np.ndarray]]:
    with np.load(_posterior_path(folder, model), allow_pickle=False) as z:
        arrays = {k: z[k] for k in ("particles", "weights", "record_theta", "record_summaries")}
        return json.loads(str(z["metadata"])), arrays


def _failed_checks(diag: dict, max_ratio: float) -> list[str]:
    """The validation checks a saved surrogate failed, by name."""
    errors = np.asarray(diag["holdout_errors"], np.float64)
    n = int(np.isfinite(errors).sum())
    cov_min, msq_max = holdout_bounds(n) if n else (np.nan, np.nan)
    failed = []
    if not (diag["holdout_coverage_95"] >= cov_min and diag["holdout_mean_squared_error"] <= msq_max):
        failed.append("marginal")
    if not diag["targeted_holdout_ok"]:
        failed.append("targeted")
    if not diag["lack_of_fit_ok"]:
        failed.append("lack_of_fit")
    if not diag["posterior_stable"]:
        failed.append("stability")
    if diag["emulator_to_noise_variance"] > max_ratio:
        failed.append("resolution")
    return failed


def _neighbour_labels(x_design: np.ndarray, broken: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Share of broken runs among the :data:`NEIGHBOURS` nearest design runs of each row of ``x``."""
    d = np.linalg.norm(x[:, None, :] - x_design[None, :, :], axis=-1)
    nearest = np.argsort(d, axis=1)[:, :NEIGHBOURS]
    return broken[nearest].mean(axis=1)


def _tails(errors: np.ndarray, fitted: list[str], draws: int = 20000) -> dict[str, Any]:
    """How far the pooled held-out errors ``(n, q)`` are from N(0, 1), and what that does to the checks.

    A Student t (centre 0) is fitted to all errors; the chance that an emulator whose errors
    followed it fails the marginal check (9 runs x q outputs) or the targeted one (2 runs x q)
    is estimated from ``draws`` Monte Carlo sets at a fixed seed (independent errors, so a
    lower bound where outputs are correlated).
    """
    a = np.abs(errors).ravel()
    df, _, scale = scipy.stats.t.fit(errors.ravel(), floc=0.0)
    rng = np.random.default_rng(0)
    q = errors.shape[1]
    e = scale * rng.standard_t(df, size=(draws, 9, q))
    cov_min, msq_max = holdout_bounds(9 * q)
    marginal = (np.mean(np.abs(e) <= 1.96, axis=(1, 2)) < cov_min) | (np.mean(e**2, axis=(1, 2)) > msq_max)
    targeted = e[:, :2, :].reshape(draws, -1)
    bound = local_check(targeted[0]).bound
    t_msq = scipy.stats.chi2.ppf(1 - 1e-3, targeted.shape[1]) / targeted.shape[1]
    targeted_fail = (np.max(np.abs(targeted), axis=1) > bound) | (np.mean(targeted**2, axis=1) > t_msq)
    # Run by run: misses that come together in one held-out run are one wrong prediction of the
    # whole summary vector (or one unusual run), not independent chance.
    k = np.sum(np.abs(errors) > MISS_SD, axis=1)
    p3 = 2 * scipy.stats.norm.sf(MISS_SD)
    rms = np.sqrt(np.mean(errors**2, axis=1))
    by_run = {
        "runs": int(errors.shape[0]),
        "with_a_miss": int(np.sum(k >= 1)),
        "with_a_miss_normal": float(errors.shape[0] * (1 - (1 - p3) ** q)),
        "with_two_misses": int(np.sum(k >= 2)),
        "with_two_misses_normal": float(errors.shape[0] * scipy.stats.binom.sf(1, q, p3)),
        "rms_quantiles": dict(zip(("0.5", "0.9", "0.99"), np.quantile(rms, [0.5, 0.9, 0.99]).tolist(), strict=True)),
        "rms_quantiles_normal": dict(
            zip(("0.5", "0.9", "0.99"), np.sqrt(scipy.stats.chi2.ppf([0.5, 0.9, 0.99], q) / q).tolist(), strict=True)
        ),
    }
    return {
        "errors": int(a.size),
        "by_run": by_run,
        "sd_by_summary": dict(zip(fitted, np.std(errors, axis=0).round(4).tolist(), strict=True)),
        "excess_kurtosis_by_summary": dict(
            zip(fitted, scipy.stats.kurtosis(errors, axis=0).round(3).tolist(), strict=True)
        ),
        "share_beyond": {
            str(k): {"observed": float(np.mean(a > k)), "normal": float(2 * scipy.stats.norm.sf(k))} for k in (2, 3, 4)
        },
        "student_t": {"df": float(df), "scale": float(scale)},
        "chance_fail_under_t": {
            "marginal": float(marginal.mean()),
            "targeted": float(targeted_fail.mean()),
            "either": float((marginal | targeted_fail).mean()),
            "draws": draws,
        },
    }


def analyse(repeats=REPEATS, max_verdicts: int | None = None) -> dict[str, Any]:
    """The payload: per repeat and model, and per model pooled over the repeats; the calibrated
    verdicts of the first ``max_verdicts`` repeats (all: None).  Only the repeats made with the
    GP's own variance: what is analysed is that variance (a calibrated run's held-out runs were
    judged by the scaled emulator, over two validations)."""
    saved = [
        (name, what, d) for name, what in repeats if (d := _load_repeat(name)) is not None and made_with_gp_variance(d)
    ]
    if not saved:
        raise FileNotFoundError("no saved model-choice repeat: run the registry's water_model_choice first")
    summaries = saved[0][2]["summaries"]
    fitted = list(summaries["fitted"])
    sd = np.array([summaries["observation_sd"][n] for n in fitted])
    observed = np.array([summaries["observed"][summaries["names"].index(n)] for n in fitted], np.float64)
    i_s5 = fitted.index("S5")
    models = list(saved[0][2]["per_model"])
    published = {m: np.asarray(saved[0][2]["models"][m]["published_lj"], np.float64) for m in models}

    # Every run of each model over the repeats, once (repeats share cached runs).
    pooled: dict[str, dict[tuple, np.ndarray]] = {m: {} for m in models}
    per_run = []
    pooled_errors: list[np.ndarray] = []
    refits: list[dict[str, np.ndarray]] = []
    saved_held: list[np.ndarray] = []
    inputs: list[Path] = []
    cases: list[dict[str, Any]] = []
    for name, what, d in saved:
        folder = ROOT / d["saved_result"]
        rows = []
        case_models = []
        for m in models:
            meta, arr = _posterior(folder, m)
            theta, z = arr["record_theta"][:, :2], arr["record_summaries"]
            for t, s in zip(theta, z, strict=True):
                if np.all(np.isfinite(s)):  # keyed by the run, so replicates stay apart
                    pooled[m][(*np.round(t, 12), *np.round(s, 12))] = np.concatenate([t, s])
            diag = meta["diagnostics"]
            role = np.asarray(diag["design_role"])
            ok = np.asarray(diag["design_ok"], bool)
            holdout = np.flatnonzero(role >= ROLE_HOLDOUT)
            checked = holdout[ok[holdout]]
            errors = np.asarray(diag["holdout_errors"], np.float64)[: len(checked)]
            targeted = np.isin(checked, holdout[len(holdout) - num_targeted(len(holdout)) :])
            pooled_errors.append(errors[np.all(np.isfinite(errors), axis=1)])
            refits.append(refit_errors(meta, arr, observed))
            n_rec = len(theta)
            role_all = np.asarray(diag["design_role"])[:n_rec]
            case_models.append(
                {
                    "theta": theta,
                    "summaries": z,
                    "role": np.where(role_all >= ROLE_HOLDOUT, ROLE_DESIGN, role_all),
                    "ok": ok[:n_rec] & np.all(np.isfinite(z), axis=1),
                    "low": np.asarray(meta["prior"]["low"][:2], np.float64),
                    "high": np.asarray(meta["prior"]["high"][:2], np.float64),
                    "observed": observed,
                    "settings": meta["settings"],
                    "jackknife_se": float(d["per_model"][m]["log_evidence_jackknife_se"]),
                    "refit": len(refits) - 1,
                }
            )
            saved_held.append(
                np.asarray(diag["holdout_errors"], np.float64)[: len(refits[-1]["targeted"])][:, refits[-1]["active"]]
            )
            worst = np.unravel_index(np.nanargmax(np.abs(errors)), errors.shape) if errors.size else None
            rows.append(
                {
                    "model": m,
                    "validated": bool(diag["validated"]),
                    "failed_checks": _failed_checks(diag, float(meta["settings"]["max_emulator_ratio"])),
                    "targeted_bound": local_check(errors[targeted]).bound,
                    "misses_by_summary": {
                        fitted[j]: int(np.sum(np.abs(errors[:, j]) > MISS_SD)) for j in range(len(fitted))
                    },
                    "worst": None
                    if worst is None
                    else {
                        "summary": fitted[worst[1]],
                        "error_sd": float(errors[worst]),
                        "targeted": bool(targeted[worst[0]]),
                        "theta_over_published": (theta[checked[worst[0]]] / published[m]).tolist(),
                        "s5_nm": float(z[checked[worst[0]], i_s5]),
                    },
                    "_particles": arr["particles"][:, :2],
                    "_weights": arr["weights"],
                }
            )
        per_run.append({"result": name, "what": what, "models": rows})
        mc = d["model_choice"]
        cases.append({"result": name, "names": mc["names"], "model_prior": mc["model_prior"], "models": case_models})

    boundary = {}
    for m in models:
        runs = np.array(list(pooled[m].values()))
        theta, z = runs[:, :2], runs[:, 2:]
        zf = z  # the records hold the fitted summaries, in ``fitted`` order
        ratio = theta / published[m]
        broken = zf[:, i_s5] >= BROKEN_S5_NM
        high = ratio[:, 1] >= HIGH_EPSILON
        bins = []
        for lo, hi in itertools.pairwise(SIGMA_BINS):
            sel = high & (ratio[:, 0] >= lo) & (ratio[:, 0] < hi)
            bins.append(
                {
                    "sigma_over_published": [lo, None if np.isinf(hi) else hi],
                    "runs": int(sel.sum()),
                    "broken_share": float(broken[sel].mean()) if sel.any() else None,
                    "mean": {n: float(zf[sel, j].mean()) for j, n in enumerate(fitted)} if sel.any() else None,
                }
            )
        near = high & (ratio[:, 0] >= SIGMA_BINS[1]) & (ratio[:, 0] < SIGMA_BINS[4])
        a, b = zf[near & ~broken], zf[near & broken]
        jump = ((b.mean(0) - a.mean(0)) / sd).tolist() if len(a) and len(b) else None
        s5 = zf[:, i_s5]
        boundary[m] = {
            "published_lj": published[m].tolist(),
            "runs": len(theta),
            "broken_runs": int(broken.sum()),
            "broken_runs_below_high_epsilon": int(np.sum(broken & ~high)),
            "s5_counts_nm": {
                "below_0.38": int(np.sum(s5 < 0.38)),
                "0.38_to_0.42": int(np.sum((s5 >= 0.38) & (s5 < 0.42))),
                "from_0.42": int(np.sum(s5 >= 0.42)),
            },
            "by_sigma_at_high_epsilon": bins,
            "jump_near_boundary_in_stated_sd": dict(zip(fitted, jump, strict=True)) if jump else None,
            "near_boundary_runs": [len(a), len(b)],
            "_x": (theta - theta.min(0)) / np.ptp(theta, axis=0),
            "_lo": theta.min(0),
            "_span": np.ptp(theta, axis=0),
            "_broken": broken.astype(float),
        }

    failures = []
    for run in per_run:
        for row in run["models"]:
            m = row["model"]
            bd = boundary[m]
            x = (row.pop("_particles") - bd["_lo"]) / bd["_span"]
            w = row.pop("_weights")
            w = w / w.sum()
            share = _neighbour_labels(bd["_x"], bd["_broken"], x)
            row["posterior_beyond_break"] = float(np.sum(w * (share == 1.0)))
            row["posterior_on_break"] = float(np.sum(w * ((share > 0.0) & (share < 1.0))))
            if row["worst"] is not None:
                t = (np.asarray(row["worst"]["theta_over_published"]) * bd["published_lj"] - bd["_lo"]) / bd["_span"]
                near = float(_neighbour_labels(bd["_x"], bd["_broken"], t[None, :])[0])
                row["worst"]["side"] = "beyond" if near == 1.0 else "on" if near > 0.0 else "before"
            if not row["validated"]:
                failures.append(row)
    for bd in boundary.values():
        for k in ("_x", "_lo", "_span", "_broken"):
            bd.pop(k)

    def count(rows, key) -> dict[str, int]:
        out: dict[str, int] = {}
        for r in rows:
            for v in key(r):
                out[v] = out.get(v, 0) + 1
        return dict(sorted(out.items(), key=lambda kv: -kv[1]))

    all_rows = [r for run in per_run for r in run["models"]]
    summary = {
        "emulators": len(all_rows),
        "failed": len(failures),
        "failed_checks": count(failures, lambda r: r["failed_checks"]),
        "worst_summary_of_failed": count(failures, lambda r: [r["worst"]["summary"]] if r["worst"] else []),
        "worst_side_of_failed": count(failures, lambda r: [r["worst"]["side"]] if r["worst"] else []),
        "worst_side_of_validated": count(
            [r for r in all_rows if r["validated"]], lambda r: [r["worst"]["side"]] if r["worst"] else []
        ),
        "misses_by_summary": {n: int(sum(r["misses_by_summary"][n] for r in all_rows)) for n in fitted},
        # Does reaching the break go with failing?  Fisher's exact test on
        # (posterior share on or beyond the break > 5 %) x (failed validation).
        "reach_vs_failure": None,
    }
    reach = np.array([r["posterior_on_break"] + r["posterior_beyond_break"] > 0.05 for r in all_rows])
    failed = np.array([not r["validated"] for r in all_rows])
    table = [[int(np.sum(r & f)) for f in (failed, ~failed)] for r in (reach, ~reach)]
    summary["reach_vs_failure"] = {
        "table_reach_failed_validated": table,
        "fisher_p": float(scipy.stats.fisher_exact(table).pvalue),
    }
    summary["heldout_tails"] = _tails(np.concatenate(pooled_errors), fitted)
    summary["tails_by_placement"] = placement_tails(refits, saved_held)
    summary["variance_inflation"] = inflation_checks(refits)
    summary["calibrated_variance"] = calibration = calibrated_errors(refits)
    for case in cases:
        for m in case["models"]:
            m["factor"] = calibration["factors"][m.pop("refit")]
    summary["calibrated_verdicts"] = calibrated_verdicts(cases[:max_verdicts])
    summary["lack_of_fit"] = lack_of_fit_by_summary(repeats)
    # Every repeat read (the lack-of-fit table reads the calibrated ones too): its JSON and records.
    for name, _ in repeats:
        if (d := _load_repeat(name)) is not None:
            folder = ROOT / d["saved_result"]
            inputs += [
                RESULTS / f"{name}.json",
                *(_posterior_path(folder, m) for m in d["per_model"]),
            ]
    return {
        "fitted": fitted,
        "stated_sd": sd.tolist(),
        "settings": {
            "broken_s5_nm": BROKEN_S5_NM,
            "neighbours": NEIGHBOURS,
            "high_epsilon": HIGH_EPSILON,
            "miss_sd": MISS_SD,
        },
        "summary": summary,
        "boundary": boundary,
        "repeats": per_run,
        "_inputs": inputs,
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument(
        "--quick", action="store_true", help="write the quick JSON (the same analysis, one repeat's verdicts)"
    )
    args = parser.parse_args(argv)
    payload = analyse(max_verdicts=1 if args.quick else None)
    inputs = payload.pop("_inputs")
    payload = {"machine": machine(), **payload}
    out = write_result("water_emulator_failures", payload, quick=args.quick, inputs=inputs)
    print(json.dumps(payload["summary"], indent=1))
    print(f"wrote {relative(out)}")
    return payload


if __name__ == "__main__":
    main()
