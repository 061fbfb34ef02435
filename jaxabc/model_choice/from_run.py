"""Model choice reached through :func:`jaxabc.run` with a list of models: the call checked and
handed, with its :class:`~jaxabc.driver.options.RunOptions`, to ABC-SMC (:mod:`.core`) or to
surrogate evidence (:mod:`.surrogate`, ``method="surrogate"``)."""

from __future__ import annotations

from typing import Any

from jaxabc.driver.options import RunOptions
from jaxabc.model_choice.core import as_models, choose_models
from jaxabc.model_choice.surrogate import choose_by_surrogate

__all__ = ["check_driver_arguments", "run_from_driver"]

#: The options of ``method="abc_smc"`` (see :func:`jaxabc.model_choice.run_model_choice`).
ABC_SMC_OPTIONS = ("quantile", "model_prior", "covariance_factor", "defensive_fraction")


def check_driver_arguments(models: Any, simulate: Any, prior: Any, observed: Any) -> Any:
    """The models of a model-choice call of :func:`jaxabc.run`, after refusing a call shaped
    like a calibration or one without data (``TypeError``)."""
    if type(models) not in (list, tuple):
        raise TypeError(
            "to choose between models pass the list of models first: jaxabc.run([(simulate_a, prior_a), "
            "(simulate_b, prior_b)], observed=...); ABC-SMC at a shared tolerance, or method='surrogate'"
        )
    if simulate is not None or prior is not None:
        raise TypeError(
            "model choice takes the models as the first argument and the data by keyword: "
            "jaxabc.run(models, observed=data, num_particles=..., ...)"
        )
    if observed is None:
        raise TypeError("model choice needs the data: jaxabc.run(models, observed=data, ...)")
    return models


def run_from_driver(
    models: Any,
    simulate: Any,
    prior: Any,
    observed: Any,
    num_particles: int | None,
    distance: Any,
    options: RunOptions,
    *,
    observation_error: Any = None,
    discrepancy: Any = None,
    method_options: dict[str, Any] | None = None,
) -> Any:
    """:func:`jaxabc.run` given a list of models: its arguments, run options and
    ``**algorithm_options`` (``method`` and the method's options).

    Returns a :class:`~jaxabc.model_choice.ModelChoiceResult`; typed ``Any`` because
    ``jaxabc.run`` is annotated to return an ``ABCResult`` for a calibration.

    Raises
    ------
    TypeError
        A call that is no model choice, options of another method, or (``"surrogate"``)
        options its evidence cannot use.
    ValueError
        An unknown ``method``.
    """
    models = check_driver_arguments(models, simulate, prior, observed)
    method_options = dict(method_options or {})
    method = method_options.pop("method", "abc_smc")
    measured = {"observation_error": observation_error, "discrepancy": discrepancy}
    if method == "surrogate":
        return _surrogate(models, observed, num_particles, distance, options, measured, method_options)
    if method != "abc_smc":
        raise ValueError(f"model choice method must be 'abc_smc' or 'surrogate', got {method!r}")
    unknown = sorted(set(method_options) - set(ABC_SMC_OPTIONS))
    if unknown:
        raise TypeError(f"unknown option(s) {unknown} for model choice: it accepts {list(ABC_SMC_OPTIONS)}")
    n = 1000 if num_particles is None else num_particles
    return choose_models(models, observed, n, distance, options, **measured, **method_options)


def _surrogate(
    models: Any,
    observed: Any,
    num_particles: int | None,
    distance: Any,
    options: RunOptions,
    measured: dict[str, Any],
    surrogate_options: dict[str, Any],
) -> Any:
    """``method="surrogate"``: ``max_simulations`` split evenly over the models."""
    stopping = options.stopping
    rules = {
        "num_steps": stopping.num_steps,
        "final_threshold": stopping.final_threshold,
        "max_wall_time": stopping.max_wall_time,
        "stop_after_iterations": stopping.stop_after,
    }
    unsupported = [name for name, value in rules.items() if value is not None]
    if distance != "mean_abs":
        unsupported.append("distance")
    if unsupported:
        raise TypeError(f"model choice with method='surrogate' does not take {unsupported}")
    if stopping.max_simulations is None:
        raise TypeError("method='surrogate' needs max_simulations (the total, split evenly over the models)")
    per_model = int(stopping.max_simulations) // max(len(as_models(models)), 1)
    n = 2000 if num_particles is None else num_particles
    model_prior = surrogate_options.pop("model_prior", None)
    return choose_by_surrogate(
        models,
        observed,
        per_model,
        n,
        options,
        model_prior=model_prior,
        **measured,
        surrogate_options=surrogate_options,
    )
