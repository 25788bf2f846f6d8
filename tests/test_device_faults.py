"""Faults between host and board: garbage on the line, a host that stops, a board that goes away."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import threading
import time
import tty

import numpy as np
import pytest

from twin.driver import DeviceDisconnected, DeviceError, DeviceTimeout, ProtocolVersionError, open_device
from twin.device import SimTwin
from twin.driver import codec as c
from twin.driver.codec import Drive, Fault, State
from twin.driver.inbox import Inbox
from twin.device.pty_board import PtyBoard
from twin.params import load_params


def telemetry_stream(count: int) -> tuple[list[c.TelemetryMessage], list[bytes]]:
    messages = [c.TelemetryMessage(time_us=25000 * k, sample_seq=k, lengths_m=(1e-3 * k, 0.0, -1e-3 * k, 0.0),
                            raw_counts=(k, -k, 2 * k, 0), state=c.State.ENABLED) for k in range(count)]
    return messages, [c.encode_frame(m, seq=k) for k, m in enumerate(messages)]


def fed(inbox: Inbox, chunks) -> list:
    for chunk in chunks:
        inbox.feed(chunk)
    return inbox.drain()


def test_random_bytes_never_crash_the_driver_and_are_counted():
    rng = np.random.default_rng(0)
    inbox = Inbox(lambda: 0.0)
    garbage = rng.integers(0, 256, 200_000, dtype=np.uint8).tobytes()
    cuts = np.sort(rng.integers(0, len(garbage), 2000))
    samples = fed(inbox, [bytes(x) for x in np.split(np.frombuffer(garbage, np.uint8), cuts)])
    # Random runs pass COBS, length and CRC together far more rarely than once in 200 kB.
    assert samples == [] and inbox.hello_count == 0
    assert inbox.decoder.bad_frames > 100


def test_mutated_frames_are_dropped_and_the_rest_received_unchanged():
    rng = np.random.default_rng(1)
    messages, frames = telemetry_stream(300)
    corrupted = set(rng.choice(len(frames), 60, replace=False).tolist())
    stream = []
    for k, frame in enumerate(frames):
        if k in corrupted:
            frame = bytearray(frame)
            # One byte changed anywhere but the delimiter. A changed data byte is a burst that
            # CRC-16 always catches; a changed COBS code byte moves zeros about and could pass
            # with probability 2^-16 (none does with this seed).
            i = int(rng.integers(0, len(frame) - 1))
            frame[i] ^= int(rng.integers(1, 256))
            frame = bytes(frame)
        stream.append(frame)
    inbox = Inbox(lambda: 0.0)
    data = b"".join(stream)
    cuts = np.sort(rng.integers(0, len(data), 500))
    samples = fed(inbox, [bytes(x) for x in np.split(np.frombuffer(data, np.uint8), cuts)])
    received = {s.seq for s in samples}
    # A corrupted delimiter merges a frame with its successor, so at most two are lost per error.
    assert received.isdisjoint(corrupted)
    assert len(received) >= len(frames) - 2 * len(corrupted)
    for s in samples:
        np.testing.assert_array_equal(s.tendon_lengths_m, np.float32(messages[s.seq].lengths_m))
    assert inbox.decoder.bad_frames >= len(corrupted) // 2
    assert inbox.lost_samples == sum(b - a - 1 for a, b in zip(sorted(received), sorted(received)[1:]))


class HandPlayedBoard:
    """A pseudo-terminal whose board end the test writes by hand."""

    def __init__(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.url = f"serial://{os.ttyname(self.slave)}"
        self.decoder = c.FrameDecoder()

    def answer_hello(self, reply: c.HelloReply, *, then: bytes = b"") -> threading.Thread:
        """Answer the HELLO with ``reply``, the DISABLE, SET_MOTORS and SET_LIMITS that a host
        sends next with an ACK each, then send ``then``; the messages received meanwhile go to :attr:`received`."""
        self.received = []

        def run():
            while True:
                for frame in self.decoder.feed(os.read(self.master, 4096)):
                    self.received.append(frame.message)
                    if isinstance(frame.message, c.Hello):
                        os.write(self.master, c.encode_frame(reply, seq=0))
                    elif isinstance(frame.message, c.Disable):
                        os.write(self.master, c.encode_frame(c.Ack(frame.seq, c.MsgType.DISABLE), seq=1))
                    elif isinstance(frame.message, c.SetMotors):
                        os.write(self.master, c.encode_frame(c.Ack(frame.seq, c.MsgType.SET_MOTORS), seq=1))
                    elif isinstance(frame.message, c.SetLimits):
                        os.write(self.master, c.encode_frame(c.Ack(frame.seq, c.MsgType.SET_LIMITS), seq=2) + then)
                        return

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        return thread

    def close(self):
        os.close(self.master)
        os.close(self.slave)


def test_a_board_of_another_protocol_version_is_refused():
    board = HandPlayedBoard()
    try:
        thread = board.answer_hello(c.HelloReply(protocol_version=c.PROTOCOL_VERSION + 1))
        device = open_device(board.url)
        with pytest.raises(ProtocolVersionError, match=rf"protocol version {c.PROTOCOL_VERSION + 1}, this host speaks "
                                                       rf"{c.PROTOCOL_VERSION}; sent it DISABLE") as info:
            device.connect(timeout_s=1.0)
        assert info.value.board_version == c.PROTOCOL_VERSION + 1
        assert not device.connected
        # Disabled, in case it understands that, and told nothing else.
        thread.join(timeout=1.0)
        assert [type(m) for m in board.received] == [c.Hello, c.Disable]
    finally:
        board.close()


RIG_M_PER_COUNT = load_params().rig.tendon_m_per_count


def test_a_board_that_counts_another_spool_is_refused():
    # The rig's spool, gearbox and encoder are the parameter file's: a board whose firmware was
    # built for another counts the tendons in other units, so every length would be off.
    board = HandPlayedBoard()
    try:
        thread = board.answer_hello(c.HelloReply(tendon_m_per_count=2 * RIG_M_PER_COUNT))
        device = open_device(board.url)
        with pytest.raises(DeviceError, match=r"counts 1.88\d+e-06 m of tendon per encoder count, the robot's rig "
                                              r"9.40\d+e-07 m \(rig.spool_radius_m"):
            device.connect(timeout_s=1.0)
        assert not device.connected
        thread.join(timeout=1.0)
        assert [type(m) for m in board.received] == [c.Hello, c.Disable]
    finally:
        board.close()


def test_the_board_is_given_the_rigs_limit_and_load_cells_on_connecting():
    params = load_params(overrides={"sensors.loadcell_gain_counts_per_n": 9000.0, "sensors.loadcell_capacity_n": 49.0,
                                    "rig.tension_limit_n": 30.0})
    board = HandPlayedBoard()
    try:
        _, telemetry = telemetry_stream(1)
        thread = board.answer_hello(c.HelloReply(tendon_m_per_count=RIG_M_PER_COUNT), then=telemetry[0])
        device = open_device(board.url, params=params)
        device.connect(timeout_s=1.0)
        thread.join(timeout=1.0)
        limits = board.received[-1]
        assert isinstance(limits, c.SetLimits)
        assert (limits.tension_limit_n, limits.loadcell_gain_counts_per_n) == (30.0, 9000.0)
        device.close()
    finally:
        board.close()


def test_garbage_on_the_line_is_skipped_and_a_silent_board_times_out():
    board = HandPlayedBoard()
    try:
        # Garbage before, between and after the frames the host needs.
        garbage = bytes(range(1, 200)) + b"\x00\x17\x42\x00"
        _, telemetry = telemetry_stream(1)
        board.answer_hello(c.HelloReply(tendon_m_per_count=RIG_M_PER_COUNT), then=garbage + telemetry[0] + garbage)
        device = open_device(board.url)
        device.connect(timeout_s=1.0)
        assert device.latest().seq == 0
        # Each garbage block is two bad frames: an over-long run, then a short one.
        assert device.bad_frames == 4
        # Nobody answers commands on this line.
        with pytest.raises(DeviceTimeout, match=r"no answer to ENABLE .* within 0.5 s \(wall clock\)"):
            device.enable()
        with pytest.raises(DeviceTimeout, match="no telemetry within 0.1 s"):
            device.wait_next(timeout_s=0.1)
        device.close()  # its DISABLE goes unanswered too; closing goes on regardless
        assert not device.connected
    finally:
        board.close()


HOST_SCRIPT = textwrap.dedent("""
    import sys, time
    from twin.driver import open_device
    device = open_device(sys.argv[1])
    device.connect()
    device.tare()
    device.set_gains("lengths", kp=60.0, ki=100.0, kd=0.0)
    device.enable()
    device.set_lengths([-0.001, 0.0, 0.001, 0.0])
    device.wait(0.3)
    print(device.latest().state.name, flush=True)
    time.sleep(60)
