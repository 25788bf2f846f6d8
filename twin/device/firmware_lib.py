"""The firmware core, built for the host and driven through ctypes.

This is the board's logic without the board: the same C++ (``firmware/core``) that runs on the
Teensy, stepped with explicit time, so the emulated board and the tests exercise the real PID,
safety state machine and codec. The library is built on first use with ``make -C firmware
lib`` (host g++) into the per-user cache (:mod:`twin.resources`), and anew when a firmware
source or the compiler changes.

Example:
    >>> fw = FirmwareLib(channels=3)
    >>> fw.receive(codec.encode_frame(codec.Hello(), seq=1))
    >>> duty = fw.tick(0, [0, 0, 0], [0, 0, 0], new_mask=0b111)
    >>> [type(f.message).__name__ for f in codec.FrameDecoder().feed(fw.take_tx())]
    ['HelloReply', 'TelemetryMessage']
"""

from __future__ import annotations

import ctypes
import functools
import shutil
import subprocess
from pathlib import Path
from typing import Sequence

import numpy as np

from twin.driver import codec
from twin.resources import NativeBuildError, build_cached, resource_path

__all__ = [
    "FIRMWARE_DIR",
    "LIB_NAME",
    "ABI_VERSION",
    "FirmwareBuildError",
    "build_library",
    "load_library",
    "tick_entry_points",
    "FirmwareLib",
    "FirmwareFrameDecoder",
]

FIRMWARE_DIR = resource_path("firmware")
LIB_NAME = "libtwinfw.so"
ABI_VERSION = 4


class FirmwareBuildError(NativeBuildError):
    """``make -C firmware lib`` failed or the built library does not match this binding."""


def _sources() -> list[Path]:
    return [
        *sorted((FIRMWARE_DIR / "core").glob("*.[ch]*")),
        *sorted((FIRMWARE_DIR / "host").glob("*.[ch]*")),
        FIRMWARE_DIR / "Makefile",
    ]


def build_library(*, force: bool = False) -> Path:
    """The host library, built with ``make -C firmware lib`` into the per-user cache
    (:func:`twin.resources.build_cached`) unless it holds one for these sources and compiler;
    the firmware folder itself is only read.

    Raises:
        FirmwareBuildError: no make or C++ compiler, or the build failed (the message holds its output).
    """
    what = "the emulated board's firmware"

    def build(folder: Path, compiler: str) -> None:
        if shutil.which("make") is None:
            raise FirmwareBuildError(f"{what} is compiled on first use with make, which is not on PATH: "
                                     "install make (e.g. apt install make)")
        command = ["make", "-C", str(FIRMWARE_DIR), f"BUILD={folder}", f"CXX={compiler}", "lib"]
        result = subprocess.run(command, capture_output=True, text=True, check=False)
        if result.returncode != 0:
            raise FirmwareBuildError(
                f"{' '.join(command)} exited {result.returncode}:\n{result.stdout[-2000:]}{result.stderr[-4000:]}"
            )

    return build_cached(LIB_NAME, _sources(), [], build, what=what, error=FirmwareBuildError, force=force)


@functools.lru_cache(maxsize=1)
def load_library() -> ctypes.CDLL:
    """Build if needed and load the library, with argument types declared.

    Raises:
        FirmwareBuildError: the build failed, or the library's ABI version is not ABI_VERSION.
    """
    path = build_library()
    lib = ctypes.CDLL(str(path))
    p, u8p, i32p, f32p = ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint8), ctypes.POINTER(ctypes.c_int32), ctypes.POINTER(ctypes.c_float)
    signatures = {
        "twinfw_abi_version": ([], ctypes.c_uint32),
        "twinfw_protocol_version": ([], ctypes.c_uint32),
        "twinfw_max_channels": ([], ctypes.c_uint32),
        "twinfw_create": ([ctypes.c_uint32], p),
        "twinfw_create_rig": ([ctypes.c_uint32, ctypes.c_float], p),
        "twinfw_channels": ([p], ctypes.c_uint32),
        "twinfw_destroy": ([p], None),
        "twinfw_receive": ([p, ctypes.c_char_p, ctypes.c_size_t], None),
        "twinfw_tick": ([p, ctypes.c_uint64, i32p, i32p, ctypes.c_uint32, f32p, u8p], None),
        "twinfw_tx_pending": ([p], ctypes.c_size_t),
        "twinfw_take_tx": ([p, ctypes.c_char_p, ctypes.c_size_t], ctypes.c_size_t),
        "twinfw_decoder_create": ([], p),
        "twinfw_decoder_destroy": ([p], None),
        "twinfw_decoder_feed": ([p, ctypes.c_char_p, ctypes.c_size_t, ctypes.c_char_p, ctypes.c_size_t], ctypes.c_size_t),
        "twinfw_decoder_bad_frames": ([p], ctypes.c_uint32),
        "twinfw_decoder_overflows": ([p], ctypes.c_uint32),
    }
    for name, (argtypes, restype) in signatures.items():
        fn = getattr(lib, name)
        fn.argtypes, fn.restype = argtypes, restype
    abi = lib.twinfw_abi_version()
    if abi != ABI_VERSION:
        raise FirmwareBuildError(f"{path} has ABI version {abi}, this binding needs {ABI_VERSION}")
    protocol = lib.twinfw_protocol_version()
    if protocol != codec.PROTOCOL_VERSION:
        raise FirmwareBuildError(
            f"{path} speaks protocol version {protocol}, twin.driver.codec speaks {codec.PROTOCOL_VERSION}"
        )
    most = lib.twinfw_max_channels()
    if most != codec.MAX_CHANNELS:
        raise FirmwareBuildError(f"{path} drives up to {most} channels, twin.driver.codec {codec.MAX_CHANNELS}")
    return lib


