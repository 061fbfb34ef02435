"""The synthetic-likelihood model from a run's simulations: one fit for the design loop
(:mod:`.algorithm`) and for the evidence (:mod:`.evidence`)."""

from __future__ import annotations

from typing import Any

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
    *,
    observation_error: np.ndarray | None = None,
    discrepancy: Any = None,
) -> tuple[emulator.OutputTransform, emulator.Emulator, sampling.LikelihoodModel, np.ndarray]:
    """Emulator on the successful design rows of ``state`` (a SurrogateState); ``drop`` (bool,
    shape (M,)) leaves rows out.  Returns (transform, emulator, likelihood model, z_all), z_all
    every row's summaries in emulated-output coordinates.

    ``observation_error`` (k, k), the measurement covariance in summary units, and
    ``discrepancy`` (a :class:`jaxabc.noise.ResolvedDiscrepancy`) are mapped into the emulated
    outputs' coordinates (:func:`.sampling.output_map`) and carried by the model.

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
    extra = measured_data_terms(transform, observation_error, discrepancy)
    model = sampling.LikelihoodModel(
        emu, z_obs, jnp.linalg.cholesky(jnp.asarray(corr)), feas, jnp.asarray(active), log_min_feasibility, *extra
    )
    return transform, emu, model, z_all


def measured_data_terms(
    transform: emulator.OutputTransform, observation_error: np.ndarray | None, discrepancy: Any
) -> tuple[jax.Array | None, jax.Array | None, jax.Array | None]:
    """``(observation_cov (q, q), discrepancy_basis (G, q, q), discrepancy_max_sd (G,))`` of
    :class:`.sampling.LikelihoodModel` (None where not given): ``T M T^T`` and ``T diag(m_g) T^T``."""
    t = sampling.output_map(transform)
    obs_cov = basis = max_sd = None
    if observation_error is not None:
        m = np.asarray(observation_error, np.float64)
        c = t @ m @ t.T
        obs_cov = jnp.asarray(0.5 * (c + c.T))
    if discrepancy is not None:
        member = np.asarray(discrepancy.membership, np.float64)
        basis = jnp.asarray(np.einsum("qk,gk,pk->gqp", t, member, t))
        max_sd = jnp.asarray(np.asarray(discrepancy.max_sd, np.float64))
    return obs_cov, basis, max_sd


def measured_data_settings(observation_error: np.ndarray | None, discrepancy: Any) -> dict:
    """The settings entries (JSON) that describe them; empty when neither is given, so that runs
    without them keep their checkpoint fingerprints."""
    out: dict = {}
    if observation_error is not None:
        out["observation_error"] = np.asarray(observation_error, np.float64).tolist()
    if discrepancy is not None:
        out["discrepancy"] = {
            "membership": np.asarray(discrepancy.membership, np.float64).tolist(),
            "max_sd": np.asarray(discrepancy.max_sd, np.float64).tolist(),
            "names": list(discrepancy.names),
        }
    return out


def measured_data_from_settings(settings: dict) -> tuple[np.ndarray | None, Any]:
    """Inverse of :func:`measured_data_settings`: ``(observation_error, ResolvedDiscrepancy)``."""
    from jaxabc.noise import ResolvedDiscrepancy

    error = settings.get("observation_error")
    disc = settings.get("discrepancy")
    resolved = None
    if disc is not None:
        resolved = ResolvedDiscrepancy(
            np.asarray(disc["membership"], np.float64), np.asarray(disc["max_sd"], np.float64), tuple(disc["names"])
        )
    return (None if error is None else np.asarray(error, np.float64)), resolved
