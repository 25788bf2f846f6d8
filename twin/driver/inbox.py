"""The host's receiving side: bytes from a transport → frames → the latest sample, a bounded
queue of samples, and the answers to commands.

A transport calls :meth:`Inbox.feed` with whatever bytes arrived (from its reader thread on
``serial://``, from the caller's thread on ``sim://``) and :meth:`Inbox.lost` when the board
goes away. Everything happens under :attr:`Inbox.condition`, which waiters use to sleep until
something arrives.

No data can make :meth:`Inbox.feed` raise: a frame that fails its checks, or a message that
cannot be turned into host values, is counted and skipped (:meth:`Inbox.stats`), so a reader
thread never dies from what the board sent.
"""

from __future__ import annotations

import collections
import dataclasses
import threading
from typing import Callable

from twin.driver import codec
from twin.driver.errors import DeviceDisconnected
from twin.driver.telemetry import Telemetry

__all__ = ["Inbox", "LinkStats"]


@dataclasses.dataclass(frozen=True)
class LinkStats:
    """What the host dropped or missed on the link.

    Attributes:
        bad_frames: frames dropped for framing or CRC errors (this connection).
        bad_messages: intact frames not used: unknown type, wrong length, a value the protocol
            does not define (unknown enum member, a float that is not finite), or an answer
            naming another command than the one awaited (this connection).
        last_error: why the latest bad frame or message was dropped, or None (this connection).
        lost_samples: samples missing from the board's sequence (lost on the link).
        dropped_samples: samples pushed out of the drain queue because nobody drained it.
    """

    bad_frames: int
    bad_messages: int
    last_error: str | None
    lost_samples: int
    dropped_samples: int


# Sent messages remembered for matching answers that nobody awaits: far more than the board can
# have unanswered (it answers each command within a tick), far fewer than the 65536 seqs.
_SENT_KEPT = 1024

class Inbox:
    """Decoded traffic from one board.

    Args:
        clock: the transport's clock (s), stamped on each sample as ``received_s``.
        queue_size: samples kept for :meth:`drain`; older ones are dropped (and counted) when
            nobody drains. 4096 samples hold 100 s of 40 Hz telemetry.
        on_lost: called once per connection, outside the condition, when the board is lost and
            may still read what is written (see :meth:`lost`), with the error.
    """

    def __init__(self, clock: Callable[[], float], *, queue_size: int = 4096,
                 on_lost: Callable[[DeviceDisconnected], None] | None = None):
        if queue_size < 1:
            raise ValueError(f"queue_size = {queue_size!r}: must be >= 1")
        self.condition = threading.Condition()
        self._clock = clock
        self._on_lost = on_lost
        self._samples: collections.deque[Telemetry] = collections.deque(maxlen=queue_size)
        # seq of an awaited command → (its type, its answer or None).
        self._awaited: dict[int, tuple[int, codec.Ack | codec.Nack | None]] = {}
        self._sent: collections.OrderedDict[int, int] = collections.OrderedDict()  # seq → type, the latest
        self.decoder = codec.FrameDecoder()
        self.latest: Telemetry | None = None
        # Called with each sample as it arrives (in the reader's thread on serial://): keep them short.
        self.listeners: list[Callable[[Telemetry], None]] = []
        self.sample_count = 0
        self.dropped_samples = 0
        self.lost_samples = 0
        self.hello_reply: codec.HelloReply | None = None
        self.hello_count = 0
        # sample_count when the latest awaited answer arrived: samples after it are newer.
        self.samples_before_answer = 0
        self.error: DeviceDisconnected | None = None

    # ------------------------------------------------------------------ transport side
    def feed(self, data: bytes) -> None:
        """Bytes from the board, in any chunking; never raises for what they contain."""
        with self.condition:
            decoder = self.decoder
            for frame in decoder.feed(data):
                try:
                    self._dispatch(frame.message)
                except Exception as exc:  # noqa: BLE001 - data must never stop the reader
                    decoder.bad_messages += 1
                    decoder.last_error = f"{type(frame.message).__name__} not usable: {exc!r}"
            self.condition.notify_all()

    def lost(self, error: DeviceDisconnected, *, writable: bool = True) -> None:
        """The link is lost; waiters wake up and raise ``error``, and so does every later call.

        Args:
            error: the cause, for every later call to raise.
            writable: False when writing already failed, so the board cannot be told anything
                (``on_lost`` is not called); True when the board may still read, e.g. the
                reader stopped for a reason of its own.
        """
        with self.condition:
            first = self.error is None
            if first:
                self.error = error
            self.condition.notify_all()
        if first and writable and self._on_lost is not None:
            self._on_lost(error)

    # ------------------------------------------------------------------ client side
    def sent(self, seq: int, msg_type: int) -> None:
        """Note that message ``seq`` of type ``msg_type`` went out: an answer to it that nobody
        awaits (a keepalive PING's) is dropped; an answer to no message sent is counted as bad."""
        with self.condition:
            self._sent[seq] = msg_type
            self._sent.move_to_end(seq)
            if len(self._sent) > _SENT_KEPT:
                self._sent.popitem(last=False)

    def expect(self, seq: int, msg_type: int) -> None:
        """Keep the answer to command ``seq`` of type ``msg_type`` (answers nobody expects,
        e.g. to keepalive PINGs, are dropped; one naming another type is counted as bad)."""
        with self.condition:
            self._awaited[seq] = (msg_type, None)

    def answered(self, seq: int) -> bool:
        with self.condition:
            awaited = self._awaited.get(seq)
            return awaited is not None and awaited[1] is not None

    def take_answer(self, seq: int) -> codec.Ack | codec.Nack | None:
        """The answer to an expected command if it arrived, else None; either way the command
        is no longer expected."""
        with self.condition:
            return self._awaited.pop(seq, (None, None))[1]

    def stats(self) -> LinkStats:
        """The link's counters now (see :class:`LinkStats`)."""
        with self.condition:
            decoder = self.decoder
            return LinkStats(bad_frames=decoder.bad_frames, bad_messages=decoder.bad_messages,
                             last_error=decoder.last_error, lost_samples=self.lost_samples,
                             dropped_samples=self.dropped_samples)

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
            for listener in self.listeners:
                listener(sample)
        elif isinstance(message, (codec.Ack, codec.Nack)):
            awaited = self._awaited.get(message.acked_seq)
            if awaited is None:
                sent_type = self._sent.get(message.acked_seq)
                if sent_type is None or sent_type != message.acked_type:
                    # A stray answer (to nothing this host sent, or naming another type): not the
                    # board's, or corrupted past its CRC.
                    self.decoder.bad_messages += 1
                    self.decoder.last_error = (
                        f"{type(message).__name__} of seq {message.acked_seq} (type 0x{message.acked_type:02x}) "
                        "answers no message this host sent")
                return
            if message.acked_type != awaited[0]:
                self.decoder.bad_messages += 1
                self.decoder.last_error = (
                    f"{type(message).__name__} of seq {message.acked_seq} names type 0x{message.acked_type:02x}, "
                    f"the command was 0x{awaited[0]:02x}")
                return
            self._awaited[message.acked_seq] = (awaited[0], message)
            self.samples_before_answer = self.sample_count
        elif isinstance(message, codec.HelloReply):
            self.hello_reply = message
            self.hello_count += 1
        else:
            # A host → board message coming back (an echoing line): count it as garbage.
            self.decoder.bad_messages += 1
            self.decoder.last_error = f"{type(message).__name__}: a host → board message received"
