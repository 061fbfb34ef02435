"""Command line: ``jaxabc run config.toml``, ``jaxabc example NAME``, ``jaxabc show result.npz``.

A configuration file describes one calibration::

    [model]
    simulator = "jaxabc.examples:gaussian_simulate"   # module:function(key, theta)
    # or a factory returning the simulator, with keyword options:
    # factory = "md.helium:make_simulator"
    # options = { preset = "cpu" }

    [prior]
    names = ["mu"]
    low = [-10.0]
    high = [10.0]
    units = [""]

    [observed]
    values = [0.0]            # or: file = "observed.npy" (relative to the config file)

    [algorithm]
    name = "apmcabc"
    num_particles = 1000
    num_steps = 6
    distance = "euclidean"
    seed = 0
    options = { alpha = 0.1, acceptance_cutoff = 0.03 }

    [executor]                # optional: without it a JAX simulator runs as one compiled
    name = "vmap"             # program (jaxabc.run's default); vmap | serial | process_pool |
    options = {}              # mpi | mpi_static | dask

    [output]
    folder = "runs/gaussian"

The output folder receives ``result.npz``, ``posterior.png``, ``summary.txt`` and the
checkpoint; ``--resume`` continues an interrupted run from that checkpoint.  ``[model]`` may
also give ``simulator_id`` (the simulator's identity in the checkpoint; for a factory it is
``factory(options as JSON)`` by default).  An unknown table or key, or a value of the wrong
type, is refused with the nearest valid name.

Errors in the input (a missing file or key, malformed TOML, a file that is not a result, a run
that refuses or fails) end with one line ``jaxabc: error: ...`` on stderr and exit code 2.
Ctrl-C ends with one line ``jaxabc: interrupted; ...`` naming the command that resumes, and
exit code 130.
"""

from __future__ import annotations

import _thread
import argparse
import difflib
import hashlib
import importlib
import inspect
import json
import os
import pickle
import shlex
import sys
import threading
import time
import tomllib
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import numpy as np

__all__ = ["ConfigError", "load_config", "main", "run_config"]

EXAMPLES: dict[str, str] = {
    "gaussian": "Gaussian mean with known variance (seconds): the analytic check",
}

#: Entry-point group through which other packages add examples: ``name = "module:function"``,
#: called as ``function(folder, quick=..., resume=...)``.  The repository's ``md`` package
#: registers ``helium`` there (pyproject.toml), so that jaxabc never imports a simulator.
EXAMPLE_GROUP = "jaxabc.examples"


def registered_examples() -> dict[str, Any]:
    """Examples other packages registered under :data:`EXAMPLE_GROUP`: name -> entry point."""
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=EXAMPLE_GROUP) if ep.name not in EXAMPLES}


def example_names() -> dict[str, str]:
    """Every example the ``example`` command can run: name -> one-line description."""
    return {**EXAMPLES, **{name: f"registered by {ep.value}" for name, ep in registered_examples().items()}}


#: Keys every configuration must have, by table.
REQUIRED: dict[str, tuple[str, ...]] = {
    "model": (),
    "prior": ("low", "high"),
    "observed": (),
    "algorithm": ("name",),
}

#: Keyword arguments of :func:`jaxabc.run` that an ``[algorithm]`` table may set, with their
#: TOML type (see :data:`_KINDS`).  The other keys of the table are the algorithm's own options.
RUN_KEYS: dict[str, str] = {
    "num_particles": "int",
    "num_steps": "int",
    "distance": "str",
    "seed": "int",
    "final_threshold": "number",
    "max_simulations": "int",
    "max_wall_time": "number",
    "max_failure_fraction": "number",
    "stop_after_iterations": "int",
    "keep_summaries": "bool",
    "dtype": "str",
}

