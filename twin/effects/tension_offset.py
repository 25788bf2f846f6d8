"""Load-cell offset error: ``effects.tension_offset_error_n``, one offset o_i (N) per load cell
(0 = off).

Twin and prediction: load cell i reports the true tension plus o_i newtons (a drifted zero);
a prediction from measured tensions subtracts it (:func:`twin.effects.true_tensions_n`).

Discrepancy: o_1, o_2 with o_3 = o_4 held. An offset common to an antagonist pair adds equal
tension on opposite sides of the backbone and bends nothing, so only o_i − o_(i+2) can be seen;
the fitted o_1, o_2 are those differences. In general one offset per antagonist pair (tendons
180° apart) and one per unpaired tendon is fitted, within ±1 N (most of the pretension).
"""

from __future__ import annotations

import numpy as np

from twin.effects.base import PER_TENDON, Candidate, Effect, FitParameter, Key, Params

__all__ = ["EFFECT"]


def _antagonist_representatives(angles_deg) -> list[int]:
    """Indices with one per antagonist pair (tendons 180° apart), and every unpaired tendon."""
    angles = np.mod(np.asarray(angles_deg, dtype=float), 360.0)
    chosen, paired = [], set()
    for i, a in enumerate(angles):
        if i in paired:
            continue
        chosen.append(i)
        for j in range(i + 1, len(angles)):
            if j not in paired and abs(np.mod(angles[j] - a, 360.0) - 180.0) < 1e-6:
                paired.add(j)
                break
    return chosen


class TensionOffsetEffect(Effect):
    name = "tension_offset"
    description = "each load cell reads the true tension plus o_i newtons"
    deciding_experiments = ("pretension",)
    parameters = (Key("tension_offset_error_n", size=PER_TENDON),)

    def loadcell_response(self, params: Params, gain: np.ndarray,
                          offset_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return gain, offset_n + np.asarray(params.effects.tension_offset_error_n, dtype=float)

    def candidate(self, params: Params) -> Candidate:
        return Candidate(self.name, tuple(FitParameter("effects.tension_offset_error_n", i, scale=0.05,
                                                       bounds=(-1.0, 1.0))
                                          for i in _antagonist_representatives(params.tendons.angles_deg)))


EFFECT = TensionOffsetEffect()
