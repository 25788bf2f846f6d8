"""The rig's sensors as the twin produces them: load cells through HX711s, and the EM tracker.

The plant loop (``native/loop.cpp``) samples both at their own rates and holds them between
samples; each sample carries a running index and its simulation time so consumers can tell a
new sample from a held one. The measurement models:

* load cells: HX711 codes ``offset + gain · (g · T + o + noise)``, rounded to nearest and
  saturated at 24 bits (:data:`HX711_RANGE_COUNTS`), where T is the tendon's tension at the spool,
  ``sensors.loadcell_gain_counts_per_n`` and ``sensors.loadcell_offset_counts`` are what a host
  calibration (:mod:`twin.calibration`) recovers, (g, o) per cell come from the effects
  (:func:`twin.effects.loadcell_response`) and the noise is Gaussian, ``sensors.loadcell_noise_n``
  RMS;
* tracker: two 5-DOF probes in a cap on the tip (:func:`probe_layout`), positions with
  ``sensors.tracker_noise_m`` RMS per axis, each axis turned by a small random rotation of
  ``sensors.tracker_noise_rad`` RMS per component.

Encoders need no sampling: the quadrature counter is read whenever asked.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from twin import effects
from twin.params import Params
from twin.tracking import CapCalibration

__all__ = ["HX711_RANGE_COUNTS", "LoadCellSample", "NoiseStream", "TrackerSample", "probe_layout"]

# The HX711 outputs 24-bit two's complement: readings saturate at these codes.
HX711_RANGE_COUNTS = (-(2**23), 2**23 - 1)


@dataclasses.dataclass(frozen=True, eq=False)
class LoadCellSample:
    """One reading of all load cells (``rig.loadcell_rate_hz``).

    Attributes:
        raw_counts: (n,) int64 HX711 codes, one per tendon.
        index: 0 for the first sample, +1 for each new one.
        time_s: simulation time the sample was taken (s).
    """

    raw_counts: np.ndarray
    index: int
    time_s: float


@dataclasses.dataclass(frozen=True, eq=False)
class TrackerSample:
    """One frame of the two 5-DOF probes (``rig.tracker_rate_hz``), in the world (tracker) frame.

    Attributes:
        positions_m: (2, 3) probe A then probe B positions (m).
        axes: (2, 3) unit probe axes.
        index: 0 for the first frame, +1 for each new one.
        time_s: simulation time of the frame (s).
    """

    positions_m: np.ndarray
    axes: np.ndarray
    index: int
    time_s: float


class NoiseStream:
    """The sensors' standard normal draws, in the order they are drawn, through a buffer.

    The plant loop reads :attr:`buffer` from its cursor on; when too few draws are left it asks
    for :meth:`refill`. A generator's normals do not depend on how many are drawn at once, so
    when the buffer is refilled does not change them.

    Args:
        rng: the generator the draws come from.
        size: draws held at a time.
    """

    def __init__(self, rng: np.random.Generator, size: int = 4096):
        self._rng = rng
        self.buffer = rng.standard_normal(size)

    def refill(self, cursor: int) -> int:
        """Move the draws from ``cursor`` on to the front (in place: the loop holds the buffer's
        address), draw new ones behind them, and return the new cursor (0)."""
        left = self.buffer.size - cursor
        self.buffer[:left] = self.buffer[cursor:]
        self._rng.standard_normal(out=self.buffer[left:])
        return 0


def probe_layout(params: Params, cap: CapCalibration | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The tracker probes in the tip frame: positions (2, 3) m and unit axes (2, 3).

    The probes sit in a cap whose origin is the tip plus the effects' tracker offset
    (:func:`twin.effects.tracker_offset_m`); their layout in the cap is
    :class:`twin.tracking.CapCalibration`'s, so the fusion there inverts the tracker exactly when
    the offset is zero.
    """
    cap = cap or CapCalibration()
    positions = np.array([cap.position_a_m, cap.position_b_m]) + effects.tracker_offset_m(params)
    return positions, np.array([cap.axis_a, cap.axis_b], dtype=float)
