"""Actuation latency: ``effects.actuation_latency_s``, the delay (s) from the firmware's motor
outputs to the motors (0 = off).

Twin: the plant loop holds each board tick's duties and drives and applies the ones of
``latency`` earlier (:class:`twin.effects.PlantDynamics`); between whole ticks the duty is
interpolated linearly, so the delay is a continuous parameter. Its sources on a rig: the
H-bridge driver's input filter, the motor's electrical time constant, a gearbox's wind-up.

Statics: none (a settled loop has the same outputs at every tick), so the static workflow has
no candidate for it.

Dynamic calibration: the delay, fitted on log scale between 1 ms and 0.15 s (the loop keeps at
most 40 ticks of 5 ms).
"""

from __future__ import annotations

from twin.effects.base import DynamicEffect, Key, Params, PlantDynamics

__all__ = ["EFFECT", "MAX_LATENCY_S"]

# The longest delay the plant loop can hold (s): BL_DELAY_TICKS board ticks of 5 ms less one.
MAX_LATENCY_S = 0.195


class ActuationLatencyEffect(DynamicEffect):
    name = "actuation_latency"
    description = "the motors act on the firmware's outputs a fixed delay late"
    parameters = (Key("actuation_latency_s", nonnegative=True),)
    field = "actuation_latency_s"
    fit_scale = 0.01
    fit_bounds = (0.001, 0.15)

    def plant_dynamics(self, params: Params, dynamics: PlantDynamics) -> PlantDynamics:
        latency_s = params.effects.actuation_latency_s
        if latency_s > MAX_LATENCY_S:
            raise ValueError(f"effects.actuation_latency_s = {latency_s!r}: the twin's plant loop delays the motors "
                             f"by at most {MAX_LATENCY_S} s")
        return super().plant_dynamics(params, dynamics)


EFFECT = ActuationLatencyEffect()
