"""State-point simulator for neon and argon: one parameter vector -> P, U_res and B2 at many points.

::

    from md.fluids.simulator import fluid_setup
    setup = fluid_setup("neon")
    summaries = setup.simulate(key, theta_full)      # theta_full = [sigma_nm, epsilon_k, eta_1..eta_6]

Model.  A Lennard-Jones fluid of ``num_atoms`` atoms in a cubic box at each (T, rho) state point,
simulated in LJ reduced units (sigma = epsilon = m = 1) with jax-md's Langevin (BAOAB) integrator;
the state points run side by side under ``jax.vmap`` in one call, and so do parameter vectors.
Everything that depends on theta -- T* = T / epsilon, rho* = rho N_A sigma^3, the Feynman-Hibbs
coefficient, the box side -- is traced, so no theta recompiles.

Summaries (SI-like units, in this order): pressure (MPa) at every state point, residual
(configurational) internal energy per mole U_res (kJ/mol) at every state point, and the second
virial coefficient B2 (cm^3/mol) at every B2 temperature, by quadrature of the same pair potential.
The simulator adds Gaussian measurement noise with the data's stated uncertainties (so the
replicate covariance that criticism uses as its yardstick holds measurement and simulation noise).

Effect parameters (:func:`fluid_catalogue`, in ``theta_full`` order after sigma and epsilon):

- ``temperature_offset`` eta: every temperature T -> T (1 + eta) (state points and B2).
- ``axilrod_teller`` nu = C9 / (epsilon sigma^9): the triple-dipole term evaluated on the pair
  fluid's configurations, ``U += <E3> / N`` and ``P += 3 <E3> / V`` (first order in nu with the
  structure's response neglected: the fluctuation terms ``-Cov(U2, E3) / kT`` that complete the
  first order are far noisier than the term itself over runs this short); triples with all
  sides below ``triple_cutoff`` sigma.  B2 is a pair property and does not see it.
- ``feynman_hibbs`` fh_scale: the quadratic Feynman-Hibbs term ``fh_scale hbar^2 / (24 mu k T)
  (u'' + 2 u' / r)`` in the dynamics and in B2; its physical value is 1.
- ``density_error`` eta: the measured density is off, rho -> rho (1 + eta) (state points only).
- ``tail_correction`` eta: the analytic long-range corrections for r > r_c (g = 1) are scaled by
  ``1 + eta``; -1 is the truncated potential with no correction, 0 the full LJ estimate.
- ``pair_shape`` eta: the pair is Mie (12 + eta)-6 with the same sigma and well depth
  (:func:`mie_prefactor`), in the dynamics, the tail corrections and B2; 0 is LJ.

Failures come back as data: :meth:`FluidSetup.simulate_with_status` returns a status bitmask per
state point (:data:`STATUS_BITS`) and :meth:`FluidSetup.simulate` NaN for a failed state point
(:data:`FAILURE_BITS`; a full triple list is reported but does not fail the point).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax_md import simulate as jmd_simulate
from jax_md import space

from jaxabc.criticism import Catalogue, Effect
from md.fluids import LITERATURE_LJ, load
from md.fluids.three_body import axilrod_teller_energy, c9_reduced, nearest_neighbors
from md.fluids.virial import AMU, HBAR, K_B, N_A
from md.lj.energy import lattice_positions

__all__ = [
    "BASE_NAMES",
    "C9_ATOMIC",
    "FAILURE_BITS",
    "STATUS_BITS",
    "FluidConfig",
    "FluidSetup",
    "b2_quadrature",
    "fluid_catalogue",
    "fluid_setup",
    "mie_prefactor",
    "tail_corrections",
]

BASE_NAMES = ("sigma_nm", "epsilon_k")
#: Axilrod-Teller C9 in hartree bohr^9 (Kumar & Meath 1985 dispersion data).
C9_ATOMIC = {"argon": 521.0, "neon": 11.9}
_QUENCH_GAMMA = 20.0
#: Status bits that make a state point fail (NaN); bit 8 is a warning only.
FAILURE_BITS = 1 | 2 | 4
#: Status bits of one state point.
STATUS_BITS = {
    1: "non-finite positions or momenta (the integration blew up)",
    2: "kinetic temperature off its set point by more than 15 % (unstable integration)",
    4: "the box is too small for a 2 sigma cutoff at this density (use more atoms)",
    8: "a triple neighbour list was full: Axilrod-Teller triples may be missing (raise triple_neighbors)",
}


@dataclasses.dataclass(frozen=True)
class FluidConfig:
    """Static settings (changing any recompiles).  Reduced units: sigma, epsilon, tau = sigma sqrt(m/eps).

    Parameters
    ----------
    num_atoms : int
        Atoms per state point (108-256: small boxes, seconds per call on a CPU).
    dt : float
        Time step, tau.
    equilibration_steps, production_steps, sample_every : int
        Run lengths in steps; thermodynamics are averaged every ``sample_every`` steps.
    gamma : float
        Langevin friction, 1/tau (static averages do not depend on it).
    cutoff : float
        Pair cutoff in sigma (reduced to half the box where the box is smaller).
    triple_cutoff : float
        Axilrod-Teller triples with all sides below this, in sigma.
    triple_neighbors : int
        Neighbour slots per atom for the triple sum (must hold all atoms within triple_cutoff).
    three_body_every : int
        The triple sum is evaluated on every this-many-th sample (it costs N M^2).
    three_body : bool
        Evaluate the triple sum at all; without it ``axilrod_teller`` has no effect (criticism
        then reports it invisible) and a call costs about half.
    measurement_noise : bool
        Add the data's uncertainties as Gaussian noise to the summaries.
    """

    num_atoms: int = 108
    dt: float = 0.005
    equilibration_steps: int = 400
    production_steps: int = 800
    sample_every: int = 10
    gamma: float = 2.0
    cutoff: float = 2.5
    triple_cutoff: float = 2.0
    triple_neighbors: int = 40
    three_body_every: int = 4
    three_body: bool = True
    measurement_noise: bool = True

    def __post_init__(self) -> None:
        if self.num_atoms < 32:
            raise ValueError(f"num_atoms={self.num_atoms}: use at least 32 atoms (108 or more for liquids)")
        if self.production_steps % (self.sample_every * self.three_body_every):
            raise ValueError("production_steps must be a multiple of sample_every * three_body_every")
        if self.dt <= 0 or self.gamma <= 0 or self.cutoff <= 1.5 or self.triple_cutoff <= 1.0:
            raise ValueError("dt, gamma must be > 0; cutoff > 1.5 and triple_cutoff > 1 (sigma)")


def fluid_catalogue(physical_nu: float | None = None) -> Catalogue:
    """The fluids catalogue (order = ``theta_full`` order after sigma and epsilon).

    ``physical_nu`` (the fluid's C9 in reduced units) is only mentioned in the description.
    """
    at_note = "" if physical_nu is None else f" (this fluid: nu about {physical_nu:.3g})"
    return Catalogue(
        [
            Effect(
                "temperature_offset",
                -0.05,
                0.05,
                0.0,
                "relative",
                "The temperatures differ from the stated ones: T -> T (1 + eta).",
                "measurement",
                "B2 (pair-only, no density) beside the liquid; T/epsilon enters everything but U/epsilon",
                ("epsilon_k",),
            ),
            Effect(
                "axilrod_teller",
                0.0,
                0.25,
                0.0,
                "nu = C9 / (epsilon sigma^9)",
                "Three-body triple-dipole dispersion missing from the pair potential" + at_note + ".",
                "physical",
                "B2 (it does not act on pairs) and the density dependence of P and U (it grows as rho^2)",
                ("tail_correction",),
            ),
            Effect(
                "feynman_hibbs",
                0.0,
                3.0,
                0.0,
                "fh_scale (1 = hbar^2 / (24 mu k T))",
                "Quantum swelling of the repulsive core of light atoms (quadratic Feynman-Hibbs).",
                "physical",
                "several temperatures (it scales as 1/T, sigma does not) and B2 at low T",
                ("sigma_nm",),
                # The quadratic Feynman-Hibbs term at its own strength (Feynman & Hibbs 1965; for
                # neon, Sese 1994): the criticism reports its detection power there.
                expected=1.0,
            ),
            Effect(
                "density_error",
                -0.03,
                0.03,
                0.0,
                "relative",
                "The stated densities are off: rho -> rho (1 + eta).",
                "measurement",
                "B2 (no density), and P (strongly) against U",
                ("sigma_nm",),
            ),
            Effect(
                "tail_correction",
                -1.0,
                1.0,
                0.0,
                "relative to the g = 1 tail beyond r_c",
                "The long-range correction beyond the cutoff is wrong: U_tail, P_tail -> (1 + eta) x.",
                "physical",
                "B2 (no cutoff) and the density dependence of P",
                ("epsilon_k", "axilrod_teller"),
            ),
            Effect(
                "pair_shape",
                -4.0,
                8.0,
                0.0,
                "repulsive exponent n - 12 (Mie n-6)",
                "The 12-6 shape is wrong: a Mie n-6 pair with the same sigma and well depth, steeper "
                "(n > 12) or softer (n < 12) repulsion and a narrower or wider well.",
                "physical",
                "B2 over a wide temperature range (its curvature in 1/T follows the well's width)",
                ("sigma_nm", "epsilon_k"),
            ),
        ],
        name="simple fluids (neon, argon)",
        notes=(
            "At one temperature Feynman-Hibbs looks like a larger sigma and Axilrod-Teller like a "
            "density-dependent softening; B2 sees neither three-body forces nor densities, so it "
            "separates pair effects (FH, temperature) from many-body and density effects."
        ),
    )


# -- pure functions --------------------------------------------------------------------------


def tail_corrections(
    rho: jax.Array, cutoff: jax.Array, d_fh: jax.Array, exponent: jax.Array | float = 12.0
) -> tuple[jax.Array, jax.Array]:
    """Long-range corrections (g = 1 beyond ``cutoff``) of U per atom and P, reduced.

    LJ: ``U = 8/3 pi rho (rc^-9 / 3 - rc^-3)``, ``P = 16/3 pi rho^2 (2/3 rc^-9 - rc^-3)``;
    Feynman-Hibbs term ``4 D (132 r^-14 - 30 r^-8)``: ``U = 8 pi rho D (12 rc^-11 - 6 rc^-5)``,
    ``P = -(8 pi / 3) rho^2 D (-168 rc^-11 + 48 rc^-5)``.  For a Mie ``n``-6 pair
    (:func:`mie_prefactor`; ``exponent`` = n) the same integrals with ``r^-n`` in place of
    ``r^-12``; at n = 12 the LJ expressions above are used as they are.
    """
    i3 = cutoff**-3.0
    i9 = i3**3
    i5, i11 = cutoff**-5.0, cutoff**-11.0
    u = 8.0 / 3.0 * math.pi * rho * (i9 / 3.0 - i3) + 8.0 * math.pi * rho * d_fh * (12.0 * i11 - 6.0 * i5)
    p = 16.0 / 3.0 * math.pi * rho**2 * (2.0 / 3.0 * i9 - i3) - 8.0 * math.pi / 3.0 * rho**2 * d_fh * (
        -168.0 * i11 + 48.0 * i5
    )
    n = jnp.asarray(exponent, jnp.result_type(float))
    c = mie_prefactor(n)
    rn3, rn1 = cutoff ** (3.0 - n), cutoff ** (1.0 - n)
    two_pi_rho = 2.0 * math.pi * rho
    u_mie = two_pi_rho * c * (rn3 / (n - 3.0) - i3 / 3.0) + two_pi_rho * d_fh * c * (n * rn1 - 6.0 * i5)
    p_pair = n * rn3 / (n - 3.0) - 2.0 * i3
    p_fh = -(n + 2.0) * n * rn1 + 48.0 * i5
    p_mie = two_pi_rho * rho / 3.0 * c * (p_pair - d_fh * p_fh)
    lj = n == 12.0
    return jnp.where(lj, u, u_mie), jnp.where(lj, p, p_mie)


def mie_prefactor(exponent: jax.Array | float) -> jax.Array:
    """``C(n) = n / (n - 6) (n / 6)^(6 / (n - 6))``: the Mie n-6 pair ``C eps ((s/r)^n - (s/r)^6)``
    then has its minimum -eps and its zero at sigma; ``C(12) = 4`` exactly (LJ)."""
    n = jnp.asarray(exponent, jnp.result_type(float))
    return n / (n - 6.0) * (n / 6.0) ** (6.0 / (n - 6.0))


def _pair(r2: jax.Array, d_fh: jax.Array, exponent: jax.Array | float = 12.0) -> tuple[jax.Array, jax.Array]:
    """Mie n-6 (LJ at n = 12) + Feynman-Hibbs pair energy and its derivative with respect to r^2, reduced.

    ``r^-n`` is ``r^-12 exp(-(n - 12) ln r)``: at n = 12 the factor is exactly 1 and the LJ
    numbers are bit for bit those of the plain 12-6 expressions.
    """
    n = jnp.asarray(exponent, r2.dtype)
    c = mie_prefactor(n).astype(r2.dtype)
    ir2 = 1.0 / r2
    ir6 = ir2 * ir2 * ir2
    irn = ir6 * ir6 * jnp.exp(-0.5 * (n - 12.0) * jnp.log(r2))
    # FH: u'' + 2 u' / r of a r^-k is a k (k - 1) r^-(k + 2); d/d(r^2) of a r^-k is -(k / 2) a r^-(k + 2).
    u = c * (irn - ir6) + d_fh * c * (n * (n - 1.0) * irn - 30.0 * ir6) * ir2
    du_fh = (-0.5 * (n + 2.0) * n * (n - 1.0) * irn + 120.0 * ir6) * ir2 * ir2
    du = c * (-0.5 * n * irn + 3.0 * ir6) * ir2 + d_fh * c * du_fh
    return u, du


def _all_pairs(
    position: jax.Array, side: jax.Array, cutoff: jax.Array, d_fh: jax.Array, exponent: jax.Array | float = 12.0
):
    """Forces (N, 3), energy () and virial W = -dU/dln L () over all minimum-image pairs."""
    n = position.shape[0]
    comps = []
    for a in range(3):
        x = position[:, a]
        d = x[None, :] - x[:, None]
        comps.append(d - side * jnp.round(d / side))
    r2 = comps[0] ** 2 + comps[1] ** 2 + comps[2] ** 2
    inside = ~jnp.eye(n, dtype=bool) & (r2 < cutoff * cutoff)
    u, du = _pair(jnp.where(inside, r2, 1.0), d_fh, exponent)
    u, du = jnp.where(inside, u, 0.0), jnp.where(inside, du, 0.0)
    force = jnp.stack([jnp.sum(2.0 * du * c, axis=1) for c in comps], axis=-1)
    # Every pair appears twice in the (N, N) sums.
    return force, 0.5 * jnp.sum(u), -jnp.sum(du * r2)


def b2_quadrature(
    temperature: jax.Array, d_fh: jax.Array, num_points: int = 2401, exponent: jax.Array | float = 12.0
) -> jax.Array:
    """Reduced ``B2*(T*) = -2 pi int (exp(-u_FH / T*) - 1) r^2 dr`` on a fixed grid (traced, vmappable).

    Simpson's rule on [0.5, 12] sigma; the core below 0.5 contributes exactly ``-1 r^2`` and the
    tail beyond 12 sigma its first two orders in u / T*.
    """
    r = jnp.linspace(0.5, 12.0, num_points)
    u, _ = _pair(r * r, d_fh, exponent)
    f = jnp.expm1(-jnp.minimum(u / temperature, 200.0)) * r * r
    h = (12.0 - 0.5) / (num_points - 1)
    w = jnp.ones(num_points).at[1:-1:2].set(4.0).at[2:-1:2].set(2.0) * h / 3.0
    inner = jnp.sum(w * f)
    core = -(0.5**3) / 3.0
    big = 12.0
    # exp(-u/T) - 1 ~ -u/T + u^2/(2 T^2) with u ~ -4 r^-6 beyond 12 sigma.
    tail = 4.0 / (3.0 * big**3 * temperature) + 8.0 / (9.0 * big**9 * temperature**2)
    return -2.0 * math.pi * (core + inner + tail)


@functools.lru_cache(maxsize=4)
def liquid_starts(num_atoms: int, count: int = 8, seed: int = 0) -> np.ndarray:
    """Liquid start configurations, fractional, shape (count, num_atoms, 3).

    A lattice start at liquid density keeps releasing heat for a thousand steps or more as it
    melts and densifies; a liquid scaled to the target box relaxes within a few hundred.  These
    are ``count`` independent LJ liquids at rho* = 0.8, T* = 1.0 after 4000 steps from a jittered
    lattice (deterministic, computed once per process).
    """
    rho, kt, side = 0.8, 1.0, (num_atoms / 0.8) ** (1.0 / 3.0)
    lattice = jnp.asarray(lattice_positions(num_atoms)) * side
    del rho
    _, shift = space.periodic(side)
    cutoff = jnp.asarray(min(2.5, 0.4999 * side))

    def force_fn(position: jax.Array, **unused) -> jax.Array:
        return _all_pairs(position, jnp.asarray(side), cutoff, jnp.zeros(()))[0]

    init_fn, apply_fn = jmd_simulate.nvt_langevin(force_fn, shift, 0.005, kt, gamma=_QUENCH_GAMMA)

    def one(key: jax.Array) -> jax.Array:
        k1, k2 = jax.random.split(key)
        state = init_fn(k2, jnp.mod(lattice + 0.05 * jax.random.normal(k1, lattice.shape), side), mass=1.0)
        state = jax.lax.fori_loop(0, 4000, lambda _, s: apply_fn(s), state)
        return state.position / side

    keys = jax.random.split(jax.random.key(seed), count)
    return np.asarray(jax.jit(jax.vmap(one))(keys), np.float32)


# -- setup -------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class FluidSetup:
    """A fluid's simulator, catalogue, observed data and summary layout.

    Attributes
    ----------
    simulate : callable ``(key, theta_full (2 + 6,)) -> summaries (2 P + B,)``
        Pure JAX, vmappable; NaN at a failed state point.
    simulate_with_status : callable ``(key, theta_full) -> (summaries, status (P,) int32)``
    diagnose : callable ``(key, theta_full) -> (summaries, dict of (P,) arrays)``
        Per state point: reduced ``u2``, ``p2`` (pair fluid), ``u3``, ``p3`` (three-body, per unit
        nu), ``cutoff``, ``temperature_ratio`` (kinetic / set point) and ``status``.
    catalogue : Catalogue
    names : list of str
        Summary names (``"P 26 K 60.7 mol/L"`` ..., ``"U ..."``, ``"B2 30 K"``).
    groups : dict of str to int array
        One group per isotherm and observable, and ``"B2"``.
    observed : numpy.ndarray, shape (2 P + B,)
        The data (reference-equation values) in the summaries' units.
    uncertainty : numpy.ndarray, shape (2 P + B,)
        Their standard uncertainties.
    temperature_k, density_mol_m3 : numpy.ndarray, shape (P,)
    b2_temperature_k : numpy.ndarray, shape (B,)
    mass_amu : float
    physical : dict
        Physical values of effect parameters (``feynman_hibbs`` 1, ``axilrod_teller`` nu from
        C9 at the literature sigma, epsilon) and the conversion used.
    config : FluidConfig
    """

    simulate: Callable
    simulate_with_status: Callable
    diagnose: Callable
    catalogue: Catalogue
    names: list[str]
    groups: dict[str, np.ndarray]
    observed: np.ndarray
    uncertainty: np.ndarray
    temperature_k: np.ndarray
    density_mol_m3: np.ndarray
    b2_temperature_k: np.ndarray
    mass_amu: float
    physical: dict
    config: FluidConfig


def _make_simulator(
    temperature_k: np.ndarray,
    density_mol_m3: np.ndarray,
    b2_temperature_k: np.ndarray,
    uncertainty: np.ndarray,
    mass_amu: float,
    cfg: FluidConfig,
) -> tuple[Callable, Callable, Callable]:
    n = cfg.num_atoms
    starts = jnp.asarray(liquid_starts(n))
    t_sp = jnp.asarray(temperature_k, jnp.float32)
    rho_sp = jnp.asarray(density_mol_m3, jnp.float32)
    t_b2 = jnp.asarray(b2_temperature_k, jnp.float32)
    u_noise = jnp.asarray(uncertainty, jnp.float32)
    num_points = len(temperature_k)
    samples = cfg.production_steps // cfg.sample_every
    # hbar^2 / (24 mu k) with mu = m / 2, in m^2 K: divide by T sigma^2 for the reduced D.
    fh_per_t_sigma2 = HBAR**2 / (24.0 * 0.5 * mass_amu * AMU * K_B)
    r_gas_kj = K_B * N_A / 1000.0

    def state_point(key: jax.Array, t_star: jax.Array, rho: jax.Array, d_fh: jax.Array, exponent: jax.Array) -> dict:
        side = (n / rho) ** (1.0 / 3.0)
        cutoff = jnp.minimum(cfg.cutoff, 0.4999 * side)
        displacement, shift = space.periodic(side)
        del displacement

        def force_fn(position: jax.Array, **unused) -> jax.Array:
            return _all_pairs(position, side, cutoff, d_fh, exponent)[0]

        # jax-md reads kT at trace time only through arithmetic, so a traced T* is fine.
        init_fn, apply_fn = jmd_simulate.nvt_langevin(force_fn, shift, cfg.dt, t_star, gamma=cfg.gamma)  # pyright: ignore[reportArgumentType]
        # The start liquid, rescaled to this box and temperature, releases heat as it relaxes: a
        # strong friction over the first half of the equilibration takes it out within a few
        # dozen steps (the kinetic temperature otherwise stays above the set point for hundreds).
        _, quench_fn = jmd_simulate.nvt_langevin(force_fn, shift, cfg.dt, t_star, gamma=_QUENCH_GAMMA)  # pyright: ignore[reportArgumentType]
        k_pick, k_pos, k_md = jax.random.split(key, 3)
        start = starts[jax.random.randint(k_pick, (), 0, starts.shape[0])]
        jitter = 0.002 * jax.random.normal(k_pos, start.shape)
        state = init_fn(k_md, jnp.mod(start + jitter, 1.0) * side, mass=1.0)

        def steps(state, count: int, fn=apply_fn):
            return jax.lax.fori_loop(0, count, lambda _, s: fn(s), state)

        state = steps(state, cfg.equilibration_steps // 2, quench_fn)
        state = steps(state, cfg.equilibration_steps - cfg.equilibration_steps // 2)

        def sample(state, i):
            state = steps(state, cfg.sample_every)
            _, energy, virial = _all_pairs(state.position, side, cutoff, d_fh, exponent)
            kinetic = 0.5 * jnp.sum(state.momentum**2)

            def triples(position: jax.Array) -> tuple[jax.Array, jax.Array]:
                vec, r2 = nearest_neighbors(position, side, cfg.triple_neighbors)
                return axilrod_teller_energy(vec, 1.0, cfg.triple_cutoff), jnp.min(r2[:, -1]) < cfg.triple_cutoff**2

            # The scan index is the same for every vmapped member, so this cond really skips.
            e3, full = jax.lax.cond(
                cfg.three_body & ((i % cfg.three_body_every) == 0),
                triples,
                lambda _: (jnp.zeros((), energy.dtype), jnp.zeros((), bool)),
                state.position,
            )
            return state, (energy, virial, kinetic, e3, full)

        state, (energy, virial, kinetic, e3, full) = jax.lax.scan(sample, state, jnp.arange(samples))
        volume = side**3
        finite = jnp.all(jnp.isfinite(state.position)) & jnp.all(jnp.isfinite(state.momentum))
        t_kin = 2.0 * jnp.mean(kinetic) / (3 * n - 3)
        w3 = (jnp.arange(samples) % cfg.three_body_every) == 0
        m3 = jnp.sum(w3)

        def mean3(x):
            return jnp.sum(jnp.where(w3, x, 0.0)) / m3

        p2 = virial / (3.0 * volume)
        status = (
            jnp.where(finite, 0, 1)
            | jnp.where(jnp.abs(t_kin / t_star - 1.0) > 0.15, 2, 0)
            | jnp.where(0.5 * side < 2.0, 4, 0)
            | jnp.where(jnp.any(full), 8, 0)
        )
        return dict(
            u2=jnp.mean(energy) / n,
            p2=rho * t_star + jnp.mean(p2),
            # Per unit nu: <E3>/N and <P3> = 3 <E3>/V on the pair fluid's configurations.
            u3=mean3(e3) / n,
            p3=3.0 * mean3(e3) / volume,
            cutoff=cutoff,
            temperature_ratio=t_kin / t_star,
            status=status.astype(jnp.int32),
        )

    def diagnose(key: jax.Array, theta: jax.Array) -> tuple[jax.Array, dict]:
        theta = jnp.asarray(theta, jnp.float32)
        sigma_m = theta[0] * 1e-9
        eps_k = theta[1]
        dt_rel, nu, fh, drho, tail = theta[2], theta[3], theta[4], theta[5], theta[6]
        # pair_shape: the repulsive exponent n = 12 + eta (a theta without it is the 12-6 model).
        exponent = 12.0 + (theta[7] if theta.shape[0] > 7 else jnp.zeros((), theta.dtype))
        t_true = t_sp * (1.0 + dt_rel)
        t_star = t_true / eps_k
        rho_star = rho_sp * (1.0 + drho) * N_A * sigma_m**3
        d_fh = fh * fh_per_t_sigma2 / (t_true * sigma_m**2)
        k_md, k_noise = jax.random.split(key)
        keys = jax.random.split(k_md, num_points)
        sp = jax.vmap(state_point, in_axes=(0, 0, 0, 0, None))(keys, t_star, rho_star, d_fh, exponent)
        u_tail, p_tail = tail_corrections(rho_star, sp["cutoff"], d_fh, exponent)
        u_star = sp["u2"] + nu * sp["u3"] + (1.0 + tail) * u_tail
        p_star = sp["p2"] + nu * sp["p3"] + (1.0 + tail) * p_tail
        pressure_mpa = p_star * eps_k * K_B / sigma_m**3 / 1e6
        energy_kj_mol = u_star * eps_k * r_gas_kj
        tb = t_b2 * (1.0 + dt_rel)
        b2_star = jax.vmap(lambda t, d: b2_quadrature(t, d, exponent=exponent))(
            tb / eps_k, fh * fh_per_t_sigma2 / (tb * sigma_m**2)
        )
        b2_cm3 = b2_star * N_A * sigma_m**3 * 1e6
        out = jnp.concatenate([pressure_mpa, energy_kj_mol, b2_cm3])
        if cfg.measurement_noise:
            out = out + u_noise * jax.random.normal(k_noise, out.shape)
        failed = (sp["status"] & FAILURE_BITS) != 0
        bad = jnp.concatenate([failed, failed, jnp.zeros(t_b2.shape, bool)])
        return jnp.where(bad, jnp.nan, out), sp

    def simulate_with_status(key: jax.Array, theta: jax.Array) -> tuple[jax.Array, jax.Array]:
        out, sp = diagnose(key, theta)
        return out, sp["status"]

    def simulate(key: jax.Array, theta: jax.Array) -> jax.Array:
        return diagnose(key, theta)[0]

    return simulate, simulate_with_status, diagnose


def fluid_setup(
    fluid: str,
    state_points: Sequence[int] | np.ndarray | None = None,
    b2_temperatures_k: Sequence[float] | None = None,
    config: FluidConfig | None = None,
    catalogue: Catalogue | None = None,
) -> FluidSetup:
    """Build a fluid's :class:`FluidSetup` from its data files (:func:`md.fluids.load`).

    Parameters
    ----------
    fluid : {"neon", "argon"}
    state_points : indices into the data's ``state_points`` rows, optional (default all)
    b2_temperatures_k : optional
        A subset of the data's B2 temperatures (default all).
    config : FluidConfig, optional
    catalogue : Catalogue, optional
        Must be :func:`fluid_catalogue` (its order is the simulator's); given to share one object.
    """
    data = load(fluid)
    cfg = config or FluidConfig()
    sp = data.state_points if state_points is None else data.state_points[np.asarray(state_points, int)]
    b2 = data.b2
    if b2_temperatures_k is not None:
        keep = np.isin(b2["T_K"], np.asarray(b2_temperatures_k, float))
        if keep.sum() != len(b2_temperatures_k):
            raise ValueError(f"B2 temperatures must be among the data's {b2['T_K'].tolist()} K")
        b2 = b2[keep]
    lj = LITERATURE_LJ[fluid]
    nu = c9_reduced(C9_ATOMIC[fluid], lj["epsilon_k"], lj["sigma_m"])
    cat = catalogue or fluid_catalogue(nu)
    if cat.names != fluid_catalogue().names:
        raise ValueError(f"the catalogue must be fluid_catalogue() (effects {fluid_catalogue().names})")
    t, rho = np.asarray(sp["T_K"], float), np.asarray(sp["rho_mol_m3"], float)
    observed = np.concatenate([sp["P_Pa"] / 1e6, sp["U_res_J_mol"] / 1e3, b2["B2_m3_mol"] * 1e6])
    unc = np.concatenate([sp["u_P_Pa"] / 1e6, sp["u_U_res_J_mol"] / 1e3, b2["u_B2_m3_mol"] * 1e6])
    labels = [f"{ti:g} K {ri / 1e3:.1f} mol/L" for ti, ri in zip(t, rho, strict=False)]
    names = [f"P {s}" for s in labels] + [f"U {s}" for s in labels] + [f"B2 {ti:g} K" for ti in b2["T_K"]]
    npt = len(t)
    groups: dict[str, np.ndarray] = {}
    for ti in np.unique(t):
        idx = np.flatnonzero(t == ti)
        groups[f"P {ti:g} K"] = idx
        groups[f"U {ti:g} K"] = npt + idx
    groups["B2"] = 2 * npt + np.arange(len(b2))
    simulate, with_status, diagnose = _make_simulator(t, rho, np.asarray(b2["T_K"], float), unc, lj["mass_amu"], cfg)
    physical = dict(
        feynman_hibbs=1.0,
        axilrod_teller=nu,
        c9_hartree_bohr9=C9_ATOMIC[fluid],
        nu_conversion=(
            f"nu = C9 / (epsilon sigma^9) = {C9_ATOMIC[fluid]} hartree bohr^9 x {4.3597447222071e-18:.6e} J/hartree "
            f"x ({5.29177210903e-11:.6e} m)^9 / ({lj['epsilon_k']} K x k_B x ({lj['sigma_m']:.4e} m)^9) = {nu:.4f}"
        ),
        temperature_offset=0.0,
        density_error=0.0,
        tail_correction=0.0,
    )
    return FluidSetup(
        simulate,
        with_status,
        diagnose,
        cat,
        names,
        groups,
        observed,
        unc,
        t,
        rho,
        np.asarray(b2["T_K"], float),
        lj["mass_amu"],
        physical,
        cfg,
    )
