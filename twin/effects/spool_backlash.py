"""Spool backlash: ``effects.spool_backlash_m``, the play (m of tendon travel) between each spool
and its motor encoder (0 = off).

Twin: the encoder follows the spool through a play operator of that width, updated every
physics step (:class:`twin.effects.PlantDynamics`): after a reversal the spool travels the
play before the encoder counts again, so a length loop settles half the play short of its
setpoint on the side it came from. Its sources on a rig: gear backlash between the motor and
the spool, a tendon wound loosely on the drum.

Statics: only through the lengths a length loop settles at; tension-driven predictions do not
use lengths, so the static workflow has no candidate for it.

Dynamic calibration: the play, fitted on log scale between 10 µm and 2 mm.
"""

from __future__ import annotations

from twin.effects.base import DynamicEffect, Key

__all__ = ["EFFECT"]


class SpoolBacklashEffect(DynamicEffect):
    name = "spool_backlash"
    description = "the motor encoders follow the spools through a play: lost motion after each reversal"
    parameters = (Key("spool_backlash_m", nonnegative=True),)
    field = "spool_backlash_m"
    fit_scale = 0.0001
    fit_bounds = (1e-05, 0.002)


EFFECT = SpoolBacklashEffect()
