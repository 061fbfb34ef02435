"""A calibration's result: the weighted posterior, its history and provenance, saved and loaded.

:class:`ABCResult` is what :func:`jaxabc.run` returns; :func:`load` reads one back from its
``.npz``; :mod:`.views` converts it for ArviZ and plots it.
"""

from jaxabc.results.result import RESULT_FORMAT, ABCResult, load, versions, write_outputs

__all__ = ["RESULT_FORMAT", "ABCResult", "load", "versions", "write_outputs"]
