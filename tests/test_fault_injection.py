"""Fault injection between host and board: bad frames played to the host, a proxy that flips
bits both ways, hosts that are killed or hang, a board that is unplugged. Each test asserts the
safe outcome: the host keeps hearing good telemetry and says so when it cannot, a corrupted
command is never acted on, and a board whose host stopped making progress stops driving
within its watchdog timeout (0.25 s).

The board is the emulated one on a pseudo-terminal (:class:`twin.device.pty_board.PtyBoard`,
the real firmware core), in wall-clock time. What the board really sent is read by a
:class:`Proxy` between it and the host, before any corruption: that is the ground truth.
"""

from __future__ import annotations

import collections
import dataclasses
import faulthandler
import math
import os
import select
import signal
import subprocess
import sys
import textwrap
import threading
import time
import tty
from typing import Callable

import numpy as np
import pytest

from twin.driver import DeviceDisconnected, DeviceTimeout, open_device
from twin.device import SimTwin
from twin.driver import codec as c
from twin.driver.codec import Fault, State
from twin.driver.inbox import Inbox
from twin.device.pty_board import PtyBoard

# The board's default watchdog timeout and telemetry period (s).
WATCHDOG_S = 0.25
TELEMETRY_S = 0.025


@pytest.fixture(autouse=True)
def bounded_in_time():
    """Each test ends within a minute: a hang dumps every thread's stack and ends the run."""
    faulthandler.dump_traceback_later(60.0, exit=True)
    yield
    faulthandler.cancel_dump_traceback_later()


def raw_frame(msg_type: int, seq: int, payload: bytes) -> bytes:
    """An intact frame (COBS, CRC) of any type and payload, whatever the protocol says of them."""
    body = bytes([msg_type]) + seq.to_bytes(2, "little") + payload
    return c.cobs_encode(body + c.crc16(body).to_bytes(2, "little")) + b"\x00"


# A sequence number no real sample reaches in these tests: a host sample carrying it is an
# injected frame the host took for telemetry.
INJECTED_SEQ = 10**9

# (name, how to make the frame from a real telemetry message, what the host's reason says).
BAD_FRAMES: list[tuple[str, Callable[[c.TelemetryMessage], bytes], str]] = [
    ("unknown state", lambda m: c.encode_frame(dataclasses.replace(m, state=7), 1), "state = 7"),
    ("unknown mode", lambda m: c.encode_frame(dataclasses.replace(m, mode=9), 1), "mode = 9"),
    ("motor drive 3", lambda m: c.encode_frame(dataclasses.replace(m, drive_modes=(0, 0, 0, 3)), 1),
     "drive_modes = (0, 0, 0, 3)"),
    ("stale bits beyond 4 cells", lambda m: c.encode_frame(dataclasses.replace(m, stale_mask=0x30), 1),
     "stale_mask = 0x30"),
    ("NaN length", lambda m: c.encode_frame(dataclasses.replace(m, lengths_m=(math.nan, 0.0, 0.0, 0.0)), 1),
     "lengths_m"),
    ("infinite tension", lambda m: c.encode_frame(dataclasses.replace(m, tensions_n=(0.0, math.inf, 0.0, 0.0)), 1),
     "tensions_n"),
    ("duty beyond 1", lambda m: c.encode_frame(dataclasses.replace(m, duty=(1.5, 0.0, 0.0, 0.0)), 1), "duty"),
    ("short payload", lambda m: raw_frame(c.MsgType.TELEMETRY, 1, c.encode_payload(m)[:-1]), "167 bytes, expected 168"),
    ("long payload", lambda m: raw_frame(c.MsgType.TELEMETRY, 1, c.encode_payload(m) + b"\x01"), "169 bytes"),
    ("unknown type", lambda m: raw_frame(0x99, 1, c.encode_payload(m)), "unknown message type 0x99"),
    ("host message echoed", lambda m: c.encode_frame(c.Enable(), 1), "host → board message"),
]


