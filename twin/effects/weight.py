"""The endoscope's weight: ``backbone.mass_kg``, and ``effects.disc_mass_fraction``, the
fraction of it that sits at the discs instead of spread uniformly (0 = off).

Twin and prediction: both build the body (:class:`twin.effects.BodySpec`) with the line mass
(1 − f) m / L and f m / D more at each of the D discs, so the sag changes shape.

Discrepancy: the endoscope's mass (log, within a factor of ten of the model's). Its split
between backbone and discs moves the centre of mass by a twentieth of the length and is
indistinguishable from the mass on a tip-position sweep, so the fraction is not fitted.
"""

from __future__ import annotations

import dataclasses

from twin.effects.base import BodySpec, Candidate, Effect, FitParameter, Key, Params

__all__ = ["EFFECT"]


class WeightEffect(Effect):
    name = "weight"
    description = "the endoscope's weight, or how much of it sits at the discs, differs"
    deciding_experiments = ("tip-load",)
    uses = ("backbone.mass_kg",)
    parameters = (Key("disc_mass_fraction", nonnegative=True),)

    def body_spec(self, params: Params, spec: BodySpec) -> BodySpec:
        """Raises:
            ValueError: ``effects.disc_mass_fraction`` above 1 (more than the whole mass moved).
        """
        b, d = params.backbone, params.discs
        fraction = params.effects.disc_mass_fraction
        if fraction > 1:
            raise ValueError(f"effects.disc_mass_fraction = {fraction!r}: must be <= 1")
        return dataclasses.replace(spec, line_mass_kg_per_m=b.mass_kg * (1.0 - fraction) / b.length_m,
                                   disc_mass_kg=spec.disc_mass_kg + fraction * b.mass_kg / d.count)

    def candidate(self, params: Params) -> Candidate:
        mass = params.backbone.mass_kg
        return Candidate(self.name, (FitParameter("backbone.mass_kg", log=True, bounds=(mass / 10.0, mass * 10.0)),))


EFFECT = WeightEffect()
