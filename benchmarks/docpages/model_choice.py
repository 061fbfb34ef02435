"""Results page of the water model choice and the criticism of its winner (issue 17)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks._common import RESULTS
from benchmarks._water_family import HOLDOUT_FAMILY as _FAMILY
from benchmarks._water_family import HOLDOUT_NO_DISCREPANCY, PUBLISHED_BOUNDS_SEEDS, PUBLISHED_BOUNDS_WIDER
from benchmarks._water_family import PUBLISHED_BOUNDS_FAMILY as _BOUNDED
from benchmarks._water_repeats import REPEATS, made_with_gp_variance
from benchmarks.docpages.common import (
    MISFIT_NOTE,
    cause_rows,
    extension_edges,
    f,
    figure,
    load,
    misfit_rows,
    retired,
    saved_extension,
    source,
    table,
)
from jaxabc.diagnostics import PRIOR_EDGE_LIMIT
from jaxabc.model_choice import interval_leader, probabilities_with_errors, probability_bounds
from jaxabc.noise import DISCREPANCY_PREFIX
from md.water.models import PAPER_TIP4P_ESTIMATES
from md.water.statistics import SECOND_SHELL_WINDOW_NM

#: Saved paper-preset checks of models of the model choice, one result each.
PAPER_CHECKS = ("water_model_paper_check",)
#: Saved criticisms of models of the model choice, one result each.
CRITICISMS = (
    "criticism_water_joint",
    "criticism_water_joint_no_discrepancy",
    "criticism_water_joint_published_bounds",
)
#: Which model choice each criticism starts from.
_CRITICISM_START = {
    "criticism_water_joint": "from the model choice with the discrepancy term",
    "criticism_water_joint_no_discrepancy": "from the model choice without the discrepancy term",
    "criticism_water_joint_published_bounds": "from seed 1 of the model choice with the published-model bounds",
}
#: The repeats meant to give the trusted verdict (:mod:`benchmarks._water_family`).
HOLDOUT_FAMILY = tuple(name for name, _ in _FAMILY)
#: The family rerun with the published-model discrepancy bounds as its prior.
PUBLISHED_BOUNDS_FAMILY = tuple(name for name, _ in _BOUNDED)
#: The published-bounds run the doubled sigma boxes are computed for, and the run that doubles them.
PUBLISHED_WIDER_BASE = dict(zip(PUBLISHED_BOUNDS_SEEDS, PUBLISHED_BOUNDS_FAMILY, strict=True)).get(
    PUBLISHED_BOUNDS_WIDER[1], ""
)


def _saved_figures(d: dict) -> list[str]:
    """The g_OO bands of every model, and the paper-style figure, where saved."""
    bands = f"{Path(d['saved_result']).relative_to('benchmarks/results').as_posix()}/predictive_goo.png"
    shown = [
        (bands, "g_OO bands of every model over the measured curve"),
        (
            "water_model_choice/figure_water_model_choice.png",
            "g_OO and g_OH side by side, g_OH against Soper's neutron curve "
            "(paper_figures/figure_water_model_choice.py)",
        ),
    ]
    return [figure(rel, caption) + "\n" for rel, caption in shown if (RESULTS / rel).is_file()]


def page_water_model_choice() -> str:
    """``docs/results/water_model_choice.md`` from ``water_model_choice.json`` and
    ``criticism_water_joint.json``."""
    parts = [
        "# Which rigid water model do the measured data prefer?\n",
        "Five published rigid water models, each with its O-O Lennard-Jones pair calibrated by the GP "
        "surrogate on the joint measured summaries, compared by their synthetic-likelihood evidence "
        "(`benchmarks/water_model_choice.py`); then the criticism of the most probable one, or of TIP4P when "
        "the choice is undecided (`benchmarks/criticism_water_joint.py`).  GROMACS quick preset.\n",
        *_family_headline(),
    ]
    if len(parts) > 2:  # the family's headline is there: what follows is the first run
        parts.append("The first run in detail (seed 0, 60 runs per model; its own verdict below):\n")
    d = load("water_model_choice")
    summaries = d["summaries"]
    added = summaries.get("observation_sd") or summaries.get("measurement_sd_added") or {}
    settings = d.get("settings", {})
    parts += [
        source("water_model_choice", data=d) + "\n",
        f"Data: {d['data']} at {settings.get('temperature_k', 298.15)} K; fitted summaries "
        f"{', '.join(summaries['fitted'])}; held out {', '.join(summaries['held_out'])}; measurement errors "
        "(stated by each source, or a documented estimate where it states none: `md/water/data/PROVENANCE.md`; "
        f"{summaries.get('observation_error_via', 'added to every simulation')}): "
        + ", ".join(f"{k} {f(v, 3)}" for k, v in added.items() if v)
        + f"; prior width: {settings.get('prior_width', 'default')}"
        + _own_boxes(d)
        + f"; method: {d['model_choice']['metadata'].get('method', d['method'])}.\n",
        f"Stopped: {d['model_choice']['stop_reason']}.\n",
        *_verdict(d),
        *_repeats(),
        *_holdout_family(),
        *(_without_discrepancy(load(HOLDOUT_NO_DISCREPANCY)) if load(HOLDOUT_FAMILY[0]) is not None else []),
        *_variance_pairs(),
        *_emulator_failures(),
        *_summary_noise(),
        *_box_sensitivity(),
        *_published_wider(),
        "### The first run's models\n",
        table(_HEADER, [_row(name, row, d["models"][name]) for name, row in d["per_model"].items()]) + "\n",
        "Side by side with the published parameters and the paper's TIP4P calibration:\n",
        side_by_side(d) + "\n",
        "Probability: delta-method error, and the 2.5-97.5 % points with each log evidence drawn from "
        "its error (importance sampling and the design jackknife).  Misfit p: the chi-square check of the "
        "observed summaries against each model's emulated posterior predictive; a small value says the "
        "model does not reproduce the data within the noise, whatever its probability.\n",
    ]
    bands = d.get("predictive")
    if bands:
        observed = dict(zip(summaries["names"], summaries["observed"], strict=True))
        measured = [observed.get("S9"), observed.get("density_kg_m3"), observed.get("hvap_kj_mol")]
        rows = [["measured", *(f(v, 4) for v in measured), "-"]]
        for name, entry in bands["models"].items():
            q = entry.get("scalars")
            cells = [f"{q[2][j]:.4g} [{q[0][j]:.4g}, {q[-1][j]:.4g}]" for j in range(3)] if q else ["-", "-", "-"]
            rows.append([name, *cells, f"{entry['num_runs']} ({entry['num_failed']} failed)"])
        parts += [
            "Posterior predictive (median [5 %, 95 %] over runs at posterior draws; simulated values, "
            "without the measurement error):\n",
            table(["model", *bands["scalar_names"], "runs"], rows) + "\n",
            *_worse_than_published(d),
            *_saved_figures(d),
        ]
    parts += _published()
    for name in PAPER_CHECKS:
        check = load(name)
        if check is not None:
            parts += _paper_check(name, check)
    for name in CRITICISMS:
        c = load(name)
        if c is not None:
            parts += _criticism(name, c)
    parts += _criticisms_compared({name: load(name) for name in CRITICISMS})
    gone = retired(["criticism_water", "water_model_paper_check"])
    if gone:
        parts.append("Retired criticisms and checks:\n\n" + gone + "\n")
    return "\n".join(parts)


#: The predictive's scalars (``scalar_names`` order) and their names in the published predictive.
_PREDICTIVE_SCALARS = ("S9", "density_kg_m3", "hvap_kj_mol")


def _worse_pairs(d: dict[str, Any]) -> tuple[list[str], int]:
    """The (model, property) pairs of :data:`_PREDICTIVE_SCALARS` whose calibrated predictive
    median lies farther from the measured value than the model's published parameters do
    (``water_published_predictive``), and how many pairs were compared."""
    p = load("water_published_predictive")
    bands = d.get("predictive") or {}
    if p is None or not bands.get("models"):
        return [], 0
    worse, compared = [], 0
    for name, entry in bands["models"].items():
        q, pub = entry.get("scalars"), p["models"].get(name) or {}
        if not q or "mean" not in pub:
            continue
        for j, key in enumerate(_PREDICTIVE_SCALARS):
            i = p["summary_names"].index(key)
            measured, published, calibrated = p["observed"][i], pub["mean"][i], q[2][j]
            compared += 1
            if abs(calibrated - measured) > abs(published - measured):
                worse.append(f"{name} {key} {published:.4g} -> {calibrated:.4g} (measured {measured:.4g})")
    return worse, compared


def _worse_than_published(d: dict[str, Any]) -> list[str]:
    """The sentence of :func:`_worse_pairs` under a run's predictive table."""
    worse, compared = _worse_pairs(d)
    if not compared:
        return []
    if not worse:
        return [f"Calibration brings every one of these {compared} predictions closer to the measured value.\n"]
    return [
        f"Farther from the measured value after calibration than at the published parameters, in {len(worse)} of "
        f"{compared} (model, property) pairs (published mean -> calibrated median): {'; '.join(worse)}.  The fit "
        "weighs every fitted summary against its measurement error and its group's discrepancy sd, so a "
        "property whose discrepancy may be large (D, hvap) is traded for the g_OO summaries, and the held-out "
        "density follows the parameters (the confounding of parameters and discrepancy, Brynjarsdottir & "
        "O'Hagan 2014): for these properties the calibrated parameters are no better than the published ones.\n"
    ]


def _own_boxes(d: dict[str, Any]) -> str:
    """The models whose box differs from the prior width's (``--model-prior``), as factors of
    their published parameters."""
    own = (d.get("settings") or {}).get("model_prior_width") or {}
    boxes = []
    for name in own:
        box = _box_factors(d, name)
        if box is None:
            continue
        lo, hi = box
        boxes.append(f"{name} sigma x[{lo[0]:.3g}, {hi[0]:.3g}], epsilon x[{lo[1]:.3g}, {hi[1]:.3g}]")
    if not boxes:
        return ""
    return (
        " (" + ", ".join(boxes) + ": where a posterior piled on a bound of the common box, that model's box was "
        "widened and the model choice rerun)"
    )


def _criticisms_compared(crits: dict[str, dict[str, Any] | None]) -> list[str]:
    """Whether the criticism's answer survives the discrepancy term and its prior: the saved runs
    side by side, and what they agree on."""
    saved = {n: c for n, c in crits.items() if c is not None}
    if len(saved) < 2:
        return []
    rows, tops, gains = [], {}, []
    for name, c in saved.items():
        top = c["causes"][0] if c.get("causes") else {}
        g = c.get("gain") or {}
        worst = max(c.get("misfits") or [{}], key=lambda m: abs(m.get("residual", 0.0)))
        failed = _extension_failed(name, c)
        rows.append(
            [
                _CRITICISM_START.get(name, name),
                f"{worst.get('name', '-')} (z {worst.get('residual', float('nan')):+.1f})",
                f"{top.get('name', '-')} ({top.get('score', float('nan')):.1f})",
                ", ".join(c.get("needed") or []) or "-",
                f"{g.get('delta_lpd', float('nan')):.1f} +- {g.get('delta_lpd_se', float('nan')):.1f}"
                + (" (extension not validated)" if failed else ""),
            ]
        )
        tops.setdefault(top.get("name", "-"), []).append(_CRITICISM_START.get(name, name))
        if not failed and g.get("delta_lpd", 0.0) > 2 * g.get("delta_lpd_se", np.inf):
            gains.append(_CRITICISM_START.get(name, name))
    n = len(saved)
    runs = "Both runs" if n == 2 else f"All {n} runs"
    if len(tops) == 1:
        sentence = f"{runs} name the same cause, {next(iter(tops))}."
    else:
        named = "; ".join(f"{cause} {', '.join(starts)}" for cause, starts in tops.items())
        sentence = (
            f"The runs name different causes ({named}): which effect the criticism names depends on how the "
            "model choice it starts from treats the discrepancy, so no one cause is a finding on its own."
        )
    sentence += (
        "  A held-out gain beyond twice its standard error, on a validated extension: "
        + ("; ".join(gains) if gains else "none")
        + f" ({len(gains)} of {n})."
    )
    common = set.intersection(*(set(c.get("needed") or []) for c in saved.values()))
    # A cause counts only where it explains part of the residual in that run.
    explains = {
        name: {k["name"] for k in c.get("causes") or [] if k.get("fraction_explained", 0.0) >= 0.05}
        for name, c in saved.items()
    }
    common = {cause for cause in common if all(cause in e for e in explains.values())}
    if common:
        sentence += (
            f"  Needed jointly, and explaining at least 5 % of the residual, in every run: {', '.join(sorted(common))}."
        )
    unvalidated = [_CRITICISM_START.get(n, n) for n, c in saved.items() if _extension_failed(n, c)]
    if unvalidated:
        sentence += (
            f"  The extension's emulator failed validation in the criticism {'; '.join(unvalidated)}: its gain is "
            "not trustworthy."
        )
    return [
        "## The criticisms side by side\n",
        table(["criticism", "largest misfit", "top cause (score)", "needed jointly", "held-out delta lpd"], rows)
        + "\n",
        sentence + "\n",
    ]


