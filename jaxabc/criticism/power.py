"""Could these data have seen it?  Detection power at expected strengths, and design advice.

A low cause score says "the data do not ask for this effect"; it does not say "the effect is
absent" unless the data *could* have shown it.  For every catalogue effect with an
``expected`` strength (the value physics predicts, e.g. ``fh_scale = 1`` for the Feynman-Hibbs
correction), criticism therefore reports the power of this data design to name it there.

Detection power
---------------
``num_power_replicates`` data sets are simulated from the base posterior with the effect at its
expected strength (all other effects at null): base parameters resampled from the calibration,
one fresh simulator key each, every draw derived from the run's seed.  On each data set the same
data-dependent pipeline that runs on the observed data (:class:`jaxabc.criticism.pipeline.Pipeline`:
Gauss-Newton refit of the base parameters, noise re-estimated at the refitted point, misfit tests
with the same correction and level, cause ranking and the joint test) decides whether it *names*
the effect: a misfit is flagged and the joint test selects the effect among the causes still
needed.  The power is the share of data sets in which it does, with its binomial standard error
``sqrt(p (1 - p) / n)`` and a 95 % Wilson interval (which, unlike the standard error, is not
zero when the count is 0 or n).  Each data set gets its own noise yardstick (replicate
simulations at the Bayes estimate with fresh keys, which also serve as its common random numbers),
so the power includes the pipeline's own randomness, as a fresh run of the criticism would have
it.  Two things are shared with the run on the observed data and not repeated per data set: the
ABC calibration itself (a replicate starts its local refit from the calibration's Bayes estimate,
as the observed data do) and the posterior predictive draws (they only draw the report's bands).

An effect that the joint test did not select and whose power is below ``power_threshold``
(0.5) is "not detectable with these data": the report says so, with the power and its error,
and never reads its low rank as evidence against it.

Design advice
-------------
For an undetectable effect and the candidate observables (or state points) the user could
measure (:class:`CandidateObservables`), each candidate ``c`` is scored by the signal the effect
would leave, at its expected strength, in the design *augmented* by ``c``:

* finite-difference sensitivities (common random numbers, at the refitted base point) of the
  candidate's expectation to the effect, ``v_c``, and to the base parameters, ``j_c``;
* the candidate's noise variance: its simulation variance over the run's replicate keys plus
  ``measurement_sd**2``, independent of the existing summaries;
* the augmented signature ``[v; v_c]`` is projected off the span of the augmented parameter
  sensitivities ``[J; j_c]`` with the same refit operator as the misfit test (generalised least
  squares in the noise metric, the candidate counted as *fitted*, so the base parameters may use
  it to absorb the effect), and its norm in that noise metric, times ``|expected - null|``, is the
  signal in noise standard deviations.

Candidates are ranked by that signal (equivalently by the gain in efficient Fisher information
for the effect with the base parameters profiled out).  A candidate that responds strongly to the
effect but only the way a base parameter does gains nothing: the free parameter absorbs it.
``raw_snr`` (``|v_c| / sd_c`` times the strength, before projection) is reported beside it to
show the difference.  It is a linear, local ranking, not a power: rerun the criticism with the
chosen observable added to measure the power it gives.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import jax
import numpy as np

from jaxabc.criticism.causes import Catalogue, sensitivities
from jaxabc.criticism.misfit import refit_operator
from jaxabc.criticism.pipeline import Diagnosis, Pipeline
from jaxabc.criticism.predictive import PosteriorPredictive, simulate_many, with_replicates

__all__ = ["CandidateObservables", "EffectPower", "design_advice", "detection_power", "wilson_interval"]


@dataclass(frozen=True)
class CandidateObservables:
    """Observables or state points the user could add to the data, as extra simulator outputs.

    Parameters
    ----------
    simulate : callable ``(key, theta_full) -> (c,)``
        Same signature as ``simulate_with_effects`` (base parameters, then one entry per catalogue
        effect); returns the ``c`` candidate summaries, e.g. the pressure at a new state point or
        B2 at a lower temperature.  A JAX function when the run's executor is the default vmap.
    names : sequence of str
        One per candidate output.
    measurement_sd : float or array_like of shape (c,), optional
        Measurement standard deviation of each candidate, added in quadrature to its simulation
        noise (estimated from the run's replicate keys).
    """

    simulate: Callable
    names: Sequence[str]
    measurement_sd: Any = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))
        if not self.names:
            raise ValueError("CandidateObservables needs at least one candidate name")
        if self.measurement_sd is not None:
            sd = np.broadcast_to(np.asarray(self.measurement_sd, float), (len(self.names),))
            if not np.all(np.isfinite(sd)) or np.any(sd < 0):
                raise ValueError("measurement_sd must be finite and non-negative")


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % by default)."""
    if n <= 0:
        return 0.0, 1.0
    p = successes / n
    den = 1.0 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return float(max(0.0, mid - half)), float(min(1.0, mid + half))


@dataclass
class EffectPower:
    """Detection power of one effect at its expected strength.

    Attributes
    ----------
    name : str
    expected : float
    power : float
        Share of replicate data sets in which the pipeline names the effect.
    se : float
        Binomial standard error ``sqrt(p (1 - p) / n)``.
    interval : tuple of float
        95 % Wilson interval.
    num_datasets : int
        Data sets the pipeline ran on (simulation failures excluded).
    num_named : int
    num_failed : int
        Data sets whose simulation or analysis failed.
    datasets : numpy.ndarray, shape (n, s)
        The replicate data sets (for checks; not written to the report).
    """

    name: str
    expected: float
    power: float
    se: float
    interval: tuple[float, float]
    num_datasets: int
    num_named: int
    num_failed: int = 0
    datasets: np.ndarray | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        return dict(
            expected=self.expected,
            power=self.power,
            se=self.se,
            interval=list(self.interval),
            num_datasets=self.num_datasets,
            num_named=self.num_named,
            num_failed=self.num_failed,
        )


def power_key(seed_key: jax.Array) -> jax.Array:
    """The power estimate's key, derived from the run's root key without disturbing its splits."""
    return jax.random.fold_in(seed_key, 0x706F77)


def detection_power(
    pipeline: Pipeline,
    result: Any,
    predictive: PosteriorPredictive,
    key: jax.Array,
    num_datasets: int,
    effects: Sequence[str] | None = None,
) -> dict[str, EffectPower]:
    """Power of the pipeline to name each effect at its expected strength (see the module doc).

    Parameters
    ----------
    pipeline : Pipeline
        The run's data-dependent steps (same settings as on the observed data).
    result : ABCResult
        The base calibration: base parameters of the replicate data sets are drawn from it.
    predictive : PosteriorPredictive
        The base predictive at the Bayes estimate, before the local refit.
    key : jax.Array
        Every draw derives from it (:func:`power_key` of the run's root key).
    num_datasets : int
        Replicate data sets per effect.
    effects : sequence of str, optional
        Default: every catalogue effect with an ``expected`` strength.
    """
    cat: Catalogue = pipeline.catalogue
    names = [e.name for e in cat if e.expected is not None] if effects is None else list(effects)
    d, nulls = pipeline.num_base, cat.nulls()
    out: dict[str, EffectPower] = {}
    if not names:
        return out
    # A fresh noise yardstick per data set, as a fresh run would have: replicates at the Bayes
    # estimate with their own keys (shared by the effects: data set i of every effect uses the
    # i-th yardstick).  Built lazily, once.
    num_rep = predictive.replicates.shape[0]
    yardsticks: list[PosteriorPredictive | None] = []

    def yardstick(i: int) -> PosteriorPredictive | None:
        if not yardsticks:
            keys = jax.random.split(jax.random.fold_in(key, 2**31 - 1), num_datasets * num_rep)
            theta_hat = np.asarray(predictive.theta_hat, float)
            reps = simulate_many(
                pipeline.simulate, keys, np.repeat(theta_hat[None], keys.shape[0], 0), pipeline.executor
            ).reshape(num_datasets, num_rep, -1)
            for j in range(num_datasets):
                try:
                    yardsticks.append(with_replicates(predictive, keys[j * num_rep : (j + 1) * num_rep], reps[j]))
                except RuntimeError:
                    yardsticks.append(None)
        return yardsticks[i]

    for name in names:
        k = cat.index(name)
        eff = cat.effects[k]
        if eff.expected is None:
            raise ValueError(f"effect {name!r} has no expected strength")
        k_theta, k_data = jax.random.split(jax.random.fold_in(key, k))
        base = result.resample(num_datasets, seed=int(jax.random.randint(k_theta, (), 0, 2**30)))
        thetas = np.concatenate([base, np.repeat(nulls[None], num_datasets, 0)], 1)
        thetas[:, d + k] = eff.expected
        data = simulate_many(pipeline.simulate, jax.random.split(k_data, num_datasets), thetas, pipeline.executor)
        ok = np.all(np.isfinite(data), axis=1)
        named, failed = [], int((~ok).sum())
        for i in np.flatnonzero(ok):
            pred_i = yardstick(int(i))
            if pred_i is None:
                failed += 1
                continue
            try:
                named.append(pipeline.diagnose(data[i], pred_i).names(name))
            except (RuntimeError, np.linalg.LinAlgError, ValueError):
                failed += 1
        n, hits = len(named), int(np.sum(named))
        p = hits / n if n else float("nan")
        se = float(np.sqrt(p * (1 - p) / n)) if n else float("nan")
        out[name] = EffectPower(
            name, float(eff.expected), float(p), se, wilson_interval(hits, n), n, hits, failed, data[ok]
        )
    return out


def _signal(
    jac: np.ndarray, v: np.ndarray, cov: np.ndarray, fitted: np.ndarray, prior_precision: np.ndarray | None = None
) -> float:
    """Norm, in the noise metric, of ``v`` after the base parameters absorb what they can (as
    far as their prior allows, with ``prior_precision``: :func:`~jaxabc.criticism.misfit.refit_operator`)."""
    a = refit_operator(jac, cov, fitted, prior_precision)
    u = a @ v
    c = a @ cov @ a.T
    if prior_precision is not None:
        jf = jac[fitted]
        prec_f = np.linalg.pinv(cov[np.ix_(fitted, fitted)], rcond=1e-10, hermitian=True)
        inv = np.linalg.pinv(jf.T @ prec_f @ jf + prior_precision, rcond=1e-8, hermitian=True)
        c = c + jac @ inv @ prior_precision @ inv @ jac.T
    prec = np.linalg.pinv(c, rcond=1e-8, hermitian=True)
    return float(np.sqrt(max(float(u @ prec @ u), 0.0)))


def design_advice(
    pipeline: Pipeline,
    diagnosis: Diagnosis,
    candidates: CandidateObservables,
    effects: Sequence[str],
) -> dict[str, list[dict]]:
    """Rank candidate observables by the signal each would add for each effect (module doc).

    Returns
    -------
    dict of effect name to list of dict
        Best candidate first; each entry has ``name``, ``snr`` (signal of the effect at its
        expected strength in the augmented design, noise sd), ``current_snr`` (without it),
        ``gain`` (``snr**2 - current_snr**2``, the information it adds), ``raw_snr`` (the
        candidate's own response before the parameters absorb it), ``absorbed`` (share of the
        candidate's raw response the base parameters take up) and ``sd``.
    """
    cat: Catalogue = pipeline.catalogue
    d = pipeline.num_base
    pred = diagnosis.predictive
    theta = np.asarray(diagnosis.theta, float)
    keys = pred.replicate_keys[: pipeline.num_gradient_replicates]
    idx = [cat.index(n) for n in effects]
    points = pipeline.base_points(theta) + [(d + k, *cat.effects[k].finite_difference_points()) for k in idx]
    sens_c = sensitivities(candidates.simulate, theta, keys, points, pipeline.executor)
    num_c = len(candidates.names)
    if sens_c.shape[0] != num_c:
        raise ValueError(f"candidate simulator returns {sens_c.shape[0]} outputs for {num_c} candidate names")
    var = _candidate_noise_var(candidates, pred, theta, pipeline.executor)
    act = pred.active
    jac, cov = diagnosis.jacobian[act], pred.noise_cov[np.ix_(act, act)]
    fitted = diagnosis.fitted[act]
    out: dict[str, list[dict]] = {}
    for col, k in enumerate(idx):
        eff = cat.effects[k]
        strength = abs(float(eff.expected if eff.expected is not None else eff.high) - eff.null)
        v = diagnosis.directions[act, k]
        current = _signal(jac, v, cov, fitted, pipeline.prior_precision) * strength
        rows = [
            _candidate_row(
                candidates.names[c],
                sens_c[c, d + col],
                sens_c[c, :d],
                var[c],
                jac,
                v,
                cov,
                fitted,
                strength,
                current,
                pipeline.prior_precision,
            )
            for c in range(num_c)
        ]
        rows.sort(key=lambda r: -r["gain"] if np.isfinite(r["gain"]) else np.inf)
        out[eff.name] = rows
    return out


def _candidate_noise_var(
    candidates: CandidateObservables, pred: PosteriorPredictive, theta: np.ndarray, executor: Any
) -> np.ndarray:
    """Noise variance (c,) of each candidate: its simulation noise over the run's replicate
    keys at ``theta`` (failed simulations dropped; zero with fewer than two), plus the
    squared measurement sd when given."""
    num_c = len(candidates.names)
    reps = simulate_many(
        candidates.simulate,
        pred.replicate_keys,
        np.repeat(theta[None], len(pred.replicate_keys), 0),
        executor,
    )
    reps = reps[np.all(np.isfinite(reps), axis=1)]
    var = reps.var(axis=0, ddof=1) if reps.shape[0] > 1 else np.zeros(num_c)
    if candidates.measurement_sd is not None:
        var = var + np.broadcast_to(np.asarray(candidates.measurement_sd, float), (num_c,)) ** 2
    return var


def _candidate_row(
    name: str,
    vc: float,
    jc: np.ndarray,
    var_c: float,
    jac: np.ndarray,
    v: np.ndarray,
    cov: np.ndarray,
    fitted: np.ndarray,
    strength: float,
    current: float,
    prior_precision: np.ndarray | None = None,
) -> dict:
    """One candidate's entry of :func:`design_advice` for one effect.

    ``vc`` and ``jc`` (d,) are the candidate's sensitivities to the effect and to the base
    parameters, ``var_c`` its noise variance; ``jac`` (s, d), ``v`` (s,), ``cov`` (s, s) and
    ``fitted`` (s,) describe the current design, whose signal at ``strength`` is ``current``.
    A candidate without a positive noise estimate gets NaN measures and a note.
    """
    sd = float(np.sqrt(var_c))
    if not sd > 0:
        return dict(name=name, snr=float("nan"), current_snr=current, gain=float("nan"),
                    raw_snr=float("nan"), absorbed=float("nan"), sd=sd,
                    note="no noise estimate: give its measurement_sd")  # fmt: skip
    jac_a = np.vstack([jac, jc[None]])
    v_a = np.concatenate([v, [vc]])
    cov_a = np.zeros((cov.shape[0] + 1,) * 2)
    cov_a[:-1, :-1], cov_a[-1, -1] = cov, var_c
    snr = _signal(jac_a, v_a, cov_a, np.concatenate([fitted, [True]]), prior_precision) * strength
    raw = abs(vc) / sd * strength
    # The candidate's own residual response once the parameters fitted to the existing
    # summaries have absorbed the effect there (the candidate not fitted).
    a_own = refit_operator(jac_a, cov_a, np.concatenate([fitted, [False]]), prior_precision)
    resid = abs(float((a_own @ v_a)[-1])) / sd * strength
    return dict(
        name=name,
        snr=snr,
        current_snr=current,
        gain=snr**2 - current**2,
        raw_snr=raw,
        absorbed=float(1.0 - resid / raw) if raw > 0 else float("nan"),
        sd=sd,
        note="",
    )


def _fmt_power(pw: EffectPower) -> str:
    lo, hi = pw.interval
    return (
        f"power {pw.power:.2f} ± {pw.se:.2f} at the expected strength {pw.expected:g}, "
        f"95% interval [{lo:.2f}, {hi:.2f}] over {pw.num_datasets} simulated data sets"
    )


def annotate_causes(
    causes: list,
    catalogue: Catalogue,
    powers: dict[str, EffectPower],
    advice: dict[str, list[dict]],
    needed: Sequence[str],
    threshold: float = 0.5,
) -> None:
    """Attach ``expected``, ``power``, ``power_se``, ``power_interval``, ``detectable`` and
    ``design_advice`` to each cause, and say in its note what the power means."""
    for c in causes:
        eff = catalogue[c.name]
        pw = powers.get(c.name)
        details: dict[str, Any] = dict(expected=eff.expected, design_advice=advice.get(c.name))
        if pw is not None:
            low = c.name not in needed and not (np.isfinite(pw.power) and pw.power >= threshold)
            details.update(power=pw.power, power_se=pw.se, power_interval=tuple(pw.interval), detectable=not low)
            if low:
                lead = f"not detectable with these data ({_fmt_power(pw)}): its rank is no evidence against it"
            elif c.name in needed:
                lead = f"named by these data; {_fmt_power(pw)}"
            else:
                lead = (
                    f"detectable at its expected strength ({_fmt_power(pw)}) but not needed here: "
                    "the data speak against it at that strength"
                )
            note = lead + (f"; {c.note}" if c.note else "")
        else:
            note = c.note
        rows = advice.get(c.name) or []
        if rows and np.isfinite(rows[0]["gain"]) and rows[0]["gain"] > 0:
            best = rows[0]
            note += (
                f"; the candidate observable that would raise its power most is {best['name']} "
                f"(signal {best['snr']:.2g} noise sd at the expected strength with it, "
                f"{best['current_snr']:.2g} without)"
            )
        details["note"] = note
        c.__dict__.update(details)
