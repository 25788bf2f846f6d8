"""The plant's steps in native code, where nothing in them needs Python.

:meth:`twin.sim.plant.Plant.step` without friction is physics steps in chunks up to the next
sensor sample, an engagement check per chunk, and the samples: in Python the glue costs as
much as the physics (``twin bench sim``). ``native/loop.cpp`` runs the same chunks
(``bl_plant_run``) with the same float operations in the same order, and hands back to Python
only for a MuJoCo warning or to refill the sensors' noise buffer; the numbers are the Python
path's to the bit (``tests/test_sim_native.py``). The emulated board's tick loop
(:mod:`twin.device.board_loop`) is built on the same library and state (``bl_run``).

It needs g++ (as the firmware library does) and MuJoCo's headers, which the wheel ships. When
either is missing the plant keeps to the Python path, with a warning: slower, same results.
"""

from __future__ import annotations

import ctypes
import fcntl
import functools
import importlib.util
import subprocess
import warnings
from pathlib import Path

import numpy as np

from twin.sim.sensors import LoadCellSample, TrackerSample

__all__ = ["PlantLoop", "Reason", "available", "build_library", "load"]

SOURCE = Path(__file__).parent / "native" / "loop.cpp"
LIB_PATH = Path(__file__).parent / "native" / "build" / "libtwinloop.so"
ABI_VERSION = 6
# Where the mujoco wheel lives (headers, libmujoco), found without importing it: MuJoCo picks its
# GL backend on first import, which the twin package arranges for (headless EGL).
_MUJOCO_DIR = Path(importlib.util.find_spec("mujoco").submodule_search_locations[0])
# Tendons (motors, load cells) the native code handles: BL_CHANNELS.
CHANNELS = 4


class Reason:
    """Why ``bl_run`` or ``bl_plant_run`` returned (``enum bl_reason`` in loop.cpp)."""

    DEADLINE = 0
    KEEPALIVE = 1
    APPLY = 2
    TX = 3
    WARNING = 4
    NOISE = 5
    DONE = 6


_Channels = ctypes.c_double * CHANNELS
_Probes = ctypes.c_double * 6


class State(ctypes.Structure):
    """``struct bl_state`` of loop.cpp: inputs, state carried across calls, outputs."""

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
        ("spool_qpos", ctypes.c_int32 * CHANNELS),
        ("pwm_ctrl", ctypes.c_int32 * CHANNELS),
        ("raw_counts", ctypes.c_int32 * CHANNELS),
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
        ("applied_duty", ctypes.c_float * CHANNELS),
        ("duty", ctypes.c_float * CHANNELS),
        ("applied_drive", ctypes.c_uint8 * CHANNELS),
        ("drive", ctypes.c_uint8 * CHANNELS),
    ]


