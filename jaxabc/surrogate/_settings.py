"""The surrogate's configuration: the builder's options checked once into
:class:`SurrogateSettings`, which every step of :mod:`.algorithm` takes explicitly, and their
JSON record (the algorithm's ``settings``, for result files and checkpoint fingerprints)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import numpy as np

from jaxabc.distances import get_distance
from jaxabc.surrogate import abc_mode, diagnostics, sampling

__all__ = [
    "EXPLORE_RADIUS",
    "MODES",
    "AbcSettings",
    "ParameterBox",
    "SurrogateSettings",
    "make_settings",
    "measured_data_from_settings",
    "measured_data_settings",
    "settings_record",
]

MODES = ("synthetic_likelihood", "abc")
ON_FAILURE = ("flag", "raise")
#: Exploration spreads a batch over a tenth of the box per parameter (unit-box widths).
EXPLORE_RADIUS = 0.1


class ParameterBox(NamedTuple):
    """The uniform box of the sampled parameters: theta's, then one ``[0, max_sd_g]`` per
    discrepancy group.  Unit-box coordinates map each interval to ``[0, 1]``.

    Attributes
    ----------
    low, high : array, shape (d,)
        Theta's box, in the prior's units.
    sampled_low, sampled_high : array, shape (d + G,)
        The box of a posterior draw (theta, then the ``G`` discrepancy sds, summary units).
    """

    low: np.ndarray
    high: np.ndarray
    sampled_low: np.ndarray
    sampled_high: np.ndarray

    @property
    def num_theta(self) -> int:
        """``d``, theta's length."""
        return self.low.size

    @property
    def num_sampled(self) -> int:
        """``d + G``, a posterior draw's length."""
        return self.sampled_low.size

    def theta_to_unit(self, theta: np.ndarray) -> np.ndarray:
        """Theta ``(..., d)`` in the prior's units to the unit box."""
        return (theta - self.low) / (self.high - self.low)

    def unit_to_theta(self, x: np.ndarray) -> np.ndarray:
        """Unit-box points ``(..., d)`` to theta in the prior's units."""
        return self.low + x * (self.high - self.low)

    def draws_to_unit(self, values: np.ndarray) -> np.ndarray:
        """Posterior draws ``(..., d + G)`` to the augmented unit box."""
        return (values - self.sampled_low) / (self.sampled_high - self.sampled_low)

    def unit_to_draws(self, x: np.ndarray) -> np.ndarray:
        """Augmented unit-box points ``(..., d + G)`` to posterior draws."""
        return self.sampled_low + x * (self.sampled_high - self.sampled_low)


class AbcSettings(NamedTuple):
    """``mode="abc"``: APMCABC on emulated summaries (:func:`.abc_mode.run_abc`)."""

    distance: Callable
    distance_name: str
    alpha: float
    acceptance_cutoff: float
    max_generations: int


