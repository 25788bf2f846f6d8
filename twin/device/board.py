"""The emulated board: the real firmware core (C++, host build) wired to the MuJoCo plant.

This is the rig without the rig: :class:`twin.device.firmware_lib.FirmwareLib` runs the same
PID, safety state machine and codec as the Teensy, ticked every 5 ms of simulated time like the
Teensy's IntervalTimer; its PWM drives :meth:`twin.sim.plant.Plant.set_motor_pwm`, and it reads
the plant's encoders and, on each new 80 Hz sample, its HX711 counts. Bytes go in with
:meth:`EmulatedBoard.receive` and come out of :meth:`EmulatedBoard.take_tx`, exactly as on the
wire. The board does not keep time itself: :mod:`twin.device.sim_transport` steps it as fast as
possible, :mod:`twin.device.pty_board` in step with the wall clock.
"""

from __future__ import annotations

import numpy as np

from twin.device import codec
from twin.device.firmware_lib import FirmwareLib
from twin.params import Params
from twin.pose import HORIZONTAL
from twin.sim.plant import Plant

__all__ = ["TICK_S", "EmulatedBoard"]

# The Teensy layer ticks the core at 200 Hz: the GCD of 100 Hz control and 40 Hz telemetry.
TICK_S = 0.005
# The firmware's drive modes (uint8 per motor) when all four motors coast.
_ALL_COAST = bytes([codec.Drive.COAST] * codec.CHANNELS)


class EmulatedBoard:
    """Firmware core + plant, stepped by the caller in two halves per 5 ms period.

    :meth:`tick` runs the firmware at the current plant time and applies its motor outputs;
    :meth:`advance` then moves the plant on by :data:`TICK_S`. Whoever steps the board takes the
    outgoing bytes in between, so a telemetry sample reaches the host at its own device time.

    Args:
        params: parameter set of the plant (default ``models/endoscope.toml``).
        seed: seed of the plant's sensor noise.
        base_rotation: clamp orientation, 3×3 (default horizontal, the thesis set-up).
        native: let the plant step in native code (:class:`twin.sim.plant.Plant`'s ``native``).

    Attributes:
        plant: the :class:`twin.sim.plant.Plant`; fixtures act on it directly.
        firmware: the :class:`FirmwareLib` of the current power-up.
    """

    def __init__(self, params: Params | None = None, *, seed: int = 0, base_rotation=HORIZONTAL, native: bool = True):
        self.plant = Plant(params, base_rotation=base_rotation, seed=seed, native=native)
        self.firmware = FirmwareLib()
        self._power_up_s = self.plant.time_s
        self._last_loadcell_index = -1
        self._held_tensions_n: np.ndarray | None = None
        # The motor outputs last given to the plant (see _apply); None forces the next.
        self._applied: tuple[bytes, bytes] | None = None

    @property
    def time_s(self) -> float:
        """Board time (s since power-up): what telemetry reports as ``time_us``."""
        return self.plant.time_s - self._power_up_s

    def receive(self, data: bytes) -> None:
        """Host → board bytes; commands are acted on (and answered) at once."""
        self.firmware.receive(data)

    def take_tx(self) -> bytes:
        """Board → host bytes queued since the last call."""
        return self.firmware.take_tx()

    def tick(self) -> None:
        """One firmware step at the current time, with the plant's sensors; applies its outputs."""
        sample = self.plant.loadcell_sample()
        new_mask = 0b1111 if sample.index != self._last_loadcell_index else 0
        self._last_loadcell_index = sample.index
        duty = self.firmware.tick(
            round(self.time_s * 1e6), self.plant.encoder_counts(), sample.raw_counts, new_mask
        )
        self._apply(duty, self.firmware.drive_modes)

    def advance(self) -> None:
        """Move the plant on by one tick period (:data:`TICK_S`)."""
        self.plant.step(TICK_S)

    def power_cycle(self) -> None:
        """A fresh firmware (power-up state: disabled, no handshake, counters at 0) on the same
        plant, as after unplugging a USB-powered Teensy and plugging it back."""
        self.firmware.close()
        self.firmware = FirmwareLib()
        self._power_up_s = self.plant.time_s
        self._last_loadcell_index = -1
        self._applied = None

    def hold_tensions(self, tensions_n) -> None:
        """Pull the tendons with ideal tension sources (N) instead of the motors, until
        :meth:`release_tensions`: masses hung on the tendons over the load-cell pulleys.

        The plant has no separate model of a mass hanging over a pulley, so the tension is put
        on the tendon at the spool; the load cell then reads it as it would the mass. The
        firmware keeps running and reporting, but its motor outputs are ignored meanwhile.
        """
        tensions = np.asarray(tensions_n, dtype=float)
        self.plant.set_tensions(tensions)
        self._held_tensions_n = tensions

    def release_tensions(self) -> None:
        """Give the spools back to the firmware's motor outputs (applied at the next tick)."""
        self._held_tensions_n = None

    @property
    def held_tensions_n(self) -> np.ndarray | None:
        """The tensions of :meth:`hold_tensions` (N), or None while the motors drive."""
        return None if self._held_tensions_n is None else self._held_tensions_n.copy()

    def close(self) -> None:
        self.firmware.close()

    def _apply(self, duty: np.ndarray, drives: np.ndarray) -> None:
        if self._held_tensions_n is not None:
            self._applied = None
            return
        # The control loop runs at 100 Hz and the board ticks at 200 Hz: every other tick
        # repeats the outputs, and the plant already has them (the plant's drive is changed only
        # here, by hold_tensions, and by a reset that comes with power_cycle).
        outputs = (duty.tobytes(), drives.tobytes())
        if outputs == self._applied:
            return
        self._applied = outputs
        if outputs[1] == _ALL_COAST:
            self.plant.coast()
        else:
            # Duty 0 in the plant shorts the motor (brake). The plant coasts all motors or none;
            # the firmware's safety states also act on all four, so a mix does not occur.
            self.plant.set_motor_pwm(np.where(drives == codec.Drive.DRIVE, duty, 0.0))