#: Every table a configuration may have and the keys each may hold, with the type of each value.
#: ``options`` tables are free-form (the factory's or the executor's keywords), except in
#: ``[algorithm]``, where they are checked against the algorithm's builder like the table itself.
SCHEMA: dict[str, dict[str, str]] = {
    "model": {"simulator": "str", "factory": "str", "options": "table", "simulator_id": "str"},
    "prior": {"names": "strs", "low": "numbers", "high": "numbers", "units": "strs"},
    "observed": {"values": "numbers", "file": "str"},
    "algorithm": {"name": "str", "options": "table", **RUN_KEYS},
    "executor": {"name": "str", "options": "table"},
    "output": {"folder": "str"},
    "truth": {"values": "numbers"},
}

#: What each type of :data:`SCHEMA` means, for the error message.
_KINDS: dict[str, str] = {
    "str": "a string",
    "int": "an integer",
    "number": "a number",
    "bool": "true or false",
    "table": "a table, e.g. options = {}",
    "numbers": "a list of numbers",
    "strs": "a list of strings",
}

#: A builder's annotation (``from __future__ import annotations`` keeps them as text) and the
#: TOML type it asks for; an option with another annotation is passed on unchecked.
_ANNOTATIONS: dict[str, str] = {
    "float": "number",
    "int": "int",
    "str": "str",
    "bool": "bool",
    "Sequence[float]": "numbers",
}

#: Builder parameters that a configuration does not set: the CLI passes them (prior, observed)
#: or the driver derives them (the bound adaptive distance).
_NOT_OPTIONS = frozenset({"prior", "observed", "adaptive_distance"})

#: Errors that mean "the input or the run is wrong", not "jaxabc has a bug": main reports them
#: in one line.  RuntimeError covers TooManyFailures and a process pool that cannot start;
#: OSError covers files that cannot be read or written.
_USER_ERRORS = (ValueError, TypeError, KeyError, FileNotFoundError, IsADirectoryError, RuntimeError, OSError)


class ConfigError(ValueError):
    """A configuration file that cannot be used; the message names the file and what to fix."""


def _import(target: str) -> Any:
    if ":" not in target:
        raise ValueError(f"expected 'module:attribute', got {target!r}")
    module, attr = target.split(":", 1)
    try:
        obj = importlib.import_module(module)
    except ImportError as exc:
        raise ValueError(f"cannot import {module!r} for {target!r}: {exc}") from None
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise ValueError(f"{module!r} has no attribute {attr!r}") from None
    return obj


def _existing_file(path: Path, what: str) -> Path:
    if not path.exists():
        raise FileNotFoundError(f"no {what} at {path}")
    if path.is_dir():
        raise IsADirectoryError(f"{path} is a directory: give the path of the {what} itself")
    return path


def load_config(path: str | Path) -> dict:
    """Read and validate a TOML configuration; paths become absolute.

    Every table and key must be in :data:`SCHEMA` (the keys of ``[algorithm]`` and of its
    ``options``: :data:`RUN_KEYS` and the named algorithm's builder options), with a value of
    the type it names.

    Raises
    ------
    FileNotFoundError, IsADirectoryError
        No file at ``path``.
    ConfigError
        Malformed TOML (with the line), a missing table or key (named), an unknown table or key
        (with the nearest valid name), or a value of the wrong type (``[table] key`` and the
        type expected).
    """
    path = _existing_file(Path(path), "configuration file")
    try:
        with open(path, "rb") as fh:
            cfg = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a text (UTF-8) TOML file: {exc}") from None
    _check_tables(cfg, path)
    for section, keys in REQUIRED.items():
        if section not in cfg:
            raise ConfigError(f"{path}: missing [{section}] table (see `jaxabc --help`)")
        if not isinstance(cfg[section], dict):
            raise ConfigError(f"{path}: {section} must be a table ([{section}]), got {cfg[section]!r}")
        for key in keys:
            if key not in cfg[section]:
                raise ConfigError(f"{path}: missing key {key!r} in the [{section}] table (see `jaxabc --help`)")
    for section in ("executor", "output", "truth"):
        if not isinstance(cfg.get(section, {}), dict):
            raise ConfigError(f"{path}: {section} must be a table ([{section}])")
    for section in ("model", "algorithm", "executor"):
        if not isinstance(cfg.get(section, {}).get("options", {}), dict):
            raise ConfigError(f"{path}: options in the [{section}] table must be a table, e.g. options = {{}}")
    for section, value in cfg.items():
        _check_keys(section, value, path)
    model = cfg["model"]
    if ("simulator" in model) == ("factory" in model):
        raise ConfigError(f"{path}: the [model] table needs exactly one of the keys 'simulator' or 'factory'")
    obs = cfg["observed"]
    if "file" in obs:
        obs["file"] = str((path.parent / obs["file"]).resolve())
    elif "values" not in obs:
        raise ConfigError(f"{path}: the [observed] table needs the key 'values' or 'file'")
    out = cfg.setdefault("output", {})
    out["folder"] = str((path.parent / out.get("folder", "jaxabc-run")).resolve())
    return cfg


