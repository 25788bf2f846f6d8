"""Motor Coulomb friction: ``effects.motor_friction_n``, the dry friction of each motor and its
gearbox (N, as a force on the tendon at the spool; 0 = off).

Twin: the spool joints' MuJoCo ``frictionloss`` (:class:`twin.effects.PlantDynamics`): a drive
must exceed it before a spool moves, so small PID outputs are lost (a dead band) and a loop
that reverses sticks first. Its sources on a rig: brushes, gearbox and bearing friction.

Statics: the settled loops integrate through it (a length or tension loop with an integral
term ends at its setpoint), so the static workflow has no candidate for it.

Dynamic calibration: the friction force, fitted on log scale between 0.01 N and 3 N.
"""

from __future__ import annotations

from twin.effects.base import DynamicEffect, Key

__all__ = ["EFFECT"]


class MotorFrictionEffect(DynamicEffect):
    name = "motor_friction"
    description = "Coulomb friction in each motor and gearbox: a dead band of the drive"
    parameters = (Key("motor_friction_n", nonnegative=True),)
    field = "motor_friction_n"
    fit_scale = 0.1
    fit_bounds = (0.01, 3.0)


EFFECT = MotorFrictionEffect()
