"""The emulated board's ticks in native code, where nothing in them needs Python.

:class:`twin.device.sim_transport.SimTransport` steps the board one 5 ms tick at a time: the
firmware's tick, its motor outputs into the plant, the plant's physics step. In Python that glue
costs three times the physics (``twin bench env``). :class:`BoardLoop` runs the same ticks in
``native/board_loop.cpp`` (with the plant's short steps near slack and its sensor samples) and
hands back to Python at the exact point of a tick where Python has work: bytes for the host, a
drive the plant must switch mode for, a MuJoCo warning, the keepalive, the deadline, the sensor
noise buffer to refill. The numbers are the Python path's to the bit (``tests/test_board_loop.py``).

It needs g++ (as the firmware library does) and MuJoCo's headers, which the wheel ships. When
either is missing, or the plant runs something only Python does (tendon friction, a time step
other than the 5 ms tick), the transport keeps to the Python path: slower, same results.
"""

from __future__ import annotations

import ctypes
import fcntl
import functools
import importlib.util
import math
import subprocess
import warnings
from pathlib import Path

import numpy as np

from twin.device import codec
from twin.device.firmware_lib import load_library as load_firmware_library
from twin.sim.plant import _ACTUATOR_BLOCK
from twin.sim.sensors import LoadCellSample, TrackerSample

__all__ = ["BoardLoop", "Reason", "available", "build_library"]

SOURCE = Path(__file__).parent / "native" / "board_loop.cpp"
LIB_PATH = Path(__file__).parent / "native" / "build" / "libboardloop.so"
ABI_VERSION = 5
# Where the mujoco wheel lives (headers, libmujoco), found without importing it: MuJoCo picks its
# GL backend on first import, which twin.sim arranges for (headless EGL).
_MUJOCO_DIR = Path(importlib.util.find_spec("mujoco").submodule_search_locations[0])
_CHANNELS = codec.CHANNELS


class Reason:
    """Why :meth:`BoardLoop.run` returned (``enum bl_reason`` in board_loop.cpp)."""

    DEADLINE = 0
    KEEPALIVE = 1
    APPLY = 2
    TX = 3
    WARNING = 4
    NOISE = 5
    DONE = 6


_Channels = ctypes.c_double * _CHANNELS
_Probes = ctypes.c_double * 6


class _State(ctypes.Structure):
    _fields_ = [
        ("noise", ctypes.c_void_p),
        ("m_per_count", ctypes.c_double),
        ("engage_stretch_m", ctypes.c_double),
        ("engage_speed_m_s", ctypes.c_double),
        ("supply_voltage_v", ctypes.c_double),
        ("stall_force_n", ctypes.c_double),
        ("reflected_mass_kg", ctypes.c_double),
        ("tick_s", ctypes.c_double),
        ("tendon_stiffness_n_per_m", ctypes.c_double),
        ("loadcell_gain_counts_per_n", ctypes.c_double),
        ("loadcell_noise_n", ctypes.c_double),
        ("loadcell_rate_hz", ctypes.c_double),
        ("tracker_noise_m", ctypes.c_double),
        ("tracker_noise_rad", ctypes.c_double),
        ("tracker_rate_hz", ctypes.c_double),
        ("slack_length_m", _Channels),
        ("loadcell_offset_counts", _Channels),
        ("loadcell_gain_error", _Channels),
        ("loadcell_offset_error_n", _Channels),
        ("probe_position_m", _Probes),
        ("probe_axis", _Probes),
        ("power_up_s", ctypes.c_double),
        ("deadline_s", ctypes.c_double),
        ("last_write_s", ctypes.c_double),
        ("keepalive_s", ctypes.c_double),
        ("next_loadcell_s", ctypes.c_double),
        ("next_tracker_s", ctypes.c_double),
        ("loadcell_time_s", ctypes.c_double),
        ("tracker_time_s", ctypes.c_double),
        ("tracker_positions_m", _Probes),
        ("tracker_axes", _Probes),
        ("pwm_v", _Channels),
        ("jump_accel_m_s2", ctypes.c_double),
        ("noise_size", ctypes.c_int32),
        ("noise_cursor", ctypes.c_int32),
        ("tip_site", ctypes.c_int32),
        ("engage_substeps", ctypes.c_int32),
        ("current_substeps", ctypes.c_int32),
        ("jump", ctypes.c_int32),
        ("short_steps", ctypes.c_int32),
        ("spool_qpos", ctypes.c_int32 * _CHANNELS),
        ("pwm_ctrl", ctypes.c_int32 * _CHANNELS),
        ("raw_counts", ctypes.c_int32 * _CHANNELS),
        ("loadcell_index", ctypes.c_int32),
        ("last_loadcell_index", ctypes.c_int32),
        ("tracker_index", ctypes.c_int32),
        ("warnings_total", ctypes.c_int32),
        ("plant_pwm", ctypes.c_int32),
        ("held", ctypes.c_int32),
        ("have_applied", ctypes.c_int32),
        ("ticks", ctypes.c_int32),
        ("applied_changed", ctypes.c_int32),
        ("resume", ctypes.c_int32),
        ("applied_duty", ctypes.c_float * _CHANNELS),
        ("duty", ctypes.c_float * _CHANNELS),
        ("applied_drive", ctypes.c_uint8 * _CHANNELS),
        ("drive", ctypes.c_uint8 * _CHANNELS),
    ]


