"""The emulated board's ticks in native code, where nothing in them needs Python.

:class:`twin.device.sim_transport.SimTransport` steps the board one 5 ms tick at a time: the
firmware's tick, its motor outputs into the plant, the plant's physics step. In Python that glue
costs three times the physics (``twin bench env``). :class:`BoardLoop` runs the same ticks in
native code (``bl_run`` in ``twin/sim/native/loop.cpp``, with the plant's steps as
:mod:`twin.sim.native_loop` takes them) and hands back to Python at the exact point of a tick
where Python has work: bytes for the host, a drive the plant must switch mode for, a MuJoCo
warning, the keepalive, the deadline, the sensor noise buffer to refill. The numbers are the
Python path's to the bit (``tests/test_board_loop.py``).

It needs g++ (as the firmware library does) and MuJoCo's headers, which the wheel ships. When
either is missing, or the plant runs something only Python does (tendon friction, a time step
other than the 5 ms tick), the transport keeps to the Python path: slower, same results.
"""

from __future__ import annotations

import ctypes
import functools
import math

import numpy as np

from twin.device import codec
from twin.device.firmware_lib import load_library as load_firmware_library
from twin.sim import native_loop
from twin.sim.native_loop import PlantLoop, Reason
from twin.sim.plant import _ACTUATOR_BLOCK

__all__ = ["BoardLoop", "Reason", "available"]

_CHANNELS = codec.CHANNELS


@functools.lru_cache(maxsize=1)
def _firmware_pointers() -> tuple[int, int] | None:
    """The firmware's tick and tx_pending, as function pointers for ``bl_run``; None when the
    native loop is not available."""
    if native_loop.load() is None:
        return None
    firmware = load_firmware_library()
    return tuple(ctypes.cast(f, ctypes.c_void_p).value for f in (firmware.twinfw_tick, firmware.twinfw_tx_pending))


def available() -> bool:
    """True when the native loop could be built and loaded."""
    return _CHANNELS == native_loop.CHANNELS and _firmware_pointers() is not None


class BoardLoop:
    """Runs ticks of one :class:`twin.device.board.EmulatedBoard` natively.

    Args:
        board: the board; its plant and firmware are read from it on every call, so a power
            cycle or a plant reset needs nothing here.

    Attributes:
        native_ticks: ticks run natively so far.
        returns: how often each :class:`Reason` handed back to Python.
    """

    def __init__(self, board):
        if not available():
            raise RuntimeError("the native tick loop is not available")
        self._tick, self._pending = _firmware_pointers()
        self.board = board
        plant = board.plant
        # One state per plant: the plant's own loop where it has one (a plant with friction has none).
        self._plant_loop = plant._native or PlantLoop(plant)
        self._lib, self._step = self._plant_loop.lib, self._plant_loop.mj_step
        s = self._state = self._plant_loop.state
        motor = plant._motor
        s.m_per_count = plant.params.rig.tendon_m_per_count
        s.supply_voltage_v = motor.supply_voltage_v
        s.stall_force_n = motor.stall_force_n
        s.reflected_mass_kg = motor.reflected_mass_kg
        s.spool_qpos[:] = [int(q) for q in plant._spool_q]
        s.pwm_ctrl[:] = [_ACTUATOR_BLOCK["pwm"] * plant.tendon_count + i for i in range(_CHANNELS)]
        self._state_ref = self._plant_loop.state_ref
        self.native_ticks = 0
        # The objects last copied into the state: (PWM voltages, applied outputs); Python
        # replaces rather than mutates them.
        self._synced = (None, None)
        self.returns: dict[int, int] = {}

    def usable(self, tick_s: float) -> bool:
        """Can the loop run the plant's steps? Not with friction (Python updates it between
        steps) or a time step other than the tick."""
        plant = self.board.plant
        return plant._friction is None and plant._substeps == 1 and plant.timestep_s == tick_s

    def run(self, deadline_s: float, last_write_s: float, keepalive_s: float | None, *, resume: bool = False,
            max_ticks: int = 1 << 20) -> int:
        """Tick until a :class:`Reason` to return; the board and plant are left where the
        Python path would be at that point. ``resume``: start at the advance of the current
        tick (after :data:`Reason.TX` and the delivery) and return :data:`Reason.DONE` when the
        tick is complete."""
        board, plant, s = self.board, self.board.plant, self._state
        synced_pwm, synced_applied = self._synced
        s.resume = resume
        s.power_up_s = board._power_up_s
        s.deadline_s = deadline_s
        s.last_write_s = last_write_s
        s.keepalive_s = math.inf if keepalive_s is None else keepalive_s
        s.last_loadcell_index = board._last_loadcell_index
        s.plant_pwm = plant._mode == "pwm"
        s.held = board._held_tensions_n is not None
        self._plant_loop.sync_in()
        # What Python may have replaced since the last call, copied only when it did.
        if plant._pwm_v is not synced_pwm:
            s.pwm_v[:] = plant._pwm_v.tolist()
        applied = board._applied
        if applied is not synced_applied:
            s.have_applied = applied is not None
            if applied is not None:
                # The board keeps the duties as float64 bytes (they were float32 to begin with).
                s.applied_duty[:] = np.frombuffer(applied[0], dtype=np.float64).tolist()
                s.applied_drive[:] = list(applied[1])
        reason = self._lib.bl_run(plant.model._address, plant.data._address, board.firmware._fw, self._tick,
                                  self._pending, self._step, self._state_ref, max_ticks)
        self._plant_loop.sync_out()
        self.native_ticks += s.ticks
        self.returns[reason] = self.returns.get(reason, 0) + 1
        board._last_loadcell_index = s.last_loadcell_index
        if s.applied_changed:
            board._applied = ((np.array(s.applied_duty[:], dtype=np.float32).astype(np.float64).tobytes(),
                               bytes(s.applied_drive)) if s.have_applied else None)
            plant._pwm_v = np.array(s.pwm_v[:])
        if s.ticks:
            board.firmware._duty[:] = s.duty[:]
            board.firmware._drive[:] = s.drive[:]
        self._synced = (plant._pwm_v, board._applied)
        return reason

    def outputs(self) -> tuple[np.ndarray, np.ndarray]:
        """The last tick's duty (float64) and drive modes (uint8), as ``FirmwareLib.tick`` and
        ``drive_modes`` give them."""
        return (np.array(self._state.duty[:], dtype=np.float32).astype(np.float64),
                np.array(self._state.drive[:], dtype=np.uint8))