def _injected(message: c.TelemetryMessage) -> c.TelemetryMessage:
    return dataclasses.replace(message, sample_seq=INJECTED_SEQ)


# ----------------------------------------------------------------------------- the inbox alone
@pytest.mark.parametrize("name, make, reason", BAD_FRAMES, ids=[b[0] for b in BAD_FRAMES])
def test_an_intact_frame_the_protocol_cannot_carry_is_counted_and_skipped(name, make, reason):
    good = [c.TelemetryMessage(time_us=25000 * k, sample_seq=k, state=State.ENABLED) for k in range(3)]
    inbox = Inbox(lambda: 0.0)
    inbox.feed(c.encode_frame(good[0], 0) + make(_injected(good[1])) + c.encode_frame(good[2], 2))
    assert [s.seq for s in inbox.drain()] == [0, 2]
    stats = inbox.stats()
    assert (stats.bad_frames, stats.bad_messages) == (0, 1)
    assert reason in stats.last_error


def test_an_answer_naming_another_command_is_not_taken_for_its_answer():
    inbox = Inbox(lambda: 0.0)
    inbox.expect(5, c.MsgType.ENABLE)
    inbox.feed(c.encode_frame(c.Ack(acked_seq=5, acked_type=c.MsgType.DISABLE), 0))
    assert not inbox.answered(5)
    assert inbox.stats().bad_messages == 1 and "the command was 0x03" in inbox.stats().last_error
    inbox.feed(c.encode_frame(c.Ack(acked_seq=5, acked_type=c.MsgType.ENABLE), 1))
    assert inbox.answered(5) and isinstance(inbox.take_answer(5), c.Ack)


def test_a_stray_answer_is_counted_and_an_unawaited_one_to_a_sent_message_is_not():
    # Before: an ACK or NACK to no command awaited was dropped without being counted.
    inbox = Inbox(lambda: 0.0)
    inbox.sent(7, c.MsgType.PING)  # a keepalive: its answer is nobody's business
    inbox.feed(c.encode_frame(c.Ack(acked_seq=7, acked_type=c.MsgType.PING), 0))
    assert inbox.stats().bad_messages == 0
    inbox.feed(c.encode_frame(c.Ack(acked_seq=8, acked_type=c.MsgType.ENABLE), 1))  # nothing sent as 8
    assert inbox.stats().bad_messages == 1 and "answers no message this host sent" in inbox.stats().last_error
    inbox.feed(c.encode_frame(c.Nack(acked_seq=7, acked_type=c.MsgType.ENABLE, error=c.NackError.BAD_VALUE), 2))
    assert inbox.stats().bad_messages == 2  # seq 7 was a PING, not an ENABLE
    inbox.feed(c.encode_frame(c.Nack(acked_seq=7, acked_type=c.MsgType.PING, error=99), 3))
    assert inbox.stats().bad_messages == 3  # an error code the protocol does not define


def test_no_bytes_make_the_inbox_raise():
    rng = np.random.default_rng(7)
    inbox = Inbox(lambda: 0.0)
    template = c.encode_payload(c.TelemetryMessage())
    # Intact frames of every type with random payloads (right length or not): the decoder's
    # checks and the inbox's conversion meet every field value.
    for _ in range(3000):
        msg_type = int(rng.choice([*c.MESSAGE_TYPES, 0x00, 0x7F, 0xFF]))
        size = len(template) if rng.random() < 0.7 and msg_type == c.MsgType.TELEMETRY else int(rng.integers(0, 40))
        payload = rng.integers(0, 256, size, dtype=np.uint8)
        if size == len(template):
            payload[0] = template[0]  # the channel count its length is right for
        inbox.feed(raw_frame(msg_type, int(rng.integers(0, 1 << 16)), payload.tobytes()))
    inbox.feed(rng.integers(0, 256, 50_000, dtype=np.uint8).tobytes())
    assert inbox.error is None
    for sample in inbox.drain():
        assert np.all(np.isfinite(sample.tendon_lengths_m)) and np.all(np.abs(sample.motor_commands) <= 1.0)