def _repeats() -> list[str]:
    """The verdict and probabilities of every saved repeat (seeds, without the discrepancy term):
    a statement on this page holds only if it holds in each."""
    saved = [(name, what, d) for name, what in REPEATS if (d := load(name)) is not None]
    missing = [name for name, _ in REPEATS if load(name) is None]
    if len(saved) < 2:
        return [f"Repeats not run yet ({', '.join(missing)}): the verdict rests on one seed.\n"] if missing else []
    names = saved[0][2]["model_choice"]["names"]
    rows = []
    for name, what, d in saved:
        mc = d["model_choice"]
        verdict = d.get("verdict") or {}
        rows.append(
            [
                f"`{name}` ({what})",
                f"{verdict.get('status', '?')} {verdict.get('model') or ''}".strip(),
                ", ".join(_flags(mc["stop_reason"])) or "-",
                _validated(d),
                *(f"{p:.3g}" for p in mc["probabilities"]),
            ]
        )
    with_disc = [d for _, _, d in saved if _missed_groups(d)]
    unreproduced = {}
    for d in with_disc:
        for g, who in _missed_groups(d).items():
            unreproduced[g] = unreproduced.get(g, 0) + (len(who) == len(d["per_model"]))
    statuses = {(d.get("verdict") or {}).get("status") for _, _, d in saved}
    tops = {d["model_choice"]["names"][int(np.argmax(d["model_choice"]["probabilities"]))] for _, _, d in saved}
    agree = "the same verdict" if len(statuses) == 1 else "different verdicts"
    trusted = [name for name, _, d in saved if "UNTRUSTED" not in _flags(d["model_choice"]["stop_reason"])]
    return (
        [
            f"Repeats: {len(saved)} runs give {agree} ({', '.join(sorted(s or '?' for s in statuses))}); the most "
            f"probable model is {' or '.join(sorted(tops))}; {len(trusted)} of {len(saved)} runs have every "
            f"emulator validated ({', '.join(f'`{n}`' for n in trusted) or 'none'}), the others are UNTRUSTED"
            + (f"; not run yet: {', '.join(missing)}" if missing else "")
            + ".\n",
            table(["run", "verdict", "flags", _VALIDATED_HEADER, *names], rows) + "\n",
        ]
        + _misspecified_sentence(saved)
        + _repeat_edges(saved)
        + (
            [
                f"In how many of the {len(with_disc)} repeats with the discrepancy term no model reproduces each "
                "group: " + "; ".join(f"{g} {k} of {len(with_disc)}" for g, k in unreproduced.items()) + ".\n"
            ]
            if with_disc
            else []
        )
    )


def _headline_families() -> tuple[tuple[tuple[str, ...], str], tuple[tuple[str, ...], str]]:
    """The family the headline stands on and the other one, each ``(run names, label)``.

    The published-bounds family once every seed of it is saved and two are trusted: its
    discrepancy bounds come from the published models' misfits to the same measured data (no
    fit) rather than a round number, and in its seeds no force-field posterior piles on a bound.
    Until then the held-out family with the fixed bounds."""
    held = (HOLDOUT_FAMILY, "held-out family")
    bounded = (PUBLISHED_BOUNDS_FAMILY, "published-bounds family")
    runs = [load(name) for name in PUBLISHED_BOUNDS_FAMILY]
    if all(d is not None for d in runs) and sum(not _flags(d["model_choice"]["stop_reason"]) for d in runs) > 1:
        return bounded, held
    return held, bounded


def _family_headline() -> list[str]:
    """The verdict the page stands on, from the trusted seeds of the family
    :func:`_headline_families` picks (every emulator validated, no flag): whether they agree, then
    one bullet each for the prior boxes, the other family, piled-up bounds, the calibrated
    predictions against the published parameters, the run without the discrepancy term, and what
    would change the verdict.  Empty until a seed of the family is saved."""
    (family, label), (other, _) = _headline_families()
    bounds_first = family == PUBLISHED_BOUNDS_FAMILY
    saved = [(name, d) for name in family if (d := load(name)) is not None]
    trusted = [(name, d) for name, d in saved if not _flags(d["model_choice"]["stop_reason"])]
    if not saved:
        return []
    if not trusted:
        return [
            f"**Verdict: none trusted yet.** {len(saved)} of {len(family)} seeds of the {label} "
            "run, none with every emulator validated and no flag (table below).\n"
        ]

    statuses = sorted({_status(d) for _, d in trusted})
    leaders = []
    for _, d in trusted:
        mc = d["model_choice"]
        k = int(np.argmax(mc["probabilities"]))
        leaders.append(f"seed {d['settings'].get('seed', '?')} {mc['names'][k]} {mc['probabilities'][k]:.2f}")
    head = statuses[0] if len(statuses) == 1 else "depends on the seed"
    text = (
        f"**Verdict: {head}.** From the "
        + (f"{len(trusted)} trusted seeds" if len(trusted) > 1 else "one trusted seed")
        + f" of the {label} ({len(saved)} of {len(family)} run; trusted: every emulator validated on held-out "
        "runs, no flag; calibrated emulator variance, a budget of 120 GROMACS runs per model"
        + (
            ", each discrepancy sd bounded by the largest misfit a published model makes in its group"
            if bounds_first
            else ""
        )
        + ", table below): "
        + (
            (f"each says {statuses[0]}" if len(trusted) > 1 else f"it says {statuses[0]}")
            if len(statuses) == 1
            else "they disagree (" + "; ".join(_status(d) for _, d in trusted) + ")"
        )
        + ("; the most probable model in each: " if len(trusted) > 1 else "; the most probable model: ")
        + f"{', '.join(leaders)}."
    )
    flagged = [(n, d) for n, d in saved if (n, d) not in trusted]
    if flagged:
        text += (
            " Not counted: "
            + "; ".join(
                f"seed {d['settings'].get('seed', '?')} ({', '.join(_flags(d['model_choice']['stop_reason']))}: "
                f"{_failed_models(d) or 'flagged'}), which says {_status(d)}"
                for _, d in flagged
            )
            + "."
        )
    if len(trusted) == 1:
        same = all(_status(d) == head for _, d in flagged)
        text += " One trusted seed alone is not a verdict" + (
            f": every flagged seed says {head} too." if flagged and same else "."
        )
    bullets = [
        b
        for b in (
            _boxes_bullet(trusted, bounds_first),
            _bottom_bullet(trusted) if bounds_first else None,
            _bounded_family(other),
            _edges_bullet(trusted),
            _missed_bullet(trusted),
            _predictions_bullet(trusted),
            _without_bullet(),
        )
        if b
    ]
    others = [d for name in other if (d := load(name)) is not None]
    other_trusted = [d for d in others if not _flags(d["model_choice"]["stop_reason"])]
    agree = sorted({_status(d) for d in other_trusted})
    if bounds_first:
        bullets.append(
            "What would change it: a seed that prefers one model; a prior box narrowed on grounds outside these "
            "data; discrepancy bounds other than the published models' largest misfits, which come from the same "
            "measured data though from no fit (with the fixed round-number bounds "
            + (f"the trusted seeds say {'; '.join(agree)}" if agree else "no seed is trusted")
            + "; tables below)."
        )
    else:
        n = len(other_trusted)
        bullets.append(
            "What would change it: a seed that prefers one model; a prior box narrowed on grounds outside these "
            "data; bounds on the discrepancy sds from outside the fit"
            + (
                f" (the published models' largest misfits, from the same measured data though from no fit, leave "
                f"it {head} in their {'one trusted seed' if n == 1 else f'{n} trusted seeds'})"
                if agree == [head]
                else ""
            )
            + " (tables below)."
        )
    return [text + "\n", "\n".join(f"- {b}" for b in bullets) + "\n"]


def _bottom_bullet(trusted: list[tuple[str, dict[str, Any]]]) -> str | None:
    """The headline's bullet on the models whose probability interval lies below another's in the
    run and in every halved box of each trusted seed (:func:`_disfavoured`), with their log
    evidence against the most probable model's."""
    below = [set(_disfavoured(d)) for _, d in trusted]
    common = sorted(set.intersection(*below)) if below else []
    if not common:
        return None
    pairs = []
    for _, d in trusted:
        mc = d["model_choice"]
        z, e = np.asarray(mc["log_evidence"], float), np.asarray(mc["log_evidence_errors"], float)
        top = int(np.argmax(mc["probabilities"]))
        for model in common:
            k = list(mc["names"]).index(model)
            pairs.append(
                f"seed {d['settings'].get('seed', '?')} {model} {z[k]:.2f} +- {e[k]:.2f} against "
                f"{mc['names'][top]} {z[top]:.2f} +- {e[top]:.2f}, a Bayes factor of {np.exp(z[top] - z[k]):.1f}"
            )
    return (
        f"Bottom: {', '.join(common)} lies below another model's probability interval in "
        + ("each trusted seed" if len(trusted) > 1 else "the trusted seed")
        + ", in the run and in every halved box, the one ranking a factor-2 prior box does not turn "
        "(log evidence: " + "; ".join(pairs) + ")."
    )


def _missed_bullet(trusted: list[tuple[str, dict[str, Any]]]) -> str | None:
    """The headline's bullet on what no model reproduces within the measurement error: the
    discrepancy groups :func:`_missed_groups` finds for every model in every trusted seed, and
    those some models miss in some seed."""
    missed = [_missed_groups(d) for _, d in trusted]
    if not missed or not all(missed):
        return None
    groups = list(missed[0])
    everyone = [
        g
        for g in groups
        if all(len(m.get(g, [])) == len(d["per_model"]) for m, (_, d) in zip(missed, trusted, strict=True))
    ]
    some = []
    for g in groups:
        if g in everyone:
            continue
        seeds: dict[str, list[str]] = {}
        for m, (_, d) in zip(missed, trusted, strict=True):
            for name in m.get(g, []):
                seeds.setdefault(name, []).append(str(d["settings"].get("seed", "?")))
        if seeds:
            some.append(
                f"{g} ("
                + "; ".join(
                    f"{name} in seed{'s' if len(k) > 1 else ''} {', '.join(k)}" for name, k in sorted(seeds.items())
                )
                + ")"
            )
    line = (
        "Not reproduced within the measurement error by any model, in "
        + ("each trusted seed" if len(trusted) > 1 else "the trusted seed")
        + " (the discrepancy sd's 2.5 % point above 2 % of its bound): "
        + (", ".join(everyone) if everyone else "no group")
    )
    if some:
        line += "; by some models in some seeds: " + ", ".join(some)
    return line + "."


def _status(d: dict[str, Any]) -> str:
    """A run's verdict as a phrase ("undecided", "preferred TIP4P")."""
    v = d.get("verdict") or {}
    return f"{v.get('status', '?')} {v.get('model') or ''}".strip()


def _boxes_bullet(trusted: list[tuple[str, dict[str, Any]]], bounded: bool = False) -> str | None:
    """The headline's bullet on the prior boxes: in how many (seed, model) cases halving one model's
    box makes it preferred, how much each half of the box moves the evidence (split by
    :mod:`benchmarks.water_box_sensitivity` over the headline's family, ``bounded`` for the
    published-bounds one, else over the nearest it has), and the verdicts with the published-model
    bounds applied to the saved runs."""
    turned, halved = 0, 0
    for _, d in trusted:
        names = list(d["model_choice"]["names"])
        for r in d.get("sensitivity") or []:
            model = r["label"].removesuffix(" box x0.5")
            if model in names and np.all(np.isfinite(np.asarray(r["probabilities"], float))):
                halved += 1
                turned += _decided(r, names) == model
    if not halved:
        return None
    line = (
        f"Prior boxes: halving one model's prior box (its force-field box about its centre and its discrepancy "
        f"bounds) makes that model preferred in {turned} of {halved} (seed, model) cases"
        + (
            ": the differences the data make between these models are smaller than what a factor-2 choice "
            "of prior makes, so no model's lead is a finding"
            if turned
            else ""
        )
    )
    split = load("water_box_sensitivity")
    if turned and split is not None:
        key, flag = (
            ("published_bounds_family_log_evidence_change_abs", "published_bounds_family")
            if bounded
            else ("family_log_evidence_change_abs", "family")
        )
        moves = split.get(key)
        runs = sum(bool(r.get(flag)) for r in split["repeats"])
        where = f"over the {runs} saved runs of this family"
        if not moves and bounded:
            moves = split.get("family_log_evidence_change_abs")
            runs = sum(bool(r.get("family")) for r in split["repeats"])
            where = f"over the {runs} saved runs of the fixed-bounds family"
        if not moves:
            moves, where = split["log_evidence_change_abs"], "over the earlier repeats"
        weigh = moves["discrepancy"]["median"] > moves["parameters"]["median"]
        line += (
            f". Split apart {where}, halving the discrepancy bounds moves a model's log evidence by a median "
            f"{moves['discrepancy']['median']:.2f}, halving the force-field box by "
            f"{moves['parameters']['median']:.2f}" + (": the discrepancy priors weigh most" if weigh else "")
        )
        reweighted = [
            v
            for r in split["repeats"]
            if r.get("family") and r["result"] in {n for n, _ in trusted}
            for v in (r.get("published_model_bounds") or {}).get("variants", [])
            if v["groups"] == "all" and v["factor"] == 1.0
        ]
        if reweighted:
            verdicts = sorted({v["verdict"] for v in reweighted})
            line += (
                ". With every discrepancy bound set from the published models' misfits instead (misfits to "
                f"the same measured data, no fit), {len(reweighted)} of {len(reweighted)} trusted "
                f"seeds say {verdicts[0]}, least probable {', '.join(v['least'] for v in reweighted)}"
                if len(verdicts) == 1
                else ". With every discrepancy bound set from the published models' misfits instead, the "
                f"trusted seeds say {'; '.join(v['verdict'] for v in reweighted)}"
            )
    if bounded:
        line += _published_doubled()
    return line + "."


def _edges_bullet(trusted: list[tuple[str, dict[str, Any]]]) -> str | None:
    """The headline's bullet on posteriors piled on a bound of their box, and, for a force-field
    parameter, where they sit."""
    edges: list[str] = []
    corners = False
    for _, d in trusted:
        for model, parameter, side, share in _piled_bounds(d):
            corner = _edge_corner(d, model, parameter)
            corners |= parameter in _FORCE_FIELD
            edges.append(
                f"{model}'s {parameter} in seed {d['settings'].get('seed', '?')}, {share:.0%} at its "
                f"{('lower', 'upper')[side]} bound" + (f"; {corner}" if corner else "")
            )
    if not edges:
        largest = [
            (share, f"{model}'s {parameter} {share:.0%} in seed {d['settings'].get('seed', '?')}")
            for _, d in trusted
            for model in d.get("prior_edge") or {}
            for parameter in _FORCE_FIELD
            if (share := _edge_share(d, model, parameter)) is not None
        ]
        return (
            "Prior edges: no posterior has more than 5 % of its mass within 2 % of a bound of its box (a "
            "discrepancy sd's bound at 0 is a physical limit, not counted)"
            + (f"; the largest force-field share: {max(largest)[1]}" if largest else "")
            + "."
        )
    return (
        "Prior edges (more than 5 % of a posterior within 2 % of a bound): "
        + "; ".join(edges)
        + (
            ".  What the calibrated predictions there miss, the discrepancy term absorbs: the piled-up mass "
            "marks a corner where the model fits g_OO as a different liquid, not a better water."
            if corners
            else "."
        )
    )