def _nearest(name: str, valid: Any) -> str | None:
    """The valid name closest to a misspelt one, if any is close."""
    close = difflib.get_close_matches(name, [str(v) for v in valid], n=1)
    return close[0] if close else None


def _check_tables(cfg: dict, path: Path) -> None:
    """Refuse a table (or a top-level key) that is not in :data:`SCHEMA`, naming the nearest."""
    for name, value in cfg.items():
        if name in SCHEMA:
            continue
        if isinstance(value, dict):
            near = _nearest(name, SCHEMA)
            hint = f"did you mean [{near}]?" if near else "the tables are " + ", ".join(f"[{t}]" for t in SCHEMA)
            raise ConfigError(f"unknown table [{name}] in {path}; {hint}")
        # A key above the first table: say which table holds it, if one does.
        owner = next((t for t, keys in SCHEMA.items() if name in keys), None)
        near = _nearest(name, SCHEMA)
        hint = (
            f"did you mean {name!r} in the [{owner}] table?"
            if owner
            else f"did you mean the table [{near}]?"
            if near
            else "every key belongs in a table: " + ", ".join(f"[{t}]" for t in SCHEMA)
        )
        raise ConfigError(f"unknown top-level key {name!r} in {path}; {hint}")


def _algorithm_keys(name: Any) -> tuple[dict[str, str | None], bool]:
    """The keys an ``[algorithm]`` table may hold with their types (None: unchecked), and
    whether the builder also takes any other keyword (``**options``)."""
    from jaxabc.algorithms import BUILDERS

    keys: dict[str, str | None] = dict(SCHEMA["algorithm"])
    builder = BUILDERS.get(name) if isinstance(name, str) else None
    if builder is None:
        return keys, True  # an unknown algorithm: jaxabc.run names the valid ones
    free = False
    for param in inspect.signature(builder).parameters.values():
        if param.kind is inspect.Parameter.VAR_KEYWORD:
            free = True
        elif param.name not in _NOT_OPTIONS and param.name not in keys:
            text = str(param.annotation).removesuffix(" | None")
            keys[param.name] = _ANNOTATIONS.get(text)
    return keys, free


