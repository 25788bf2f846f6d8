"""The EM tracker over OpenIGTLink: probe frames from PLUS Toolkit (or any OpenIGTLink server).

:class:`OpenIGTLinkSource` keeps a TCP connection to the server in a thread, reconnecting on its
own when the server restarts or the connection dies, and hands :class:`~twin.tracking.TipTracker`
the newest reading of each probe. What PLUS and NDI setups differ in is configurable
(:class:`IgtlSettings`, and from the device URL via :func:`settings_from_options`):

* device names: PLUS names a tool's transform ``<Tool>To<Reference>``, e.g. ``Probe1ToTracker``;
* message types: TRANSFORM and POSITION are both read, and a POSITION beside a TRANSFORM of the
  same name updates the same probe;
* the probe axis: the column of the tool's rotation along the 5-DOF sensor coil (NDI: z), with
  its sign;
* the length unit of the translation (PLUS: mm);
* the clock: message timestamps are the server's clock; the offset to ours is measured from the
  stream (or given), so a server whose clock is off does not make every frame stale;
* validity: a transform whose OpenIGTLink 3 metadata ``TransformStatus`` is not ``OK`` marks the
  probe invalid (PLUS sends invalid transforms only with ``SendValidTransformsOnly="FALSE"``).
"""

from __future__ import annotations

import collections
import dataclasses
import math
import socket
import threading
import time
from typing import Callable

import numpy as np

from twin.driver import igtl
from twin.tracking import ProbeFrame, ProbeReading

__all__ = ["IgtlSettings", "OpenIGTLinkSource", "settings_from_options", "URL_KEYS"]

_AXES = {"x": 0, "y": 1, "z": 2}
_SCALES_M = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}

# Device URL keys this module reads (with ``igtl`` itself); see :func:`settings_from_options`.
URL_KEYS = ("igtl_probes", "igtl_axis", "igtl_scale", "igtl_clock", "igtl_timeout_s")


@dataclasses.dataclass(frozen=True)
class IgtlSettings:
    """How the tracker's messages map to probe readings.

    Attributes:
        device_a, device_b: device names of probe A and probe B (TRANSFORM or POSITION).
        axis_column: column (0, 1 or 2) of the tool rotation along the probe axis.
        axis_sign: +1 or −1: whether that column points along the probe axis or against it.
        position_scale_m: metres per unit of the translation (1e-3 for PLUS's mm).
        clock_offset_s: server clock minus ours (s); None measures it from the stream.
        idle_timeout_s: a connection that delivers nothing for this long is taken as dead and
            reopened (s): long enough for PLUS to be quiet while every tool is out of view
            without the client reconnecting all the time, short enough to notice a hung server.
        future_tolerance_s: a pose stamped further than this ahead of our clock (plus the
            offset) is refused (s): two clocks a measured offset apart agree to the jitter of
            the stream's latency, a few ms on a LAN; 50 ms leaves room for it.
    """

    device_a: str = "ProbeAToTracker"
    device_b: str = "ProbeBToTracker"
    axis_column: int = 2
    axis_sign: float = 1.0
    position_scale_m: float = 1e-3
    clock_offset_s: float | None = None
    idle_timeout_s: float = 5.0
    future_tolerance_s: float = 0.05

    def __post_init__(self):
        if self.axis_column not in (0, 1, 2):
            raise ValueError(f"axis_column = {self.axis_column!r}: must be 0, 1 or 2")
        if self.axis_sign not in (1.0, -1.0):
            raise ValueError(f"axis_sign = {self.axis_sign!r}: must be +1 or -1")
        if not (math.isfinite(self.position_scale_m) and self.position_scale_m > 0):
            raise ValueError(f"position_scale_m = {self.position_scale_m!r}: must be finite and > 0")
        if self.device_a == self.device_b:
            raise ValueError(f"device_a = device_b = {self.device_a!r}: the probes need distinct names")
        for name in (self.device_a, self.device_b):
            if not name or len(name.encode("utf-8")) > 20:
                raise ValueError(f"device name {name!r}: must be 1 to 20 bytes (OpenIGTLink's limit)")
        if self.clock_offset_s is not None and not math.isfinite(self.clock_offset_s):
            raise ValueError(f"clock_offset_s = {self.clock_offset_s!r}: must be finite (or None to measure it)")
        if not (math.isfinite(self.idle_timeout_s) and self.idle_timeout_s > 0):
            raise ValueError(f"idle_timeout_s = {self.idle_timeout_s!r}: must be finite and > 0")
        if not (math.isfinite(self.future_tolerance_s) and self.future_tolerance_s >= 0):
            raise ValueError(f"future_tolerance_s = {self.future_tolerance_s!r}: must be finite and >= 0")


