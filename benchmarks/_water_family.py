"""The held-out family of the water model choice: the runs meant to give the trusted verdict.

One run per seed with the calibrated emulator variance, a budget of 120 GROMACS runs per model and
``r_oo_max2_nm`` held out (the one summary no emulator of TIP3P could fit), seed 0 again without
the discrepancy term, and every seed again with the published-model discrepancy bounds.  Kept apart
from :mod:`benchmarks._water_repeats` so that the scripts reading only the earlier repeats
(``water_emulator_failures``) do not depend on it.
"""

from __future__ import annotations

#: The family's seeds: five, so that the verdict the results page stands on holds over >= 5 seeds.
FAMILY_SEEDS = (0, 1, 2, 3, 4)
#: The family's results, one per seed, and what each varies.
HOLDOUT_FAMILY = tuple(
    (f"water_model_choice_calibrated_holdout_seed{seed}", f"seed {seed}, held-out family") for seed in FAMILY_SEEDS
)
#: Seed 0 of the family without the discrepancy term, every other setting equal.
HOLDOUT_NO_DISCREPANCY = "water_model_choice_calibrated_holdout_no_discrepancy"
#: The family rerun with each discrepancy sd bounded by the largest misfit a published rigid model
#: makes in its group (:mod:`benchmarks._published_bounds`) as the run's prior, every other setting equal.
#: Its seeds: the family's first three, and a fourth, because two of the first three had an
#: emulator fail validation and the results page stands on this family only with two trusted seeds.
#: It is a sensitivity check of the family's verdict (a different prior), not a verdict of its own.
PUBLISHED_BOUNDS_SEEDS = (0, 1, 2, 3)
PUBLISHED_BOUNDS_FAMILY = tuple(
    (f"water_model_choice_published_bounds_seed{seed}", f"seed {seed}, published-model bounds")
    for seed in PUBLISHED_BOUNDS_SEEDS
)
#: Its trusted seed again with every sigma box doubled about its centre: the wider rows of its
#: sensitivity table, computed (epsilon keeps its box, as in ``water_model_choice_sigma_x2``).
PUBLISHED_BOUNDS_WIDER = ("water_model_choice_published_bounds_sigma_x2", 1)