def _piled_bounds(d: dict[str, Any]) -> list[tuple[str, str, int, float]]:
    """``(model, parameter, side, mass)`` for every bound of a run's boxes with more than 5 % of the
    posterior within 2 % of it (side 0 lower, 1 upper).  A discrepancy sd's lower bound, 0, is a
    physical limit (the run's prior marks it so) and is left out, as the run's warnings leave it."""
    out = []
    for model, e in (d.get("prior_edge") or {}).items():
        for parameter, mass in zip(e["parameters"], e["mass"], strict=True):
            for side, share in enumerate(mass):
                if share > PRIOR_EDGE_LIMIT and not (side == 0 and parameter.startswith(DISCREPANCY_PREFIX)):
                    out.append((model, parameter, side, float(share)))
    return out


def _predictions_bullet(trusted: list[tuple[str, dict[str, Any]]]) -> str | None:
    """The headline's bullet on the calibrated predictions against the published parameters."""
    worse = [(d["settings"].get("seed", "?"), *_worse_pairs(d)) for _, d in trusted]
    worse = [(seed, len(w), n) for seed, w, n in worse if n]
    if not worse:
        return None
    fitted = trusted[0][1]["summaries"].get("fitted", [])
    n_goo = sum(name not in ("S9", "hvap_kj_mol") for name in fitted)
    return (
        "Predictions: the calibrated parameters leave D (S9), the held-out density and hvap farther from the "
        "measured values than the published parameters in "
        + " and ".join(
            f"{k} of {n}" + (" (model, property) pairs" if i == 0 else "") + f" in seed {seed}"
            for i, (seed, k, n) in enumerate(worse)
        )
        + f": the fit weighs {n_goo} g_OO summaries against one D and one hvap, and the discrepancy sds "
        "absorb what it leaves, so for these properties the calibrated parameters are no better force fields "
        "than the published ones (the first run's pairs under its predictive below)."
    )


def _rejections(d: dict[str, Any]) -> tuple[dict[str, float | None], list[str], list[str]]:
    """A run's misfit p per model, the models whose emulator failed validation, and the models
    rejected at p < 0.01."""
    misfit = {name: (row.get("observed_misfit") or {}).get("p_value") for name, row in d["per_model"].items()}
    failed = [name for name, row in d["per_model"].items() if row.get("validated") is False]
    rejected = [name for name, p in misfit.items() if p is not None and p < 0.01]
    return misfit, failed, rejected


def _without_bullet() -> str | None:
    """The headline's bullet on the run without the discrepancy term."""
    without = load(HOLDOUT_NO_DISCREPANCY)
    if without is None:
        return None
    misfit, _, rejected = _rejections(without)
    validated = sum(row.get("validated") is True for row in without["per_model"].values())
    ok = validated == len(without["per_model"])
    line = "Without the discrepancy term (seed 0): " + (
        "every model's misfit check rejects it (p < 0.01"
        + (
            ") on validated emulators"
            if ok
            else f"; {validated} of {len(without['per_model'])} on validated emulators)"
        )
        + ": no rigid model here reproduces the measured summaries within their stated errors"
        if len(rejected) == len(misfit)
        else f"verdict {_status(without)}" + ("" if ok else ", not every emulator validated")
    )
    w, n = _worse_pairs(without)
    if n:
        line += (
            "; its calibrated predictions of D, density and hvap are farther from the measured values than "
            f"the published parameters' in {len(w)} of {n} pairs"
        )
    return line + "."


def _edge_share(d: dict[str, Any], model: str, parameter: str) -> float | None:
    """The largest posterior mass of a model's ``parameter`` within 2 % of either bound."""
    e = (d.get("prior_edge") or {}).get(model)
    if not e or parameter not in e["parameters"]:
        return None
    return float(max(e["mass"][e["parameters"].index(parameter)]))


def _intervals(mc: dict[str, Any]) -> np.ndarray:
    """A saved model choice's probability intervals ``(K, 2)``, each log evidence +- 2 s.e."""
    return probability_bounds(
        np.asarray(mc["log_evidence"], float),
        np.asarray(mc["log_evidence_errors"], float),
        np.asarray(mc["model_prior"], float),
    )


def _disfavoured(d: dict[str, Any]) -> list[str]:
    """The models whose probability interval lies wholly below another model's, in the run and in
    every halved-box variant of its sensitivity table (a narrower box reuses the run): a ranking
    at the bottom that a factor-2 prior box does not turn.  None without a halved variant."""
    mc = d["model_choice"]
    names = list(mc["names"])
    runs = [_intervals(mc)]
    runs += [
        np.asarray(r["intervals"], float)
        for r in d.get("sensitivity") or []
        if "x0.5" in r["label"] and np.all(np.isfinite(np.asarray(r["intervals"], float)))
    ]
    if len(runs) < 2:  # no halved box to check it against
        return []
    return [names[k] for k in sorted(set.intersection(*(_below_others(b) for b in runs)))]


def _below_others(intervals: np.ndarray) -> set[int]:
    """Indices of the models whose probability interval ``(K, 2)`` lies wholly below another's."""
    k_all = range(len(intervals))
    return {k for k in k_all if any(intervals[k, 1] < intervals[j, 0] for j in k_all if j != k)}


def _bounded_family(family: tuple[str, ...] | None = None) -> str | None:
    """The bullet of the family the headline does not stand on: by default
    :data:`PUBLISHED_BOUNDS_FAMILY`, the family rerun with every discrepancy sd bounded by the
    published models' largest misfit in its group (the prior of the run, not a reweighting), or
    :data:`HOLDOUT_FAMILY` with its fixed bounds: each seed's verdict, the bounds, where the
    posteriors still pile on a force-field bound, and the calibrated predictions against the
    published parameters."""
    family = PUBLISHED_BOUNDS_FAMILY if family is None else family
    saved = [(name, d) for name in family if (d := load(name)) is not None]
    if not saved:
        return None
    first = saved[0][1]["settings"]["discrepancy"]
    groups = list(first["groups"])
    bounds = ", ".join(f"{g} {b:.3g}" for g, b in zip(groups, first["max_sd"], strict=True))
    seeds = []
    for _, d in saved:
        mc = d["model_choice"]
        k = int(np.argmax(mc["probabilities"]))
        flags = _flags(mc["stop_reason"])
        seeds.append(
            f"seed {d['settings'].get('seed', '?')} {_status(d)}"
            + f" (most probable {mc['names'][k]} {mc['probabilities'][k]:.2f}"
            + (f"; {', '.join(flags)}: {_failed_models(d) or 'flagged'}" if flags else "")
            + ")"
        )
    line = (
        (
            f"With the published-model discrepancy bounds as the prior ({bounds}; rerun, not reweighted; "
            if family == PUBLISHED_BOUNDS_FAMILY
            else f"With the fixed round-number discrepancy bounds of the held-out family instead ({bounds}; "
        )
        + f"{len(saved)} of {len(family)} seeds run): "
        + "; ".join(seeds)
    )
    piled = [
        f"{model}'s {parameter} {share:.0%} in seed {d['settings'].get('seed', '?')}"
        for _, d in saved
        for model in d["per_model"]
        for parameter in _FORCE_FIELD
        if (share := _edge_share(d, model, parameter)) is not None and share > 0.05
    ]
    tip3p = [f"{share:.0%}" for _, d in saved if (share := _edge_share(d, "TIP3P", "epsilon_OO")) is not None]
    line += (
        ". Force-field mass within 2 % of a bound above 5 %: "
        + ("; ".join(piled) if piled else "none")
        + (
            f" (TIP3P's epsilon: {', '.join(tip3p)})"
            if tip3p and not any(p.startswith("TIP3P's epsilon") for p in piled)
            else ""
        )
    )
    below = [
        f"{', '.join(models)} in seed {d['settings'].get('seed', '?')}" for _, d in saved if (models := _disfavoured(d))
    ]
    line += _among_validated_sentence(saved) or (
        ". Below another model's probability interval in the run and in every halved box: "
        + ("; ".join(below) if below else "no model")
    )
    if family == PUBLISHED_BOUNDS_FAMILY:
        line += _published_doubled()
    worse = [(d["settings"].get("seed", "?"), *_worse_pairs(d)) for _, d in saved]
    worse = [(seed, len(w), n) for seed, w, n in worse if n]
    if worse:
        line += ". Predictions farther from the measured values than the published parameters' in " + ", ".join(
            f"{k} of {n} pairs in seed {seed}" for seed, k, n in worse
        )
    return line + "."


def _among_validated(d: dict[str, Any]) -> tuple[list[str], str, list[str]] | None:
    """A run's model choice restricted to the models whose emulators validated: ``(models left
    out, verdict, models below another's interval in the run and in every narrower box computed
    from it)``.

    The model prior is renormalised over the validated models: the comparison conditional on the
    true model being one of them (a failed emulator makes only its own evidence untrustworthy).
    The verdict follows :meth:`jaxabc.model_choice.ModelChoiceResult.verdict`: the most probable
    model's interval above every other's in the run and in every row computed from it ("reused").
    Whether a left-out model would lead stays unknown.  None for a run flagged for anything else
    (MISSPECIFIED), or with fewer than two validated models."""
    mc = d["model_choice"]
    if set(_flags(mc["stop_reason"])) - {"UNTRUSTED"}:
        return None
    names = list(mc["names"])
    keep = [k for k, name in enumerate(names) if (d["per_model"].get(name) or {}).get("validated") is not False]
    if len(keep) < 2:
        return None
    prior = np.asarray(mc["model_prior"], float)[keep]
    prior = prior / prior.sum()

    def kept(row: dict[str, Any], key: str) -> np.ndarray:
        values = row.get(key)
        return (
            np.full(len(keep), np.inf if key.endswith("upper_bounds") else np.nan)
            if values is None
            else (np.asarray(values, float)[keep])
        )

    rows = [mc] + [r for r in mc.get("sensitivity") or [] if str(r.get("status", "")).startswith("reused")]
    leaders, below = [], []
    for r in rows:
        z, e = kept(r, "log_evidence"), kept(r, "log_evidence_errors")
        if np.isnan(z).any():  # not comparable (the library's verdict says undecided there too)
            leaders.append(None)
            below.append(set())
            continue
        iv = probability_bounds(z, e, prior, kept(r, "log_evidence_upper_bounds"))
        leaders.append(interval_leader(probabilities_with_errors(z, e, prior)[0], iv))
        below.append({keep[k] for k in _below_others(iv)})
    lead = leaders[0]
    verdict = f"preferred {names[keep[lead]]}" if lead is not None and all(x == lead for x in leaders) else "undecided"
    bottom = sorted(set.intersection(*below)) if len(rows) > 1 else []
    return [n for k, n in enumerate(names) if k not in keep], verdict, [names[k] for k in bottom]


def _among_validated_sentence(saved: list[tuple[str, dict[str, Any]]]) -> str:
    """The sentence of :func:`_among_validated` over a family's seeds ("" when no seed failed an
    emulator)."""
    runs, dropped = [], []
    compared: dict[str, list[str]] = {}
    for _, d in saved:
        seed = (d.get("settings") or {}).get("seed", "?")
        r = _among_validated(d)
        if r is None:
            dropped.append(str(seed))
            continue
        runs.append((seed, r))
        for name in d["model_choice"]["names"]:
            if name not in r[0]:
                compared.setdefault(name, []).append(str(seed))
    if not any(out for _, (out, _, _) in runs):
        return ""
    said = {verdict for _, (_, verdict, _) in runs}
    if len(said) == 1:
        verdicts = f"each of the {len(runs)} seeds says {said.pop()}" if len(runs) > 1 else f"it says {said.pop()}"
    else:
        verdicts = "; ".join(
            f"seed {seed} {verdict}" + (f" (without {', '.join(out)})" if out else "")
            for seed, (out, verdict, _) in runs
        )
    below: dict[str, list[str]] = {}
    for seed, (_, _, bottom) in runs:
        for name in bottom:
            below.setdefault(name, []).append(str(seed))
    return (
        ". Restricted in each seed to the models whose emulators validated (the model prior renormalised over "
        f"them; whether a left-out model would lead is unknown): {verdicts}; below another validated model's "
        "interval in the run and in every narrower box computed from it: "
        + (
            "; ".join(
                (
                    f"{name} in every seed where its emulator validated ({', '.join(k)})"
                    if len(k) == len(compared.get(name, []))
                    else f"{name} in {len(k)} of the {len(compared.get(name, []))} seeds where its emulator "
                    f"validated ({', '.join(k)})"
                )
                for name, k in sorted(below.items())
            )
            if below
            else "no model"
        )
        + (
            f" (not counted: seed{'s' if len(dropped) > 1 else ''} {', '.join(dropped)}, flagged otherwise)"
            if dropped
            else ""
        )
    )


def _failed_models(d: dict[str, Any]) -> str:
    """Which models' emulators failed validation in a run, as a phrase ("" if none)."""
    failed = [m for m, row in d["per_model"].items() if row.get("validated") is False]
    return (
        ", ".join(failed) + ("'s emulator" if len(failed) == 1 else "'s emulators") + " failed validation"
        if failed
        else ""
    )


#: Force-field parameters of a model's box, in the order of its posterior's columns.
_FORCE_FIELD = ("sigma_OO", "epsilon_OO")