def _check_keys(section: str, table: dict, path: Path) -> None:
    """Refuse an unknown key of ``[section]`` (naming the nearest) or a value of the wrong type."""
    if section == "algorithm":
        known, free = _algorithm_keys(table.get("name"))
    else:
        known, free = dict[str, str | None](SCHEMA[section]), False
    items = [(key, key, value) for key, value in table.items()]  # (as written, bare key, value)
    options = table.get("options")
    if section == "algorithm" and isinstance(options, dict):
        # jaxabc.run takes an algorithm's options and the table's own keys alike.
        for key, value in options.items():
            if key in table:
                raise ConfigError(
                    f"{key!r} is given twice in the [algorithm] table of {path}: at the top and in options"
                )
            items.append((f"options.{key}", key, value))
    for label, key, value in items:
        nested = label != key
        if key not in known or (nested and key in ("name", "options")):
            if free:
                continue
            owner = next((t for t, keys in SCHEMA.items() if key in keys and t != section), None)
            near = _nearest(key, [k for k in known if not nested or k not in ("name", "options")])
            # Else a close key of another table (`unit` in [algorithm]: 'units' of [prior]).
            elsewhere = [(t, _nearest(key, keys)) for t, keys in SCHEMA.items() if t != section]
            other = next(((t, k) for t, k in elsewhere if k), None)
            hint = (
                f"it belongs in the [{owner}] table"
                if owner and not nested
                else f"did you mean {near!r}?"
                if near
                else f"did you mean {other[1]!r} in the [{other[0]}] table?"
                if other and not nested
                else "the keys are " + ", ".join(repr(k) for k in known)
            )
            raise ConfigError(f"unknown key {label!r} in the [{section}] table of {path}; {hint}")
        kind = known[key]
        if kind is not None and not _type_ok(kind, value):
            raise ConfigError(
                f"{path}: [{section}] {label} must be {_KINDS[kind]}, got {value!r} ({_toml_type(value)})"
            )


def _numeric(value: Any) -> bool:
    """A number, or a (nested) list of numbers: TOML booleans are not numbers here."""
    if isinstance(value, list):
        return all(_numeric(v) for v in value)
    return isinstance(value, int | float) and not isinstance(value, bool)


def _type_ok(kind: str, value: Any) -> bool:
    if kind == "str":
        return isinstance(value, str)
    if kind == "bool":
        return isinstance(value, bool)
    if kind == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "number":
        return isinstance(value, int | float) and not isinstance(value, bool)
    if kind == "table":
        return isinstance(value, dict)
    if kind == "strs":
        return isinstance(value, list) and all(isinstance(v, str) for v in value)
    if kind == "numbers":
        return _numeric(value)
    raise AssertionError(f"no type {kind!r} in _KINDS")


def _toml_type(value: Any) -> str:
    """The TOML name of a value's type, for an error message."""
    for kind, name in ((bool, "a boolean"), (str, "a string"), (int, "an integer"), (float, "a float")):
        if isinstance(value, kind):
            return name
    return "an array" if isinstance(value, list) else "a table" if isinstance(value, dict) else type(value).__name__


def simulator_id_of(model: dict, simulate: Any = None) -> str | None:
    """The simulator's identity in the checkpoint for a ``[model]`` table.

    Its own ``simulator_id`` when given; for a factory, the factory and its options as
    canonical JSON (``'md.helium:make_simulator({"preset":"cpu"})'``), so that a resume with
    other options is refused even when the closure it returns cannot be fingerprinted, followed
    by ``#`` and a digest of :func:`jaxabc.checkpoint.describe_callable` of ``simulate`` when
    that can be fingerprinted (so that an edit of the factory's code is seen too); None (the
    function's own identity) for ``simulator = "module:function"``.
    """
    if "simulator_id" in model:
        return model["simulator_id"]
    if "factory" not in model:
        return None
    options = json.dumps(model.get("options", {}), sort_keys=True, separators=(",", ":"), default=str)
    identity = f"{model['factory']}({options})"
    if simulate is not None:
        from jaxabc.checkpoint import describe_callable, unfingerprintable_parts

        description = describe_callable(simulate)
        if not unfingerprintable_parts(description):
            digest = hashlib.sha256(json.dumps(description, sort_keys=True).encode()).hexdigest()[:16]
            identity += f"#{digest}"
    return identity


