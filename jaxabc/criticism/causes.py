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

import jax
import numpy as np
from scipy import stats

from jaxabc.criticism._stats import _projector, _residual_test, _span
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
    """
    prec = np.linalg.pinv(null_cov, rcond=1e-8, hermitian=True)
    u = refit @ directions
    r = refit_residual
    total = float(r @ prec @ r)
    norms = np.sqrt(np.maximum(np.einsum("sk,st,tk->k", u, prec, u), 0.0))
    k_eff = len(catalogue)
    cos = np.full((k_eff, k_eff), np.nan)
    for a in range(k_eff):
        for b in range(k_eff):
            if norms[a] > 0 and norms[b] > 0:
                cos[a, b] = float(u[:, a] @ prec @ u[:, b] / (norms[a] * norms[b]))
    rows = []
    for k, eff in enumerate(catalogue):
        span = (
            max(eff.high - eff.null, eff.null - eff.low)
            if eff.one_sided == 0
            else (eff.high - eff.null if eff.one_sided == 1 else eff.null - eff.low)
        )
        max_snr = float(norms[k] * span)
        if norms[k] <= 0 or max_snr < invisible_snr:
            rows.append(
                dict(
                    name=eff.name,
                    score=0.0,
                    statistic=0.0,
                    p_value=1.0,
                    fraction_explained=0.0,
                    estimate=float("nan"),
                    max_snr=max_snr,
                    invisible=True,
                )
            )
            continue
        t = float(u[:, k] @ prec @ r / norms[k])
        # Signed in the direction of increasing eta; a one-sided prior can only use one sign.
        signed = t * (eff.one_sided if eff.one_sided else 1.0)
        score = max(signed, 0.0) if eff.one_sided else abs(t)
        p = float(stats.norm.sf(signed) if eff.one_sided else 2 * stats.norm.sf(abs(t)))
        estimate = eff.null + t / norms[k]
        load = np.abs(u[:, k]) * np.sqrt(np.diag(prec))
        acts_on = sorted(groups, key=lambda g: -float(np.sum(load[groups[g]] ** 2)))[:3]
        rows.append(
            dict(
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
        )
    adj = adjust_pvalues(np.array([row["p_value"] for row in rows]), "holm")
    for row, q in zip(rows, adj, strict=True):
        row["adjusted_p_value"] = float(q)
        row["significant"] = bool(q <= alpha and not row["invisible"])
    rows.sort(key=lambda row: (row["invisible"], -row["score"]))
    ambiguities: list[str] = []
    names = catalogue.names
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
    # Which effects are still needed once the stronger ones are in: forward selection on
    # conditional scores (each candidate's signature and the residual with the selected
    # signatures projected out, Holm over the remaining candidates).  Per-effect scores share
    # the residual, so an absent effect that points partly the same way as the true one is
    # "significant" on its own; the conditional score asks what it adds.
    spans = {k: _span(eff) for k, eff in enumerate(catalogue)}
    visible_idx = [names.index(row["name"]) for row in rows if not row["invisible"]]
    selected: list[int] = []
    conditional: dict[int, tuple[float, float]] = {}
    while True:
        cand, stats_, ps = [], [], []
        proj = _projector(u[:, selected], prec)
        r_perp = proj @ r
        for k in visible_idx:
            if k in selected:
                continue
            up = proj @ u[:, k]
            nk = float(np.sqrt(max(up @ prec @ up, 0.0)))
            if nk * spans[k] < invisible_snr:
                continue  # nothing left that the selected effects do not already do
            t = float(up @ prec @ r_perp / nk)
            side = catalogue.effects[k].one_sided
            signed = t * (side if side else 1.0)
            cand.append(k)
            stats_.append(max(signed, 0.0) if side else abs(t))
            ps.append(float(stats.norm.sf(signed) if side else 2 * stats.norm.sf(abs(t))))
        if not cand:
            break
        adj_c = adjust_pvalues(np.array(ps), "holm")
        for k, sc, q in zip(cand, stats_, adj_c, strict=True):
            conditional.setdefault(k, (sc, float(q)))
        best = int(np.argmax(stats_))
        if adj_c[best] > alpha:
            break
        selected.append(cand[best])
        for k, sc, q in zip(cand, stats_, adj_c, strict=True):
            conditional[k] = (sc, float(q))
    proj = _projector(u[:, selected], prec)
    residual = _residual_test(proj @ r, null_cov, num_replicates, len(selected))
    top_k = visible_idx[0] if visible_idx else None
    after_top = _residual_test(
        _projector(u[:, [top_k]] if top_k is not None else u[:, []], prec) @ r,
        null_cov,
        num_replicates,
        int(top_k is not None),
    )
    for row in rows:
        k = names.index(row["name"])
        row["needed"] = k in selected
        sc, q = conditional.get(k, (0.0, 1.0))
        row["conditional_score"], row["conditional_p_value"] = sc, q

    # Ambiguity: can the data tell a partner from a leader under the priors?  A partner counts
    # only if its own prior allows the sign the data ask for (score > 0).  Then either its
    # signature is collinear (|cos| >= ambiguity_cosine), or it points mostly the same way and the
    # data barely prefer the leader: fitting one effect alone removes score^2 from the residual
    # chi2, so (score_a^2 - score_b^2) / 2 is the log likelihood ratio of "a alone" over "b alone".
    # The score gap's noise sd, sqrt(2 (1 - |cos|)), is reported beside it.
    by_name = {row["name"]: row for row in rows}
    leaders = [row for row in rows if row["significant"]] or rows[:1]
    for row in leaders:
        if row["invisible"]:
            continue
        a = names.index(row["name"])
        partners = []
        for b in range(k_eff):
            other = by_name[names[b]]
            if b == a or not np.isfinite(cos[a, b]) or other["invisible"] or other["score"] <= 0:
                continue
            c = abs(cos[a, b])
            log_lr = 0.5 * (row["score"] ** 2 - other["score"] ** 2)
            gap_sd = float(np.sqrt(max(2.0 * (1.0 - c), 0.0)))
            near_tie = c >= near_tie_cosine and log_lr < near_tie_log_lr
            if c >= ambiguity_cosine or near_tie:
                partners.append((names[b], cos[a, b], row["score"] - other["score"], gap_sd, log_lr))
        if partners:
            row["ambiguous"] = True
            needs = "; ".join(
                sorted(
                    {catalogue[n].separated_by for n, *_ in [*partners, (row["name"],)] if catalogue[n].separated_by}
                )
            )
            txt = ", ".join(
                f"{n} (cos {c:+.3f}, score gap {g:.2f}, gap noise sd {gs:.2f}, log LR {lr:.1f})"
                for n, c, g, gs, lr in partners
            )
            row["note"] = f"ambiguous with {txt}: these summaries cannot tell them apart" + (
                f"; needs {needs}" if needs else ""
            )
            ambiguities.append(f"{row['name']}: {row['note']}")
        else:
            others = [(names[b], cos[a, b]) for b in range(k_eff) if b != a and np.isfinite(cos[a, b])]
            if others:
                name_b, c = max(others, key=lambda x: abs(x[1]))
                row["note"] = f"closest competitor {name_b} (cos {c:+.2f})"
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
