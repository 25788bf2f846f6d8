"""``sim://``: the emulated board in this process, in simulated time, as fast as possible.

Bytes pass in memory through the same codec as on the wire. Time stands still between calls:
it advances only while the host waits (``Device.wait``, ``Device.wait_next``, a command
awaiting its answer), one 5 ms board tick at a time, and while it does the transport sends the
keepalive PINGs a live host would, at the same simulated instants every run. With the same
seed, parameters and calls a run is therefore repeated exactly.
"""

from __future__ import annotations

import math
from typing import Callable

from twin.device import board_loop
from twin.device.board import TICK_S, EmulatedBoard
from twin.device.board_loop import BoardLoop, Reason
from twin.device.inbox import Inbox
from twin.device.transport import Transport

__all__ = ["SimTransport"]


class SimTransport(Transport):
    """A transport to an :class:`EmulatedBoard` stepped in simulated time.

    The board lives as long as the transport (a board that stays powered): closing and
    reconnecting does not reset it.

    Args:
        board: the emulated board.
        url: the device URL, for messages.
    """

    clock = "simulated"

    def __init__(self, board: EmulatedBoard, *, url: str = "sim://", native_loop: bool = True):
        self.board = board
        self.url = url
        # The ticks in native code where they need no Python (twin.device.board_loop).
        self._loop = BoardLoop(board) if native_loop and board_loop.available() else None
        self._inbox: Inbox | None = None
        self._keepalive_s: float | None = None
        self._ping: Callable[[], None] | None = None
        self._last_write_s = -math.inf

    def open(self, inbox: Inbox, *, timeout_s: float) -> None:
        self._inbox = inbox
        self._deliver()

    def write(self, data: bytes) -> None:
        self.board.receive(data)
        self._last_write_s = self.board.time_s
        self._deliver()

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        # Whole ticks: a wait ends at the first tick boundary at or after the deadline.
        deadline_s = self.board.time_s + timeout_s - 1e-9
        while not predicate():
            if self.board.time_s >= deadline_s:
                return False
            if self._loop is not None and self._loop.usable(TICK_S):
                self._run_native(deadline_s)
            else:
                self._step()
        return True

    def time_s(self) -> float:
        return self.board.time_s

    def keep_alive(self, period_s: float | None, ping: Callable[[], None]) -> None:
        self._keepalive_s, self._ping = period_s, ping

    def close(self) -> None:
        self._inbox = None
        self._keepalive_s = None

    def _step(self) -> None:
        if self._keepalive_s is not None and self.board.time_s - self._last_write_s >= self._keepalive_s - 1e-9:
            self._ping()
        self.board.tick()
        self._deliver()
        self.board.advance()

    def _run_native(self, deadline_s: float) -> None:
        """Ticks in native code up to the first that needs Python, then the rest of that tick
        as :meth:`_step` would do it (or, before a tick, the noise refill). Bytes reach the
        inbox only in :meth:`_deliver`, so the wait's predicate cannot change during the
        native ticks."""
        board, loop = self.board, self._loop
        reason = loop.run(deadline_s, self._last_write_s, self._keepalive_s)
        if reason == Reason.TX:
            # Deliver, then the tick's advance natively.
            self._deliver()
            reason = loop.run(deadline_s, self._last_write_s, self._keepalive_s, resume=True)
        if reason in (Reason.DEADLINE, Reason.DONE):
            return
        if reason == Reason.KEEPALIVE:
            self._step()
        elif reason == Reason.APPLY:
            board._apply(*loop.outputs())
            self._deliver()
            board.advance()
        elif reason == Reason.WARNING:
            board.plant._end_chunk()
        elif reason == Reason.NOISE:
            board.plant._noise.refill()
        else:
            raise RuntimeError(f"board loop returned {reason!r}")

    def _deliver(self) -> None:
        data = self.board.take_tx()
        if data and self._inbox is not None:
            self._inbox.feed(data)