def settings_from_options(options: dict[str, str]) -> IgtlSettings:
    """:class:`IgtlSettings` from device-URL options (the keys of :data:`URL_KEYS`).

    ``igtl_probes=A,B`` (device names), ``igtl_axis=z`` (``x``, ``y``, ``z``, optionally signed,
    e.g. ``-z``), ``igtl_scale=mm`` (``mm``, ``cm``, ``m`` or metres per unit), ``igtl_clock=auto``
    (``auto`` measures the offset; a number is the server clock minus ours, s),
    ``igtl_timeout_s=5`` (idle time before reconnecting, s).

    Raises:
        ValueError: one line naming the key and its value.
    """
    settings = IgtlSettings()
    for key in URL_KEYS:
        if key not in options:
            continue
        try:
            settings = dataclasses.replace(settings, **_PARSERS[key](options[key].strip()))
        except ValueError as exc:
            raise ValueError(f"{key} = {options[key]!r}: {exc}") from None
    return settings


def _probes(text: str) -> dict:
    names = [n.strip() for n in text.split(",")]
    if len(names) != 2 or not all(names):
        raise ValueError("expected two device names, e.g. Probe1ToTracker,Probe2ToTracker")
    return dict(device_a=names[0], device_b=names[1])


def _axis(text: str) -> dict:
    text = text.lower()
    sign, letter = (-1.0, text[1:]) if text.startswith("-") else (1.0, text.removeprefix("+"))
    if letter not in _AXES:
        raise ValueError("expected x, y or z, optionally signed (e.g. -z)")
    return dict(axis_column=_AXES[letter], axis_sign=sign)


def _scale(text: str) -> dict:
    scale = _SCALES_M.get(text.lower())
    if scale is None:
        try:
            scale = float(text)
        except ValueError:
            raise ValueError("expected mm, cm, m or metres per unit (a number)") from None
    return dict(position_scale_m=scale)


def _clock(text: str) -> dict:
    if text.lower() == "auto":
        return dict(clock_offset_s=None)
    try:
        return dict(clock_offset_s=float(text))
    except ValueError:
        raise ValueError("expected auto or the server clock minus ours in seconds") from None


def _timeout(text: str) -> dict:
    try:
        return dict(idle_timeout_s=float(text))
    except ValueError:
        raise ValueError("expected seconds (a number)") from None


_PARSERS = {"igtl_probes": _probes, "igtl_axis": _axis, "igtl_scale": _scale, "igtl_clock": _clock,
            "igtl_timeout_s": _timeout}


class _ClockOffset:
    """Server clock minus ours (s), measured as the largest ``timestamp − arrival`` over the last
    ``window_s`` of messages: each difference is the offset minus that message's latency, so the
    largest is the offset minus the smallest latency; a sliding window follows a drifting clock."""

    def __init__(self, window_s: float = 5.0):
        self.window_s = window_s
        self._samples: collections.deque[tuple[float, float]] = collections.deque()  # (arrival, diff), diff falling
        self.offset_s: float | None = None

    def add(self, timestamp_s: float, arrival_s: float) -> None:
        diff = timestamp_s - arrival_s
        while self._samples and self._samples[-1][1] <= diff:
            self._samples.pop()
        self._samples.append((arrival_s, diff))
        while self._samples[0][0] < arrival_s - self.window_s:
            self._samples.popleft()
        self.offset_s = self._samples[0][1]

    def restart(self) -> None:
        """Forget the samples (a new connection may be a restarted server with another clock);
        the last offset stays until the first new message."""
        self._samples.clear()


