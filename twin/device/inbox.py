"""The host's receiving side: bytes from a transport → frames → the latest sample, a bounded
queue of samples, and the answers to commands.

A transport calls :meth:`Inbox.feed` with whatever bytes arrived (from its reader thread on
``serial://``, from the caller's thread on ``sim://``) and :meth:`Inbox.lost` when the board
goes away. Everything happens under :attr:`Inbox.condition`, which waiters use to sleep until
something arrives.
"""

from __future__ import annotations

import collections
import threading
from typing import Callable

from twin.device import codec
from twin.device.errors import DeviceDisconnected
from twin.device.telemetry import Telemetry

__all__ = ["Inbox"]


class Inbox:
    """Decoded traffic from one board.

    Args:
        clock: the transport's clock (s), stamped on each sample as ``received_s``.
        queue_size: samples kept for :meth:`drain`; older ones are dropped (and counted) when
            nobody drains. 4096 samples hold 100 s of 40 Hz telemetry.
    """

    def __init__(self, clock: Callable[[], float], *, queue_size: int = 4096):
        if queue_size < 1:
            raise ValueError(f"queue_size = {queue_size!r}: must be >= 1")
        self.condition = threading.Condition()
        self._clock = clock
        self._samples: collections.deque[Telemetry] = collections.deque(maxlen=queue_size)
        self._awaited: dict[int, codec.Ack | codec.Nack | None] = {}
        self.decoder = codec.FrameDecoder()
        self.latest: Telemetry | None = None
        self.sample_count = 0
        self.dropped_samples = 0
        self.lost_samples = 0
        self.hello_reply: codec.HelloReply | None = None
        self.hello_count = 0
        self.samples_before_hello_reply = 0
        self.error: DeviceDisconnected | None = None

    # ------------------------------------------------------------------ transport side
    def feed(self, data: bytes) -> None:
        """Bytes from the board, in any chunking."""
        with self.condition:
            for frame in self.decoder.feed(data):
                self._dispatch(frame.message)
            self.condition.notify_all()

    def lost(self, error: DeviceDisconnected) -> None:
        """The board went away; waiters wake up and raise ``error``."""
        with self.condition:
            if self.error is None:
                self.error = error
            self.condition.notify_all()

    # ------------------------------------------------------------------ client side
    def expect(self, seq: int) -> None:
        """Keep the answer to command ``seq`` (answers nobody expects, e.g. to keepalive PINGs,
        are dropped)."""
        with self.condition:
            self._awaited[seq] = None

    def answered(self, seq: int) -> bool:
        with self.condition:
            return self._awaited.get(seq) is not None

    def take_answer(self, seq: int) -> codec.Ack | codec.Nack | None:
        """The answer to an expected command if it arrived, else None; either way the command
        is no longer expected."""
        with self.condition:
            return self._awaited.pop(seq, None)

    def drain(self) -> list[Telemetry]:
        """All queued samples, oldest first; the queue is emptied."""
        with self.condition:
            samples = list(self._samples)
            self._samples.clear()
            return samples

    def restart(self) -> None:
        """Forget the link state of a previous connection (decoder, error, pending answers);
        the queued samples and ``latest`` are kept."""
        with self.condition:
            self.decoder = codec.FrameDecoder()
            self._awaited.clear()
            self.error = None
            self.hello_reply = None

    # ------------------------------------------------------------------ internals
    def _dispatch(self, message: codec.Message) -> None:
        if isinstance(message, codec.TelemetryMessage):
            sample = Telemetry.from_message(message, self._clock())
            previous = self.latest
            # A board that restarted counts from 0 again: only a forward jump is a loss.
            if previous is not None and sample.seq > previous.seq + 1:
                self.lost_samples += sample.seq - previous.seq - 1
            if len(self._samples) == self._samples.maxlen:
                self.dropped_samples += 1
            self._samples.append(sample)
            self.latest = sample
            self.sample_count += 1
        elif isinstance(message, (codec.Ack, codec.Nack)):
            if message.acked_seq in self._awaited:
                self._awaited[message.acked_seq] = message
        elif isinstance(message, codec.HelloReply):
            self.hello_reply = message
            self.hello_count += 1
            self.samples_before_hello_reply = self.sample_count
        else:
            # A host → board message coming back (an echoing line): count it as garbage.
            self.decoder.bad_messages += 1
