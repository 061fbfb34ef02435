"""Where to simulate: a space-filling start, then batches where the posterior is most uncertain.

The start is a scrambled Sobol sequence in the prior box.  Replicate runs, whose scatter
measures the simulator's own noise, follow once enough runs have succeeded, at two of the
successful sites (:func:`replicate_sites`): placed in advance (the box centre, the first Sobol
point) they land where runs fail whenever most of the box does (water's prior vaporises), and
the nugget is then fitted from a handful of scattered runs, usually at its lower bound.

Later batches maximise a posterior-weighted emulator uncertainty, in the spirit of the
``MAXV`` rule of Järvenpää et al. (2019, Bayesian Analysis 14, 595): ``a(x) = pi(x)
sqrt(mean_j var_j(x) / noise_j^2) p_feasible(x)``, with ``pi`` the current surrogate posterior
density (which contains ``p_feasible`` too) and the last factor the chance that a run at ``x``
succeeds at all, so regions where runs fail are avoided.  A batch is chosen
greedily; each pick multiplies the acquisition by ``1 - exp(-|x - x_pick|^2_ell / 2)`` with
``ell`` half the posterior sd or the emulator's length scale where shorter (local
penalisation, González et al. 2016), so that the workers of one batch explore different places.
``ell`` never falls below a tenth of the length scale (:func:`penalty_radius`): two runs that
close are near-replicates, and a posterior collapsed onto one candidate would otherwise repeat
one point across the batch.  Runs that failed are penalised the same way before the first pick:
they teach the emulator nothing, so its variance, and the acquisition, stays high right there.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.linalg
import scipy.special
import scipy.stats

__all__ = [
    "MIN_DESIGN_SUCCESS",
    "MIN_RADIUS_FRACTION",
    "Candidates",
    "acquisition",
    "candidates",
    "design_level",
    "importance_pool",
    "initial_design",
    "kish_ess",
    "mixture_candidates",
    "penalty_radius",
    "replicate_groups",
    "replicate_sites",
    "select_batch",
]

#: Floor of the penalisation radius, in emulator length scales: a run 0.1 length scales from
#: another is 99.5 % correlated with it under the squared-exponential kernel.
MIN_RADIUS_FRACTION = 0.1

#: Design runs go only where the success classifier expects a run to succeed at least this
#: often.  The posterior keeps its own, lower level (``min_feasibility``): when the data pull
#: the likelihood beyond the feasible region, the posterior piles against that level, and an
#: acquisition free to follow it would place run after run where most fail.
MIN_DESIGN_SUCCESS = 0.5


def initial_design(seed: int, dim: int, num_points: int, num_replicates: int) -> tuple[np.ndarray, np.ndarray]:
    """Space-filling points in the unit box and replicate groups.

    Parameters
    ----------
    seed : int
        Scrambling seed of the Sobol sequence.
    dim, num_points : int
        Dimension and number of distinct space-filling points.
    num_replicates : int
        Extra runs: ``ceil(r / 2)`` at the box centre (group 0) and ``floor(r / 2)`` repeating
        the first Sobol point (group 1, which includes that point itself).

    Returns
    -------
    x : array, shape (num_points + num_replicates, dim)
    group : array of int, shape (num_points + num_replicates,)
        Replicate group per row, -1 for unreplicated points.
    """
    # seed= (scipy < 1.15 has no rng=) is added by scipy's rng-transition decorator, unseen by
    # its annotations.
    sobol = scipy.stats.qmc.Sobol(dim, scramble=True, seed=seed)  # pyright: ignore[reportCallIssue]
    # The first 2^m points of a scrambled Sobol sequence are balanced; taking the first n of
    # them keeps low discrepancy without scipy's warning about non-powers of two.
    x = sobol.random_base2(int(np.ceil(np.log2(max(num_points, 2)))))[:num_points]
    n_centre, n_first = (num_replicates + 1) // 2, num_replicates // 2
    x = np.concatenate([x, np.full((n_centre, dim), 0.5), np.repeat(x[:1], n_first, axis=0)])
    return x, replicate_groups(num_points, num_replicates)


def replicate_groups(num_points: int, num_replicates: int) -> np.ndarray:
    """Replicate group of each row of :func:`initial_design` (-1: unreplicated)."""
    n_centre, n_first = (num_replicates + 1) // 2, num_replicates // 2
    group = np.full(num_points + num_replicates, -1, np.int32)
    if n_first:
        group[0] = 1
    group[num_points : num_points + n_centre] = 0
    group[num_points + n_centre :] = 1
    return group


def replicate_sites(x_ok: np.ndarray, x_failed: np.ndarray, num_replicates: int) -> tuple[np.ndarray, np.ndarray]:
    """Where ``num_replicates`` repeat runs go: two of the successful runs ``x_ok (n, d)``.

    Site 0 is the successful run farthest from every failed run ``x_failed (m, d)`` (unit box),
    so that its repeats succeed too; site 1 the one farthest from the failed runs and from site
    0, so that the noise is measured in two places.  Distances count up to half the box;
    ties go to the run nearest the box centre (site 0) or the earliest run (site 1), so with no
    failures site 0 is near the centre and site 1 a Sobol point half a box away.

    Returns
    -------
    site : array of int, shape (2,), or (1,) with one successful run or one repeat
        Row of ``x_ok`` of each site (its own run joins the group).
    count : array of int, same shape
        Repeats per site: ``ceil(r / 2)`` and ``floor(r / 2)``.
    """
    x_ok = np.asarray(x_ok, np.float64)
    if x_ok.shape[0] == 0 or num_replicates < 1:
        raise ValueError("replicate_sites needs a successful run and num_replicates >= 1")
    x_failed = np.asarray(x_failed, np.float64).reshape(-1, x_ok.shape[1])

    def distance_to(points: np.ndarray) -> np.ndarray:
        if points.shape[0] == 0:
            return np.full(x_ok.shape[0], 0.5)
        d = np.sqrt(np.min(np.sum((x_ok[:, None, :] - points[None]) ** 2, axis=-1), axis=1))
        return np.minimum(d, 0.5)

    from_failed = distance_to(x_failed)
    # np.lexsort sorts by its last key first: distance (descending), then the tie-breaker.
    first = int(np.lexsort((np.sum((x_ok - 0.5) ** 2, axis=1), -from_failed))[0])
    if x_ok.shape[0] == 1 or num_replicates < 2:
        return np.array([first]), np.array([num_replicates])
    spread = np.minimum(from_failed, distance_to(x_ok[first : first + 1]))
    spread[first] = -1.0
    second = int(np.lexsort((np.arange(x_ok.shape[0]), -spread))[0])
    return np.array([first, second]), np.array([(num_replicates + 1) // 2, num_replicates // 2])


class Candidates:
    """Points where the acquisition and the importance-weighted posterior are evaluated.

    A defensive mixture: half uniform in the box (Sobol), half from a Gaussian fitted to the
    current posterior (inflated twice), so narrow posteriors are resolved in any dimension.

    Attributes
    ----------
    x : array, shape (n, d)
        Unit-box points.
    log_q : array, shape (n,)
        Log density of the mixture at ``x`` (for importance weights).
    """

    def __init__(self, x: np.ndarray, log_q: np.ndarray):
        self.x, self.log_q = x, log_q


def candidates(
    rng: np.random.Generator, dim: int, num: int, centre: np.ndarray | None = None, cov: np.ndarray | None = None
) -> Candidates:
    """Draw ``num`` candidates; with ``centre``/``cov`` (unit-box coordinates) half are local.

    The local Gaussian is ``cov`` inflated twice, floored at the uniform half's spacing
    ``num**(-1/d)``: a posterior narrower than that grid was seen by at most one uniform point,
    and its weighted covariance is then near zero, not the posterior's.
    """
    # seed= as in initial_design (scipy's decorator adds it; its annotations do not show it).
    sobol = scipy.stats.qmc.Sobol(dim, scramble=True, seed=rng)  # pyright: ignore[reportCallIssue]
    n_uniform = num if centre is None else num // 2
    xu = sobol.random_base2(int(np.ceil(np.log2(n_uniform))))[:n_uniform]
    if centre is None:
        return Candidates(xu, np.zeros(n_uniform))
    assert cov is not None, "a local proposal needs both centre and cov"
    spacing = float(num) ** (-1.0 / dim)
    local_cov = 4.0 * (np.asarray(cov) + spacing**2 * np.eye(dim))
    draws = rng.multivariate_normal(centre, local_cov, size=4 * (num - n_uniform))
    inside = np.all((draws > 0) & (draws < 1), axis=1)
    frac_inside = max(inside.mean(), 1.0 / draws.shape[0])
    xl = draws[inside][: num - n_uniform]
    x = np.concatenate([xu, xl])
    # scipy's unannotated multivariate_normal(mean=None, cov=1) makes pyright infer cov: int.
    mvn = scipy.stats.multivariate_normal(centre, local_cov)  # pyright: ignore[reportArgumentType]
    local = mvn.logpdf(x).reshape(-1) - np.log(frac_inside)
    log_q = np.logaddexp(np.log(n_uniform / len(x)), np.log(len(xl) / len(x)) + local)
    return Candidates(x, log_q)


def mixture_candidates(
    rng: np.random.Generator, dim: int, num: int, means: np.ndarray, covs: np.ndarray, mix: np.ndarray
) -> Candidates:
    """Like :func:`candidates`, the local half from a Gaussian mixture: ``means (k, d)``,
    ``covs (k, d, d)``, mixing weights ``mix (k,)`` (summing to one), truncated to the box."""
    sobol = scipy.stats.qmc.Sobol(dim, scramble=True, seed=rng)  # pyright: ignore[reportCallIssue]
    n_uniform = num // 2
    xu = sobol.random_base2(int(np.ceil(np.log2(n_uniform))))[:n_uniform]
    n_draw = 4 * (num - n_uniform)
    chol = np.linalg.cholesky(covs)
    comp = rng.choice(len(mix), size=n_draw, p=mix)
    draws = means[comp] + np.einsum("nij,nj->ni", chol[comp], rng.standard_normal((n_draw, dim)))
    inside = np.all((draws > 0) & (draws < 1), axis=1)
    frac_inside = max(inside.mean(), 1.0 / n_draw)
    xl = draws[inside][: num - n_uniform]
    x = np.concatenate([xu, xl])
    # log N(x; m_k, C_k) for every component, from the Cholesky factors.
    diff = x[:, None, :] - means[None, :, :]
    r = np.stack([scipy.linalg.solve_triangular(chol[k], diff[:, k].T, lower=True) for k in range(len(mix))])
    log_det = np.sum(np.log(np.diagonal(chol, axis1=1, axis2=2)), axis=1)
    log_n = -0.5 * np.sum(r**2, axis=1).T - log_det - 0.5 * dim * np.log(2.0 * np.pi)
    local = scipy.special.logsumexp(log_n + np.log(mix), axis=1) - np.log(frac_inside)
    log_q = np.logaddexp(np.log(n_uniform / len(x)), np.log(len(xl) / len(x)) + local)
    return Candidates(x, log_q)


def kish_ess(log_weights: np.ndarray) -> float:
    """Kish effective sample size ``(sum w)^2 / sum w^2`` of log weights ``(n,)``."""
    w = np.exp(np.asarray(log_weights, np.float64) - np.max(log_weights))
    return float(w.sum() ** 2 / np.sum(w**2))


#: Refinements of :func:`importance_pool`'s local proposal at most.  Each divides the kernel
#: variance by ``REFINE_FACTOR``, starting from the uniform spacing's square over it: eight
#: reach a posterior 4**9 times narrower (in sd) than the spacing of the pool's uniform half.
MAX_REFINEMENTS = 8
REFINE_FACTOR = 16.0
#: Kernel centres of a refinement, drawn by weight from the pass before.
NUM_KERNELS = 64
#: Effective sample size :func:`importance_pool` wants by default: one per this many points.
POINTS_PER_ESS = 16


def importance_pool(
    rng: np.random.Generator,
    dim: int,
    num: int,
    evaluate: Callable[[np.ndarray], tuple[np.ndarray, ...]],
    first_num: int | None = None,
    target_ess: float | None = None,
) -> tuple[Candidates, tuple[np.ndarray, ...]]:
    """Importance points for a log density on the unit box, refined until they resolve it.

    A uniform (Sobol) pass of ``first_num`` points (default ``num``) locates the density; a
    pass of ``num`` :func:`candidates` (the defensive mixture) around its weighted mean and
    covariance follows.  While a pass's Kish ESS is below ``target_ess`` (default
    ``num / POINTS_PER_ESS``), the next pass draws its local half from a Gaussian mixture
    (:func:`mixture_candidates`): half the weighted Gaussian of the last pass, half
    ``NUM_KERNELS`` kernels at its weighted draws, their variance floor divided by
    ``REFINE_FACTOR`` each time, up to ``MAX_REFINEMENTS`` times.  Without this a posterior far
    narrower than the uniform spacing (a sharp synthetic likelihood on misfitting data) is seen
    by one point, an ESS of 1.  The pass with the largest ESS is returned; when the first local
    pass reaches the target nothing else is drawn.  A mode that no point of a pass weighs is
    not found: the uniform pass must see each (its log density a few tens of nats, not
    hundreds, below the peak's at the nearest uniform point).

    Parameters
    ----------
    evaluate : callable
        ``x (n, d) -> (log_density (n,), *extras)``; the extras are returned with the points.

    Returns
    -------
    points : Candidates
    values : tuple of arrays
        ``evaluate(points.x)``.

    Raises
    ------
    FloatingPointError
        Where the log density is not finite anywhere in the first pass.
    """
    target = num / POINTS_PER_ESS if target_ess is None else target_ess
    first = candidates(rng, dim, first_num or num)
    values = evaluate(first.x)
    log_w = values[0] - first.log_q
    if not np.any(np.isfinite(log_w)):
        raise FloatingPointError("the log density is not finite anywhere in the box")
    w = np.exp(log_w - np.max(log_w))
    w /= w.sum()
    centre = w @ first.x
    cov = (first.x - centre).T @ ((first.x - centre) * w[:, None])
    points = candidates(rng, dim, num, centre, cov)
    variance = float(num) ** (-2.0 / dim)
    best: tuple[float, Candidates, tuple[np.ndarray, ...]] | None = None
    for refinement in range(MAX_REFINEMENTS + 1):
        values = evaluate(points.x)
        log_w = values[0] - points.log_q
        ess = kish_ess(log_w) if np.any(np.isfinite(log_w)) else 0.0
        if best is None or ess > best[0]:
            best = (ess, points, values)
        if ess >= target or refinement == MAX_REFINEMENTS:
            break
        # Half the local mass on the weighted Gaussian, half on kernels at draws of the latest
        # pass, both narrower each time: the Gaussian follows a ridge to its peak, the kernels
        # home in on every mode the pass saw (one Gaussian would span the valleys between two).
        w = np.exp(log_w - np.max(log_w))
        w /= w.sum()
        centre = w @ points.x
        cov = (points.x - centre).T @ ((points.x - centre) * w[:, None])
        tempered = np.sqrt(w)
        centres = points.x[rng.choice(len(w), size=NUM_KERNELS, p=tempered / tempered.sum())]
        variance /= REFINE_FACTOR
        eye = np.eye(dim)
        means = np.concatenate([centre[None], centres])
        kernels = np.repeat(4.0 * variance * eye[None], NUM_KERNELS, axis=0)
        covs = np.concatenate([4.0 * (cov + variance * eye)[None], kernels])
        mix = np.concatenate([[0.5], np.full(NUM_KERNELS, 0.5 / NUM_KERNELS)])
        points = mixture_candidates(rng, dim, num, means, covs, mix)
    assert best is not None
    return best[1], best[2]


def design_level(p_ok: np.ndarray) -> float:
    """Least success probability of a design point: ``MIN_DESIGN_SUCCESS``, or the best of the
    candidates' ``p_ok (n,)`` where none reaches it (a simulator that fails often everywhere)."""
    return min(MIN_DESIGN_SUCCESS, float(np.max(p_ok, initial=0.0)))


def acquisition(log_posterior: np.ndarray, emulator_ratio: np.ndarray, p_ok: np.ndarray) -> np.ndarray:
    """``pi(x) sqrt(var / noise^2) p_ok(x)`` at candidates (arrays (n,)), 0 where ``p_ok`` is
    below :func:`design_level`, scaled so that its maximum is 1.

    Computed in logs and scaled over the eligible candidates only: scaled over all of them, a
    posterior peak beyond the design level (thousands of nats above the rest, where the data
    pull the likelihood into a failing region) underflows every eligible candidate to 0.
    """
    with np.errstate(divide="ignore"):
        log_a = np.asarray(log_posterior, np.float64) + 0.5 * np.log(emulator_ratio) + np.log(p_ok)
    log_a = np.where(p_ok >= design_level(p_ok), log_a, -np.inf)
    return np.exp(log_a - np.max(log_a))


def penalty_radius(emulator_ls: np.ndarray, posterior_sd: np.ndarray) -> np.ndarray:
    """Penalisation radii (d,), unit-box widths: half the posterior sd, capped at the emulator's
    length scale ``emulator_ls (d,)`` and floored at ``MIN_RADIUS_FRACTION`` of it."""
    ls = np.asarray(emulator_ls, np.float64)
    return np.maximum(np.minimum(ls, 0.5 * np.asarray(posterior_sd, np.float64)), MIN_RADIUS_FRACTION * ls)


def select_batch(
    x: np.ndarray, acquisition: np.ndarray, lengthscales: np.ndarray, size: int, avoid: np.ndarray | None = None
) -> np.ndarray:
    """Greedy batch of ``size`` rows of ``x (n, d)`` maximising the locally penalised acquisition.

    ``lengthscales (d,)``, the penalisation radii, are in unit-box widths; the acquisition is
    penalised around each row of ``avoid (m, d)`` (failed runs) before the first pick.  Returns
    indices (size,).
    """
    a = np.where(np.isfinite(acquisition), acquisition, 0.0).copy()
    for x0 in () if avoid is None else avoid:
        a *= 1.0 - np.exp(-0.5 * np.sum(((x - x0) / lengthscales) ** 2, axis=1))
    chosen = []
    for _ in range(size):
        i = int(np.argmax(a))
        chosen.append(i)
        r2 = np.sum(((x - x[i]) / lengthscales) ** 2, axis=1)
        a *= 1.0 - np.exp(-0.5 * r2)
        a[i] = -np.inf
    return np.asarray(chosen)
