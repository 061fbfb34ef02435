"""The record of an ABC model choice: probabilities with Monte Carlo errors, per-model posteriors."""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from jaxabc.diagnostics import PRIOR_EDGE_WIDTH, prior_edge_mass, prior_edge_messages, prior_limit_notes
from jaxabc.errors import PriorEdgeWarning, caller_stacklevel
from jaxabc.noise import DISCREPANCY_PREFIX
from jaxabc.results import ABCResult

__all__ = [
    "INTERVAL_Z",
    "STATUS_NEEDS_SIMULATIONS",
    "STATUS_REUSED",
    "ModelChoiceResult",
    "SensitivityRow",
    "Verdict",
    "check_prior_edges",
    "file_stem",
    "load_model_choice",
    "probabilities_with_errors",
    "probability_bounds",
]

RESULT_FORMAT = "jaxabc-model-choice-1"


def probabilities_with_errors(
    log_evidence: np.ndarray, relative_errors: np.ndarray, model_prior: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Posterior model probabilities and their delta-method standard errors.

    ``P_m = p_m Z_m / sum_k p_k Z_k``.  With independent estimates of relative standard error
    ``r_k``, ``Var P_m = P_m^2 [(1 - P_m)^2 r_m^2 + sum_{k != m} P_k^2 r_k^2]``.

    Parameters
    ----------
    log_evidence : numpy.ndarray, shape (..., K)
        ``log Z``; ``-inf`` for a model with no accepted simulation.
    relative_errors : numpy.ndarray, shape (..., K)
        Standard error of ``Z`` over ``Z`` (any value where ``Z`` is zero).
    model_prior : numpy.ndarray, shape (K,)

    Returns
    -------
    probabilities, standard_errors : numpy.ndarray, shape (..., K)
        NaN in rows where every ``Z`` is zero.
    """
    log_z = np.asarray(log_evidence, np.float64)
    log_a = log_z + np.log(np.asarray(model_prior, np.float64))
    top = np.max(log_a, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore"):
        a = np.exp(log_a - top)  # NaN in rows whose top is -inf
    probs = a / np.sum(a, axis=-1, keepdims=True)
    r2 = np.where(probs > 0, np.asarray(relative_errors, np.float64) ** 2, 0.0)
    contrib = probs**2 * r2
    var = probs**2 * ((1.0 - probs) ** 2 * r2 + (np.sum(contrib, axis=-1, keepdims=True) - contrib))
    return probs, np.sqrt(var)


#: Status of a sensitivity row computed from the run's posterior samples (boxes inside the run's).
STATUS_REUSED = "reused: narrower box, no new simulations"
#: Status of a sensitivity row whose box reaches outside a model's run box.
STATUS_NEEDS_SIMULATIONS = "needs simulations in the wider box"
#: Standard errors each log evidence is moved by for the verdict's probability intervals.
INTERVAL_Z = 2.0
_ABC_SMC = "abcsmc_model_choice"  # _model_choice_smc.ALGORITHM_NAME (not imported: no JAX here)


def interval_leader(probabilities: np.ndarray, intervals: np.ndarray) -> int | None:
    """Index of the most probable model when its interval lies above every other's, else None.

    The rule by which :meth:`ModelChoiceResult.verdict` calls a model preferred (before it
    checks the sensitivity rows).  ``probabilities`` (K,), ``intervals`` (K, 2) as from
    :func:`probability_bounds`; None too when a probability is not finite.
    """
    p = np.asarray(probabilities, float)
    if p.size == 0 or not np.all(np.isfinite(p)):
        return None
    best = int(np.argmax(p))
    return None if _overlapping(best, np.asarray(intervals, float)) else best


def _overlapping(best: int, intervals: np.ndarray) -> list[int]:
    """The other models whose interval reaches the lower end of model ``best``'s."""
    return [k for k in range(len(intervals)) if k != best and not intervals[k, 1] < intervals[best, 0]]


def probability_bounds(
    log_evidence: np.ndarray,
    log_evidence_errors: np.ndarray,
    model_prior: np.ndarray,
    log_evidence_upper_bounds: np.ndarray | None = None,
    z: float = INTERVAL_Z,
) -> np.ndarray:
    """Each model's probability interval ``(K, 2)`` from intervals on the log evidences.

    Every ``log Z_k`` gets the interval ``log Z_k -+ z s.e.``; model ``m``'s lowest probability
    puts its own evidence at the bottom of its interval and every other model's at the top,
    its highest the reverse.  The interval is therefore conservative (it covers every
    combination of the evidence intervals), lies in [0, 1] and is asymmetric where the errors
    are large, unlike the delta method's ``P -+ 2 s.e.``.  A model without accepted
    simulations (``log Z = -inf``) runs from 0 to its upper bound
    (``log_evidence_upper_bounds``, ``inf`` when none is known); a NaN evidence makes every
    interval ``[0, 1]`` for that model and NaN-free for none: its row is ``[0, 1]``.
    """
    log_z = np.asarray(log_evidence, np.float64)
    se = np.nan_to_num(np.asarray(log_evidence_errors, np.float64), nan=np.inf)
    up = np.full(log_z.shape, np.inf) if log_evidence_upper_bounds is None else np.asarray(log_evidence_upper_bounds)
    up = np.where(np.isnan(up), np.inf, up)
    finite = np.isfinite(log_z)
    with np.errstate(invalid="ignore", over="ignore"):
        lo = np.where(finite, log_z - z * se, -np.inf)
        hi = np.where(finite, log_z + z * se, np.where(np.isnan(log_z), np.inf, up))
    log_p = np.log(np.asarray(model_prior, np.float64))
    la, ha = lo + log_p, hi + log_p
    out = np.zeros((log_z.size, 2))
    for m in range(log_z.size):
        others = np.delete(np.arange(log_z.size), m)
        out[m, 0] = _share(la[m], ha[others])
        out[m, 1] = _share(ha[m], la[others])
    return out


def _share(log_a: float, log_others: np.ndarray) -> float:
    """``a / (a + sum(others))`` from logs, with the limits at 0 and infinity."""
    rest = float(np.logaddexp.reduce(log_others)) if log_others.size else -np.inf
    if log_a == -np.inf:
        return 0.0 if rest > -np.inf else math.nan
    if log_a == np.inf:
        return 1.0 if rest < np.inf else math.nan
    if rest == np.inf:
        return 0.0
    if rest == -np.inf:
        return 1.0
    return float(math.exp(log_a - np.logaddexp(log_a, rest)))


class SensitivityRow(NamedTuple):
    """The model probabilities with some models' prior boxes changed (:meth:`ModelChoiceResult.sensitivity`).

    For a box ``B'`` inside a model's run box ``B`` the evidence follows from the run without
    new simulations: ``Z' = Z P(theta in B' | data) pi(B) / pi(B')`` (``pi(B)/pi(B')`` is
    ``vol(B) / vol(B')`` for a uniform prior), ``P(theta in B' | data)`` read off the model's
    weighted posterior sample.  Outside ``B`` the run knows nothing: such a model gets
    :data:`STATUS_NEEDS_SIMULATIONS`, its ``log_evidence`` is then the known **lower bound**
    ``log(Z P(theta in B' and B | data) pi(B) / pi(B'))``, and the row's probabilities are NaN.

    Attributes
    ----------
    label : str
        E.g. ``"near box x0.5"``, ``"all boxes x2"``, ``"near box [0, 1]"``.
    changed : str
        The model whose box changed, or ``"all"``.
    scale : float or None
        The width factor about each box's centre (None for a box given by the user).
    boxes : dict
        ``{model: [low, high]}`` for the models whose box changed.
    status : str
        :data:`STATUS_REUSED`, :data:`STATUS_NEEDS_SIMULATIONS` (``"... of 'name'"``), or
        ``"not computed: <why>"``.
    names : tuple of str, length K
    probabilities, standard_errors : numpy.ndarray, shape (K,)
        Delta-method standard errors as for the run; NaN unless the status is reused.
    intervals : numpy.ndarray, shape (K, 2)
        :func:`probability_bounds` (each ``log Z`` -+ 2 s.e.); NaN unless reused.
    log_evidence, log_evidence_errors : numpy.ndarray, shape (K,)
        The evidences under the changed boxes (lower bounds for the models in
        ``needs_simulations``) and their standard errors (from the posterior weights).
    log_evidence_upper_bounds : numpy.ndarray, shape (K,)
        For a model with no posterior particle in its new box (or none accepted at all): an
        approximate 95% upper bound (rule of three on the effective sample size); NaN otherwise.
    needs_simulations : tuple of str
        Models whose new box reaches outside their run box.
    """

    label: str
    changed: str
    scale: float | None
    boxes: dict[str, list]
    status: str
    names: tuple[str, ...]
    probabilities: np.ndarray
    standard_errors: np.ndarray
    intervals: np.ndarray
    log_evidence: np.ndarray
    log_evidence_errors: np.ndarray
    log_evidence_upper_bounds: np.ndarray
    needs_simulations: tuple[str, ...] = ()

    @property
    def computed(self) -> bool:
        """Whether the probabilities are known (every changed box inside its run box)."""
        return self.status == STATUS_REUSED

    @property
    def preferred(self) -> str | None:
        """The model these boxes alone would decide (:func:`interval_leader`), else None."""
        if not self.computed:
            return None
        k = interval_leader(self.probabilities, self.intervals)
        return None if k is None else self.names[k]

    def describe(self) -> str:
        """One line: the probabilities with intervals, or what is missing and the known bound."""
        if self.computed:
            parts = [
                f"{n} {p:.3f} [{lo:.3f}, {hi:.3f}]"
                for n, p, (lo, hi) in zip(self.names, self.probabilities, self.intervals, strict=True)
            ]
            return f"{self.label}: " + ", ".join(parts)
        if self.needs_simulations:
            bounds = ", ".join(
                f"log Z({n}) >= {self.log_evidence[self.names.index(n)]:.3f}" for n in self.needs_simulations
            )
            return f"{self.label}: {self.status} ({bounds})"
        return f"{self.label}: {self.status}"

    def to_json(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "changed": self.changed,
            "scale": self.scale,
            "boxes": {k: [list(map(float, v[0])), list(map(float, v[1]))] for k, v in self.boxes.items()},
            "status": self.status,
            "names": list(self.names),
            "probabilities": _encode(self.probabilities),
            "standard_errors": _encode(self.standard_errors),
            "intervals": [_encode(row) for row in self.intervals],
            "log_evidence": _encode(self.log_evidence),
            "log_evidence_errors": _encode(self.log_evidence_errors),
            "log_evidence_upper_bounds": _encode(self.log_evidence_upper_bounds),
            "needs_simulations": list(self.needs_simulations),
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> SensitivityRow:
        return cls(
            label=data["label"],
            changed=data["changed"],
            scale=data["scale"],
            boxes={k: [list(v[0]), list(v[1])] for k, v in data["boxes"].items()},
            status=data["status"],
            names=tuple(data["names"]),
            probabilities=_decode(data["probabilities"]),
            standard_errors=_decode(data["standard_errors"]),
            intervals=np.array([_decode(row) for row in data["intervals"]]).reshape(-1, 2),
            log_evidence=_decode(data["log_evidence"]),
            log_evidence_errors=_decode(data["log_evidence_errors"]),
            log_evidence_upper_bounds=_decode(data["log_evidence_upper_bounds"]),
            needs_simulations=tuple(data["needs_simulations"]),
        )


class Verdict(NamedTuple):
    """Whether the model choice prefers a model (:meth:`ModelChoiceResult.verdict`).

    Attributes
    ----------
    status : str
        ``"preferred"`` or ``"undecided"``.
    model : str or None
        The preferred model (None when undecided).
    reason : str
        In words: the interval that decided it, or which models overlap, which box flips the
        order, which evidence is missing; and the rows left unchecked.
    unchecked : tuple of str
        Labels of the sensitivity rows that need simulations in a wider box and could change
        the order (compute them with :func:`jaxabc.model_choice.with_boxes`).
    """

    status: str
    model: str | None
    reason: str
    unchecked: tuple[str, ...] = ()

    def __str__(self) -> str:
        head = f"preferred: {self.model}" if self.status == "preferred" else "undecided"
        return f"{head} ({self.reason})"


def _encode(values: Any) -> list:
    """Floats for JSON, non-finite ones as the strings ``"nan"``, ``"inf"``, ``"-inf"``."""
    return [float(v) if np.isfinite(v) else str(float(v)) for v in np.asarray(values, np.float64).reshape(-1)]


def _decode(values: list) -> np.ndarray:
    return np.array([float(v) for v in values], np.float64)


def _prior_box(prior: Any, d: int) -> tuple[np.ndarray, np.ndarray]:
    low = np.broadcast_to(np.asarray(getattr(prior, "low", -np.inf), np.float64).reshape(-1), (d,))
    high = np.broadcast_to(np.asarray(getattr(prior, "high", np.inf), np.float64).reshape(-1), (d,))
    return np.array(low), np.array(high)


def _log_prior_mass(prior: Any, low: np.ndarray, high: np.ndarray) -> float | None:
    """``log pi_0([low, high])`` of the prior's distribution before truncation to its box, up to a
    constant shared by every box; None for a prior without a known mass function."""
    if np.any(high <= low):
        return -math.inf
    if type(prior).__name__ == "Uniform":
        return float(np.sum(np.log(high - low)))
    distributions = getattr(prior, "distributions", None)
    if isinstance(distributions, Mapping) and len(distributions) == low.size:
        total = 0.0
        for d, lo, hi in zip(distributions.values(), low, high, strict=True):
            mass = float(d.cdf(hi)) - float(d.cdf(lo))
            if not mass > 0:
                return -math.inf
            total += math.log(mass)
        return total
    return None


def _box_evidence(
    post: ABCResult, log_z: float, log_se: float, log_z_up: float, low2: np.ndarray, high2: np.ndarray
) -> tuple[float, float, float, bool, str]:
    """``(log Z', s.e., upper bound, inside, problem)`` of one model under the box ``[low2, high2]``.

    ``inside``: the box lies within the run's box, so ``log Z'`` is an estimate; otherwise it is
    the lower bound from the part inside.  ``problem`` is non-empty when nothing can be said.
    """
    x = np.asarray(post.particles, np.float64)
    d = x.shape[1]
    low, high = _prior_box(post.prior, d)
    span = np.where(np.isfinite(high - low), high - low, 1.0)
    tol = 1e-9 * span
    inside = bool(np.all(low2 >= low - tol) and np.all(high2 <= high + tol))
    mass_run = _log_prior_mass(post.prior, low, high)
    if inside:  # within rounding of the run's box: clip to it
        low2, high2 = np.maximum(low2, low), np.minimum(high2, high)
    mass_new = _log_prior_mass(post.prior, low2, high2)
    if mass_run is None or mass_new is None:
        return (
            math.nan,
            math.nan,
            math.nan,
            inside,
            f"the prior of {post.settings.get('model', 'this model')!r} is neither Uniform nor Independent",
        )
    if mass_new == -math.inf:
        return math.nan, math.nan, math.nan, inside, "the box holds no prior mass"
    log_ratio = mass_run - mass_new
    if np.isnan(log_z):
        return math.nan, math.nan, math.nan, inside, ""
    if log_z == -math.inf:  # no accepted simulation: nothing inside, the bound scales
        return -math.inf, math.inf, (log_z_up + log_ratio) if inside else math.nan, inside, ""
    w = np.asarray(post.weights, np.float64)
    w = w / w.sum()
    in_box = np.all((x >= np.maximum(low, low2)) & (x <= np.minimum(high, high2)), axis=1)
    q = float(np.sum(w[in_box]))
    ess = float(post.effective_sample_size())
    if q <= 0.0:
        # Rule of three on the effective sample size: P(B' | data) < 3 / ESS at about 95%.
        bound = log_z + math.log(min(1.0, 3.0 / max(ess, 1.0))) + log_ratio
        return -math.inf, math.inf, bound if inside else math.nan, inside, ""
    proposals = post.metadata.get("proposals_per_step") if isinstance(post.metadata, dict) else None
    if post.algorithm == _ABC_SMC and proposals and len(proposals) == len(post.thresholds) and proposals[-1] > 1:
        # Z' is the mean over the generation's M slots of the accepted weights inside B': the
        # same estimator as Z, so its relative error follows from the same weights exactly.
        m = float(proposals[-1])
        rel2 = max(float(np.sum(w[in_box] ** 2)) / q**2 - 1.0 / m, 0.0) * m / (m - 1.0)
    else:
        # Z times a posterior fraction: their errors add (the fraction's is binomial on the ESS).
        rel2 = log_se**2 + (1.0 - q) / (q * max(ess, 1.0))
    return log_z + math.log(q) + log_ratio, math.sqrt(rel2), math.nan, inside, ""


def check_prior_edges(names: Sequence[str], posteriors: Sequence[ABCResult], warn: bool = True) -> dict[str, Any]:
    """Per model: the posterior mass near each bound of its prior box, and a
    :class:`~jaxabc.PriorEdgeWarning` naming the model, parameter and bound where more than
    :data:`~jaxabc.diagnostics.PRIOR_EDGE_LIMIT` lies within
    :data:`~jaxabc.diagnostics.PRIOR_EDGE_WIDTH` of the range from it.

    Returns ``{model: {"parameters", "mass" (d, 2), "messages"}}``; a model whose sample
    cannot be checked is left out.
    """
    out: dict[str, Any] = {}
    for name, post in zip(names, posteriors, strict=True):
        x = np.asarray(post.particles, np.float64)
        if x.ndim != 2 or x.shape[0] == 0:
            continue
        low, high = _prior_box(post.prior, x.shape[1])
        try:
            mass = prior_edge_mass(x, post.weights, low, high, PRIOR_EDGE_WIDTH)
        except ValueError:
            continue
        params = list(post.names)
        limits = getattr(post.prior, "limits", None)
        messages = prior_edge_messages(mass, params, low, high, PRIOR_EDGE_WIDTH, limits)
        notes = prior_limit_notes(mass, params, low, high, PRIOR_EDGE_WIDTH, limits)
        out[name] = {"parameters": params, "mass": mass.tolist(), "messages": messages, "at_physical_limits": notes}
        if warn and messages:
            warnings.warn(
                f"model {name!r}: " + "; ".join(messages) + ": its evidence, and the model probabilities, "
                "depend on where the box was cut (see ModelChoiceResult.sensitivity)",
                PriorEdgeWarning,
                stacklevel=caller_stacklevel(),
            )
    return out


@dataclass
class ModelChoiceResult:
    """Posterior model probabilities at a shared ABC tolerance, and each model's posterior.

    ``K`` models, ``g`` generations.

    Attributes
    ----------
    names : tuple of str, length K
    probabilities : numpy.ndarray, shape (K,)
        ``P(model | observed summaries)`` at the final tolerance; they sum to one.
    standard_errors : numpy.ndarray, shape (K,)
        Monte Carlo standard errors of ``probabilities`` (delta method on the importance-
        sampling evidence estimates, conditional on the tolerance).
    log_evidence : numpy.ndarray, shape (K,)
        ``log P(distance <= threshold | model)``, the ABC evidence; ``-inf`` when no simulation
        of the model met the tolerance.
    log_evidence_errors : numpy.ndarray, shape (K,)
        Standard errors of ``log_evidence`` (the evidence's relative standard errors).
    probability_upper_bounds : numpy.ndarray, shape (K,)
        For a model with no simulation within the final tolerance (probability 0, standard
        error 0): a 95% upper bound on its probability; NaN for the others.
    model_prior : numpy.ndarray, shape (K,)
    threshold : float
        The final shared tolerance, in distance units (NaN for surrogate evidence, which has
        none; ``thresholds`` then holds one NaN).
    thresholds : numpy.ndarray, shape (g,)
        The shared tolerance of each generation (``inf`` for the prior sample).
    probability_history, standard_error_history : numpy.ndarray, shape (g, K)
        Probabilities and their errors at each generation's tolerance: how the answer moved
        as the tolerance shrank.
    simulations_per_step : numpy.ndarray, shape (g, K)
    posteriors : tuple of ABCResult, length K
        Each model's weighted posterior at the final tolerance (``log_evidence`` filled in).
    num_simulations : int
        Over all models.
    seed : int
    stop_reason : str
    wall_time : float
        Seconds.
    metadata : dict
    prior_edge : dict
        Per model with a posterior sample: ``{"parameters", "mass" (d, 2), "messages"}``, the
        posterior mass within 2 % of the range from each bound of its prior box
        (:func:`jaxabc.diagnostics.prior_edge_mass`) and a sentence per bound holding more than
        5 % (each also raised as a :class:`jaxabc.PriorEdgeWarning` naming the model).
    sensitivity_table : list of SensitivityRow
        The box-sensitivity rows computed so far (:meth:`sensitivity`; the run computes the
        default scales 0.5 and 2); :meth:`verdict` checks every one.
    """

    names: tuple[str, ...]
    probabilities: np.ndarray
    standard_errors: np.ndarray
    log_evidence: np.ndarray
    log_evidence_errors: np.ndarray
    probability_upper_bounds: np.ndarray
    model_prior: np.ndarray
    threshold: float
    thresholds: np.ndarray
    probability_history: np.ndarray
    standard_error_history: np.ndarray
    simulations_per_step: np.ndarray
    posteriors: tuple[ABCResult, ...]
    num_simulations: int
    seed: int
    stop_reason: str = ""
    wall_time: float = 0.0
    metadata: dict[str, Any] = field(default_factory=dict)
    prior_edge: dict[str, Any] = field(default_factory=dict)
    sensitivity_table: list[SensitivityRow] = field(default_factory=list)

    def _index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no model named {name!r}: the models are {list(self.names)}") from None

    def posterior(self, name: str) -> ABCResult:
        """The posterior of the model called ``name``."""
        return self.posteriors[self._index(name)]

    def probability(self, name: str) -> tuple[float, float]:
        """``(probability, standard error)`` of the model called ``name``."""
        i = self._index(name)
        return float(self.probabilities[i]), float(self.standard_errors[i])

    @property
    def best(self) -> str:
        """The name of the most probable model."""
        return self.names[int(np.argmax(self.probabilities))]

    def bayes_factor(self, numerator: str, denominator: str) -> tuple[float, float]:
        """``(B, standard error of log B)`` for ``Z_numerator / Z_denominator``.

        ``B`` is ``inf`` or ``0`` when one of the two models had no accepted simulation (NaN
        when neither had), and its error is then ``inf``.
        """
        i, j = self._index(numerator), self._index(denominator)
        with np.errstate(invalid="ignore", over="ignore"):
            bayes = float(np.exp(self.log_evidence[i] - self.log_evidence[j]))
        return bayes, math.hypot(self.log_evidence_errors[i], self.log_evidence_errors[j])

    def _log_evidence_upper_bounds(self) -> np.ndarray:
        """``log`` of the 95% upper bound on ``Z`` of each model without an accepted simulation
        (from ``probability_upper_bounds``), NaN for the others."""
        out = np.full(len(self.names), np.nan)
        log_a = self.log_evidence + np.log(self.model_prior)
        for i, bound in enumerate(self.probability_upper_bounds):
            if not 0.0 < bound < 1.0:
                continue
            others = np.delete(log_a, i)
            others = others[np.isfinite(others)]
            if others.size:
                rest = float(np.logaddexp.reduce(others))
                out[i] = math.log(bound) + rest - math.log(self.model_prior[i]) - math.log1p(-bound)
        return out

    def probability_intervals(self, z: float = INTERVAL_Z) -> np.ndarray:
        """Each model's probability interval ``(K, 2)``: every log evidence moved by ``z`` of its
        standard errors, in every combination (:func:`probability_bounds`); a model without
        accepted simulations runs from 0 to its upper bound.  :meth:`verdict` uses these."""
        return probability_bounds(
            self.log_evidence, self.log_evidence_errors, self.model_prior, self._log_evidence_upper_bounds(), z
        )

    def _discrepancy_columns(self, i: int) -> np.ndarray:
        """Which of model ``i``'s parameters are discrepancy sds, shape ``(d,)``."""
        post = self.posteriors[i]
        names = list(getattr(post, "names", ()) or ())
        d = int(np.shape(post.particles)[1])
        return np.array([str(n).startswith(DISCREPANCY_PREFIX) for n in names[:d]] + [False] * (d - len(names)))

    def _scaled_box(self, i: int, scale: float, which: str = "all") -> tuple[np.ndarray, np.ndarray]:
        """Model ``i``'s box scaled by ``scale``: every parameter (``which="all"``), the force
        field's only (``"parameters"``) or the discrepancy sds' only (``"discrepancy"``)."""
        post = self.posteriors[i]
        low, high = _prior_box(post.prior, np.shape(post.particles)[1])
        if not np.all(np.isfinite(high - low)):
            raise ValueError(f"model {self.names[i]!r} has an unbounded prior: give its boxes explicitly")
        if which != "all":
            disc = self._discrepancy_columns(i)
            keep = ~disc if which == "discrepancy" else disc
            scaled_low, scaled_high = self._scaled_box(i, scale)
            return np.where(keep, low, scaled_low), np.where(keep, high, scaled_high)
        centre, half = 0.5 * (low + high), 0.5 * scale * (high - low)
        new_low, new_high = centre - half, centre + half
        # A bound that is a physical limit (a discrepancy sd's 0) stays: the width is scaled from it.
        limits = np.asarray(getattr(post.prior, "limits", None) or [(False, False)] * low.size, bool)
        width = scale * (high - low)
        new_low = np.where(
            limits[:, 0] & ~limits[:, 1], low, np.where(limits[:, 1] & ~limits[:, 0], high - width, new_low)
        )
        new_high = np.where(
            limits[:, 0] & ~limits[:, 1], low + width, np.where(limits[:, 1] & ~limits[:, 0], high, new_high)
        )
        both = limits[:, 0] & limits[:, 1]
        return np.where(both, low, new_low), np.where(both, high, new_high)

    def _user_boxes(self, name: str, value: Any) -> list[tuple[np.ndarray, np.ndarray]]:
        i = self._index(name)
        d = int(np.shape(self.posteriors[i].particles)[1])
        if hasattr(value, "low") and hasattr(value, "high"):
            value = (value.low, value.high)
        arr = np.asarray(value, np.float64)
        if arr.size % (2 * d) or arr.size == 0:
            raise ValueError(
                f"boxes for {name!r}: give (low, high) with {d} value(s) each, or a list of such pairs; "
                f"got shape {arr.shape}"
            )
        out = []
        for low, high in arr.reshape(-1, 2, d):
            if not np.all(low < high):
                raise ValueError(f"box for {name!r}: need low < high, got low={low.tolist()}, high={high.tolist()}")
            out.append((low, high))
        return out

    def _row(self, label: str, changed: str, scale: float | None, boxes: dict) -> SensitivityRow:
        log_z = np.array(self.log_evidence, np.float64)
        se = np.array(self.log_evidence_errors, np.float64)
        up = self._log_evidence_upper_bounds()
        needs, problems = [], []
        for name, (low, high) in boxes.items():
            i = self._index(name)
            lz, e, u, inside, problem = _box_evidence(self.posteriors[i], log_z[i], se[i], up[i], low, high)
            if problem:
                problems.append(f"{name}: {problem}")
                continue
            log_z[i], se[i], up[i] = lz, e, u
            if not inside:
                needs.append(name)
        k = len(self.names)
        probs, errors, intervals = np.full(k, np.nan), np.full(k, np.nan), np.full((k, 2), np.nan)
        if problems:
            status = "not computed: " + "; ".join(problems)
        elif needs:
            status = STATUS_NEEDS_SIMULATIONS
        else:
            status = STATUS_REUSED
            probs, errors = probabilities_with_errors(log_z, se, self.model_prior)
            intervals = probability_bounds(log_z, se, self.model_prior, up)
        return SensitivityRow(
            label=label,
            changed=changed,
            scale=scale,
            boxes={n: [np.asarray(lo).tolist(), np.asarray(hi).tolist()] for n, (lo, hi) in boxes.items()},
            status=status,
            names=tuple(self.names),
            probabilities=probs,
            standard_errors=errors,
            intervals=intervals,
            log_evidence=log_z,
            log_evidence_errors=se,
            log_evidence_upper_bounds=up,
            needs_simulations=tuple(needs),
        )

    def sensitivity(
        self,
        scales: Sequence[float] = (0.5, 2.0),
        boxes: Mapping[str, Any] | None = None,
        split_discrepancy: bool = False,
    ) -> list[SensitivityRow]:
        """How the model probabilities move when the prior boxes change.

        One row per model and scale (that model's box scaled in width about its centre, the
        others' kept), one per scale with every box scaled (``"all boxes x<scale>"``), and one
        per box given in ``boxes``.  A box inside the run's box reuses the run: the evidence
        becomes ``Z' = Z P(theta in B' | data) pi(B) / pi(B')`` (``vol(B) / vol(B')`` for a
        uniform prior) from the model's weighted posterior sample, with its Monte Carlo error
        from the same weights (for ABC-SMC model choice exactly the importance-sampling error
        of the generation's evidence restricted to ``B'``; for surrogate evidence the
        evidence's error plus the binomial error of the posterior fraction on the chains' ESS).
        A box reaching outside the run's box is **not** extrapolated: the row's status is
        :data:`STATUS_NEEDS_SIMULATIONS`, its probabilities are NaN, and its ``log_evidence``
        holds the known lower bound ``log(Z P(theta in B' and B | data) pi(B) / pi(B'))`` for
        those models; compute it with :func:`jaxabc.model_choice.with_boxes`.

        The rows are also kept in :attr:`sensitivity_table` (replacing rows of the same label),
        which :meth:`verdict`, :meth:`summary` and :meth:`save` use.

        Parameters
        ----------
        scales : sequence of float
            Width factors, positive; ``< 1`` narrows (computed), ``> 1`` widens (needs
            simulations).
        boxes : mapping, optional
            ``{model name: (low, high)}`` or ``{model name: [(low, high), ...]}``, or a prior
            with ``low`` and ``high``; ``low`` and ``high`` one value per parameter.
        split_discrepancy : bool
            Also scale, for each model with discrepancy sds and each scale, its force-field box
            alone (``"<model> parameters x<scale>"``) and its discrepancy bounds alone
            (``"<model> discrepancy x<scale>"``, each ``max_sd`` scaled from 0), and every
            model's discrepancy bounds at once (``"all discrepancy x<scale>"``): which prior
            moves the probabilities.  An sd the data bound from below only
            (:meth:`jaxabc.ABCResult.discrepancy_identification`) moves its model's evidence
            with its ``max_sd``.

        Returns
        -------
        list of SensitivityRow
        """
        specs: list[tuple[str, str, float | None, dict]] = []
        for scale in scales:
            scale = float(scale)
            if not (math.isfinite(scale) and scale > 0):
                raise ValueError(f"scales must be positive and finite, got {scale!r}")
            for i, name in enumerate(self.names):
                specs.append((f"{name} box x{scale:g}", name, scale, {name: self._scaled_box(i, scale)}))
            every = {name: self._scaled_box(i, scale) for i, name in enumerate(self.names)}
            specs.append((f"all boxes x{scale:g}", "all", scale, every))
            if split_discrepancy:
                with_disc = [i for i in range(len(self.names)) if self._discrepancy_columns(i).any()]
                for i in with_disc:
                    name = self.names[i]
                    for which in ("parameters", "discrepancy"):
                        specs.append(
                            (f"{name} {which} x{scale:g}", name, scale, {name: self._scaled_box(i, scale, which)})
                        )
                if with_disc:
                    every = {self.names[i]: self._scaled_box(i, scale, "discrepancy") for i in with_disc}
                    specs.append((f"all discrepancy x{scale:g}", "all", scale, every))
        for name, value in (boxes or {}).items():
            for low, high in self._user_boxes(name, value):
                text = ", ".join(f"[{lo:g}, {hi:g}]" for lo, hi in zip(low, high, strict=True))
                specs.append((f"{name} box {text}", name, None, {name: (low, high)}))
        rows = [self._row(*spec) for spec in specs]
        fresh = {row.label for row in rows}
        self.sensitivity_table = [r for r in self.sensitivity_table if r.label not in fresh] + rows
        return rows

    def _overlaps(self, best: int, intervals: np.ndarray) -> list[str]:
        """The other models whose interval reaches the best model's, in words."""
        iv = intervals
        return [f"{self.names[k]} [{iv[k, 0]:.3f}, {iv[k, 1]:.3f}]" for k in _overlapping(best, iv)]

    def verdict(self, z: float = INTERVAL_Z) -> Verdict:
        """``"preferred"`` with the model only when the data decide it, else ``"undecided"`` and why.

        The rule: the most probable model's interval (:meth:`probability_intervals`: every log
        evidence moved by ``z`` standard errors, in every combination; 2 by default) lies above
        every other model's interval, **and** it stays so in every row of
        :attr:`sensitivity_table` computed from the run (the narrower boxes).  A row that needs
        simulations in a wider box decides only where the widened model is the preferred one
        and its known lower bound keeps it preferred; the others (a competitor's wider box could
        raise its evidence without limit) are listed in ``unchecked`` and in the reason: the
        preference holds for the boxes computed, not for those.
        """
        names = self.names
        missing = [n for n, v in zip(names, self.log_evidence, strict=True) if np.isnan(v)]
        if missing:
            return Verdict("undecided", None, f"no evidence comparable across the models for {missing}")
        if not np.any(np.isfinite(self.log_evidence)):
            return Verdict("undecided", None, "no model has an accepted simulation")
        best = int(np.argmax(self.probabilities))
        intervals = self.probability_intervals(z)
        how = f"each log evidence +- {z:g} s.e."
        overlap = self._overlaps(best, intervals)
        if overlap:
            return Verdict(
                "undecided",
                None,
                f"the probability interval of {names[best]} [{intervals[best, 0]:.3f}, {intervals[best, 1]:.3f}] "
                f"overlaps that of {', '.join(overlap)} ({how})",
            )
        flips, unchecked, by_bound, computed = [], [], [], 0
        for row in self.sensitivity_table:
            if row.computed and not np.any(np.isfinite(row.probabilities)):
                unchecked.append(f"{row.label} (no finite probabilities)")
            elif row.computed:
                computed += 1
                b = int(np.nanargmax(row.probabilities))
                if b != best:
                    flips.append(
                        f"with {row.label} {names[b]} is the most probable ({row.probabilities[b]:.3f} "
                        f"[{row.intervals[b, 0]:.3f}, {row.intervals[b, 1]:.3f}])"
                    )
                elif overlap := self._overlaps(best, row.intervals):
                    flips.append(f"with {row.label} {names[best]}'s interval overlaps {', '.join(overlap)}")
            elif set(row.needs_simulations) == {names[best]} and not row.status.startswith("not computed"):
                iv = probability_bounds(
                    row.log_evidence, row.log_evidence_errors, self.model_prior, row.log_evidence_upper_bounds, z
                )
                (by_bound if not self._overlaps(best, iv) else unchecked).append(row.label)
            else:
                unchecked.append(row.label)
        rest = ""
        if unchecked:
            rest = (
                f"; not checked, as they need simulations in a wider box and could change the order: "
                f"{', '.join(unchecked)} (compute them with "
                "jaxabc.run(jaxabc.model_choice.with_boxes(models, boxes), ...))"
            )
        if flips:
            return Verdict(
                "undecided", None, "the order depends on the prior boxes: " + "; ".join(flips) + rest, tuple(unchecked)
            )
        reason = (
            f"{names[best]} {self.probabilities[best]:.3f} [{intervals[best, 0]:.3f}, {intervals[best, 1]:.3f}] "
            f"lies above every other model's interval ({how}) at the run's boxes"
        )
        if computed:
            reason += f" and in all {computed} narrower-box rows of the sensitivity table"
        if by_bound:
            reason += f"; the known lower bound keeps it so in {', '.join(by_bound)}"
        if not self.sensitivity_table:
            reason += "; box sensitivity not computed (call sensitivity())"
        return Verdict("preferred", names[best], reason + rest, tuple(unchecked))

    def summary(self) -> str:
        """A few lines for a terminal: probabilities with errors, evidence, cost per model."""
        if np.isnan(self.threshold):
            head = f"surrogate evidence: {len(self.names)} models, {self.num_simulations} simulations"
        else:
            head = (
                f"ABC model choice: {len(self.names)} models, {self.num_simulations} simulations, "
                f"{len(self.thresholds)} steps, shared tolerance {self.threshold:.4g}"
            )
        # Where the log evidences carry large errors the delta-method SE of a probability can
        # exceed 1; the interval drawn from those errors (surrogate evidence) is then shown.
        interval = self.metadata.get("probability_interval_95")
        lines = [
            f"{head}, stopped: {self.stop_reason}, {self.wall_time:.1f} s",
            f"  {'model':>16s}  {'probability':>18s}  {'log evidence':>17s}  {'simulations':>11s}  {'ESS':>7s}",
        ]
        for i, name in enumerate(self.names):
            post = self.posteriors[i]
            if interval is None:
                probability = f"{self.probabilities[i]:8.4f} +- {self.standard_errors[i]:6.4f}"
            else:
                probability = f"{self.probabilities[i]:.3f} [{interval[i][0]:.2f}, {interval[i][1]:.2f}]"
            lines.append(
                f"  {name:>16s}  {probability:>18s}"
                f"  {self.log_evidence[i]:8.3f} +- {self.log_evidence_errors[i]:5.3f}"
                f"  {post.num_simulations:11d}  {post.effective_sample_size():7.1f}"
            )
        for name, info in self.prior_edge.items():
            lines.extend(f"  prior edge, model {name!r}: {message}" for message in info.get("messages", []))
        for name, post in zip(self.names, self.posteriors, strict=True):
            if hasattr(post, "discrepancy_identification"):
                lines.extend(f"  discrepancy, model {name!r}: {m}" for m in post.discrepancy_identification()[1])
        if self.sensitivity_table:
            lines.append(f"  prior-box sensitivity (probability [interval, each log evidence +- {INTERVAL_Z:g} s.e.]):")
            lines.extend(f"    {row.describe()}" for row in self.sensitivity_table)
        lines.append(f"  verdict: {self.verdict()}")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no particles or records): for benchmark results and reports."""
        return {
            "format": RESULT_FORMAT,
            "names": list(self.names),
            "probabilities": self.probabilities.tolist(),
            "standard_errors": self.standard_errors.tolist(),
            "log_evidence": [_finite_or_none(v) for v in self.log_evidence],
            "log_evidence_errors": [_finite_or_none(v) for v in self.log_evidence_errors],
            "probability_upper_bounds": [_finite_or_none(v) for v in self.probability_upper_bounds],
            "model_prior": self.model_prior.tolist(),
            "threshold": _finite_or_none(self.threshold),
            "thresholds": [_finite_or_none(v) for v in self.thresholds],
            "probability_history": self.probability_history.tolist(),
            "standard_error_history": self.standard_error_history.tolist(),
            "simulations_per_step": self.simulations_per_step.tolist(),
            "num_simulations": self.num_simulations,
            "seed": self.seed,
            "stop_reason": self.stop_reason,
            "wall_time": self.wall_time,
            "metadata": self.metadata,
            "prior_edge": self.prior_edge,
            "sensitivity": [row.to_json() for row in self.sensitivity_table],
            "verdict": self.verdict()._asdict(),
            "posteriors": {
                name: {
                    "bayes_estimate": post.bayes_estimate().tolist(),
                    "credible_interval_95": post.credible_interval(0.95).tolist(),
                    "ess": post.effective_sample_size(),
                    "num_simulations": post.num_simulations,
                    "num_failures": post.num_failures,
                    "parameter_names": list(post.names),
                }
                for name, post in zip(self.names, self.posteriors, strict=True)
            },
        }

    def save(self, folder: str | Path, overwrite: bool = False) -> Path:
        """Write ``model_choice.json`` and one ``<name>.npz`` posterior per model in ``folder``.

        Raises ``FileExistsError`` when ``model_choice.json`` exists and ``overwrite`` is False.
        Read back with :func:`jaxabc.model_choice.load_model_choice`.
        """
        folder = Path(folder)
        summary = folder / "model_choice.json"
        if summary.exists() and not overwrite:
            raise FileExistsError(f"{summary} exists: pass overwrite=True to replace it, or choose another folder")
        stems = [file_stem(name) for name in self.names]
        if len(set(stems)) < len(stems):
            raise ValueError(f"model names {list(self.names)} map to clashing file names {stems}: rename the models")
        folder.mkdir(parents=True, exist_ok=True)
        for name, post in zip(self.names, self.posteriors, strict=True):
            post.save(folder / f"{file_stem(name)}.npz", overwrite=True)
        summary.write_text(json.dumps(self.to_dict(), indent=1, default=_json_default) + "\n")
        return summary


def load_model_choice(folder: str | Path) -> ModelChoiceResult:
    """Read a result written by :meth:`ModelChoiceResult.save`.

    Raises
    ------
    FileNotFoundError
        No ``model_choice.json`` (or a posterior file) in ``folder``.
    ValueError
        The folder holds something other than a jaxabc model-choice result.
    """
    from jaxabc.results import load

    folder = Path(folder)
    summary = folder / "model_choice.json"
    if not summary.exists():
        raise FileNotFoundError(f"no model_choice.json in {folder}")
    data = json.loads(summary.read_text())
    if not isinstance(data, dict) or data.get("format") != RESULT_FORMAT:
        raise ValueError(f"{summary} is not a jaxabc model-choice result (expected format {RESULT_FORMAT!r})")

    def floats(values: list) -> np.ndarray:
        return np.array([np.nan if v is None else v for v in values], np.float64)

    log_z = np.array([-np.inf if v is None else v for v in data["log_evidence"]], np.float64)
    log_z_err = np.array([np.inf if v is None else v for v in data["log_evidence_errors"]], np.float64)
    # None is an infinite tolerance (the prior sample), or no tolerance at all (surrogate evidence).
    missing = np.nan if data["threshold"] is None else np.inf
    thresholds = np.array([missing if v is None else v for v in data["thresholds"]], np.float64)
    return ModelChoiceResult(
        names=tuple(data["names"]),
        probabilities=floats(data["probabilities"]),
        standard_errors=floats(data["standard_errors"]),
        log_evidence=log_z,
        log_evidence_errors=log_z_err,
        probability_upper_bounds=floats(data["probability_upper_bounds"]),
        model_prior=floats(data["model_prior"]),
        threshold=float(missing if data["threshold"] is None else data["threshold"]),
        thresholds=thresholds,
        probability_history=np.asarray(data["probability_history"], np.float64),
        standard_error_history=np.asarray(data["standard_error_history"], np.float64),
        simulations_per_step=np.asarray(data["simulations_per_step"]),
        posteriors=tuple(load(folder / f"{file_stem(name)}.npz") for name in data["names"]),
        num_simulations=int(data["num_simulations"]),
        seed=int(data["seed"]),
        stop_reason=data["stop_reason"],
        wall_time=float(data["wall_time"]),
        metadata=data["metadata"],
        prior_edge=data.get("prior_edge", {}),
        sensitivity_table=[SensitivityRow.from_json(row) for row in data.get("sensitivity", [])],
    )


def file_stem(name: str) -> str:
    """The file-name stem of model ``name``'s posterior (``posterior_<name>``, characters other
    than letters, digits, ``-``, ``_`` and ``.`` replaced by ``_``)."""
    stem = "".join(c if c.isalnum() or c in "-_." else "_" for c in name)
    return f"posterior_{stem}"


def _finite_or_none(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)
