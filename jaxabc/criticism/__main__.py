"""Command line: ``python -m jaxabc.criticism CONFIG.py [--out DIR] [--seed N]``.

``CONFIG.py`` is a Python file that defines a function ``setup()`` returning a dict with the
arguments of :func:`jaxabc.criticism.critique`: ``result`` (an ABCResult or the path of a saved
one), ``simulate_with_effects``, ``observed``, ``catalogue`` and optionally ``held_out``,
``summary_names``, ``groups`` and any other keyword.  The report goes to ``--out``
(default ``criticism_report/``).
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

from jaxabc.criticism.core import critique
from jaxabc.results import load


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m jaxabc.criticism", description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("config", help="Python file defining setup() -> dict of critique() arguments")
    parser.add_argument("--out", default="criticism_report", help="report directory")
    parser.add_argument("--seed", type=int, default=None, help="override the seed")
    args = parser.parse_args(argv)
    path = Path(args.config)
    if not path.exists():
        parser.error(f"no config file {path}")
    spec = importlib.util.spec_from_file_location("criticism_config", path)
    if spec is None or spec.loader is None:
        parser.error(f"{path} cannot be imported as a Python module: give a .py file")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    if not hasattr(module, "setup"):
        parser.error(f"{path} must define setup() returning the critique() arguments as a dict")
    kwargs = dict(module.setup())
    if isinstance(kwargs.get("result"), str | Path):
        kwargs["result"] = load(kwargs["result"])
    if args.seed is not None:
        kwargs["seed"] = args.seed
    report = critique(**kwargs)
    out = report.write(args.out)
    print(report.verdict)
    for m in report.misfits[:10]:
        print("  " + m.line)
    print(f"report: {out / 'report.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
