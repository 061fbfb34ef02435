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

    [executor]
    name = "vmap"             # serial | process_pool | mpi | mpi_static
    options = {}

    [output]
    folder = "runs/gaussian"

The output folder receives ``result.npz``, ``posterior.png``, ``summary.txt`` and the
checkpoint; ``--resume`` continues an interrupted run from that checkpoint.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["load_config", "main", "run_config"]

EXAMPLES: dict[str, str] = {
    "gaussian": "Gaussian mean with known variance (seconds): the analytic check",
    "helium": "the paper's helium Lennard-Jones calibration on the CPU preset (md.helium)",
}


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


def load_config(path: str | Path) -> dict:
    """Read and validate a TOML configuration; paths become absolute."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no configuration file at {path}")
    with open(path, "rb") as fh:
        cfg = tomllib.load(fh)
    for section in ("model", "prior", "observed", "algorithm"):
        if section not in cfg:
            raise ValueError(f"{path}: missing [{section}] section (see `jaxabc --help`)")
    model = cfg["model"]
    if ("simulator" in model) == ("factory" in model):
        raise ValueError(f"{path}: [model] needs exactly one of simulator= or factory=")
    obs = cfg["observed"]
    if "file" in obs:
        obs["file"] = str((path.parent / obs["file"]).resolve())
    elif "values" not in obs:
        raise ValueError(f"{path}: [observed] needs values= or file=")
    out = cfg.setdefault("output", {})
    out["folder"] = str((path.parent / out.get("folder", "jaxabc-run")).resolve())
    return cfg


def run_config(cfg: dict, resume: bool = False, progress: bool = True):
    """Run the calibration a configuration describes; write results into its folder."""
    import jaxabc

    model = cfg["model"]
    if "simulator" in model:
        simulate = _import(model["simulator"])
    else:
        simulate = _import(model["factory"])(**model.get("options", {}))
    p = cfg["prior"]
    prior = jaxabc.Uniform(p["low"], p["high"], names=p.get("names"), units=p.get("units"))
    obs_cfg = cfg["observed"]
    if "file" in obs_cfg:
        observed = np.load(obs_cfg["file"])
    else:
        observed = np.asarray(obs_cfg["values"], dtype=np.float64)
    a = dict(cfg["algorithm"])
    name = a.pop("name")
    options = a.pop("options", {})
    ex = cfg.get("executor", {})
    executor = jaxabc.executors.get_executor(ex.get("name", "vmap"), **ex.get("options", {}))
    folder = Path(cfg["output"]["folder"])
    result = jaxabc.run(name, simulate, prior, observed, executor=executor,
                        checkpoint_dir=folder, resume=resume, progress=progress,
                        metadata={"config": cfg}, **a, **options)
    executor.close()
    write_outputs(result, folder, truth=cfg.get("truth", {}).get("values"))
    return result


def write_outputs(result, folder: Path, truth=None) -> None:
    """Result file, posterior figure and a text summary in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    result.save(folder / "result.npz")
    if result.particles.shape[1] >= 2:
        result.plot_posterior(folder / "posterior.png",
                              truth=None if truth is None else np.asarray(truth))
    (folder / "summary.txt").write_text(result.summary() + "\n")


def _example(name: str, folder: Path, quick: bool) -> None:
    import jax.numpy as jnp

    import jaxabc
    from jaxabc import examples

    if name == "gaussian":
        prior = jaxabc.Uniform([-10.0, -10.0], [10.0, 10.0], names=("a", "b"))
        result = jaxabc.run("apmcabc", examples.correlated_simulate, prior, jnp.zeros(2),
                            num_particles=2000, num_steps=8, distance="euclidean", seed=0,
                            progress=True, checkpoint_dir=folder, overwrite=True)
        write_outputs(result, folder, truth=np.zeros(2))
        print(result.summary())
        eps = float(result.thresholds[-1])
        print(f"exact ABC posterior correlation at eps={eps:.3f}: "
              f"{examples.correlated_abc_correlation(eps):.3f}")
        return
    if name == "helium":
        try:
            from md import helium_calibration
        except ImportError as exc:
            raise SystemExit(f"the helium example needs the md package: {exc}") from None
        helium_calibration.main(["--output", str(folder), *(["--quick"] if quick else [])])
        return
    raise SystemExit(f"unknown example {name!r}: choose from {sorted(EXAMPLES)}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="jaxabc", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run a calibration described by a TOML file")
    p_run.add_argument("config")
    p_run.add_argument("--resume", action="store_true", help="continue from the checkpoint")
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
            result = run_config(load_config(args.config), resume=args.resume,
                                progress=not args.no_progress)
            print(result.summary())
        elif args.command == "example":
            _example(args.name, Path(args.output or f"runs/{args.name}"), args.quick)
        elif args.command == "show":
            import jaxabc

            print(jaxabc.load(args.result).summary())
    except (ValueError, FileNotFoundError, TypeError) as exc:
        print(f"jaxabc: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
