"""The water model choice's repeats: which saved results repeat the verdict, and how each was made.

Kept apart from the registry so that the scripts and pages that read the repeats depend on this
list only, not on every registry entry (an edit elsewhere in the registry changes no number here).
"""

from __future__ import annotations

from typing import Any

#: The registry's model-choice results that repeat the verdict, and what each varies (the
#: results page's repeats table, ``water_emulator_failures`` and ``water_box_sensitivity`` read
#: them in this order).
REPEATS = (
    ("water_model_choice", "seed 0"),
    ("water_model_choice_seed1", "seed 1"),
    ("water_model_choice_seed2", "seed 2"),
    ("water_model_choice_seed3", "seed 3"),
    ("water_model_choice_no_discrepancy", "seed 0, no discrepancy term"),
    ("water_model_choice_seed1_budget120", "seed 1, twice the budget"),
    ("water_model_choice_seed3_budget120", "seed 3, twice the budget"),
    ("water_model_choice_sigma_x2", "seed 0, every sigma box doubled"),
    ("water_model_choice_seed3_budget120_calibrated", "seed 3, twice the budget, calibrated emulator variance"),
)


def made_with_gp_variance(result: dict[str, Any]) -> bool:
    """Whether a saved model choice used the GP's own emulator variance (the default), not a
    calibrated or fixed factor on it (``--emulator-variance``)."""
    return (result.get("settings") or {}).get("emulator_variance", "gp") in (None, "gp")