@functools.lru_cache(maxsize=1)
def tick_entry_points() -> tuple[int, int]:
    """Addresses of ``twinfw_tick`` and ``twinfw_tx_pending``, for a native loop that ticks a
    :attr:`FirmwareLib.handle` itself (the emulated board's, :mod:`twin.device.board`)."""
    lib = load_library()
    tick, tx_pending = (ctypes.cast(f, ctypes.c_void_p).value for f in (lib.twinfw_tick, lib.twinfw_tx_pending))
    if tick is None or tx_pending is None:
        raise FirmwareBuildError("the firmware library's twinfw_tick or twinfw_tx_pending resolves to a null address")
    return tick, tx_pending


_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1


def _channels(name: str, values: Sequence[int], out: np.ndarray) -> None:
    """Copy one integer per channel into the int32 buffer ``out``, refusing what does not fit."""
    array = np.asarray(values)
    if array.shape != out.shape or array.dtype.kind not in "iu":
        raise ValueError(f"{name} = {values!r}: must be {out.size} integers")
    # Checked as Python ints: this runs twice per tick, 200 ticks per simulated second, and
    # numpy's min and max cost five times as much on a few values.
    items = array.tolist()
    if min(items) < _INT32_MIN or max(items) > _INT32_MAX:
        raise ValueError(f"{name} = {values!r}: must fit in int32")
    out[:] = items