def _edge_corner(d: dict[str, Any], model: str, parameter: str) -> str | None:
    """Where a model's posterior mass piled on a force-field bound sits: the other force-field
    parameter's weighted mean there and its box, as factors of the published values, and the
    model's calibrated predictions (posterior predictive medians) beside the measured values."""
    path = RESULTS.parents[1] / d["saved_result"] / f"posterior_{model.replace('/', '_')}.npz"
    if parameter not in _FORCE_FIELD or not path.is_file():
        return None
    import warnings

    import jaxabc

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post = jaxabc.load(path)
    x, w = np.asarray(post.particles, np.float64), np.asarray(post.weights, np.float64)
    low, high = np.asarray(post.prior.low, np.float64), np.asarray(post.prior.high, np.float64)
    j = list(post.names).index(parameter)
    k = 1 - j
    near_low = x[:, j] < low[j] + 0.02 * (high[j] - low[j])
    near = near_low if w[near_low].sum() > 0 else x[:, j] > high[j] - 0.02 * (high[j] - low[j])
    if w[near].sum() <= 0:
        return None
    pub = d["models"][model]["published_lj"]
    other = float(w[near] @ x[near, k] / w[near].sum()) / pub[k]
    text = (
        f"there {post.names[k]} is x{other:.3f} of the published (its box x{low[k] / pub[k]:.3f}-"
        f"x{high[k] / pub[k]:.3f})"
    )
    q = ((d.get("predictive") or {}).get("models") or {}).get(model, {}).get("scalars")
    if q:
        names, observed = d["summaries"]["names"], d["summaries"]["observed"]
        cells = [
            f"{key} {q[2][i]:.4g} (measured {observed[names.index(key)]:.4g})"
            for i, key in enumerate(_PREDICTIVE_SCALARS)
            if key in names
        ]
        text += f", and its calibrated predictions are {', '.join(cells)}"
    return text


def _holdout_family() -> list[str]:
    """The repeats of :data:`HOLDOUT_FAMILY`, each seed with its verdict, its emulators' validation
    and every model's probability interval, and what they say together: the verdict is trusted
    only from seeds whose every emulator validated, and only where those seeds agree."""
    saved = [(name, d) for name in HOLDOUT_FAMILY if (d := load(name)) is not None]
    missing = [name for name in HOLDOUT_FAMILY if load(name) is None]
    if not saved:
        return []
    names = saved[0][1]["model_choice"]["names"]
    without = load(HOLDOUT_NO_DISCREPANCY)

    def row(name: str, d: dict[str, Any], what: str) -> list[str]:
        mc = d["model_choice"]
        intervals = _intervals(mc)
        verdict = d.get("verdict") or {}
        return [
            f"`{name}` ({what})",
            f"{verdict.get('status', '?')} {verdict.get('model') or ''}".strip(),
            ", ".join(_flags(mc["stop_reason"])) or "-",
            _validated(d),
            f"{sum(row['num_simulations'] for row in d['per_model'].values())}",
            *(f"{p:.3g} [{lo:.3g}, {hi:.3g}]" for p, (lo, hi) in zip(mc["probabilities"], intervals, strict=True)),
        ]

    rows = [row(name, d, f"seed {d['settings'].get('seed', '?')}") for name, d in saved]
    trusted = [(name, d) for name, d in saved if not _flags(d["model_choice"]["stop_reason"])]
    if without is not None:
        rows.append(row(HOLDOUT_NO_DISCREPANCY, without, "seed 0, no discrepancy term"))
    for name in PUBLISHED_BOUNDS_FAMILY:
        if (bounded := load(name)) is not None:
            rows.append(row(name, bounded, f"seed {bounded['settings'].get('seed', '?')}, published-model bounds"))
    held = ", ".join(saved[0][1]["summaries"]["held_out"])
    out = [
        "The repeats meant to give the trusted verdict: the emulator's variance calibrated, a budget of 120 "
        f"runs per model, and `r_oo_max2_nm` held out (held out in these runs: {held}), because every lack-of-fit "
        "failure of the earlier repeats is that one summary (below). One run per seed; probability "
        "[interval], each log evidence +- 2 s.e.:\n",
        table(["run", "verdict", "flags", _VALIDATED_HEADER, "GROMACS runs", *names], rows) + "\n",
    ]
    statuses = sorted({_status(d) for _, d in trusted})
    trusted_names = {n for n, _ in trusted}
    untrusted = [f"`{n}`" for n, _ in saved if n not in trusted_names]
    sentence = (
        f"{len(saved)} of {len(HOLDOUT_FAMILY)} seeds run"
        + (f" ({', '.join(missing)} not yet)" if missing else "")
        + f"; {len(trusted)} with every emulator validated and no flag"
        + (f" (flagged: {', '.join(untrusted)})" if untrusted else "")
    )
    low_ess = [
        f"seed {d['settings'].get('seed', '?')} {m} ({e:.0f})"
        for _, d in saved
        for m, post in (d["model_choice"].get("posteriors") or {}).items()
        if (e := post.get("ess")) is not None and e < 100
    ]
    if low_ess:
        # The evidence does not rest on these draws (importance sampling over the box), the
        # posterior summaries do.
        sentence += "; posterior ESS below 100 (its posterior summaries, not its evidence): " + ", ".join(low_ess)
    if not trusted:
        sentence += "; no trusted verdict yet."
    elif len(trusted) == 1:
        sentence += f"; the one trusted seed says {statuses[0]}: one seed is not yet a verdict."
    elif len(statuses) == 1:
        sentence += f"; the {len(trusted)} trusted seeds agree: {statuses[0]}"
        sentence += "." if len(trusted) == len(HOLDOUT_FAMILY) else " (the others: not run or flagged)."
    else:
        sentence += f"; the trusted seeds disagree ({'; '.join(statuses)}): the verdict depends on the seed."
    return [*out, sentence + "\n"]


def _without_discrepancy(d: dict[str, Any] | None) -> list[str]:
    """What seed 0 of the family says without the discrepancy term: whether its emulators
    validated (so its misfits can be believed) and whether any model reproduces the data."""
    if d is None:
        return [f"Without the discrepancy term: `{HOLDOUT_NO_DISCREPANCY}` not run yet.\n"]
    mc = d["model_choice"]
    flags = _flags(mc["stop_reason"])
    misfit, failed, rejected = _rejections(d)
    text = (
        "Without the discrepancy term (seed 0, every other setting equal): "
        + (
            f"the emulator{'s' if len(failed) > 1 else ''} of {', '.join(failed)} failed validation "
            f"({'their misfits are' if len(failed) > 1 else 'its misfit is'} not trustworthy);"
            if failed
            else "every emulator validated;"
        )
        + " the misfit check (chi-square of the observed summaries against each model's emulated posterior "
        "predictive) gives p = " + ", ".join(f"{name} {'-' if p is None else f'{p:.2g}'}" for name, p in misfit.items())
    )
    trusted_rejected = [name for name in rejected if name not in failed]
    if len(rejected) == len(misfit) and not failed:
        text += (
            ": no model reproduces the measured summaries within their stated errors, so without the "
            "discrepancy term the probabilities rank misfits of rejected models"
        )
    elif len(rejected) == len(misfit):
        text += (
            f": every model is rejected at p < 0.01, {len(trusted_rejected)} of them on validated emulators "
            f"({', '.join(trusted_rejected)}), so without the discrepancy term the probabilities rank misfits of "
            "rejected models"
        )
    elif rejected:
        text += f": rejected at p < 0.01: {', '.join(rejected)}"
    else:
        text += ": no model is rejected at p < 0.01"
    verdict = d.get("verdict") or {}
    text += (
        f". Its verdict: {verdict.get('status', '?')} {verdict.get('model') or ''}".rstrip()
        + (f" ({', '.join(flags)})" if flags else "")
        + ".\n"
    )
    return [text]


def _variance_pairs() -> list[str]:
    """Each repeat made with the calibrated emulator variance beside the repeat with every other
    setting equal (seed, budget, boxes, discrepancy) made with the GP's own variance: what the
    calibration changes, like for like."""
    saved = {name: d for name, _ in REPEATS if (d := load(name)) is not None}

    def same_but_variance(a: dict[str, Any], b: dict[str, Any]) -> bool:
        drop = ("emulator_variance", "workers")
        sa, sb = (({k: v for k, v in x["settings"].items() if k not in drop}) for x in (a, b))
        return sa == sb and a["summaries"]["fitted"] == b["summaries"]["fitted"]

    pairs = [
        (gp_name, name)
        for name, d in saved.items()
        if not made_with_gp_variance(d)
        for gp_name, g in saved.items()
        if made_with_gp_variance(g) and same_but_variance(d, g)
    ]
    if not pairs:
        return []
    rows = []
    for gp_name, name in pairs:
        gp, cal = saved[gp_name], saved[name]
        names = cal["model_choice"]["names"]

        def top(d: dict[str, Any], names: list[str] = names) -> str:
            p = d["model_choice"]["probabilities"]
            return f"{names[int(np.argmax(p))]} {max(p):.2f}"

        shift = max(
            abs(a - b)
            for a, b in zip(gp["model_choice"]["probabilities"], cal["model_choice"]["probabilities"], strict=True)
        )
        for label, d in ((f"`{gp_name}`", gp), (f"`{name}`", cal)):
            failed = [m for m, row in d["per_model"].items() if row.get("validated") is False]
            rows.append(
                [
                    label,
                    "calibrated" if d is cal else "GP's own",
                    _validated(d),
                    ", ".join(failed) or "-",
                    f"{(d.get('verdict') or {}).get('status', '?')}",
                    top(d),
                    f"{sum(row['num_simulations'] for row in d['per_model'].values())}",
                    f"{shift:.2f}" if d is cal else "",
                ]
            )
    gp_ok = sum(sum(r.get("validated") is True for r in saved[g]["per_model"].values()) for g, _ in pairs)
    cal_ok = sum(sum(r.get("validated") is True for r in saved[c]["per_model"].values()) for _, c in pairs)
    total = sum(len(saved[c]["per_model"]) for _, c in pairs)
    return [
        "Calibrated against the GP's own emulator variance, like for like (the same seed, budget, boxes and "
        'discrepancy term; `jaxabc.run(emulator_variance="calibrated")` scales the emulator\'s variance by the '
        "factor its held-out runs measure and keeps a second validation's runs to judge the scaled emulator). "
        f"Emulators validated: {gp_ok} of {total} with the GP's variance, {cal_ok} of {total} calibrated, over "
        f"{len(pairs)} pair{'s' if len(pairs) != 1 else ''} (one pair per seed: a count over seeds, not a rate).\n",
        table(
            [
                "run",
                "emulator variance",
                _VALIDATED_HEADER,
                "failed",
                "verdict",
                "most probable",
                "GROMACS runs",
                "largest probability change",
            ],
            rows,
        )
        + "\n",
    ]


def _emulator_failures() -> list[str]:
    """Why emulators of the repeats fail validation (``water_emulator_failures.json``)."""
    d = load("water_emulator_failures")
    if d is None:
        return []
    s, tails = d["summary"], d["summary"]["heldout_tails"]
    st = d["settings"]
    beyond = tails["share_beyond"]
    chance = tails["chance_fail_under_t"]
    reach = s["reach_vs_failure"]
    (rf, rv), (nf, nv) = reach["table_reach_failed_validated"]
    rows = []
    for model, b in d["boundary"].items():
        shares = [
            "-" if x["broken_share"] is None else f"{x['broken_share']:.2f} ({x['runs']})"
            for x in b["by_sigma_at_high_epsilon"]
        ]
        jump = b["jump_near_boundary_in_stated_sd"] or {}
        rows.append(
            [
                model,
                f"{b['broken_runs']} of {b['runs']}",
                *shares,
                ", ".join(f"{k} {v:+.0f}" for k, v in jump.items() if k in ("S7", "S9", "hvap_kj_mol")),
            ]
        )
    edges = d["boundary"][next(iter(d["boundary"]))]["by_sigma_at_high_epsilon"]
    labels = [
        f"sigma/pub {x['sigma_over_published'][0]:g}-{x['sigma_over_published'][1]:g}"
        if x["sigma_over_published"][1] is not None
        else f"sigma/pub >= {x['sigma_over_published'][0]:g}"
        for x in edges
    ]
    shares = [r["posterior_on_break"] + r["posterior_beyond_break"] for run in d["repeats"] for r in run["models"]]
    reach_share = (float(np.median(shares)), float(np.max(shares)))
    checks = ", ".join(f"{k} {v}" for k, v in s["failed_checks"].items())
    worst = ", ".join(f"{k} {v}" for k, v in s["worst_summary_of_failed"].items())
    side_f = ", ".join(f"{k} {v}" for k, v in s["worst_side_of_failed"].items())
    side_v = ", ".join(f"{k} {v}" for k, v in s["worst_side_of_validated"].items())
    return [
        "### Why emulators fail validation\n",
        source("water_emulator_failures", data=d) + " No GROMACS run: it reads the repeats' saved designs.\n",
        f"Over the repeats {s['failed']} of {s['emulators']} emulators failed validation; checks failed: {checks}. "
        f"The summary the worst-predicted held-out run missed most, in the failed ones: {worst}.\n",
        f"The quick-preset liquid has a structural break: where its first g_OO minimum (S5) lies beyond "
        f"{st['broken_s5_nm']} nm the hydrogen-bond network is gone (S5 is bimodal, so this splits two "
        f"structures).  Share of such runs at epsilon >= {st['high_epsilon']} x published, by sigma, and the "
        "jump of S7, D (S9) and hvap across the break next to it, in stated measurement errors:\n",
        table(["model", "broken runs", *labels, "jump (stated sd)"], rows) + "\n",
        f"The break is not what fails the emulators: the posteriors put a median {reach_share[0]:.1%} (at most "
        f"{reach_share[1]:.0%}) of their mass on or beyond it, the worst "
        f"held-out run of a failed emulator lies before it as often as that of a validated one (failed: "
        f"{side_f}; validated: {side_v}), and emulators whose posterior reaches it (more than 5 % on or beyond "
        f"it) fail {rf} of {rf + rv} times against {nf} of {nf + nv} for the others (Fisher p = "
        f"{reach['fisher_p']:.2f}).\n",
        f"What the failures do follow is the tails of the held-out errors.  Pooled over all "
        f"{tails['errors']} standardised errors their sd is "
        f"{min(tails['sd_by_summary'].values()):.2f}-{max(tails['sd_by_summary'].values()):.2f} (1 if right), "
        f"but |e| > 3 in {beyond['3']['observed']:.2%} (normal: {beyond['3']['normal']:.2%}) and |e| > 4 in "
        f"{beyond['4']['observed']:.2%} (normal: {beyond['4']['normal']:.3%}); excess kurtosis "
        f"{min(tails['excess_kurtosis_by_summary'].values()):.1f}-"
        f"{max(tails['excess_kurtosis_by_summary'].values()):.1f} by summary.  A Student t fits them with "
        f"{tails['student_t']['df']:.1f} degrees of freedom; an emulator whose errors followed it, independent, "
        f"would fail the marginal or the targeted check {chance['either']:.0%} of the time by chance "
        f"(checks built for 0.1 % under a normal), against {s['failed'] / s['emulators']:.0%} observed: chance "
        f"under such tails accounts for {chance['either'] / (s['failed'] / s['emulators']):.0%} of the failure "
        "rate.  The designs hold too few replicates (5 at each of 2 sites per emulator) to tell the simulator's "
        "noise from the emulator's error; the noise runs below do.  The Gaussian synthetic likelihood assumes "
        "what the checks assume.\n",
        *(
            [
                f"Run by run, {by_run['with_a_miss']} of {by_run['runs']} held-out runs miss a summary by more than "
                f"{st['miss_sd']:g} sd (independent normal errors: {by_run['with_a_miss_normal']:.0f}) and "
                f"{by_run['with_two_misses']} miss two or more at once (normal: "
                f"{by_run['with_two_misses_normal']:.2f}); "
                f"the 90 % point of a run's rms error is {by_run['rms_quantiles']['0.9']:.2f} (normal: "
                f"{by_run['rms_quantiles_normal']['0.9']:.2f}).  The misses come together: the emulator gets a few "
                "runs' whole summary vectors wrong rather than scattering single misses.\n"
            ]
            if (by_run := tails.get("by_run"))
            else []
        ),
        *_placement(s.get("tails_by_placement")),
        *_inflation(s.get("variance_inflation"), calibrated="calibrated_variance" in s),
        *_calibrated(s.get("calibrated_variance"), s.get("calibrated_verdicts"), s.get("variance_inflation")),
        *_lack_of_fit(s.get("lack_of_fit")),
    ]


