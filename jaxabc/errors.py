"""Exceptions and status codes shared by the inference core and its simulators.

A simulator signals a failed run (a crashed program, an exploded or vaporised system, a timeout)
by raising :class:`SimulationFailure` on the host side, or, inside JAX, by returning non-finite
summaries.  Executors turn either into data: a status code and a reason per particle.  The
particle then gets distance ``+inf`` and the run goes on.
"""

from __future__ import annotations

__all__ = [
    "STATUS_BAD_DISTANCE",
    "STATUS_FAILED",
    "STATUS_NAMES",
    "STATUS_NONFINITE",
    "STATUS_OK",
    "STATUS_TIMEOUT",
    "STATUS_WORKER_DIED",
    "NoPosterior",
    "PriorEdgeWarning",
    "SimulationFailure",
    "TooManyFailures",
    "caller_stacklevel",
]

STATUS_OK = 0
#: The simulator raised (any exception, :class:`SimulationFailure` included).
STATUS_FAILED = 1
#: The simulator returned NaN or infinite summaries.
STATUS_NONFINITE = 2
#: The simulator ran past the executor's time limit and was stopped.
STATUS_TIMEOUT = 3
#: The worker process running the simulation died (killed, segfault, out of memory).
STATUS_WORKER_DIED = 4
#: The simulation succeeded but its distance to the observed data was NaN (or ``-inf``).
STATUS_BAD_DISTANCE = 5

STATUS_NAMES = {
    STATUS_OK: "ok",
    STATUS_FAILED: "failed",
    STATUS_NONFINITE: "non-finite summaries",
    STATUS_TIMEOUT: "timeout",
    STATUS_WORKER_DIED: "worker died",
    STATUS_BAD_DISTANCE: "distance was NaN",
}


class SimulationFailure(RuntimeError):
    """Raised by a host-side simulator when a run produced no usable summaries.

    The message is recorded verbatim as the failure's reason, so say what happened and,
    where it helps, the measured value (``"density 10.2 kg/m3 < 500 kg/m3: the box vaporised"``).
    """


class TooManyFailures(RuntimeError):
    """Raised by the driver when the fraction of failed simulations exceeds its limit."""


class NoPosterior(RuntimeError):
    """Raised by the driver when a run ends before it has any accepted particle to return."""


class PriorEdgeWarning(UserWarning):
    """The posterior piles against a bound of the prior box.

    More than 5 % of the posterior mass lies within 2 % of the range from a bound
    (:func:`jaxabc.diagnostics.prior_edge_mass`): the data would move the parameter further, so
    the posterior, and any evidence, depend on where the box was cut.  Widen the box there, or
    say which physical limit stops it.
    """


def caller_stacklevel() -> int:
    """The ``stacklevel`` that points a warning at the first frame outside jaxabc."""
    import inspect
    from pathlib import Path

    package = str(Path(__file__).parent)
    level = 0  # this function's own frame is not counted by warnings.warn
    frame = inspect.currentframe()
    while frame is not None and frame.f_code.co_filename.startswith(package):
        frame = frame.f_back
        level += 1
    return level
