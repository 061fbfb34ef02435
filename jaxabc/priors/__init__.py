"""Priors: the :class:`Uniform` box and :class:`Independent` numpyro marginals.

Both satisfy the :class:`Prior` protocol the algorithms need: a bounding box (``low``,
``high``), ``sample`` and ``log_prob``.
"""

from jaxabc.priors.independent import TAIL, Independent, prior_from_dict
from jaxabc.priors.uniform import Prior, Uniform

__all__ = ["TAIL", "Independent", "Prior", "Uniform", "prior_from_dict"]
