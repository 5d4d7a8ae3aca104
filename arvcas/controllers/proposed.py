"""The proposed controller of section 3: modified AGSTA (eq. 19's decreasing law) + ATD + RESO."""

from __future__ import annotations

from arvcas.controllers import gsta
from arvcas.controllers.base import register
from arvcas.controllers.smc import G_ADAPT, G_GSTA, G_OMEGA, G_SURFACE, RESOCompensation, SlidingModeController

__all__ = ["Proposed", "PROPOSED_GAINS"]

# Table 2's column order for the proposed controller
PROPOSED_GAINS = (G_SURFACE, *G_GSTA, G_ADAPT["l"], G_ADAPT["r"], G_ADAPT["k1_0"], G_ADAPT["k1min"], G_ADAPT["eps"],
                  G_ADAPT["beta"], G_ADAPT["sigma"], G_OMEGA)


class Proposed(SlidingModeController):
    name = "proposed"  # the paper's name (files, directories and compiled functions keep it)
    aliases = ("agsta_reso_decay",)  # what it is: AGSTA, RESO compensation, the gain's clamped exponential decay
    label = "Proposed"
    color = "tab:blue"
    description = "modified AGSTA (eq. 19) with the ATD reference and the RESO (eq. 14-16, 20)"
    gains = PROPOSED_GAINS
    defaults_block = "proposed"
    compensation = RESOCompensation()

    def k1_next(self, G, k1, s, h):
        return gsta.k1_next_proposed(k1, s, G["sigma"], G["l"], G["r"], G["k1min"], h)


register(Proposed())
