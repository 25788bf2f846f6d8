"""Base tilt: ``effects.base_tilt_deg``, the clamp tilted about world x, then world y (deg;
0 = off), on top of the nominal base orientation.

Twin and prediction: the clamp's orientation (:func:`twin.effects.clamp_rotation`) is
R_y(t_y) R_x(t_x) R_base; the world, gravity and the tracker stay put.

Discrepancy: the tilt about world x and y (deg), each within ±10° (more is a misplaced clamp,
visible by eye).
"""

from __future__ import annotations

import numpy as np

from twin.effects.base import Candidate, Effect, FitParameter, Key, Params
from twin.pose import rot_x, rot_y

__all__ = ["EFFECT"]


class BaseTiltEffect(Effect):
    name = "base_tilt"
    description = "the clamp is tilted about world x, then y"
    deciding_experiments = ("planes",)
    parameters = (Key("base_tilt_deg", size=2),)

    def clamp_rotation(self, params: Params, rotation: np.ndarray) -> np.ndarray:
        tilt_x, tilt_y = np.radians(params.effects.base_tilt_deg)
        return rot_y(tilt_y) @ rot_x(tilt_x) @ rotation

    def candidate(self, params: Params) -> Candidate:
        return Candidate(self.name, tuple(FitParameter("effects.base_tilt_deg", i, scale=1.0, bounds=(-10.0, 10.0))
                                          for i in range(2)))


EFFECT = BaseTiltEffect()
