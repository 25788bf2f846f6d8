"""The binding on the twin's plant loop (``native/loop.cpp``): typed calls, no logic of its own.

``loop.cpp`` is the one implementation of how the simulated rig is driven, stepped and sensed,
and of the emulated board's tick. :class:`PlantLoop` holds one plant's shared state — a ctypes
structure built from the field table the library exports, so the state is declared once, in
C++ — and wraps each entry point; it handles the one thing the loop hands back that is the
binding's business, refilling the sensors' noise buffer, and returns every other
:class:`Reason` to its caller (:class:`twin.sim.plant.Plant`, :class:`twin.device.board.EmulatedBoard`).

It needs a C++ compiler (``$CXX`` or g++) and MuJoCo's headers, which the mujoco wheel ships; the
library is built on first use into the per-user cache (:mod:`twin.resources`).
"""

from __future__ import annotations

import ctypes
import enum
import functools
import importlib.metadata
import importlib.util
import subprocess
from pathlib import Path
from typing import Any

from twin.resources import NativeBuildError, build_cached, resource_path
from twin.sim.sensors import NoiseStream

__all__ = ["LoopState", "Mode", "NativeLoopError", "PlantLoop", "Reason", "build_library", "load"]

SOURCE = resource_path("native") / "loop.cpp"
LIB_NAME = "libtwinloop.so"
ABI_VERSION = 11
# Where the mujoco wheel lives (headers, libmujoco), found without importing it: MuJoCo picks its
# GL backend on first import, which the twin package arranges for (headless EGL).
_MUJOCO_SPEC = importlib.util.find_spec("mujoco")
if _MUJOCO_SPEC is None or not _MUJOCO_SPEC.submodule_search_locations:
    raise ImportError("twin.sim needs the mujoco package (a dependency of twin: pip install mujoco)")
_MUJOCO_DIR = Path(_MUJOCO_SPEC.submodule_search_locations[0])


class NativeLoopError(NativeBuildError):
    """The plant loop could not be built or loaded (no g++, no MuJoCo headers, a bad build)."""


class Reason(enum.IntEnum):
    """Why the loop returned (``enum bl_reason``)."""

    DONE = 0
    DEADLINE = 1
    KEEPALIVE = 2
    TX = 3
    WARNING = 4
    NOISE = 5


class Mode(enum.IntEnum):
    """The spools' drive (``enum bl_mode``); :class:`twin.sim.plant.DriveMode` names them."""

    PWM = 0
    COAST = 1
    TENSION = 2
    LENGTH = 3


_KINDS = {"ptr": ctypes.c_void_p, "f64p": ctypes.c_void_p, "f64": ctypes.c_double, "i32": ctypes.c_int32, "f32": ctypes.c_float,
          "u8": ctypes.c_uint8}


class _Field(ctypes.Structure):
    _fields_ = [("name", ctypes.c_char_p), ("offset", ctypes.c_uint32), ("kind", ctypes.c_char_p),
                ("count", ctypes.c_uint32)]


class LoopState(ctypes.Structure):
    """``struct bl_state``: its fields are filled in from the library's table when it is loaded
    (:func:`load`); ``loop.cpp`` documents each."""


def build_library(*, force: bool = False) -> Path:
    """The plant loop's library, compiled from ``native/loop.cpp`` into the per-user cache
    (:func:`twin.resources.build_cached`) unless it holds one for this source, compiler and
    MuJoCo.

    Raises:
        NativeLoopError: no C++ compiler, or the build failed (the message holds its output).
    """
    include = _MUJOCO_DIR / "include"
    flags = ["-std=c++17", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-shared", "-fPIC",
             f"-I{include}"]

    def build(folder: Path, compiler: str) -> None:
        command = [compiler, *flags, str(SOURCE), "-o", str(folder / LIB_NAME)]
        result = subprocess.run(command, capture_output=True, text=True, check=False)
        if result.returncode != 0:
            raise NativeLoopError(f"{' '.join(command)} exited {result.returncode}:\n{result.stderr[-4000:]}")

    return build_cached(LIB_NAME, [SOURCE], [*flags, _mujoco_version()], build,
                        what="the twin's plant loop", error=NativeLoopError, force=force)


def _mujoco_version() -> str:
    """The mujoco wheel's version: its headers lay out the structures the loop reads."""
    try:
        return importlib.metadata.version("mujoco")
    except importlib.metadata.PackageNotFoundError:
        return str(_MUJOCO_DIR)


