"""B2(T) from an accurate pair potential held within its stated uncertainty (no MD).

Why this design exists: with a Lennard-Jones sigma and epsilon free, the Feynman-Hibbs quantum
correction of neon is absorbed by a slightly larger sigma and a smaller epsilon, so no data set of
liquid isotherms or B2 can show it.  An accurate pair potential whose length and energy scales
may move only within their stated uncertainty (a scale prior that is knowledge, passed to
:func:`jaxabc.criticism.critique` as ``base_prior="prior"``) leaves the correction nowhere to
hide: at 25-40 K it shifts B2 by 3.5-12 cm^3/mol, against a length or energy scale that moves it
by 2-4 cm^3/mol per per cent.

The simulator takes ``theta_full = [length_scale, energy_scale, temperature_offset,
feynman_hibbs, shape, axilrod_teller]`` and returns B2 (cm^3/mol) at the design's
temperatures with the data's measurement noise (one draw per key)::

    u(r) = energy_scale * V(r' / length_scale)          V: the reference potential, in K
    r'   = r_m - (r_m - r) (1 + repulsive_wall)  for r < r_m, else r      (wall steepness)
    (or, for LJ: u(r) = energy_scale * Mie_{12 + pair_shape}(r / length_scale), same sigma and depth)
    u_FH = u + fh_scale * hbar^2 / (24 mu k T) (u'' + 2 u' / r)           (quadratic FH)
    B2   = -2 pi N_A int (exp(-u_FH / k T') - 1) r^2 dr,   T' = T (1 + temperature_offset)

``axilrod_teller`` is a parameter that B2 cannot see (three-body forces do not act on a pair):
the report lists it as invisible, which is the honest answer for pair data.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.criticism import Catalogue, Effect
from md.fluids import LITERATURE_LJ, load
from md.fluids.simulator import fluid_catalogue
from md.fluids.virial import AMU, HBAR, K_B, N_A

__all__ = [
    "NEON_HFD_B",
    "NEON_TT2003",
    "POTENTIALS",
    "B2Design",
    "PairPotential",
    "b2_catalogue",
    "b2_design",
    "b2_pair",
    "mie",
]

HARTREE_K = 3.1577502480407e5  # K per hartree (CODATA 2018)
BOHR_A = 0.529177210903  # Angstrom per bohr (CODATA 2018)
BASE_NAMES = ("length_scale", "energy_scale")


def tang_toennies(r: jax.Array, a: float, b: float, c6: float, c8: float, c10: float) -> jax.Array:
    """Tang-Toennies potential (K) at ``r`` (Angstrom); parameters in atomic units.

    ``V = A exp(-b r) - sum_{n=3..5} f_2n(b r) C_2n / r^2n`` with the damping
    ``f_2n(x) = 1 - exp(-x) sum_{k=0..2n} x^k / k!``.
    """
    x_r = r / BOHR_A
    br = b * x_r
    v = a * jnp.exp(-br)
    term, partial = jnp.ones_like(br), jnp.ones_like(br)
    for k in range(1, 11):
        term = term * br / k
        partial = partial + term
        if k in (6, 8, 10):
            c = {6: c6, 8: c8, 10: c10}[k]
            v = v - (1.0 - jnp.exp(-br) * partial) * c / x_r**k
    return v * HARTREE_K


def hfd_b(
    r: jax.Array,
    eps_k: float,
    r_m: float,
    a: float,
    alpha: float,
    beta: float,
    c6: float,
    c8: float,
    c10: float,
    d: float,
) -> jax.Array:
    """Aziz HFD-B potential (K) at ``r`` (Angstrom); reduced parameters as published.

    ``V / eps = A exp(-alpha x + beta x^2) - F(x) (C6 / x^6 + C8 / x^8 + C10 / x^10)``,
    ``x = r / r_m``, ``F = exp(-(D / x - 1)^2)`` for ``x < D``, else 1.
    """
    x = r / r_m
    damp = jnp.where(x < d, jnp.exp(-((d / jnp.minimum(x, d) - 1.0) ** 2)), 1.0)
    return eps_k * (a * jnp.exp(-alpha * x + beta * x * x) - damp * (c6 / x**6 + c8 / x**8 + c10 / x**10))


@dataclass(frozen=True)
class PairPotential:
    """A reference pair potential ``V(r)`` (K, r in Angstrom) with its source.

    Attributes
    ----------
    name, source : str
    energy : callable ``r -> V`` (JAX, elementwise)
    mie : callable ``(r, n) -> V``, optional
        The Mie n-6 family the potential belongs to (same sigma and well depth), for LJ.
    r_min : float
        Minimum of ``V`` (Angstrom), found numerically; the wall effect pivots there.
    mass_amu : float
        Atomic mass of the fluid the potential describes.
    """

    name: str
    source: str
    energy: Callable[[jax.Array], jax.Array] = field(repr=False)
    mass_amu: float = 20.1797
    #: For an n-6 family (LJ), ``mie(r, n)``: its pair-shape effect is the exponent n - 12 rather
    #: than the repulsive-wall stretch of a reference potential.
    mie: Callable[[jax.Array, jax.Array], jax.Array] | None = field(default=None, repr=False)

    @property
    def r_min(self) -> float:
        r = np.linspace(2.0, 6.0, 40001)
        return float(r[np.argmin(np.asarray(self.energy(jnp.asarray(r))))])

    @property
    def well_depth_k(self) -> float:
        return float(-self.energy(jnp.asarray(self.r_min)))


NEON_TT2003 = PairPotential(
    "tt2003",
    "Tang & Toennies, J. Chem. Phys. 118, 4976 (2003): Ne2, A = 199.5 hartree, b = 2.458 / bohr, "
    "C6 = 6.383, C8 = 90.34, C10 = 1536 (atomic units)",
    lambda r: tang_toennies(r, 199.5, 2.458, 6.383, 90.34, 1536.0),
)
NEON_HFD_B = PairPotential(
    "hfd_b",
    "Aziz & Slaman, Chem. Phys. 130, 187 (1989): Ne2 HFD-B, eps / k = 42.25 K, r_m = 3.091 Angstrom, "
    "A* = 895717.95, alpha* = 13.86434671, beta* = -0.12993822, C6 = 1.21317545, C8 = 0.53222749, "
    "C10 = 0.24570703, D = 1.36",
    lambda r: hfd_b(r, 42.25, 3.091, 8.9571795e5, 13.86434671, -0.12993822, 1.21317545, 0.53222749, 0.24570703, 1.36),
)


def mie(r: jax.Array, sigma_a: float, eps_k: float, n: jax.Array | float = 12.0) -> jax.Array:
    """Mie n-6 pair (K) with well depth ``eps_k`` and zero at ``sigma_a`` (Angstrom); LJ at n = 12."""
    n = jnp.asarray(n, jnp.result_type(float))
    c = n / (n - 6.0) * (n / 6.0) ** (6.0 / (n - 6.0))
    x = sigma_a / r
    return c * eps_k * (x**n - x**6)


def _lj(fluid: str, mass_amu: float) -> PairPotential:
    lit = LITERATURE_LJ[fluid]
    s_a, e_k = lit["sigma_m"] * 1e10, lit["epsilon_k"]
    return PairPotential(
        "lj",
        f"Lennard-Jones 12-6 at the gas-data parameters of Hirschfelder, Curtiss & Bird (1954): sigma = {s_a} "
        f"Angstrom, epsilon / k = {e_k} K (an effective potential, not a reference one)",
        lambda r: mie(r, s_a, e_k),
        mass_amu,
        mie=lambda r, n: mie(r, s_a, e_k, n),
    )


POTENTIALS: dict[str, dict[str, PairPotential]] = {
    "neon": {p.name: p for p in (NEON_TT2003, NEON_HFD_B, _lj("neon", 20.1797))},
    "argon": {"lj": _lj("argon", 39.948)},
}


def b2_pair(
    potential: Callable[[jax.Array], jax.Array],
    temperature_k: jax.Array | float,
    fh_scale: jax.Array | float = 0.0,
    mass_amu: float = 20.1797,
    *,
    r_core: float = 1.6,
    r_max: float = 40.0,
    num_points: int = 4001,
) -> jax.Array:
    """B2 (cm^3/mol) of a pair potential (K, r in Angstrom) with an optional Feynman-Hibbs term.

    Simpson's rule on ``[r_core, r_max]`` (odd ``num_points``); below ``r_core`` the Boltzmann
    factor is taken as 0 (the potential must be thousands of K there), beyond ``r_max`` the first
    order of a ``-C6 / r^6`` tail with ``C6 = -V(r_max) r_max^6``.  ``u'`` and ``u''`` come
    from automatic differentiation.  Traced: vmaps over ``temperature_k`` and ``fh_scale``.
    """
    if num_points % 2 == 0:
        raise ValueError("num_points must be odd for Simpson's rule")
    r = jnp.linspace(r_core, r_max, num_points)
    d1 = jax.vmap(jax.grad(potential))
    d2 = jax.vmap(jax.grad(jax.grad(potential)))
    u = potential(r)
    lap = d2(r) + 2.0 * d1(r) / r
    # hbar^2 / (24 mu k T) in Angstrom^2 with mu = m / 2 (the constant in float64: its SI
    # factors under- and overflow float32).
    d_fh = float(HBAR**2 / (24.0 * 0.5 * mass_amu * AMU * K_B) * 1e20) / temperature_k
    u_fh = u + fh_scale * d_fh * lap
    f = jnp.expm1(-jnp.minimum(u_fh / temperature_k, 500.0)) * r * r
    h = (r_max - r_core) / (num_points - 1)
    w = jnp.ones(num_points).at[1:-1:2].set(4.0).at[2:-1:2].set(2.0) * h / 3.0
    tail = -u[-1] * r_max**3 / (3.0 * temperature_k)
    integral = -(r_core**3) / 3.0 + jnp.sum(w * f) + tail
    return -2.0 * math.pi * integral * N_A * 1e-24


def b2_catalogue(shape: str = "wall") -> Catalogue:
    """The pair-data catalogue (order = ``theta_full`` order after the two scales).

    ``shape="wall"``: the third effect is the repulsive-wall stretch of a reference potential;
    ``"mie"``: the repulsive exponent of an n-6 family (``pair_shape``, n = 12 + eta).
    """
    if shape not in ("wall", "mie"):
        raise ValueError(f"shape must be 'wall' or 'mie', not {shape!r}")
    shape_effect = (
        Effect(
            "repulsive_wall",
            -0.1,
            0.1,
            0.0,
            "relative stretch of r_m - r inside the well",
            "The repulsive wall is softer (eta > 0) or steeper (eta < 0) than the potential's: a pair-shape error.",
            "physical",
            "B2 at high temperatures, where collisions probe the wall",
            ("length_scale",),
        )
        if shape == "wall"
        # The engine's Mie-exponent effect, confused here with the scales rather than sigma, epsilon.
        else dataclasses.replace(fluid_catalogue()["pair_shape"], confusable_with=("length_scale", "energy_scale"))
    )
    return Catalogue(
        [
            Effect(
                "temperature_offset",
                -0.02,
                0.02,
                0.0,
                "relative",
                "The temperatures differ from the stated ones: T -> T (1 + eta).",
                "measurement",
                "the high-temperature B2, where dB2/dT is small and FH negligible",
                ("energy_scale",),
            ),
            Effect(
                "feynman_hibbs",
                0.0,
                3.0,
                0.0,
                "fh_scale (1 = hbar^2 / (24 mu k T))",
                "Quantum swelling of the repulsive core of light atoms (quadratic Feynman-Hibbs).",
                "physical",
                "the low-temperature B2 (it scales as 1/T; a scale change does not)",
                ("length_scale",),
                expected=1.0,
            ),
            shape_effect,
            Effect(
                "axilrod_teller",
                0.0,
                0.25,
                0.0,
                "nu = C9 / (epsilon sigma^9)",
                "Three-body triple-dipole dispersion: it does not act on a pair, so B2 cannot see it.",
                "physical",
                "dense-fluid data (pressure and energy of the liquid)",
            ),
        ],
        name="pair data (B2) with a reference potential",
        notes=(
            "B2 sees only the pair: a quantum correction, the wall's shape and the temperature scale; "
            "three-body forces and densities are invisible to it by construction."
        ),
    )


@dataclass(frozen=True)
class B2Design:
    """Everything a B2 criticism needs, from :func:`b2_design`.

    Attributes
    ----------
    simulate : callable ``(key, theta_full (6,)) -> B2 (T,)`` in cm^3/mol, measurement noise included
    catalogue : Catalogue
    low, high : numpy.ndarray, shape (2,)
        The scale prior box (the potential's stated uncertainty).
    names : list of str
        ``"B2 <T> K"`` per temperature.
    observed, uncertainty, temperature_k : numpy.ndarray, shape (T,)
    potential : PairPotential
    """

    simulate: Callable
    catalogue: Catalogue
    low: np.ndarray
    high: np.ndarray
    names: list[str]
    observed: np.ndarray
    uncertainty: np.ndarray
    temperature_k: np.ndarray
    potential: PairPotential


def b2_design(
    fluid: str = "neon",
    potential: str | PairPotential = "tt2003",
    temperatures_k: Sequence[float] | None = None,
    length_uncertainty: float = 0.01,
    energy_uncertainty: float = 0.02,
    measurement_noise: bool = True,
) -> B2Design:
    """The B2 design of ``fluid`` with a ``potential`` whose scales move within a box.

    Parameters
    ----------
    fluid : {"neon", "argon"}
    potential : name in ``POTENTIALS[fluid]`` or a PairPotential
        A reference potential (neon: ``"tt2003"``, ``"hfd_b"``), whose box states its
        uncertainty, or ``"lj"`` (both fluids), an effective potential whose box is a search
        range; an n-6 family gets the ``pair_shape`` effect (Mie exponent), a reference
        potential the ``repulsive_wall`` stretch (:func:`b2_catalogue`).
    temperatures_k : optional
        A subset of the data's B2 temperatures (default all).
    length_uncertainty, energy_uncertainty : float
        Half-widths of the uniform scale box (relative): the prior is
        ``[1 - u, 1 + u]`` for each scale.
    measurement_noise : bool
        Add the data's stated uncertainty as Gaussian noise (one draw per key).

    Raises
    ------
    ValueError
        Unknown fluid or potential, temperatures not in the data, non-positive uncertainties.
    """
    if fluid not in POTENTIALS:
        raise ValueError(f"no pair potentials for fluid {fluid!r}: available are {sorted(POTENTIALS)}")
    pot = POTENTIALS[fluid].get(potential) if isinstance(potential, str) else potential
    if pot is None:
        raise ValueError(f"unknown potential {potential!r} for {fluid}: available are {sorted(POTENTIALS[fluid])}")
    if not (0 < length_uncertainty < 0.5 and 0 < energy_uncertainty < 0.5):
        raise ValueError("length_uncertainty and energy_uncertainty must lie in (0, 0.5)")
    b2 = load(fluid).b2
    if temperatures_k is not None:
        keep = np.isin(b2["T_K"], np.asarray(temperatures_k, float))
        if keep.sum() != len(set(temperatures_k)):
            raise ValueError(f"B2 temperatures must be among the data's {b2['T_K'].tolist()} K")
        b2 = b2[keep]
    t = np.asarray(b2["T_K"], float)
    observed = np.asarray(b2["B2_m3_mol"], float) * 1e6
    unc = np.asarray(b2["u_B2_m3_mol"], float) * 1e6
    r_m = pot.r_min
    t_j, unc_j = jnp.asarray(t), jnp.asarray(unc)

    def one(theta: jax.Array, temperature: jax.Array) -> jax.Array:
        length, energy, dt_rel, fh, shape = theta[0], theta[1], theta[2], theta[3], theta[4]

        def u(r: jax.Array) -> jax.Array:
            if pot.mie is not None:
                return energy * pot.mie(r / length, 12.0 + shape)
            inner = jnp.where(r < r_m * length, r_m * length - (r_m * length - r) * (1.0 + shape), r)
            return energy * pot.energy(inner / length)

        return b2_pair(u, temperature * (1.0 + dt_rel), fh, pot.mass_amu)

    def simulate(key: jax.Array, theta: jax.Array) -> jax.Array:
        theta = jnp.asarray(theta, jnp.float32)
        out = jax.vmap(one, in_axes=(None, 0))(theta, t_j)
        if measurement_noise:
            out = out + unc_j * jax.random.normal(key, out.shape)
        return out.astype(jnp.float32)

    return B2Design(
        simulate,
        b2_catalogue("mie" if pot.mie is not None else "wall"),
        np.array([1.0 - length_uncertainty, 1.0 - energy_uncertainty]),
        np.array([1.0 + length_uncertainty, 1.0 + energy_uncertainty]),
        [f"B2 {ti:g} K" for ti in t],
        observed,
        unc,
        t,
        pot,
    )
