"""Load-cell gain error: ``effects.tension_gain_error``, one relative error g_i per load cell
(0 = off).

Twin and prediction: load cell i reports (1 + g_i) times the true tension (with the offset of
:mod:`twin.effects.tension_offset`: (1 + g_i) T_i + o_i); a prediction from measured tensions
divides it out (:func:`twin.effects.true_tensions_n`). The errors are a load cell that reads
differently from what its calibration says, e.g. one loaded off its axis.

Discrepancy: g_1 … g_n, one relative gain error per load cell, within ±0.5 (a cell reading half
or one and a half times the force is broken, not miscalibrated).
"""

from __future__ import annotations

import numpy as np

from twin.effects.base import PER_TENDON, Candidate, Effect, FitParameter, Key, Params

__all__ = ["EFFECT"]


class TensionGainEffect(Effect):
    name = "tension_gain"
    description = "each load cell reads (1 + g_i) times the true tension"
    deciding_experiments = ("pretension",)
    parameters = (Key("tension_gain_error", size=PER_TENDON),)

    def loadcell_response(self, params: Params, gain: np.ndarray,
                          offset_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return gain * (1.0 + np.asarray(params.effects.tension_gain_error, dtype=float)), offset_n

    def candidate(self, params: Params) -> Candidate:
        return Candidate(self.name, tuple(FitParameter("effects.tension_gain_error", i, scale=0.05, bounds=(-0.5, 0.5))
                                          for i in range(params.tendons.count)))


EFFECT = TensionGainEffect()
