"""The synthetic-likelihood model from a run's simulations: one fit for the design loop
(:mod:`.algorithm`) and for the evidence (:mod:`.evidence`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.surrogate import emulator, sampling
from jaxabc.surrogate._support import _noise_correlation

#: Roles of a state's rows: unused, design, held out, held out in a failed validation (then design).
ROLE_EMPTY, ROLE_DESIGN, ROLE_HOLDOUT, ROLE_FAILED_HOLDOUT = -1, 0, 1, 2


def fit_likelihood(
    state,
    low: np.ndarray,
    high: np.ndarray,
    observed: np.ndarray,
    max_outputs: int,
    max_simulations: int,
    log_min_feasibility: jax.Array,
    drop: np.ndarray | None = None,
) -> tuple[emulator.OutputTransform, emulator.Emulator, sampling.LikelihoodModel, np.ndarray]:
    """Emulator on the successful design rows of ``state`` (a SurrogateState); ``drop`` (bool,
    shape (M,)) leaves rows out.  Returns (transform, emulator, likelihood model, z_all), z_all
    every row's summaries in emulated-output coordinates.

    Raises
    ------
    RuntimeError
        Fewer than 3 successful design runs.
    """
    thetas = np.asarray(state.thetas, np.float64)
    summaries = np.asarray(state.summaries, np.float64)
    role, ok = np.asarray(state.role), np.asarray(state.ok, bool)
    used = role != ROLE_EMPTY
    if drop is not None:
        used = used & ~drop
    rows = used & ok & (role != ROLE_HOLDOUT)
    if rows.sum() < 3:
        raise RuntimeError(
            f"surrogate: only {int(rows.sum())} of {int(used.sum())} simulations succeeded; "
            "the emulator needs at least 3. Check the simulator or narrow the prior"
        )
    transform = emulator.fit_transform(summaries[rows], max_outputs)
    z_all = np.asarray(transform.apply(jnp.asarray(np.nan_to_num(summaries))))
    x_all = (thetas - low) / (high - low)
    emu = emulator.fit(x_all, z_all, rows)
    loo = np.asarray(emulator.loo_residuals(emu))[rows]
    # An output constant over the design (a summary the data set does not measure, zeroed by
    # the simulator) carries no information about theta: out of the likelihood.
    active = np.std(z_all[rows], axis=0) > 1e-9
    corr = _noise_correlation(loo, active)
    feas = sampling.fit_feasibility(x_all[used], ok[used], size=int(max_simulations))
    z_obs = transform.apply(jnp.asarray(np.asarray(observed, np.float64).reshape(-1)))
    model = sampling.LikelihoodModel(
        emu, z_obs, jnp.linalg.cholesky(jnp.asarray(corr)), feas, jnp.asarray(active), log_min_feasibility
    )
    return transform, emu, model, z_all
