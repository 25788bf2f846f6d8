"""Tracker offset: ``effects.tracker_offset_m``, the probe cap's origin relative to the tip, in
the tip frame (m; 0 = off): a cap mounted off the tip.

Twin: the probes sit at their places in the cap plus this offset (:class:`twin.sim.sensors.Tracker`).
Prediction: the tracked point is tip + R_tip · offset (:func:`twin.effects.tracked_point_m`).

Discrepancy: the offset's three components (m), each within ±10 mm (the cap's size).
"""

from __future__ import annotations

import numpy as np

from twin.effects.base import Candidate, Effect, FitParameter, Key, Params

__all__ = ["EFFECT"]


class TrackerOffsetEffect(Effect):
    name = "tracker_offset"
    description = "the tracker's origin is offset from the tip, in the tip frame"
    deciding_experiments = ("planes",)
    parameters = (Key("tracker_offset_m", size=3),)

    def tracker_offset_m(self, params: Params, offset_m: np.ndarray) -> np.ndarray:
        return offset_m + np.asarray(params.effects.tracker_offset_m, dtype=float)

    def candidate(self, params: Params) -> Candidate:
        return Candidate(self.name, tuple(FitParameter("effects.tracker_offset_m", i, scale=1e-3, bounds=(-0.01, 0.01))
                                          for i in range(3)))


EFFECT = TrackerOffsetEffect()
