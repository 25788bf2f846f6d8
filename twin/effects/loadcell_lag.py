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

import dataclasses

from twin.effects.base import DYNAMIC_ONLY, Effect, FitParameter, Key, Params, PlantDynamics

__all__ = ["EFFECT"]


class LoadcellLagEffect(Effect):
    name = "loadcell_lag"
    description = "each load cell reads its tendon's tension through a first-order low-pass"
    parameters = (Key("loadcell_lag_s", nonnegative=True),)
    untestable = DYNAMIC_ONLY

    def plant_dynamics(self, params: Params, dynamics: PlantDynamics) -> PlantDynamics:
        return dataclasses.replace(dynamics, loadcell_lag_s=params.effects.loadcell_lag_s)

    def dynamic_candidate(self, params: Params) -> FitParameter:
        return FitParameter("effects.loadcell_lag_s", log=True, scale=0.02, bounds=(1e-3, 0.5))


EFFECT = LoadcellLagEffect()
