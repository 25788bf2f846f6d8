"""Boards of any tendon count: the emulated board sized by its robot, the driver sized by the
board's HELLO_REPLY, and a board whose count is not the robot's refused at connect."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from twin.driver import ChannelCountError, CommandRejected, open_device
from twin.driver import codec as c
from twin.device.firmware_lib import FirmwareLib
from twin.device.pty_board import PtyBoard
from twin.params import load_params
from twin.robots import load_robot


def _evenly_routed(count: int):
    """The endoscope with ``count`` tendons evenly round its discs, its per-tendon errors off."""
    return load_params(overrides={"tendons.angles_deg": [360.0 * i / count for i in range(count)],
                                  "effects.tension_gain_error": [0.0] * count,
                                  "effects.tension_offset_error_n": [0.0] * count,
                                  "sensors.loadcell_offset_counts": [0.0] * count})


def _unloaded_calibration(device, params) -> tuple[list[float], list[float]]:
    """The parameter set's nominal gain, and the raw counts now (tendons coasting) as offsets."""
    raw = np.mean([device.wait_next().raw_counts for _ in range(4)], axis=0)
    return [params.sensors.loadcell_gain_counts_per_n] * device.channels, raw.tolist()


@pytest.mark.parametrize("robot", ["three-tendon", "two-segment"])
def test_a_sim_board_of_the_robots_tendon_count_drives_lengths_and_tensions(robot):
    params = load_robot(robot)
    n = params.tendons.count
    with open_device("sim://", params=params, robot=robot) as device:
        assert device.info.channels == device.channels == n
        sample = device.latest()
        for array in (sample.encoder_counts, sample.tendon_lengths_m, sample.raw_counts, sample.tensions_n,
                      sample.targets, sample.motor_commands):
            assert array.shape == (n,)
        assert len(sample.drives) == n

        device.tare()
        device.enable()
        step = [0.0] * n
        step[-1] = 0.001
        device.set_lengths(step)
        device.wait(1.0)
        sample = device.latest()
        assert sample.enabled and sample.targets[-1] == pytest.approx(0.001, abs=1e-7)
        assert sample.tendon_lengths_m[-1] == pytest.approx(0.001, abs=1e-4)
        assert np.all(np.abs(sample.tendon_lengths_m[:-1]) < 5e-5)

        device.disable()
        device.wait(0.2)
        gains, offsets = _unloaded_calibration(device, params)
        device.set_calibration(gain_counts_per_n=gains, offset_counts=offsets)
        device.set_mode("tensions")
        device.enable()
        device.set_tensions([1.0] * n)
        device.wait(1.5)
        sample = device.latest()
        assert sample.enabled and sample.fault_flags == 0
        truth = device.twin.true_tensions_n()
        assert truth.shape == (n,)
        np.testing.assert_allclose(truth, 1.0, atol=0.1)
        np.testing.assert_allclose(sample.tensions_n, truth, atol=0.05)

        with pytest.raises(ValueError, match=f"expected {n} finite numbers"):
            device.set_tensions([1.0] * (n + 1))


def test_pairs_of_six_tendons_are_tendon_k_and_k_plus_three():
    params = load_robot("two-segment")
    with open_device("sim://", params=params, robot="two-segment") as device:
        device.tare()
        device.set_mode("pairs")
        device.enable()
        start = device.latest().tendon_lengths_m.copy()
        with pytest.raises(ValueError, match="expected 3 finite numbers"):
            device.set_pairs([0.001, 0.0])
        device.set_pairs([0.001, 0.0, 0.0])
        device.wait(1.5)
        sample = device.latest()
        centre = 0.5 * (start[0] + start[3])
        assert sample.targets[0] == pytest.approx(centre + 0.001, abs=1e-6)
        assert sample.targets[3] == pytest.approx(centre - 0.001, abs=1e-6)
        assert sample.tendon_lengths_m[0] - sample.tendon_lengths_m[3] == pytest.approx(0.002, abs=2e-4)
        assert abs(sample.tendon_lengths_m[1] - sample.tendon_lengths_m[4]) < 1e-4


def test_pairs_on_an_odd_count_are_refused_by_host_and_board():
    params = load_robot("three-tendon")
    with open_device("sim://", params=params, robot="three-tendon") as device:
        with pytest.raises(ValueError, match=r"^mode = 'pairs': the board's 3 tendons do not form antagonistic pairs"):
            device.set_mode("pairs")
        with pytest.raises(ValueError, match="3 tendons do not form antagonistic pairs"):
            device.set_pairs([0.001])
        assert device.latest().mode is c.Mode.LENGTHS
    with pytest.raises(c.CodecError, match="channels = 3: pairs need an even count"):
        c.SetSetpoints.pairs([0.001], channels=3)
    # The board refuses it too, should a host send it.
    with FirmwareLib(channels=3) as board:
        board.receive(c.encode_frame(c.Hello(), seq=1) + c.encode_frame(c.SetMode(c.Mode.PAIRS), seq=2))
        answers = [f.message for f in c.FrameDecoder().feed(board.take_tx())]
    assert answers[0].channels == 3
    assert answers[1] == c.Nack(acked_seq=2, acked_type=c.MsgType.SET_MODE, error=c.NackError.BAD_VALUE)


