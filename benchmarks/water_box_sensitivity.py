"""Which prior boxes move the water model probabilities: the force field's or the discrepancy's?

The model choice's sensitivity rows scale a model's whole box, force-field parameters and
discrepancy sds together (``jaxabc.ModelChoiceResult.sensitivity``).  This splits them, from each
saved repeat with the discrepancy term (no new simulations: every box here is inside the run's, so
:meth:`~jaxabc.model_choice.ModelChoiceResult.sensitivity` reuses the run):

- ``parameters x s``: the model's (sigma, epsilon) box scaled by ``s`` about its centre, its
  discrepancy bounds kept;
- ``discrepancy x s``: its discrepancy bounds (``max_sd``) scaled from 0, the force field's box kept

(``ModelChoiceResult.sensitivity(split_discrepancy=True)``) for ``s`` in :data:`SCALES`, one model
at a time, with the probability that model gets and how far
its log evidence moves.  A discrepancy group of one summary (D, hvap) has one residual: above it
the likelihood is nearly flat in the group's sd, so that sd's posterior follows its prior and the
evidence follows ``max_sd``.  The posterior share of each discrepancy sd in the upper half of its
bound (``ABCResult.discrepancy_identification``; 0.5 for a flat posterior) says how much of it is
prior.

Usage::

    python -m benchmarks.water_box_sensitivity [--quick]
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np

from benchmarks._common import RESULTS, ROOT, machine, relative, write_result
from benchmarks.registry import REPEATS
from jaxabc.model_choice import load_model_choice
from jaxabc.noise import DISCREPANCY_PREFIX

#: Width factors (< 1: inside the run's box, computed from the run).
SCALES = (0.5,)


def analyse_repeat(name: str, what: str, d: dict[str, Any]) -> dict[str, Any] | None:
    """The split sensitivity of one saved repeat (None without discrepancy columns)."""
    choice = load_model_choice(ROOT / d["saved_result"])
    if not any(n.startswith(DISCREPANCY_PREFIX) for n in choice.posteriors[0].names):
        return None
    base_p = np.asarray(choice.probabilities, np.float64)
    base_z = np.asarray(choice.log_evidence, np.float64)
    rows = []
    for row in choice.sensitivity(scales=SCALES, split_discrepancy=True):
        kind = row.label.split(" ")[-2] if row.changed != "all" else None
        if kind not in ("parameters", "discrepancy"):
            continue  # the whole-box rows are the model choice's own, on its page
        i = choice.names.index(row.changed)
        rows.append(
            {
                "model": row.changed,
                "kind": kind,
                "scale": row.scale,
                "status": row.status,
                "probability": float(row.probabilities[i]),
                "probability_before": float(base_p[i]),
                "log_evidence_change": float(row.log_evidence[i] - base_z[i]),
                "leader": choice.names[int(np.nanargmax(row.probabilities))]
                if np.any(np.isfinite(row.probabilities))
                else None,
            }
        )
    upper_half = {
        model: post.discrepancy_identification()[0] for model, post in zip(choice.names, choice.posteriors, strict=True)
    }
    return {
        "result": name,
        "what": what,
        "probabilities": base_p.tolist(),
        "names": list(choice.names),
        "rows": rows,
        "discrepancy_upper_half_share": upper_half,
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="write the quick JSON (the same analysis)")
    args = parser.parse_args(argv)
    repeats, inputs = [], []
    for name, what in REPEATS:
        path = RESULTS / f"{name}.json"
        if not path.is_file():
            continue
        d = json.loads(path.read_text())
        out = analyse_repeat(name, what, d)
        if out is not None:
            repeats.append(out)
            inputs.append(ROOT / d["saved_result"] / "model_choice.json")
    if not repeats:
        raise SystemExit("no saved model-choice repeat with the discrepancy term")
    moves: dict[str, list[float]] = {"parameters": [], "discrepancy": []}
    for r in repeats:
        for row in r["rows"]:
            moves[row["kind"]].append(abs(row["log_evidence_change"]))
    payload = {
        "machine": machine(),
        "scales": list(SCALES),
        "repeats": repeats,
        "log_evidence_change_abs": {
            k: {"median": float(np.median(v)), "max": float(np.max(v)), "n": len(v)} for k, v in moves.items()
        },
    }
    out = write_result("water_box_sensitivity", payload, quick=args.quick, inputs=inputs)
    print(json.dumps(payload["log_evidence_change_abs"], indent=1))
    print(f"wrote {relative(out)}")
    return payload


if __name__ == "__main__":
    main()
