"""The posterior record: summaries of the weighted sample, a self-describing file, plots.

A result file is a single ``.npz`` holding the arrays (particles, weights, the record of every
simulation) and a JSON string ``metadata`` (algorithm, settings, seed, prior, versions,
threshold history, stopping reason), so it can be read back with NumPy alone.

The Monte Carlo error of the summaries is set by the effective sample size: Kish's
``1 / sum w^2`` for weighted independent particles; for ABCsubsim, whose population is a set of
short Markov chains with shared ancestors, the honest estimate of
:func:`jaxabc.algorithms.subsim.chain_diagnostics` (never more than the distinct particles).
The MCSE of the posterior mean of ABCsubsim and APMCABC comes from their particles' lineages
(``diagnostics["mcse"]``), and is ``inf`` for a population that has collapsed onto a few points.
"""

from __future__ import annotations

import inspect
import json
import os
import platform
import tempfile
import warnings
import zipfile
import zlib
from dataclasses import InitVar, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jaxabc.diagnostics import (
    PRIOR_EDGE_LIMIT,
    PRIOR_EDGE_WIDTH,
    discrepancy_identification,
    prior_edge_mass,
    prior_edge_messages,
    prior_limit_notes,
)
from jaxabc.errors import PriorEdgeWarning
from jaxabc.priors import Uniform

__all__ = ["ABCResult", "load", "versions", "write_outputs"]

RESULT_FORMAT = "jaxabc-result-1"
_REQUIRED_ARRAYS = (
    "particles",
    "weights",
    "distances",
    "thresholds",
    "simulations_per_step",
    "acceptance_rates",
    "ess",
)


def versions() -> dict[str, str]:
    """Versions of the packages that shape a result, for result files and benchmarks.

    Read from the installed distributions' metadata, so stamping a result never imports
    jax-md or mdtraj (importing jax-md alone costs seconds).  A package that is not installed
    is left out.
    """
    from importlib.metadata import PackageNotFoundError, version

    from jaxabc import __version__

    out = {"python": platform.python_version(), "numpy": np.__version__}
    for key, dist in (("jax", "jax"), ("jaxlib", "jaxlib"), ("jax_md", "jax-md")):
        try:
            out[key] = version(dist)
        except PackageNotFoundError:
            pass
    out["jaxabc"] = __version__
    return out


