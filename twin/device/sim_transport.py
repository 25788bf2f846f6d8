"""``sim://``: the emulated board in this process, in simulated time, as fast as possible.

Bytes pass in memory through the same codec as on the wire. Time stands still between calls:
it advances only while the host waits (``Device.wait``, ``Device.wait_next``, a command
awaiting its answer), one 5 ms board tick at a time, and while it does the transport sends the
keepalive PINGs a live host would, at the same simulated instants every run. With the same
seed, parameters and calls a run is therefore repeated exactly. Since no simulated time passes
outside the host's waits, no PING falls due there: :meth:`SimTransport.ping_if_due` and
:meth:`SimTransport.attended` have nothing to send.
"""

from __future__ import annotations

import contextlib
import math
from typing import Callable, ContextManager

from twin.device.board import EmulatedBoard, Reason
from twin.driver.inbox import Inbox
from twin.driver.transport import Clock, Transport
from twin.sim.events import EventSchedule

__all__ = ["SimTransport"]


class SimTransport(Transport):
    """A transport to an :class:`EmulatedBoard` stepped in simulated time.

    The board lives as long as the transport (a board that stays powered): closing and
    reconnecting does not reset it.

    Args:
        board: the emulated board.
        url: the device URL, for messages.
        schedule: hidden events applied to the plant as its time passes (``sim://?events=FILE``),
            each at the first tick boundary at or after its time; None for none.
    """

    clock = Clock.SIMULATED

    def __init__(self, board: EmulatedBoard, *, url: str = "sim://", schedule: EventSchedule | None = None):
        self.board = board
        self.url = url
        self.schedule = schedule
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
        # Whole ticks: a wait ends at the first tick boundary at or after the deadline. Bytes
        # reach the inbox only in _deliver, so the predicate cannot change while the board ticks.
        board = self.board
        deadline_s = board.time_s + timeout_s - 1e-9
        while not predicate():
            if board.time_s >= deadline_s:
                return False
            if self._run(deadline_s) == Reason.KEEPALIVE and self._ping is not None:
                # The PING, then the tick it came before.
                self._ping()
                self._run(deadline_s, max_ticks=1)
        return True

    def time_s(self) -> float:
        return self.board.time_s

    def keep_alive(self, period_s: float | None, ping: Callable[[], None]) -> None:
        self._keepalive_s, self._ping = period_s, ping

    def ping_if_due(self) -> None:
        pass

    def attended(self) -> ContextManager[None]:
        return contextlib.nullcontext()

    def close(self) -> None:
        self._inbox = None
        self._keepalive_s = None

    def _run(self, deadline_s: float, max_ticks: int = 1 << 20) -> Reason:
        """Ticks up to the deadline, the keepalive or bytes for the host; bytes are delivered
        and their tick finished."""
        board = self.board
        schedule = self.schedule
        if schedule is not None:
            schedule.apply_due(board.plant)
            # Board time of the next event: the ticks stop there so that it happens on time.
            deadline_s = min(deadline_s, schedule.next_time_s - (board.plant.time_s - board.time_s))
        reason = board.run(deadline_s=deadline_s, last_write_s=self._last_write_s, keepalive_s=self._keepalive_s,
                           max_ticks=max_ticks)
        if reason == Reason.TX:
            self._deliver()
            board.run(resume=True)
        return reason

    def _deliver(self) -> None:
        data = self.board.take_tx()
        if data and self._inbox is not None:
            self._inbox.feed(data)