""")


def test_a_host_that_stops_mid_run_is_stopped_by_the_watchdog():
    with PtyBoard(seed=1) as board:
        host = subprocess.Popen([sys.executable, "-c", HOST_SCRIPT, board.url], stdout=subprocess.PIPE, text=True)
        try:
            assert host.stdout.readline().strip() == "ENABLED"
            assert SimTwin(board.board).drive_mode == "pwm"  # driven
        finally:
            host.kill()
            host.wait()
        time.sleep(0.4)  # past the 250 ms watchdog
        assert SimTwin(board.board).drive_mode == "coast"
        with open_device(board.url) as device:
            sample = device.latest()
            # Connecting disables the board; the watchdog's fault stays latched for the host to read.
            assert sample.state is State.DISABLED
            assert sample.fault_flags & Fault.WATCHDOG
            assert sample.drives == (Drive.COAST,) * 4 and not np.any(sample.motor_commands)
            # Latched until the next enable.
            device.enable()
            assert device.wait_next().state is State.ENABLED and device.latest().fault_flags == 0


def test_a_quiet_host_on_sim_trips_the_watchdog_in_simulated_time():
    with open_device("sim://", keepalive_s=None) as device:
        device.enable()
        device.wait(0.2)
        assert device.latest().state is State.ENABLED
        device.wait(0.1)
        assert device.latest().state is State.FAULT and device.latest().fault_flags & Fault.WATCHDOG


def test_a_board_that_disappears_raises_a_clear_error_keeps_the_data_and_can_come_back(tmp_path):
    link = tmp_path / "ttyTWIN"
    with PtyBoard(seed=2, link_path=link) as board:
        device = open_device(f"serial://{link}")
        device.connect()
        device.drain()
        device.enable()
        threading.Timer(0.5, board.unplug).start()
        start = time.monotonic()
        # The reader or a keep-alive write, whichever meets the unplugged port first, says so.
        with pytest.raises(DeviceDisconnected, match=rf"serial://{link}: (write failed, )?the board is gone"):
            device.wait(5.0)
        assert time.monotonic() - start < 1.0
        assert not device.connected and not link.exists()
        recorded = device.drain()
        assert len(recorded) >= 10  # ~20 in the 0.5 s at 40 Hz, fewer if the machine is loaded
        assert [s.seq for s in recorded] == list(range(recorded[0].seq, recorded[0].seq + len(recorded)))
        assert device.latest() is recorded[-1]
        with pytest.raises(DeviceDisconnected):
            device.set_lengths([0.0] * 4)

        threading.Timer(0.3, board.plug).start()
        info = device.reconnect(timeout_s=3.0)
        assert info.protocol_version == c.PROTOCOL_VERSION
        # The board came back powered up afresh: disabled, its clock and counters restarted.
        sample = device.latest()
        assert sample.state is State.DISABLED and sample.time_s < 0.2
        device.enable()
        assert device.wait_next().state is State.ENABLED
        device.close()
