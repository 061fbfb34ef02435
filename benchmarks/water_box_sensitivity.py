"""Which prior boxes move the water model probabilities: the force field's or the discrepancy's?

The model choice's sensitivity rows scale a model's whole box, force-field parameters and
discrepancy sds together (``jaxabc.ModelChoiceResult.sensitivity``).  This splits them, from each
saved repeat with the discrepancy term, the earlier repeats, the held-out family and its rerun
with the published-model bounds (:mod:`benchmarks._water_family`) (no new simulations: every box
here is inside the run's, so
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

Then a bound on the discrepancy sds from outside the fit
(:func:`benchmarks._published_bounds.published_model_bounds`): each group's
``max_sd`` set to the largest misfit a *published* rigid model makes in that group at its own
parameters, in the same protocol and against the same data (``water_published_predictive``),
times :data:`FAMILY_FACTORS`.  That is a reference-class prior ("this model's systematic error
is no worse than the worst published rigid model's"); it uses the measured values but no fit.
Each group alone and all groups at once, each model's evidence by the same reuse, and the
probability intervals and verdict rule of :meth:`~jaxabc.model_choice.ModelChoiceResult.verdict`
(the leader preferred only when its interval lies above every other's).

Usage::

    python -m benchmarks.water_box_sensitivity [--quick]
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np

from benchmarks._common import RESULTS, ROOT, machine, relative, write_result
from benchmarks._published_bounds import PUBLISHED, published_model_bounds
from benchmarks._water_family import HOLDOUT_FAMILY, PUBLISHED_BOUNDS_FAMILY
from benchmarks._water_repeats import REPEATS
from jaxabc.model_choice import (
    STATUS_REUSED,
    ModelChoiceResult,
    interval_leader,
    load_model_choice,
    probabilities_with_errors,
    probability_bounds,
)
from jaxabc.noise import DISCREPANCY_PREFIX

#: Width factors (< 1: inside the run's box, computed from the run).
SCALES = (0.5,)
#: The published-model bounds times these (capped at the run's own bounds: no extrapolation).
FAMILY_FACTORS = (1.0, 2.0)


def _group(column: str) -> str:
    return column.removeprefix(DISCREPANCY_PREFIX).rstrip("]")


def bounded_box(post: Any, bounds: dict[str, float], factor: float, only: str | None = None):
    """``(low, high)`` of a model's augmented box with the discrepancy bounds ``factor * bounds``
    (every group, or ``only`` that one), each capped at the run's own bound."""
    low, high = np.array(post.prior.low, np.float64), np.array(post.prior.high, np.float64)
    for j, column in enumerate(post.names):
        if column.startswith(DISCREPANCY_PREFIX) and only in (None, _group(column)):
            high[j] = min(high[j], factor * bounds[_group(column)])
    return low, high


def family_variant(
    choice: ModelChoiceResult, bounds: dict[str, float], factor: float, only: str | None = None
) -> dict[str, Any]:
    """The model probabilities with every model's discrepancy bounds set by :func:`bounded_box`;
    each model's evidence reuses its run (:meth:`~jaxabc.model_choice.ModelChoiceResult.sensitivity`
    with that box).  The verdict rule is the library's: preferred only when the leader's
    probability interval lies above every other model's."""
    log_z, se, share_cut = [], [], {}
    for i, (name, post) in enumerate(zip(choice.names, choice.posteriors, strict=True)):
        low, high = bounded_box(post, bounds, factor, only)
        row = choice.sensitivity(scales=(), boxes={name: (low, high)})[0]
        if row.status != STATUS_REUSED:
            raise RuntimeError(f"{name}: the bounded box was not computed from the run ({row.status})")
        log_z.append(float(row.log_evidence[i]))
        se.append(float(row.log_evidence_errors[i]))
        x, w = np.asarray(post.particles, np.float64), np.asarray(post.weights, np.float64)
        w = w / w.sum()
        share_cut[name] = {
            _group(c): float(w @ (x[:, j] > high[j]))
            for j, c in enumerate(post.names)
            if c.startswith(DISCREPANCY_PREFIX) and only in (None, _group(c))
        }
    prior = np.asarray(choice.model_prior, np.float64)
    p, _ = probabilities_with_errors(np.asarray(log_z), np.asarray(se), prior)
    iv = probability_bounds(np.asarray(log_z), np.asarray(se), prior)
    best = int(np.argmax(p))
    leader = interval_leader(p, iv)
    return {
        "groups": "all" if only is None else only,
        "factor": factor,
        "bounds": {g: factor * b for g, b in bounds.items() if only in (None, g)},
        "log_evidence": log_z,
        "log_evidence_change": (np.asarray(log_z) - np.asarray(choice.log_evidence, np.float64)).tolist(),
        "log_evidence_errors": se,
        "probabilities": p.tolist(),
        "intervals": iv.tolist(),
        "leader": choice.names[best],
        "least": choice.names[int(np.argmin(p))],
        "verdict": "undecided" if leader is None else f"preferred: {choice.names[leader]}",
        "posterior_share_cut": share_cut,
    }


