"""The criticism report: Markdown, JSON and PNG figures."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["CritiqueReport"]


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return str(obj)
    return obj


@dataclass
class CritiqueReport:
    """What :func:`jaxabc.criticism.critique` found.

    Attributes
    ----------
    misfits : list of Misfit
        The *flagged* misfits (after the multiple-testing correction), ranked; each unpacks as
        ``(name, standardised_residual, p_value)`` and has a ``line``.  Empty when nothing is wrong.
    all_misfits : list of Misfit
        Every test, ranked.
    causes : list of Cause
        Every catalogue effect, ranked; each unpacks as ``(effect_name, score)``, with
        ``ambiguous``, ``invisible`` and ``note``.
    extension : ABCResult or None
        The refit over base parameters plus the top cause (None when nothing was flagged).
    base_refit : ABCResult or None
        The base model refitted with the same distance and settings (the gain's reference).
    gain : dict
        Held-out measures with standard errors (see :mod:`jaxabc.criticism.gain`).
    ambiguities : list of str
    power : dict
        Per effect with an expected strength: ``expected``, ``power``, ``se``, ``interval``,
        ``num_datasets``, ``num_named``, ``num_failed`` (see :mod:`jaxabc.criticism.power`).
    design_advice : dict
        Per undetectable effect: candidate observables ranked by the signal they would add.
    power_estimates : dict
        The :class:`jaxabc.criticism.power.EffectPower` objects behind ``power``, with the
        replicate data sets (not written to disk).
    """

    misfits: list
    all_misfits: list
    causes: list
    extension: Any
    base_refit: Any
    gain: dict
    ambiguities: list[str]
    predictive: Any = None
    misfit_analysis: Any = None
    cause_analysis: Any = None
    catalogue: Any = None
    observed: np.ndarray | None = None
    held_out: np.ndarray | None = None
    base_result: Any = None
    settings: dict = field(default_factory=dict)
    extension_draws: np.ndarray | None = None
    base_draws: np.ndarray | None = None
    power: dict = field(default_factory=dict)
    design_advice: dict = field(default_factory=dict)
    power_estimates: dict = field(default_factory=dict, repr=False)

    @property
    def undetectable(self) -> list:
        """Causes these data could not have seen: not named, power below the threshold."""
        return [c for c in self.causes if getattr(c, "detectable", None) is False]

    def _unseen_clause(self) -> str:
        unseen = self.undetectable
        if not unseen:
            return ""
        parts = []
        for c in unseen:
            part = f"{c.name} (power {c.power:.2f} ± {c.power_se:.2f} at its expected strength {c.expected:g})"
            rows = getattr(c, "design_advice", None) or []
            if rows and np.isfinite(rows[0]["gain"]) and rows[0]["gain"] > 0:
                part += f", best added observable {rows[0]['name']}"
            parts.append(part)
        return "; not detectable with these data, so not ruled out: " + ", ".join(parts)

    @property
    def flagged(self) -> bool:
        """Whether any misfit survived the multiple-testing correction."""
        return bool(self.misfits)

    @property
    def verdict(self) -> str:
        """One sentence."""
        unseen = self._unseen_clause()
        if not self.misfits:
            return f"No misfit: the calibrated model reproduces every summary and region within its noise{unseen}."
        top = self.misfits[0]
        visible = [c for c in self.causes if not c.invisible]
        if not visible:
            return f"Misfit in {top.name}, but no catalogue effect is visible in these summaries{unseen}."
        c = visible[0]
        ca = self.cause_analysis
        if ca is not None and ca.unexplained:
            res = ca.residual
            best = ", ".join(ca.needed) or c.name
            why = (
                f"no catalogue effect accounts for it: the best extension ({best}) explains "
                f"{100 * (ca.explained_fraction if ca.needed else c.fraction_explained):.0f}% of the remaining "
                f"residual and leaves chi2 {res['chi2']:.1f} on {res['dof']} dof (p={res['p_value']:.1e}); "
                "the cause is probably outside the catalogue"
            )
        elif c.ambiguous:
            why = f"the most likely cause is {c.name} but it is ambiguous: {c.note}"
        elif c.significant:
            why = (
                f"the most likely cause is {c.name} (score {c.score:.1f}, explains "
                f"{100 * c.fraction_explained:.0f}% of the remaining residual)"
            )
            if ca is not None and ca.needed and ca.needed != [c.name]:
                why += f"; effects needed jointly: {', '.join(ca.needed)}"
        else:
            why = f"no catalogue effect explains it significantly (best: {c.name}, score {c.score:.1f})"
        g = self.gain
        tail = ""
        if "delta_lpd" in g:
            counts = (
                "counts"
                if g.get("counts")
                else "exceeds its uncertainty, but the new parameter is not learned away from its null"
                if g.get("significant")
                # The mirror of "significant" (gain.py): a loss beyond 2 SE is not a null result.
                else "a loss: the extension predicts the held-out data worse than the base"
                if g["delta_lpd"] < -2.0 * g["delta_lpd_se"]
                else "does not exceed its uncertainty"
            )
            tail = (
                f"; held-out gain of the extension: delta log predictive density {g['delta_lpd']:.1f} "
                f"+- {g['delta_lpd_se']:.1f} ({counts})"
            )
        return f"Misfit in {top.name}; {why}{tail}{unseen}."

    # -- text ---------------------------------------------------------------------------------

    def to_dict(self) -> dict:
        d = {
            "verdict": self.verdict,
            "misfits": [
                dict(
                    name=m.name,
                    residual=m.residual,
                    p_value=m.p_value,
                    adjusted_p_value=m.adjusted_p_value,
                    held_out=m.held_out,
                    kind=m.kind,
                    observed=m.observed,
                    band=m.band,
                    line=m.line,
                )
                for m in self.all_misfits
            ],
            "flagged": [m.name for m in self.misfits],
            "causes": [
                dict(
                    name=c.name,
                    score=c.score,
                    statistic=c.statistic,
                    p_value=c.p_value,
                    adjusted_p_value=c.adjusted_p_value,
                    significant=c.significant,
                    fraction_explained=c.fraction_explained,
                    estimate=c.estimate,
                    max_snr=c.max_snr,
                    ambiguous=c.ambiguous,
                    invisible=c.invisible,
                    note=c.note,
                    acts_on=c.acts_on,
                    needed=getattr(c, "needed", False),
                    conditional_score=getattr(c, "conditional_score", None),
                    conditional_p_value=getattr(c, "conditional_p_value", None),
                    expected=getattr(c, "expected", None),
                    power=getattr(c, "power", None),
                    power_se=getattr(c, "power_se", None),
                    power_interval=getattr(c, "power_interval", None),
                    detectable=getattr(c, "detectable", None),
                )
                for c in self.causes
            ],
            "ambiguities": self.ambiguities,
            "power": self.power,
            "undetectable": [c.name for c in self.undetectable],
            "design_advice": self.design_advice,
            "gain": self.gain,
            "settings": self.settings,
        }
        ca = self.cause_analysis
        if ca is not None:
            d["needed"] = list(ca.needed)
            d["unexplained"] = ca.unexplained
            d["explained_fraction"] = ca.explained_fraction
            d["residual_after_needed"] = ca.residual
            d["residual_after_top"] = ca.residual_after_top
        if self.misfit_analysis is not None:
            d["global_chi2"] = dict(
                statistic=self.misfit_analysis.chi2,
                dof=self.misfit_analysis.chi2_dof,
                p_value=self.misfit_analysis.chi2_p_value,
            )
        for label, res in (("extension", self.extension), ("base_refit", self.base_refit)):
            if res is not None:
                d[label] = dict(
                    names=list(res.names),
                    bayes_estimate=res.bayes_estimate().tolist(),
                    ci95=res.credible_interval(0.95).tolist(),
                    num_simulations=res.num_simulations,
                )
        return _jsonable(d)

    def to_markdown(self, figures: dict[str, str] | None = None) -> str:
        """The report as Markdown; ``figures`` maps ``misfits``, ``causes``, ``extension`` and
        ``gain`` to the image paths to embed (those absent are left out)."""
        figures = figures or {}
        lines = ["# Model criticism report", "", f"**Verdict.** {self.verdict}", ""]
        if self.base_result is not None:
            lines += ["## Base calibration", "", "```", self.base_result.summary(), "```", ""]
        lines += _misfit_section(self, figures)
        lines += _cause_section(self, figures)
        if self.power:
            lines += _power_section(self)
        if self.design_advice:
            lines += _design_advice_section(self)
        lines += _extension_and_gain_sections(self, figures)
        if self.catalogue is not None and self.catalogue.notes:
            lines += ["", "## Catalogue notes", "", self.catalogue.notes]
        return "\n".join(lines) + "\n"

    # -- figures ------------------------------------------------------------------------------

    def _figures(self, out: Path) -> dict[str, str]:
        """Write the PNG figures that this report has data for into ``out``; returns
        ``{figure name: file name}`` for :meth:`to_markdown`.  Needs matplotlib."""
        try:
            import matplotlib
        except ImportError as exc:  # the optional `plotting` extra
            raise ImportError("criticism figures need matplotlib: pip install 'jaxabc[plotting]'") from exc

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt

        figs: dict[str, str] = {}
        for name, draw in (
            ("misfits", _misfit_figure),
            ("causes", _cause_figure),
            ("extension", _extension_figure),
            ("gain", _gain_figure),
        ):
            fig = draw(self, plt)
            if fig is None:
                continue
            fig.tight_layout()
            fig.savefig(out / f"{name}.png", dpi=110)
            plt.close(fig)
            figs[name] = f"{name}.png"
        return figs

    def write(self, directory: str | Path, figures: bool = True) -> Path:
        """Write ``report.md``, ``report.json`` and PNG figures into ``directory``; returns its path."""
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        figs = self._figures(out) if figures else {}
        (out / "report.md").write_text(self.to_markdown(figs))
        (out / "report.json").write_text(json.dumps(self.to_dict(), indent=1, default=str))
        if self.extension is not None:
            self.extension.save(out / "extension.npz", overwrite=True)
        return out


# -- Markdown sections: lists of lines --------------------------------------------------------


def _misfit_section(report: CritiqueReport, figures: dict[str, str]) -> list[str]:
    """ "What it gets wrong": the flagged misfits, or the closest calls when none is flagged."""
    lines = ["## What it gets wrong", ""]
    corr = report.settings.get("correction", "holm")
    lines.append(
        f"Calibrated p-values (refit-adjusted null from replicate simulations at the estimate), "
        f"{'Holm' if corr == 'holm' else 'Benjamini-Hochberg'} correction within the fitted and "
        f"held-out families at overall level {report.settings.get('alpha')}."
    )
    lines.append("")
    if report.misfits:
        lines += [f"{i + 1}. {m.line}" for i, m in enumerate(report.misfits)]
    else:
        lines.append("Nothing flagged. Closest calls:")
        lines += [f"- {m.line}" for m in report.all_misfits[:5]]
    if "misfits" in figures:
        lines += ["", f"![misfits]({figures['misfits']})"]
    return lines


def _cause_section(report: CritiqueReport, figures: dict[str, str]) -> list[str]:
    """ "Why": the ranked causes, the joint test's verdict and the ambiguities."""
    lines = [
        "",
        "## Why: ranked causes",
        "",
        "| rank | effect | score | adjusted p | explains | linearised estimate | note |",
        "|---|---|---|---|---|---|---|",
    ]
    for i, c in enumerate(report.causes):
        lines.append(
            f"| {i + 1} | {c.name} | {c.score:.2f} | {c.adjusted_p_value:.2g} | "
            f"{100 * c.fraction_explained:.0f}% | {c.estimate:.4g} | {c.note} |"
        )
    ca = report.cause_analysis
    if ca is not None and ca.residual:
        res = ca.residual
        lines += [
            "",
            f"Needed after the stronger effects are included (conditional Holm test): "
            f"{', '.join(ca.needed) or 'none'}. Residual after them: chi2 {res['chi2']:.1f} on "
            f"{res['dof']} dof (p={res['p_value']:.2g}); explained fraction "
            f"{100 * ca.explained_fraction:.0f}%"
            + (" -- **no catalogue effect accounts for the misfit**." if ca.unexplained else "."),
        ]
    if report.ambiguities:
        lines += ["", "Ambiguities:"] + [f"- {a}" for a in report.ambiguities]
    if "causes" in figures:
        lines += ["", f"![causes]({figures['causes']})"]
    return lines


def _power_section(report: CritiqueReport) -> list[str]:
    """The detection-power table: one row per effect with an expected strength."""
    n = report.settings.get("num_power_replicates")
    lines = [
        "",
        "## Could these data have seen it? Detection power",
        "",
        f"Share of {n} data sets simulated from the base posterior with the effect at its expected "
        "strength in which this pipeline (refit, misfit tests, ranking, joint test) names it; "
        "binomial standard error and 95% Wilson interval.  An effect not named here with power "
        f"below {report.settings.get('power_threshold', 0.5)} is not detectable with these data: "
        "its rank is no evidence against it.",
        "",
        "| effect | expected strength | power | s.e. | 95% interval | named here | reading |",
        "|---|---|---|---|---|---|---|",
    ]
    ca = report.cause_analysis
    needed = set(ca.needed) if ca is not None else set()
    by_name = {c.name: c for c in report.causes}
    for name, pw in report.power.items():
        c = by_name.get(name)
        reading = (
            "not detectable with these data"
            if c is not None and getattr(c, "detectable", None) is False
            else "detectable"
        )
        lo, hi = pw["interval"]
        lines.append(
            f"| {name} | {pw['expected']:g} | {pw['power']:.2f} | {pw['se']:.2f} | [{lo:.2f}, {hi:.2f}] | "
            f"{'yes' if name in needed else 'no'} | {reading} |"
        )
    return lines


def _design_advice_section(report: CritiqueReport) -> list[str]:
    """One table of ranked candidate observables per effect that has design advice."""
    lines = [
        "",
        "## Design advice: what would make them visible",
        "",
        "Candidate observables ranked by the signal (noise sd) the effect would leave at its expected "
        "strength in the design with the candidate added, after the base parameters absorb what they "
        "can; `raw` is the candidate's own response before that absorption.",
    ]
    for name, rows in report.design_advice.items():
        lines += ["", f"**{name}**", "", "| rank | candidate | signal with it | without | raw | absorbed |"]
        lines.append("|---|---|---|---|---|---|")
        for i, r in enumerate(rows):
            lines.append(
                f"| {i + 1} | {r['name']} | {r['snr']:.3g} | {r['current_snr']:.3g} | {r['raw_snr']:.3g} | "
                + (f"{100 * r['absorbed']:.0f}% |" if np.isfinite(r["absorbed"]) else "- |")
            )
    return lines


def _extension_and_gain_sections(report: CritiqueReport, figures: dict[str, str]) -> list[str]:
    """The extension's fit and the held-out gain table (each only when there is one)."""
    lines: list[str] = []
    if report.extension is not None:
        lines += ["", "## Extension", "", "```", report.extension.summary(), "```"]
        if "extension" in figures:
            lines += ["", f"![extension]({figures['extension']})"]
    if report.gain:
        lines += ["", "## Gain on held-out summaries", "", "| measure | value |", "|---|---|"]
        for k, v in report.gain.items():
            lines.append(f"| {k} | {v if not isinstance(v, float) else f'{v:.4g}'} |")
        if "gain" in figures:
            lines += ["", f"![gain]({figures['gain']})"]
    return lines


# -- figures: each returns a matplotlib Figure, or None when the report lacks its data ---------


def _misfit_figure(report: CritiqueReport, plt: Any) -> Any:
    """Observed against the predictive band, and the calibrated z of every summary."""
    p = report.predictive
    if p is None or report.observed is None:
        return None
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    x = np.arange(report.observed.size)
    band = p.band(report.settings.get("level", 0.9))
    # Predictive sd (noise + parameter uncertainty), so every summary shares one scale.
    sd = p.draws.std(axis=0)
    sd = np.where(sd > 0, sd, 1.0)
    ref = p.mean()
    ax1.fill_between(
        x, (band[:, 0] - ref) / sd, (band[:, 1] - ref) / sd, color="C0", alpha=0.3, label="predictive band"
    )
    ax1.plot(x, (report.observed - ref) / sd, "ko", ms=3, label="observed")
    ax1.set_ylabel("(y - predictive mean) / predictive sd")
    ax1.legend(fontsize=8)
    z = np.zeros(x.size)
    flag = np.zeros(x.size, bool)
    for m in report.all_misfits:
        if m.kind == "summary":
            z[m.indices[0]] = m.residual
            flag[m.indices[0]] = m.flagged
    ax2.bar(x, z, color=np.where(flag, "C3", "C7"))
    if report.held_out is not None and report.held_out.any():
        ax2.plot(x[report.held_out], np.zeros(report.held_out.sum()), "b|", ms=12, label="held out")
        ax2.legend(fontsize=8)
    ax2.set_ylabel("calibrated z (red: flagged)")
    ax2.set_xticks(x)
    ax2.set_xticklabels(p.names, rotation=90, fontsize=6)
    return fig


def _cause_figure(report: CritiqueReport, plt: Any) -> Any:
    """Matched-filter score of every cause (red: significant)."""
    if not report.causes:
        return None
    fig, ax = plt.subplots(figsize=(6, 0.4 * len(report.causes) + 1.5))
    names = [
        c.name + (" (ambiguous)" if c.ambiguous else "") + (" (invisible)" if c.invisible else "")
        for c in report.causes
    ][::-1]
    ax.barh(
        names,
        [c.score for c in report.causes][::-1],
        color=["C3" if c.significant else "C7" for c in report.causes][::-1],
    )
    ax.axvline(2.0, color="k", ls=":", lw=1)
    ax.set_xlabel("matched-filter score (noise sd)")
    return fig


def _extension_figure(report: CritiqueReport, plt: Any) -> Any:
    """Posterior of the extension's effect parameter against its null, with its 95 % interval."""
    if report.extension is None:
        return None
    fig, ax = plt.subplots(figsize=(5, 3.5))
    x, w = report.extension.particles[:, -1], report.extension.weights
    ax.hist(x, bins=30, weights=w, color="C0", alpha=0.7)
    eff = report.catalogue[report.extension.names[-1]]
    ax.axvline(eff.null, color="k", ls="--", label="null (no effect)")
    ci = report.extension.credible_interval(0.95)[-1]
    ax.axvspan(ci[0], ci[1], color="C1", alpha=0.2, label="95% CI")
    ax.set_xlabel(f"{eff.name}" + (f" [{eff.unit}]" if eff.unit else ""))
    ax.legend(fontsize=8)
    return fig


def _gain_figure(report: CritiqueReport, plt: Any) -> Any:
    """Base and extended predictive draws on the held-out summaries, relative to the data."""
    p = report.predictive
    if (
        p is None
        or report.observed is None
        or report.extension_draws is None
        or report.base_draws is None
        or report.held_out is None
        or not report.held_out.any()
    ):
        return None
    h = np.flatnonzero(report.held_out & p.active)
    fig, ax = plt.subplots(figsize=(7, 3.5))
    sd = np.where(p.noise_sd > 0, p.noise_sd, 1.0)[h]
    for label, draws, c in (("base", report.base_draws, "C7"), ("extended", report.extension_draws, "C2")):
        q = np.quantile((draws[:, h] - report.observed[h]) / sd, [0.05, 0.5, 0.95], axis=0)
        ax.errorbar(
            np.arange(h.size) + (0.15 if c == "C2" else -0.15),
            q[1],
            yerr=[q[1] - q[0], q[2] - q[1]],
            fmt="o",
            color=c,
            label=label,
            ms=3,
        )
    ax.axhline(0, color="k", lw=1)
    ax.set_xticks(np.arange(h.size))
    ax.set_xticklabels([p.names[i] for i in h], rotation=90, fontsize=6)
    ax.set_ylabel("(predictive - observed) / noise sd")
    g = report.gain
    ax.set_title(
        f"held out: delta lpd {g.get('delta_lpd', float('nan')):.1f} +- {g.get('delta_lpd_se', float('nan')):.1f}",
        fontsize=9,
    )
    ax.legend(fontsize=8)
    return fig
