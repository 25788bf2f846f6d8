"""Stiffness: ``backbone.youngs_modulus_pa`` E and ``backbone.shear_modulus_pa`` G differ from
their nominal values.

Twin and prediction: both take the moduli from the parameter set as they are; no ``[effects]``
key and no hook.

Discrepancy: E and G (log), each within a factor of ten of the model's value (further off is
another material, not a discrepancy). The core's share of the axial stiffness, E·A, moves with E
(``backbone.axial_stiffness_n`` also holds the rigid insert, which does not): a softer core is
also axially softer, and a fit that held EA would leave that as a shortened or offset tip.
"""

from __future__ import annotations

from twin.effects.base import Candidate, Effect, FitParameter, Params

__all__ = ["EFFECT"]

# Factor by which a fitted modulus may differ from the model's.
_RANGE = 10.0


class StiffnessEffect(Effect):
    name = "stiffness"
    description = "Young's and shear moduli differ"
    deciding_experiments = ("tip-load",)
    uses = ("backbone.youngs_modulus_pa", "backbone.shear_modulus_pa")

    def candidate(self, params: Params) -> Candidate:
        b = params.backbone
        e, g = b.youngs_modulus_pa, b.shear_modulus_pa
        return Candidate(self.name, (
            FitParameter("backbone.youngs_modulus_pa", log=True, bounds=(e / _RANGE, e * _RANGE),
                         follows=(("backbone.axial_stiffness_n", b.area_m2),)),
            FitParameter("backbone.shear_modulus_pa", log=True, bounds=(g / _RANGE, g * _RANGE))))


EFFECT = StiffnessEffect()