def analyse_repeat(
    name: str, what: str, d: dict[str, Any], published: dict[str, Any] | None = None
) -> dict[str, Any] | None:
    """The split sensitivity of one saved repeat (None without discrepancy columns), and with
    ``published`` (a ``water_published_predictive`` payload) its published-model bounds."""
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
    family = None
    if published is not None:
        groups = d["settings"]["discrepancy"]["groups"]
        bounds = published_model_bounds(
            published, d["summaries"]["fitted"], groups, d["data"], float(d["settings"]["temperature_k"])
        )
        variants = [family_variant(choice, bounds, 1.0, g) for g in groups]
        variants += [family_variant(choice, bounds, f) for f in FAMILY_FACTORS]
        family = {"bounds": bounds, "run_bounds": d["settings"]["discrepancy"]["max_sd"], "variants": variants}
    return {
        "result": name,
        "what": what,
        "probabilities": base_p.tolist(),
        "names": list(choice.names),
        "rows": rows,
        "discrepancy_upper_half_share": upper_half,
        "published_model_bounds": family,
    }


def _moves(repeats: list[dict[str, Any]]) -> dict[str, dict[str, float]] | None:
    """Median and largest ``|log evidence change|`` of the halved force-field boxes and of the
    halved discrepancy bounds over ``repeats`` (None when there are none)."""
    if not repeats:
        return None
    moves: dict[str, list[float]] = {"parameters": [], "discrepancy": []}
    for r in repeats:
        for row in r["rows"]:
            moves[row["kind"]].append(abs(row["log_evidence_change"]))
    return {k: {"median": float(np.median(v)), "max": float(np.max(v)), "n": len(v)} for k, v in moves.items()}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="write the quick JSON (the same analysis)")
    args = parser.parse_args(argv)
    repeats, inputs = [], []
    published_path = RESULTS / f"{PUBLISHED}.json"
    published = json.loads(published_path.read_text()) if published_path.is_file() else None
    if published is not None:
        inputs.append(published_path)
    family = {name for name, _ in HOLDOUT_FAMILY}
    bounded = {name for name, _ in PUBLISHED_BOUNDS_FAMILY}
    for name, what in (*REPEATS, *HOLDOUT_FAMILY, *PUBLISHED_BOUNDS_FAMILY):
        path = RESULTS / f"{name}.json"
        if not path.is_file():
            continue
        d = json.loads(path.read_text())
        # A run made with the published-model bounds is not reweighted to them again.
        out = analyse_repeat(name, what, d, None if name in bounded else published)
        if out is not None:
            repeats.append(out | {"family": name in family, "published_bounds_family": name in bounded})
            inputs.append(ROOT / d["saved_result"] / "model_choice.json")
    if not repeats:
        raise SystemExit("no saved model-choice repeat with the discrepancy term")
    payload = {
        "machine": machine(),
        "scales": list(SCALES),
        "family_factors": list(FAMILY_FACTORS),
        "published_result": PUBLISHED if published is not None else None,
        "repeats": repeats,
        "log_evidence_change_abs": _moves([r for r in repeats if not r["published_bounds_family"]]),
        "family_log_evidence_change_abs": _moves([r for r in repeats if r["family"]]),
        "published_bounds_family_log_evidence_change_abs": _moves([r for r in repeats if r["published_bounds_family"]]),
    }
    out = write_result("water_box_sensitivity", payload, quick=args.quick, inputs=inputs)
    print(json.dumps(payload["log_evidence_change_abs"], indent=1))
    print(f"wrote {relative(out)}")
    return payload


if __name__ == "__main__":
    main()
