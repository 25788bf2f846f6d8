"""The rig driver reaches a board over the network: pyserial's ``socket://`` (raw TCP, as
``twin emulate --tcp`` and ser2net serve a port) and ``rfc2217://`` (a serial port shared by an
RFC 2217 server), over loopback, with the real :class:`twin.driver.Device` on the emulated board;
and URL schemes come from a registry other rooms add to."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import serial
import serial.rfc2217

from twin.device.pty_board import PtyBoard
from twin.driver import DeviceError, open_device, schemes
from twin.driver import url as device_url


def _drive_one_tendon(device) -> float:
    """Enable, pull tendon 1 in by 1 mm and return how far it went (m) after 0.5 s of wall time."""
    device.enable()
    start = device.latest().tendon_lengths_m.copy()
    target = start.copy()
    target[0] -= 1e-3
    device.set_lengths(target)
    device.wait(0.5)
    moved_m = start[0] - device.latest().tendon_lengths_m[0]
    device.disable()
    return float(moved_m)


def test_the_device_drives_a_board_served_over_tcp_and_closes_at_once():
    with PtyBoard(seed=2, tcp=("127.0.0.1", 0)) as board:
        assert board.url.startswith("socket://127.0.0.1:")
        device = open_device(board.url)
        info = device.connect()
        assert info.clock == "wall" and info.url == board.url and info.channels == 4
        device.drain()
        device.wait(0.3)
        # Telemetry streams at the board's 40 Hz over the socket: ~12 samples in 0.3 s.
        assert len(device.drain()) >= 6
        assert _drive_one_tendon(device) == pytest.approx(1e-3, abs=0.3e-3)
        # A second host is turned away while the first holds the board, as an exclusive port.
        with pytest.raises(DeviceError):
            open_device(board.url).connect(timeout_s=0.5)
        started_s = time.monotonic()
        device.close()  # a network port has no cancel_read: the reader stops within a read timeout
        assert time.monotonic() - started_s < 0.5
        # The board runs on; the next host connects once the first has hung up.
        with open_device(board.url) as again:
            assert again.info.channels == 4 and board.error is None


class _Rfc2217Server:
    """A serial port shared over TCP by pyserial's RFC 2217 port manager (what
    ``examples/rfc2217_server.py`` in pyserial does), for one client."""

    def __init__(self, port_url: str):
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.serial = serial.serial_for_url(port_url, timeout=0.05)
        self.stop = threading.Event()
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        connection, _ = self.listener.accept()
        connection.settimeout(0.05)
        manager = serial.rfc2217.PortManager(self.serial, _Writer(connection))

        def to_client():
            while not self.stop.is_set():
                data = self.serial.read(self.serial.in_waiting or 1)
                try:
                    connection.sendall(b"".join(manager.escape(data)))
                except OSError:
                    return  # the client hung up

        threading.Thread(target=to_client, daemon=True).start()
        while not self.stop.is_set():
            try:
                data = connection.recv(1024)
            except socket.timeout:
                continue
            if not data:
                break
            self.serial.write(b"".join(manager.filter(data)))
        connection.close()

    def close(self) -> None:
        self.stop.set()
        self.listener.close()
        time.sleep(0.1)
        self.serial.close()


class _Writer:
    def __init__(self, connection: socket.socket):
        self.connection = connection

    def write(self, data: bytes) -> None:
        self.connection.sendall(data)


def test_the_device_drives_a_board_behind_an_rfc2217_server():
    # The server's own port is the board on TCP (a pseudo-terminal has no modem lines to report).
    with PtyBoard(seed=3, tcp=("127.0.0.1", 0)) as board:
        server = _Rfc2217Server(board.url)
        try:
            with open_device(f"rfc2217://127.0.0.1:{server.port}") as device:
                assert device.info.url == f"rfc2217://127.0.0.1:{server.port}"
                assert _drive_one_tendon(device) == pytest.approx(1e-3, abs=0.3e-3)
        finally:
            server.close()


def test_twin_emulate_serves_board_tracker_and_fixture_over_tcp():
    """``twin emulate --tcp 0`` prints a ``socket://`` URL with its tracker and fixture: a host on
    another machine reaches the whole emulated rig through it."""
    process = subprocess.Popen([sys.executable, "-m", "twin.cli", "emulate", "--seed", "1", "--tcp", "0",
                                "--igtl-port", "0", "--fixture-port", "0"], stdout=subprocess.PIPE, text=True)
    try:
        process.stdout.readline()
        url = process.stdout.readline().split(":", 1)[1].strip()
        assert url.startswith("socket://127.0.0.1:") and "igtl=" in url and "fixture=" in url
        with open_device(url) as device:
            device.fixture.hang_tip_mass(0.01)
            for _ in range(40):  # the tracker's first frames arrive after the connection
                device.wait_next()
                fused = device.tracker.read()
                if fused.ok:
                    break
            assert fused.ok, fused.reason
            # The tip is a backbone's length from the clamp at the origin.
            assert np.linalg.norm(fused.pose.position_m) > 0.01
    finally:
        process.send_signal(signal.SIGTERM)
        process.communicate(timeout=20)
    assert process.returncode == 0


def test_twin_emulate_refuses_a_bad_tcp_port_in_one_line():
    run = subprocess.run([sys.executable, "-m", "twin.cli", "emulate", "--tcp", "70000"], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 2 and run.stderr.strip() == "twin emulate: --tcp 70000: expected 0..65535"


def test_a_scheme_module_named_in_the_registry_is_imported_when_its_scheme_is_asked_for(tmp_path, monkeypatch):
    """pyserial's pattern: a module listed by name registers its scheme on import, and only when a
    URL asks for a scheme not yet known (or the schemes are listed)."""
    (tmp_path / "loop_scheme.py").write_text(
        "from twin.driver.url import Scheme, register_scheme, _open_port, DeviceRequest\n"
        "import dataclasses\n"
        "def open_loop(request):\n"
        "    parts = request.parts._replace(scheme='socket', netloc='127.0.0.1:' + request.parts.netloc)\n"
        "    return _open_port(dataclasses.replace(request, parts=parts))\n"
        "register_scheme(Scheme('loopback', (), open_loop))\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(device_url, "SCHEME_MODULES", [*device_url.SCHEME_MODULES, "loop_scheme"])
    schemes()  # the twin's sim:// registered before the registry is copied, so the copy holds it
    monkeypatch.setattr(device_url, "_SCHEMES", dict(device_url._SCHEMES))
    monkeypatch.setattr(device_url, "_LOADED", set(device_url._LOADED))
    with PtyBoard(seed=4, tcp=("127.0.0.1", 0)) as board:
        tcp_port = board.port.rpartition(":")[2]
        with open_device(f"loopback://{tcp_port}") as device:
            assert device.info.channels == 4
    assert "loopback" in schemes()
    assert "loop_scheme" in device_url._LOADED