class SurrogateSettings(NamedTuple):
    """Everything :func:`.algorithm.build` was told, checked, plus what follows from it.

    Attributes
    ----------
    box : ParameterBox
    observed : array
        The measured summaries, the simulator's output shape (float64, finite).
    observation_error : array, shape (k, k), or None
        Measurement covariance of the observed summaries, summary units.
    discrepancy : jaxabc.noise.ResolvedDiscrepancy or None
        Model discrepancy groups (``G`` of them), sampled with theta.
    theta_names, theta_units : tuple of str
        The prior's parameter names and units (for the augmented prior).
    max_simulations : int
        Real simulations in all (``M``), the length of the state's buffers.
    num_initial, num_replicates, batch_size, num_candidates : int
        Design: Sobol start, replicate runs, runs per acquisition batch, candidate points.
    tolerance : float
        Design stops once the posterior mean emulator-to-noise variance ratio is below this.
    min_successes : int
        Successful runs below which no emulator is fitted and batches explore instead.
    max_outputs : int
        Emulated outputs at most (more summaries are projected on principal components).
    min_feasibility : float
        The posterior's cut on the fitted chance that a run succeeds.
    log_min_feasibility : jax.Array, shape ()
        Its log as the likelihood model carries it (``-inf``: never cut).
    num_particles, num_chains, num_warmup, thin : int
        Posterior draws; NUTS chains, warm-up steps and thinning.
    mode : {"synthetic_likelihood", "abc"}
    abc : AbcSettings or None
        The APMCABC options in ABC mode, None otherwise.
    num_holdout : int
        Held-out simulations per validation.
    max_emulator_ratio : float
        Validation fails while the emulator-to-noise variance ratio is above this.
    on_failure : {"flag", "raise"}
    noise_model : {"auto", "homoscedastic", "heteroscedastic"}
        The simulator noise's dependence on theta (:func:`._fit.noise_profile_choice`).
    emulator_variance : "gp", "calibrated" or float
        The factor on the GP's predictive variance: none, estimated from failed validations'
        held-out runs (:func:`.emulator.variance_scale_mle`), or fixed (at least 1).
    """

    box: ParameterBox
    observed: np.ndarray
    observation_error: np.ndarray | None
    discrepancy: Any
    theta_names: tuple[str, ...]
    theta_units: tuple[str, ...]
    max_simulations: int
    num_initial: int
    num_replicates: int
    batch_size: int
    num_candidates: int
    tolerance: float
    min_successes: int
    max_outputs: int
    min_feasibility: float
    log_min_feasibility: jax.Array
    num_particles: int
    num_chains: int
    num_warmup: int
    thin: int
    mode: str
    abc: AbcSettings | None
    num_holdout: int
    max_emulator_ratio: float
    on_failure: str
    noise_model: str = "auto"
    emulator_variance: str | float = "gp"

    @property
    def num_summaries(self) -> int:
        """``k``, the observed summaries' size."""
        return self.observed.size

    @property
    def num_outputs(self) -> int:
        """``q``, the emulated outputs (summaries or their leading principal components)."""
        return min(self.num_summaries, self.max_outputs)

    @property
    def pending_rows(self) -> int:
        """``B``, rows of the state's pending batch: the largest batch ever proposed."""
        return max(self.num_initial + self.num_replicates, self.batch_size, self.num_holdout)


def observation_covariance(error: Any, shape: tuple[int, ...]) -> np.ndarray | None:
    """``observation_error`` as the (k, k) covariance of :func:`jaxabc.noise.observation_covariance`."""
    if error is None:
        return None
    from jaxabc.noise import observation_covariance as covariance

    try:
        return covariance(error, tuple(shape))
    except ValueError as exc:
        raise ValueError(f"surrogate: {exc}") from None


def resolve_discrepancy(discrepancy: Any, shape: tuple[int, ...]) -> Any:
    """``discrepancy`` as a :class:`jaxabc.noise.ResolvedDiscrepancy` checked against summaries
    of ``shape``; ``ValueError`` naming the expected shapes otherwise."""
    if discrepancy is None:
        return None
    from jaxabc.noise import Discrepancy, ResolvedDiscrepancy

    k = int(np.prod(shape)) if len(shape) else 1
    if isinstance(discrepancy, Discrepancy):
        try:
            return discrepancy.resolve(tuple(shape))
        except ValueError as exc:
            raise ValueError(f"surrogate: {exc}") from None
    if not isinstance(discrepancy, ResolvedDiscrepancy):
        raise TypeError(
            f"discrepancy must be a jaxabc.noise.Discrepancy or ResolvedDiscrepancy, got {type(discrepancy).__name__}"
        )
    member = np.asarray(discrepancy.membership, np.float64)
    max_sd = np.asarray(discrepancy.max_sd, np.float64)
    if member.ndim != 2 or member.shape[1] != k:
        raise ValueError(
            f"surrogate: discrepancy membership has shape {member.shape}, but the observed data have {k} "
            f"summaries: it must be (G, {k}) (resolve the Discrepancy against the observed summaries)"
        )
    g = member.shape[0]
    if g == 0:
        raise ValueError("surrogate: discrepancy has no groups")
    if max_sd.shape != (g,) or len(discrepancy.names) != g:
        raise ValueError(
            f"surrogate: discrepancy has {g} groups but max_sd of shape {max_sd.shape} and "
            f"{len(discrepancy.names)} names: give one of each per group"
        )
    if not np.all(np.isfinite(max_sd)) or np.any(max_sd <= 0):
        raise ValueError(f"surrogate: discrepancy max_sd must be positive and finite, got {max_sd.tolist()}")
    if not np.all((member == 0) | (member == 1)) or np.any(member.sum(axis=0) > 1):
        raise ValueError("surrogate: discrepancy membership must be 0/1 with every summary in at most one group")
    return ResolvedDiscrepancy(member, max_sd, tuple(str(n) for n in discrepancy.names))


