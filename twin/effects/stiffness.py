"""Stiffness: ``backbone.youngs_modulus_pa`` E and ``backbone.shear_modulus_pa`` G differ from
their nominal values.

Twin and prediction: both take the moduli from the parameter set as they are; no ``[effects]``
key and no hook.

Discrepancy: E and G (log).
"""

from __future__ import annotations

from twin.effects.base import Candidate, Effect, FitParameter, Params

__all__ = ["EFFECT"]


class StiffnessEffect(Effect):
    name = "stiffness"
    description = "Young's and shear moduli differ"
    uses = ("backbone.youngs_modulus_pa", "backbone.shear_modulus_pa")

    def candidate(self, params: Params) -> Candidate:
        return Candidate(self.name, (FitParameter("backbone.youngs_modulus_pa", log=True),
                                     FitParameter("backbone.shear_modulus_pa", log=True)))


EFFECT = StiffnessEffect()
