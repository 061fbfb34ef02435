"""Where the water model choice's saved result is, for the scripts that start from it.

``water_model_choice.py`` names its folders by variant (data, preset, prior width, discrepancy,
seed); its JSON records the folder it saved (``saved_result``).  The criticism and the paper-preset
check read that record, so they follow whatever the registry's model choice last wrote instead of
a folder name of their own.  :func:`physical_marginal` gives them the posterior they start from.
"""

from __future__ import annotations

import json
from pathlib import Path

import jaxabc
from benchmarks._common import RESULTS, resolve_recorded
from jaxabc.criticism import without_discrepancy


def model_choice_folder(data: str, tiny: bool = False, result: str = "water_model_choice") -> Path:
    """The saved model-choice folder (holding ``model_choice.json``) for ``data``.

    ``tiny``: the smoke test's, ``runs/cache/water_model_choice/<data>_quick_tiny/result``.
    Otherwise the ``saved_result`` of ``benchmarks/results/<result>.json`` (the registry's model
    choice, or one of its repeats such as ``water_model_choice_no_discrepancy``).

    Raises
    ------
    FileNotFoundError
        When the full model choice is not saved, or was made on other data.
    """
    if tiny:
        return resolve_recorded(f"runs/cache/water_model_choice/{data}_quick_tiny/result")
    path = RESULTS / f"{result}.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: run the registry's {result} first")
    saved = json.loads(path.read_text())
    if saved.get("data") != data:
        raise FileNotFoundError(f"{path} is the model choice on {saved.get('data')!r} data, not {data!r}")
    return resolve_recorded(saved["saved_result"])


def physical_marginal(result: jaxabc.ABCResult) -> jaxabc.ABCResult:
    """``result`` without the discrepancy sds a model choice with ``--discrepancy`` appends.

    The criticism asks what the simulation itself misses, and the simulator takes the force-field
    parameters only: :func:`jaxabc.criticism.without_discrepancy`.
    """
    return without_discrepancy(result)


__all__ = ["model_choice_folder", "physical_marginal"]
