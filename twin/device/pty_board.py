"""The emulated board behind a pseudo-terminal or a TCP port, in wall-clock time: a rig without the rig.

:class:`PtyBoard` runs an :class:`twin.device.board.EmulatedBoard` (the real firmware core and
the MuJoCo plant) in a background thread, one 5 ms tick per 5 ms of wall-clock time, and
exposes one end of an ``os.openpty()`` pair in raw mode. ``serial://<port>`` on that end goes
through the real serial driver, protocol and PID. With ``tcp=(host, port)`` the board listens
there instead and ``socket://host:port`` reaches it over the network, one host at a time (as
ser2net serves a rig's port in raw mode; a second connection is closed at once). Host bytes are handed to the firmware as
they arrive (commands are answered at once, as on the Teensy); board bytes are written after
each tick and each command.

:meth:`PtyBoard.unplug` makes the board disappear as an unplugged USB cable does (the host's
port fails), and :meth:`PtyBoard.plug` brings it back powered up afresh on the same plant. A
new pseudo-terminal may get another name, so pass ``link_path`` for a stable name (a symbolic
link re-pointed on each plug, like udev's ``/dev/serial/by-id`` links) to reconnect to.

Code in the same process acts on the plant between two ticks through :meth:`PtyBoard.call`
and follows every tick through :attr:`PtyBoard.tick_hooks` (both run in the board's thread, so
they never see a half-stepped plant); that is how :class:`twin.device.emulated_rig.EmulatedRig`
adds the rig's tracker (OpenIGTLink) and an automatic fixture. Reading ``board.plant`` from
another thread is allowed for display, bearing in mind the board's thread is stepping it.
"""

from __future__ import annotations

import math
import os
import queue
import select
import socket
import threading
import time
import tty
from pathlib import Path
from typing import Any, Callable

from twin.device.board import TICK_S, EmulatedBoard
from twin.params import Params

__all__ = ["PtyBoard"]

# Behind by more than this, the board stops catching up with the wall clock and skips ahead
# (counted in ``overruns``): a board that ran late for a moment must not then run fast.
_MAX_LAG_S = 0.1


