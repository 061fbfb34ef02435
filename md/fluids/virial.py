"""Second virial coefficient B2(T) of Lennard-Jones and Feynman-Hibbs LJ by quadrature.

Everything here is in LJ reduced units: distance in sigma, energy in epsilon, temperature
``T* = k T / epsilon``, ``B2* = B2 / (N_A sigma^3)``.  The Feynman-Hibbs (quadratic) effective
pair potential is::

    u_FH(r) = u(r) + fh_scale * D (u''(r) + 2 u'(r) / r),     D = hbar^2 / (24 mu k T)

with ``mu = m / 2`` the reduced mass of a pair; :func:`fh_coefficient` gives ``D* = D / sigma^2``.
"""

from __future__ import annotations

import numpy as np
from scipy import integrate, special

__all__ = ["b2_lj", "b2_lj_series", "b2_reduced", "fh_coefficient", "lj_fh_potential"]

HBAR = 1.054571817e-34  # J s
K_B = 1.380649e-23  # J / K
AMU = 1.66053906660e-27  # kg
N_A = 6.02214076e23  # 1 / mol


def fh_coefficient(temperature_k: float | np.ndarray, mass_amu: float, sigma_m: float) -> np.ndarray:
    """``D* = hbar^2 / (24 mu k T sigma^2)`` with ``mu = m / 2``; dimensionless, same shape as T."""
    t = np.asarray(temperature_k, float)
    if np.any(t <= 0) or mass_amu <= 0 or sigma_m <= 0:
        raise ValueError("temperature, mass and sigma must be positive (K, amu, m)")
    mu = 0.5 * mass_amu * AMU
    return HBAR**2 / (24.0 * mu * K_B * t * sigma_m**2)


def lj_fh_potential(r: np.ndarray, d_star: float = 0.0) -> np.ndarray:
    """Reduced LJ pair energy plus the Feynman-Hibbs term ``d_star (u'' + 2 u' / r)``; shape of r."""
    r = np.asarray(r, float)
    ir6 = r**-6
    u = 4.0 * (ir6 * ir6 - ir6)
    # u' = 4 (-12 r^-13 + 6 r^-7), u'' = 4 (156 r^-14 - 42 r^-8); u'' + 2 u'/r = 4 (132 r^-14 - 30 r^-8)
    lap = 4.0 * (132.0 * ir6 * ir6 - 30.0 * ir6) / (r * r)
    return u + d_star * lap


def b2_reduced(temperature: float, d_star: float = 0.0) -> float:
    """``B2*(T*) = -2 pi int_0^inf (exp(-u_FH(r) / T*) - 1) r^2 dr`` for reduced LJ (+ FH).

    Parameters
    ----------
    temperature : float
        ``T* > 0``.
    d_star : float
        Feynman-Hibbs coefficient ``D*`` (already multiplied by any ``fh_scale``); 0 is classical.
        With ``d_star > 0`` the FH core is steeper; a negative value is refused (it makes the
        effective potential unbounded below at small r).
    """
    if not temperature > 0:
        raise ValueError(f"reduced temperature must be positive, got {temperature}")
    if d_star < 0:
        raise ValueError("d_star must be >= 0: the FH term with a negative coefficient diverges to -inf at r -> 0")

    def f(r: float) -> float:
        return float(np.expm1(-lj_fh_potential(np.asarray(r), d_star) / temperature)) * r * r

    # The core (r < 0.5) contributes -1 * r^2 to high accuracy: exp(-u/T) underflows there.
    core = -(0.5**3) / 3.0
    parts = [
        integrate.quad(f, a, b, limit=200, epsabs=1e-12, epsrel=1e-11)[0]
        for a, b in ((0.5, 1.0), (1.0, 1.5), (1.5, 3.0), (3.0, 10.0))
    ]
    tail = integrate.quad(f, 10.0, np.inf, limit=200, epsabs=1e-13)[0]
    return float(-2.0 * np.pi * (core + sum(parts) + tail))


def b2_lj(temperature: float | np.ndarray, d_star: float | np.ndarray = 0.0) -> np.ndarray:
    """Vectorised :func:`b2_reduced` over matching (or broadcast) arrays of ``T*`` and ``D*``."""
    t, d = np.broadcast_arrays(np.asarray(temperature, float), np.asarray(d_star, float))
    return np.vectorize(b2_reduced)(t, d)


def b2_lj_series(temperature: float | np.ndarray, terms: int = 60) -> np.ndarray:
    """Classical LJ ``B2*`` from its exact series (Hirschfelder, Curtiss & Bird, eq. 3.6-8)::

    B2* = -(2 pi / 3) sum_n 2^(n + 1/2) / (4 n!) Gamma((2n - 1) / 4) T*^(-(2n + 1) / 4)
    """
    t = np.asarray(temperature, float)
    n = np.arange(terms)[:, None]
    coef = 2.0 ** (n + 0.5) / (4.0 * special.factorial(n)) * special.gamma((2.0 * n - 1.0) / 4.0)
    return -(2.0 * np.pi / 3.0) * np.sum(coef * t.reshape(1, -1) ** (-(2.0 * n + 1.0) / 4.0), axis=0).reshape(t.shape)
