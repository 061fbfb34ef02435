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

BUILDERS = {
    "apmcabc": apmc.build,
    "abcsubsim": subsim.build,
    "pmcabc": pmc.build,
    "rejection": pmc.build_rejection,
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
