"""Why: a catalogue of candidate causes, their signatures, and a matched-filter ranking.

Each :class:`Effect` adds one parameter ``eta`` to the simulator (a prior box and a null value
meaning "no effect").  The simulator used by criticism takes the *extended* parameter vector::

    simulate_with_effects(key, theta_full) -> summaries (s,)
    theta_full = [theta_base (d,), eta_1, ..., eta_K]     # effects in catalogue order

so that it has the shape of every jaxabc simulator and vmaps over a batch of thetas.

Ranking
-------
For every effect ``k`` the sensitivity ``v_k = d E[summaries] / d eta_k`` at the Bayes estimate
(all other effects at null) is estimated by finite differences with common random numbers: the
same replicate keys at ``eta_null +- h`` (one-sided from a boundary null).  The base parameters'
sensitivities ``J`` are estimated the same way.  The base directions are projected out with the
refit operator ``A`` of :mod:`jaxabc.criticism.misfit` (what the base parameters can absorb, in
the noise-whitened metric), giving ``u_k = A v_k``.  With ``C`` the null covariance of the refit
residual ``r_c``, the matched-filter (score) statistic is::

    t_k = u_k' C^+ r_c / sqrt(u_k' C^+ u_k)        ~ N(0, 1) when the model is right

and ``t_k^2 / (r_c' C^+ r_c)`` is the fraction of the remaining residual it explains.  Effects are
ranked by ``|t_k|`` (``max(t_k, 0)`` when the prior only allows one sign), with Holm-adjusted
p-values.  Two effects whose ``u`` are nearly collinear in the ``C^+`` metric (|cos| above
``ambiguity_cosine``) cannot be told apart by these summaries: the report says so, with the
cosine and the data that would separate them (``Effect.separated_by``).  An effect whose largest
possible signal over its prior range is below ``invisible_snr`` noise standard deviations after
projection is reported as invisible.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import jax
import numpy as np

from jaxabc.criticism._stats import directed_score, prior_span, projector, residual_test
from jaxabc.criticism.misfit import adjust_pvalues
from jaxabc.criticism.predictive import simulate_many
from jaxabc.executors import Executor

__all__ = ["Catalogue", "Cause", "CauseAnalysis", "Effect", "rank_causes", "sensitivities"]


@dataclass(frozen=True)
class Effect:
    """A candidate cause of misfit with one parameter.

    Parameters
    ----------
    name : str
    low, high : float
        Prior box of the effect parameter (uniform).
    null : float
        The value meaning "no effect"; must lie in ``[low, high]``.
    unit : str
    description : str
        What the effect is, physically or as a measurement artefact.
    kind : {"physical", "measurement"}
        Physical effects need the simulator to re-run; measurement effects act on its output.
    separated_by : str
        Which data separate it from the effects it is confused with.
    confusable_with : tuple of str
        Names of effects (or base parameters) it is exactly or nearly confusable with.
    step : float, optional
        Finite-difference step for its sensitivity (default a fifth of the prior half-range).
    expected : float, optional
        The strength physics expects (e.g. ``1.0`` for a Feynman-Hibbs ``fh_scale``), inside the
        prior box.  Criticism then reports the power of the data design to detect the effect
        there (:mod:`jaxabc.criticism.power`), so that a low rank is not read as evidence
        against an effect the data could not have seen.  None (default): no known strength.
    """

    name: str
    low: float
    high: float
    null: float = 0.0
    unit: str = ""
    description: str = ""
    kind: str = "physical"
    separated_by: str = ""
    confusable_with: tuple[str, ...] = ()
    step: float | None = None
    expected: float | None = None

    def __post_init__(self) -> None:
        if self.expected is not None:
            if not np.isfinite(self.expected) or not self.low <= self.expected <= self.high:
                raise ValueError(
                    f"effect {self.name!r}: expected strength {self.expected} lies outside its prior "
                    f"[{self.low}, {self.high}]"
                )
            object.__setattr__(self, "expected", float(self.expected))
        if not self.low < self.high:
            raise ValueError(f"effect {self.name!r}: prior low={self.low} must be below high={self.high}")
        if not self.low <= self.null <= self.high:
            raise ValueError(
                f"effect {self.name!r}: null {self.null} lies outside its prior [{self.low}, {self.high}]; "
                "the prior must contain 'no effect'"
            )

    @property
    def one_sided(self) -> int:
        """+1 when only eta > null is allowed, -1 when only eta < null, 0 when both."""
        if self.null == self.low:
            return 1
        if self.null == self.high:
            return -1
        return 0

    def finite_difference_points(self) -> tuple[float, float]:
        """(lower, upper) evaluation points around the null."""
        half = 0.2 * max(self.high - self.null, self.null - self.low)
        h = self.step if self.step is not None else half
        lo, hi = self.null - h, self.null + h
        if self.one_sided == 1:
            lo = self.null
        elif self.one_sided == -1:
            hi = self.null
        return max(lo, self.low), min(hi, self.high)


@dataclass(frozen=True)
class Catalogue:
    """An ordered set of effects; their parameters follow the base ones in ``theta_full``.

    Parameters
    ----------
    effects : sequence of Effect
    name : str
    notes : str
        Free text (e.g. which effects are exactly confusable at one state point).
    """

    effects: tuple[Effect, ...]
    name: str = "catalogue"
    notes: str = ""

    def __init__(self, effects: Iterable[Effect], name: str = "catalogue", notes: str = ""):
        effects = tuple(effects)
        names = [e.name for e in effects]
        if len(set(names)) != len(names):
            raise ValueError(f"effect names must be unique, got {names}")
        if not effects:
            raise ValueError("a catalogue needs at least one effect")
        object.__setattr__(self, "effects", effects)
        object.__setattr__(self, "name", name)
        object.__setattr__(self, "notes", notes)

    def __iter__(self):
        return iter(self.effects)

    def __len__(self) -> int:
        return len(self.effects)

    def __getitem__(self, name: str) -> Effect:
        return self.effects[self.index(name)]

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.effects]

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no effect {name!r} in the catalogue: effects are {self.names}") from None

    def nulls(self) -> np.ndarray:
        """Null values, shape (K,)."""
        return np.array([e.null for e in self.effects], float)

    def subset(self, names: Sequence[str]) -> Catalogue:
        return Catalogue([self[n] for n in names], self.name, self.notes)


class Cause(tuple):
    """A ranked cause: unpacks as ``(effect_name, score)``.

    Further attributes: ``statistic`` (signed t), ``p_value``, ``adjusted_p_value``,
    ``significant``, ``fraction_explained``, ``estimate`` (linearised eta), ``max_snr``,
    ``ambiguous`` (bool), ``invisible`` (bool), ``note`` (str), ``acts_on`` (group names),
    ``needed`` (bool: selected by the conditional test), ``conditional_score`` and
    ``conditional_p_value`` (what it adds beyond the effects selected before it).  With an
    ``Effect.expected`` strength: ``expected``, ``power`` (share of data sets simulated at that
    strength in which the pipeline names it), ``power_se`` (binomial standard error),
    ``power_interval`` (95 % Wilson), ``detectable`` (False: not named here and power below
    the threshold) and ``design_advice`` (candidate observables, best first); otherwise these
    are None (also for causes unpickled from before they existed).
    """

    # Set per instance from ``details``; declared for type checkers.
    adjusted_p_value: float
    ambiguous: bool
    invisible: bool
    # Defaults for causes without a power estimate (and for pickles that predate it).
    expected: float | None = None
    power: float | None = None
    power_se: float | None = None
    power_interval: tuple[float, float] | None = None
    detectable: bool | None = None
    design_advice: list | None = None

    def __new__(cls, name: str, score: float, **details):
        obj = super().__new__(cls, (name, float(score)))
        obj.__dict__.update(details)
        return obj

    def __reduce__(self):
        return (_make_cause, (self[0], self[1], dict(self.__dict__)))

    name = property(lambda self: self[0])
    score = property(lambda self: self[1])

    def __repr__(self) -> str:
        flags = "".join([", ambiguous" if self.ambiguous else "", ", invisible" if self.invisible else ""])
        return f"Cause({self.name!r}, score={self.score:.2f}, p={self.adjusted_p_value:.2e}{flags})"


def _make_cause(name, score, details):
    return Cause(name, score, **details)


def sensitivities(
    simulate: Callable,
    theta: np.ndarray,
    keys: jax.Array,
    points: Sequence[tuple[int, float, float]],
    executor: Executor,
) -> np.ndarray:
    """Finite-difference sensitivities with common random numbers.

    Parameters
    ----------
    simulate : callable ``(key, theta_full) -> (s,)``
    theta : numpy.ndarray, shape (d_full,)
        Where to differentiate.
    keys : jax.Array, shape (g,)
        The common random numbers: every evaluation point uses these same keys.
    points : sequence of (index, lower, upper)
        Entry of ``theta_full`` to move and the two values to evaluate at.

    Returns
    -------
    numpy.ndarray, shape (s, len(points))
        ``(E[s(upper)] - E[s(lower)]) / (upper - lower)`` over the same keys; a pair whose
        simulation failed on either side is dropped.
    """
    g = keys.shape[0]
    theta = np.asarray(theta, float)
    # Distinct evaluation points only: a one-sided difference from a null that ``theta`` already
    # holds evaluates ``theta`` itself, and every such effect shares that one batch.
    unique: dict[tuple[float, ...], int] = {}
    slots = []
    for j, lo, hi in points:
        for v in (lo, hi):
            t = theta.copy()
            t[j] = v
            slots.append(unique.setdefault(tuple(t), len(unique)))
    thetas = np.repeat(np.array(list(unique), float), g, 0)
    all_keys = jax.numpy.concatenate([keys] * len(unique))
    sims = simulate_many(simulate, all_keys, thetas, executor).reshape(len(unique), g, -1)
    sims = sims[np.asarray(slots)].reshape(len(points), 2, g, -1)
    out = np.zeros((sims.shape[-1], len(points)))
    for c, (_j, lo, hi) in enumerate(points):
        diff = sims[c, 1] - sims[c, 0]
        ok = np.all(np.isfinite(diff), axis=1)
        if ok.sum() == 0:
            raise RuntimeError(f"every finite-difference simulation failed for parameter {_j}")
        out[:, c] = diff[ok].mean(axis=0) / (hi - lo)
    return out


@dataclass
class CauseAnalysis:
    """Ranked causes plus the quantities behind them.

    Attributes
    ----------
    causes : list of Cause
        Ranked, best first.
    directions : numpy.ndarray, shape (s, K)
        Raw sensitivities ``v_k``.
    projected : numpy.ndarray, shape (s, K)
        ``u_k = A v_k``.
    cosines : numpy.ndarray, shape (K, K)
        Cosines between projected directions in the ``C^+`` metric (NaN for invisible ones).
    ambiguities : list of str
    needed : list of str
        Effects selected in order by the conditional (joint) test: what the data still need
        after the stronger ones are included.  Read this, not ``significant``, for "the causes".
    total_chi2 : float
        ``r_c' C^+ r_c``, the residual the effects compete for.
    residual : dict
        ``chi2``, ``dof``, ``p_value`` of the residual after projecting out the needed effects.
    residual_after_top : dict
        The same after the top-ranked visible effect alone (the extension that is refitted).
    alpha : float
    """

    causes: list[Cause]
    directions: np.ndarray
    projected: np.ndarray
    cosines: np.ndarray
    ambiguities: list[str] = field(default_factory=list)
    needed: list[str] = field(default_factory=list)
    total_chi2: float = 0.0
    residual: dict = field(default_factory=dict)
    residual_after_top: dict = field(default_factory=dict)
    alpha: float = 0.05

    @property
    def explained_fraction(self) -> float:
        """Share of ``total_chi2`` that the needed effects explain (0 when none is needed)."""
        if self.total_chi2 <= 0 or not self.residual:
            return 0.0
        return float(max(0.0, 1.0 - self.residual["chi2"] / self.total_chi2))

    @property
    def unexplained(self) -> bool:
        """True when the residual after the needed effects is still significant at ``alpha``:
        no catalogue effect (or combination the test selected) accounts for the misfit."""
        return bool(self.residual) and self.residual["p_value"] <= self.alpha

    @property
    def top(self) -> Cause | None:
        return self.causes[0] if self.causes else None


def rank_causes(
    catalogue: Catalogue,
    directions: np.ndarray,
    refit: np.ndarray,
    refit_residual: np.ndarray,
    null_cov: np.ndarray,
    groups: dict[str, np.ndarray],
    *,
    alpha: float = 0.05,
    ambiguity_cosine: float = 0.95,
    invisible_snr: float = 3.0,
    near_tie_cosine: float = 0.8,
    near_tie_log_lr: float = 3.0,
    num_replicates: int | None = None,
) -> CauseAnalysis:
    """Score every effect by how much of the refit residual its projected signature explains.

    Parameters
    ----------
    catalogue : Catalogue
    directions : numpy.ndarray, shape (s, K)
    refit : numpy.ndarray, shape (s, s)
        The operator ``A``.
    refit_residual : numpy.ndarray, shape (s,)
    null_cov : numpy.ndarray, shape (s, s)
    groups : dict
        Used to say which regions each effect acts on.
    alpha : float
        Level of the Holm-adjusted per-effect and conditional tests, and of the residual test.
    ambiguity_cosine : float
        |cos| at or above which two admissible signatures are confusable whatever their scores.
    near_tie_cosine, near_tie_log_lr : float
        Below ``ambiguity_cosine``, a partner with |cos| >= ``near_tie_cosine`` is also ambiguous
        when the data favour the leader alone over it alone by a log likelihood ratio
        ``(score_a^2 - score_b^2) / 2`` below ``near_tie_log_lr`` (3: odds of 20 to 1).
    num_replicates : int, optional
        Replicates behind ``null_cov`` (F tail for the residual test; chi-squared if None).

    Returns
    -------
    CauseAnalysis
        Causes ranked visible first, then by score; ``needed`` from the forward selection.
    """
    prec = np.linalg.pinv(null_cov, rcond=1e-8, hermitian=True)
    u = refit @ directions
    r = refit_residual
    total = float(r @ prec @ r)
    norms = np.sqrt(np.maximum(np.einsum("sk,st,tk->k", u, prec, u), 0.0))
    cos = _signature_cosines(u, prec, norms)
    rows = [
        _score_effect(eff, u[:, k], norms[k], prec, r, total, groups, invisible_snr) for k, eff in enumerate(catalogue)
    ]
    _adjust_and_rank(rows, alpha)
    _note_invisible(rows, catalogue)
    names = catalogue.names
    visible_idx = [names.index(row["name"]) for row in rows if not row["invisible"]]
    selected, conditional = _forward_selection(
        catalogue, u, prec, r, visible_idx, alpha=alpha, invisible_snr=invisible_snr
    )
    residual = residual_test(projector(u[:, selected], prec) @ r, null_cov, num_replicates, len(selected))
    top = visible_idx[:1]  # the extension that is refitted: the top-ranked visible effect
    after_top = residual_test(projector(u[:, top], prec) @ r, null_cov, num_replicates, len(top))
    for row in rows:
        k = names.index(row["name"])
        row["needed"] = k in selected
        row["conditional_score"], row["conditional_p_value"] = conditional.get(k, (0.0, 1.0))
    ambiguities = _mark_ambiguities(rows, catalogue, cos, ambiguity_cosine, near_tie_cosine, near_tie_log_lr)
    causes = [Cause(row.pop("name"), row.pop("score"), **row) for row in rows]
    return CauseAnalysis(
        causes,
        directions,
        u,
        cos,
        ambiguities,
        needed=[names[k] for k in selected],
        total_chi2=total,
        residual=residual,
        residual_after_top=after_top,
        alpha=alpha,
    )


# One ranked effect while :func:`rank_causes` builds it; becomes a :class:`Cause`'s details.
_Row = dict[str, Any]


def _signature_cosines(u: np.ndarray, prec: np.ndarray, norms: np.ndarray) -> np.ndarray:
    """Cosines between the columns of ``u`` (s, K) in the ``prec`` metric, shape (K, K).

    ``norms`` (K,) are the columns' ``prec``-norms; a pair involving a zero norm is NaN.
    """
    k_eff = u.shape[1]
    cos = np.full((k_eff, k_eff), np.nan)
    for a in range(k_eff):
        for b in range(k_eff):
            if norms[a] > 0 and norms[b] > 0:
                cos[a, b] = float(u[:, a] @ prec @ u[:, b] / (norms[a] * norms[b]))
    return cos


def _score_effect(
    eff: Effect,
    u_k: np.ndarray,
    norm: float,
    prec: np.ndarray,
    r: np.ndarray,
    total: float,
    groups: dict[str, np.ndarray],
    invisible_snr: float,
) -> _Row:
    """Matched-filter score of one effect on its own against the refit residual ``r`` (s,).

    ``u_k`` (s,) is its projected signature with ``prec``-norm ``norm``; ``total`` is
    ``r' prec r``.  An effect whose largest signal over its prior is below ``invisible_snr``
    noise sd is returned as invisible (score 0, p-value 1).
    """
    max_snr = float(norm * prior_span(eff))
    if norm <= 0 or max_snr < invisible_snr:
        return dict(
            name=eff.name,
            score=0.0,
            statistic=0.0,
            p_value=1.0,
            fraction_explained=0.0,
            estimate=float("nan"),
            max_snr=max_snr,
            invisible=True,
        )
    t = float(u_k @ prec @ r / norm)
    # Signed in the direction of increasing eta; a one-sided prior can only use one sign.
    score, p = directed_score(t, eff.one_sided)
    estimate = eff.null + t / norm
    load = np.abs(u_k) * np.sqrt(np.diag(prec))
    acts_on = sorted(groups, key=lambda g: -float(np.sum(load[groups[g]] ** 2)))[:3]
    return dict(
        name=eff.name,
        score=score,
        statistic=t,
        p_value=p,
        fraction_explained=score * score / total if total > 0 else 0.0,
        estimate=float(estimate),
        max_snr=max_snr,
        invisible=False,
        acts_on=acts_on,
        outside_prior=not (eff.low <= estimate <= eff.high),
    )


def _adjust_and_rank(rows: list[_Row], alpha: float) -> None:
    """Holm-adjust the per-effect p-values, mark the significant visible ones, and sort ``rows``
    in place: visible effects first, each part by decreasing score."""
    adj = adjust_pvalues(np.array([row["p_value"] for row in rows]), "holm")
    for row, q in zip(rows, adj, strict=True):
        row["adjusted_p_value"] = float(q)
        row["significant"] = bool(q <= alpha and not row["invisible"])
    rows.sort(key=lambda row: (row["invisible"], -row["score"]))


def _note_invisible(rows: list[_Row], catalogue: Catalogue) -> None:
    """Give every row ``acts_on``, ``ambiguous`` (False) and ``note``; invisible effects get a
    note that says how small their signal is and which data would show them."""
    for row in rows:
        row.setdefault("acts_on", [])
        row["ambiguous"] = False
        row["note"] = ""
        eff = catalogue[row["name"]]
        if row["invisible"]:
            row["note"] = (
                f"invisible in the available summaries (largest signal over the prior "
                f"{row['max_snr']:.2g} noise sd after the base parameters absorb theirs)"
                + (f"; needs {eff.separated_by}" if eff.separated_by else "")
            )


def _forward_selection(
    catalogue: Catalogue,
    u: np.ndarray,
    prec: np.ndarray,
    r: np.ndarray,
    candidates: Sequence[int],
    *,
    alpha: float,
    invisible_snr: float,
) -> tuple[list[int], dict[int, tuple[float, float]]]:
    """Which effects are still needed once the stronger ones are in.

    Per-effect scores share the residual, so an absent effect that points partly the same way
    as the true one is "significant" on its own; the conditional score asks what it adds.  Each
    round scores the remaining ``candidates`` (catalogue indices) conditionally
    (:func:`_conditional_scores`), Holm-adjusts over them, and selects the best while its
    adjusted p-value is at most ``alpha``.

    Returns
    -------
    selected : list of int
        Catalogue indices in the order selected.
    conditional : dict of int to (score, adjusted p-value)
        Each scored candidate's values from the round that selected it, else from the first
        round that scored it.
    """
    spans = [prior_span(eff) for eff in catalogue]
    selected: list[int] = []
    conditional: dict[int, tuple[float, float]] = {}
    while True:
        cand, scores, ps = _conditional_scores(catalogue, u, prec, r, selected, candidates, spans, invisible_snr)
        if not cand:
            break
        adj = adjust_pvalues(np.array(ps), "holm")
        for k, sc, q in zip(cand, scores, adj, strict=True):
            conditional.setdefault(k, (sc, float(q)))
        best = int(np.argmax(scores))
        if adj[best] > alpha:
            break
        selected.append(cand[best])
        for k, sc, q in zip(cand, scores, adj, strict=True):
            conditional[k] = (sc, float(q))
    return selected, conditional


def _conditional_scores(
    catalogue: Catalogue,
    u: np.ndarray,
    prec: np.ndarray,
    r: np.ndarray,
    selected: list[int],
    candidates: Sequence[int],
    spans: list[float],
    invisible_snr: float,
) -> tuple[list[int], list[float], list[float]]:
    """Scores of the unselected candidates with the ``selected`` signatures projected out of
    both their signature and the residual; (candidate indices, scores, unadjusted p-values).

    A candidate whose remaining signal over its prior span is below ``invisible_snr`` is
    skipped: the selected effects already do everything it could.
    """
    proj = projector(u[:, selected], prec)
    r_perp = proj @ r
    cand: list[int] = []
    scores: list[float] = []
    ps: list[float] = []
    for k in candidates:
        if k in selected:
            continue
        up = proj @ u[:, k]
        nk = float(np.sqrt(max(up @ prec @ up, 0.0)))
        if nk * spans[k] < invisible_snr:
            continue
        t = float(up @ prec @ r_perp / nk)
        score, p = directed_score(t, catalogue.effects[k].one_sided)
        cand.append(k)
        scores.append(score)
        ps.append(p)
    return cand, scores, ps


# A partner of a leading effect: (name, signed cosine, score gap, gap noise sd, log LR).
_Partner = tuple[str, float, float, float, float]


def _mark_ambiguities(
    rows: list[_Row],
    catalogue: Catalogue,
    cos: np.ndarray,
    ambiguity_cosine: float,
    near_tie_cosine: float,
    near_tie_log_lr: float,
) -> list[str]:
    """Mark leaders the data cannot tell from a partner, and note each leader's nearest rival.

    Leaders are the significant effects (or the top row when none is).  A leader with
    confusable partners (:func:`_confusable_partners`) gets ``ambiguous`` and a note naming
    them and the data that would separate them; otherwise its note names its closest
    competitor by |cos|.  Returns one line per ambiguous leader.
    """
    names = catalogue.names
    by_name = {row["name"]: row for row in rows}
    ambiguities: list[str] = []
    leaders = [row for row in rows if row["significant"]] or rows[:1]
    for row in leaders:
        if row["invisible"]:
            continue
        a = names.index(row["name"])
        partners = _confusable_partners(row, a, names, by_name, cos, ambiguity_cosine, near_tie_cosine, near_tie_log_lr)
        if partners:
            row["ambiguous"] = True
            row["note"] = _ambiguity_note(row["name"], partners, catalogue)
            ambiguities.append(f"{row['name']}: {row['note']}")
        else:
            others = [(names[b], cos[a, b]) for b in range(len(names)) if b != a and np.isfinite(cos[a, b])]
            if others:
                name_b, c = max(others, key=lambda x: abs(x[1]))
                row["note"] = f"closest competitor {name_b} (cos {c:+.2f})"
    return ambiguities


def _confusable_partners(
    leader: _Row,
    a: int,
    names: list[str],
    by_name: dict[str, _Row],
    cos: np.ndarray,
    ambiguity_cosine: float,
    near_tie_cosine: float,
    near_tie_log_lr: float,
) -> list[_Partner]:
    """Effects the data cannot tell from the leader (catalogue index ``a``) under the priors.

    A partner counts only if its own prior allows the sign the data ask for (score > 0).  Then
    either its signature is collinear (|cos| >= ``ambiguity_cosine``), or it points mostly the
    same way (|cos| >= ``near_tie_cosine``) and the data barely prefer the leader: fitting one
    effect alone removes score^2 from the residual chi2, so ``(score_a^2 - score_b^2) / 2`` is
    the log likelihood ratio of "a alone" over "b alone", compared with ``near_tie_log_lr``.
    The score gap's noise sd, ``sqrt(2 (1 - |cos|))``, is reported beside it.
    """
    partners: list[_Partner] = []
    for b, name_b in enumerate(names):
        other = by_name[name_b]
        if b == a or not np.isfinite(cos[a, b]) or other["invisible"] or other["score"] <= 0:
            continue
        c = abs(cos[a, b])
        log_lr = 0.5 * (leader["score"] ** 2 - other["score"] ** 2)
        gap_sd = float(np.sqrt(max(2.0 * (1.0 - c), 0.0)))
        near_tie = c >= near_tie_cosine and log_lr < near_tie_log_lr
        if c >= ambiguity_cosine or near_tie:
            partners.append((name_b, cos[a, b], leader["score"] - other["score"], gap_sd, log_lr))
    return partners


def _ambiguity_note(leader: str, partners: list[_Partner], catalogue: Catalogue) -> str:
    """The note of an ambiguous leader: its partners and the data that would separate them."""
    needs = "; ".join(
        sorted({catalogue[n].separated_by for n, *_ in [*partners, (leader,)] if catalogue[n].separated_by})
    )
    txt = ", ".join(
        f"{n} (cos {c:+.3f}, score gap {g:.2f}, gap noise sd {gs:.2f}, log LR {lr:.1f})" for n, c, g, gs, lr in partners
    )
    return f"ambiguous with {txt}: these summaries cannot tell them apart" + (f"; needs {needs}" if needs else "")