# ----------------------------------------------------------------------------- the proxy
class Proxy:
    """A pseudo-terminal between a host and a board's port that passes whole frames.

    The board's frames are decoded as they pass (:attr:`truth`: what it really sent, with the
    wall time), then given to ``to_host``, which returns the bytes the host gets (the frame,
    a corrupted one, nothing); the host's frames likewise pass ``to_board``. :meth:`inject`
    queues bytes for the host, sent between two frames.

    Args:
        board_port: the board's pseudo-terminal (``PtyBoard.port``).
        to_host: frame (with its 0x00) → bytes for the host; the frame itself by default.
        to_board: the same for the host's frames.
    """

    def __init__(self, board_port: str, *, to_host=None, to_board=None):
        self._board = os.open(board_port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.url = f"serial://{os.ttyname(self._slave)}"
        self.to_host = to_host or (lambda frame: frame)
        self.to_board = to_board or (lambda frame: frame)
        self.truth: list[tuple[float, c.TelemetryMessage]] = []
        self.host_frames: list[tuple[float, c.Frame]] = []
        self._injected: collections.deque[bytes] = collections.deque()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def inject(self, data: bytes) -> None:
        self._injected.append(data)

    def latest_truth(self) -> c.TelemetryMessage:
        return self.truth[-1][1]

    def truth_after(self, wall_s: float) -> list[c.TelemetryMessage]:
        return [m for t, m in list(self.truth) if t > wall_s]

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        for fd in (self._board, self._master, self._slave):
            os.close(fd)

    def __enter__(self) -> "Proxy":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _run(self) -> None:
        pending = {self._board: bytearray(), self._master: bytearray()}
        truth, host = c.FrameDecoder(), c.FrameDecoder()
        while not self._stop.is_set():
            ready, _, _ = select.select([self._board, self._master], [], [], 0.01)
            for fd in ready:
                try:
                    pending[fd] += os.read(fd, 4096)
                except (BlockingIOError, OSError):
                    continue
                *frames, rest = pending[fd].split(b"\x00")
                pending[fd] = bytearray(rest)
                now_s = time.monotonic()
                for body in frames:
                    frame = bytes(body) + b"\x00"
                    if fd == self._board:
                        self.truth += [(now_s, f.message) for f in truth.feed(frame)
                                       if isinstance(f.message, c.TelemetryMessage)]
                        self._write(self._master, self.to_host(frame))
                    else:
                        self.host_frames += [(now_s, f) for f in host.feed(frame)]
                        self._write(self._board, self.to_board(frame))
            while self._injected:
                self._write(self._master, self._injected.popleft())

    @staticmethod
    def _write(fd: int, data: bytes) -> None:
        try:
            os.write(fd, data)
        except BlockingIOError:
            pass  # nobody reads: dropped, as on a USB port without a host


def flip_one_bit(frame: bytes, rng: np.random.Generator) -> bytes:
    """``frame`` with one bit flipped, its delimiter kept and no new 0x00 made: exactly one bad
    frame at the receiver."""
    body = bytearray(frame[:-1])
    while True:
        i, bit = int(rng.integers(0, len(body))), 1 << int(rng.integers(0, 8))
        if body[i] ^ bit:
            body[i] ^= bit
            return bytes(body) + b"\x00"


def not_driving(message: c.TelemetryMessage) -> bool:
    """No motor driven: all coast or brake (the board's own report, as it left the board)."""
    return c.Drive.DRIVE not in message.drives() and not any(message.duty)


def enable_and_hold(device, lengths_m=(-0.0005, 0.0, 0.0005, 0.0)) -> None:
    device.tare()
    device.set_gains("lengths", kp=60.0, ki=100.0, kd=0.0)
    device.enable()
    device.set_lengths(list(lengths_m))


def holding_host(url: str, **options):
    """A connected device at ``url`` driving the board to hold small length setpoints."""
    device = open_device(url, **options)
    device.connect()
    enable_and_hold(device)
    return device


def assert_samples_are_the_boards(samples, proxy: Proxy) -> None:
    """Every sample the host took is one the board sent, unchanged."""
    sent = {m.sample_seq: m for _, m in list(proxy.truth)}
    assert samples
    for s in samples:
        assert s.seq in sent, f"sample {s.seq} was never sent by the board"
        np.testing.assert_array_equal(s.tendon_lengths_m, np.float32(sent[s.seq].lengths_m))
        assert s.state == sent[s.seq].state and np.array_equal(s.targets, np.float32(sent[s.seq].targets))


# ----------------------------------------------------------------------------- bad frames
def test_bad_frames_played_to_a_host_are_counted_and_skipped_and_it_keeps_hearing_the_board():
    with PtyBoard(seed=3) as board, Proxy(board.port) as proxy:
        device = holding_host(proxy.url)
        device.drain()
        for name, make, reason in BAD_FRAMES:
            before = device.stats.bad_messages
            proxy.inject(make(_injected(proxy.latest_truth())))
            device.wait_next(timeout_s=0.2)
            device.wait_next(timeout_s=0.2)
            assert device.stats.bad_messages == before + 1, name
            assert reason in device.stats.last_error, name
        # Garbage: a run of random bytes ending in a delimiter, then a frame cut short.
        rng = np.random.default_rng(0)
        bad_frames = device.stats.bad_frames
        proxy.inject(rng.integers(1, 256, 300, dtype=np.uint8).tobytes() + b"\x00")
        proxy.inject(c.encode_frame(proxy.latest_truth(), 1)[40:])
        device.wait_next(timeout_s=0.2)
        device.wait_next(timeout_s=0.2)
        assert device.stats.bad_frames == bad_frames + 2
        # Still connected, still commanding a board that never stopped.
        assert device.connected
        device.set_lengths([0.0, 0.0, 0.0, 0.0])
        assert device.wait_next().enabled and proxy.latest_truth().state == State.ENABLED
        # Not one good sample missed meanwhile, and none taken that the board did not send.
        samples = device.drain()
        assert [s.seq for s in samples] == list(range(samples[0].seq, samples[0].seq + len(samples)))
        assert device.lost_samples == 0
        assert_samples_are_the_boards(samples, proxy)
        device.close()


def test_bit_flips_both_ways_are_dropped_and_no_corrupted_command_is_acted_on():
    rngs = {"to_host": np.random.default_rng(1), "to_board": np.random.default_rng(2)}
    flipped = {"to_host": 0, "to_board": 0}
    corrupting = threading.Event()

    def corrupt(direction: str):
        def to(frame: bytes) -> bytes:
            if corrupting.is_set() and len(frame) > 1 and rngs[direction].random() < 0.2:
                flipped[direction] += 1
                return flip_one_bit(frame, rngs[direction])
            return frame
        return to

    hold_m = (-0.0005, 0.0, 0.0005, 0.0)
    with PtyBoard(seed=4) as board, Proxy(board.port, to_host=corrupt("to_host"), to_board=corrupt("to_board")) as proxy:
        # A short command timeout: a command or its answer corrupted on the way costs little.
        device = open_device(proxy.url, command_timeout_s=0.1)
        device.connect()
        # Commands lost for 0.25 s together would trip the watchdog, as they should; this test
        # is about what the board does with the commands it gets.
        device.set_limits(watchdog_timeout_s=2.0)
        enable_and_hold(device, hold_m)
        held = float(np.float32(hold_m[0]))
        first = device.wait_next()
        assert first.targets[0] == held
        device.drain()
        bad_frames = device.stats.bad_frames
        corrupting.set()
        sent = {held}
        for k in range(60):
            target = float(np.float32((k + 1) * 1e-5 * (-1) ** k))
            sent.add(target)
            try:
                device.set_lengths([target, 0.0, 0.0, 0.0])
            except DeviceTimeout:
                pass  # the command or its ACK was corrupted: not acted on, or acted on unacknowledged
            device.wait_next(timeout_s=0.3)
        corrupting.clear()
        time.sleep(0.1)  # what was corrupted arrives
        samples = device.drain()
        assert flipped["to_host"] > 10 and flipped["to_board"] > 5
        # The host dropped exactly the frames corrupted on the way to it, and every sample it
        # took is the board's, unchanged.
        assert device.stats.bad_frames - bad_frames == flipped["to_host"]
        assert_samples_are_the_boards(samples, proxy)
        # The board dropped exactly the corrupted commands (it heard nothing else) and, while
        # enabled, drove only to setpoints the host sent.
        truth = [m for _, m in proxy.truth]
        assert truth[-1].rx_bad_frames == flipped["to_board"]
        since = next(k for k, m in enumerate(truth) if m.sample_seq == first.seq)
        assert all(m.state == State.ENABLED for m in truth[since:])
        assert {float(m.targets[0]) for m in truth[since:]} <= sent
        device.close()


# ----------------------------------------------------------------------------- a host that stops
KILLED_HOST = textwrap.dedent("""
    import sys
    from twin.driver import open_device
    device = open_device(sys.argv[1])
    device.connect()
    device.set_limits(watchdog_timeout_s=float(sys.argv[2]))
    device.tare()
    device.set_gains("lengths", kp=60.0, ki=100.0, kd=0.0)
    device.enable()
    device.set_lengths([-0.0005, 0.0, 0.0005, 0.0])
    print(device.wait_next().state.name, flush=True)
    while True:  # a control loop, alive until killed
        device.wait_next()
""")


def _start_host(url: str, watchdog_s: float = WATCHDOG_S) -> subprocess.Popen:
    host = subprocess.Popen([sys.executable, "-c", KILLED_HOST, url, str(watchdog_s)], stdout=subprocess.PIPE, text=True)
    assert host.stdout.readline().strip() == "ENABLED"
    return host


def _kill(host: subprocess.Popen) -> float:
    host.send_signal(signal.SIGKILL)
    host.wait(timeout=10)
    return time.monotonic()


def test_a_killed_host_trips_the_watchdog_and_the_next_host_finds_the_board_disabled():
    with PtyBoard(seed=5) as board, Proxy(board.port) as proxy:
        host = _start_host(proxy.url)
        time.sleep(0.5)  # the host's loop keeps the board enabled meanwhile
        assert proxy.latest_truth().state == State.ENABLED
        _kill(host)
        time.sleep(0.5)
        last_write_s = proxy.host_frames[-1][0]
        # Board time at the host's last byte: no later than the first sample after it.
        after = proxy.truth_after(last_write_s)
        tripped = next(m for m in after if m.state == State.FAULT)
        assert tripped.fault_flags & Fault.WATCHDOG
        assert all(m.state == State.ENABLED for m in after[: after.index(tripped)])
        # The watchdog's 0.25 s from the last byte, seen at the next sample.
        assert (tripped.time_us - after[0].time_us) / 1e6 <= WATCHDOG_S + TELEMETRY_S + 0.015
        assert all(not_driving(m) for m in after[after.index(tripped):])
        with open_device(proxy.url) as device:
            sample = device.latest()
            assert sample.state is State.DISABLED and sample.fault_flags & Fault.WATCHDOG


def test_a_host_restarted_at_once_finds_the_board_disabled_not_driving_the_dead_hosts_setpoints():
    # A watchdog of 2 s, so that the new host surely connects before it trips (the old host
    # leaves its limits on the board).
    with PtyBoard(seed=6) as board, Proxy(board.port) as proxy:
        host = _start_host(proxy.url, watchdog_s=2.0)
        assert SimTwin(board.board).drive_mode == "pwm"
        killed_s = _kill(host)
        with open_device(proxy.url) as device:
            connected_s = time.monotonic()
            sample = device.latest()
            assert connected_s - killed_s < 1.0
            assert sample.state is State.DISABLED and sample.fault_flags == 0  # DISABLE, not the watchdog
            assert not_driving(proxy.latest_truth())
            assert device.wait_next().state is State.DISABLED


def test_a_host_whose_control_loop_hangs_trips_the_watchdog():
    with PtyBoard(seed=7) as board:
        device = holding_host(board.url)
        device.wait(0.2)
        device.drain()
        last = device.latest()  # the loop's last call before it hangs
        time.sleep(1.0)
        # The reader thread went on receiving while the main thread hung.
        samples = device.drain()
        tripped = next(s for s in samples if s.state is State.FAULT)
        assert tripped.fault_flags & Fault.WATCHDOG
        # The last PING went out at most one keepalive period before the last call.
        assert 0.25 - 0.1 - TELEMETRY_S <= tripped.time_s - last.time_s <= WATCHDOG_S + 2 * TELEMETRY_S + 0.005
        assert device.connected  # the link is fine: it is the host that stopped
        assert device.wait_next().state is State.FAULT
        device.close()


def test_an_operator_prompt_keeps_the_board_enabled():
    with PtyBoard(seed=8) as board:
        device = open_device(board.url, prompt=lambda request: time.sleep(0.6))
        device.connect()
        enable_and_hold(device)
        device.fixture.hang_tip_mass(0.01)  # the operator takes 0.6 s
        assert device.wait_next().state is State.ENABLED and device.latest().fault_flags == 0
        device.close()


# ----------------------------------------------------------------------------- a deaf host
def test_a_reader_that_stops_disables_the_board_and_every_call_names_the_cause(monkeypatch):
    with PtyBoard(seed=9) as board, Proxy(board.port) as proxy:
        device = holding_host(proxy.url)
        device.wait(0.1)
        assert not not_driving(proxy.latest_truth())
        received = device.drain()

        def broken(data: bytes) -> None:
            raise RuntimeError("decoder bug")

        start = time.monotonic()
        # The reader's next bytes meet a bug in the host (no data can stop it any more).
        monkeypatch.setattr(device._inbox.decoder, "feed", broken)
        with pytest.raises(DeviceDisconnected, match=r"reader thread stopped \(RuntimeError\('decoder bug'\)\)"):
            device.wait(2.0)
        assert time.monotonic() - start < 0.2 and not device.connected
        # The DISABLE arrived: the board reports itself disabled (the watchdog would have said
        # FAULT, and later), its motors undriven.
        deadline_s = time.monotonic() + WATCHDOG_S
        while proxy.latest_truth().state != State.DISABLED and time.monotonic() < deadline_s:
            time.sleep(0.005)
        assert proxy.latest_truth().state == State.DISABLED and not_driving(proxy.latest_truth())
        for call in (device.wait_next, device.enable, device.ping, lambda: device.set_lengths([0.0] * 4)):
            with pytest.raises(DeviceDisconnected, match="reader thread stopped"):
                call()
        assert received and device.latest() is received[-1]  # the data before is kept
        time.sleep(WATCHDOG_S)
        monkeypatch.undo()
        # Disabled by the host, not stopped by the watchdog: no fault latched.
        device.reconnect()
        assert device.latest().state is State.DISABLED and device.latest().fault_flags == 0
        device.close()


def test_an_unplugged_board_raises_disconnected_promptly_and_the_data_is_kept():
    with PtyBoard(seed=10) as board:
        device = holding_host(board.url)
        device.wait(0.3)
        threading.Timer(0.1, board.unplug).start()
        start = time.monotonic()
        with pytest.raises(DeviceDisconnected, match="the board is gone"):
            device.wait(5.0)
        assert time.monotonic() - start < 0.1 + 0.3
        assert not device.connected
        for call in (device.wait_next, device.disable):
            with pytest.raises(DeviceDisconnected, match="the board is gone"):
                call()
        samples = device.drain()
        assert len(samples) >= 10 and device.latest() is samples[-1]
        device.close()
