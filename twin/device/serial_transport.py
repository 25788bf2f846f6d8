"""``serial://``: a board on a serial port (the Teensy's USB CDC, or a pseudo-terminal), in
wall-clock time.

A reader thread hands bytes to the inbox as they arrive; a keepalive thread sends a PING
whenever the host has written nothing for the keepalive period, so the board's watchdog stays
fed as long as this process runs; waits are real sleeps. When the port fails (board
unplugged, pseudo-terminal closed) the inbox is told and every later call raises
:class:`DeviceDisconnected`; :meth:`twin.device.Device.reconnect` opens the port again.
"""

from __future__ import annotations

import threading
import time
from typing import Callable

import serial

from twin.device.errors import DeviceDisconnected, DeviceError
from twin.device.inbox import Inbox
from twin.device.transport import Transport

__all__ = ["SerialTransport"]

# How long a blocked read waits before checking whether the transport is closing (s).
_READ_POLL_S = 0.05
# How often a port that is not there yet is tried again while opening (s).
_OPEN_RETRY_S = 0.1


class SerialTransport(Transport):
    """A transport over a serial port.

    Args:
        port: device path, e.g. ``/dev/ttyACM0`` or a pseudo-terminal such as ``/dev/pts/4``.
        url: the device URL, for messages.
    """

    clock = "wall"

    def __init__(self, port: str, *, url: str | None = None):
        self.port = port
        self.url = url or f"serial://{port}"
        self._serial: serial.Serial | None = None
        self._inbox: Inbox | None = None
        self._write_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._last_write_s = time.monotonic()

    def open(self, inbox: Inbox, *, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                # exclusive: a second host on the same board would interleave commands.
                port = serial.Serial(self.port, baudrate=115200, timeout=_READ_POLL_S, exclusive=True)
                break
            except (serial.SerialException, OSError) as exc:
                if time.monotonic() >= deadline:
                    raise DeviceError(f"{self.url}: cannot open {self.port} ({exc})") from exc
                time.sleep(_OPEN_RETRY_S)
        self._serial, self._inbox = port, inbox
        self._stop.clear()
        self._last_write_s = time.monotonic()
        self._start(self._read_loop, "reader")

    def write(self, data: bytes) -> None:
        with self._write_lock:
            if self._serial is None:
                raise DeviceDisconnected(f"{self.url}: not connected")
            try:
                self._serial.write(data)
            except (serial.SerialException, OSError) as exc:
                error = DeviceDisconnected(f"{self.url}: write failed, the board is gone ({exc})")
                self._inbox.lost(error)
                raise error from exc
            self._last_write_s = time.monotonic()

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        with self._inbox.condition:
            return self._inbox.condition.wait_for(predicate, timeout=max(0.0, timeout_s))

    def time_s(self) -> float:
        return time.monotonic()

    def keep_alive(self, period_s: float | None, ping: Callable[[], None]) -> None:
        if period_s is None:
            return

        def loop() -> None:
            # Checking twice per period keeps the longest silence under 1.5 periods.
            while not self._stop.wait(period_s / 2):
                if time.monotonic() - self._last_write_s >= period_s:
                    try:
                        ping()
                    except DeviceError:
                        return

        self._start(loop, "keepalive")

    def close(self) -> None:
        self._stop.set()
        port, self._serial = self._serial, None
        if port is not None:
            port.cancel_read()
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join()
        self._threads.clear()
        if port is not None:
            port.close()

    def _start(self, target: Callable[[], None], name: str) -> None:
        thread = threading.Thread(target=target, name=f"{name} {self.port}", daemon=True)
        self._threads.append(thread)
        thread.start()

    def _read_loop(self) -> None:
        port, inbox = self._serial, self._inbox
        while not self._stop.is_set():
            try:
                data = port.read(max(1, port.in_waiting))
            except (serial.SerialException, OSError) as exc:
                if not self._stop.is_set():
                    inbox.lost(DeviceDisconnected(f"{self.url}: the board is gone ({exc})"))
                return
            if data:
                inbox.feed(data)
