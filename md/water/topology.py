"""TIP4P topology for GROMACS with every calibrated parameter as a preprocessor macro.

Each parameter a calibration may vary is a macro with TIP4P's own value as default; a run sets
its values through the ``define`` line of the ``.mdp`` file (:meth:`TIP4PParameters.defines`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["TIP4P_PARAMETERS", "TIP4PParameters", "topology_text"]


@dataclass(frozen=True)
class TIP4PParameters:
    """TIP4P force-field parameters that a run may vary.

    Defaults are TIP4P (Jorgensen et al. 1983) as in GROMACS's ``oplsaa.ff/tip4p.itp``.

    Attributes
    ----------
    sigma_ow_nm : float
        Oxygen Lennard-Jones sigma (nm).
    epsilon_ow_kj_mol : float
        Oxygen Lennard-Jones epsilon (kJ/mol).
    charge_h_e : float
        Hydrogen partial charge (e); the M site carries ``-2 * charge_h_e`` and the oxygen none.
    om_distance_nm : float
        Distance of the M site from the oxygen along the HOH bisector (nm).
    oh_distance_nm, hh_distance_nm : float
        Rigid geometry (nm), held by SETTLE. Not meant to be calibrated (SETTLE needs both).
    """

    sigma_ow_nm: float = 0.315365
    epsilon_ow_kj_mol: float = 0.648520
    charge_h_e: float = 0.52
    om_distance_nm: float = 0.015
    oh_distance_nm: float = 0.09572
    hh_distance_nm: float = 0.15139

    def __post_init__(self) -> None:
        for name in ("sigma_ow_nm", "epsilon_ow_kj_mol", "om_distance_nm", "oh_distance_nm", "hh_distance_nm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"TIP4P parameter {name} must be finite and > 0, got {value!r}")
        if not math.isfinite(self.charge_h_e):
            raise ValueError(f"charge_h_e must be finite, got {self.charge_h_e!r}")

    @property
    def charge_m_e(self) -> float:
        """M-site charge (e), ``-2 * charge_h_e`` so that the molecule stays neutral."""
        return -2.0 * self.charge_h_e

    @property
    def vsite_coefficient(self) -> float:
        """``virtual_sites3`` coefficient ``a = b`` placing M at ``om_distance_nm``."""
        half_angle_cos = math.sqrt(1.0 - (self.hh_distance_nm / (2 * self.oh_distance_nm)) ** 2)
        return self.om_distance_nm / (2.0 * self.oh_distance_nm * half_angle_cos)

    def defines(self) -> str:
        """The ``define`` line of the ``.mdp`` file that sets these parameters."""
        # repr-precision floats: the topology must see exactly the theta the sampler proposed.
        return (
            f"-DSIGMA_OW={self.sigma_ow_nm!r} -DEPSILON_OW={self.epsilon_ow_kj_mol!r} "
            f"-DQ_H={self.charge_h_e!r} -DQ_M={self.charge_m_e!r} "
            f"-DVSITE_A={self.vsite_coefficient!r}"
        )


#: TIP4P's own parameters (the truth of the simulated-data calibration).
TIP4P_PARAMETERS = TIP4PParameters()


def topology_text(num_molecules: int, params: TIP4PParameters = TIP4P_PARAMETERS) -> str:
    """Return a self-contained TIP4P topology for ``num_molecules`` waters.

    Every variable parameter is a macro, defaulting to ``params`` (so ``grompp`` also works
    without a ``define`` line), overridden per run by :meth:`TIP4PParameters.defines`.
    """
    # comb-rule 2 (sigma/epsilon): only OW carries LJ, so the rule never mixes two values; the
    # [atomtypes] therefore hold exactly sigma and epsilon.  gen-pairs/fudge are irrelevant
    # (no 1-4 pairs in a rigid 4-site molecule).
    return f"""; jaxabc TIP4P water topology (self-contained; parameters are macros)
#ifndef SIGMA_OW
#define SIGMA_OW {params.sigma_ow_nm!r}
#endif
#ifndef EPSILON_OW
#define EPSILON_OW {params.epsilon_ow_kj_mol!r}
#endif
#ifndef Q_H
#define Q_H {params.charge_h_e!r}
#endif
#ifndef Q_M
#define Q_M {params.charge_m_e!r}
#endif
#ifndef VSITE_A
#define VSITE_A {params.vsite_coefficient!r}
#endif

[ defaults ]
; nbfunc  comb-rule  gen-pairs  fudgeLJ  fudgeQQ
1         2          no         1.0      1.0

[ atomtypes ]
; name  at.num  mass     charge  ptype  sigma     epsilon
OW      8       15.9994  0.0     A      SIGMA_OW  EPSILON_OW
HW      1       1.008    0.0     A      0.0       0.0
MW      0       0.0      0.0     D      0.0       0.0

[ moleculetype ]
; name  nrexcl
SOL     2

[ atoms ]
; nr  type  resnr  res  atom  cgnr  charge  mass
1     OW    1      SOL  OW    1     0.0     15.9994
2     HW    1      SOL  HW1   1     Q_H     1.008
3     HW    1      SOL  HW2   1     Q_H     1.008
4     MW    1      SOL  MW    1     Q_M     0.0

[ settles ]
; OW  funct  doh  dhh
1     1      {params.oh_distance_nm!r}  {params.hh_distance_nm!r}

[ exclusions ]
1 2 3 4
2 1 3 4
3 1 2 4
4 1 2 3

[ virtual_sites3 ]
; site  from       funct  a        b
4       1  2  3    1      VSITE_A  VSITE_A

[ system ]
TIP4P water

[ molecules ]
SOL {num_molecules}
"""