def run_config(cfg: dict, resume: bool = False, progress: bool = True, overwrite: bool = False):
    """Run the calibration a configuration describes; write results into its folder."""
    import jaxabc
    from jaxabc.results import write_outputs

    model = cfg["model"]
    if "simulator" in model:
        simulate = _import(model["simulator"])
    else:
        simulate = _import(model["factory"])(**model.get("options", {}))
    p = cfg["prior"]
    prior = jaxabc.Uniform(p["low"], p["high"], names=p.get("names"), units=p.get("units"))
    obs_cfg = cfg["observed"]
    if "file" in obs_cfg:
        observed = np.load(_existing_file(Path(obs_cfg["file"]), "observed data file"))
    else:
        observed = np.asarray(obs_cfg["values"], dtype=np.float64)
    a = dict(cfg["algorithm"])
    name = a.pop("name")
    options = a.pop("options", {})
    ex = cfg.get("executor")
    # No [executor] section: jaxabc.run's default (the fused program for a JAX simulator).
    executor = None if ex is None else jaxabc.executors.get_executor(ex.get("name", "vmap"), **ex.get("options", {}))
    folder = Path(cfg["output"]["folder"])
    try:
        result = jaxabc.run(
            name,
            simulate,
            prior,
            observed,
            executor=executor,
            checkpoint_dir=folder,
            resume=resume,
            overwrite=overwrite,
            progress=progress,
            metadata={"config": cfg},
            simulator_id=simulator_id_of(model, simulate),
            **a,
            **options,
        )
    finally:
        if executor is not None:
            executor.close()
    write_outputs(result, folder, truth=cfg.get("truth", {}).get("values"))
    return result


def _load_result(path: str | Path):
    """:func:`jaxabc.load` with one clear error for a missing, corrupt or foreign file."""
    import jaxabc

    path = _existing_file(Path(path), "result file")
    try:
        return jaxabc.load(path)
    except (
        zipfile.BadZipFile,
        EOFError,
        pickle.UnpicklingError,
        UnicodeDecodeError,
        TypeError,
        AttributeError,
        OSError,
    ) as exc:
        # TypeError/AttributeError: np.load returned a plain array (an .npy), not an archive.
        raise ValueError(f"{path} is not a jaxabc result file: it is not a readable .npz archive ({exc})") from None
    except KeyError as exc:
        entry = str(exc.args[0]).split(" is not a file")[0] if exc.args else ""
        raise ValueError(f"{path} is not a jaxabc result file: it has no entry {entry!r}") from None
    except ValueError as exc:
        if "jaxabc" in str(exc):
            raise
        raise ValueError(f"{path} is not a jaxabc result file: {exc}") from None


def run_state(folder: Path) -> Literal["none", "finished", "interrupted", "unreadable"]:
    """What the checkpoint in ``folder`` holds: nothing, a run that ended (its stop reason is
    recorded), a run stopped before its end (resumable), or a file that cannot be resumed."""
    from jaxabc.checkpoint import CHECKPOINT_NAME, LEGACY_CHECKPOINT_NAME, CheckpointError, load

    path = folder / CHECKPOINT_NAME
    if not path.exists():
        return "unreadable" if (folder / LEGACY_CHECKPOINT_NAME).exists() else "none"
    try:
        return "finished" if load(path).counters.get("stop_reason") else "interrupted"
    except (CheckpointError, OSError):
        return "unreadable"


def _example_folder(folder: Path, resume: bool, overwrite: bool) -> None:
    """Refuse to start an example over an interrupted run of it unless told which to do.

    A finished run is the example's own output, so running the example again replaces it (with
    a note on stderr): the main job must work a second time without flags.

    Raises
    ------
    ValueError
        Both ``resume`` and ``overwrite``.
    jaxabc.checkpoint.CheckpointExists
        Neither, and ``folder`` holds an interrupted run or a checkpoint that cannot be read.
    """
    from jaxabc.checkpoint import CHECKPOINT_NAME, CheckpointExists

    if resume and overwrite:
        raise ValueError("--resume and --overwrite contradict each other: choose one")
    if resume or overwrite:
        return
    state = run_state(folder)
    if state == "interrupted":
        raise CheckpointExists(
            f"{folder / CHECKPOINT_NAME} holds an interrupted run of this example: continue it with "
            "--resume, or start over with --overwrite (which deletes it)"
        )
    if state == "unreadable":
        raise CheckpointExists(
            f"{folder} holds a checkpoint this jaxabc cannot resume (corrupt, or of an older version): "
            "start over with --overwrite (which deletes it), or pass --resume to see why"
        )
    if state == "finished":
        print(f"jaxabc: replacing the finished run in {folder} (--resume would reload it)", file=sys.stderr)