def _lack_of_fit(rows: list[dict[str, Any]] | None) -> list[str]:
    """Which summary fails the lack-of-fit check, per failed emulator of every repeat."""
    if not rows:
        return []
    failing = sorted({name for r in rows for name in r["failing"]})
    models = sorted({r["model"] for r in rows})
    table_rows = [
        [
            f"`{r['result']}`",
            r["model"],
            ", ".join(r["failing"]) or "none on refit",
            "; ".join(
                f"{k} {v['noise_over_replicate_variance']:.0f}" for k, v in r["by_summary"].items() if k in r["failing"]
            ),
            "; ".join(
                f"{k} sd {v['replicate_sd']:.2g}, runs {v['runs_5_95'][0]:.3g}-{v['runs_5_95'][1]:.3g}"
                for k, v in r["failing_spread"].items()
            ),
        ]
        for r in rows
    ]
    lo, hi = SECOND_SHELL_WINDOW_NM
    edges = [
        r
        for r in rows
        if (v := r["failing_spread"].get("r_oo_max2_nm"))
        and v["runs_5_95"][0] - lo < 0.01 * (hi - lo) + 0.005
        and hi - v["runs_5_95"][1] < 0.01 * (hi - lo) + 0.005
    ]
    why = (
        [
            f"`r_oo_max2_nm` is the position of the largest smoothed g_OO in the fixed window [{lo:g}, {hi:g}] nm "
            "(`md.water.statistics.SECOND_SHELL_WINDOW_NM`).  Where a model's second shell is nearly flat, as "
            "TIP3P's is, the maximum sits on one edge of the window or the other, and which edge flips with the "
            f"curve's slight tilt: in {len(edges)} of {len(rows)} of these emulators the runs span the window from "
            "edge to edge (5-95 %).  The summary is then discontinuous in the parameters, whatever the number of "
            "runs.  "
            "A continuous locator (the window's g-weighted centroid, say) would remove this failure but change "
            "every water summary and so every model choice here; the held-out family holds the summary out "
            "instead.\n"
        ]
        if edges
        else []
    )
    return [
        f"Lack of fit (the fitted noise far above the replicates' own scatter) failed {len(rows)} emulators over "
        f"the repeats, all of {', '.join(models)}; refitted on each one's runs, the test fails in "
        f"{', '.join(failing) or 'no summary'} alone.  A summary whose value jumps between neighbouring parameters "
        "while replicates agree is one a stationary GP cannot represent, so more runs do not cure it:\n",
        table(
            [
                "repeat",
                "model",
                "summary failing the test",
                "noise / replicate variance",
                "replicate sd; 5-95 % over the runs (summary units)",
            ],
            table_rows,
        )
        + "\n",
        *why,
    ]


def _inflation(rows: list[dict[str, Any]] | None, calibrated: bool = False) -> list[str]:
    """The marginal and targeted checks with the emulator's variance multiplied by a factor."""
    if not rows:
        return []
    base = rows[0]
    calibrated = min(rows, key=lambda r: abs(r["targeted_sd"] - 1.0))
    return [
        f"How much wider would the emulator's error bars have to be?  The same held-out errors over a "
        f"predictive sd with the emulator's variance (not the noise's) multiplied by a factor: the marginal "
        f"and targeted checks then fail {base['either_failed']} of {base['emulators']} emulators at factor 1 "
        f"(the runs' own checks), and {calibrated['either_failed']} at factor {calibrated['factor']:g}, where "
        f"the targeted errors' sd is {calibrated['targeted_sd']:.2f}.  So an emulator variance about "
        f"{calibrated['factor']:g} times the GP's would remove most of these failures; estimating that factor "
        "needs runs other than those that judge it"
        + (
            " (below).\n"
            if calibrated
            else " (a second held-out set, or cross-validation at targeted points), and what it does to the "
            "posteriors is not measured here.\n"
        ),
        table(
            [
                "factor on the emulator variance",
                "marginal check failed",
                "targeted check failed",
                "either",
                "targeted sd",
            ],
            [
                [
                    f"{r['factor']:g}",
                    str(r["marginal_failed"]),
                    str(r["targeted_failed"]),
                    str(r["either_failed"]),
                    f"{r['targeted_sd']:.2f}",
                ]
                for r in rows
            ],
        )
        + "\n",
    ]


def _calibrated(
    cal: dict[str, Any] | None, verdicts: list[dict[str, Any]] | None, inflation: list[dict[str, Any]] | None
) -> list[str]:
    """The library's calibrated emulator variance on these emulators, and what it does to the verdicts."""
    if not cal:
        return []
    q, loo = cal["factor_quantiles"], cal["leave_one_run_out"]
    base = inflation[0]["either_failed"] if inflation else None
    out = [
        'The library\'s `emulator_variance="calibrated"` estimates the factor by maximum likelihood from '
        "held-out runs (`jaxabc.surrogate.emulator.variance_scale_mle`).  From each emulator's held-out runs: "
        f"median {q['0.5']:.2f} (quartiles {q['0.25']:.2f}-{q['0.75']:.2f}, largest {q['1']:.2f}; "
        f"{cal['factor_at_one']} of {len(cal['factors'])} at 1, where the errors are no larger than the GP "
        "says).  Judged on runs it was not estimated from (each held-out run standardised with the factor "
        f"from its emulator's other held-out runs), the errors' sd is {loo['all']['sd']:.2f} "
        f"({loo['targeted']['sd']:.2f} for the targeted runs), {loo['all']['beyond_3']:.2%} lie beyond 3 sd "
        f"and {loo['all']['beyond_4']:.2%} beyond 4 (targeted: {loo['targeted']['beyond_4']:.2%}), and the "
        f"marginal and targeted checks fail {loo['either_failed']} of {loo['emulators']} emulators"
        + (f" (against {base} with the GP's variance).\n" if base is not None else ".\n"),
    ]
    if not verdicts:
        return out
    names = None
    rows = []
    same = changed_top = 0
    shifts = []
    for v in verdicts:
        g, c = v["gp"], v["calibrated"]
        names = names or list(range(len(g["probabilities"])))
        same += (g["preferred"] or "undecided") == (c["preferred"] or "undecided")
        changed_top += g["most_probable"] != c["most_probable"]
        shift = float(np.max(np.abs(v["mean_shift_in_sd"])))
        shifts.append(shift)
        sd = np.asarray(v["sd_ratio"], float)
        rows.append(
            [
                f"`{v['result']}`",
                f"{min(v['factors']):.2g}-{max(v['factors']):.2g}",
                g["preferred"] or "undecided",
                c["preferred"] or "undecided",
                f"{g['most_probable']} {max(g['probabilities']):.3g}",
                f"{c['most_probable']} {max(c['probabilities']):.3g}",
                f"{shift:.2f}",
                f"{sd.min():.2f}-{sd.max():.2f}",
            ]
        )
    n = len(verdicts)
    out += [
        "What the calibrated variance does to the verdict.  Each repeat's emulators refitted on all their "
        "runs (design and held-out, as after a failed validation), once with the GP's variance and once "
        "with the factor their held-out runs measure; the library's evidence (same importance points; the "
        "design's part of its error the run's own jackknife) and the model choice's rule on both.  "
        f"The verdict is the same in {same} of {n} repeats; the most probable model changes in "
        f"{changed_top} of {n}; posterior means of the force-field parameters move by at most "
        f"{max(shifts):.2f} posterior sd.  Not a rerun: the designs are those the GP's variance chose.\n",
        table(
            [
                "repeat",
                "factors",
                "verdict (GP variance)",
                "verdict (calibrated)",
                "most probable (GP)",
                "most probable (calibrated)",
                "largest mean shift (sd)",
                "sd ratio",
            ],
            rows,
        )
        + "\n",
    ]
    return out


def _placement(t: dict[str, Any] | None) -> list[str]:
    """Where the held-out tails sit: by placement and by the emulator's own variance."""
    if not t:
        return []
    normal = t["normal"]

    def cells(b: dict[str, Any]) -> list[str]:
        return [str(b["n"]), f"{b['sd']:.2f}", f"{b['beyond_3']:.2%}", f"{b['beyond_4']:.2%}"]

    rows = [
        ["design runs, leave-one-out", *cells(t["design_loo"])],
        ["held out, placed at random", *cells(t["held_out_random"])],
        ["held out, targeted (where the emulator is least sure)", *cells(t["held_out_targeted"])],
    ]
    rows += [
        [f"held out, emulator / noise variance {b['ratio_low']:.2g}-{b['ratio_high']:.2g}", *cells(b)]
        for b in t["by_ratio"]
    ]
    low, high = t["by_ratio"][0], t["by_ratio"][-1]
    return [
        f"Where the tails sit.  Each emulator refitted as at its last validation (the library's fit on the "
        f"saved design; it reproduces the saved held-out errors of {t['reproduced_emulators']} emulators to "
        f"{t['reproduced_max_abs']:.0e}): the design runs' own leave-one-out errors and the held-out runs placed "
        f"at random have much lighter tails ({t['design_loo']['beyond_4']:.2%} and "
        f"{t['held_out_random']['beyond_4']:.2%} beyond 4 sd); the tails are in the targeted runs "
        f"({t['held_out_targeted']['beyond_4']:.2%}) and grow "
        f"with the emulator's own variance at the run, from {low['beyond_4']:.2%} beyond 4 sd where it is small "
        f"against the noise to {high['beyond_4']:.2%} where it dominates (normal: {normal['beyond_4']:.4%}).  "
        "Where the emulator is unsure, its error bars are too narrow: the stationary squared-exponential GP with "
        "type-II maximum-likelihood hyper-parameters understates its error away from the design, which is "
        "where the targeted check looks.\n",
        table(["errors", "n", "sd (1 if right)", f"beyond 3 sd (normal {normal['beyond_3']:.2%})", "beyond 4 sd"], rows)
        + "\n",
    ]


def _summary_noise() -> list[str]:
    """Is the simulator's noise Gaussian at the posterior estimates (``water_summary_noise.json``)?"""
    d = load("water_summary_noise")
    if d is None:
        return []
    null = d["pooled_null_excess_kurtosis_95"]
    failures = load("water_emulator_failures")
    held = (failures or {}).get("summary", {}).get("heldout_tails", {}).get("excess_kurtosis_by_summary") or {}
    rows, heavy = [], []
    for name in d["fitted"]:
        m = d["pooled"][name]
        lo, hi = m["excess_kurtosis_95"]
        shapiro = sum(
            1
            for entry in d["models"].values()
            if entry.get("summaries") and entry["summaries"][name]["shapiro_p"] < 0.01
        )
        if lo > null[1]:
            heavy.append(name)
        rows.append(
            [
                name,
                f"{m['excess_kurtosis']:+.2f} [{lo:+.2f}, {hi:+.2f}]",
                f"{m['skewness']:+.2f}",
                f"{m['share_beyond_3sd']:.1%}",
                f"{shapiro} of {len(d['models'])}",
                f"{held[name]:+.2f}" if name in held else "-",
            ]
        )
    runs = sum(e["num_runs"] for e in d["models"].values())
    failed = sum(len(e["failures"]) for e in d["models"].values())
    verdict = (
        f"The noise itself is heavier-tailed than normal for {', '.join(heavy)} (the interval's lower end "
        f"above the normal's {null[1]:+.2f}); for the others it is consistent with normal noise, so their "
        "held-out tails are the emulator's error."
        if heavy
        else "No summary's noise is heavier-tailed than normal (every interval's lower end is below the "
        f"upper end of normal noise's, {null[1]:+.2f}), so the held-out errors' heavy tails are the emulator's "
        "error, not the simulator's."
    ) + (
        "  (The noise was measured at one point per model, its posterior estimate; near the network break "
        "a run can land on either structure, which no Gaussian noise model describes.)"
    )
    return [
        "### Is the simulator's noise Gaussian?\n",
        source("water_summary_noise", data=d) + "\n",
        f"{d['runs_per_model']} runs with independent keys per model at its posterior Bayes estimate in "
        f"`{d['model_choice']}` ({runs} runs, {failed} failed), on the model choice's protocol.  Each "
        "model's runs standardised by their own mean and sd, then pooled; excess kurtosis with a bootstrap "
        f"95 % interval (normal noise, standardised the same way: [{null[0]:+.2f}, {null[1]:+.2f}]), "
        "beside the held-out errors' excess kurtosis:\n",
        table(
            [
                "summary",
                "noise excess kurtosis [95 %]",
                "skewness",
                "beyond 3 sd (normal 0.27 %)",
                "models with Shapiro-Wilk p < 0.01",
                "held-out errors' excess kurtosis",
            ],
            rows,
        )
        + "\n",
        verdict + "\n",
    ]


