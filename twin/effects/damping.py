"""Backbone damping: ``effects.damping_scale``, a factor on the backbone joints' damping
(``sim.damping_time_s`` × stiffness; 1 = off).

Twin: each backbone joint's MuJoCo ``damping`` times the factor (:class:`twin.effects.PlantDynamics`).
The twin's damping time is an assumption (the first bending mode critically damped); the rig's
silicone core and the tendons rubbing in the disc holes may damp more or less.

Statics: none (damping acts only while the backbone moves), so the static workflow has no
candidate for it.

Dynamic calibration: the factor, fitted on log scale between 0.1 and 10.
"""

from __future__ import annotations

import dataclasses

from twin.effects.base import DYNAMIC_ONLY, Effect, FitParameter, Key, Params, PlantDynamics

__all__ = ["EFFECT"]


class DampingEffect(Effect):
    name = "damping"
    description = "the backbone damps its motion more (or less) than sim.damping_time_s says"
    parameters = (Key("damping_scale", off=1.0, nonnegative=True),)
    untestable = DYNAMIC_ONLY

    def plant_dynamics(self, params: Params, dynamics: PlantDynamics) -> PlantDynamics:
        return dataclasses.replace(dynamics, damping_scale=params.effects.damping_scale)

    def dynamic_candidate(self, params: Params) -> FitParameter:
        return FitParameter("effects.damping_scale", log=True, scale=0.5, bounds=(0.1, 10.0))


EFFECT = DampingEffect()
