"""The held-out family of the water model choice: the runs meant to give the trusted verdict.

One run per seed with the calibrated emulator variance, a budget of 120 GROMACS runs per model
and ``r_oo_max2_nm`` held out (the one summary no emulator of TIP3P could fit), and seed 0 again
without the discrepancy term.  Kept apart from :mod:`benchmarks._water_repeats` so that the
scripts reading only the earlier repeats (``water_emulator_failures``) do not depend on it.
"""

from __future__ import annotations

#: The family's results, one per seed, and what each varies.
HOLDOUT_FAMILY = tuple(
    (f"water_model_choice_calibrated_holdout_seed{seed}", f"seed {seed}, held-out family") for seed in (0, 1, 2)
)
#: Seed 0 of the family without the discrepancy term, every other setting equal.
HOLDOUT_NO_DISCREPANCY = "water_model_choice_calibrated_holdout_no_discrepancy"
