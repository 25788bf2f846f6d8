"""The emulated rig behind ``serial://``: its OpenIGTLink tracker, its automatic fixture, the
operator's prompts when there is no fixture, and the main job run end to end with no person."""

import io
import signal
import subprocess
import sys

import numpy as np
import pytest

from twin.cli import main
from twin.driver import open_device
from twin.device.emulated_rig import EmulatedRig
from twin.driver.fixture import FixtureUnavailable, OperatorFixture, RemoteFixture


def _ended_stdin(*_):
    raise EOFError


def test_an_operator_prompt_without_an_operator_is_one_line_naming_the_action():
    fixture = OperatorFixture(_ended_stdin)
    with pytest.raises(FixtureUnavailable, match=r"^no operator to ask \(stdin ended\) to: Hang 5 g at the tip, let it hang still; "
                                                 r".*fixture=host:port"):
        fixture.hang_tip_mass(0.005)


def test_the_automatic_fixture_acts_on_the_twin_and_refuses_what_it_cannot_do():
    with EmulatedRig(seed=2, igtl_port=None, fixture_port=0) as rig:
        port = rig.fixture.port
        fixture = RemoteFixture(rig.host, port, settle_s=0.05)
        try:
            fixture.hang_tip_mass(0.010)
            assert rig.board.call(lambda: rig.twin.tip_mass_kg) == pytest.approx(0.010)
            fixture.engage_holder()
            assert rig.board.call(lambda: rig.twin.holder_engaged)
            fixture.release_holder()
            assert not rig.board.call(lambda: rig.twin.holder_engaged)
            with pytest.raises(FixtureUnavailable, match=r"hang_calibration_mass: channels = \(7,\)"):
                fixture.hang_calibration_mass(100.0, [7])
            fixture.hang_tip_mass(0.0)  # the connection survives a refusal
            assert rig.fixture.actions[-1] == ("hang_tip_mass", [0.0])
        finally:
            fixture.close()
    with pytest.raises(FixtureUnavailable, match=r"^fixture at 127.0.0.1:\d+: hang_tip_mass: "):
        RemoteFixture("127.0.0.1", port).hang_tip_mass(0.0)  # the rig is gone


def test_the_emulated_tracker_streams_the_twins_tip_as_plus_names_it():
    with EmulatedRig(seed=3, igtl_port=0, fixture_port=None) as rig:
        assert "igtl_probes=Probe1ToTracker,Probe2ToTracker" in rig.url
        with open_device(rig.url) as device:
            for _ in range(40):
                device.wait_next()
                fused = device.tracker.read()
                if fused.ok:
                    break
            assert fused.ok, fused.reason
            truth = rig.board.call(lambda: rig.twin.tip_pose()[0])
            # The fused tip against the twin's: the probes' noise (0.2 mm) and a frame of age.
            assert np.linalg.norm(fused.pose.position_m - truth) < 1.5e-3
            assert rig.tracker.frames > 0


def test_validate_on_the_rig_without_an_operator_stops_in_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))
    with EmulatedRig(seed=4, igtl_port=0, fixture_port=None) as rig:
        code = main(["validate", "--quick", "--device", rig.url, "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 4, err
    (line,) = [l for l in err.splitlines() if "no operator" in l]
    assert "stdin ended" in line and "Traceback" not in err


@pytest.mark.slow
def test_validate_runs_the_quick_grid_unattended_against_twin_emulate(tmp_path, capsys, monkeypatch):
    """The hardware-in-the-loop switch: the main job on ``serial://`` through the real serial driver,
    protocol, OpenIGTLink client and fusion, ``twin emulate`` serving the tracker and hanging the
    masses; stdin at its end, so any prompt to an operator would stop it. About 2 minutes."""
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))
    process = subprocess.Popen([sys.executable, "-m", "twin.cli", "emulate", "--seed", "1", "--igtl-port", "0",
                                "--fixture-port", "0"], stdout=subprocess.PIPE, text=True)
    try:
        process.stdout.readline()
        url = process.stdout.readline().split(":", 1)[1].strip()
        assert "igtl=" in url and "fixture=" in url
        code = main(["validate", "--quick", "--device", url, "--out", str(tmp_path)])
        first = capsys.readouterr()
        if code != 0:
            # A host starved of the CPU for a quarter second (a loaded 2-core machine) trips the
            # board's watchdog, as on the rig; the run then goes on as a lab's would, resumed.
            assert code == 4 and "WATCHDOG" in first.err, first.err
            (run,) = tmp_path.glob("validate-*")
            code = main(["validate", "--resume", str(run), "--quick", "--device", url])
        assert code == 0, capsys.readouterr().err
    finally:
        process.send_signal(signal.SIGTERM)
        process.communicate(timeout=10)
    (run,) = tmp_path.glob("validate-*")
    from twin.data.dataset import read_dataset

    dataset = read_dataset(run / "dataset")
    assert len(dataset) == 24
    out = first.out + capsys.readouterr().out
    assert "24 configurations, 0 failed predictions" in out
    # The same figures as on sim:// (median ~0.1 mm): the tracker and fixture are the twin's.
    median_mm = float(out.split("prediction error median ")[1].split(" mm")[0])
    assert median_mm < 0.5, out


def test_twin_emulate_serves_on_the_ports_asked_and_refuses_a_taken_one_in_one_line(tmp_path):
    import socket

    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        result = subprocess.run([sys.executable, "-m", "twin.cli", "emulate", "--igtl-port", str(port),
                                 "--fixture-port", "0"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert "cannot listen: Address already in use" in result.stderr and len(result.stderr.strip().splitlines()) == 1
    with socket.create_server(("127.0.0.1", 0)) as free:
        port = free.getsockname()[1]
    process = subprocess.Popen([sys.executable, "-m", "twin.cli", "emulate", "--igtl-port", str(port),
                                "--fixture-port", "-1"], stdout=subprocess.PIPE, text=True)
    try:
        process.stdout.readline()
        url = process.stdout.readline().split(":", 1)[1].strip()
        assert f"igtl=127.0.0.1:{port}&" in url and "fixture" not in url
    finally:
        process.send_signal(signal.SIGTERM)
        process.communicate(timeout=10)
    assert process.returncode == 0
