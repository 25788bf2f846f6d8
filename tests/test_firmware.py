"""The firmware core: its C++ unit tests on the host, and the board driven through ctypes.

``make -C firmware firmware-check`` runs the same C++ tests under QEMU (see firmware/README.md);
it needs the ARM toolchain, so it is not part of this suite.
"""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from twin.driver import codec as c
from twin.device.firmware_lib import FIRMWARE_DIR, FirmwareLib
from twin.params import load_params

RAW_PER_N = 45000.0
RAW_OFFSET = 8200


def test_cpp_unit_tests_pass_on_host():
    result = subprocess.run(["make", "-C", str(FIRMWARE_DIR), "host-test"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert " 0 failures" in result.stdout


class Board:
    """A FirmwareLib with a host on one side and still motors and steady load cells on the other."""

    def __init__(self):
        self.fw = FirmwareLib()
        self.decoder = c.FrameDecoder()
        self.now_us = 0
        self.seq = 0
        self.counts = [0, 0, 0, 0]
        self.tensions_n = [1.0, 1.0, 1.0, 1.0]
        self.frames: list[c.Frame] = []
        self.duty = np.zeros(4)

    def send(self, message: c.Message) -> int:
        self.seq += 1
        self.fw.receive(c.encode_frame(message, self.seq))
        self._drain()
        return self.seq

    def run(self, seconds: float, tick_us: int = 1000) -> None:
        for _ in range(round(seconds * 1e6 / tick_us)):
            self.now_us += tick_us
            raw = [RAW_OFFSET + round(RAW_PER_N * t) for t in self.tensions_n]
            mask = 0b1111 if self.now_us % 12500 < tick_us else 0
            self.duty = self.fw.tick(self.now_us, self.counts, raw, mask)
            self._drain()

    def replies(self, cls: type[c.Message]) -> list:
        return [f.message for f in self.frames if isinstance(f.message, cls)]

    def _drain(self) -> None:
        self.frames += self.decoder.feed(self.fw.take_tx())


def test_handshake_reports_the_rig_constants_of_the_parameter_set():
    board = Board()
    board.send(c.Hello())
    (reply,) = board.replies(c.HelloReply)
    rig = load_params().rig
    assert reply.protocol_version == c.PROTOCOL_VERSION
    assert reply.channels == 4
    assert reply.control_period_us == round(1e6 / rig.control_rate_hz)
    assert reply.telemetry_period_us == round(1e6 / rig.telemetry_rate_hz)
    assert reply.tendon_m_per_count == pytest.approx(rig.tendon_m_per_count, rel=1e-6)


def test_enable_needs_a_matching_handshake():
    board = Board()
    board.send(c.Hello(protocol_version=c.PROTOCOL_VERSION + 1))
    seq = board.send(c.Enable())
    assert board.replies(c.Nack)[-1] == c.Nack(seq, c.MsgType.ENABLE, c.NackError.NO_HANDSHAKE)
    board.send(c.Hello())
    seq = board.send(c.Enable())
    assert board.replies(c.Ack)[-1] == c.Ack(seq, c.MsgType.ENABLE)


def _enabled_board() -> Board:
    board = Board()
    board.send(c.Hello())
    board.run(0.05)  # fresh load-cell samples
    board.send(c.Enable())
    board.run(0.02)
    assert board.replies(c.TelemetryMessage)[-1].state == c.State.ENABLED
    return board


def test_length_setpoint_drives_the_motors_the_right_way():
    board = _enabled_board()
    assert np.all(board.duty == 0.0)  # enabled, holding where it is
    board.send(c.SetSetpoints.lengths([0.001, -0.001, 0.0, 0.0]))
    board.run(0.02)
    assert board.duty[0] > 0 and board.duty[1] < 0 and board.duty[2] == 0 and board.duty[3] == 0
    assert list(board.fw.drive_modes) == [c.Drive.DRIVE] * 4
    t = board.replies(c.TelemetryMessage)[-1]
    assert t.targets[:2] == pytest.approx((0.001, -0.001))
    assert t.duty[0] > 0 and t.duty[1] < 0 and t.drives() == (c.Drive.DRIVE,) * 4


def test_watchdog_stops_the_motors_when_the_host_goes_silent():
    board = _enabled_board()
    board.send(c.SetSetpoints.lengths([0.002, 0.0, 0.0, 0.0]))
    for _ in range(5):
        board.send(c.Ping())
        board.run(0.1)
    assert board.replies(c.TelemetryMessage)[-1].state == c.State.ENABLED
    board.run(0.3)  # silent for longer than the 250 ms default
    t = board.replies(c.TelemetryMessage)[-1]
    assert t.state == c.State.FAULT and t.fault_flags & c.Fault.WATCHDOG
    assert t.drives() == (c.Drive.COAST,) * 4 and np.all(board.duty == 0.0)
    board.send(c.Ping())
    board.run(0.05)
    assert board.replies(c.TelemetryMessage)[-1].state == c.State.FAULT  # latched
    board.send(c.Enable())
    board.run(0.03)
    assert board.replies(c.TelemetryMessage)[-1].state == c.State.ENABLED
    assert board.replies(c.TelemetryMessage)[-1].fault_flags == 0


def test_telemetry_at_40_hz_with_consecutive_sequence_numbers():
    board = Board()
    board.run(1.0)
    samples = board.replies(c.TelemetryMessage)
    assert len(samples) == 40
    assert [t.sample_seq for t in samples] == list(range(40))
    assert np.all(np.diff([t.time_us for t in samples]) == 25_000)


def test_garbage_from_the_host_is_counted_and_never_acted_on():
    board = Board()
    board.send(c.Hello())
    rng = np.random.default_rng(5)
    garbage = rng.integers(0, 256, 50_000).astype(np.uint8)
    garbage[rng.random(garbage.size) < 0.05] = 0
    enable = bytearray(c.encode_frame(c.Enable(), 99))
    enable[4] ^= 0x10  # the CRC no longer matches
    board.fw.receive(garbage.tobytes() + b"\x00" + bytes(enable))
    board.run(0.03)
    t = board.replies(c.TelemetryMessage)[-1]
    assert t.state == c.State.DISABLED
    assert board.replies(c.Ack) == [] and board.replies(c.Nack) == []
    assert t.rx_bad_frames > 2000


def test_tick_names_bad_arguments():
    fw = FirmwareLib()
    with pytest.raises(ValueError, match="encoder_counts"):
        fw.tick(0, [0, 0, 0], [0] * 4, 0)
    with pytest.raises(ValueError, match="raw_counts"):
        fw.tick(0, [0] * 4, [0, 0, 0, 2**31], 0)
    with pytest.raises(ValueError, match="new_mask = 16"):
        fw.tick(0, [0] * 4, [0] * 4, 16)
    fw.close()
    with pytest.raises(ValueError, match="closed"):
        fw.take_tx()


def _nack_error(board: Board, seq: int):
    (nack,) = [n for n in board.replies(c.Nack) if n.acked_seq == seq]
    return nack.error


@pytest.mark.parametrize("gain_n_per_count, offset_counts, why", [
    (-1 / RAW_PER_N, RAW_OFFSET, "counts falling with tension"),
    (1e-30, RAW_OFFSET, "1e30 counts/N"),
    (1 / (10 * RAW_PER_N), RAW_OFFSET, "a cell read ten times low"),
    (1 / RAW_PER_N, 1e9, "an offset beyond the HX711's range"),
])
def test_the_board_refuses_calibrations_outside_physical_bounds(gain_n_per_count, offset_counts, why):
    board = Board()
    board.send(c.Hello())
    seq = board.send(c.SetCalibration((1 / RAW_PER_N, gain_n_per_count, 1 / RAW_PER_N, 1 / RAW_PER_N),
                                      (RAW_OFFSET, offset_counts, RAW_OFFSET, RAW_OFFSET)))
    assert _nack_error(board, seq) == c.NackError.BAD_VALUE, why


def test_the_board_refuses_gains_that_multiply_out_to_nan():
    board = Board()
    board.send(c.Hello())
    seq = board.send(c.SetGains(c.Mode.LENGTHS, kp=3e38, ki=0.0, kd=3e38, output_limit=1.0))
    assert _nack_error(board, seq) == c.NackError.BAD_VALUE


def test_any_hello_stops_an_enabled_board():
    # A host restarted within the watchdog's 250 ms, or one of another version, must not take
    # over a board still driving the setpoints of the host before.
    for hello in (c.Hello(), c.Hello(protocol_version=c.PROTOCOL_VERSION + 1)):
        board = _enabled_board()
        board.send(c.SetSetpoints.lengths([0.002, 0.0, 0.0, 0.0]))
        board.run(0.05)
        assert board.replies(c.TelemetryMessage)[-1].state == c.State.ENABLED
        board.send(hello)
        board.run(0.03)
        t = board.replies(c.TelemetryMessage)[-1]
        assert t.state == c.State.DISABLED and np.all(board.duty == 0.0)
        seq = board.send(c.Enable())
        accepted = hello.protocol_version == c.PROTOCOL_VERSION
        assert (board.replies(c.Ack)[-1].acked_seq == seq) if accepted else (_nack_error(board, seq) == c.NackError.NO_HANDSHAKE)