def parameter_box(prior: Any, discrepancy: Any) -> ParameterBox:
    """The box of theta (the prior's) and of the discrepancy sds (``[0, max_sd_g]``)."""
    low = np.asarray(prior.low, np.float64)
    high = np.asarray(prior.high, np.float64)
    num_groups = 0 if discrepancy is None else len(discrepancy.max_sd)
    sampled_high = np.zeros(0) if discrepancy is None else discrepancy.max_sd
    return ParameterBox(low, high, np.concatenate([low, np.zeros(num_groups)]), np.concatenate([high, sampled_high]))


def abc_settings(
    mode: str, num_particles: int, distance: Any, alpha: float, cutoff: float, generations: int
) -> AbcSettings | None:
    """The ABC-mode options (None in synthetic-likelihood mode), checked."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if mode != "abc":
        return None
    abc_mode.population_size(num_particles, alpha)  # refuses an alpha that cannot keep P
    distance_fn = get_distance(distance)
    if generations < 2:
        raise ValueError(f"abc_max_generations must be at least 2, got {generations}")
    name = distance if isinstance(distance, str) else getattr(distance, "__name__", "custom")
    return AbcSettings(distance_fn, name, float(alpha), float(cutoff), int(generations))


def check_sample_size(num_particles: int, num_chains: int, abc: bool) -> None:
    """Refuse fewer than 1000 posterior draws, or NUTS draws the chains cannot share (ValueError)."""
    if num_particles < 1000 or (not abc and num_particles % num_chains):
        raise ValueError(
            f"num_particles must be >= 1000 and a multiple of num_chains={num_chains}, got {num_particles}"
        )


def check_budget(
    on_failure: str, max_simulations: int, num_initial: int, num_replicates: int, batch_size: int, num_holdout: int
) -> None:
    """Refuse an unknown ``on_failure``, and batch sizes or a budget that leave no room for a
    validation (ValueError)."""
    if on_failure not in ON_FAILURE:
        raise ValueError(f"on_failure must be 'flag' or 'raise', got {on_failure!r}")
    if num_replicates < 0 or batch_size < 1 or num_holdout < diagnostics.MIN_HOLDOUT_RUNS:
        raise ValueError(f"need num_replicates >= 0, batch_size >= 1 and num_holdout >= {diagnostics.MIN_HOLDOUT_RUNS}")
    first = num_initial + num_replicates
    if first + num_holdout > max_simulations:
        raise ValueError(
            f"max_simulations={max_simulations} leaves no room for validation: the start uses "
            f"{first} runs and each validation {num_holdout}; raise max_simulations or lower "
            "num_initial / num_replicates / num_holdout"
        )


def design_defaults(
    max_simulations: int,
    d: int,
    num_initial: int | None,
    num_replicates: int | None,
    batch_size: int | None,
    num_holdout: int | None,
) -> tuple[int, int, int, int]:
    """``(num_initial, num_replicates, batch_size, num_holdout)``, each given value kept and each
    ``None`` sized to the budget ``B = max_simulations`` in ``d`` parameters.

    From ``B`` about 134 up (``B >= 80 d`` for the start) the defaults are fixed: a Sobol start of
    ``max(20, 10 d)``, 8 replicates, batches of 10, 20 held out.  A smaller budget would spend itself
    on them and leave no acquisition round (at ``B = 50``, ``d = 2``: 20 + 8 + 20 = 48 runs), so the
    start takes at most a quarter of ``B`` (not below ``4 d + 4``), replicates ``B / 12`` (4 to 8),
    batches ``B / 10`` (5 to 10) and held-out runs 15 % of ``B`` (8 to 20).
    """
    b = int(max_simulations)
    if num_initial is None:
        num_initial = min(max(20, 10 * d), max(4 * d + 4, b // 4))
    if num_replicates is None:
        num_replicates = min(8, max(4, b // 12))
    if batch_size is None:
        batch_size = min(10, max(5, b // 10))
    if num_holdout is None:
        num_holdout = min(20, max(8, round(0.15 * b)))
    return int(num_initial), int(num_replicates), int(batch_size), int(num_holdout)


def make_settings(
    prior: Any,
    num_particles: int,
    *,
    observed: Any,
    max_simulations: int,
    num_initial: int | None,
    num_replicates: int | None,
    batch_size: int | None,
    num_holdout: int | None,
    tolerance: float,
    max_outputs: int,
    num_candidates: int,
    num_chains: int,
    num_warmup: int,
    thin: int,
    max_emulator_ratio: float,
    min_feasibility: float,
    on_failure: str,
    mode: str,
    abc_distance: Any,
    abc_alpha: float,
    abc_acceptance_cutoff: float,
    abc_max_generations: int,
    observation_error: Any,
    discrepancy: Any,
    noise_model: str = "auto",
    emulator_variance: Any = "gp",
) -> SurrogateSettings:
    """:func:`.algorithm.build`'s options, checked, as :class:`SurrogateSettings`.

    Raises
    ------
    ValueError
        Non-finite observed summaries, an unknown ``mode``, ``on_failure``, ``noise_model`` or
        ``emulator_variance``, sample sizes or a budget the run cannot work with, a measurement
        error or discrepancy that does not fit the observed summaries.
    """
    obs = np.asarray(observed, np.float64)
    if not np.all(np.isfinite(obs)):
        raise ValueError("observed summaries must be finite")
    if noise_model not in ("auto", "homoscedastic", "heteroscedastic"):
        raise ValueError(
            f"surrogate: noise_model must be 'auto', 'homoscedastic' or 'heteroscedastic', got {noise_model!r}"
        )
    emulator_variance = check_emulator_variance(emulator_variance)
    obs_error = observation_covariance(observation_error, obs.shape)
    disc = resolve_discrepancy(discrepancy, obs.shape)
    box = parameter_box(prior, disc)
    d = box.num_theta
    num_initial, num_replicates, batch_size, num_holdout = design_defaults(
        max_simulations, d, num_initial, num_replicates, batch_size, num_holdout
    )
    abc = abc_settings(mode, num_particles, abc_distance, abc_alpha, abc_acceptance_cutoff, abc_max_generations)
    check_sample_size(num_particles, num_chains, abc is not None)
    log_min_feasibility = sampling.log_level(min_feasibility)
    check_budget(on_failure, max_simulations, num_initial, num_replicates, batch_size, num_holdout)
    return SurrogateSettings(
        box=box,
        observed=obs,
        observation_error=obs_error,
        discrepancy=disc,
        theta_names=tuple(getattr(prior, "names", None) or (f"theta{i}" for i in range(d))),
        theta_units=tuple(getattr(prior, "units", None) or ("",) * d),
        max_simulations=int(max_simulations),
        num_initial=num_initial,
        num_replicates=int(num_replicates),
        batch_size=int(batch_size),
        num_candidates=int(num_candidates),
        tolerance=float(tolerance),
        min_successes=max(3, d + 1),
        max_outputs=int(max_outputs),
        min_feasibility=float(min_feasibility),
        log_min_feasibility=log_min_feasibility,
        num_particles=int(num_particles),
        num_chains=int(num_chains),
        num_warmup=int(num_warmup),
        thin=int(thin),
        mode=mode,
        abc=abc,
        num_holdout=int(num_holdout),
        max_emulator_ratio=float(max_emulator_ratio),
        on_failure=on_failure,
        noise_model=noise_model,
        emulator_variance=emulator_variance,
    )


EMULATOR_VARIANCE = ("gp", "calibrated")


def check_emulator_variance(value: Any) -> str | float:
    """``emulator_variance`` checked: ``"gp"``, ``"calibrated"`` or a finite factor >= 1 (a
    float); ValueError otherwise (a factor below 1 would shrink the GP's error bars)."""
    if isinstance(value, str):
        if value not in EMULATOR_VARIANCE:
            raise ValueError(f"surrogate: emulator_variance must be 'gp', 'calibrated' or a factor >= 1, got {value!r}")
        return value
    try:
        factor = float(value)
    except (TypeError, ValueError):
        raise ValueError(
            f"surrogate: emulator_variance must be 'gp', 'calibrated' or a factor >= 1, got {value!r}"
        ) from None
    if not np.isfinite(factor) or factor < 1.0:
        raise ValueError(
            f"surrogate: an emulator_variance factor must be finite and at least 1 (it widens the GP's "
            f"error bars, never narrows them), got {factor}"
        )
    return factor


def settings_record(settings: SurrogateSettings) -> dict:
    """The JSON record of ``settings``: the algorithm's ``settings``, which result files store
    and checkpoint fingerprints hash.  Measured data, the augmented prior and the ABC options
    appear only when used, so that runs without them keep their fingerprints."""
    record = {
        "num_particles": settings.num_particles,
        "max_simulations": settings.max_simulations,
        "num_initial": settings.num_initial,
        "num_replicates": settings.num_replicates,
        "batch_size": settings.batch_size,
        "num_holdout": settings.num_holdout,
        "tolerance": settings.tolerance,
        "max_outputs": settings.max_outputs,
        "num_candidates": settings.num_candidates,
        "num_chains": settings.num_chains,
        "num_warmup": settings.num_warmup,
        "thin": settings.thin,
        "on_failure": settings.on_failure,
        "observed_size": settings.num_summaries,
        "max_emulator_ratio": settings.max_emulator_ratio,
        "min_feasibility": settings.min_feasibility,
        "noise_model": settings.noise_model,
    }
    if settings.emulator_variance != "gp":
        # Only when used, so that runs without it keep their checkpoint fingerprints.
        record["emulator_variance"] = settings.emulator_variance
    record |= measured_data_settings(settings.observation_error, settings.discrepancy)
    if settings.discrepancy is not None:
        record["augmented_prior"] = augmented_prior_record(settings)
    if settings.abc is not None:
        record |= {
            "mode": settings.mode,
            "abc_distance": settings.abc.distance_name,
            "abc_alpha": settings.abc.alpha,
            "abc_acceptance_cutoff": settings.abc.acceptance_cutoff,
            "abc_max_generations": settings.abc.max_generations,
        }
    return record


def augmented_prior_record(settings: SurrogateSettings) -> dict:
    """The :class:`jaxabc.Uniform` (as its ``to_dict``) of a posterior draw with a discrepancy:
    theta's box, then ``[0, max_sd_g]`` per group named ``discrepancy.names``."""
    box, names = settings.box, settings.discrepancy.names
    d, num_groups = box.num_theta, len(names)
    return {
        "type": "Uniform",
        "low": box.sampled_low.tolist(),
        "high": box.sampled_high.tolist(),
        "names": [*settings.theta_names, *names],
        "units": [*settings.theta_units, *("summary units",) * num_groups],
        # A standard deviation cannot be negative: 0 is a physical limit, max_sd a choice.
        "limits": [*([False, False] for _ in range(d)), *([True, False] for _ in range(num_groups))],
    }


def measured_data_settings(observation_error: np.ndarray | None, discrepancy: Any) -> dict:
    """The settings entries (JSON) that describe them; empty when neither is given, so that runs
    without them keep their checkpoint fingerprints."""
    out: dict = {}
    if observation_error is not None:
        out["observation_error"] = np.asarray(observation_error, np.float64).tolist()
    if discrepancy is not None:
        out["discrepancy"] = {
            "membership": np.asarray(discrepancy.membership, np.float64).tolist(),
            "max_sd": np.asarray(discrepancy.max_sd, np.float64).tolist(),
            "names": list(discrepancy.names),
        }
    return out


def measured_data_from_settings(settings: dict) -> tuple[np.ndarray | None, Any]:
    """Inverse of :func:`measured_data_settings`: ``(observation_error, ResolvedDiscrepancy)``."""
    from jaxabc.noise import ResolvedDiscrepancy

    error = settings.get("observation_error")
    disc = settings.get("discrepancy")
    resolved = None
    if disc is not None:
        resolved = ResolvedDiscrepancy(
            np.asarray(disc["membership"], np.float64), np.asarray(disc["max_sd"], np.float64), tuple(disc["names"])
        )
    return (None if error is None else np.asarray(error, np.float64)), resolved