@functools.lru_cache(maxsize=1)
def load() -> "_Library":
    """Build if needed and load the library; lay out :class:`LoopState` from its field table.

    Raises:
        NativeLoopError: it cannot be built or loaded, or it does not match this binding.
    """
    path = build_library()
    try:
        lib = ctypes.CDLL(str(path))
        mujoco_lib = ctypes.CDLL(str(next(_MUJOCO_DIR.glob("libmujoco.so*"))))
    except (OSError, StopIteration) as exc:
        raise NativeLoopError(f"the twin's plant loop cannot be loaded: {exc}") from None
    lib.bl_abi_version.restype = ctypes.c_uint32
    lib.bl_state_size.restype = ctypes.c_uint32
    lib.bl_max_channels.restype = ctypes.c_uint32
    lib.bl_state_fields.restype = ctypes.POINTER(_Field)
    lib.bl_state_fields.argtypes = [ctypes.POINTER(ctypes.c_uint32)]
    if lib.bl_abi_version() != ABI_VERSION:
        raise NativeLoopError(f"{path}: ABI {lib.bl_abi_version()}, this binding needs {ABI_VERSION}")
    count = ctypes.c_uint32()
    table = lib.bl_state_fields(ctypes.byref(count))
    fields = [table[i] for i in range(count.value)]
    layout: list[Any] = [(f.name.decode(), _KINDS[f.kind.decode()] * f.count if f.count > 1 else _KINDS[f.kind.decode()])
                         for f in fields]
    LoopState._fields_ = layout
    offsets = {f.name.decode(): f.offset for f in fields}
    misplaced = [name for name, *_ in LoopState._fields_ if getattr(LoopState, name).offset != offsets[name]]
    if misplaced or ctypes.sizeof(LoopState) != lib.bl_state_size():
        raise NativeLoopError(f"{path}: ctypes lays out bl_state differently from g++ ({misplaced})")
    state = ctypes.POINTER(LoopState)
    p = ctypes.c_void_p
    for name, argtypes in {"bl_plant_run": [p, p, state, ctypes.c_int32], "bl_plant_reset": [p, p, state],
                           "bl_board_run": [p, p, state, ctypes.c_int32]}.items():
        fn = getattr(lib, name)
        fn.argtypes, fn.restype = argtypes, ctypes.c_int
    lib.bl_set_drive.argtypes = [p, p, state, ctypes.c_int32, ctypes.POINTER(ctypes.c_double)]
    lib.bl_set_drive.restype = None
    lib.bl_encoder_counts.argtypes = [p, state, ctypes.POINTER(ctypes.c_int32)]
    lib.bl_encoder_counts.restype = None
    mujoco_fns = {}
    for name in ("mj_step", "mj_forward"):
        address = ctypes.cast(getattr(mujoco_lib, name), ctypes.c_void_p).value
        if address is None:
            raise NativeLoopError(f"{mujoco_lib}: {name} resolves to a null address")
        mujoco_fns[name] = address
    return _Library(lib, int(lib.bl_max_channels()), mujoco_fns)


class _Library:
    def __init__(self, lib: ctypes.CDLL, max_channels: int, mujoco_fns: dict[str, int]):
        self.lib, self.max_channels, self.mujoco_fns = lib, max_channels, mujoco_fns


_HOOK = ctypes.CFUNCTYPE(None)


class PlantLoop:
    """One plant's state in the loop, and the loop's entry points on it.

    Args:
        model: the compiled twin (``mujoco.MjModel``).
        data: its ``mujoco.MjData``.
        channels: tendons of the plant (at most the library's ``bl_max_channels``).

    Attributes:
        state: the :class:`LoopState`; the plant sets its constants, the board its board fields.
    """

    def __init__(self, model, data, channels: int):
        library = load()
        if not 1 <= channels <= library.max_channels:
            raise ValueError(f"tendons = {channels}: the twin's plant loop handles 1 to {library.max_channels}")
        self._lib = library.lib
        self._model, self._data = model, data
        self._m, self._d = model._address, data._address
        self.state = LoopState()
        self._ref = ctypes.byref(self.state)
        s = self.state
        s.channels = channels
        s.step_fn = library.mujoco_fns["mj_step"]
        s.forward_fn = library.mujoco_fns["mj_forward"]
        self._noise: NoiseStream | None = None
        self._hook: object | None = None  # the ctypes callback, kept alive while the loop may call it
        self._values = (ctypes.c_double * library.max_channels)()
        self._counts = (ctypes.c_int32 * library.max_channels)()

    def set_hook(self, hook) -> None:
        """Call ``hook()`` before every physics step (None: no hook)."""
        if hook is None:
            self._hook = self.state.hook_fn = None
            return
        callback = _HOOK(hook)
        self._hook = callback
        self.state.hook_fn = ctypes.cast(callback, ctypes.c_void_p).value

    def set_noise(self, noise: NoiseStream) -> None:
        """Draw the sensors' noise from ``noise`` (a new stream with each reset)."""
        self._noise = noise
        s = self.state
        s.noise = noise.buffer.ctypes.data
        s.noise_size = noise.buffer.size
        s.noise_cursor = 0

    def reset(self) -> None:
        """``bl_plant_reset`` (after ``mj_resetData``): braked motors, the first samples."""
        self._call(self._lib.bl_plant_reset, self._m, self._d, self._ref)

    def set_drive(self, mode: Mode, values=None) -> None:
        """``bl_set_drive``: duties, nothing (coast), tensions (N) or relative lengths (m)."""
        if values is not None:
            self._values[:len(values)] = values
        self._lib.bl_set_drive(self._m, self._d, self._ref, int(mode), self._values)

    def encoder_counts(self) -> list[int]:
        """The motor encoders' quadrature counts."""
        self._lib.bl_encoder_counts(self._d, self._ref, self._counts)
        return self._counts[:self.state.channels]

    def run(self, steps: int) -> Reason:
        """``bl_plant_run``: ``steps`` physics steps; :data:`Reason.DONE` or :data:`Reason.WARNING`."""
        while True:
            reason = self._lib.bl_plant_run(self._m, self._d, self._ref, steps)
            steps -= self.state.ticks
            if reason != Reason.NOISE:
                return Reason(reason)
            self._refill()

    def board_run(self, max_ticks: int) -> Reason:
        """``bl_board_run``: up to ``max_ticks`` board ticks (board fields set by the caller)."""
        while True:
            reason = self._lib.bl_board_run(self._m, self._d, self._ref, max_ticks)
            if reason != Reason.NOISE:
                return Reason(reason)
            max_ticks -= self.state.ticks
            self._refill()

    def _call(self, fn, *args) -> None:
        while fn(*args) == Reason.NOISE:
            self._refill()

    def _refill(self) -> None:
        if self._noise is None:
            raise NativeLoopError("the plant loop asked for sensor noise before set_noise() gave it a stream")
        self.state.noise_cursor = self._noise.refill(self.state.noise_cursor)
