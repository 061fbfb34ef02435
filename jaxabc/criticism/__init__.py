"""Model criticism: what a calibrated simulator gets wrong, why, the extension, and its gain.

::

    from jaxabc.criticism import critique, Catalogue, Effect
    report = critique(result, simulate_with_effects, observed, catalogue, held_out=[...], seed=0)
    report.misfits      # flagged, ranked (name, standardised residual, p-value)
    report.causes       # ranked (effect name, score), with .ambiguous / .note
    report.cause_analysis.needed       # effects still needed after the stronger ones (joint test)
    report.cause_analysis.unexplained  # residual after them still significant: cause not catalogued
    report.extension    # ABCResult over base parameters + the top effect
    report.gain         # held-out measures with standard errors
    report.power        # per effect with an expected strength: power to name it there, with s.e.
    report.undetectable # causes these data could not have seen (not ruled out)
    report.design_advice  # with candidates=CandidateObservables(...): what to measure next
    report.write("report_dir/")

``simulate_with_effects(key, theta_full) -> summaries (s,)`` takes the base parameters followed
by one parameter per catalogue effect (catalogue order); at the effects' null values it is the
base simulator.  It is a single-theta function, so ``jax.vmap`` batches it.
"""

from jaxabc.criticism.causes import Catalogue, Cause, Effect
from jaxabc.criticism.core import critique, without_discrepancy
from jaxabc.criticism.misfit import Misfit, adjust_pvalues
from jaxabc.criticism.power import CandidateObservables
from jaxabc.criticism.report import CritiqueReport

__all__ = [
    "CandidateObservables",
    "Catalogue",
    "Cause",
    "CritiqueReport",
    "Effect",
    "Misfit",
    "adjust_pvalues",
    "critique",
    "without_discrepancy",
]