def test_a_command_sized_for_another_count_is_refused_as_bad_length():
    with open_device("sim://", params=load_robot("three-tendon")) as device:
        device.enable()
        with pytest.raises(CommandRejected, match="BAD_LENGTH") as info:
            device._command(c.SetSetpoints.lengths([0.0] * 4, channels=4))
        assert info.value.error == c.NackError.BAD_LENGTH


def test_a_four_channel_board_is_refused_for_a_three_tendon_robot():
    with PtyBoard(load_robot("endoscope")) as board:
        device = open_device(board.url, params=load_robot("three-tendon"), robot="three-tendon")
        with pytest.raises(ChannelCountError) as info:
            device.connect(timeout_s=2.0)
        assert str(info.value) == f"board at {board.url} has 4 channels; robot 'three-tendon' has 3 tendons"
        assert (info.value.board_channels, info.value.tendons) == (4, 3)
        assert not device.connected
        # The same board serves the robot it was made for.
        with open_device(board.url, params=load_robot("endoscope")) as right:
            assert right.channels == 4


def test_a_pty_board_whose_thread_fails_says_why():
    board = PtyBoard(load_robot("three-tendon"))

    def diverge():
        raise RuntimeError("the simulation diverged")

    board.board.run_tick = diverge
    with board:
        deadline = time.monotonic() + 2.0
        while board.error is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert isinstance(board.error, RuntimeError) and "diverged" in str(board.error)
        assert not board._thread.is_alive()


def test_twin_emulate_exits_nonzero_with_one_line_when_the_board_cannot_start():
    env = dict(os.environ, CXX="/nonexistent/c++")
    result = subprocess.run([sys.executable, "-m", "twin.cli", "emulate", "--robot", "three-tendon"],
                            capture_output=True, text=True, timeout=120, env=env)
    assert result.returncode == 1
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("twin emulate: the board cannot start: ")
    assert "/nonexistent/c++" in lines[0]


@pytest.mark.parametrize("channels", [1, 2, 5, 8, c.MAX_CHANNELS])
def test_the_emulated_firmware_reports_its_count_and_sizes_its_telemetry(channels):
    with FirmwareLib(channels=channels) as board:
        board.receive(c.encode_frame(c.Hello(), seq=1))
        duty = board.tick(0, [0] * channels, [0] * channels, new_mask=(1 << channels) - 1)
        frames = [f.message for f in c.FrameDecoder().feed(board.take_tx())]
        assert duty.shape == (channels,) and board.drive_modes.shape == (channels,)
    hello, telemetry = frames
    assert hello.channels == channels and hello.protocol_version == c.PROTOCOL_VERSION
    assert telemetry.channels == channels and len(telemetry.duty) == len(telemetry.drive_modes) == channels
    with pytest.raises(ValueError, match="channels = 13: the firmware drives 1..12 motors"):
        FirmwareLib(channels=13)


def test_a_three_channel_board_on_a_pseudo_terminal_serves_its_robot():
    params = load_robot("three-tendon")
    with PtyBoard(params) as board, open_device(board.url, params=params, robot="three-tendon") as device:
        assert device.clock == "wall" and device.channels == 3
        device.tare()
        device.enable()
        device.set_lengths([0.0, 0.0005, 0.0])
        sample = device.wait_next()
        while sample.targets[1] == 0.0:
            sample = device.wait_next()
        assert sample.targets.tolist() == pytest.approx([0.0, 0.0005, 0.0], abs=1e-7)
        assert sample.tensions_n.shape == (3,) and len(sample.drives) == 3


@pytest.mark.parametrize("count", [2, 8])
def test_an_emulated_board_of_two_or_eight_tendons_drives_its_pairs(count):
    with open_device("sim://", params=_evenly_routed(count)) as device:
        assert device.channels == count
        device.tare()
        device.set_mode("pairs")
        device.enable()
        device.set_pairs([0.001] + [0.0] * (count // 2 - 1))
        device.wait(1.5)
        sample = device.latest()
        assert sample.enabled and sample.fault_flags == 0
        half = count // 2
        assert sample.targets[0] - sample.targets[half] == pytest.approx(0.002, abs=1e-6)
        assert sample.tendon_lengths_m[0] - sample.tendon_lengths_m[half] == pytest.approx(0.002, abs=2e-4)
