"""The record of an ABC model choice: probabilities with Monte Carlo errors, per-model posteriors."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jaxabc.results import ABCResult

__all__ = ["ModelChoiceResult", "load_model_choice", "probabilities_with_errors"]

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
        stems = [_file_stem(name) for name in self.names]
        if len(set(stems)) < len(stems):
            raise ValueError(f"model names {list(self.names)} map to clashing file names {stems}: rename the models")
        folder.mkdir(parents=True, exist_ok=True)
        for name, post in zip(self.names, self.posteriors, strict=True):
            post.save(folder / f"{_file_stem(name)}.npz", overwrite=True)
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
        posteriors=tuple(load(folder / f"{_file_stem(name)}.npz") for name in data["names"]),
        num_simulations=int(data["num_simulations"]),
        seed=int(data["seed"]),
        stop_reason=data["stop_reason"],
        wall_time=float(data["wall_time"]),
        metadata=data["metadata"],
    )


def _file_stem(name: str) -> str:
    # Model names are free text; file names keep letters, digits, '-', '_' and '.'.
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