def build_library(*, force: bool = False) -> Path:
    """Compile ``native/board_loop.cpp`` if the library is missing or older than it.

    Raises:
        RuntimeError: g++ is missing or the build failed (the message holds its output).
    """
    LIB_PATH.parent.mkdir(parents=True, exist_ok=True)
    with open(LIB_PATH.parent / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if force or not LIB_PATH.exists() or LIB_PATH.stat().st_mtime < SOURCE.stat().st_mtime:
            include = _MUJOCO_DIR / "include"
            tmp = LIB_PATH.with_suffix(".tmp")
            # -ffp-contract=off: no fused multiply-adds, so the sums round as Python's do.
            command = ["g++", "-std=c++17", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror",
                       "-shared", "-fPIC", f"-I{include}", str(SOURCE), "-o", str(tmp)]
            try:
                result = subprocess.run(command, capture_output=True, text=True, check=False)
            except FileNotFoundError as exc:
                raise RuntimeError(f"{command[0]}: {exc}") from None
            if result.returncode != 0:
                raise RuntimeError(f"{' '.join(command)} exited {result.returncode}:\n{result.stderr[-4000:]}")
            tmp.replace(LIB_PATH)
    return LIB_PATH


@functools.lru_cache(maxsize=1)
def _load() -> tuple[ctypes.CDLL, int, int, int] | None:
    """The loop library and the function pointers it calls, or None (with a warning) when it
    cannot be built or loaded."""
    try:
        lib = ctypes.CDLL(str(build_library()))
        lib.bl_abi_version.restype = ctypes.c_uint32
        lib.bl_state_size.restype = ctypes.c_uint32
        if lib.bl_abi_version() != ABI_VERSION or lib.bl_state_size() != ctypes.sizeof(_State):
            raise RuntimeError(f"{LIB_PATH}: ABI {lib.bl_abi_version()}, state {lib.bl_state_size()} bytes; "
                               f"expected {ABI_VERSION}, {ctypes.sizeof(_State)}")
        lib.bl_run.restype = ctypes.c_int
        lib.bl_run.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                               ctypes.c_void_p, ctypes.POINTER(_State), ctypes.c_int32]
        mujoco_lib = ctypes.CDLL(str(next(_MUJOCO_DIR.glob("libmujoco.so*"))))
        firmware = load_firmware_library()
        pointers = tuple(ctypes.cast(f, ctypes.c_void_p).value for f in
                         (firmware.twinfw_tick, firmware.twinfw_tx_pending, mujoco_lib.mj_step))
    except (OSError, RuntimeError, StopIteration) as exc:
        warnings.warn(f"the emulated board's native tick loop is not available, ticking in Python: {exc}",
                      RuntimeWarning, stacklevel=3)
        return None
    return (lib, *pointers)