def build_library(*, force: bool = False) -> Path:
    """Compile ``native/loop.cpp`` if the library is missing or older than it.

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
def load() -> tuple[ctypes.CDLL, int] | None:
    """The loop library and MuJoCo's ``mj_step`` (a function pointer it calls), or None (with a
    warning) when it cannot be built or loaded."""
    try:
        lib = ctypes.CDLL(str(build_library()))
        lib.bl_abi_version.restype = ctypes.c_uint32
        lib.bl_state_size.restype = ctypes.c_uint32
        if lib.bl_abi_version() != ABI_VERSION or lib.bl_state_size() != ctypes.sizeof(State):
            raise RuntimeError(f"{LIB_PATH}: ABI {lib.bl_abi_version()}, state {lib.bl_state_size()} bytes; "
                               f"expected {ABI_VERSION}, {ctypes.sizeof(State)}")
        lib.bl_run.restype = ctypes.c_int
        lib.bl_run.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                               ctypes.c_void_p, ctypes.POINTER(State), ctypes.c_int32]
        lib.bl_plant_run.restype = ctypes.c_int
        lib.bl_plant_run.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.POINTER(State),
                                     ctypes.c_int32]
        mujoco_lib = ctypes.CDLL(str(next(_MUJOCO_DIR.glob("libmujoco.so*"))))
        step = ctypes.cast(mujoco_lib.mj_step, ctypes.c_void_p).value
    except (OSError, RuntimeError, StopIteration) as exc:
        warnings.warn(f"the twin's native stepping loop is not available, stepping in Python: {exc}",
                      RuntimeWarning, stacklevel=3)
        return None
    return lib, step


def available() -> bool:
    """True when the native loop could be built and loaded."""
    return load() is not None


class PlantLoop:
    """Runs :meth:`twin.sim.plant.Plant.step` natively for one plant, and keeps the state the
    board loop shares (:class:`twin.device.board_loop.BoardLoop`).

    Args:
        plant: the plant (four tendons, no friction).

    Attributes:
        state: the ``bl_state`` both loops read and write.
        returns: how often each :class:`Reason` handed back to Python.
    """

    def __init__(self, plant):
        loaded = load()
        if loaded is None:
            raise RuntimeError("the native loop is not available")
        if plant.tendon_count != CHANNELS:
            raise ValueError(f"{plant.tendon_count} tendons: the native loop handles {CHANNELS}")
        self.lib, self.mj_step = loaded
        self.plant = plant
        s = self.state = State()
        s.engage_stretch_m = plant._engage_stretch_m
        s.engage_speed_m_s = plant._engage_speed_m_s
        s.engage_substeps = plant._engage_substeps
        s.tick_s = plant.timestep_s
        s.tendon_stiffness_n_per_m = plant._tendon_stiffness
        s.loadcell_rate_hz = plant.params.rig.loadcell_rate_hz
        s.tracker_rate_hz = plant.params.rig.tracker_rate_hz
        s.tip_site = plant._tip_site
        s.slack_length_m[:] = plant._slack_length_list
        self.state_ref = ctypes.byref(s)
        # The objects last copied into the state: (noise stream, load-cell sample, warning
        # counts); Python replaces rather than mutates them.
        self._synced = (None, None, None)
        self.returns: dict[int, int] = {}

    def run(self, steps: int) -> None:
        """Take ``steps`` physics steps as :meth:`Plant.step` would.

        Raises:
            SimulationError: MuJoCo warned (from :meth:`Plant._end_chunk`, as in Python).
        """
        plant = self.plant
        while steps > 0:
            self.sync_in()
            reason = self.lib.bl_plant_run(plant.model._address, plant.data._address, self.mj_step, self.state_ref,
                                           steps)
            self.sync_out()
            self.returns[reason] = self.returns.get(reason, 0) + 1
            steps -= self.state.ticks
            if reason == Reason.NOISE:
                plant._noise.refill()
            elif reason == Reason.WARNING:
                plant._end_chunk()
            elif reason != Reason.DONE:
                raise RuntimeError(f"bl_plant_run returned {reason!r}")

    def sync_in(self) -> None:
        """Copy into the state what Python may have changed since the last call."""
        plant, s = self.plant, self.state
        synced_noise, synced_sample, synced_warnings = self._synced
        s.jump = plant._jump
        s.jump_accel_m_s2 = plant._jump_accel_m_s2
        s.current_substeps = plant._current_substeps
        s.next_loadcell_s = plant._next_loadcell_s
        s.next_tracker_s = plant._next_tracker_s
        s.tracker_index = plant._tracker_frame.index
        noise = plant._noise
        if noise is not synced_noise:
            self._sync_sensors()
        s.noise_cursor = noise.cursor
        sample = plant._loadcell
        if sample is not synced_sample:
            s.raw_counts[:] = sample.raw_counts.tolist()
            s.loadcell_index = sample.index
        if plant._warnings_seen is not synced_warnings:
            s.warnings_total = int(plant._warnings_seen.sum())
        self._synced = (noise, sample, plant._warnings_seen)

    def sync_out(self) -> None:
        """Hand the state's results back to the plant: what the Python path would have left."""
        plant, s = self.plant, self.state
        noise, sample, warnings_seen = self._synced
        noise.cursor = s.noise_cursor
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
        self._synced = (noise, sample, warnings_seen)

    def _sync_sensors(self) -> None:
        """Point the state at the plant's noise buffer (new with each reset) and copy the
        sensors' constants."""
        s, plant = self.state, self.plant
        noise, cells, tracker = plant._noise, plant._loadcells, plant._tracker
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