class FirmwareLib:
    """One emulated board: the firmware core with its own state, stepped by the caller.

    Time is whatever the caller says: ``tick(now_us, ...)`` runs the safety checks, the 100 Hz
    control loop when due and the 40 Hz telemetry when due; commands given to ``receive`` take
    effect at the time of the latest tick. Call ``tick`` at 200 Hz or faster to hit both rates
    exactly. Not thread-safe.

    Args:
        channels: motors and load cells of the board (1..:data:`codec.MAX_CHANNELS`), what its
            HELLO_REPLY reports; default the thesis endoscope's four.
        tendon_m_per_count: tendon per encoder count of the rig it drives (m), what its
            HELLO_REPLY reports and its lengths and spool speeds are counted in (a robot's
            ``rig.tendon_m_per_count``); None: the thesis rig's, as the Teensy is built.

    Attributes:
        channels: that count.

    Raises:
        ValueError: ``channels`` outside 1..MAX_CHANNELS, or ``tendon_m_per_count`` not in (0, 1) m.
    """

    def __init__(self, channels: int = codec.DEFAULT_CHANNELS, tendon_m_per_count: float | None = None) -> None:
        if not (isinstance(channels, (int, np.integer)) and 1 <= channels <= codec.MAX_CHANNELS):
            raise ValueError(f"channels = {channels!r}: the firmware drives 1..{codec.MAX_CHANNELS} motors")
        if tendon_m_per_count is not None and not 0.0 < tendon_m_per_count < 1.0:
            raise ValueError(f"tendon_m_per_count = {tendon_m_per_count!r}: must be in (0, 1) m, or None")
        self._lib = load_library()
        self._fw = self._lib.twinfw_create(int(channels)) if tendon_m_per_count is None else \
            self._lib.twinfw_create_rig(int(channels), float(tendon_m_per_count))
        if not self._fw:
            raise MemoryError("twinfw_create returned NULL")
        self.channels = int(self._lib.twinfw_channels(self._fw))
        self._duty = np.zeros(self.channels, dtype=np.float32)
        self._drive = np.zeros(self.channels, dtype=np.uint8)
        self._counts = np.zeros(self.channels, dtype=np.int32)
        self._raw = np.zeros(self.channels, dtype=np.int32)
        # The buffers live as long as the board, so their C pointers are taken once.
        self._pointers = (
            self._counts.ctypes.data_as(ctypes.POINTER(ctypes.c_int32)),
            self._raw.ctypes.data_as(ctypes.POINTER(ctypes.c_int32)),
            self._duty.ctypes.data_as(ctypes.POINTER(ctypes.c_float)),
            self._drive.ctypes.data_as(ctypes.POINTER(ctypes.c_uint8)),
        )

    def receive(self, data: bytes) -> None:
        """Host → board bytes, in any chunking."""
        self._check_open()
        self._lib.twinfw_receive(self._fw, bytes(data), len(data))

    def tick(
        self, now_us: int, encoder_counts: Sequence[int], raw_counts: Sequence[int], new_mask: int
    ) -> np.ndarray:
        """Step the board at ``now_us`` (µs, non-decreasing, any origin).

        Args:
            now_us: board time in microseconds.
            encoder_counts: a quadrature count per channel (int32).
            raw_counts: an HX711 reading per channel (int32); only channels in ``new_mask`` are taken.
            new_mask: bit i set when ``raw_counts[i]`` is a sample taken since the last tick.

        Returns:
            Duty per motor in [-1, 1], shape (channels,); positive pays tendon out. The drive state
            (coast/drive/brake) of the same step is in :attr:`drive_modes`.
        """
        self._check_open()
        if now_us < 0:
            raise ValueError(f"now_us = {now_us!r}: must be >= 0")
        if not 0 <= new_mask < 1 << self.channels:
            raise ValueError(f"new_mask = {new_mask!r}: must be in 0..{(1 << self.channels) - 1}")
        _channels("encoder_counts", encoder_counts, self._counts)
        _channels("raw_counts", raw_counts, self._raw)
        counts, raw, duty, drive = self._pointers
        self._lib.twinfw_tick(self._fw, now_us, counts, raw, new_mask, duty, drive)
        return self._duty.astype(np.float64)

    @property
    def handle(self) -> int:
        """The firmware core's C handle, for :func:`tick_entry_points`' functions."""
        self._check_open()
        return self._fw

    @property
    def drive_modes(self) -> np.ndarray:
        """:class:`codec.Drive` per motor after the latest tick, shape (channels,), uint8."""
        return self._drive.copy()

    def take_tx(self) -> bytes:
        """All board → host bytes queued so far (frames are whole)."""
        self._check_open()
        size = self._lib.twinfw_tx_pending(self._fw)
        if size == 0:
            return b""
        buffer = ctypes.create_string_buffer(size)
        n = self._lib.twinfw_take_tx(self._fw, buffer, size)
        return buffer.raw[:n]

    def close(self) -> None:
        if self._fw:
            self._lib.twinfw_destroy(self._fw)
            self._fw = None

    def __enter__(self) -> "FirmwareLib":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        if getattr(self, "_fw", None):
            self.close()

    def _check_open(self) -> None:
        if not self._fw:
            raise ValueError("FirmwareLib is closed")


class FirmwareFrameDecoder:
    """The firmware's C++ frame decoder on its own, to test it against the Python one."""

    def __init__(self) -> None:
        self._lib = load_library()
        self._decoder = self._lib.twinfw_decoder_create()
        if not self._decoder:
            raise MemoryError("twinfw_decoder_create returned NULL")

    def feed(self, data: bytes) -> list[tuple[int, int, bytes]]:
        """Frames completed by ``data`` that passed COBS and CRC, as (type, seq, payload)."""
        capacity = len(data) + 8  # a record is never longer than the encoded frame it came from
        out = ctypes.create_string_buffer(capacity)
        n = self._lib.twinfw_decoder_feed(self._decoder, bytes(data), len(data), out, capacity)
        if self._lib.twinfw_decoder_overflows(self._decoder):
            raise RuntimeError(f"twinfw_decoder_feed dropped records with capacity {capacity} for {len(data)} bytes")
        records, raw, i = [], out.raw[:n], 0
        while i < n:
            size = int.from_bytes(raw[i : i + 2], "little")
            record = raw[i + 2 : i + 2 + size]
            records.append((record[0], int.from_bytes(record[1:3], "little"), bytes(record[3:])))
            i += 2 + size
        return records

    @property
    def bad_frames(self) -> int:
        return self._lib.twinfw_decoder_bad_frames(self._decoder)

    def __del__(self) -> None:
        if getattr(self, "_decoder", None):
            self._lib.twinfw_decoder_destroy(self._decoder)
            self._decoder = None
