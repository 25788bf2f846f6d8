"""Load-cell lag: ``effects.loadcell_lag_s``, the time constant (s) of a first-order low-pass
between each tendon's tension and its load cell (0 = off).

Twin: the plant loop filters each tendon's spring tension every physics step and the HX711
samples the filtered value (:class:`twin.effects.PlantDynamics`). Its sources on a rig: the
HX711's digital filter and settling, a compliant load-cell mount with viscous damping.

Statics: none (the filter passes a constant tension as it is), so the static workflow has no
candidate for it.

Dynamic calibration: the time constant, fitted on log scale between 1 ms and 0.5 s.
"""

from __future__ import annotations

from twin.effects.base import DynamicEffect, Key

__all__ = ["EFFECT"]


class LoadcellLagEffect(DynamicEffect):
    name = "loadcell_lag"
    description = "each load cell reads its tendon's tension through a first-order low-pass"
    parameters = (Key("loadcell_lag_s", nonnegative=True),)
    field = "loadcell_lag_s"
    fit_scale = 0.02
    fit_bounds = (0.001, 0.5)


EFFECT = LoadcellLagEffect()
