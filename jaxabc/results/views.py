"""Views of an :class:`~jaxabc.results.ABCResult` that need optional libraries: ArviZ, matplotlib.

Functions of the result object, so that :mod:`jaxabc.results` stays small and imports neither.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["plot_posterior", "to_arviz"]


def to_arviz(result: Any, num_draws: int | None = None, seed: int = 0) -> Any:
    """The posterior as an ArviZ ``InferenceData``.

    Groups: ``posterior`` (one variable per parameter name), ``sample_stats``
    (``distance`` of each draw), ``observed_data`` (``observed``, when the run stored it) and
    ``constant_data`` (per-step ``threshold``, ``simulations``, ``acceptance_rate``,
    ``ess``).  An ABCsubsim population is given as its chains (``num_chains`` chains of
    ``1 / P0`` draws), so ArviZ's diagnostics see the autocorrelation; any other posterior
    is resampled by weight into one chain of ``num_draws`` equally weighted draws
    (default: as many as particles).  ``attrs`` state the algorithm, how the draws were
    made and the effective sample size.

    Raises
    ------
    ImportError
        Without ArviZ (``pip install arviz``, or the ``arviz`` extra of jaxabc).
    """
    try:
        with warnings.catch_warnings():
            # ArviZ 0.x announces its 1.0 refactor with a FutureWarning on import.
            warnings.simplefilter("ignore", FutureWarning)
            import arviz as az
    except ImportError as exc:
        raise ImportError("to_arviz needs ArviZ: pip install arviz") from exc
    if result._is_chain_population() and num_draws is None:
        from jaxabc.algorithms.subsim import level_chains

        num_chains = int(result.settings["num_chains"])
        draws = level_chains(result.particles, num_chains)
        distances = level_chains(np.asarray(result.distances)[:, None], num_chains)[..., 0]
        how = f"ABCsubsim chains: {num_chains} chains of {draws.shape[1]} states"
    else:
        n = result.particles.shape[0] if num_draws is None else int(num_draws)
        if n < 1:
            raise ValueError(f"num_draws must be a positive integer, got {num_draws}")
        rng = np.random.default_rng(seed)
        idx = rng.choice(result.particles.shape[0], size=n, p=result.weights)
        draws = result.particles[idx][None]
        distances = np.asarray(result.distances)[idx][None]
        how = f"{n} draws resampled by weight (seed {seed})"
    posterior = {name: draws[..., j] for j, name in enumerate(result.names)}
    constant = {
        "threshold": np.asarray(result.thresholds, np.float64),
        "simulations": np.asarray(result.simulations_per_step),
        "acceptance_rate": np.asarray(result.acceptance_rates, np.float64),
        "ess": np.asarray(result.ess, np.float64),
    }
    dims = {k: ["step"] for k in constant}
    observed = result.metadata.get("observed")
    kwargs = {}
    if observed is not None:
        kwargs["observed_data"] = {"observed": np.asarray(observed, np.float64)}
    with warnings.catch_warnings():
        # ABCsubsim has more chains than draws by design; ArviZ warns about that shape.
        warnings.filterwarnings("ignore", message="More chains", category=UserWarning)
        return az.from_dict(
            posterior=posterior,
            sample_stats={"distance": np.asarray(distances, np.float64)},
            constant_data=constant,
            dims=dims,
            attrs={
                "algorithm": result.algorithm,
                "draws": how,
                "effective_sample_size": result.effective_sample_size(),
                "stop_reason": result.stop_reason,
                "inference_library": "jaxabc",
            },
            **kwargs,
        )


def plot_posterior(
    result: Any,
    path: str | Path | None = None,
    truth: np.ndarray | None = None,
    params: tuple[int, int] = (0, 1),
    ax: Any = None,
) -> Any:
    """Weighted Gaussian-KDE contours of two parameters, the Bayes estimate and the truth.

    Returns the matplotlib figure; saves it when ``path`` is given.
    """
    try:
        import matplotlib
    except ImportError as exc:  # the optional `plotting` extra
        raise ImportError("plot_posterior needs matplotlib: pip install 'jaxabc[plotting]'") from exc

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from scipy.stats import gaussian_kde

    i, j = params
    if ax is None:
        fig, ax = plt.subplots(figsize=(5, 4))
    else:
        fig = ax.figure
    x, y = result.particles[:, i], result.particles[:, j]
    est = result.bayes_estimate()
    try:
        kde = gaussian_kde(np.vstack([x, y]), weights=result.weights)
        pad_x, pad_y = 0.25 * np.ptp(x) + 1e-12, 0.25 * np.ptp(y) + 1e-12
        gx, gy = np.meshgrid(
            np.linspace(x.min() - pad_x, x.max() + pad_x, 120), np.linspace(y.min() - pad_y, y.max() + pad_y, 120)
        )
        z = kde(np.vstack([gx.ravel(), gy.ravel()])).reshape(gx.shape)
        cs = ax.contourf(gx, gy, z, levels=12, cmap="Blues")
        fig.colorbar(cs, ax=ax, label="posterior density")
    except (np.linalg.LinAlgError, ValueError):
        pass  # a degenerate sample has no KDE; the scatter below still shows it
    ax.scatter(x, y, s=4 + 200 * result.weights / result.weights.max(), c="k", alpha=0.3, lw=0)
    ax.plot(est[i], est[j], "r*", ms=14, label="Bayes estimate")
    if truth is not None:
        ax.plot(truth[i], truth[j], "gX", ms=11, label="true value")
    units = result.prior.units
    ax.set_xlabel(f"{result.names[i]}" + (f" [{units[i]}]" if units[i] else ""))
    ax.set_ylabel(f"{result.names[j]}" + (f" [{units[j]}]" if units[j] else ""))
    ax.set_title(f"{result.algorithm}: corr {result.correlation()[i, j]:+.3f}")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=120)
    return fig
