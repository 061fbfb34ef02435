"""ABC model choice: which of several simulators explains the observed data, and how surely.

- :mod:`.core`: :func:`run_model_choice` (ABC-SMC at a shared tolerance with per-model
  importance-sampling evidence), :class:`Model`, :func:`with_boxes`;
- :mod:`.smc`: one generation's proposals, weights and threshold;
- :mod:`.surrogate`: the same question answered by the surrogate's evidence;
- :mod:`.result`: :class:`ModelChoiceResult`, its verdict and evidence sensitivity;
- :mod:`.checkpoint`: exact resume;
- :mod:`.from_run`: model choice reached through :func:`jaxabc.run`.
"""

from jaxabc.model_choice.core import ALGORITHM_NAME, Model, as_models, run_model_choice, with_boxes
from jaxabc.model_choice.from_run import check_driver_arguments, run_from_driver
from jaxabc.model_choice.result import (
    INTERVAL_Z,
    STATUS_NEEDS_SIMULATIONS,
    STATUS_REUSED,
    ModelChoiceResult,
    SensitivityRow,
    Verdict,
    interval_leader,
    load_model_choice,
    probabilities_with_errors,
    probability_bounds,
)

__all__ = [
    "ALGORITHM_NAME",
    "INTERVAL_Z",
    "STATUS_NEEDS_SIMULATIONS",
    "STATUS_REUSED",
    "Model",
    "ModelChoiceResult",
    "SensitivityRow",
    "Verdict",
    "as_models",
    "check_driver_arguments",
    "interval_leader",
    "load_model_choice",
    "probabilities_with_errors",
    "probability_bounds",
    "run_from_driver",
    "run_model_choice",
    "with_boxes",
]