def available() -> bool:
    """True when the native loop could be built and loaded."""
    return _load() is not None


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
        loaded = _load()
        if loaded is None:
            raise RuntimeError("the native tick loop is not available")
        self._lib, self._tick, self._pending, self._step = loaded
        self.board = board
        plant = board.plant
        if plant.tendon_count != _CHANNELS:
            raise ValueError(f"{plant.tendon_count} tendons: the native loop drives {_CHANNELS}")
        s = self._state = _State()
        motor = plant._motor
        s.m_per_count = plant.params.rig.tendon_m_per_count
        s.engage_stretch_m = plant._engage_stretch_m
        s.engage_speed_m_s = plant._engage_speed_m_s
        s.engage_substeps = plant._engage_substeps
        s.supply_voltage_v = motor.supply_voltage_v
        s.stall_force_n = motor.stall_force_n
        s.reflected_mass_kg = motor.reflected_mass_kg
        s.tick_s = plant.timestep_s
        s.tendon_stiffness_n_per_m = plant._tendon_stiffness
        s.loadcell_rate_hz = plant.params.rig.loadcell_rate_hz
        s.tracker_rate_hz = plant.params.rig.tracker_rate_hz
        s.tip_site = plant._tip_site
        s.slack_length_m[:] = plant._slack_length_list
        s.spool_qpos[:] = [int(q) for q in plant._spool_q]
        s.pwm_ctrl[:] = [_ACTUATOR_BLOCK["pwm"] * plant.tendon_count + i for i in range(_CHANNELS)]
        self._state_ref = ctypes.byref(s)
        self.native_ticks = 0
        # The objects last copied into the state: (noise stream, load-cell sample, warning
        # counts, PWM voltages, applied outputs); Python replaces rather than mutates them.
        self._synced = (None, None, None, None, None)
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
        synced_noise, synced_sample, synced_warnings, synced_pwm, synced_applied = self._synced
        s.resume = resume
        s.power_up_s = board._power_up_s
        s.deadline_s = deadline_s
        s.last_write_s = last_write_s
        s.keepalive_s = math.inf if keepalive_s is None else keepalive_s
        s.last_loadcell_index = board._last_loadcell_index
        s.plant_pwm = plant._mode == "pwm"
        s.held = board._held_tensions_n is not None
        s.jump = plant._jump
        s.jump_accel_m_s2 = plant._jump_accel_m_s2
        s.current_substeps = plant._current_substeps
        s.next_loadcell_s = plant._next_loadcell_s
        s.next_tracker_s = plant._next_tracker_s
        s.tracker_index = plant._tracker_frame.index
        # What Python may have replaced since the last call, copied only when it did.
        noise = plant._noise
        if noise is not synced_noise:
            self._sync_sensors(plant)
        s.noise_cursor = noise.cursor
        sample = plant._loadcell
        if sample is not synced_sample:
            s.raw_counts[:] = sample.raw_counts.tolist()
            s.loadcell_index = sample.index
        if plant._warnings_seen is not synced_warnings:
            s.warnings_total = int(plant._warnings_seen.sum())
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
        self.native_ticks += s.ticks
        self.returns[reason] = self.returns.get(reason, 0) + 1
        noise.cursor = s.noise_cursor
        board._last_loadcell_index = s.last_loadcell_index
        plant._jump = bool(s.jump)
        plant._jump_accel_m_s2 = s.jump_accel_m_s2
        plant._current_substeps = s.current_substeps
        plant.short_steps += s.short_steps
        if s.loadcell_index != sample.index:
            sample = plant._loadcell = LoadCellSample(np.array(s.raw_counts[:], dtype=np.int64), s.loadcell_index,
                                                      s.loadcell_time_s)
            plant._next_loadcell_s = s.next_loadcell_s
        if s.tracker_index != plant._tracker_frame.index:
            plant._tracker_frame = TrackerSample(np.array(s.tracker_positions_m[:]).reshape(2, 3),
                                                 np.array(s.tracker_axes[:]).reshape(2, 3), s.tracker_index,
                                                 s.tracker_time_s)
            plant._next_tracker_s = s.next_tracker_s
        if s.applied_changed:
            board._applied = ((np.array(s.applied_duty[:], dtype=np.float32).astype(np.float64).tobytes(),
                               bytes(s.applied_drive)) if s.have_applied else None)
            plant._pwm_v = np.array(s.pwm_v[:])
        if s.ticks:
            board.firmware._duty[:] = s.duty[:]
            board.firmware._drive[:] = s.drive[:]
        self._synced = (noise, sample, plant._warnings_seen, plant._pwm_v, board._applied)
        return reason

    def outputs(self) -> tuple[np.ndarray, np.ndarray]:
        """The last tick's duty (float64) and drive modes (uint8), as ``FirmwareLib.tick`` and
        ``drive_modes`` give them."""
        return (np.array(self._state.duty[:], dtype=np.float32).astype(np.float64),
                np.array(self._state.drive[:], dtype=np.uint8))

    def _sync_sensors(self, plant) -> None:
        """Point the state at the plant's noise buffer (new with each reset) and copy the
        sensors' constants."""
        s, noise, cells, tracker = self._state, plant._noise, plant._loadcells, plant._tracker
        s.noise = noise.buffer.ctypes.data
        s.noise_size = noise.buffer.size
        s.loadcell_gain_counts_per_n = cells.gain_counts_per_n
        s.loadcell_noise_n = cells.noise_n
        s.loadcell_offset_counts[:] = cells.offset_counts
        s.loadcell_gain_error[:] = cells.gain_error
        s.loadcell_offset_error_n[:] = cells.offset_error_n
        s.tracker_noise_m = tracker.noise_m
        s.tracker_noise_rad = tracker.noise_rad
        s.probe_position_m[:] = [x for position in tracker.positions_m for x in position]
        s.probe_axis[:] = [x for axis in tracker.axes for x in axis]
