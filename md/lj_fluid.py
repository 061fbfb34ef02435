"""Dense Lennard-Jones liquids: presets, summaries computed in JAX, and the LJ equation of state.

These are the cheap, informative systems on which model criticism hides effects: unlike the
dilute helium gas, a dense LJ liquid has structure (g(r)), transport (self-diffusion) and a
pressure that all respond strongly to (sigma, epsilon).

Units: the engine's nm, ps, amu, kJ/mol.  A *reduced* preset uses sigma = 1 nm,
epsilon = 1 kJ/mol, m = 1 amu, so engine numbers are LJ reduced numbers (T is converted through
k_B); an *argon* preset uses sigma 0.3405 nm, epsilon/k_B 119.8 K, m 39.948 amu.

Summaries
---------
``simulate(key, theta) -> summaries`` with theta = (sigma_nm, epsilon_kj_mol) returns the 1-D
vector ``[g(r) at num_bins bin centres..., D (nm^2/ps), <P> (kJ/mol/nm^3), <U>/N (kJ/mol)]``
(:func:`summary_names` names them).  g(r) is averaged over samples, D is the slope of the mean
squared displacement over the production run divided by 6, P and U are sample means.

Reference
---------
:func:`jzg_equation_of_state`: Johnson, Zollweg & Gubbins, Mol. Phys. 78, 591 (1993), the
modified Benedict-Webb-Rubin fit (33 parameters, Table 10) for the *full* (untruncated) LJ
fluid.  A simulation with cutoff r_c is compared with it after the explicit long-range tail
corrections of :func:`tail_corrections` (g(r) = 1 beyond r_c).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from md._presets import resolve_preset
from md.lj import Carry, EngineConfig, LJEngine, LJParams
from md.units import ReducedLJUnits

__all__ = [
    "PRESETS",
    "LJFluidPreset",
    "get_preset",
    "jzg_equation_of_state",
    "make_engine",
    "make_simulator",
    "mean_squared_displacement",
    "rdf",
    "self_diffusion",
    "summary_names",
    "tail_corrections",
]

# Johnson, Zollweg & Gubbins (1993), Table 10: x_1 .. x_32 and gamma.
_JZG_X = (
    0.8623085097507421,
    2.976218765822098,
    -8.402230115796038,
    0.1054136629203555,
    -0.8564583828174598,
    1.582759470107601,
    0.7639421948305453,
    1.753173414312048,
    2.798291772190376e3,
    -4.8394220260857657e-2,
    0.9963265197721935,
    -3.698000291272493e1,
    2.084012299434647e1,
    8.305402124717285e1,
    -9.574799715203068e2,
    -1.477746229234994e2,
    6.398607852471505e1,
    1.603993673294834e1,
    6.805916615864377e1,
    -2.791293578795945e3,
    -6.245128304568454,
    -8.116836104958410e3,
    1.488735559561229e1,
    -1.059346754655084e4,
    -1.131607632802822e2,
    -8.867771540418822e3,
    -3.986982844450543e1,
    -4.689270299917261e3,
    2.593535277438717e2,
    -2.694523589434903e3,
    -7.218487631550215e2,
    1.721802063863269e2,
)
_JZG_GAMMA = 3.0


def jzg_equation_of_state(density: float, temperature: float) -> tuple[float, float]:
    """Pressure and potential energy per atom of the full LJ fluid (JZG 1993), reduced units.

    Parameters
    ----------
    density : float
        rho* = rho sigma^3.
    temperature : float
        T* = k_B T / epsilon.

    Returns
    -------
    (pressure, energy) : tuple of float
        P* = P sigma^3 / epsilon (ideal part included) and the configurational energy per atom
        U*/N.  JZG quote the fit's accuracy against their MD data as a few percent in P (worse
        near the critical point) and about 0.02-0.05 in U*/N.
    """
    x = (0.0, *_JZG_X)  # 1-based like the paper
    t, rho, g = temperature, density, _JZG_GAMMA
    a = [
        x[1] * t + x[2] * math.sqrt(t) + x[3] + x[4] / t + x[5] / t**2,
        x[6] * t + x[7] + x[8] / t + x[9] / t**2,
        x[10] * t + x[11] + x[12] / t,
        x[13],
        x[14] / t + x[15] / t**2,
        x[16] / t,
        x[17] / t + x[18] / t**2,
        x[19] / t**2,
    ]
    b = [
        x[20] / t**2 + x[21] / t**3,
        x[22] / t**2 + x[23] / t**4,
        x[24] / t**2 + x[25] / t**3,
        x[26] / t**2 + x[27] / t**4,
        x[28] / t**2 + x[29] / t**3,
        x[30] / t**2 + x[31] / t**3 + x[32] / t**4,
    ]
    c = [
        x[2] * math.sqrt(t) / 2 + x[3] + 2 * x[4] / t + 3 * x[5] / t**2,
        x[7] + 2 * x[8] / t + 3 * x[9] / t**2,
        x[11] + 2 * x[12] / t,
        x[13],
        2 * x[14] / t + 3 * x[15] / t**2,
        2 * x[16] / t,
        2 * x[17] / t + 3 * x[18] / t**2,
        3 * x[19] / t**2,
    ]
    d = [
        3 * x[20] / t**2 + 4 * x[21] / t**3,
        3 * x[22] / t**2 + 5 * x[23] / t**4,
        3 * x[24] / t**2 + 4 * x[25] / t**3,
        3 * x[26] / t**2 + 5 * x[27] / t**4,
        3 * x[28] / t**2 + 4 * x[29] / t**3,
        3 * x[30] / t**2 + 4 * x[31] / t**3 + 5 * x[32] / t**4,
    ]
    f = math.exp(-g * rho**2)
    big_g = [(1.0 - f) / (2.0 * g)]
    for i in range(1, 6):
        big_g.append(-(f * rho ** (2 * i) - 2 * i * big_g[i - 1]) / (2.0 * g))
    pressure = rho * t + sum(a[i] * rho ** (i + 2) for i in range(8))
    pressure += f * sum(b[i] * rho ** (2 * i + 3) for i in range(6))
    energy = sum(c[i] * rho ** (i + 1) / (i + 1) for i in range(8))
    energy += sum(d[i] * big_g[i] for i in range(6))
    return float(pressure), float(energy)


def tail_corrections(density: float, cutoff: float) -> tuple[float, float]:
    """Long-range corrections for an LJ potential truncated at r_c, reduced units.

    Assuming g(r) = 1 beyond r_c: ``U_tail/N = (8/3) pi rho [(1/3) r_c^-9 - r_c^-3]`` and
    ``P_tail = (16/3) pi rho^2 [(2/3) r_c^-9 - r_c^-3]``.  P_tail corrects the virial pressure
    computed from the forces inside r_c (the forces this engine applies, plain truncation or
    shifted); U_tail corrects the *unshifted* energy inside r_c.

    Parameters
    ----------
    density : float
        rho*.
    cutoff : float
        r_c / sigma.

    Returns
    -------
    (energy_per_atom, pressure) : tuple of float
    """
    rc3 = cutoff**-3
    rc9 = cutoff**-9
    energy = 8.0 / 3.0 * math.pi * density * (rc9 / 3.0 - rc3)
    pressure = 16.0 / 3.0 * math.pi * density**2 * (2.0 * rc9 / 3.0 - rc3)
    return energy, pressure


# --------------------------------------------------------------------------------------------
# Summaries in JAX
# --------------------------------------------------------------------------------------------


def rdf(r_max_nm: float, num_bins: int) -> Callable[[jax.Array, jax.Array], jax.Array]:
    """Radial distribution function factory (all pairs, minimum image).

    Parameters
    ----------
    r_max_nm : float
        Largest distance, nm; must not exceed half the box side.
    num_bins : int

    Returns
    -------
    g : callable
        ``g(position, box)`` with fractional positions (N, 3) and box (3, 3) nm returns g(r) at
        the bin centres, shape (num_bins,): pair counts normalised by the ideal-gas count
        ``(N - 1)/V * shell volume`` per atom, so an ideal gas gives 1.  Vmappable.
    """
    edges = np.linspace(0.0, r_max_nm, num_bins + 1)
    shell = jnp.asarray(4.0 / 3.0 * np.pi * (edges[1:] ** 3 - edges[:-1] ** 3), jnp.float32)
    width = r_max_nm / num_bins

    def g(position: jax.Array, box: jax.Array) -> jax.Array:
        n = position.shape[0]
        d = position[None, :, :] - position[:, None, :]
        d = d - jnp.round(d)
        r = jnp.sqrt(jnp.sum((d @ box.T) ** 2, axis=-1))
        off_diagonal = ~jnp.eye(n, dtype=bool)
        index = jnp.floor(r / width).astype(jnp.int32)
        keep = off_diagonal & (index < num_bins)
        counts = jnp.zeros(num_bins, jnp.float32).at[jnp.where(keep, index, 0)].add(keep.astype(jnp.float32))
        volume = jnp.abs(jnp.linalg.det(box))
        return counts / (n * (n - 1) / volume * shell)

    return g


def mean_squared_displacement(unwrapped: jax.Array, box: jax.Array) -> jax.Array:
    """MSD from the first frame, nm^2.

    Parameters
    ----------
    unwrapped : jax.Array, shape (T, N, 3)
        Unwrapped fractional positions over T frames.
    box : jax.Array, shape (3, 3)
        Fixed box, nm.

    Returns
    -------
    jax.Array, shape (T,)
    """
    d = (unwrapped - unwrapped[:1]) @ box.T
    return jnp.mean(jnp.sum(d**2, axis=-1), axis=-1)


def self_diffusion(msd: jax.Array, times_ps: jax.Array, skip_fraction: float = 0.2) -> jax.Array:
    """Self-diffusion coefficient D = slope(MSD(t)) / 6, nm^2/ps.

    A least-squares line is fitted after the first ``skip_fraction`` of the frames (the
    ballistic regime).

    Parameters
    ----------
    msd, times_ps : jax.Array, shape (T,)
    skip_fraction : float
    """
    start = int(skip_fraction * msd.shape[0])
    t, m = times_ps[start:], msd[start:]
    tc = t - jnp.mean(t)
    slope = jnp.sum(tc * (m - jnp.mean(m))) / jnp.sum(tc * tc)
    return slope / 6.0


# --------------------------------------------------------------------------------------------
# Presets and simulator
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class LJFluidPreset:
    """A dense LJ state point and run settings (NVT unless ``ensemble`` says otherwise).

    Parameters
    ----------
    name : str
    units : ReducedLJUnits
        The reference (sigma, epsilon, mass) that defines the state point and the default theta.
    num_atoms : int
    temperature_reduced, density_reduced : float
        T* and rho* with respect to ``units``.
    cutoff_reduced : float
        r_c / sigma of the reference units (fixed in nm when theta changes).
    dt_reduced : float
        Time step in LJ time units tau.
    tau_t_reduced : float
        Thermostat damping, tau.
    equilibration_steps, production_steps, sample_every : int
    ensemble : str
        ``"nvt_nose_hoover"`` or ``"nvt_langevin"`` (summaries assume a fixed box).
    truncation : str
        ``"shifted"`` by default (continuous energy; forces are the same as plain).
    num_bins : int
        g(r) bins between 0 and r_max = min(r_c + 0.5 sigma, L/2).
    """

    name: str
    units: ReducedLJUnits
    num_atoms: int = 108
    temperature_reduced: float = 1.5
    density_reduced: float = 0.8
    cutoff_reduced: float = 2.5
    dt_reduced: float = 0.005
    tau_t_reduced: float = 0.5
    equilibration_steps: int = 1000
    production_steps: int = 4000
    sample_every: int = 20
    ensemble: str = "nvt_nose_hoover"
    truncation: str = "shifted"
    num_bins: int = 25
    use_neighbor_list: bool = False
    rebuild_every: int = 10

    @property
    def box_nm(self) -> float:
        """Box side, nm."""
        rho = self.units.number_density_nm3(self.density_reduced)
        return float((self.num_atoms / rho) ** (1.0 / 3.0))

    @property
    def r_max_nm(self) -> float:
        """Largest g(r) distance, nm."""
        return min((self.cutoff_reduced + 0.5) * self.units.sigma_nm, 0.5 * self.box_nm)

    @property
    def default_theta(self) -> tuple[float, float]:
        """(sigma_nm, epsilon_kj_mol) of the reference units."""
        return (self.units.sigma_nm, self.units.epsilon_kj_mol)

    def engine_config(self) -> EngineConfig:
        """The :class:`md.lj.EngineConfig` of this preset."""
        u = self.units
        return EngineConfig(
            num_atoms=self.num_atoms,
            box_nm=self.box_nm,
            mass_amu=u.mass_amu,
            cutoff_nm=self.cutoff_reduced * u.sigma_nm,
            dt_ps=self.dt_reduced * u.time_ps,
            temperature_k=u.temperature_k(self.temperature_reduced),
            ensemble=self.ensemble,
            tau_t_ps=self.tau_t_reduced * u.time_ps,
            gamma_per_ps=1.0 / (self.tau_t_reduced * u.time_ps),
            truncation=self.truncation,
            use_neighbor_list=self.use_neighbor_list,
            skin_nm=0.3 * u.sigma_nm,
            rebuild_every=self.rebuild_every,
            allocation_box_fraction=1.0,
        )


_REDUCED = ReducedLJUnits(1.0, 1.0, 1.0)

PRESETS: dict[str, LJFluidPreset] = {
    # A liquid near the triple point: strong structure, slow diffusion.
    "reduced_liquid": LJFluidPreset("reduced_liquid", _REDUCED, 108, 0.85, 0.8),
    # A supercritical dense fluid (the JZG check state points use the same settings).
    "reduced_dense_fluid": LJFluidPreset("reduced_dense_fluid", _REDUCED, 108, 2.0, 0.7),
    # Liquid argon at 94.4 K, 1.374 g/cm^3 (Rahman 1964): T* = 0.788, rho* = 0.83.
    "argon_liquid": LJFluidPreset("argon_liquid", ReducedLJUnits.argon(), 108, 94.4 / 119.8, 0.83),
}


def get_preset(preset: str | LJFluidPreset, **overrides: Any) -> LJFluidPreset:
    """Resolve a preset name or object, with field overrides."""
    return resolve_preset(preset, PRESETS, "LJ fluid", **overrides)


@functools.lru_cache(maxsize=16)
def make_engine(preset: LJFluidPreset) -> LJEngine:
    """The (cached) engine of a preset."""
    return LJEngine(preset.engine_config())


def summary_names(preset: str | LJFluidPreset) -> list[str]:
    """Names of the entries of the summary vector."""
    p = get_preset(preset)
    centres = (np.arange(p.num_bins) + 0.5) * p.r_max_nm / p.num_bins
    return [f"g(r={r:.3f} nm)" for r in centres] + ["D_nm2_per_ps", "P_kj_mol_nm3", "U_per_atom"]


def run_details(preset: str | LJFluidPreset, key: jax.Array, theta: jax.Array) -> dict[str, jax.Array]:
    """Run one trajectory and return every per-sample observable (pure JAX, vmappable).

    Returns
    -------
    dict
        ``potential`` (S,) kJ/mol, ``pressure`` (S,) kJ/mol/nm^3, ``temperature`` (S,) K,
        ``kinetic`` (S,), ``rdf`` (S, num_bins), ``msd`` (S,) nm^2, ``times_ps`` (S,),
        ``failed`` () bool (neighbour-list overflow, skin or box violation, non-finite state).
    """
    p = get_preset(preset)
    engine = make_engine(p)
    params = LJParams(jnp.asarray(theta[0], jnp.float32), jnp.asarray(theta[1], jnp.float32))
    g = rdf(p.r_max_nm, p.num_bins)
    k = p.rebuild_every
    if p.sample_every % k or p.equilibration_steps % k:
        raise ValueError("sample_every and equilibration_steps must be multiples of rebuild_every")

    def observe(carry: Carry, params: LJParams) -> dict:
        t = engine.thermo(carry, params)
        return {
            "potential": t.potential,
            "pressure": t.pressure,
            "temperature": t.temperature,
            "kinetic": t.kinetic,
            "rdf": g(carry.md.position, engine.box(carry.md)),
            "unwrapped": carry.unwrapped,
        }

    carry = engine.init(key, params)
    carry, _ = engine.run(carry, params, p.equilibration_steps // k, 1)
    num = p.production_steps // p.sample_every
    carry, obs = engine.run(carry, params, num, p.sample_every // k, observe)
    unwrapped = obs.pop("unwrapped")
    obs["msd"] = mean_squared_displacement(unwrapped, engine.box0)
    obs["times_ps"] = (jnp.arange(num) + 1) * p.sample_every * engine.config.dt_ps
    d = carry.diagnostics
    obs["failed"] = d.overflow | d.failed()
    return obs


def make_simulator(
    preset: str | LJFluidPreset = "reduced_liquid", **overrides: Any
) -> Callable[[jax.Array, jax.Array], jax.Array]:
    """Build ``simulate(key, theta) -> summaries`` for an LJ fluid preset.

    Parameters
    ----------
    preset : str or LJFluidPreset
    **overrides
        Fields of :class:`LJFluidPreset`.

    Returns
    -------
    simulate : callable
        theta shape (2,) = (sigma_nm, epsilon_kj_mol); returns shape (num_bins + 3,):
        mean g(r), D (nm^2/ps), mean P (kJ/mol/nm^3), mean U/N (kJ/mol).  NaN on failure.
        Pure and vmappable; sigma and epsilon are traced.
    """
    p = get_preset(preset, **overrides)

    def simulate(key: jax.Array, theta: jax.Array) -> jax.Array:
        obs = run_details(p, key, theta)
        out = jnp.concatenate(
            [
                jnp.mean(obs["rdf"], axis=0),
                self_diffusion(obs["msd"], obs["times_ps"])[None],
                jnp.mean(obs["pressure"])[None],
                (jnp.mean(obs["potential"]) / p.num_atoms)[None],
            ]
        )
        return jnp.where(obs["failed"], jnp.nan, out)

    simulate.preset = p  # type: ignore[attr-defined]
    return simulate
