"""Tip-load error: ``effects.tip_load_error_fraction``, a hung tip mass weighs this fraction more
than its nominal value (0 = off).

Twin and prediction: the mass hung at the tip (:meth:`twin.sim.plant.Plant.set_tip_mass_kg`),
and the tip force a prediction applies (:func:`twin.effects.tip_force_n`), are the nominal mass
times (1 + e).

Discrepancy: the relative error e, between −0.5 and 1 (half or twice the mass); only datasets
with rows that hang a tip mass can show it.
"""

from __future__ import annotations

import numpy as np

from twin.effects.base import Candidate, Effect, FitParameter, Key, Params

__all__ = ["EFFECT"]


class TipLoadEffect(Effect):
    name = "tip_load"
    description = "the hung tip load weighs a fraction more than its nominal mass"
    deciding_experiments = ("tip-load",)
    parameters = (Key("tip_load_error_fraction"),)

    def true_tip_mass_kg(self, params: Params, mass_kg: float) -> float:
        return mass_kg * (1.0 + params.effects.tip_load_error_fraction)

    def candidate(self, params: Params) -> Candidate:
        return Candidate(self.name, (FitParameter("effects.tip_load_error_fraction", scale=0.1, bounds=(-0.5, 1.0)),),
                         applies=lambda dataset: bool(np.any(dataset["tip_mass_kg"] > 0)))


EFFECT = TipLoadEffect()