def _box_sensitivity() -> list[str]:
    """Which prior moves the probabilities (``water_box_sensitivity.json``)."""
    d = load("water_box_sensitivity")
    if d is None:
        return []
    # The published-bounds family has its own sentence below: its bounds are a different prior.
    repeats = [r for r in d["repeats"] if not r.get("published_bounds_family")]
    names = repeats[0]["names"]
    moves = d["log_evidence_change_abs"]
    rows = []
    for model in names:
        cells = []
        for kind in ("parameters", "discrepancy"):
            change = [
                r["log_evidence_change"]
                for rep in repeats
                for r in rep["rows"]
                if r["model"] == model and r["kind"] == kind
            ]
            cells.append(f"{np.median(change):+.2f} [{min(change):+.2f}, {max(change):+.2f}]")
        shares = {}
        for rep in repeats:
            for col, v in rep["discrepancy_upper_half_share"][model].items():
                shares.setdefault(col.removeprefix("discrepancy_sd[").rstrip("]"), []).append(v)
        first = repeats[0]
        p0 = first["probabilities"][names.index(model)]
        halved = {r["kind"]: r["probability"] for r in first["rows"] if r["model"] == model}
        rows.append(
            [
                model,
                f"{p0:.2f} -> {halved.get('parameters', np.nan):.2f} / {halved.get('discrepancy', np.nan):.2f}",
                *cells,
                ", ".join(f"{g} {np.median(v):.2f}" for g, v in shares.items()),
            ]
        )
    choice = (load("water_model_choice") or {}).get("model_choice", {})
    groups = (choice.get("metadata", {}).get("discrepancy") or {}).get("groups", {})
    sizes = {g: f"{len(idx)} summar{'y' if len(idx) == 1 else 'ies'}" for g, idx in groups.items()}
    unidentified = sorted(
        {
            col.removeprefix("discrepancy_sd[").rstrip("]")
            for rep in repeats
            for model_shares in rep["discrepancy_upper_half_share"].values()
            for col, v in model_shares.items()
            if v >= 0.25
        }
    )
    named = [f"{g} (a group of {sizes.get(g, '?')})" for g in unidentified]
    return [
        "### Which prior moves the probabilities\n",
        source("water_box_sensitivity", data=d) + " No GROMACS run: every box is inside the run's.\n",
        f"Each model's force-field box (sigma, epsilon) and its discrepancy bounds halved apart "
        f"(`sensitivity(split_discrepancy=True)`), over the {len(repeats)} runs with the discrepancy "
        f"term ({sum(bool(r.get('family')) for r in repeats)} of them from the held-out family).  Halving a "
        "model's discrepancy bounds moves its log evidence by a median "
        f"{moves['discrepancy']['median']:.2f} (at most {moves['discrepancy']['max']:.2f}); halving its "
        f"force-field box by a median {moves['parameters']['median']:.2f} (at most "
        f"{moves['parameters']['max']:.2f}).  The discrepancy sds the data bound from below only (a "
        f"posterior share of 0.25 or more in the upper half of the range, 0.5 for a flat one): "
        f"{', '.join(named) or 'none'}.  A "
        "verdict between these models rests on the bounds chosen for those sds more than on the "
        "force-field boxes; a bound on them from outside the fit (or a model choice without them) is what "
        "could change it." + _bounded_moves(d) + "\n",
        table(
            [
                "model",
                f"probability in `{repeats[0]['result']}` -> parameters x0.5 / discrepancy x0.5",
                "log evidence change, parameters x0.5 (median [range] over repeats)",
                "log evidence change, discrepancy x0.5",
                "discrepancy sd's share in the upper half (median)",
            ],
            rows,
        )
        + "\n",
        *_published_bounds(d),
    ]


def _bounded_moves(d: dict[str, Any]) -> str:
    """The same split over the published-bounds family (its runs' own prior), or ""."""
    moves = d.get("published_bounds_family_log_evidence_change_abs")
    runs = [r for r in d["repeats"] if r.get("published_bounds_family")]
    if not moves or not runs:
        return ""
    loose: dict[str, set[str]] = {}
    for r in runs:
        for model, model_shares in r["discrepancy_upper_half_share"].items():
            for col, v in model_shares.items():
                if v >= 0.25:
                    loose.setdefault(col.removeprefix("discrepancy_sd[").rstrip("]"), set()).add(model)
    models = len(runs[0]["names"])
    groups = [
        f"{g} ({len(who)} of {models} models" + (f": {', '.join(sorted(who))})" if len(who) < models else ")")
        for g, who in sorted(loose.items(), key=lambda item: -len(item[1]))
    ]
    return (
        f"  In the {len(runs)} runs made with the published-model bounds as the prior (not in the table), "
        f"halving the discrepancy bounds moves a log evidence by a median {moves['discrepancy']['median']:.2f} "
        f"(at most {moves['discrepancy']['max']:.2f}), halving the force-field box by "
        f"{moves['parameters']['median']:.2f} (at most {moves['parameters']['max']:.2f}); discrepancy sds the "
        f"data bound from below only there (in any run): {', '.join(groups) or 'none'}."
    )


def _published_bounds_sentence(d: dict[str, Any]) -> str:
    """One sentence: the verdicts and the least probable model under the published-model bounds
    (all groups x1), over the repeats."""
    variants = [
        v
        for r in d["repeats"]
        for v in (r.get("published_model_bounds") or {}).get("variants", [])
        if v["groups"] == "all" and v["factor"] == 1.0
    ]
    if not variants:
        return ""
    least = [v["least"] for v in variants]
    common = max(set(least), key=least.count)
    undecided = sum(v["verdict"] == "undecided" for v in variants)
    return (
        f" With every discrepancy bound set from the published models' misfits (below), {undecided} of "
        f"{len(variants)} runs stay undecided and {common} is the least probable in {least.count(common)} "
        f"of {len(variants)}."
    )


def _published_bounds(d: dict[str, Any]) -> list[str]:
    """The model probabilities under discrepancy bounds set from the published models' misfits
    (``published_model_bounds`` of ``water_box_sensitivity.json``)."""
    repeats = [r for r in d["repeats"] if r.get("published_model_bounds")]
    if not repeats:
        return []
    names = repeats[0]["names"]
    first = repeats[0]["published_model_bounds"]
    run_bounds = dict(zip(first["bounds"], first["run_bounds"], strict=True))
    groups = list(first["bounds"])
    bound_text = ", ".join(f"{g} {first['bounds'][g]:.3g} (run: {run_bounds[g]:g})" for g in groups)
    by_label: dict[str, list[dict[str, Any]]] = {}
    for rep in repeats:
        for v in rep["published_model_bounds"]["variants"]:
            label = f"all groups x{v['factor']:g}" if v["groups"] == "all" else f"{v['groups']} alone x{v['factor']:g}"
            by_label.setdefault(label, []).append(v)
    rows = []
    for label, variants in by_label.items():
        p = np.array([v["probabilities"] for v in variants])
        cells = [f"{np.median(p[:, k]):.2f} [{p[:, k].min():.2f}, {p[:, k].max():.2f}]" for k in range(len(names))]
        least = [v["least"] for v in variants]
        decided = [v["verdict"] for v in variants if v["verdict"] != "undecided"]
        rows.append(
            [
                label,
                *cells,
                ", ".join(f"{m} {least.count(m)}" for m in names if least.count(m)),
                f"{len(variants) - len(decided)} of {len(variants)} undecided"
                + (f" ({'; '.join(decided)})" if decided else ""),
            ]
        )
    cut = {
        m: [rep["published_model_bounds"]["variants"][len(groups)]["posterior_share_cut"][m] for rep in repeats]
        for m in names
    }
    prior_cut = ", ".join(
        f"{g} {1 - first['bounds'][g] / run_bounds[g]:.2f}" for g in ("D", "hvap") if g in first["bounds"]
    )
    cut_text = "; ".join(
        f"{m} " + ", ".join(f"{g} {np.median([c[g] for c in cut[m]]):.2f}" for g in ("D", "hvap") if g in cut[m][0])
        for m in names
    )
    return [
        "#### Discrepancy bounds from the published models\n",
        "A bound on the discrepancy sds from outside the fit: each group's `max_sd` set to the largest "
        "misfit a published rigid model makes in that group at its own parameters, in the same protocol "
        f"and against the same data (`{d.get('published_result')}`): {bound_text}.  It says that a "
        "model's systematic error is no worse than the worst published model's; it uses the measured "
        "values but no fit.  Each model's evidence is recomputed from its run (every bound is inside the "
        "run's), the verdict by the library's rule.  Median [range] of each probability over the "
        f"{len(repeats)} repeats:\n",
        table(["bounds", *names, "least probable (repeats)", "verdict"], rows),
        "\nThe D and hvap sds are not identified (one summary each), so the bound cuts their posterior "
        f"about as it cuts their prior ({prior_cut} of it lies above the bound); the median share of the "
        f"posterior above the bound, all groups x1: {cut_text}.  A share above the prior's means the model's "
        "posterior leans to a larger discrepancy there.\n",
    ]


_VALIDATED_HEADER = "emulators validated (runs per model); emulator variance factor; ESS < 100"


def _validated(d: dict[str, Any]) -> str:
    """How many of a model choice's emulators passed validation, its budget per model, the
    factor on any emulator's variance (:func:`_variance_factors`), and any posterior resting on
    an effective sample size below 100."""
    flags = [row.get("validated") for row in d.get("per_model", {}).values()]
    budget = (d.get("settings") or {}).get("budget_per_model")
    ess = {name: post.get("ess") for name, post in (d["model_choice"].get("posteriors") or {}).items()}
    low = {name: e for name, e in ess.items() if e is not None and e < 100}
    return (
        f"{sum(v is True for v in flags)} of {len(flags)}"
        + (f" ({budget})" if budget else "")
        + "".join(f"; {name} variance x{c:.3g}" for name, c in _variance_factors(d).items())
        + "".join(f"; {name} ESS {e:.0f}" for name, e in low.items())
    )


def _variance_factors(d: dict[str, Any]) -> dict[str, float]:
    """The factor on the emulator's variance each model's last fit used, where it is not 1
    (runs with ``emulator_variance`` other than the GP's own; read from the saved posteriors)."""
    if made_with_gp_variance(d):
        return {}
    out = {}
    for name in d["model_choice"]["names"]:
        path = RESULTS.parents[1] / d["saved_result"] / f"posterior_{name.replace('/', '_')}.npz"
        if not path.is_file():
            continue
        with np.load(path) as z:
            c = json.loads(str(z["metadata"])).get("diagnostics", {}).get("emulator_variance_scale")
        if c is not None and c != 1.0:
            out[name] = float(c)
    return out


def _repeat_edges(saved: list[tuple[str, str, dict[str, Any]]]) -> list[str]:
    """Posteriors piled on a bound of a box (not a physical limit) in any repeat, with whether
    that model's emulator validated: the prior-edge statement must hold in every run."""
    piled = []
    for name, _, d in saved:
        for model, edge in (d.get("prior_edge") or {}).items():
            validated = (d.get("per_model", {}).get(model) or {}).get("validated")
            piled += [
                f"`{name}` {model}: {msg}" + ("" if validated is not False else " (its emulator failed validation)")
                for msg in edge.get("messages") or []
            ]
    if not piled:
        return [f"Prior edges in the repeats: no posterior piles on a bound of its box in any of the {len(saved)}.\n"]
    return ["Prior edges in the repeats: " + "; ".join(piled) + ".\n"]


def _misspecified_sentence(saved: list[tuple[str, str, dict[str, Any]]]) -> list[str]:
    """Which repeats are MISSPECIFIED (their probabilities rank misfits), and which are not."""
    mis = [f"`{name}`" for name, _, d in saved if "MISSPECIFIED" in _flags(d["model_choice"]["stop_reason"])]
    if not mis:
        return []
    ok = [f"`{name}`" for name, _, d in saved if f"`{name}`" not in mis]
    return [
        f"MISSPECIFIED (no model reproduces the data within the noise, misfit p < 0.01 for every model, so the "
        f"probabilities rank misfits): {', '.join(mis)}" + (f"; not in {', '.join(ok)}" if ok else "") + ".\n"
    ]


def _flags(stop_reason: str) -> list[str]:
    """The upper-case flags a model choice's stop reason starts its sentences with (UNTRUSTED, ...)."""
    return re.findall(r"\b([A-Z]{5,}):", stop_reason)


def _published() -> list[str]:
    """Each model at its published parameters on the same protocol (water_published_predictive.json)."""
    p = load("water_published_predictive")
    if p is None:
        return []
    names = [n for n, fit in zip(p["summary_names"], p["fitted"], strict=True) if fit]
    index = [p["summary_names"].index(n) for n in names]
    rows = [["measured", *(f"{p['observed'][i]:.4g} +- {p['stated_errors'][i]:.2g}" for i in index), "-"]]
    for name, m in p["models"].items():
        if "mean" not in m:
            rows.append([name, *("-" for _ in index), f"0 ({len(m['failures'])} failed)"])
            continue
        z = ["-" if v is None else f"{v:+.1f}" for v in m["z"]]
        cells = [f"{m['mean'][i]:.4g} ({z[i]})" for i in index]
        rows.append([name, *cells, f"{m['num_runs']} ({len(m['failures'])} failed)"])
    return [
        f"Each model at its published parameters, same protocol ({p['temperature_k']} K), mean over "
        f"{p['runs_per_model']} runs (z: (mean - measured) / sqrt(stated error^2 + the mean's squared standard "
        "error over the runs)):\n",
        table(["model", *names, "runs"], rows) + "\n",
        source("water_published_predictive", data=p) + "\n",
    ]


