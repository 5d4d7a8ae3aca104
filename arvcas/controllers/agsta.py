"""The original AGSTA (Guerrero et al. 2019) with a nominal model in place of the RESO: the paper's baseline."""

from __future__ import annotations

from arvcas.controllers import gsta
from arvcas.controllers.base import register
from arvcas.controllers.smc import G_ADAPT, G_GSTA, G_SURFACE, NominalCompensation, SlidingModeController

__all__ = ["AGSTA"]


class AGSTA(SlidingModeController):
    name = "agsta"  # the paper's name (files, directories and compiled functions keep it)
    aliases = ("agsta_nominal",)  # what it is: the original AGSTA, nominal-model compensation, the gain only grows
    label = "AGSTA"
    color = "tab:red"
    description = "original AGSTA with nominal-model compensation (the paper's baseline)"
    # Table 2's column order for AGSTA
    gains = (G_SURFACE, *G_GSTA, G_ADAPT["l"], G_ADAPT["eps"], G_ADAPT["beta"], G_ADAPT["k1_0"], G_ADAPT["sigma"])
    defaults_block = "agsta"
    compensation = NominalCompensation()

    def k1_next(self, G, k1, s, h):
        return gsta.k1_next_agsta(k1, s, G["sigma"], G["l"], h)


register(AGSTA())