class OpenIGTLinkSource:
    """Probe frames from an OpenIGTLink server (PLUS bridging the NDI tracker).

    A 5-DOF sensor has no roll, so only one column of its rotation is meaningful:
    ``axis_column`` (NDI: the z axis of the tool frame), times ``axis_sign``. PLUS sends only
    valid transforms by default, so a probe that leaves the field goes silent: the last reading
    stays and ages, and :func:`~twin.tracking.fuse_frame` rejects it as stale once it is older
    than ``max_age_s``. Timestamps are the server's clock; ``now_s`` of each frame is
    ``clock()`` plus the clock offset (given, or measured from the stream). A message stamped 0
    ("no time") is stamped with its arrival instead.

    The connection lives in a thread. It reconnects (backing off from 50 ms to 1 s, the wait
    reset only by a connection that delivered a pose) when the server closes it, when it
    breaks, or when nothing arrives for ``idle_timeout_s``; TCP
    keep-alive probes catch a peer that vanished without closing.

    Args:
        host, port: the OpenIGTLink server (PLUS default port 18944).
        settings: names, conventions and clock; the keyword arguments below override it.
        device_a, device_b, axis_column, position_scale_m: as in :class:`IgtlSettings`.
        clock: our current time (s), default :func:`time.time` (OpenIGTLink stamps Unix time).

    Use as a context manager, or call :meth:`close`, to stop the thread.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 18944,
        *,
        settings: IgtlSettings | None = None,
        clock: Callable[[], float] = time.time,
        **overrides,
    ):
        settings = settings if settings is not None else IgtlSettings()
        self.settings = dataclasses.replace(settings, **overrides) if overrides else settings
        self.host, self.port = host, int(port)
        self.devices = (self.settings.device_a, self.settings.device_b)
        self._clock = clock
        self._offset = _ClockOffset()
        self._lock = threading.Lock()
        self._latest = {name: ProbeReading.missing() for name in self.devices}
        self._connected = False
        self._stop = threading.Event()
        self._socket: socket.socket | None = None
        self.messages = 0  # messages received
        self.bad_messages = 0  # CRC mismatches and undecodable bodies
        self.connections = 0  # successful connects (1 + reconnects)
        self.refused_poses = 0  # pose messages refused: not finite, not a rotation, from the future
        self._delivered = False
        self._thread = threading.Thread(target=self._run, name=f"igtl-client {host}:{port}", daemon=True)
        self._thread.start()

    # --------------------------------------------------------------------------- public
    @property
    def axis_column(self) -> int:
        return self.settings.axis_column

    @property
    def position_scale_m(self) -> float:
        return self.settings.position_scale_m

    @property
    def clock_offset_s(self) -> float:
        """Server clock minus ours (s): the given one, else the measured one (0 before any message)."""
        if self.settings.clock_offset_s is not None:
            return self.settings.clock_offset_s
        return self._offset.offset_s or 0.0

    @property
    def connected(self) -> bool:
        """True while the thread has a live connection (one that delivered within the idle timeout)."""
        return self._connected

    def read(self) -> ProbeFrame:
        """The newest reading of each probe (invalid until its first message) and ``now_s`` in the
        server's clock."""
        with self._lock:
            probe_a, probe_b = (self._latest[name] for name in self.devices)
        return ProbeFrame(probe_a, probe_b, self._clock() + self.clock_offset_s)

    def close(self) -> None:
        """Stop the thread and close its socket."""
        self._stop.set()
        sock = self._socket
        if sock is not None:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self._thread.join(timeout=2.0)

    def __enter__(self) -> "OpenIGTLinkSource":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --------------------------------------------------------------------------- thread
    def _run(self) -> None:
        # The wait grows after every connection that ends without delivering a pose, whether the
        # connect failed or the server accepted and closed: a server that hangs up at once is not
        # hammered (it was, ~1,400 connects a second, when only failed connects backed off).
        backoff_s = 0.05
        while not self._stop.is_set():
            delivered = False
            try:
                sock = socket.create_connection((self.host, self.port), timeout=1.0)
            except OSError:
                sock = None
            if sock is not None:
                self._socket = sock
                try:
                    delivered = self._serve(sock)
                except OSError:
                    pass
                finally:
                    delivered = delivered or self._delivered
                    self._connected = False
                    self._socket = None
                    sock.close()
            if delivered:
                backoff_s = 0.05
            self._stop.wait(backoff_s)
            backoff_s = min(2 * backoff_s, 1.0)

    def _serve(self, sock: socket.socket) -> bool:
        """Read messages until the connection ends, breaks or idles past the timeout.

        Only the bodies of messages this client reads (TRANSFORM and POSITION of its probes, at
        most :data:`MAX_POSE_BODY_BYTES`) are kept and CRC-checked; any other body is passed
        over as it arrives, never held in memory. Returns whether a pose was taken."""
        _keepalive(sock)
        sock.settimeout(0.1)
        self._offset.restart()
        self._delivered = False
        self.connections += 1
        self._connected = True
        buffer = bytearray()
        skip = 0  # bytes of a body being passed over
        last_rx = time.monotonic()
        while not self._stop.is_set():
            try:
                chunk = sock.recv(65536)
            except socket.timeout:
                if time.monotonic() - last_rx > self.settings.idle_timeout_s:
                    return self._delivered
                continue
            if not chunk:
                return self._delivered  # the server closed the connection
            last_rx = time.monotonic()
            if skip:
                taken = min(skip, len(chunk))
                skip -= taken
                chunk = chunk[taken:]
            buffer += chunk
            while not skip and len(buffer) >= igtl.HEADER_SIZE:
                header = bytes(buffer[:igtl.HEADER_SIZE])
                try:
                    _, type_, device, timestamp_s, size, _ = igtl.unpack_header(header)
                except igtl.MessageError:
                    self.bad_messages += 1
                    return self._delivered  # no way to find the next header in a foreign stream: start afresh
                wanted = type_ in ("TRANSFORM", "POSITION") and device in self._latest
                if not wanted or size > MAX_POSE_BODY_BYTES:
                    if wanted:
                        self.bad_messages += 1  # a pose message no sender makes this large
                    else:
                        self.messages += 1
                        if timestamp_s > 0:
                            self._offset.add(timestamp_s, self._clock())
                    taken = min(igtl.HEADER_SIZE + size, len(buffer))
                    skip = igtl.HEADER_SIZE + size - taken
                    del buffer[:taken]
                    continue
                end = igtl.HEADER_SIZE + size
                if len(buffer) < end:
                    break
                body = bytes(buffer[igtl.HEADER_SIZE:end])
                del buffer[:end]
                self._handle(header, body)
        return self._delivered

    def _handle(self, header: bytes, body: bytes) -> None:
        arrival_s = self._clock()
        try:
            message = igtl.decode(header, body)
        except igtl.MessageError:
            self.bad_messages += 1
            return
        self.messages += 1
        if message.timestamp_s > 0:
            self._offset.add(message.timestamp_s, arrival_s)
        if message.device not in self._latest or message.type not in ("TRANSFORM", "POSITION"):
            return
        try:
            pose = igtl.decode_pose(message)
        except igtl.MessageError:
            self.bad_messages += 1
            return
        if pose.rotation is None:
            return  # a position without orientation has no probe axis: nothing a 5-DOF fusion can use
        timestamp_s = message.timestamp_s if message.timestamp_s > 0 else arrival_s + self.clock_offset_s
        if timestamp_s > arrival_s + self.clock_offset_s + self.settings.future_tolerance_s:
            # From the future of our clock: a wrong offset or a forged stamp; taken, it would
            # pass every staleness check for as long as it is ahead.
            self.bad_messages += 1
            self.refused_poses += 1
            return
        if message.metadata.get("TransformStatus", "OK").upper() != "OK":
            reading = ProbeReading(np.full(3, np.nan), np.full(3, np.nan), timestamp_s, valid=False)
        elif not _is_pose(pose):
            # Not a pose (a NaN, or a "rotation" that is not one): the probe is unknown now,
            # not where it was.
            self.bad_messages += 1
            self.refused_poses += 1
            reading = ProbeReading(np.full(3, np.nan), np.full(3, np.nan), timestamp_s, valid=False)
        else:
            s = self.settings
            reading = ProbeReading(pose.translation * s.position_scale_m,
                                   s.axis_sign * pose.rotation[:, s.axis_column], timestamp_s)
            self._delivered = True
        with self._lock:
            self._latest[message.device] = reading


