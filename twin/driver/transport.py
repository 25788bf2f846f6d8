"""How bytes and time reach a board: the interface :class:`twin.driver.Device` talks through.

Two kinds exist and differ in their clock:

* ``"wall"`` (:class:`twin.driver.serial_transport.SerialTransport`): the board runs on its
  own; a reader thread hands received bytes to the inbox as they arrive, and waiting is
  sleeping.
* ``"simulated"`` (:class:`twin.device.sim_transport.SimTransport`): the board is emulated in
  this process and time stands still unless the host waits; waiting steps the board, and
  bytes are delivered as they are produced.

Either way the keepalive PINGs that feed the board's watchdog go out only from the host's own
calls — while it waits, or when it calls in without waiting — never from a thread of their
own: the watchdog then trips when the host's control loop stops making progress, whatever
else in the process is still running.
"""

from __future__ import annotations

import abc
import enum
from typing import Callable, ContextManager

from twin.driver.inbox import Inbox

__all__ = ["Clock", "Transport"]


class Clock(enum.StrEnum):
    """How a transport's time advances (module doc); the value is what the reports spell."""

    WALL = "wall"
    SIMULATED = "simulated"


class Transport(abc.ABC):
    """Bytes to and from one board, and the clock waits are measured in.

    Attributes:
        url: the device URL this transport was made for.
        clock: how its time advances.
    """

    url: str
    clock: Clock

    @abc.abstractmethod
    def open(self, inbox: Inbox, *, timeout_s: float) -> None:
        """Connect; from now on received bytes go to ``inbox``.

        Args:
            inbox: where received bytes (and a lost connection) are reported.
            timeout_s: how long to keep trying if the board is not there yet (wall seconds).

        Raises:
            DeviceError: the board could not be reached.
        """

    @abc.abstractmethod
    def write(self, data: bytes) -> None:
        """Send bytes to the board. Raises DeviceDisconnected if it is gone."""

    @abc.abstractmethod
    def wait_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Let time pass until ``predicate()`` holds (checked under the inbox's condition) or
        ``timeout_s`` of this transport's clock has passed; returns the last ``predicate()``."""

    @abc.abstractmethod
    def time_s(self) -> float:
        """Now, in this transport's clock (s)."""

    @abc.abstractmethod
    def keep_alive(self, period_s: float | None, ping: Callable[[], None]) -> None:
        """A PING is due whenever nothing was written for ``period_s`` (None: never); the
        transport calls ``ping()`` when one is due during :meth:`wait_until`,
        :meth:`ping_if_due` and :meth:`attended`, and at no other time."""

    @abc.abstractmethod
    def ping_if_due(self) -> None:
        """The host called in without waiting (its control loop made progress): send the PING
        that is due, if any. A failed write is not raised here; the inbox records it."""

    @abc.abstractmethod
    def attended(self) -> ContextManager[None]:
        """A block in which the host, alive, waits on something other than the board (an
        operator's confirmation): PINGs go out as they fall due until the block ends."""

    @abc.abstractmethod
    def close(self) -> None:
        """Disconnect (idempotent)."""
