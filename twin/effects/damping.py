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

from twin.effects.base import DynamicEffect, Key

__all__ = ["EFFECT"]


class DampingEffect(DynamicEffect):
    name = "damping"
    description = "the backbone damps its motion more (or less) than sim.damping_time_s says"
    parameters = (Key("damping_scale", off=1.0, nonnegative=True),)
    field = "damping_scale"
    fit_scale = 0.5
    fit_bounds = (0.1, 10.0)


EFFECT = DampingEffect()