@dataclass
class ABCResult:
    """A weighted posterior sample and the history of the run that produced it.

    Attributes
    ----------
    particles : numpy.ndarray, shape (n, d)
    weights : numpy.ndarray, shape (n,)
        Normalised, summing to one.
    distances : numpy.ndarray, shape (n,)
    thresholds : numpy.ndarray, shape (g,)
        Tolerance of each completed generation (``inf`` for a prior sample).
    simulations_per_step : numpy.ndarray, shape (g,)
        Simulations run to produce each generation.
    acceptance_rates, ess : numpy.ndarray, shape (g,)
        ``ess`` is each generation's effective sample size; for ABCsubsim the last entry is the
        honest chain estimate (see :meth:`effective_sample_size`), never more than the distinct
        particles.
    num_simulations : int
    algorithm : str
    settings : dict
    prior : Uniform
    seed : int
    stop_reason : str
    wall_time : float
        Seconds.
    log_evidence : float or None
        ABCsubsim's ``log P(d < eps_final)`` estimate.
    records : dict of numpy.ndarray
        Every simulation: ``theta (S, d)``, ``summaries (S, ...)``, ``distance``, ``status``,
        ``wall_time``, ``cpu_time`` (see :class:`jaxabc.SimulationBatch`), ``worker``,
        ``iteration``, and ``reasons`` (list of str).
    metadata : dict
        Versions, executor, distance, anything else worth keeping.
    diagnostics : dict
        Monte Carlo diagnostics of the final population (for ABCsubsim: distinct particles,
        chain ESS, whether the chains stopped moving; for ABCsubsim and APMCABC: ``mcse``,
        ``num_lineages``, ``effective_lineages``, ``collapsed`` and ``mcse_note``); filled in
        on construction; ``diagnostics["prior_edge"]`` (every result) holds the posterior mass
        near each bound of the prior box (see :meth:`prior_edge_mass`) and the sentences for the
        bounds where it exceeds 5 %.
    check : bool
        Warn on construction when the final population is degenerate (ABCsubsim chains that
        stopped moving), and with a :class:`jaxabc.PriorEdgeWarning` when the posterior piles
        against a bound of the prior; :func:`load` and :meth:`from_sample` pass False.
    """

    particles: np.ndarray
    weights: np.ndarray
    distances: np.ndarray
    thresholds: np.ndarray
    simulations_per_step: np.ndarray
    acceptance_rates: np.ndarray
    ess: np.ndarray
    num_simulations: int
    algorithm: str
    settings: dict
    prior: Uniform
    seed: int
    stop_reason: str = ""
    wall_time: float = 0.0
    log_evidence: float | None = None
    records: dict[str, Any] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)
    check: InitVar[bool] = True

    def __post_init__(self, check: bool) -> None:
        self._check_chains(check)
        edge = self._prior_edge_diagnostics()
        if edge is None:
            return
        self.diagnostics = {**self.diagnostics, "prior_edge": edge}
        if check and edge["messages"]:
            model = self.settings.get("model") if isinstance(self.settings, dict) else None
            prefix = f"model {model!r}: " if model is not None else ""
            # One warning per result, pointed at the user's call (run, run_fused, ...).
            warnings.warn(prefix + "; ".join(edge["messages"]), PriorEdgeWarning, stacklevel=_user_stacklevel())

    def _check_chains(self, check: bool) -> None:
        """ABCsubsim's chain diagnostics, computed on construction (see ``diagnostics``)."""
        # "mcse": diagnostics from before the lineage MCSE (older files) are recomputed.
        if not self._is_chain_population() or "mcse" in self.diagnostics:
            return
        from jaxabc.algorithms.subsim import chain_diagnostics

        ess = np.array(self.ess, dtype=np.float64, copy=True)
        level = len(self.thresholds) - 1
        acceptance = float(self.acceptance_rates[-1]) if len(self.acceptance_rates) else 1.0
        # The driver's per-level ESS (ABCsubsim's jittable lineage bound) caps the chain estimate.
        bound = float(ess[-1]) if ess.size else None
        self.diagnostics = {
            **self.diagnostics,
            **chain_diagnostics(self.particles, self.settings, level, acceptance, bound),
        }
        if ess.size:
            ess[-1] = self.diagnostics["ess"]
            self.ess = ess
        if check and self.diagnostics["warning"]:
            warnings.warn(self.diagnostics["warning"], UserWarning, stacklevel=_user_stacklevel())

    def _prior_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The prior's box ``(low, high)``, float64, shape (d,) each; ``inf`` where it has none.

        :class:`~jaxabc.Uniform` and :class:`~jaxabc.Independent` (whose box is each
        distribution's support cut by its ``bounds``: where the kernels truncate the posterior)
        both have ``low`` and ``high``; a prior without them, or with a non-finite bound, has no
        edge there.
        """
        d = np.shape(self.particles)[1]
        out = []
        for attr, missing in (("low", -np.inf), ("high", np.inf)):
            value = getattr(self.prior, attr, None)
            bound = np.full(d, missing) if value is None else np.asarray(value, np.float64).reshape(-1)
            out.append(np.array(np.broadcast_to(bound, (d,))))
        return out[0], out[1]

    def prior_edge_mass(self, width: float = PRIOR_EDGE_WIDTH) -> np.ndarray:
        """Posterior mass near each bound of the prior box.

        The weighted share of the final population within ``width * (high - low)`` of each
        bound of the prior box (:func:`jaxabc.diagnostics.prior_edge_mass`).  A posterior that
        piles against a bound (more than 5 % of its mass within 2 % of the range, the rule of
        :class:`jaxabc.PriorEdgeWarning`) is one the data would move further: it, and any
        evidence, depend on where the box was cut.  A flat posterior holds ``width`` at each
        bound.

        Parameters
        ----------
        width : float
            The band's width as a fraction of the range ``high - low``, in (0, 0.5).

        Returns
        -------
        numpy.ndarray, shape (d, 2)
            ``[j, 0]`` the posterior mass of parameter ``j`` within the band above its lower
            bound, ``[j, 1]`` within the band below its upper bound; each in [0, 1].  A
            non-finite bound (a prior without a box there) has mass 0.

        Raises
        ------
        ValueError
            If ``width`` is not in (0, 0.5).
        """
        if not 0.0 < float(width) < 0.5:
            raise ValueError(f"width must be a fraction of the range in (0, 0.5), got {width!r}")
        low, high = self._prior_box()
        return prior_edge_mass(self.particles, self.weights, low, high, width)

    def discrepancy_identification(self) -> tuple[dict[str, float], list[str]]:
        """Each discrepancy sd's posterior share in the upper half of its prior range, and a
        sentence for each the data bound from below only
        (:func:`jaxabc.diagnostics.discrepancy_identification`); empty without discrepancy sds."""
        low, high = self._prior_box()
        return discrepancy_identification(self.particles, self.weights, self.names, low, high)

    def _prior_edge_diagnostics(self) -> dict | None:
        """``diagnostics["prior_edge"]``: the mass at the default width and the sentences for
        the bounds past the limit; None for a population it cannot be computed on (weights that
        are not a distribution, particles that do not match the prior)."""
        try:
            mass = self.prior_edge_mass()
            low, high = self._prior_box()
        except (ValueError, TypeError, IndexError):
            return None
        limits = getattr(self.prior, "limits", None)
        return {
            "width": PRIOR_EDGE_WIDTH,
            "limit": PRIOR_EDGE_LIMIT,
            "mass": mass.tolist(),
            "messages": prior_edge_messages(mass, self.names, low, high, PRIOR_EDGE_WIDTH, limits),
            "at_physical_limits": prior_limit_notes(mass, self.names, low, high, PRIOR_EDGE_WIDTH, limits),
        }

    def _is_chain_population(self) -> bool:
        """ABCsubsim's population (equal weights, chains stored step-major), intact."""
        if self.algorithm != "abcsubsim":
            return False
        num_chains = self.settings.get("num_chains")
        chain_length = self.settings.get("chain_length")
        return (
            num_chains is not None
            and chain_length is not None
            and np.ndim(self.particles) == 2
            and self.particles.shape[0] == int(num_chains) * int(chain_length)
        )

    @classmethod
    def from_sample(cls, particles: np.ndarray, weights: np.ndarray, prior: Uniform, algorithm: str = "") -> ABCResult:
        """A result holding only a weighted sample (no run history), for its summaries.

        Parameters
        ----------
        particles : array_like, shape (n, d)
        weights : array_like, shape (n,)
            Non-negative, not necessarily normalised.
        prior : Uniform
        algorithm : str
        """
        p = np.asarray(particles, np.float64)
        w = np.asarray(weights, np.float64)
        if p.ndim != 2 or w.shape != (p.shape[0],):
            raise ValueError(f"need particles (n, d) and weights (n,), got {p.shape} and {w.shape}")
        if not (np.all(w >= 0) and w.sum() > 0):
            raise ValueError("weights must be non-negative with a positive sum")
        n = p.shape[0]
        return cls(
            particles=p,
            weights=w / w.sum(),
            distances=np.zeros(n),
            thresholds=np.array([np.nan]),
            simulations_per_step=np.array([n]),
            acceptance_rates=np.array([np.nan]),
            ess=np.array([1.0 / np.sum((w / w.sum()) ** 2)]),
            num_simulations=0,
            algorithm=algorithm,
            settings={},
            prior=prior,
            seed=0,
            # Not a run's result (e.g. one of the many posteriors of a coverage study): no warning.
            check=False,
        )

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.prior.names)

    @property
    def num_failures(self) -> int:
        status = self.records.get("status")
        return 0 if status is None else int(np.sum(np.asarray(status) != 0))

    def bayes_estimate(self) -> np.ndarray:
        """Posterior mean, shape (d,) (the Bayes estimate under squared-error loss)."""
        return np.sum(self.weights[:, None] * self.particles, axis=0)

    def covariance(self) -> np.ndarray:
        """Weighted posterior covariance, shape (d, d) (reliability-weight corrected)."""
        return np.atleast_2d(np.cov(self.particles, aweights=self.weights, rowvar=False))

    def correlation(self) -> np.ndarray:
        """Posterior correlation matrix, shape (d, d)."""
        cov = self.covariance()
        sd = np.sqrt(np.diag(cov))
        # A parameter without spread (a collapsed population) has NaN correlations, silently.
        with np.errstate(divide="ignore", invalid="ignore"):
            return cov / np.outer(sd, sd)

    def effective_sample_size(self) -> float:
        """Effective sample size of the final population, the one that sets Monte Carlo errors.

        Kish's ``1 / sum w^2`` for weighted independent particles; for an ABCsubsim population
        of Markov chains the autocorrelation- and lineage-aware estimate in ``ess[-1]``
        (never more than the distinct particles); for the surrogate's NUTS draws (equal
        weights, correlated) the chains' ESS its algorithm reported in ``ess[-1]``.
        """
        kish = float(1.0 / np.sum(self.weights**2))
        if self._is_chain_population() and "ess" in self.diagnostics:
            return min(kish, float(self.diagnostics["ess"]))
        if self.algorithm == "surrogate" and np.size(self.ess) and np.isfinite(self.ess[-1]):
            return min(kish, float(self.ess[-1]))
        return kish

    def mcse(self) -> np.ndarray:
        """Monte Carlo standard error of :meth:`bayes_estimate`, shape (d,).

        The error of the estimate from the finite sample, not the posterior's width.  Where the
        algorithm measured it from the particles' lineages (``diagnostics["mcse"]``: ABCsubsim,
        APMCABC, whose particles share ancestors) that value; otherwise the posterior standard
        deviation over ``sqrt(ESS)`` with the ESS of :meth:`effective_sample_size`.  ``inf``
        when the population has collapsed (``diagnostics["collapsed"]``, or fewer than two
        distinct particles carry weight): a few repeated points cannot say how far off the
        estimate is.
        """
        stored = self.diagnostics.get("mcse")
        d = self.particles.shape[1]
        if stored is not None and np.shape(stored) == (d,):
            return np.asarray(stored, np.float64)
        weighted = self.particles[np.asarray(self.weights) > 0]
        if weighted.shape[0] < 2 or np.all(weighted == weighted[0]):
            return np.full(d, np.inf)
        return np.sqrt(np.diag(self.covariance()) / self.effective_sample_size())

    def credible_interval(self, level: float = 0.95, adjust_for_ess: bool = False) -> np.ndarray:
        """Equal-tailed weighted credible interval per parameter, shape (d, 2).

        Parameters
        ----------
        level : float
            In (0, 1).
        adjust_for_ess : bool
            Widen each interval about the weighted median by the factor
            ``t_{ESS-1}(q) sqrt(1 + 1 / ESS) / z(q)`` (a prediction interval from ``ESS``
            effective draws), so that a small effective sample does not give overconfident
            intervals; the ESS is :meth:`effective_sample_size`.
        """
        if not 0.0 < level < 1.0:
            raise ValueError(f"level must lie in (0, 1), got {level}")
        out = self._quantile_interval(level)
        if adjust_for_ess:
            from scipy.stats import norm, t

            ess = max(self.effective_sample_size(), 2.0)
            q = (1.0 + level) / 2.0
            factor = t.ppf(q, ess - 1.0) * np.sqrt(1.0 + 1.0 / ess) / norm.ppf(q)
            median = self._quantile_interval(1e-9)[:, 0]
            out = median[:, None] + factor * (out - median[:, None])
        return out

    def _quantile_interval(self, level: float) -> np.ndarray:
        lo_q, hi_q = (1.0 - level) / 2.0, (1.0 + level) / 2.0
        out = np.empty((self.particles.shape[1], 2))
        for j in range(self.particles.shape[1]):
            order = np.argsort(self.particles[:, j])
            cdf = np.cumsum(self.weights[order])
            x = self.particles[order, j]
            out[j] = [x[np.searchsorted(cdf, lo_q * cdf[-1])], x[min(np.searchsorted(cdf, hi_q * cdf[-1]), x.size - 1)]]
        return out

    def credible_level(self, point: np.ndarray) -> float:
        """The smallest highest-density credible level whose region contains ``point``.

        The posterior mass denser than ``point``: a value below 0.5 puts ``point`` inside the
        50 % HPD region.  Densities come from a weighted Gaussian KDE (Scott's bandwidth on the
        Kish ESS).  Each particle's density is computed from the *other* particles and ``point``,
        and ``point``'s from all particles, so the n + 1 points are ranked alike (a full-conformal
        rank): for a point drawn from the same posterior as n equally weighted particles the
        level is uniform on {0, 1/n, ..., 1}; with unequal weights it stays close (mean 0.51 at ESS
        0.9 n, 0.48 at ESS 0.7 n).  The plain in-sample estimate, each particle's
        density with its own kernel included, is biased high for the small final populations of
        ABC: with 10 exchangeable draws it puts the truth inside the 50 % region 22 % of the time
        instead of 5/11 (``tests/test_run.py`` checks both).

        Parameters
        ----------
        point : array_like, shape (d,)

        Returns
        -------
        float
            In [0, 1].
        """
        x = np.asarray(point, np.float64).reshape(-1)
        p = np.asarray(self.particles, np.float64)
        if x.shape != (p.shape[1],):
            raise ValueError(f"point has shape {x.shape}; this posterior has {p.shape[1]} parameters")
        if p.shape[0] < 3:
            raise ValueError(f"a credible level needs at least 3 particles, this posterior has {p.shape[0]}")
        w = np.asarray(self.weights, np.float64)
        w = w / w.sum()
        neff = 1.0 / np.sum(w**2)
        bandwidth = self.covariance() * neff ** (-2.0 / (p.shape[1] + 4))
        try:
            whiten = np.linalg.cholesky(np.linalg.inv(bandwidth))
        except np.linalg.LinAlgError:
            raise ValueError("the particles are degenerate (singular covariance): no density to rank by") from None
        z, zx = p @ whiten, x @ whiten
        sq = np.sum(z**2, axis=1)
        kernel = np.exp(-0.5 * np.maximum(sq[:, None] + sq[None, :] - 2.0 * z @ z.T, 0.0))
        np.fill_diagonal(kernel, 0.0)
        to_point = np.exp(-0.5 * np.sum((z - zx) ** 2, axis=1))
        # Each particle's density from the other particles and the point (weight 1/n), the
        # point's from all particles: the n + 1 points are scored alike (a full-conformal rank).
        w_point = 1.0 / p.shape[0]
        others = (kernel @ w + w_point * to_point) / (1.0 - w + w_point)
        return float(np.sum(w[others > np.sum(w * to_point)]))

    def resample(self, num: int, seed: int = 0) -> np.ndarray:
        """``num`` equally weighted draws from the weighted sample, shape (num, d)."""
        rng = np.random.default_rng(seed)
        return self.particles[rng.choice(self.particles.shape[0], size=num, p=self.weights)]

    def summary(self) -> str:
        """A few lines for a terminal: estimates with their Monte Carlo errors and intervals."""
        est, ci, err = self.bayes_estimate(), self.credible_interval(0.95), self.mcse()
        lines = [
            f"{self.algorithm}: {self.num_simulations} simulations "
            f"({self.num_failures} failed), {len(self.thresholds)} steps, "
            f"final threshold {self.thresholds[-1]:.4g}, ESS {self.effective_sample_size():.1f} "
            f"of {self.particles.shape[0]}, stopped: {self.stop_reason}, {self.wall_time:.1f} s",
        ]
        if self.diagnostics.get("warning"):
            lines.append(f"  warning: {self.diagnostics['warning']}")
        edge = self.diagnostics.get("prior_edge") or {}
        if edge.get("messages"):
            lines.append(f"  prior edge: {'; '.join(edge['messages'])}")
        if edge.get("at_physical_limits"):
            lines.append(f"  at a physical limit: {'; '.join(edge['at_physical_limits'])}")
        for message in self.discrepancy_identification()[1]:
            lines.append(f"  discrepancy: {message}")
        if "emulator_variance_scale" in self.diagnostics:
            d = self.diagnostics
            lines.append(
                f"  emulator variance: x{d['emulator_variance_scale']:.3g} ({d['emulator_variance']}); "
                f"held-out runs measure x{d['emulator_variance_scale_estimate']:.3g} "
                f"from {d['emulator_variance_scale_estimate_errors']} errors"
            )
        if not np.all(np.isfinite(err)):
            # Say why in words: "+- inf" alone reads like a bug.
            note = self.diagnostics.get("mcse_note") or "collapsed: fewer than 2 distinct particles; MCSE not available"
            if note not in self.diagnostics.get("warning", ""):
                lines.append(f"  {note}")
        for j, name in enumerate(self.names):
            unit = self.prior.units[j] if self.prior.units[j] else ""
            error = f"+- {err[j]:.2g} (MCSE)" if np.isfinite(err[j]) else "(MCSE not available)"
            lines.append(f"  {name:>12s} = {est[j]:.5g} {error} {unit}  95% CI [{ci[j, 0]:.5g}, {ci[j, 1]:.5g}]")
        if len(self.names) > 1:
            lines.append("  correlation:\n" + np.array2string(self.correlation(), precision=3))
        return "\n".join(lines)

    # -- files -------------------------------------------------------------------------------

    def to_metadata(self) -> dict:
        return {
            "format": RESULT_FORMAT,
            "algorithm": self.algorithm,
            "settings": self.settings,
            "prior": self.prior.to_dict(),
            "seed": self.seed,
            "num_simulations": self.num_simulations,
            "stop_reason": self.stop_reason,
            "wall_time": self.wall_time,
            "log_evidence": self.log_evidence,
            "bayes_estimate": self.bayes_estimate().tolist(),
            "correlation": self.correlation().tolist(),
            "reasons": list(self.records.get("reasons", [])),
            "metadata": self.metadata,
            "diagnostics": self.diagnostics,
        }

    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Write the result to ``path`` with ``.npz`` appended unless it ends in ``.npz``.

        An existing folder, or a path ending in a separator (``"runs/alpha/"``, created if
        missing), gets ``result.npz`` inside it, the name :func:`write_outputs` uses.  The file
        is written to a temporary file in the same folder and moved into place, so an
        interrupted save leaves either the old file or the complete new one.

        Parameters
        ----------
        path : str or Path
            ``"run_alpha0.1"`` writes ``run_alpha0.1.npz``; an existing folder ``"run1"``
            writes ``run1/result.npz``.
        overwrite : bool
            Replace an existing file; without it an existing file raises ``FileExistsError``.

        Returns
        -------
        Path
            The file written.
        """
        names_folder = str(path).endswith((os.sep, "/"))
        path = Path(path)
        if names_folder or path.is_dir():
            # Not a sibling "<folder>.npz" next to it: a folder is where the user wants it.
            path = path / "result.npz"
        elif path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
        if path.is_dir():
            raise IsADirectoryError(f"cannot save the result to {path}: it is a directory")
        if path.exists() and not overwrite:
            raise FileExistsError(f"{path} exists: pass overwrite=True to replace it, or choose another name")
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {
            "particles": self.particles,
            "weights": self.weights,
            "distances": self.distances,
            "thresholds": self.thresholds,
            "simulations_per_step": self.simulations_per_step,
            "acceptance_rates": self.acceptance_rates,
            "ess": self.ess,
        }
        for k, v in self.records.items():
            if k != "reasons":
                arrays[f"record_{k}"] = np.asarray(v)
        metadata = json.dumps(self.to_metadata(), default=_json_default)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as fh:
                np.savez_compressed(fh, metadata=metadata, **arrays)  # pyright: ignore[reportArgumentType]  # numpy stubs: **kwds may bind allow_pickle
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return path

    def to_arviz(self, num_draws: int | None = None, seed: int = 0) -> Any:
        """The posterior as an ArviZ ``InferenceData`` (:func:`jaxabc.results.views.to_arviz`)."""
        from jaxabc.results.views import to_arviz

        return to_arviz(self, num_draws=num_draws, seed=seed)

    def plot_posterior(
        self,
        path: str | Path | None = None,
        truth: np.ndarray | None = None,
        params: tuple[int, int] = (0, 1),
        ax: Any = None,
    ) -> Any:
        """Weighted KDE contours of two parameters (:func:`jaxabc.results.views.plot_posterior`)."""
        from jaxabc.results.views import plot_posterior

        return plot_posterior(self, path, truth=truth, params=params, ax=ax)


def _user_stacklevel() -> int:
    """The ``stacklevel`` that points a warning of :meth:`ABCResult.__post_init__` (or of a method
    it calls) at the first frame outside jaxabc: the user's ``run(...)``, not the assembly.

    The frames below that one are jaxabc's own and the dataclass's generated ``__init__`` (whose
    file name is ``"<string>"``), found as the frame that called ``__post_init__``.
    """
    package = str(Path(__file__).parents[1]) + os.sep  # jaxabc/, not jaxabc/results/
    frame = inspect.currentframe()
    frame = frame.f_back if frame is not None else None  # the frame that calls warnings.warn
    level = 1
    while frame is not None and frame.f_code.co_name != "__post_init__":
        frame, level = frame.f_back, level + 1
    if frame is None:
        return 2
    frame, level = frame.f_back, level + 1  # the generated __init__
    while frame is not None and frame.f_back is not None:
        frame, level = frame.f_back, level + 1
        if not frame.f_code.co_filename.startswith(package):
            break
    return level


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)


def load(path: str | Path) -> ABCResult:
    """Read a result written by :meth:`ABCResult.save`.

    Raises
    ------
    FileNotFoundError
        If there is no file at ``path``.
    ValueError
        If ``path`` is a directory, or not a readable jaxabc result file (corrupt, truncated,
        another program's ``.npz``); the message names the file and what is wrong.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no result file at {path}")
    if path.is_dir():
        raise ValueError(f"{path} is a directory, not a jaxabc result file (.npz)")
    try:
        data = np.load(path, allow_pickle=False)
        if not hasattr(data, "files"):
            raise ValueError(f"{path} is a single .npy array, not a jaxabc result file (.npz)")
        with data:
            return _from_npz(path, data)
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, KeyError) as exc:
        raise ValueError(
            f"{path} cannot be read as a jaxabc result file (corrupt or truncated .npz?): {type(exc).__name__}: {exc}"
        ) from None
    except ValueError as exc:
        if str(path) in str(exc):
            raise
        # np.load's own refusals: not an .npy/.npz, or pickled objects.
        raise ValueError(f"{path} is not a jaxabc result file: {exc}") from None


