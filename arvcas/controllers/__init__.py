"""Controller building blocks (paper section 3, SPEC 5 and 5b), one module per idea.

- :mod:`.atd`:  adaptive tracking differentiator (eq. 12-13), the reference ``y1``, ``y2``.
- :mod:`.reso`: reduced-order extended state observer (eq. 14-16), the disturbance ``chi2_hat``.
- :mod:`.gsta`: generalised super-twisting (eq. 18, 21), explicit and implicit (SPEC 5b) steps,
  and the adaptive gain laws (eq. 19; AGSTA; the "traditional" law of Fig. 10).

All steps are pure functions over any CasADi type, elementwise per DOF, for use inside one
compiled closed-loop step function.
"""

from arvcas.controllers.atd import atd_params, atd_step, fhan
from arvcas.controllers.gsta import gsta_explicit, gsta_implicit, k1_next_agsta, k1_next_proposed, k1_next_traditional, k2_of_k1, phi1, phi2
from arvcas.controllers.reso import check_reso_stability, reso_gains, reso_poles, reso_step

__all__ = [
    "fhan",
    "atd_params",
    "atd_step",
    "reso_gains",
    "reso_step",
    "reso_poles",
    "check_reso_stability",
    "phi1",
    "phi2",
    "k2_of_k1",
    "k1_next_proposed",
    "k1_next_agsta",
    "k1_next_traditional",
    "gsta_explicit",
    "gsta_implicit",
]
