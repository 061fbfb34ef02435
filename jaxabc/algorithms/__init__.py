"""ABC algorithms as pure ``init`` / ``propose`` / ``update`` functions (see :mod:`.base`)."""

from jaxabc.algorithms import apmc, pmc, subsim
from jaxabc.algorithms.base import (
    ABCAlgorithm,
    Info,
    Proposal,
    default_stop_reason,
    make_jax_step,
    no_extras,
)


def _surrogate(prior, num_particles: int = 2000, *, observed, max_simulations: int, **options):
    """:func:`jaxabc.surrogate.build`, imported on first use (tinygp and blackjax are extras)."""
    from jaxabc.surrogate import build

    return build(prior, num_particles, observed=observed, max_simulations=max_simulations, **options)


BUILDERS = {
    "apmcabc": apmc.build,
    "abcsubsim": subsim.build,
    "pmcabc": pmc.build,
    "rejection": pmc.build_rejection,
    "surrogate": _surrogate,
}

__all__ = [
    "BUILDERS",
    "ABCAlgorithm",
    "Info",
    "Proposal",
    "apmc",
    "default_stop_reason",
    "make_jax_step",
    "no_extras",
    "pmc",
    "subsim",
]