def _decided(row: dict[str, Any], names: list[str]) -> str | None:
    """The model a computed sensitivity row would call preferred (the library's
    :func:`jaxabc.model_choice.interval_leader`, the first step of ``verdict``), else None."""
    k = interval_leader(np.asarray(row["probabilities"], float), np.asarray(row["intervals"], float))
    return None if k is None else names[k]


def _what_would_change(d: dict[str, Any], names: list[str], rows: list[dict[str, Any]]) -> str:
    """Which computed box changes would turn the verdict, and which leave it as it is."""
    verdict = d.get("verdict") or {}
    base = verdict.get("model") if verdict.get("status") == "preferred" else None
    computed = [r for r in rows if np.all(np.isfinite(np.asarray(r["probabilities"], float)))]
    turned, kept, one_box = [], [], False
    for r in computed:
        now = _decided(r, names)
        if now == base:
            kept.append(r["label"])
            continue
        k = names.index(now) if now else int(np.argmax(r["probabilities"]))
        lo, hi = r["intervals"][k]
        what = f"{now} preferred" if now else "undecided"
        turned.append(f"{r['label']} gives {what} ({r['probabilities'][k]:.2f} [{lo:.2f}, {hi:.2f}])")
        one_box |= r["label"].split(" box ")[0] in names
    text = "What would change the verdict: " + ("; ".join(turned) or "no computed box change") + "."
    if kept:
        text += f" Unchanged with {', '.join(kept)}."
    if one_box:
        text += (
            " Narrowing one model's box alone turns it: the ranking follows the widths of the prior boxes "
            "(each model's Occam factor) as much as the data."
        )
        split = load("water_box_sensitivity")
        if split is not None:
            moves = split["log_evidence_change_abs"]
            text += (
                f" Split apart (below), halving a model's discrepancy bounds moves its log evidence by a median "
                f"{moves['discrepancy']['median']:.2f}, halving its force-field box by "
                f"{moves['parameters']['median']:.2f}."
            )
            text += _published_bounds_sentence(split)
    wider = [r["label"] for r in rows if r not in computed]
    if wider:
        text += f" Not computed from this run (they need simulations in the wider boxes): {', '.join(wider)}."
    return text + "\n"


#: The model choice run again with every sigma box doubled: the wider rows, computed.
WIDER_RUN = "water_model_choice_sigma_x2"


def _wider_rows(d: dict[str, Any], wide: dict[str, Any]) -> list[tuple[str, int | None, Any, Any, list[str]]]:
    """The doubled-sigma-box rows of run ``d`` from a second run ``wide`` with every sigma box
    doubled (same seed, data and budget): ``(label, preferred index or None, probabilities,
    intervals, doubled models whose emulator failed)``.  One model's doubled box takes that
    model's evidence from the second run and the others' from ``d`` (each evidence is a
    separate calibration); all doubled is the second run itself."""
    names = list(d["model_choice"]["names"])
    base, other = d["model_choice"], wide["model_choice"]
    prior = np.asarray(base["model_prior"], float)
    cases = [(f"{n} sigma box x2", [k]) for k, n in enumerate(names)] + [
        ("all sigma boxes x2", list(range(len(names))))
    ]
    rows = []
    for label, changed in cases:
        log_z = np.asarray(base["log_evidence"], float).copy()
        se = np.asarray(base["log_evidence_errors"], float).copy()
        log_z[changed] = np.asarray(other["log_evidence"], float)[changed]
        se[changed] = np.asarray(other["log_evidence_errors"], float)[changed]
        probs, _ = probabilities_with_errors(log_z, se, prior)
        intervals = probability_bounds(log_z, se, prior)
        unvalidated = [names[j] for j in changed if wide["per_model"][names[j]].get("validated") is False]
        rows.append((label, interval_leader(probs, intervals), probs, intervals, unvalidated))
    return rows


def _wider_boxes(d: dict[str, Any], name: str) -> list[str]:
    """The wider-box rows the run cannot give, from a second run with every sigma box doubled
    (:func:`_wider_rows`), as a table and whether one turns the verdict."""
    wide = load(name)
    if wide is None:
        return [f"Wider sigma boxes: `{name}` not run yet.\n"]
    names = list(d["model_choice"]["names"])
    if list(wide["model_choice"]["names"]) != names:
        return [f"Wider sigma boxes: `{name}` compares other models ({wide['model_choice']['names']}).\n"]
    body, turned = [], []
    for label, k, probs, intervals, unvalidated in _wider_rows(d, wide):
        status = ("undecided" if k is None else f"{names[k]} preferred") + (
            f" ({', '.join(unvalidated)} not validated)" if unvalidated else ""
        )
        body.append(
            [label, status, *(f"{p:.3g} [{lo:.3g}, {hi:.3g}]" for p, (lo, hi) in zip(probs, intervals, strict=True))]
        )
        if k is not None:
            turned.append(f"{label} ({names[k]})")
    sigma = ", ".join(f"{n} x[{b[0][0]:.3g}, {b[1][0]:.3g}]" for n in names if (b := _box_factors(wide, n)) is not None)
    seed = (d.get("settings") or {}).get("seed", "?")
    return [
        f"Wider boxes, computed (`{name}`: seed {seed} again with every sigma box doubled about its centre"
        + (f", {sigma} of the published sigma" if sigma else "")
        + "; epsilon keeps its box: doubled about its centre its low end would be negative, and below x0.45 of "
        "the published epsilon the quick box is no longer liquid at the published sigma, `water_prior_range_low`). "
        "One model's row takes its evidence from that run and the others' from this one:\n",
        table(["boxes", "verdict", *names], body) + "\n",
        (
            "A doubled sigma box turns the verdict: " + "; ".join(turned) + ".\n"
            if turned
            else "No doubled sigma box turns the verdict.\n"
        ),
    ]


def _published_doubled() -> str:
    """:func:`_doubled_sentence` for the published-bounds family's run with doubled sigma boxes, or
    that it is not run yet."""
    base = load(PUBLISHED_WIDER_BASE) if PUBLISHED_WIDER_BASE else None
    if base is None:
        return ""
    wide = load(PUBLISHED_BOUNDS_WIDER[0])
    if wide is None:
        return f". Doubled sigma boxes: `{PUBLISHED_BOUNDS_WIDER[0]}` not run yet"
    return _doubled_sentence(base, PUBLISHED_BOUNDS_WIDER[0], wide) or (
        f". Doubled sigma boxes: `{PUBLISHED_BOUNDS_WIDER[0]}` compares other models"
    )


def _published_wider() -> list[str]:
    """The page's section on the published-bounds family's trusted seed in doubled sigma boxes."""
    base = load(PUBLISHED_WIDER_BASE) if PUBLISHED_WIDER_BASE else None
    if base is None:
        return []
    return [
        "### The published-bounds family in wider boxes\n",
        f"`{PUBLISHED_WIDER_BASE}` (probabilities "
        + ", ".join(
            f"{n} {p:.3g}"
            for n, p in zip(base["model_choice"]["names"], base["model_choice"]["probabilities"], strict=True)
        )
        + "; its halved boxes are in its sensitivity table).\n",
        *_wider_boxes(base, PUBLISHED_BOUNDS_WIDER[0]),
    ]


def _doubled_sentence(d: dict[str, Any], name: str, wide: dict[str, Any] | None = None) -> str:
    """One sentence on a run's doubled sigma boxes (:func:`_wider_rows`): the verdicts, and the
    models below another model's interval in every doubled row ("" when ``name`` is not saved or
    compares other models).  ``wide``: the run ``name`` when already loaded."""
    wide = load(name) if wide is None else wide
    if wide is None or list(wide["model_choice"]["names"]) != list(d["model_choice"]["names"]):
        return ""
    names = list(d["model_choice"]["names"])
    rows = _wider_rows(d, wide)
    said = [
        ("undecided" if k is None else f"{names[k]} preferred")
        + (" (from a failed emulator)" if k is not None and names[k] in unvalidated else "")
        for _, k, _, _, unvalidated in rows
    ]
    below = [names[k] for k in sorted(set.intersection(*(_below_others(iv) for _, _, _, iv, _ in rows)))]
    failed = sorted({m for *_, unvalidated in rows for m in unvalidated})
    verdicts = sorted(set(said))
    seed = (d.get("settings") or {}).get("seed", "?")
    head = f". With the sigma boxes doubled (seed {seed} again, `{name}`; each model's box alone, then all"
    return (
        f"{head}): {len(rows)} of {len(rows)} rows say {verdicts[0]}"
        if len(verdicts) == 1
        else f"{head}): " + "; ".join(f"{label} {v}" for (label, *_), v in zip(rows, said, strict=True))
    ) + (
        f", below another model's interval in every doubled row: {', '.join(below) if below else 'no model'}"
        + (
            f" (the emulator{'s' if len(failed) > 1 else ''} of {', '.join(failed)} failed in the wider run)"
            if failed
            else ""
        )
    )


def _missed_groups(d: dict[str, Any]) -> dict[str, list[str]]:
    """``{group: models that do not reproduce it}`` of a model choice with the discrepancy term.

    A group is "not reproduced" by a model when its discrepancy sd's 2.5 % point lies outside the
    2 % band above 0 (the prior-edge band): the data exclude a zero discrepancy there.
    """
    disc = (d.get("settings") or {}).get("discrepancy")
    if not disc:
        return {}
    groups = list(disc["groups"])
    return {
        g: [
            name
            for name, row in d["per_model"].items()
            if row["credible_interval_95"][len(row["bayes_estimate"]) - len(groups) + j][0] > 0.02 * disc["max_sd"][j]
        ]
        for j, g in enumerate(groups)
    }


def _over_repeats(groups: list[str]) -> str:
    """In how many of the saved repeats with the discrepancy term no model reproduces each of
    ``groups``: a statement of one run holds only if it holds in each."""
    runs = [d for name, _ in REPEATS if (d := load(name)) is not None and _missed_groups(d)]
    if len(runs) < 2:
        return ""
    counts = [sum(len(_missed_groups(d).get(g, [])) == len(d["per_model"]) for d in runs) for g in groups]
    return "; over the repeats with the discrepancy term: " + ", ".join(
        f"{g} in {k} of {len(runs)}" for g, k in zip(groups, counts, strict=True)
    )


def _verdict(d: dict[str, Any]) -> list[str]:
    """The verdict sentence, the box-sensitivity table, the discrepancy posteriors and the prior
    edges, where the JSON has them (results from before they existed have not)."""
    out = []
    v = d.get("verdict")
    if v:
        who = f" {v['model']}" if v.get("model") else ""
        reason = v["reason"][:1].upper() + v["reason"][1:]
        out.append(f"**Verdict: {v['status']}{who}.** {reason}.\n")
    rows = d.get("sensitivity") or []
    if rows:
        names = list(d["per_model"])
        body = []
        for r in rows:
            cells = [
                "-" if p != p else f"{p:.3g} [{lo:.3g}, {hi:.3g}]"
                for p, (lo, hi) in zip(r["probabilities"], r["intervals"], strict=True)
            ]
            body.append([r["label"], r["status"], *cells])
        out += [
            "How the probabilities move with the prior boxes (each box scaled about its centre; a "
            "narrower box from the run itself, a wider one needs simulations there and is not "
            "extrapolated; probability [interval], each log evidence +- 2 s.e.):\n",
            table(["boxes", "status", *names], body) + "\n",
            _what_would_change(d, names, rows),
            *_wider_boxes(d, WIDER_RUN),
        ]
    disc = (d.get("settings") or {}).get("discrepancy")
    if disc:
        groups = list(disc["groups"])
        body = []
        for name, row in d["per_model"].items():
            est, ci = row["bayes_estimate"], row["credible_interval_95"]
            k = len(est) - len(groups)
            body.append(
                [name, *(f"{est[k + j]:.3g} [{ci[k + j][0]:.3g}, {ci[k + j][1]:.3g}]" for j in range(len(groups)))]
            )
        missed = _missed_groups(d)
        everyone = [g for g, names in missed.items() if len(names) == len(d["per_model"])]
        out.append(
            (
                "In this run no model reproduces "
                + ", ".join(everyone)
                + " within the measurement error (every model's discrepancy "
                "sd's 2.5 % point lies above 2 % of its bound)" + _over_repeats(everyone) + ". "
                if everyone
                else "Every group is reproduced by at least one model. "
            )
            + "; ".join(f"{g}: missed by {', '.join(n)}" for g, n in missed.items() if n and g not in everyone)
            + (". " if any(n and g not in everyone for g, n in missed.items()) else "")
            + "\n"
        )
        out += [
            "Model discrepancy: each group's extra standard deviation (summary units), posterior mean "
            "[95 % interval], uniform prior on [0, max_sd] with max_sd "
            + ", ".join(f"{g} {m:g}" for g, m in zip(groups, disc["max_sd"], strict=True))
            + ". A group clearly above 0 is one the model does not reproduce within the measurement error.\n",
            table(["model", *groups], body) + "\n",
        ]
    edges = d.get("prior_edge") or {}
    piled = [f"{m}: {'; '.join(e['messages'])}" for m, e in edges.items() if e.get("messages")]
    limits = [f"{m}: {'; '.join(e['at_physical_limits'])}" for m, e in edges.items() if e.get("at_physical_limits")]
    if edges:
        out.append(
            "Prior edges: "
            + ("; ".join(piled) if piled else "no posterior piles against a bound of its box (under 5 % within 2 %)")
            + (". At a physical limit: " + "; ".join(limits) if limits else "")
            + ".\n"
        )
        at_low = [m for m, e in edges.items() if any("epsilon" in msg and "lower" in msg for msg in e["messages"])]
        below = _below_box(d, at_low)
        if below:
            out.append(below + "\n")
    return out


def _box_factors(d: dict[str, Any], model: str) -> tuple[list[float], list[float]] | None:
    """A model's prior box (low, high) as factors of its published (sigma, epsilon); None if not saved."""
    row = d.get("models", {}).get(model, {})
    if not all(k in row for k in ("prior_low", "prior_high", "published_lj")):
        return None
    lo = [low / p for low, p in zip(row["prior_low"], row["published_lj"], strict=True)]
    hi = [high / p for high, p in zip(row["prior_high"], row["published_lj"], strict=True)]
    return lo, hi


