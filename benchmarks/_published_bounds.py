"""Bounds on the water model choice's discrepancy sds from the published rigid models.

Each group's ``max_sd`` set to the largest misfit a *published* rigid model makes in that group
at its own parameters, in the same protocol and against the same data
(``water_published_predictive``): a reference-class prior ("this model's systematic error is
no worse than the worst published rigid model's").  It uses the measured values but no fit.
Read by ``water_box_sensitivity`` (the bounds applied to saved runs) and by
``water_model_choice --discrepancy-bounds published`` (the bounds as the run's prior).
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: The result holding each published model's summaries at its published parameters.
PUBLISHED = "water_published_predictive"


def published_model_bounds(
    published: dict[str, Any], fitted: list[str], groups: dict[str, list[int]], data: str, temperature_k: float
) -> dict[str, float]:
    """Per discrepancy group, the largest ``|mean - observed|`` over the published models and the
    group's summaries (its units), from a ``water_published_predictive`` payload.

    ``groups`` index into ``fitted`` (summary names), as a model choice's settings record them.

    Raises
    ------
    ValueError
        The published runs used other data or another temperature, or lack a group's summary,
        or a model has no mean for it.
    """
    if published.get("data") != data or not np.isclose(float(published.get("temperature_k", np.nan)), temperature_k):
        raise ValueError(
            f"published-model runs are for data {published.get('data')!r} at {published.get('temperature_k')} K; "
            f"the model choice is for {data!r} at {temperature_k} K"
        )
    names = list(published["summary_names"])
    observed = published["observed"]
    out = {}
    for group, idx in groups.items():
        wanted = [fitted[i] for i in idx]
        missing = [n for n in wanted if n not in names]
        if missing:
            raise ValueError(f"group {group!r}: the published-model runs lack {missing}")
        devs = []
        for model, m in published["models"].items():
            for n in wanted:
                k = names.index(n)
                if m["mean"][k] is None or observed[k] is None:
                    raise ValueError(f"group {group!r}: no value of {n} for {model} or the data")
                devs.append(abs(float(m["mean"][k]) - float(observed[k])))
        out[group] = float(max(devs))
    return out
