"""Finite-size (Yeh-Hummer) correction of the simulated self-diffusion coefficient.

In a cubic periodic box of edge ``L`` a molecule drags its own periodic images through the
liquid, which slows its diffusion by (Yeh & Hummer 2004, J. Phys. Chem. B 108, 15873)

    D_inf - D_box = xi k_B T / (6 pi eta L),        xi = 2.837297,

with ``eta`` the shear viscosity **of the simulated model** (not of real water).  The water
simulator (:class:`md.water.model_simulator.WaterModelSimulator`) returns ``D_inf`` as S9,
using :func:`model_viscosity_mpa_s`: each model's published 298 K viscosity
(:data:`MODEL_VISCOSITY_298K`), scaled to the run's temperature by real water's relative
temperature dependence (:func:`water_viscosity_mpa_s`).  The viscosity is that of the model
at its *published* Lennard-Jones pair; at other (sigma, epsilon) it is an approximation (see
``md/water/README.md``).  :func:`measure_viscosity` measures a model's viscosity with GROMACS's
periodic-perturbation (cos-acceleration) method; it did not reproduce the published values
(about 0.6-0.7 mPa s for TIP4P and TIP3P alike; ``md/water/README.md``) and is not used.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any, cast

import numpy as np

__all__ = [
    "MODEL_VISCOSITY_298K",
    "YEH_HUMMER_XI",
    "correct_diffusion",
    "measure_viscosity",
    "model_viscosity_mpa_s",
    "water_viscosity_mpa_s",
    "yeh_hummer_shift",
]

#: Yeh & Hummer's (2004) constant for a cubic periodic lattice.
YEH_HUMMER_XI = 2.837297
_BOLTZMANN_J_K = 1.380649e-23

_GONZALEZ_ABASCAL = "Gonzalez & Abascal 2010, J. Chem. Phys. 132, 096101 (Green-Kubo, 298 K, 1 bar)"
#: Shear viscosity (mPa s) of each model at its published parameters, 298 K, 1 bar, with source.
MODEL_VISCOSITY_298K: dict[str, dict[str, object]] = {
    "TIP4P": {"value": 0.494, "source": _GONZALEZ_ABASCAL},
    "TIP4P/2005": {"value": 0.855, "source": _GONZALEZ_ABASCAL},
    "SPC/E": {"value": 0.729, "source": _GONZALEZ_ABASCAL},
    "TIP3P": {"value": 0.321, "source": _GONZALEZ_ABASCAL},
    # Not in Gonzalez & Abascal's table.  0.69 is between SPC/E and TIP4P/2005, as the
    # nano-channel viscosities of Markesteijn, Hartkamp, Luding & Westerweel 2012 (J. Chem.
    # Phys. 136, 134104) order them; not measured here (measure_viscosity is not validated).
    "TIP4P-Ew": {
        "value": 0.69,
        "source": "approximate; ordering of Markesteijn et al. 2012, J. Chem. Phys. 136, 134104; not measured here",
    },
}


def water_viscosity_mpa_s(temperature_k: float) -> float:
    """Real water's shear viscosity (mPa s) at 1 bar: Vogel equation ``A 10^(B / (T - C))``.

    ``A = 2.414e-2 mPa s``, ``B = 247.8 K``, ``C = 140 K``; within 0.2 % of IAPWS 2008
    (0.8900 mPa s at 298.15 K, 0.9544 at 295.15 K) between 283 and 313 K.  Used only for the
    *relative* temperature dependence of the models' viscosities.
    """
    if not (math.isfinite(temperature_k) and temperature_k > 150.0):
        raise ValueError(f"temperature_k must be finite and > 150 K, got {temperature_k!r}")
    return 2.414e-2 * 10.0 ** (247.8 / (temperature_k - 140.0))


def model_viscosity_mpa_s(model: Any, temperature_k: float = 298.15) -> float:
    """A model's shear viscosity (mPa s) at ``temperature_k``.

    The published 298 K value times ``eta_water(T) / eta_water(298 K)``: the models' viscosities
    change with temperature roughly as water's (Markesteijn et al. 2012); over the 3 K between
    the X-ray data and 298 K this scaling is a 7 % change of a 10-20 % correction.
    """
    from md.water.models import get_model

    name = get_model(model).name
    if name not in MODEL_VISCOSITY_298K:
        raise ValueError(f"no viscosity for {name!r}; known: {sorted(MODEL_VISCOSITY_298K)}")
    eta = float(MODEL_VISCOSITY_298K[name]["value"])  # type: ignore[arg-type]
    return eta * water_viscosity_mpa_s(temperature_k) / water_viscosity_mpa_s(298.0)


def yeh_hummer_shift(box_nm: float, viscosity_mpa_s: float, temperature_k: float = 298.15) -> float:
    """Finite-size deficit of the self-diffusion coefficient in a cubic box, in 1e-5 cm^2/s.

    ``D_infinite = D_box + xi k_B T / (6 pi eta L)`` (Yeh & Hummer 2004, J. Phys. Chem. B 108,
    15873), ``xi = 2.837297``.  ``eta`` must be the *model's* shear viscosity: the
    hydrodynamic self-interaction that slows diffusion in the box is that of the simulated
    liquid, not of real water.

    Raises
    ------
    ValueError
        Non-positive or non-finite input.
    """
    values = np.array([box_nm, viscosity_mpa_s, temperature_k], dtype=float)
    if not np.all(np.isfinite(values) & (values > 0)):
        raise ValueError(f"box_nm, viscosity_mpa_s and temperature_k must be finite and > 0, got {values}")
    shift_m2_s = YEH_HUMMER_XI * _BOLTZMANN_J_K * temperature_k / (6 * np.pi * viscosity_mpa_s * 1e-3 * box_nm * 1e-9)
    return float(shift_m2_s * 1e4 * 1e5)  # m^2/s -> cm^2/s -> 1e-5 cm^2/s


def correct_diffusion(d_box: float, box_nm: float, viscosity_mpa_s: float, temperature_k: float) -> tuple[float, float]:
    """``(D_inf, shift)`` in 1e-5 cm^2/s for a D measured in a cubic box of edge ``box_nm``."""
    shift = yeh_hummer_shift(box_nm, viscosity_mpa_s, temperature_k)
    return float(d_box) + shift, shift


def measure_viscosity(
    model,
    temperature_k: float = 298.0,
    num_steps: int = 75_000,
    acceleration_nm_ps2: float = 0.1,
    discard_ps: float = 20.0,
    seed: int = 1,
    gmx: str | None = None,
    workdir: str | os.PathLike | None = None,
) -> dict:
    """Shear viscosity of ``model`` (published parameters) by periodic perturbation.

    GROMACS's ``cos-acceleration`` applies ``a cos(2 pi z / L_z)`` along x; the steady velocity
    profile's amplitude gives ``eta`` (Hess 2002, J. Chem. Phys. 116, 209), reported by ``gmx
    energy`` as ``1/Viscosity``.  The ``quick`` preset's box (216 molecules), thermostat and
    barostat; ``num_steps`` of 2 fs, the first ``discard_ps`` discarded.  A small box and a
    finite amplitude bias eta low by a few percent (shear thinning); this is a cross-check of
    the published values, not a replacement.

    Returns
    -------
    dict
        ``viscosity_mpa_s``, ``standard_error_mpa_s`` (over 5 blocks), ``density_kg_m3``,
        ``box_nm``, the settings and the wall time.
    """
    import tempfile

    from md.water.gromacs import _run_gmx, find_gmx, run_gromacs
    from md.water.model_simulator import run_gromacs_three_site
    from md.water.models import get_model
    from md.water.protocol import get_protocol

    model = get_model(model)
    gmx_path = find_gmx(gmx)
    protocol = get_protocol(
        "quick",
        num_steps=int(num_steps),
        temperature_k=float(temperature_k),
        frame_interval_steps=50,
        analysis_start_ps=float(discard_ps),
        timeout_s=3600.0,
        extra_mdp={"cos-acceleration": repr(float(acceleration_nm_ps2))},
    )
    start = time.monotonic()
    context = tempfile.TemporaryDirectory(prefix="jaxabc-visc-") if workdir is None else None
    folder = Path(context.name) if context is not None else Path(cast("str | os.PathLike", workdir))
    try:
        if model.num_sites == 4:
            run = run_gromacs(model.tip4p_parameters(), protocol, folder, seed, seed, gmx=gmx_path)
        else:
            run = run_gromacs_three_site(model, protocol, folder, seed, seed, gmx_path)
        values = {}
        for term in ("1/Viscosity", "Density", "Box-X"):
            xvg = folder / f"{term.replace('/', '_')}.xvg"
            _run_gmx(
                [gmx_path, "energy", "-f", run.energy.name, "-o", xvg.name, "-b", repr(float(discard_ps))],
                folder,
                time.monotonic() + 120,
                stdin=f"{term}\n\n",
            )
            values[term] = np.loadtxt(xvg, comments=["#", "@"], ndmin=2)[:, 1]
    finally:
        if context is not None:
            context.cleanup()
    inverse = values["1/Viscosity"]  # 1/(Pa s)
    blocks = np.array([b.mean() for b in np.array_split(inverse, 5)])
    mean_inverse = float(inverse.mean())
    eta = 1e3 / mean_inverse
    se = 1e3 * float(blocks.std(ddof=1) / np.sqrt(len(blocks))) / mean_inverse**2
    return {
        "model": model.name,
        "theta": list(model.lj),
        "temperature_k": float(temperature_k),
        "acceleration_nm_ps2": float(acceleration_nm_ps2),
        "length_ps": protocol.length_ps,
        "discarded_ps": float(discard_ps),
        "num_molecules": run.num_molecules,
        "viscosity_mpa_s": eta,
        "standard_error_mpa_s": se,
        "density_kg_m3": float(values["Density"].mean()),
        "box_nm": float(values["Box-X"].mean()),
        "wall_s": time.monotonic() - start,
    }