# A rotation sent as float32 is orthonormal to ~1e-7; 1e-3 also passes one PLUS composed from
# several float32 transforms, and refuses anything that is not a rotation at all.
_ROTATION_TOLERANCE = 1e-3
# The largest pose message body read (TRANSFORM is 48 bytes, POSITION at most 28, pyigtl's
# POSITION 152 per element; version 2 adds the extended header and metadata): a larger one is
# counted bad and passed over unread.
MAX_POSE_BODY_BYTES = 64 * 1024


def _is_pose(pose: igtl.Pose) -> bool:
    """Finite translation and a proper rotation (orthonormal, determinant +1, within float32 rounding)."""
    r = pose.rotation
    if r is None or not (np.isfinite(pose.translation).all() and np.isfinite(r).all()):
        return False
    return bool(np.abs(r.T @ r - np.eye(3)).max() < _ROTATION_TOLERANCE and np.linalg.det(r) > 0)


def _keepalive(sock: socket.socket) -> None:
    """TCP keep-alive probing after 1 s idle, every 1 s, 3 misses: a vanished peer ends the
    connection within ~4 s even while the server is allowed to be silent."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    for name, value in (("TCP_KEEPIDLE", 1), ("TCP_KEEPINTVL", 1), ("TCP_KEEPCNT", 3)):
        option = getattr(socket, name, None)
        if option is not None:
            sock.setsockopt(socket.IPPROTO_TCP, option, value)
