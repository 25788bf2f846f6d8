"""A board on a serial port, in wall-clock time: ``serial://`` (the Teensy's USB CDC, or a
pseudo-terminal), or a port over the network, ``socket://`` (raw TCP) and ``rfc2217://``, all
opened by pyserial's ``serial_for_url``.

A reader thread hands bytes to the inbox as they arrive; waits are real sleeps. The keepalive
PINGs are sent by the host's own calls: a wait sends those that fall due while it sleeps, a
call that does not wait sends one if it is due (:meth:`SerialTransport.ping_if_due`). No
thread feeds the watchdog behind the host's back, so a host whose control loop hangs, or a
process that dies, stops the rig within the watchdog timeout.

When the port fails (board unplugged, pseudo-terminal closed), or the reader thread stops for
any other reason, the inbox is told and every later call raises :class:`DeviceDisconnected`
naming the cause; :meth:`twin.driver.Device.reconnect` opens the port again.
"""

from __future__ import annotations

import contextlib
import threading
import time
from typing import Callable, Iterator

import serial

from twin.driver.errors import DeviceDisconnected, DeviceError
from twin.driver.inbox import Inbox
from twin.driver.transport import Clock, Transport

__all__ = ["SerialTransport"]

# How long a blocked read waits before checking whether the transport is closing (s).
_READ_POLL_S = 0.05
# How often a port that is not there yet is tried again while opening (s).
_OPEN_RETRY_S = 0.1
# Longest a write may block (s). The host writes frames of at most 39 bytes, so a port that
# takes this long to accept them belongs to a board that no longer reads: it is gone.
_WRITE_TIMEOUT_S = 0.5


class SerialTransport(Transport):
    """A transport over a serial port.

    Args:
        port: what ``serial.serial_for_url`` opens: a device path, e.g. ``/dev/ttyACM0`` or a
            pseudo-terminal such as ``/dev/pts/4``, or a pyserial URL such as
            ``socket://127.0.0.1:7000`` or ``rfc2217://host:port``.
        url: the device URL, for messages.
    """

    clock = Clock.WALL

    def __init__(self, port: str, *, url: str | None = None):
        self.port = port
        self.url = url or f"serial://{port}"
        self._serial: serial.Serial | None = None
        self._inbox: Inbox | None = None
        self._write_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._last_write_s = time.monotonic()
        self._keepalive_s: float | None = None
        self._ping: Callable[[], None] | None = None

    def open(self, inbox: Inbox, *, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                # exclusive: a second host on the same board would interleave commands.
                port = serial.serial_for_url(self.port, baudrate=115200, timeout=_READ_POLL_S, exclusive=True,
                                             do_not_open=True)
                # pyserial's RFC 2217 client refuses a write timeout (3.5); its writes go to a TCP
                # socket, which a board that stops reading fills only after kilobytes.
                if not self.port.startswith("rfc2217://"):
                    port.write_timeout = _WRITE_TIMEOUT_S
                port.open()
                break
            except (serial.SerialException, OSError) as exc:
                if time.monotonic() >= deadline:
                    raise DeviceError(f"{self.url}: cannot open {self.port} ({exc})") from exc
                time.sleep(_OPEN_RETRY_S)
        self._serial, self._inbox = port, inbox
        self._stop.clear()
        self._last_write_s = time.monotonic()
        self._keepalive_s = self._ping = None
        self._start(self._read_loop, "reader")

    def write(self, data: bytes) -> None:
        with self._write_lock:
            if self._serial is None:
                raise DeviceDisconnected(f"{self.url}: not connected")
            try:
                self._serial.write(data)
                error = None
            except (serial.SerialException, OSError) as exc:
                error, cause = DeviceDisconnected(f"{self.url}: write failed, the board is gone ({exc})"), exc
            else:
                self._last_write_s = time.monotonic()
        if error is not None:
            # Outside the lock: whoever is told of the loss may want to write.
            if self._inbox is not None:
                self._inbox.lost(error, writable=False)
            raise error from cause

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        if self._inbox is None:
            raise DeviceDisconnected(f"{self.url}: not connected")
        condition = self._inbox.condition
        deadline_s = time.monotonic() + max(0.0, timeout_s)
        keepalive_s = self._keepalive_s
        while True:
            wake_s = deadline_s if keepalive_s is None else min(deadline_s, self._last_write_s + keepalive_s)
            with condition:
                if condition.wait_for(predicate, timeout=max(0.0, wake_s - time.monotonic())):
                    return True
            if time.monotonic() >= deadline_s:
                return False
            # Not under the condition: the reader must go on delivering while the PING is written.
            if not self._ping_if_due():
                keepalive_s = None  # the PING failed: the loss is in the inbox, no more this wait

    def time_s(self) -> float:
        return time.monotonic()

    def keep_alive(self, period_s: float | None, ping: Callable[[], None]) -> None:
        self._keepalive_s, self._ping = period_s, ping

    def ping_if_due(self) -> None:
        self._ping_if_due()

    @contextlib.contextmanager
    def attended(self) -> Iterator[None]:
        period_s = self._keepalive_s
        if period_s is None:
            yield
            return
        done = threading.Event()

        def loop() -> None:
            # Checking twice per period keeps the longest silence under 1.5 periods.
            while not done.wait(period_s / 2) and self._ping_if_due():
                pass

        thread = threading.Thread(target=loop, name=f"attended {self.port}", daemon=True)
        thread.start()
        try:
            yield
        finally:
            done.set()
            thread.join()

    def close(self) -> None:
        self._stop.set()
        self._keepalive_s = self._ping = None
        port, self._serial = self._serial, None
        # A local port's blocked read returns at once; a network port has no cancel_read, and
        # its reader notices the stop within one read timeout.
        cancel_read = getattr(port, "cancel_read", None)
        if cancel_read is not None:
            cancel_read()
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join()
        self._threads.clear()
        if port is not None:
            port.close()

    def _ping_if_due(self) -> bool:
        """Send the PING if one is due; False if it failed (the inbox holds the loss, and the
        host's next wait or command raises it)."""
        period_s, ping = self._keepalive_s, self._ping
        if period_s is None or ping is None or time.monotonic() - self._last_write_s < period_s:
            return True
        try:
            ping()
        except DeviceError:
            return False
        return True

    def _start(self, target: Callable[[], None], name: str) -> None:
        thread = threading.Thread(target=target, name=f"{name} {self.port}", daemon=True)
        self._threads.append(thread)
        thread.start()

    def _read_loop(self) -> None:
        port, inbox = self._serial, self._inbox
        if port is None or inbox is None:
            return  # started by open(), which sets both
        try:
            while not self._stop.is_set():
                try:
                    data = port.read(max(1, port.in_waiting))
                except (serial.SerialException, OSError) as exc:
                    if not self._stop.is_set():
                        inbox.lost(DeviceDisconnected(f"{self.url}: the board is gone ({exc})"))
                    return
                if data:
                    inbox.feed(data)
        except BaseException as exc:
            # Data cannot get here (the inbox counts and skips it); whatever does, the host is
            # deaf from now on and must say so rather than time out.
            inbox.lost(DeviceDisconnected(f"{self.url}: the host's reader thread stopped ({exc!r})"))
            if not isinstance(exc, Exception):
                raise