def _epsilon_edge(d: dict[str, Any], model: str) -> float | None:
    """A model's epsilon lower bound as a factor of its published value (None if not saved)."""
    box = _box_factors(d, model)
    return None if box is None else round(box[0][1], 3)


def _below_box(d: dict[str, Any], piled: list[str]) -> str:
    """What the liquid does below epsilon's lower bound (``water_prior_range_low``), for the
    models whose epsilon piles there: whether the bound stands at a physical limit."""
    low = load("water_prior_range_low")
    if not piled or low is None:
        return ""
    lo, hi = low["liquid_density_kg_m3"]
    base = load("water_prior_range")
    scans = low["scan"] + ((base or {}).get("scan") or [])
    edges = {m: _epsilon_edge(d, m) for m in piled}
    parts, at_edge, liquid_below = [], [], False
    for model in piled:
        edge = edges[model]
        runs_of = [r for r in scans if r["model"] == model]
        at = [r["density_kg_m3"] for r in runs_of if r["epsilon_factor"] == edge and r["status"] == "ok"]
        if at:
            at_edge.append(f"{model} {np.mean(at):.0f} kg/m3 at x{edge:g}")
        points = []
        for factor in sorted(
            {r["epsilon_factor"] for r in runs_of if edge is None or r["epsilon_factor"] < edge}, reverse=True
        ):
            runs = [r for r in runs_of if r["epsilon_factor"] == factor]
            dense = [r["density_kg_m3"] for r in runs if r["status"] == "ok"]
            liquid_below |= any(r["liquid"] for r in runs)
            if dense and not any(r["liquid"] for r in runs):
                points.append(f"x{factor:g} {min(dense):.0f}-{max(dense):.0f} kg/m3")
            elif dense:
                points.append(f"x{factor:g} liquid water ({min(dense):.0f}-{max(dense):.0f} kg/m3)")
            else:
                why = runs[0].get("reason", "failed").split(": ", 1)[-1]
                points.append(f"x{factor:g} {why}")
        parts.append(f"{model} (box from x{edge:g}): " + (", ".join(points) or "no run below the box"))
    corr = [
        f"{m} {d['per_model'][m]['correlation']:+.2f}"
        for m in piled
        if isinstance(d.get("per_model", {}).get(m, {}).get("correlation"), float)
    ]
    if liquid_below:
        verdict = "the liquid holds below the bound, so the box should be widened and the model choice rerun"
    else:
        verdict = (
            f"at the published sigma none of the runs below the box is liquid water by the scan's criterion "
            f"(density in [{lo:g}, {hi:g}] kg/m3, against 997 measured).  But the posterior trades epsilon for "
            "sigma (correlation "
            + (", ".join(corr) or "not saved")
            + "): along that ridge, with sigma up to its +5 % bound, the liquid may hold lower, so the scan does "
            "not make the bound a physical limit for the calibrated model"
        )
    return (
        "Below epsilon's lower bound"
        + (f" (density at the published sigma: {', '.join(at_edge)})" if at_edge else "")
        + f", where {', '.join(piled)} piles (`water_prior_range_low` and `water_prior_range`, published sigma, "
        f"{low['seeds']} runs per point): " + "; ".join(parts) + f". So {verdict}."
    )


def side_by_side(d: dict[str, Any]) -> str:
    """Markdown table: each model's published (sigma, epsilon), its calibration here, and the
    TIP4P Bayes estimates of Dutta et al. (2018) on the same kind of data (g_OO alone, APMCABC)."""
    header = ["", "sigma_OO (nm)", "epsilon_OO (kJ/mol)", "correlation", "probability"]
    rows = []
    paper = PAPER_TIP4P_ESTIMATES.get(d["data"])
    if paper:
        est = paper["bayes_estimate"]
        label = f"paper, TIP4P ({d['data']} g_OO only)"
        rows.append([label, f"{est[0]:.4f}", f"{est[1]:.3f}", paper["correlation"], "-"])
    for name, row in d["per_model"].items():
        pub, est, ci = d["models"][name]["published_lj"], row["bayes_estimate"], row["credible_interval_95"]
        rows.append([f"{name}, published", f"{pub[0]:.4f}", f"{pub[1]:.3f}", "-", "-"])
        rows.append(
            [
                f"{name}, calibrated here",
                f"{est[0]:.4f} [{ci[0][0]:.4f}, {ci[0][1]:.4f}]",
                f"{est[1]:.3f} [{ci[1][0]:.3f}, {ci[1][1]:.3f}]",
                f"{row['correlation']:.2f}",
                f"{row['probability']:.3g}",
            ]
        )
    return table(header, rows)


_HEADER = [
    "model",
    "probability",
    "2.5-97.5 % (log evidences drawn)",
    "sigma_OO nm: estimate [95 %] / published",
    "epsilon_OO kJ/mol: estimate [95 %] / published",
    "runs (failed)",
    "validated",
    "misfit p",
]


def _row(name: str, row: dict[str, Any], model: dict[str, Any]) -> list[str]:
    est, ci, pub = row["bayes_estimate"], row["credible_interval_95"], model["published_lj"]
    lo, hi = row["probability_interval_95"] or (float("nan"), float("nan"))
    misfit = row.get("observed_misfit") or {}
    p = misfit.get("p_value")
    return [
        name,
        f"{row['probability']:.3g}",
        f"[{lo:.3g}, {hi:.3g}]",
        f"{est[0]:.4f} [{ci[0][0]:.4f}, {ci[0][1]:.4f}] / {pub[0]:.4f}",
        f"{est[1]:.3f} [{ci[1][0]:.3f}, {ci[1][1]:.3f}] / {pub[1]:.3f}",
        f"{row['num_simulations']} ({row['num_failures']})",
        "yes" if row["validated"] else f"no: {row['validation_failure']}",
        "-" if p is None else f"{p:.2g}",
    ]


def _paper_check(name: str, c: dict[str, Any]) -> list[str]:
    sets, shift, summaries = c["sets"], c["preset_shift"], c["summaries"]

    def cell(stats: dict[str, Any], j: int) -> str:
        if stats["mean"] is None:
            return "-"
        sd = "" if stats["sd"] is None else f" +- {stats['sd'][j]:.3g}"
        return f"{stats['mean'][j]:.4g}{sd}"

    rows = []
    for j, summary in enumerate(summaries["names"]):
        observed = summaries["observed"][j]
        if observed == 0.0:
            continue  # not measured in these data
        d = "-" if shift["se"] is None else f"{shift['mean'][j]:+.3g} +- {shift['se'][j]:.2g}"
        rows.append(
            [
                summary + (" (held out)" if summary in summaries["held_out"] else ""),
                f"{observed:.4g}",
                cell(sets["calibrated_quick"], j),
                cell(sets["calibrated_paper"], j),
                d,
                cell(sets["published_paper"], j),
            ]
        )
    header = ["summary", "measured", "calibrated, quick", "calibrated, paper", "shift paper - quick"]
    header.append("published, paper")
    return [
        f"## Does {c['model']}'s calibration hold in the paper preset?\n",
        source(name, data=c) + "\n",
        f"Model: {c['model']}, {c.get('model_selected_as', 'the most probable model')}.\n",
        f"{sets['calibrated_quick']['num_runs']} posterior draws run in the quick preset and again in the paper "
        f"preset with the same keys, {sets['calibrated_paper']['num_runs']} of them completed there"
        + (
            f" ({'; '.join(c['failures']['calibrated_paper'])})"
            if (c.get("failures") or {}).get("calibrated_paper")
            else ""
        )
        + " (mean +- sd over runs; the shift is paired over the draws run in both, +- its SE), and "
        f"{sets['published_paper']['num_runs']} runs at the published parameters in the paper preset "
        f"({c['check_preset']}).\n",
        table(header, rows) + "\n",
    ]


def _criticism(name: str, c: dict[str, Any]) -> list[str]:
    refits = ", ".join(
        f"{label} {r['num_simulations']} runs, ESS {r['ess']:.0f}" + (f" ({r['source']})" if r.get("source") else "")
        for label, r in c["refits"].items()
        if r
    )
    lines = [
        f"## What {c['model']} still gets wrong ({_CRITICISM_START.get(name, name)})\n",
        source(name, data=c) + "\n",
        f"Model: {c['model']}, {c.get('model_selected_as', 'the most probable model')}"
        + ("; the model choice found no model that reproduces the data." if c.get("model_choice_misspecified") else ".")
        + "\n",
        f"Held out: {', '.join(c['summaries']['held_out'])}; catalogue: {', '.join(c['catalogue'])}.\n",
        f"Verdict: {c['verdict']}\n",
    ]
    misfits, causes = misfit_rows(c, 8), cause_rows(c)
    if misfits:
        lines += [table(["misfit", "observed", "predictive 90 % band", "z", "adjusted p", ""], misfits) + "\n"]
        lines += [MISFIT_NOTE + "\n"]
    if causes:
        lines.append(table(["cause", "score", "explains", "adjusted p", "ambiguous", "note"], causes) + "\n")
    gain = c.get("gain")
    if gain:
        lines.append(
            f"Surrogate posteriors ({refits}).  Held-out delta log predictive density "
            f"{f(gain['delta_lpd'], 2)} +- {f(gain['delta_lpd_se'], 2)}.\n"
        )
    ext, saved = c.get("extension"), saved_extension(RESULTS / f"{name}_{c['data']}" / "extension.npz")
    if ext:
        box = _extension_box(saved)
        lines.append(
            "Extended model's posterior (mean [95 %]"
            + (", prior box" if box else "")
            + "): "
            + "; ".join(
                f"{n} {f(m, 3)} [{f(lo, 3)}, {f(hi, 3)}]"
                + (f" in [{f(box[0][i], 3)}, {f(box[1][i], 3)}]" if box else "")
                for i, (n, m, (lo, hi)) in enumerate(zip(ext["names"], ext["bayes_estimate"], ext["ci95"], strict=True))
            )
            + "."
            + _extension_validation(saved)
            + "\n"
        )
    edges = extension_edges(saved)
    if edges:
        lines.append(
            "Prior edges of the extended model's refit: "
            + "; ".join(edges)
            + ".  The effect's size, and the gain, depend on where that box was cut.\n"
        )
    return lines


def _extension_box(result: Any) -> tuple[list[float], list[float]] | None:
    """The prior box ``(low, high)`` of an extension refit (None when not saved)."""
    if result is None:
        return None
    return [float(v) for v in result.prior.low], [float(v) for v in result.prior.high]


def _extension_failed(name: str, c: dict[str, Any]) -> bool:
    """Whether a criticism's saved extension refit failed its emulator's validation."""
    saved = saved_extension(RESULTS / f"{name}_{c['data']}" / "extension.npz")
    return saved is not None and saved.diagnostics.get("validated") is False


def _extension_validation(result: Any) -> str:
    """Whether an extension refit has a validated emulator ("" when not saved)."""
    if result is None:
        return ""
    if result.diagnostics.get("validated") is not False:
        return " The extension's emulator validated on held-out runs."
    return (
        f" The extension's emulator failed validation ({result.diagnostics.get('failure') or 'see its result'}): "
        "its posterior, and the gain, are not trustworthy."
    )


def misfit_table(d: dict[str, Any]) -> str:
    """Markdown table: each model's standardised residual (observed - predictive) / sd per fitted
    summary, with the misfit chi-square, its degrees of freedom and p-value."""
    fitted = d["summaries"]["fitted"]
    rows = []
    for name, row in d["per_model"].items():
        m = row.get("observed_misfit") or {}
        z = m.get("standardised_residuals") or [float("nan")] * len(fitted)
        chi2, dof, p = m.get("mahalanobis_squared"), m.get("dof"), m.get("p_value")
        rows.append(
            [
                name,
                *(f"{v:+.1f}" for v in z),
                "-" if chi2 is None else f"{chi2:.0f} / {dof}",
                "-" if p is None else f"{p:.1g}",
            ]
        )
    return table(["model", *fitted, "chi-square / dof", "p"], rows)


def outcome(d: dict[str, Any], checks: dict[str, Any], crits: dict[str, Any]) -> str:
    """The README block under the side-by-side table: the model choice's verdict, the misfit of
    every model per summary, the paper-preset check and the criticism's held-out gain."""
    parts = [
        *_family_headline(),
        source("water_model_choice", data=d),
        f"The first run in detail (seed 0, 60 runs per model) stopped: {d['model_choice']['stop_reason']}.",
        *(line.replace("**Verdict:", "**The first run's verdict:", 1) for line in _verdict(d)[:1]),
        *(
            f"The repeats meant to be trusted (calibrated emulator variance, `r_oo_max2_nm` held out): {line}"
            for line in _holdout_family()[-1:]
        ),
        *(_without_discrepancy(load(HOLDOUT_NO_DISCREPANCY)) if load(HOLDOUT_FAMILY[0]) is not None else []),
        misfit_table(d),
    ]
    for name, check in checks.items():
        if check is not None:
            parts += _paper_check(name, check)[1:]
    for name, crit in crits.items():
        if crit is None:
            continue
        refits = ", ".join(
            f"{k} ESS {r['ess']:.0f} from {r['num_simulations']} runs" for k, r in crit["refits"].items() if r
        )
        parts += [source(name, data=crit), f"Criticism of {crit['model']}: {crit['verdict']}  Posteriors: {refits}."]
    return "\n\n".join(p.strip() for p in parts if p.strip())


__all__ = ["CRITICISMS", "PAPER_CHECKS", "misfit_table", "outcome", "page_water_model_choice", "side_by_side"]


def block_water_model_choice() -> str:
    """The side-by-side table of the water model choice, for ``md/water/README.md``."""
    d = load("water_model_choice")
    if d is None:
        return "Not run yet: `python -m benchmarks.regenerate --only water_model_choice --budget 4h`."
    return "\n\n".join([source("water_model_choice", data=d), side_by_side(d)])


def block_water_model_outcome() -> str:
    """What the model choice, the paper-preset check and the criticism found, for ``md/water/README.md``."""
    d = load("water_model_choice")
    if d is None:
        return "Not run yet."
    crits = {name: load(name) for name in CRITICISMS}
    checks = {name: load(name) for name in PAPER_CHECKS}
    return outcome(d, checks, crits)
