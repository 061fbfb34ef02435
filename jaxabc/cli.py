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
checkpoint; ``--resume`` continues an interrupted run from that checkpoint.

Errors in the input (a missing file or key, malformed TOML, a file that is not a result, a run
that refuses or fails) end with one line ``jaxabc: error: ...`` on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import pickle
import sys
import tomllib
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["ConfigError", "load_config", "main", "run_config"]

EXAMPLES: dict[str, str] = {
    "gaussian": "Gaussian mean with known variance (seconds): the analytic check",
    "helium": "the paper's helium Lennard-Jones calibration on the CPU preset (md.helium)",
}

#: Keys every configuration must have, by table.
REQUIRED: dict[str, tuple[str, ...]] = {
    "model": (),
    "prior": ("low", "high"),
    "observed": (),
    "algorithm": ("name",),
}

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

    Raises
    ------
    FileNotFoundError, IsADirectoryError
        No file at ``path``.
    ConfigError
        Malformed TOML (with the line), a missing table or key (named), or a table of the wrong type.
    """
    path = _existing_file(Path(path), "configuration file")
    try:
        with open(path, "rb") as fh:
            cfg = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a text (UTF-8) TOML file: {exc}") from None
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


def _example(name: str, folder: Path, quick: bool) -> None:
    import jax.numpy as jnp

    import jaxabc
    from jaxabc import examples
    from jaxabc.results import write_outputs

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
            overwrite=True,
        )
        write_outputs(result, folder, truth=np.zeros(2))
        print(result.summary())
        eps = float(result.thresholds[-1])
        print(f"exact ABC posterior correlation at eps={eps:.3f}: {examples.correlated_abc_correlation(eps):.3f}")
        return
    if name == "helium":
        # Looked up at call time: jaxabc (inference) never imports md (simulators) at module level.
        try:
            helium_calibration = importlib.import_module("md.helium_calibration")
        except ImportError as exc:
            raise RuntimeError(f"the helium example needs the md package (run from the repository): {exc}") from None
        helium_calibration.main(["--output", str(folder), *(["--quick"] if quick else [])])
        return
    raise ValueError(f"unknown example {name!r}: choose from {sorted(EXAMPLES)}")


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
    p_ex = sub.add_parser("example", help="run a built-in example: " + ", ".join(EXAMPLES))
    p_ex.add_argument("name", choices=sorted(EXAMPLES))
    p_ex.add_argument("--output", default=None, help="folder (default runs/NAME)")
    p_ex.add_argument("--quick", action="store_true", help="a smaller, faster variant")
    p_show = sub.add_parser("show", help="print the summary of a result file")
    p_show.add_argument("result")
    args = parser.parse_args(argv)
    try:
        if args.command == "run":
            result = run_config(
                load_config(args.config), resume=args.resume, progress=not args.no_progress, overwrite=args.overwrite
            )
            print(result.summary())
        elif args.command == "example":
            _example(args.name, Path(args.output or f"runs/{args.name}"), args.quick)
        elif args.command == "show":
            print(_load_result(args.result).summary())
    except _USER_ERRORS as exc:
        print(f"jaxabc: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    return 0


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
