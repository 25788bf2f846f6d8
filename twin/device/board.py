"""The emulated board: the real firmware core (C++, host build) wired to the MuJoCo plant.

This is the rig without the rig: :class:`twin.device.firmware_lib.FirmwareLib` runs the same
PID, safety state machine and codec as the Teensy, ticked every 5 ms of simulated time like the
Teensy's IntervalTimer; its PWM drives the plant's motors, and it reads the plant's encoders and,
on each new load-cell sample, its HX711 counts. The ticks run in the plant loop
(``bl_board_run`` in ``twin/sim/native/loop.cpp``, through :attr:`twin.sim.plant.Plant.loop`).
Bytes go in with :meth:`EmulatedBoard.receive` and come out of :meth:`EmulatedBoard.take_tx`,
exactly as on the wire. The board does not keep time itself: :mod:`twin.device.sim_transport`
steps it as fast as possible, :mod:`twin.device.pty_board` in step with the wall clock.
"""

from __future__ import annotations

import math

import numpy as np

from twin.driver import codec
from twin.device.firmware_lib import FirmwareLib, tick_entry_points
from twin.params import Params
from twin.sim.native_loop import Reason
from twin.sim.plant import Plant

__all__ = ["TICK_S", "EmulatedBoard", "Reason"]

# The Teensy layer ticks the core at 200 Hz: the GCD of 100 Hz control and 40 Hz telemetry.
TICK_S = 0.005


class EmulatedBoard:
    """Firmware core + plant, ticked by the caller.

    Args:
        params: parameter set of the plant (default ``models/endoscope/endoscope.toml``).
        seed: seed of the plant's sensor noise.
        base_rotation: clamp orientation, 3×3 (default the parameter set's ``rig.base_quat``).

    The firmware drives as many motors as the plant has tendons (``tendons.count``, up to
    :data:`twin.driver.codec.MAX_CHANNELS`), and says so in its HELLO_REPLY.

    Raises:
        ValueError: the robot has more tendons than the firmware drives.

    Attributes:
        plant: the :class:`twin.sim.plant.Plant`; fixtures act on it directly.
        firmware: the :class:`FirmwareLib` of the current power-up.
    """

    def __init__(self, params: Params | None = None, *, seed: int = 0, base_rotation=None):
        self.plant = Plant(params, base_rotation=base_rotation, seed=seed)
        if not 1 <= self.plant.tendon_count <= codec.MAX_CHANNELS:
            raise ValueError(f"tendons.count = {self.plant.tendon_count}: the firmware drives 1..{codec.MAX_CHANNELS} motors")
        self._loop = self.plant.loop
        s = self._loop.state
        s.tick_fn, s.pending_fn = tick_entry_points()
        s.tick_steps = max(1, round(TICK_S / self.plant.timestep_s))
        self._held_tensions_n: np.ndarray | None = None
        self.firmware: FirmwareLib
        self._power_up()

    @property
    def time_s(self) -> float:
        """Board time (s since power-up): what telemetry reports as ``time_us``."""
        return self.plant.time_s - self._loop.state.power_up_s

    def receive(self, data: bytes) -> None:
        """Host → board bytes; commands are acted on (and answered) at once."""
        self.firmware.receive(data)

    def take_tx(self) -> bytes:
        """Board → host bytes queued since the last call."""
        return self.firmware.take_tx()

    def run(self, *, deadline_s: float = math.inf, last_write_s: float = -math.inf,
            keepalive_s: float | None = None, max_ticks: int = 1 << 20, resume: bool = False) -> Reason:
        """Tick until there is work for the host, at most ``max_ticks`` ticks.

        Each tick runs the firmware at the current board time, gives its outputs to the motors
        and advances the plant by :data:`TICK_S`.

        Args:
            deadline_s: board time (s) before which the host's wait ends: no tick starts at or after it.
            last_write_s: board time (s) of the host's last write, for the keepalive.
            keepalive_s: the host's keepalive period (s), or None.
            max_ticks: ticks at most.
            resume: finish the tick whose bytes were just taken (after :data:`Reason.TX`).

        Returns:
            :data:`Reason.DONE` (ticks taken; with ``resume``, the tick finished),
            :data:`Reason.DEADLINE`, :data:`Reason.KEEPALIVE` (a PING is due before the next
            tick) or :data:`Reason.TX` (bytes to take before the tick's advance).

        Raises:
            twin.sim.plant.SimulationError: the simulation diverged.
        """
        s = self._loop.state
        s.deadline_s = deadline_s
        s.last_write_s = last_write_s
        s.keepalive_s = math.inf if keepalive_s is None else keepalive_s
        s.resume = resume
        reason = self._loop.board_run(max_ticks)
        if reason == Reason.WARNING:
            self.plant.raise_warnings()
        return reason

    def run_tick(self) -> bytes:
        """One whole tick; returns the bytes it sent the host."""
        sent = b""
        if self.run(max_ticks=1) == Reason.TX:
            sent = self.take_tx()
            self.run(resume=True)
        return sent

    def power_cycle(self) -> None:
        """A fresh firmware (power-up state: disabled, no handshake, counters at 0) on the same
        plant, as after unplugging a USB-powered Teensy and plugging it back."""
        self.firmware.close()
        self._power_up()

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
        self._loop.state.held = 1

    def release_tensions(self) -> None:
        """Give the spools back to the firmware's motor outputs (applied at the next tick)."""
        self._held_tensions_n = None
        self._loop.state.held = 0

    @property
    def held_tensions_n(self) -> np.ndarray | None:
        """The tensions of :meth:`hold_tensions` (N), or None while the motors drive."""
        return None if self._held_tensions_n is None else self._held_tensions_n.copy()

    def close(self) -> None:
        self.firmware.close()

    @property
    def channels(self) -> int:
        """Motors and load cells of the board: the plant's tendon count."""
        return self.plant.tendon_count

    def _power_up(self) -> None:
        # The plant's encoders count its rig's spool, gearbox and encoder: so does its board.
        self.firmware = FirmwareLib(self.plant.tendon_count, self.plant.params.rig.tendon_m_per_count)
        s = self._loop.state
        s.firmware = self.firmware.handle
        s.power_up_s = self.plant.time_s
        s.last_loadcell_index = -1
        s.have_applied = 0