class PtyBoard:
    """An emulated board on a pseudo-terminal.

    Args:
        params: parameter set of the plant (default ``models/endoscope/endoscope.toml``).
        seed: seed of the plant's sensor noise.
        base_rotation: clamp orientation (default the parameter set's ``rig.base_quat``).
        link_path: optional path of a symbolic link to the current port.
        tcp: ``(host, port)`` to serve on a TCP port instead of a pseudo-terminal (port 0 picks
            a free one: see :attr:`port`).

    Attributes:
        board: the :class:`EmulatedBoard` (its ``plant`` is the twin behind the port).
        ticks: board ticks run so far.
        overruns: times the board fell more than 0.1 s behind the wall clock and skipped ahead.
        tx_dropped_bytes: bytes not written because nobody read the port and its buffer was full.
        tick_hooks: callables run in the board's thread after every tick (an exception in one
            stops the board, as :attr:`error`).
        error: what stopped the board's thread (the simulation diverged, say), or None while
            it runs: the port then stays open but silent, as a board that hung.
    """

    def __init__(
        self,
        params: Params | None = None,
        *,
        seed: int = 0,
        base_rotation=None,
        link_path: str | os.PathLike | None = None,
        tcp: tuple[str, int] | None = None,
    ):
        if tcp is not None and link_path is not None:
            raise ValueError(f"link_path = {str(link_path)!r}: a board on a TCP port has no device file to link to")
        self.board = EmulatedBoard(params, seed=seed, base_rotation=base_rotation)
        self.link_path = Path(link_path) if link_path is not None else None
        self.ticks = 0
        self.overruns = 0
        self.tx_dropped_bytes = 0
        self.error: BaseException | None = None
        self._fds: tuple[int, int] | None = None
        self.tcp = tcp
        self._listener: socket.socket | None = None
        self._client: socket.socket | None = None
        self._device_path = ""
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._powered_before = False
        self._calls: queue.SimpleQueue = queue.SimpleQueue()
        self.tick_hooks: list[Callable[[], None]] = []

    @property
    def port(self) -> str:
        """What a host opens: ``link_path`` if given, else the pseudo-terminal itself, or the
        ``host:port`` the board listens on."""
        return str(self.link_path) if self.link_path is not None else self._device_path

    @property
    def url(self) -> str:
        return f"{'socket' if self.tcp is not None else 'serial'}://{self.port}"

    @property
    def plugged(self) -> bool:
        return self._thread is not None

    def plug(self) -> str:
        """Open a pseudo-terminal and start the board; returns the port.

        After an :meth:`unplug` the firmware powers up afresh (disabled, no handshake); the
        plant keeps its state.
        """
        if self.plugged:
            return self.port
        if self._powered_before:
            self.board.power_cycle()
        self._powered_before = True
        if self.tcp is not None:
            self._listen(self.tcp)
        else:
            self._open_pty()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"PtyBoard {self._device_path}", daemon=True)
        self._thread.start()
        return self.port

    def _listen(self, address: tuple[str, int]) -> None:
        listener = socket.create_server(address)
        listener.setblocking(False)
        self._listener = listener
        host, port = listener.getsockname()[:2]
        self._device_path = f"{host}:{port}"

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        # The slave end is the host's; raw mode there, or the line discipline echoes and
        # mangles bytes before the host's driver has set the port up.
        tty.setraw(slave)
        os.set_blocking(master, False)
        # Holding the slave open keeps the master readable between hosts (no EIO when a host
        # closes its end).
        self._fds = (master, slave)
        self._device_path = os.ttyname(slave)
        if self.link_path is not None:
            # Made in one step that fails if anything is at the path (no temporary beside it, no
            # rename over it): what someone else put there, even a moment ago, is never lost.
            try:
                os.symlink(self._device_path, self.link_path)
            except FileExistsError:
                for fd in self._fds:
                    os.close(fd)
                self._fds = None
                raise ValueError(f"link {self.link_path}: already exists; not replacing it "
                                 "(remove it or choose another path)") from None

    def unplug(self) -> None:
        """Stop the board and close the pseudo-terminal: the host's port fails as when a USB
        cable is pulled. The link (if any) is removed."""
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join()
        self._thread = None
        if self.tcp is not None:
            self._drop_client()
            listener, self._listener = self._listener, None
            if listener is not None:
                listener.close()
            return
        for fd in self._fds or ():
            os.close(fd)
        self._fds = None
        if self.link_path is not None and self.link_path.is_symlink() and \
                os.readlink(self.link_path) == self._device_path:
            self.link_path.unlink()  # only the link made here: whatever replaced it is not ours to remove

    def call(self, function: Callable[[], object], *, timeout_s: float = 5.0) -> object:
        """Run ``function()`` in the board's thread between two ticks and return its result (or
        raise its exception here).

        Raises:
            RuntimeError: the board is not running (unplugged, or its thread stopped).
            TimeoutError: the board's thread did not get to it within ``timeout_s`` (wall s).
        """
        if not self.plugged or self.error is not None:
            raise RuntimeError(f"{self.port or 'the emulated board'}: the board is not running")
        done = threading.Event()
        box: dict[str, Any] = {}

        def job():
            try:
                box["value"] = function()
            except Exception as exc:  # noqa: BLE001 - handed to the caller
                box["error"] = exc
            finally:
                done.set()

        self._calls.put(job)
        if not done.wait(timeout_s):
            raise TimeoutError(f"{self.port}: the board's thread did not run the call within {timeout_s:g} s")
        if "error" in box:
            raise box["error"]
        return box.get("value")

    def wait_board_s(self, duration_s: float) -> None:
        """Return once the board has run ``duration_s`` of its own time (whole ticks) from now, or
        has stopped."""
        target = self.ticks + math.ceil(duration_s / TICK_S - 1e-9)
        while self.ticks < target and self.plugged and self.error is None:
            time.sleep(TICK_S)

    def close(self) -> None:
        """Unplug and free the firmware."""
        self.unplug()
        self.board.close()

    def __enter__(self) -> "PtyBoard":
        self.plug()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _run(self) -> None:
        try:
            self._serve()
        except Exception as exc:  # noqa: BLE001 - kept for the owner to report; the thread ends here
            self.error = exc

    def _serve(self) -> None:
        next_tick_s = time.monotonic()
        while not self._stop.is_set():
            if self._fds is not None:
                watched: list = [self._fds[0]]
            else:
                watched = [self._listener] + ([self._client] if self._client is not None else [])
            ready, _, _ = select.select(watched, [], [], max(0.0, next_tick_s - time.monotonic()))
            if self._listener is not None and self._listener in ready:
                self._accept(self._listener)
            if self._client in ready or (self.tcp is None and ready):
                self.board.receive(self._read())
                self._write(self.board.take_tx())
            now_s = time.monotonic()
            if now_s < next_tick_s:
                continue
            self._write(self.board.run_tick())
            self.ticks += 1
            for hook in self.tick_hooks:
                hook()
            while True:
                try:
                    job = self._calls.get_nowait()
                except queue.Empty:
                    break
                job()
            next_tick_s += TICK_S
            if now_s - next_tick_s > _MAX_LAG_S:
                next_tick_s = now_s
                self.overruns += 1

    def _accept(self, listener: socket.socket) -> None:
        connection, _ = listener.accept()
        if self._client is not None:
            connection.close()  # one host at a time, as a serial port opened exclusively
            return
        connection.setblocking(False)
        # Frames are a few bytes: sent as they are made, not held back to fill a segment.
        connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._client = connection

    def _drop_client(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            client.close()

    def _read(self) -> bytes:
        if self._fds is not None:
            try:
                return os.read(self._fds[0], 4096)
            except BlockingIOError:
                return b""
        if self._client is None:
            return b""
        try:
            data = self._client.recv(4096)
        except BlockingIOError:
            return b""
        except OSError:
            data = b""
        if not data:
            self._drop_client()  # the host hung up; the board runs on, as the rig does
        return data

    def _write(self, data: bytes) -> None:
        while data:
            try:
                if self._fds is not None:
                    written = os.write(self._fds[0], data)
                elif self._client is None:
                    raise BlockingIOError
                else:
                    written = self._client.send(data)
            except BlockingIOError:
                # Nobody reads the port: drop, as a USB serial device does without a host.
                self.tx_dropped_bytes += len(data)
                return
            except OSError:
                if self.tcp is None:
                    raise
                self._drop_client()  # the host is gone
                self.tx_dropped_bytes += len(data)
                return
            data = data[written:]
