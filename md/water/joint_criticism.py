"""Model criticism of any published rigid water model on the joint summaries.

:func:`joint_catalogue` is the water catalogue (:func:`md.water.criticism.water_catalogue`)
for one model: a 3-site model has no M site, so ``msite_shift`` is left out.
:class:`WaterModelWithEffects` is the matching ``simulate(key, theta_full)`` returning the 14
joint summaries of :class:`md.water.model_simulator.WaterModelSimulator` (S1..S9, density,
enthalpy of vaporisation, second shell of g_OO) with the effects applied.  S9 already carries
the simulator's Yeh-Hummer correction with the model's published viscosity, so
``finite_box_diffusion`` adds a further shift on top of it (a residual, e.g. a viscosity that
differs from the published one):

* ``charge_scale``: ``q_H -> q_H (1 + eta)`` (``q_O`` or ``q_M = -2 q_H``); the enthalpy's
  self-polarisation correction follows the new dipole;
* ``msite_shift``: ``d_OM -> d_OM + eta`` (4-site models);
* ``temperature_offset``: the thermostat at ``T + eta`` (and ``R T`` in the enthalpy);
* ``finite_box_diffusion``: the Yeh-Hummer shift of S9 for the run's box, fluidity ``eta``;
* ``oh_contamination``: g_OO mixed with g_OH before S4..S8 are computed.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from jaxabc.criticism import Catalogue
from md.water.criticism import water_catalogue
from md.water.models import WaterModel, get_model

__all__ = ["WaterModelWithEffects", "joint_catalogue"]


def joint_catalogue(model: WaterModel | str) -> Catalogue:
    """The water catalogue for ``model``: without ``msite_shift`` for 3-site models; for 4-site
    models its box reaches down to ``-d_OM``, the physical limit where M sits on O."""
    model = get_model(model)
    full = water_catalogue()
    if model.num_sites == 4:
        # The shift's sensitivity step stays that of the catalogue's own box (a fifth of its
        # half-range), so that widening the box does not move the screening's finite differences.
        return Catalogue(
            [
                replace(e, low=-model.om_distance_nm, step=e.step or 0.2 * (e.high - e.low) / 2)
                if e.name == "msite_shift"
                else e
                for e in full
            ],
            name=f"water ({model.name})",
            notes=full.notes,
        )
    keep = [e for e in full if e.name != "msite_shift"]
    keep = [replace(e, confusable_with=tuple(c for c in e.confusable_with if c != "msite_shift")) for e in keep]
    return Catalogue(keep, name=f"water ({model.name})", notes=full.notes)


class WaterModelWithEffects:
    """Picklable host ``simulate(key, theta_full) -> (14,)`` for criticism of one water model.

    ``theta_full = (sigma_OO, epsilon_OO, *effects)`` with the effects in the order of
    :func:`joint_catalogue` ``(model)``; at their nulls it equals
    :class:`md.water.model_simulator.WaterModelSimulator` (same seeds, same summaries).

    Parameters
    ----------
    model : WaterModel or str
    preset, statistics, observed_kind, **options
        As for :class:`~md.water.model_simulator.WaterModelSimulator`.
    """

    def __init__(
        self,
        model: WaterModel | str,
        preset: str = "quick",
        statistics: str = "robust",
        observed_kind: str = "xray",
        **options: Any,
    ) -> None:
        from md.water.model_simulator import WaterModelSimulator

        self.model = get_model(model)
        self.catalogue = joint_catalogue(self.model)
        self.effects = [e.name for e in self.catalogue]
        self.base = WaterModelSimulator(self.model, preset, statistics, observed_kind, **options)
        self._args = (statistics, observed_kind, options)

    def __repr__(self) -> str:
        return f"WaterModelWithEffects({self.base!r}, effects={self.effects})"

    @property
    def protocol(self) -> Any:
        """The protocol at the effects' nulls (for caches keyed on it)."""
        return self.base.protocol

    def simulator_for(self, eta: dict[str, float]) -> Any:
        """The WaterModelSimulator with the charge, M-site and temperature effects applied."""
        from md.water.model_simulator import WaterModelSimulator

        charge, shift, offset = (eta.get(n, 0.0) for n in ("charge_scale", "msite_shift", "temperature_offset"))
        if charge == 0.0 and shift == 0.0 and offset == 0.0:
            return self.base
        model = replace(
            self.model,
            charge_h_e=self.model.charge_h_e * (1.0 + charge),
            om_distance_nm=self.model.om_distance_nm + shift,
        )
        protocol = replace(self.base.protocol, temperature_k=self.base.protocol.temperature_k + offset)
        statistics, observed_kind, options = self._args
        options = {k: v for k, v in options.items() if k == "gmx"}
        return WaterModelSimulator(model, protocol, statistics, observed_kind, **options)

    def __call__(self, key, theta_full) -> np.ndarray:
        from md.water.criticism import diffusion_shift
        from md.water.simulator import OBSERVED_KINDS
        from md.water.statistics import summary_statistics

        theta_full = np.asarray(theta_full, np.float64).reshape(-1)
        if theta_full.size != 2 + len(self.effects):
            raise ValueError(f"theta_full must hold sigma, epsilon and {self.effects}, got {theta_full.size} numbers")
        eta = dict(zip(self.effects, theta_full[2:].tolist(), strict=True))
        simulate = self.simulator_for(eta)
        out = simulate.run(key, theta_full[:2])
        stats = np.array(out.statistics, np.float64)
        second_shell = np.asarray(out.second_shell, np.float64)
        w = eta.get("oh_contamination", 0.0)
        if w != 0.0:
            from md.water.statistics import second_shell_statistics

            c = out.curves
            g_oh = np.interp(c.r_oo_nm, c.r_oh_nm, c.g_oh)
            mixed = (1.0 - w) * c.g_oo + w * g_oh
            d = stats[8]  # the simulator's (finite-size corrected) D; the mixing does not touch it
            stats = summary_statistics(c._replace(g_oo=mixed), simulate.statistics)
            stats[8] = d
            second_shell = np.asarray(second_shell_statistics(c.r_oo_nm, mixed), np.float64)
        fluidity = eta.get("finite_box_diffusion", 0.0)
        if fluidity != 0.0:
            stats[8] += diffusion_shift(
                out.run.num_molecules,
                out.density_kg_m3,
                fluidity,
                simulate.protocol.temperature_k,
                simulate.statistics,
            )
        stats = np.where(OBSERVED_KINDS[simulate.observed_kind], stats, 0.0)
        return np.concatenate([stats, [out.density_kg_m3, out.hvap_kj_mol], second_shell])
