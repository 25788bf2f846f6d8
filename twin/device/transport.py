"""How bytes and time reach a board: the interface :class:`twin.device.Device` talks through.

Two kinds exist and differ in their clock:

* ``"wall"`` (:class:`twin.device.serial_transport.SerialTransport`): the board runs on its
  own; a reader thread hands received bytes to the inbox as they arrive, a keepalive thread
  pings when the host has been quiet, and waiting is sleeping.
* ``"simulated"`` (:class:`twin.device.sim_transport.SimTransport`): the board is emulated in
  this process and time stands still unless the host waits; waiting steps the board, and
  bytes are delivered as they are produced.
"""

from __future__ import annotations

import abc
from typing import Callable

from twin.device.inbox import Inbox

__all__ = ["Transport"]


class Transport(abc.ABC):
    """Bytes to and from one board, and the clock waits are measured in.

    Attributes:
        url: the device URL this transport was made for.
        clock: ``"simulated"`` or ``"wall"``.
    """

    url: str
    clock: str

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
        """Call ``ping()`` whenever nothing was written for ``period_s`` (None: never), so the
        board's watchdog stays fed while the host is alive."""

    @abc.abstractmethod
    def close(self) -> None:
        """Disconnect (idempotent)."""