def _example(name: str, folder: Path, quick: bool, resume: bool = False, overwrite: bool = False) -> None:
    import jax.numpy as jnp

    import jaxabc
    from jaxabc import examples
    from jaxabc.results import write_outputs

    _example_folder(folder, resume, overwrite)
    if name == "gaussian":
        prior = jaxabc.Uniform([-10.0, -10.0], [10.0, 10.0], names=("a", "b"))
        result = jaxabc.run(
            "apmcabc",
            examples.correlated_simulate,
            prior,
            jnp.zeros(2),
            num_particles=2000,
            num_steps=8,
            distance="euclidean",
            seed=0,
            progress=True,
            checkpoint_dir=folder,
            # _example_folder has refused to replace an interrupted run without --overwrite.
            resume=resume,
            overwrite=not resume,
        )
        write_outputs(result, folder, truth=np.zeros(2))
        print(result.summary())
        eps = float(result.thresholds[-1])
        print(f"exact ABC posterior correlation at eps={eps:.3f}: {examples.correlated_abc_correlation(eps):.3f}")
        return
    registered = registered_examples()
    if name in registered:
        try:
            run_example = registered[name].load()
        except ImportError as exc:
            raise RuntimeError(f"example {name!r} ({registered[name].value}) cannot be imported: {exc}") from None
        # A registered example starts over unless resuming, which _example_folder has made safe.
        run_example(folder, quick=quick, resume=resume)
        return
    raise ValueError(f"unknown example {name!r}: choose from {sorted(example_names())}")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``jaxabc`` command; returns the exit code (2 for a user error)."""
    parser = argparse.ArgumentParser(
        prog="jaxabc", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run a calibration described by a TOML file")
    p_run.add_argument("config")
    p_run.add_argument("--resume", action="store_true", help="continue from the checkpoint")
    p_run.add_argument(
        "--overwrite", action="store_true", help="start over, replacing a checkpoint left in the output folder"
    )
    p_run.add_argument("--no-progress", action="store_true")
    names = example_names()
    p_ex = sub.add_parser(
        "example", help="run an example: " + "; ".join(f"{k} ({v})" for k, v in sorted(names.items()))
    )
    p_ex.add_argument("name", choices=sorted(names))
    p_ex.add_argument("--output", default=None, help="folder (default runs/NAME)")
    p_ex.add_argument("--quick", action="store_true", help="a smaller, faster variant")
    p_ex.add_argument("--resume", action="store_true", help="continue an interrupted run of the example")
    p_ex.add_argument(
        "--overwrite", action="store_true", help="start over, replacing an interrupted run in the output folder"
    )
    p_show = sub.add_parser("show", help="print the summary of a result file")
    p_show.add_argument("result")
    args = parser.parse_args(argv)
    started = time.time()
    folder: Path | None = None  # where this command checkpoints, once known
    previous_hook = sys.unraisablehook
    reraise = _ReraiseInterrupt(previous_hook)
    sys.unraisablehook = reraise
    try:
        if args.command == "run":
            cfg = load_config(args.config)
            folder = Path(cfg["output"]["folder"])
            result = run_config(cfg, resume=args.resume, progress=not args.no_progress, overwrite=args.overwrite)
            print(result.summary())
        elif args.command == "example":
            folder = Path(args.output or f"runs/{args.name}")
            _example(args.name, folder, args.quick, resume=args.resume, overwrite=args.overwrite)
        elif args.command == "show":
            print(_load_result(args.result).summary())
    except KeyboardInterrupt:
        # Ctrl-C is how a long run is paused, not a crash: say how to go on, in one line.
        print(f"jaxabc: interrupted{_how_to_go_on(args, folder, started)}", file=sys.stderr)
        if argv is None:
            # The command itself, not a call from Python: end the process now.  Python's teardown
            # after an interrupted XLA compilation can crash (SIGSEGV) or hang, and nothing is
            # left to do: the checkpoint is on disk (written atomically, fsynced).
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(130)
        return 130
    except _USER_ERRORS as exc:
        print(f"jaxabc: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    finally:
        reraise.close()
        sys.unraisablehook = previous_hook
    return 0


class _ReraiseInterrupt:
    """An unraisable-exception hook that raises a swallowed Ctrl-C again.

    A Ctrl-C that arrives while a garbage-collection callback runs (JAX registers one) is raised
    inside it, where Python only prints it ("Exception ignored in ...") and the run goes on.
    Interrupting the main thread again, from another thread a moment later (from here it would
    be raised inside this hook, and swallowed too), raises it where it can end the command.
    At most one interrupt is pending: every callback of a collection sees the same Ctrl-C, and
    each would otherwise add one, to land after the command has returned. One that lands in a
    callback again is swallowed again, and scheduled again. :meth:`close` cancels a pending one.
    """

    delay = 0.01  # seconds; long enough for the collection that swallowed the Ctrl-C to end

    def __init__(self, previous: Callable[[Any], object]) -> None:
        self.previous = previous
        self.timer: threading.Timer | None = None
        self.closed = False

    def __call__(self, unraisable: Any) -> None:
        if unraisable.exc_type is not None and issubclass(unraisable.exc_type, KeyboardInterrupt):
            if self.timer is None and not self.closed:
                self.timer = threading.Timer(self.delay, self._fire)
                self.timer.daemon = True
                self.timer.start()
        else:
            self.previous(unraisable)

    def _fire(self) -> None:
        self.timer = None
        if not self.closed:
            _thread.interrupt_main()

    def close(self) -> None:
        self.closed = True
        if self.timer is not None:
            self.timer.cancel()


def _how_to_go_on(args: argparse.Namespace, folder: Path | None, started: float) -> str:
    """The rest of the Ctrl-C line: the command that resumes, or the one that starts again.

    The checkpoint is this command's own unless it was asked to overwrite one and has not yet
    replaced it (the old file is older than the command).
    """
    if folder is None:
        return ""
    from jaxabc.checkpoint import CHECKPOINT_NAME

    if args.command == "run":
        words = ["jaxabc", "run", args.config, *(["--no-progress"] if args.no_progress else [])]
    else:
        output = ["--output", args.output] if args.output else []
        words = ["jaxabc", "example", args.name, *output, *(["--quick"] if args.quick else [])]
    path = folder / CHECKPOINT_NAME
    state = run_state(folder)
    own = state in ("interrupted", "finished") and path.stat().st_mtime >= started
    if state == "interrupted" and (own or not args.overwrite):
        return f"; the steps done are saved in {path}: continue with `{shlex.join([*words, '--resume'])}`"
    if state == "finished" and own:
        return f" after the run ended; `{shlex.join([*words, '--resume'])}` writes its outputs from {path}"
    again = [*words, *(["--resume"] if args.resume else []), *(["--overwrite"] if args.overwrite else [])]
    return f" before the first checkpoint: nothing to resume; start again with `{shlex.join(again)}`"


def _one_line(exc: BaseException) -> str:
    """The exception as one line: its message (a KeyError's key quoted), else its type."""
    if isinstance(exc, KeyError) and exc.args:
        text = f"missing key {exc.args[0]!r}"
    else:
        text = str(exc) or type(exc).__name__
    if isinstance(exc, OSError) and exc.filename is not None and str(exc.filename) not in text:
        text = f"{exc.filename}: {text}"
    return " ".join(text.split())


if __name__ == "__main__":
    sys.exit(main())
