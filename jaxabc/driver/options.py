"""The options of a run, validated once, in one frozen object that every driver reads.

:func:`jaxabc.run`, :func:`jaxabc.run_fused`, :func:`jaxabc.model_choice.run_model_choice` and
surrogate model choice each build a :class:`RunOptions` from their keyword arguments
(:meth:`RunOptions.from_keywords`) and pass it on whole: stopping rules (:class:`Stopping`),
checkpointing (:class:`Checkpointing`) and execution (:class:`Execution`).  Constructing one
validates it, so a driver holding one never checks these values again.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax.numpy as jnp

from jaxabc import checkpoint
from jaxabc.algorithms.base import ABCAlgorithm
from jaxabc.driver.checks import validate_seed

__all__ = ["Checkpointing", "Execution", "RunOptions", "Stopping"]


@dataclass(frozen=True)
class Stopping:
    """When a run ends: at the first rule that holds.

    Attributes
    ----------
    num_steps : int, optional
        Generations (levels, steps), the initial prior sample included; at least 1.
    final_threshold : float, optional
        Stop once a generation's threshold is at or below this.
    max_simulations : int, optional
        Stop before an iteration that would take the simulations past this.
    max_wall_time : float, optional
        Seconds since the run (or its resume) started.
    stop_after : int, optional
        Stop, resumably, after this many iterations (generations in model choice).

    Raises
    ------
    ValueError
        ``num_steps`` below 1.
    """

    num_steps: int | None = None
    final_threshold: float | None = None
    max_simulations: int | None = None
    max_wall_time: float | None = None
    stop_after: int | None = None

    def __post_init__(self) -> None:
        if self.num_steps is not None and self.num_steps < 1:
            raise ValueError(f"num_steps must be at least 1, got {self.num_steps}")

    @property
    def has_rule(self) -> bool:
        """Whether one of ``num_steps``, ``final_threshold``, ``max_simulations`` and
        ``max_wall_time`` is given (``stop_after`` pauses a run, it does not end it)."""
        rules = (self.num_steps, self.final_threshold, self.max_simulations, self.max_wall_time)
        return any(rule is not None for rule in rules)

    def check_algorithm(self, algorithm: ABCAlgorithm) -> None:
        """Refuse an algorithm that may never stop by itself (``needs_stopping_rule``) when no
        rule is given (``ValueError``)."""
        if algorithm.needs_stopping_rule and not self.has_rule:
            raise ValueError(
                f"{algorithm.name} with these settings may never stop by itself: give num_steps, "
                "final_threshold, max_simulations or max_wall_time (it needs a stopping rule)"
            )

    def reopen(self, stop_reason: str, history: dict, path: Path) -> str:
        """The stop reason a resumed run starts with (:func:`jaxabc.checkpoint.reopen`)."""
        return checkpoint.reopen(
            stop_reason,
            history,
            num_steps=self.num_steps,
            final_threshold=self.final_threshold,
            max_simulations=self.max_simulations,
            max_wall_time=self.max_wall_time,
            path=path,
        )


@dataclass(frozen=True)
class Checkpointing:
    """Where a run writes its checkpoint, and what to do with one already there.

    Attributes
    ----------
    folder : path, optional
        ``checkpoint.npz`` is written there after every iteration; None: no checkpoint.
    resume : bool
        Continue from the checkpoint in ``folder``.
    overwrite : bool
        Delete the checkpoint in ``folder`` and start over.
    simulator_id : str, optional
        The simulator's identity in the checkpoint's fingerprint.

    The folder itself is checked by :meth:`prepare`, once every other input has been.
    """

    folder: str | Path | None = None
    resume: bool = False
    overwrite: bool = False
    simulator_id: str | None = None

    def require_fingerprintable(self, simulate: Callable, distance: Any) -> None:
        """Refuse, when checkpointing, a simulator or distance a resume could not recognise
        (:func:`jaxabc.checkpoint.require_fingerprintable`)."""
        if self.folder is not None:
            checkpoint.require_fingerprintable(simulate, self.simulator_id, distance)

    @contextlib.contextmanager
    def locked(self) -> Iterator[None]:
        """Hold the folder for this run (:class:`jaxabc.checkpoint.FolderLock`; nothing without one)."""
        lock = checkpoint.FolderLock.acquire(self.folder)
        try:
            yield
        finally:
            if lock is not None:
                lock.release()

    def prepare(self) -> Path | None:
        """The checkpoint's path (:func:`jaxabc.checkpoint.prepare_folder`); with ``overwrite``
        this deletes the old checkpoint, so call it with the folder locked and every input checked."""
        return checkpoint.prepare_folder(self.folder, self.resume, self.overwrite)


@dataclass(frozen=True)
class Execution:
    """How a run executes.

    Attributes
    ----------
    executor : str, Executor or None
        As :func:`jaxabc.run`'s ``executor`` (None: its default).
    max_failure_fraction : float
        In (0, 1]: the share of failed simulations (after the first 20) that stops the run.
    keep_summaries : bool
        Keep every simulation's summaries in the record.
    progress : bool
        Show a progress bar.
    dtype : {"float32", "float64"}
        Working precision.

    Raises
    ------
    ValueError
        Another ``dtype``, or ``max_failure_fraction`` outside (0, 1].
    """

    executor: Any = None
    max_failure_fraction: float = 0.5
    keep_summaries: bool = True
    progress: bool = False
    dtype: str = "float32"

    def __post_init__(self) -> None:
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"dtype must be 'float32' or 'float64', got {self.dtype!r}")
        if not 0.0 < self.max_failure_fraction <= 1.0:
            raise ValueError(f"max_failure_fraction must lie in (0, 1], got {self.max_failure_fraction}")

    @property
    def jdtype(self) -> Any:
        """The JAX dtype of ``dtype``."""
        return jnp.float64 if self.dtype == "float64" else jnp.float32


@dataclass(frozen=True)
class RunOptions:
    """Everything about a run that is not the problem itself.

    Attributes
    ----------
    seed : int
        The run's only source of randomness, ``0 <= seed < 2**32`` (a NumPy integer becomes
        a Python ``int``).
    stopping : Stopping
    checkpointing : Checkpointing
    execution : Execution
    metadata : dict, optional
        Stored in the result.

    Raises
    ------
    TypeError, ValueError
        A bad seed (:func:`jaxabc.driver.checks.validate_seed`), or a bad value of a group.
    """

    seed: int = 0
    stopping: Stopping = field(default_factory=Stopping)
    checkpointing: Checkpointing = field(default_factory=Checkpointing)
    execution: Execution = field(default_factory=Execution)
    metadata: dict | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "seed", validate_seed(self.seed))

    @classmethod
    def from_keywords(
        cls,
        *,
        seed: Any = 0,
        executor: Any = None,
        num_steps: int | None = None,
        final_threshold: float | None = None,
        max_simulations: int | None = None,
        max_wall_time: float | None = None,
        max_failure_fraction: float = 0.5,
        checkpoint_dir: str | Path | None = None,
        resume: bool = False,
        overwrite: bool = False,
        simulator_id: str | None = None,
        stop_after: int | None = None,
        keep_summaries: bool = True,
        progress: bool = False,
        dtype: str = "float32",
        metadata: dict | None = None,
    ) -> RunOptions:
        """The options from :func:`jaxabc.run`'s keyword arguments (``stop_after`` is its
        ``stop_after_iterations``)."""
        return cls(
            seed=seed,
            execution=Execution(executor, max_failure_fraction, keep_summaries, progress, dtype),
            stopping=Stopping(num_steps, final_threshold, max_simulations, max_wall_time, stop_after),
            checkpointing=Checkpointing(checkpoint_dir, resume, overwrite, simulator_id),
            metadata=metadata,
        )

    def keywords(self) -> dict[str, Any]:
        """:func:`jaxabc.run`'s keyword arguments for these options (inverse of :meth:`from_keywords`)."""
        s, c, e = self.stopping, self.checkpointing, self.execution
        return {
            "seed": self.seed,
            "executor": e.executor,
            "num_steps": s.num_steps,
            "final_threshold": s.final_threshold,
            "max_simulations": s.max_simulations,
            "max_wall_time": s.max_wall_time,
            "max_failure_fraction": e.max_failure_fraction,
            "checkpoint_dir": c.folder,
            "resume": c.resume,
            "overwrite": c.overwrite,
            "simulator_id": c.simulator_id,
            "stop_after_iterations": s.stop_after,
            "keep_summaries": e.keep_summaries,
            "progress": e.progress,
            "dtype": e.dtype,
            "metadata": self.metadata,
        }
