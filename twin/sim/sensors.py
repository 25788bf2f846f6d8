"""The rig's sensors as the twin produces them: load cells through HX711s, and the EM tracker.

Both are sampled at their own rates by :class:`twin.sim.plant.Plant` and held between samples;
each sample carries a running index and its simulation time so consumers can tell a new
sample from a held one. Encoders need no sampling: the quadrature counter is read whenever
asked (:func:`twin.sim.motor.encoder_counts`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from twin.params import Params
from twin.tracking import CapCalibration

__all__ = ["HX711_RANGE_COUNTS", "LoadCellSample", "LoadCells", "NoiseStream", "Tracker", "TrackerSample"]

# The HX711 outputs 24-bit two's complement: readings saturate at these codes.
HX711_RANGE_COUNTS = (-(2**23), 2**23 - 1)


@dataclasses.dataclass(frozen=True, eq=False)
class LoadCellSample:
    """One 80 Hz reading of all load cells.

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
    """One 40 Hz frame of the two 5-DOF probes, in the world (tracker) frame.

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

    :class:`LoadCells` and :class:`Tracker` take their noise from here rather than from the
    generator directly, so that the native loop (:mod:`twin.sim.native_loop`) can sample
    the sensors too: it reads :attr:`buffer` from :attr:`cursor` on and moves the cursor on, and
    both take the same draws in the same order. A generator's normals do not depend on how
    many are drawn at once, so the buffer does not change them.

    Args:
        rng: the generator the draws come from.
        size: draws held at a time.
    """

    def __init__(self, rng: np.random.Generator, size: int = 4096):
        self._rng = rng
        self.buffer = rng.standard_normal(size)
        self.cursor = 0

    def take(self, n: int) -> list[float]:
        """The next ``n`` standard normal draws."""
        if self.cursor + n > self.buffer.size:
            self.refill()
        start = self.cursor
        self.cursor += n
        return self.buffer[start:self.cursor].tolist()

    def refill(self) -> None:
        """Move the draws not taken yet to the front (in place: the native loop holds the
        buffer's address) and draw new ones behind them."""
        left = self.buffer.size - self.cursor
        self.buffer[:left] = self.buffer[self.cursor:]
        self._rng.standard_normal(out=self.buffer[left:])
        self.cursor = 0


class LoadCells:
    """Tension → raw HX711 counts: ``offset + gain · ((1 + e_g) T + e_o + noise)``.

    ``sensors.loadcell_gain_counts_per_n`` and ``sensors.loadcell_offset_counts`` are what a
    host calibration (:mod:`twin.calibration`) recovers; ``effects.tension_gain_error`` and
    ``effects.tension_offset_error_n`` are a load cell that reads differently from what its
    calibration would say — a drifted zero or a cell loaded off its axis; the noise is Gaussian,
    ``sensors.loadcell_noise_n`` RMS, drawn from the plant's seeded :class:`NoiseStream`.
    ``native/loop.cpp`` does the same sums in the same order.
    """

    def __init__(self, params: Params, noise: NoiseStream):
        s, e = params.sensors, params.effects
        self.gain_counts_per_n = float(s.loadcell_gain_counts_per_n)
        self.offset_counts = [float(x) for x in s.loadcell_offset_counts]
        self.gain_error = [float(x) for x in e.tension_gain_error]
        self.offset_error_n = [float(x) for x in e.tension_offset_error_n]
        self.noise_n = float(s.loadcell_noise_n)
        self._noise = noise

    def read(self, tensions_n) -> np.ndarray:
        """Raw counts (int64, clipped to the 24-bit range) for true tensions (N)."""
        # Plain floats (round() rounds half to even, as np.rint): on four channels they are
        # several times faster than numpy's calls.
        t = np.asarray(tensions_n, dtype=float).tolist()
        z = self._noise.take(len(t)) if self.noise_n > 0 else None
        low, high = HX711_RANGE_COUNTS
        gain, counts = self.gain_counts_per_n, []
        for i, (o, e_g, e_o) in enumerate(zip(self.offset_counts, self.gain_error, self.offset_error_n)):
            sensed = (1.0 + e_g) * t[i] + e_o
            if z is not None:
                sensed = sensed + self.noise_n * z[i]
            counts.append(min(max(round(o + gain * sensed), low), high))
        return np.array(counts, dtype=np.int64)


class Tracker:
    """Tip pose → the two probe readings, with ``effects.tracker_offset_m`` and noise.

    The probes sit in a cap whose origin is the tip plus ``effects.tracker_offset_m`` (in the
    tip frame: a cap mounted off the tip); their layout in the cap is
    :class:`twin.tracking.CapCalibration`'s, so the fusion there inverts this exactly when
    the offset is zero. Position noise is ``sensors.tracker_noise_m`` RMS per axis; each axis is
    turned by a small random rotation of ``sensors.tracker_noise_rad`` RMS per component.
    """

    def __init__(self, params: Params, noise: NoiseStream, cap: CapCalibration | None = None):
        cap = cap or CapCalibration()
        offset = np.asarray(params.effects.tracker_offset_m, dtype=float)
        # Probe positions (m) and unit axes in the tip frame, as plain floats for read().
        self.positions_m = (np.array([cap.position_a_m, cap.position_b_m]) + offset).tolist()
        self.axes = [[float(x) for x in cap.axis_a], [float(x) for x in cap.axis_b]]
        self.noise_m = float(params.sensors.tracker_noise_m)
        self.noise_rad = float(params.sensors.tracker_noise_rad)
        self._noise = noise

    def read(self, tip_position_m, tip_rotation) -> tuple[np.ndarray, np.ndarray]:
        """(positions (2, 3) m, unit axes (2, 3)) in the world frame for a tip pose."""
        # Plain floats: on two 3-vectors they are several times faster than numpy's calls.
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = np.asarray(tip_rotation, dtype=float).tolist()
        px, py, pz = np.asarray(tip_position_m, dtype=float).tolist()
        # The same sums in the same order as native/loop.cpp.
        noise_m = [self.noise_m * z for z in self._noise.take(6)] if self.noise_m > 0 else [0.0] * 6
        noise_rad = [self.noise_rad * z for z in self._noise.take(6)] if self.noise_rad > 0 else None
        positions, axes = [], []
        for k, ((x, y, z), (u, v, w)) in enumerate(zip(self.positions_m, self.axes)):
            positions.append([px + r00 * x + r01 * y + r02 * z + noise_m[3 * k],
                              py + r10 * x + r11 * y + r12 * z + noise_m[3 * k + 1],
                              pz + r20 * x + r21 * y + r22 * z + noise_m[3 * k + 2]])
            a0, a1, a2 = r00 * u + r01 * v + r02 * w, r10 * u + r11 * v + r12 * w, r20 * u + r21 * v + r22 * w
            if noise_rad is not None:
                # Small-angle rotation of the axis: a + w × a, then renormalised.
                w0, w1, w2 = noise_rad[3 * k:3 * k + 3]
                a0, a1, a2 = a0 + w1 * a2 - w2 * a1, a1 + w2 * a0 - w0 * a2, a2 + w0 * a1 - w1 * a0
                norm = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
                a0, a1, a2 = a0 / norm, a1 / norm, a2 / norm
            axes.append([a0, a1, a2])
        return np.array(positions), np.array(axes)