def _from_npz(path: Path, data: Any) -> ABCResult:
    if "metadata" not in data.files:
        raise ValueError(
            f"{path} is an .npz without jaxabc metadata (arrays: {', '.join(data.files[:8])}): not a jaxabc result file"
        )
    try:
        meta = json.loads(str(data["metadata"]))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: the result metadata is not valid JSON ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != RESULT_FORMAT:
        found = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise ValueError(f"{path} is not a jaxabc result file (format {found!r}, expected {RESULT_FORMAT!r})")
    missing = [k for k in _REQUIRED_ARRAYS if k not in data.files]
    missing += [k for k in ("num_simulations", "algorithm", "settings", "prior", "seed") if k not in meta]
    if missing:
        raise ValueError(f"{path} is an incomplete jaxabc result file: missing {', '.join(missing)}")
    from jaxabc.priors.independent import prior_from_dict

    records = {k[len("record_") :]: data[k] for k in data.files if k.startswith("record_")}
    _check_shapes(path, {k: data[k] for k in _REQUIRED_ARRAYS}, records)
    records["reasons"] = meta.get("reasons", [])
    return ABCResult(
        particles=data["particles"],
        weights=data["weights"],
        distances=data["distances"],
        thresholds=data["thresholds"],
        simulations_per_step=data["simulations_per_step"],
        acceptance_rates=data["acceptance_rates"],
        ess=data["ess"],
        num_simulations=int(meta["num_simulations"]),
        algorithm=meta["algorithm"],
        settings=meta["settings"],
        prior=prior_from_dict(meta["prior"]),
        seed=meta["seed"],
        stop_reason=meta.get("stop_reason", ""),
        wall_time=meta.get("wall_time", 0.0),
        log_evidence=meta.get("log_evidence"),
        records=records,
        metadata=meta.get("metadata", {}),
        diagnostics=meta.get("diagnostics") or {},
        check=False,
    )


