"""The helium Lennard-Jones model of Dutta, Brotzakis & Mira (2018), in process on jax-md.

The model: N helium atoms (4.0026 amu) interacting by a plain-truncated LJ 12-6 potential with a
fixed 0.639 nm cutoff, NPT with Nose-Hoover chains at 300 K; parameters
theta = (sigma_nm, epsilon_zJ), truth (0.2556 nm, 0.141 zJ), prior U[0.1, 0.8] x U[0.01, 1.0].
The summary is the time series

    f_B(t) = exp(-H(t) / (N k_B T_inst(t))),    H = KE + U + P_inst V,

sampled at a fixed interval after equilibration (LAMMPS ``units nano``, thermo keyword
``enthalpy``, as the published pipeline did).  Because ``P_inst V = 2 KE / 3 + W / 3`` (W the
virial) and ``KE = (dof / 2) k_B T_inst`` with dof = 3N - 3, this is exactly
``exp(-5 dof / (6 N)) * exp(-(U + W/3) / (N k_B T_inst))``: the kinetic part cancels and what
carries information about (sigma, epsilon) is configurational.  The ideal-gas limit is
``exp(-2.5 (N - 1) / N)``.

Presets
-------
``paper``: the published settings (1000 atoms, 27.3 nm box, 300 K, 1 atm, r_c 0.639 nm, 2 fs,
tau_T 2 ps, tau_P 20 ps, 0.2 ns equilibration, f_B every 2 ps over 2 ns; the observed series is
4x longer, as the paper's 20 ns observed vs 5 ns simulated).  A neighbour list, members run one
at a time.

``cpu`` (default): 32 atoms at 100 atm, 4 fs steps, tau_T = tau_P = 0.5 ps, 4 ps equilibration,
f_B every 0.1 ps over 10 ps, all pairs (nothing can overflow), vmapped over parameters.  Chosen
by ``benchmarks/helium_identifiability.py`` (results in ``benchmarks/results/``): at 1 atm a
short run of a small system sees almost no collisions and seed noise swamps the parameters; at
100 atm (still a dilute gas) the configurational part of f_B separates (sigma, epsilon) within
picoseconds.  ``benchmarks/helium_lammps_agreement.py`` checks it against LAMMPS.

``cpu64``: ``cpu`` with 64 atoms, about 3x the cost per simulation.  The same study finds that
it tells near-truth parameters (sigma 10 % off, or epsilon 40 % off) from the truth 70 % of
the time, against 7 % for 32 atoms; the helium Table 1 uses it.

The prior corner sigma > r_c / 2.5 = 0.2556 nm
----------------------------------------------
The cutoff stays at 0.639 nm for every sigma (as in the paper's LAMMPS input), so for
sigma > 0.639 nm the potential is a repulsive step at r_c.  The engine keeps the paper's model:
forces are the analytic LJ forces inside r_c and zero outside (LAMMPS ``lj/cut``), the
thermostat absorbs the energy not conserved across the step, and the summaries stay finite.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
import os
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from md._presets import resolve_preset
from md.lj import Carry, EngineConfig, LJEngine, LJParams
from md.lj.batch import batched  # noqa: F401  (re-exported: benchmarks use helium.batched)
from md.units import (
    BOLTZMANN_KJ_MOL_K,
    HELIUM_MASS_AMU,
    ZJ_IN_KJ_MOL,
    atm_to_kj_mol_nm3,
)

__all__ = [
    "PRESETS",
    "PRIOR_HIGH",
    "PRIOR_LOW",
    "TRUE_THETA",
    "HeliumPreset",
    "f_b_ideal_gas",
    "get_preset",
    "make_batch_simulator",
    "make_engine",
    "make_simulator",
    "observed_series",
]

#: True (sigma_nm, epsilon_zJ) of the paper's simulated data.
TRUE_THETA = (0.2556, 0.141)
#: Prior bounds (uniform) of (sigma_nm, epsilon_zJ).
PRIOR_LOW = (0.1, 0.01)
PRIOR_HIGH = (0.8, 1.0)


@dataclasses.dataclass(frozen=True)
class HeliumPreset:
    """Settings of one helium set-up.

    Parameters
    ----------
    name : str
    num_atoms : int
    temperature_k : float
    pressure_atm : float
    box_nm : float or None
        Initial cubic box side, nm; None: the ideal-gas box at (N, P, T).
    cutoff_nm : float
        LJ cutoff, nm (the paper's 0.639).
    dt_ps : float
        Time step, ps.
    tau_t_ps, tau_p_ps : float
        Nose-Hoover damping times, ps.
    equilibration_ps : float
        NPT equilibration before the first sample, ps.
    production_ps : float
        Length of the sampled series, ps (samples = production / interval).
    sample_every_ps : float
        Interval between f_B samples, ps.
    observed_factor : int
        The observed series is this many times longer than a simulated one.
    use_neighbor_list : bool
        Neighbour list (large boxes) or all pairs (small systems).
    skin_nm : float
    rebuild_every : int
        Steps per block (list rebuild, or the check for one, at each block start).
    rebuild : str
        ``"every_block"`` or ``"when_needed"`` (see :class:`md.lj.EngineConfig`).
    batch_size : int
        Members per compiled batch in :func:`make_batch_simulator`.
    vmap_width : int or None
        Members advanced together by ``jax.vmap`` inside a batch; the batch is a sequential
        ``jax.lax.map`` over groups of this size.  None: the whole batch in one vmap.  On CPU
        vmapping large systems is slower than running them one after another (XLA's batched
        gathers and scatters, and working sets beyond the caches); 32-atom systems need the
        vmap to amortise per-operation overhead (see benchmarks/engine_throughput.py).
    """

    name: str
    num_atoms: int
    temperature_k: float = 300.0
    pressure_atm: float = 1.0
    box_nm: float | None = None
    cutoff_nm: float = 0.639
    dt_ps: float = 0.002
    tau_t_ps: float = 2.0
    tau_p_ps: float = 20.0
    equilibration_ps: float = 200.0
    production_ps: float = 2000.0
    sample_every_ps: float = 2.0
    observed_factor: int = 4
    use_neighbor_list: bool = True
    skin_nm: float = 0.3
    rebuild_every: int = 10
    rebuild: str = "every_block"
    batch_size: int = 64
    vmap_width: int | None = None

    @property
    def initial_box_nm(self) -> float:
        """Initial box side, nm (ideal-gas volume N k_B T / P when ``box_nm`` is None)."""
        if self.box_nm is not None:
            return self.box_nm
        volume = self.num_atoms * BOLTZMANN_KJ_MOL_K * self.temperature_k / atm_to_kj_mol_nm3(self.pressure_atm)
        return float(volume ** (1.0 / 3.0))

    def _steps(self, ps: float, what: str, multiple: int) -> int:
        steps = round(ps / self.dt_ps)
        if abs(steps * self.dt_ps - ps) > 1e-6 * max(ps, 1.0) or steps % multiple:
            raise ValueError(
                f"{what} = {ps} ps is not a whole number of {multiple}-step blocks of "
                f"{self.dt_ps} ps: adjust it or rebuild_every"
            )
        return steps

    @property
    def blocks_per_sample(self) -> int:
        """Blocks of ``rebuild_every`` steps between samples."""
        return self._steps(self.sample_every_ps, "sample_every_ps", self.rebuild_every) // (self.rebuild_every)

    @property
    def equilibration_blocks(self) -> int:
        """Blocks of equilibration."""
        return self._steps(self.equilibration_ps, "equilibration_ps", self.rebuild_every) // (self.rebuild_every)

    @property
    def num_samples(self) -> int:
        """Samples in a simulated series."""
        n = round(self.production_ps / self.sample_every_ps)
        if n < 2:
            raise ValueError("production_ps must hold at least two samples")
        return n

    def engine_config(self) -> EngineConfig:
        """The :class:`md.lj.EngineConfig` of this preset."""
        return EngineConfig(
            num_atoms=self.num_atoms,
            box_nm=self.initial_box_nm,
            mass_amu=HELIUM_MASS_AMU,
            cutoff_nm=self.cutoff_nm,
            dt_ps=self.dt_ps,
            temperature_k=self.temperature_k,
            ensemble="npt",
            pressure_kj_mol_nm3=atm_to_kj_mol_nm3(self.pressure_atm),
            tau_t_ps=self.tau_t_ps,
            tau_p_ps=self.tau_p_ps,
            truncation="plain",
            use_neighbor_list=self.use_neighbor_list,
            skin_nm=self.skin_nm,
            rebuild_every=self.rebuild_every,
            rebuild=self.rebuild,
        )


PRESETS: dict[str, HeliumPreset] = {
    "paper": HeliumPreset(
        name="paper",
        num_atoms=1000,
        pressure_atm=1.0,
        box_nm=27.3,
        dt_ps=0.002,
        tau_t_ps=2.0,
        tau_p_ps=20.0,
        equilibration_ps=200.0,
        production_ps=2000.0,
        sample_every_ps=2.0,
        use_neighbor_list=True,
        # A dilute gas: rebuilds, not pairs, dominate, so a wide skin rebuilt only when needed
        # (members run one at a time, so the lax.cond is real), checked every 5 steps.
        # benchmarks/engine_throughput.py measures it against LAMMPS.
        skin_nm=0.6,
        rebuild_every=5,
        rebuild="when_needed",
        batch_size=16,
        vmap_width=1,
    ),
    "cpu": HeliumPreset(
        name="cpu",
        num_atoms=32,
        pressure_atm=100.0,
        dt_ps=0.004,
        tau_t_ps=0.5,
        tau_p_ps=0.5,
        equilibration_ps=4.0,
        production_ps=10.0,
        sample_every_ps=0.1,
        use_neighbor_list=False,
        rebuild_every=5,
        batch_size=64,
    ),
    "cpu64": HeliumPreset(
        name="cpu64",
        num_atoms=64,
        pressure_atm=100.0,
        dt_ps=0.004,
        tau_t_ps=0.5,
        tau_p_ps=0.5,
        equilibration_ps=4.0,
        production_ps=10.0,
        sample_every_ps=0.1,
        use_neighbor_list=False,
        rebuild_every=5,
        batch_size=64,
    ),
}


def get_preset(preset: str | HeliumPreset = "cpu", **overrides: Any) -> HeliumPreset:
    """Resolve a preset name (``"cpu"``, ``"cpu64"``, ``"paper"``) or object, with field overrides."""
    return resolve_preset(preset, PRESETS, "helium", **overrides)


@functools.lru_cache(maxsize=16)
def make_engine(preset: HeliumPreset) -> LJEngine:
    """The (cached) :class:`md.lj.LJEngine` of a preset."""
    return LJEngine(preset.engine_config())


def f_b_ideal_gas(num_atoms: int) -> float:
    """f_B of an ideal gas with 3N - 3 thermal degrees of freedom: exp(-2.5 (N - 1) / N)."""
    return float(np.exp(-2.5 * (num_atoms - 1) / num_atoms))


def _params(theta: jax.Array) -> LJParams:
    theta = jnp.asarray(theta, jnp.float32)
    return LJParams(theta[0], theta[1] * jnp.float32(ZJ_IN_KJ_MOL), jnp.float32(0.0))


@functools.lru_cache(maxsize=16)
def _f_b_observer(engine: LJEngine) -> Callable[[Carry, LJParams], jax.Array]:
    n = engine.config.num_atoms

    def observe(carry: Carry, params: LJParams) -> jax.Array:
        t = engine.thermo(carry, params)
        enthalpy = t.kinetic + t.potential + t.pressure * t.volume
        return jnp.exp(-enthalpy / (n * BOLTZMANN_KJ_MOL_K * t.temperature))

    return observe


def _trajectory(
    engine: LJEngine, preset: HeliumPreset, key: jax.Array, theta: jax.Array, num_samples: int
) -> tuple[jax.Array, Carry]:
    params = _params(theta)
    carry = engine.init(key, params)
    carry, _ = engine.run(carry, params, preset.equilibration_blocks, 1)
    carry, f_b = engine.run(carry, params, num_samples, preset.blocks_per_sample, _f_b_observer(engine))
    return f_b, carry


def make_simulator(
    preset: str | HeliumPreset = "cpu", num_samples: int | None = None, **overrides: Any
) -> Callable[[jax.Array, jax.Array], jax.Array]:
    """Build the pure-JAX helium simulator ``simulate(key, theta) -> f_B``.

    Parameters
    ----------
    preset : str or HeliumPreset
        ``"cpu"`` (default) or ``"paper"``, or a custom :class:`HeliumPreset`.
    num_samples : int, optional
        Length of the series; default ``preset.num_samples``.
    **overrides
        Fields of :class:`HeliumPreset` to change (e.g. ``production_ps=20.0``).

    Returns
    -------
    simulate : callable
        ``simulate(key, theta)`` with ``theta`` shape (2,) = (sigma_nm, epsilon_zJ) returns the
        f_B series, shape (num_samples,), float32.  Pure and vmappable over (key, theta); sigma
        and epsilon are traced (no recompilation per value).  If the neighbour list overflowed,
        the box fell below twice the cutoff, an atom outran the skin, or the state went
        non-finite, the series is all NaN (the core records a failure): a traced function cannot
        re-allocate, so use :func:`make_batch_simulator` where overflow may happen (the
        ``paper`` preset; the ``cpu`` preset uses all pairs and cannot overflow).
    """
    preset = get_preset(preset, **overrides)
    engine = make_engine(preset)
    n = preset.num_samples if num_samples is None else int(num_samples)

    def simulate(key: jax.Array, theta: jax.Array) -> jax.Array:
        f_b, carry = _trajectory(engine, preset, key, theta, n)
        d = carry.diagnostics
        bad = d.overflow | d.failed()
        return jnp.where(bad, jnp.nan, f_b)

    simulate.preset = preset  # type: ignore[attr-defined]
    return simulate


def make_batch_simulator(
    preset: str | HeliumPreset = "cpu",
    num_samples: int | None = None,
    samples_per_chunk: int | None = None,
    max_reallocations: int = 6,
    threads: int | None = None,
    **overrides: Any,
) -> Callable[[jax.Array, jax.Array], tuple[np.ndarray, np.ndarray]]:
    """Build the host-side batched simulator ``simulate_batch(keys, thetas) -> (f_B, ok)``.

    It runs the same trajectories as :func:`make_simulator` (same key -> same series), vmapped
    over ``preset.batch_size`` members at a time, in chunks of samples.  After every chunk it
    reads the diagnostics on the host (:meth:`md.lj.LJEngine.run_checked`): if any member's
    neighbour list overflowed the engine re-allocates a larger shared list and redoes the chunk
    for the whole group from its saved start, so no pair is ever dropped and results do not
    depend on which members shared a batch.

    Parameters
    ----------
    preset : str or HeliumPreset
    num_samples : int, optional
        Series length; default ``preset.num_samples``.
    samples_per_chunk : int, optional
        Samples between host checks; default 10% of the series (at least 1).
    max_reallocations : int
        Give up (mark the group failed) after this many re-allocations of one chunk.
    threads : int, optional
        Groups of ``batch_size`` run concurrently on this many threads (default: the CPU
        count) when the engine has no neighbour list; results do not depend on it.
    **overrides
        Fields of :class:`HeliumPreset`.

    Returns
    -------
    simulate_batch : callable
        ``simulate_batch(keys, thetas)`` with keys shape (b, 2) (or typed keys (b,)) and thetas
        shape (b, 2) returns ``(f_b, ok)``: numpy arrays of shapes (b, num_samples) float32
        (NaN rows where not ok) and (b,) bool.  A group is padded to ``batch_size`` by
        repeating its last member, so one compilation serves every batch.
    """
    preset = get_preset(preset, **overrides)
    engine = make_engine(preset)
    n = preset.num_samples if num_samples is None else int(num_samples)
    chunk = samples_per_chunk or max(1, n // 10)
    # A neighbour-list re-allocation changes the shared engine: groups then run one at a time.
    workers = 1 if engine.neighbor_fn is not None else int(threads or os.cpu_count() or 1)
    observe = _f_b_observer(engine)
    width = preset.vmap_width

    def run_group(keys: jax.Array, thetas: jax.Array) -> tuple[np.ndarray, np.ndarray]:
        params = jax.vmap(_params)(thetas)
        carry = engine.init_batch(keys, params, width, max_reallocations)
        ok_all = True
        per_chunk = chunk * preset.blocks_per_sample
        if preset.equilibration_blocks % per_chunk == 0:
            # Equilibrate with the production chunk's program, its observations discarded: one
            # XLA compilation fewer (seconds of a cold run); the dynamics are the same.
            for _ in range(preset.equilibration_blocks // per_chunk):
                carry, _, ok = engine.run_checked(
                    carry, params, chunk, preset.blocks_per_sample, observe, width, max_reallocations
                )
                ok_all &= ok
        else:
            remaining = preset.equilibration_blocks
            eq_chunk = max(1, preset.equilibration_blocks // 4)
            while remaining > 0:
                num = min(eq_chunk, remaining)
                carry, _, ok = engine.run_checked(carry, params, num, 1, None, width, max_reallocations)
                ok_all &= ok
                remaining -= num
        pieces = []
        remaining = n
        while remaining > 0:
            num = min(chunk, remaining)
            carry, f_b, ok = engine.run_checked(
                carry, params, num, preset.blocks_per_sample, observe, width, max_reallocations
            )
            ok_all &= ok
            pieces.append(np.asarray(f_b))
            remaining -= num
        f_b = np.concatenate(pieces, axis=1)
        d = carry.diagnostics
        ok = ~np.asarray(d.failed()) & ~np.asarray(d.overflow) & np.all(np.isfinite(f_b), axis=1)
        ok &= ok_all
        f_b = np.where(ok[:, None], f_b, np.nan).astype(np.float32)
        return f_b, ok

    def simulate_batch(keys: jax.Array, thetas: jax.Array) -> tuple[np.ndarray, np.ndarray]:
        keys = jnp.asarray(keys)
        thetas = jnp.asarray(thetas, jnp.float32).reshape(-1, 2)
        b = thetas.shape[0]
        if keys.shape[0] != b:
            raise ValueError(f"got {keys.shape[0]} keys for {b} parameter vectors")
        size = preset.batch_size
        groups = []
        for start in range(0, b, size):
            k = keys[start : start + size]
            t = thetas[start : start + size]
            m = t.shape[0]
            if m < size:  # pad with copies of the last member: one compiled shape
                k = jnp.concatenate([k, jnp.repeat(k[-1:], size - m, axis=0)])
                t = jnp.concatenate([t, jnp.repeat(t[-1:], size - m, axis=0)])
            groups.append((k, t, m))
        if workers > 1 and len(groups) > 1:
            # XLA runs one small-system batch on one core; groups are independent, and JAX
            # releases the GIL while a program runs, so threads keep every core busy.
            with concurrent.futures.ThreadPoolExecutor(min(workers, len(groups))) as pool:
                outs = list(pool.map(lambda g: run_group(g[0], g[1]), groups))
        else:
            outs = [run_group(k, t) for k, t, _ in groups]
        out_f = [f[:m] for (f, _), (_, _, m) in zip(outs, groups, strict=True)]
        out_ok = [ok[:m] for (_, ok), (_, _, m) in zip(outs, groups, strict=True)]
        return np.concatenate(out_f), np.concatenate(out_ok)

    simulate_batch.preset = preset  # type: ignore[attr-defined]
    return simulate_batch


def observed_series(
    key: jax.Array,
    preset: str | HeliumPreset = "cpu",
    theta: tuple[float, float] = TRUE_THETA,
    **overrides: Any,
) -> np.ndarray:
    """The 'observed' f_B series: one run ``observed_factor`` times longer than a simulation.

    As in the paper (20 ns observed vs 5 ns simulated), the observed data come from a longer run
    at the true parameters, so a simulation cannot reproduce them exactly.

    Parameters
    ----------
    key : PRNG key
    preset : str or HeliumPreset
    theta : (sigma_nm, epsilon_zJ)
        Default the paper's truth (0.2556, 0.141).
    **overrides
        Fields of :class:`HeliumPreset`.

    Returns
    -------
    np.ndarray, shape (observed_factor * num_samples,)
        Raises ``jaxabc.errors.SimulationFailure`` if the run failed.
    """
    from jaxabc.errors import SimulationFailure

    preset = get_preset(preset, **overrides)
    n = preset.observed_factor * preset.num_samples
    batch = make_batch_simulator(preset, num_samples=n, batch_size=1)
    f_b, ok = batch(jnp.asarray(key)[None], jnp.asarray([theta], jnp.float32))
    if not ok[0]:
        raise SimulationFailure(f"observed helium run failed at theta={theta}")
    return f_b[0]