def _check_shapes(path: Path, arrays: dict[str, np.ndarray], records: dict[str, np.ndarray]) -> None:
    """Refuse arrays of a result file that do not fit together, naming them and the file.

    A file edited by hand or by another program would otherwise load and fail later with
    NumPy's broadcasting error, which names neither.  The rules: particles (n, d); weights and
    distances (n,); the per-generation arrays one length (g,); the record arrays one length.
    """
    problems = []
    particles = arrays["particles"]
    if particles.ndim != 2:
        problems.append(f"particles has shape {particles.shape}, expected (n, d)")
    else:
        n = particles.shape[0]
        problems += [
            f"{k} has shape {arrays[k].shape}, expected ({n},) like the particles"
            for k in ("weights", "distances")
            if arrays[k].shape != (n,)
        ]
    per_generation = ("thresholds", "simulations_per_step", "acceptance_rates", "ess")
    g = arrays["thresholds"].shape
    problems += [
        f"{k} has shape {arrays[k].shape}, expected {g} like the thresholds"
        for k in per_generation
        if arrays[k].ndim != 1 or arrays[k].shape != g
    ]
    lengths = {k: v.shape[0] if v.ndim else None for k, v in records.items()}
    if len(set(lengths.values())) > 1:
        problems.append(
            "the record arrays have different lengths: "
            + ", ".join(f"record_{k} {None if n is None else n}" for k, n in sorted(lengths.items()))
        )
    if problems:
        raise ValueError(f"{path} is an inconsistent jaxabc result file: " + "; ".join(problems))


def write_outputs(result: ABCResult, folder: str | Path, truth: np.ndarray | None = None) -> None:
    """Write ``result.npz``, ``summary.txt`` and (two or more parameters) ``posterior.png`` in ``folder``.

    ``truth``, shape (d,), is marked on the figure when given.  The folder is created if needed.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    # The folder is the run's own (its checkpoint guards it): a resumed run replaces its result.
    result.save(folder / "result.npz", overwrite=True)
    if result.particles.shape[1] >= 2:
        result.plot_posterior(folder / "posterior.png", truth=None if truth is None else np.asarray(truth))
    (folder / "summary.txt").write_text(result.summary() + "\n")
