"""OpenIGTLink both ways, checked against pyigtl (an independent implementation) on loopback.

pyigtl's server feeds our tracker client (:class:`twin.driver.igtl_source.OpenIGTLinkSource`) as
PLUS would; pyigtl's client reads our server (:class:`twin.device.igtl_server.OpenIGTLinkServer`).
Ports are ephemeral, so the suite's parallel workers never collide.
"""

import signal
import socket
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from twin.driver import igtl
from twin.device.igtl_server import OpenIGTLinkServer, probe_rotation, twin_messages
from twin.driver.igtl_source import IgtlSettings, OpenIGTLinkSource, settings_from_options
from twin.driver.url import open_device
from twin.pose import matrix_to_quat, quat_to_matrix, rot_x, rot_z
from twin.tracking import CapCalibration, FrameStatus, FusionSettings, ProbeReading, fuse_frame

pyigtl = pytest.importorskip("pyigtl")

CAL = CapCalibration()
PLUS_NAMES = ("Probe1ToTracker", "Probe2ToTracker")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(predicate, timeout_s=10.0, what="condition"):
    # generous: the machine may be loaded; a passing test never waits this long
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.01)
    raise AssertionError(f"{what} not met within {timeout_s} s")


def probe_readings(rotation, position_m, cal=CAL):
    """World-frame readings of both probes for a tip at (rotation, position_m)."""
    return [ProbeReading(position_m + rotation @ np.asarray(c), rotation @ np.asarray(a), 0.0)
            for c, a in ((cal.position_a_m, cal.axis_a), (cal.position_b_m, cal.axis_b))]


def tool_matrix(reading, *, roll_rad=0.3, axis_column=2, axis_sign=1.0, unit_m=1e-3):
    """4×4 tool transform of a 5-DOF probe: ``axis_sign · axis`` as column ``axis_column``, an
    arbitrary roll about it, translation in units of ``unit_m``."""
    r = probe_rotation(axis_sign * reading.axis) @ rot_z(roll_rad)
    cols = [r[:, 0], r[:, 1]]
    cols.insert(axis_column, r[:, 2])
    if np.linalg.det(np.column_stack(cols)) < 0:
        cols[(axis_column + 1) % 3] = -cols[(axis_column + 1) % 3]
    m = np.eye(4)
    m[:3, :3] = np.column_stack(cols)
    m[:3, 3] = reading.position_m / unit_m
    return m


@pytest.fixture
def restore_signals():
    """pyigtl's server installs SIGINT/SIGTERM handlers; put ours back afterwards."""
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    yield
    for sig, handler in handlers.items():
        signal.signal(sig, handler)


@pytest.fixture
def plus(restore_signals):
    """A pyigtl server standing in for PLUS, on a free port, and a factory of our clients to it."""
    port = free_port()
    server = pyigtl.OpenIGTLinkServer(port=port, local_server=True)
    clients = []

    def connect(**overrides):
        # pyigtl's server serves one connection at a time and loses a message when the old one
        # breaks, so these clients must not drop a connection over the tests' own pauses.
        overrides.setdefault("idle_timeout_s", 60.0)
        source = OpenIGTLinkSource("127.0.0.1", port, **overrides)
        clients.append(source)
        wait_for(lambda: source.connected, what="client connected")
        return source

    try:
        yield server, connect, port
    finally:
        for source in clients:  # clients first: the pyigtl server waits for its handler to end
            source.close()
        server.stop()


def send(server, message, *, version=1, metadata=None):
    message.header_version = version
    if metadata:
        message.metadata = dict(metadata)
    server.send_message(message, wait=True)


def send_probes(server, readings, *, names=PLUS_NAMES, timestamp=None, **matrix_kw):
    timestamp = time.time() if timestamp is None else timestamp
    for name, reading in zip(names, readings):
        send(server, pyigtl.TransformMessage(tool_matrix(reading, **matrix_kw), timestamp=timestamp, device_name=name))


def read_fused(source, predicate=lambda r: r.ok, timeout_s=10.0, **fuse_kw):
    return wait_for(lambda: (lambda r: r if predicate(r) else None)(fuse_frame(source.read(), **fuse_kw)),
                    timeout_s, "matching fused frame")


# --------------------------------------------------------------------------- wire format

def test_crc64_is_ecma_182_as_pyigtl_computes_it():
    from pyigtl.messages import CRC64  # crcmod's table, built from the polynomial independently

    assert igtl.crc64(b"123456789") == 0x6C40DF5F0B497347  # the published check value
    rng = np.random.default_rng(0)
    for size in (0, 1, 7, 48, 1000):
        data = rng.integers(0, 256, size, dtype=np.uint8).tobytes()
        assert igtl.crc64(data) == CRC64(data)


@pytest.mark.parametrize("version", [1, 2])
def test_pyigtl_transform_decodes_with_timestamp_and_metadata(version):
    m = np.eye(4)
    m[:3, :3] = rot_x(0.4) @ rot_z(1.1)
    m[:3, 3] = [12.5, -3.25, 140.0]
    message = pyigtl.TransformMessage(m, timestamp=1_700_000_000.123456, device_name="Probe1ToTracker")
    message.header_version = version
    if version == 2:
        message.metadata = {"TransformStatus": "OK", "Unit": "mm"}
    raw = message.pack()
    ours = igtl.decode(raw[:igtl.HEADER_SIZE], raw[igtl.HEADER_SIZE:])
    assert (ours.type, ours.device, ours.version) == ("TRANSFORM", "Probe1ToTracker", version)
    assert ours.timestamp_s == pytest.approx(1_700_000_000.123456, abs=1e-6)
    assert ours.metadata == ({"TransformStatus": "OK", "Unit": "mm"} if version == 2 else {})
    pose = igtl.decode_pose(ours)
    np.testing.assert_allclose(pose.rotation, m[:3, :3], atol=1e-7)
    np.testing.assert_allclose(pose.translation, m[:3, 3], atol=1e-5)


@pytest.mark.parametrize("version", [1, 2])
def test_our_messages_unpack_in_pyigtl(version):
    rotation, t_mm = rot_x(-0.7), np.array([1.0, 2.0, 3.0])
    meta = {"Status": "OK"} if version == 2 else None
    raw = igtl.pack("TRANSFORM", "TipToTracker", igtl.encode_transform(rotation, t_mm), timestamp_s=1234.5,
                    version=version, metadata=meta)
    header = pyigtl.MessageBase.parse_header(raw[:igtl.HEADER_SIZE])
    message = pyigtl.TransformMessage()
    message.unpack(header, raw[igtl.HEADER_SIZE:])
    np.testing.assert_allclose(message.matrix[:3, :3], rotation, atol=1e-7)
    np.testing.assert_allclose(message.matrix[:3, 3], t_mm)
    assert message.timestamp == pytest.approx(1234.5) and message.metadata == (meta or {})

    points = np.array([[0.0, 0, 0], [1.5, -2, 30], [4, 5, 60.25]])
    raw = igtl.pack("POINT", "BackbonePoints", igtl.encode_point(points, group="Backbone"), timestamp_s=1.0)
    message = pyigtl.PointMessage()
    message.unpack(pyigtl.MessageBase.parse_header(raw[:igtl.HEADER_SIZE]), raw[igtl.HEADER_SIZE:])
    np.testing.assert_allclose(message.positions, points)
    assert message.names == ["P1", "P2", "P3"] and message.groups == ["Backbone"] * 3


def test_position_layouts_standard_and_pyigtl():
    q = matrix_to_quat(rot_x(0.9) @ rot_z(-0.4))  # (w, x, y, z), w >= 0
    xyz = [10.0, -20.0, 30.0]
    for content in (struct.pack(">7f", *xyz, q[1], q[2], q[3], q[0]), struct.pack(">6f", *xyz, q[1], q[2], q[3])):
        pose = igtl.decode_pose(igtl.Message("POSITION", "P", 0.0, content))
        np.testing.assert_allclose(pose.translation, xyz)
        np.testing.assert_allclose(pose.rotation, quat_to_matrix(q), atol=1e-6)
    assert igtl.decode_pose(igtl.Message("POSITION", "P", 0.0, struct.pack(">3f", *xyz))).rotation is None

    raw = pyigtl.PositionMessage(xyz, [q[1], q[2], q[3], q[0]], device_name="P").pack()
    ours = igtl.decode(raw[:igtl.HEADER_SIZE], raw[igtl.HEADER_SIZE:])
    np.testing.assert_allclose(igtl.decode_pose(ours).rotation, quat_to_matrix(q), atol=1e-6)
    with pytest.raises(igtl.MessageError, match="13 bytes"):
        igtl.decode_pose(igtl.Message("POSITION", "P", 0.0, bytes(13)))


def test_corrupt_body_and_oversized_header_are_refused():
    raw = bytearray(igtl.pack("TRANSFORM", "X", igtl.encode_transform(np.eye(3), [0, 0, 0]), timestamp_s=1.0))
    raw[-1] ^= 0x01
    with pytest.raises(igtl.MessageError, match="CRC mismatch"):
        igtl.decode(bytes(raw[:igtl.HEADER_SIZE]), bytes(raw[igtl.HEADER_SIZE:]))
    header = struct.pack(">H12s20sIIQQ", 1, b"TRANSFORM", b"X", 0, 0, 2**40, 0)
    with pytest.raises(igtl.MessageError, match="not an OpenIGTLink stream"):
        igtl.unpack_header(header)
    with pytest.raises(ValueError, match="longer than 20 bytes"):
        igtl.pack("TRANSFORM", "A" * 21, b"", timestamp_s=0.0)


def test_polydata_layout():
    points = np.array([[0.0, 0, 0], [1, 2, 3], [4, 5, 6]])
    content = igtl.encode_polydata(points, lines=[[0, 1, 2]])
    counts = struct.unpack_from(">10I", content)
    # points 3; no vertices; one line of 4 uint32 (count + 3 indices); no polygons, strips, attributes
    assert counts == (3, 0, 0, 1, 16, 0, 0, 0, 0, 0)
    assert struct.unpack_from(">4I", content, 40 + 36) == (3, 0, 1, 2)
    decoded, lines = igtl.decode_polydata(content)
    np.testing.assert_allclose(decoded, points)
    assert lines == [[0, 1, 2]]


# --------------------------------------------------------------------------- pyigtl server → our client

def test_plus_style_names_give_every_frame(plus):
    server, connect, _ = plus
    source = connect(device_a=PLUS_NAMES[0], device_b=PLUS_NAMES[1])
    rng = np.random.default_rng(5)
    ok = 0
    for _ in range(40):
        rotation, position = quat_to_matrix(rng.normal(size=4)), rng.normal(scale=0.05, size=3)
        readings = probe_readings(rotation, position)
        send_probes(server, readings, roll_rad=rng.uniform(-3, 3))
        result = read_fused(source, lambda r: r.ok and np.allclose(r.pose.position_m, position, atol=1e-5))
        ok += result.ok
        np.testing.assert_allclose(result.pose.rotation, rotation, atol=1e-5)
    assert ok == 40
    assert source.bad_messages == 0 and source.messages >= 80


def test_default_names_do_not_match_plus_names(plus):
    server, connect, _ = plus
    source = connect()
    send_probes(server, probe_readings(np.eye(3), np.array([0.0, 0.0, 0.1])))
    wait_for(lambda: source.messages >= 2, what="messages received")
    assert fuse_frame(source.read()).status is FrameStatus.INVALID


def test_position_alone_and_beside_a_transform_of_the_same_name(plus):
    server, connect, _ = plus
    source = connect(device_a=PLUS_NAMES[0], device_b=PLUS_NAMES[1])
    rotation, position = rot_x(0.5) @ rot_z(0.2), np.array([0.02, -0.01, 0.15])
    readings = probe_readings(rotation, position)

    def send_positions():
        for name, reading in zip(PLUS_NAMES, readings):
            m = tool_matrix(reading)
            w, x, y, z = matrix_to_quat(m[:3, :3])
            send(server, pyigtl.PositionMessage(m[:3, 3], [x, y, z, w], timestamp=time.time(), device_name=name))

    send_positions()
    result = read_fused(source)
    np.testing.assert_allclose(result.pose.position_m, position, atol=1e-5)
    np.testing.assert_allclose(result.pose.rotation, rotation, atol=1e-5)

    moved = position + [0.01, 0.0, 0.0]
    readings = probe_readings(rotation, moved)
    send_probes(server, readings)  # TRANSFORMs of the same names, then POSITIONs again
    send_positions()
    result = read_fused(source, lambda r: r.ok and np.allclose(r.pose.position_m, moved, atol=1e-5))
    assert source.bad_messages == 0


@pytest.mark.parametrize("axis,column,sign", [("-z", 2, -1.0), ("x", 0, 1.0), ("-y", 1, -1.0)])
def test_axis_and_scale_conventions(plus, axis, column, sign):
    server, connect, _ = plus
    settings = settings_from_options({"igtl_probes": ",".join(PLUS_NAMES), "igtl_axis": axis, "igtl_scale": "m"})
    assert (settings.axis_column, settings.axis_sign, settings.position_scale_m) == (column, sign, 1.0)
    source = connect(settings=settings)
    rotation, position = rot_z(1.0) @ rot_x(-0.3), np.array([0.3, 0.1, -0.2])
    send_probes(server, probe_readings(rotation, position), axis_column=column, axis_sign=sign, unit_m=1.0)
    result = read_fused(source)
    np.testing.assert_allclose(result.pose.position_m, position, atol=1e-6)
    np.testing.assert_allclose(result.pose.rotation, rotation, atol=1e-5)


def test_server_clock_half_a_second_off_is_measured(plus):
    server, connect, _ = plus
    measured = connect(device_a=PLUS_NAMES[0], device_b=PLUS_NAMES[1])
    other_port = free_port()
    other = pyigtl.OpenIGTLinkServer(port=other_port, local_server=True)  # pyigtl serves one client each
    fixed = OpenIGTLinkSource("127.0.0.1", other_port, device_a=PLUS_NAMES[0], device_b=PLUS_NAMES[1],
                              clock_offset_s=0.0, idle_timeout_s=60.0)
    try:
        wait_for(lambda: fixed.connected, what="second client connected")
        readings = probe_readings(rot_z(0.3), np.array([0.0, 0.05, 0.1]))
        settings = FusionSettings(max_age_s=0.3)  # well below the 0.5 s offset, well above a loaded machine's delays
        statuses = []
        for _ in range(10):
            stamp = time.time() - 0.5
            send_probes(server, readings, timestamp=stamp)
            send_probes(other, readings, timestamp=stamp)
            time.sleep(0.02)
            statuses.append(fuse_frame(measured.read(), settings=settings).status)
        wait_for(lambda: fixed.messages >= 20, what="second client fed")
        assert statuses[-5:] == [FrameStatus.OK] * 5
        assert measured.clock_offset_s == pytest.approx(-0.5, abs=0.05)
        # Taking the server's clock as ours, every frame is half a second old.
        assert fuse_frame(fixed.read(), settings=settings).status is FrameStatus.STALE
        # A probe that goes silent still ages in the measured clock.
        time.sleep(0.4)
        assert fuse_frame(measured.read(), settings=settings).status is FrameStatus.STALE
    finally:
        fixed.close()
        other.stop()


def test_unstamped_messages_take_their_arrival_time(plus):
    server, connect, _ = plus
    source = connect(device_a=PLUS_NAMES[0], device_b=PLUS_NAMES[1])
    send_probes(server, probe_readings(np.eye(3), np.array([0.0, 0.0, 0.1])), timestamp=0)
    result = read_fused(source)
    assert result.pose.timestamp_s == pytest.approx(time.time(), abs=1.0)


def test_transform_status_invalid_marks_the_probe(plus):
    server, connect, _ = plus
    source = connect(device_a=PLUS_NAMES[0], device_b=PLUS_NAMES[1])
    readings = probe_readings(np.eye(3), np.array([0.0, 0.0, 0.1]))
    now = time.time()
    for name, reading, status in zip(PLUS_NAMES, readings, ("OK", "INVALID")):
        send(server, pyigtl.TransformMessage(tool_matrix(reading), timestamp=now, device_name=name),
             version=2, metadata={"TransformStatus": status})
    result = read_fused(source, lambda r: r.status is FrameStatus.INVALID and source.messages >= 2)
    assert "probe B" in result.reason


def test_reconnects_after_the_server_restarts(plus, restore_signals):
    server, connect, port = plus
    source = connect(device_a=PLUS_NAMES[0], device_b=PLUS_NAMES[1])
    readings = probe_readings(np.eye(3), np.array([0.0, 0.0, 0.1]))
    send_probes(server, readings)
    read_fused(source)
    server.stop()
    wait_for(lambda: not source.connected, what="dead connection noticed")
    restarted = pyigtl.OpenIGTLinkServer(port=port, local_server=True)
    try:
        wait_for(lambda: source.connected, what="reconnected")
        moved = probe_readings(np.eye(3), np.array([0.01, 0.0, 0.1]))
        send_probes(restarted, moved)
        read_fused(source, lambda r: r.ok and r.pose.position_m[0] == pytest.approx(0.01, abs=1e-6))
        assert source.connections >= 2  # a connect may land in the old listener while it closes
    finally:
        source.close()
        restarted.stop()


def test_a_silent_connection_is_taken_as_dead():
    with socket.create_server(("127.0.0.1", 0)) as listener:
        port = listener.getsockname()[1]
        accepted = []

        def accept():
            while len(accepted) < 3:
                try:
                    accepted.append(listener.accept()[0])
                except OSError:
                    return

        thread = threading.Thread(target=accept, daemon=True)
        thread.start()
        with OpenIGTLinkSource("127.0.0.1", port, idle_timeout_s=0.2) as source:
            wait_for(lambda: source.connections >= 3, what="idle connections reopened")
        listener.close()
        for conn in accepted:
            conn.close()


def test_a_corrupt_message_is_counted_and_the_stream_goes_on():
    readings = probe_readings(np.eye(3), np.array([0.0, 0.0, 0.1]))
    good = [pyigtl.TransformMessage(tool_matrix(r), timestamp=time.time(), device_name=n).pack()
            for n, r in zip(PLUS_NAMES, readings)]
    bad = bytearray(good[0])
    bad[-1] ^= 0xFF
    with socket.create_server(("127.0.0.1", 0)) as listener:
        with OpenIGTLinkSource("127.0.0.1", listener.getsockname()[1], device_a=PLUS_NAMES[0],
                               device_b=PLUS_NAMES[1]) as source:
            conn, _ = listener.accept()
            with conn:
                conn.sendall(bytes(bad) + good[1])
                wait_for(lambda: source.bad_messages == 1 and source.messages == 1, what="corrupt one dropped")
                assert fuse_frame(source.read()).status is FrameStatus.INVALID
                conn.sendall(good[0])
                assert read_fused(source).ok


# --------------------------------------------------------------------------- our server → pyigtl client

@pytest.fixture
def our_server():
    with OpenIGTLinkServer("127.0.0.1", 0) as server:
        yield server


@pytest.mark.parametrize("version", [1, 2])
def test_pyigtl_reads_our_frames(our_server, version):
    client = pyigtl.OpenIGTLinkClient("127.0.0.1", our_server.port)
    try:
        wait_for(lambda: our_server.clients == 1, what="pyigtl connected")
        tip = (np.array([0.01, 0.02, 0.2]), rot_x(0.3))
        model_tip = (np.array([0.011, 0.019, 0.2]), rot_x(0.31))
        backbone = np.column_stack([np.zeros(5), np.zeros(5), np.linspace(0, 0.2, 5)])
        readings = probe_readings(tip[1], tip[0])
        probes = (np.array([r.position_m for r in readings]), np.array([r.axis for r in readings]))
        stamp = time.time()
        messages = twin_messages(timestamp_s=stamp, tip_pose=tip, backbone_m=backbone, probes=probes,
                                 predicted_tip_pose=model_tip, predicted_backbone_m=backbone[:4], version=version)
        assert our_server.send(messages) == 1
        for name, (position_m, rotation) in (("TipToTracker", tip), ("ModelTipToTracker", model_tip)):
            message = client.wait_for_message(name, timeout=10)
            assert message is not None, name
            np.testing.assert_allclose(message.matrix[:3, 3], position_m * 1e3, rtol=1e-6)
            np.testing.assert_allclose(message.matrix[:3, :3], rotation, atol=1e-6)
            assert message.timestamp == pytest.approx(stamp, abs=1e-6)
        for name, shape in (("BackbonePoints", backbone), ("ModelBackbonePoints", backbone[:4])):
            message = client.wait_for_message(name, timeout=10)
            np.testing.assert_allclose(np.array(message.positions), shape * 1e3, atol=1e-4)
        for name, reading in zip(PLUS_NAMES, readings):
            message = client.wait_for_message(name, timeout=10)
            np.testing.assert_allclose(message.matrix[:3, 2], reading.axis, atol=1e-6)
            np.testing.assert_allclose(message.matrix[:3, 3], reading.position_m * 1e3, rtol=1e-6)
    finally:
        client.stop()


def test_our_client_reads_our_server_of_the_twin(our_server):
    """The twin's probes, streamed as PLUS would, fuse back to the twin's tip pose."""
    from twin.params import load_params
    from twin.sim.plant import Plant
    from twin.rod.grid import pcc_tensions_n

    params = load_params()
    plant = Plant(params, seed=1)
    plant.set_tensions(pcc_tensions_n(20.0, 45.0, params))
    plant.step(0.5)
    frame = plant.tracker_probes()
    with OpenIGTLinkSource("127.0.0.1", our_server.port, device_a=PLUS_NAMES[0], device_b=PLUS_NAMES[1]) as source:
        wait_for(lambda: our_server.clients == 1, what="client connected")
        our_server.send(twin_messages(timestamp_s=time.time(), probes=(frame.positions_m, frame.axes)))
        result = read_fused(source, settings=FusionSettings.from_params(params))
    position_m, _ = plant.tip_pose()
    noise_m = params.sensors.tracker_noise_m
    assert np.linalg.norm(result.pose.position_m - position_m) < 5 * max(noise_m, 1e-6)


def test_twin_igtl_serve_streams_to_pyigtl():
    """The command as an operator runs it: its own process, a free port it prints, SIGTERM to stop."""
    process = subprocess.Popen([sys.executable, "-m", "twin.cli", "igtl-serve", "--port", "0", "--rate-hz", "10"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = process.stdout.readline()
        assert first.startswith("serving OpenIGTLink on 127.0.0.1:"), first + process.stderr.read()
        port = int(first.rsplit(":", 1)[1])
        client = pyigtl.OpenIGTLinkClient("127.0.0.1", port)
        try:
            assert client.wait_for_message("TipToTracker", timeout=60) is not None
            # Past the start the twin follows the slow sweep; a loaded machine may make the loop
            # skip ahead now and then, so the closest of a few frames is compared.
            time.sleep(1.0)
            frames = []
            for _ in range(8):
                time.sleep(0.25)
                frames.append({m.device_name: m for m in client.get_latest_messages()})
        finally:
            client.stop()
        process.send_signal(signal.SIGTERM)
        out, err = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 0, err
    assert "stopped after" in out
    # whole frames only: a snapshot may fall between two messages of one frame
    devices = ("TipToTracker", "ModelTipToTracker", "BackbonePoints", "ModelBackbonePoints", PLUS_NAMES[0])
    frames = [f for f in frames if all(d in f for d in devices)
              and len({f[d].timestamp for d in devices}) == 1]
    assert frames
    gaps_mm = []
    for frame in frames:
        tip, model_tip = frame["TipToTracker"].matrix[:3, 3], frame["ModelTipToTracker"].matrix[:3, 3]
        gaps_mm.append(np.linalg.norm(model_tip - tip))
        assert np.linalg.norm(frame[PLUS_NAMES[0]].matrix[:3, 3] - tip) < 10.0  # a probe, in the cap
        np.testing.assert_allclose(frame["ModelBackbonePoints"].positions[-1], model_tip, atol=1e-3)
        np.testing.assert_allclose(frame["BackbonePoints"].positions[-1], tip, atol=1e-3)
    # the twin's tip and the predictor's agree to the predictor's accuracy (mm)
    assert min(gaps_mm) < 3.0


# --------------------------------------------------------------------------- device URL

def test_url_keys_reach_the_tracker():
    url = ("serial:///dev/ttyACM0?igtl=127.0.0.1:1&igtl_probes=Probe1ToTracker,Probe2ToTracker&igtl_axis=-z"
           "&igtl_scale=m&igtl_clock=0.25&igtl_timeout_s=3&cap_a_mm=0,-4,2&cap_b_axis=0,2,0")
    tracker = open_device(url).tracker
    assert tracker.calibration.position_a_m == pytest.approx((0.0, -0.004, 0.002))
    assert tracker.calibration.axis_b == (0.0, 1.0, 0.0)
    source = tracker._open_source()
    try:
        assert source.settings == IgtlSettings(device_a="Probe1ToTracker", device_b="Probe2ToTracker", axis_column=2,
                                               axis_sign=-1.0, position_scale_m=1.0, clock_offset_s=0.25,
                                               idle_timeout_s=3.0)
    finally:
        source.close()


@pytest.mark.parametrize("query,message", [
    ("igtl_probes=Probe1ToTracker", r"igtl_probes = 'Probe1ToTracker': expected two device names"),
    ("igtl_axis=w", r"igtl_axis = 'w': expected x, y or z"),
    ("igtl_scale=inch", r"igtl_scale = 'inch': expected mm, cm, m"),
    ("igtl_scale=-1", r"igtl_scale = '-1': .*must be finite and > 0"),
    ("igtl_clock=soon", r"igtl_clock = 'soon': expected auto"),
    ("igtl_timeout_s=0", r"igtl_timeout_s = '0': .*> 0"),
    ("cap_a_mm=1,2", r"cap_a_mm = '1,2': expected 3 numbers"),
    ("cap_b_axis=1,0,0", r"cap_b_axis = '1,0,0': .*nearly parallel"),
])
def test_bad_url_values_name_key_and_value(query, message):
    with pytest.raises(ValueError, match=message) as info:
        open_device(f"serial:///dev/ttyACM0?igtl=127.0.0.1:18944&{query}")
    assert "\n" not in str(info.value)


def test_tracker_keys_need_igtl():
    with pytest.raises(ValueError, match="igtl_axis configure the tracker; give igtl=host:port"):
        open_device("serial:///dev/ttyACM0?igtl_axis=z")


def test_twin_igtl_serve_refuses_bad_probe_names(capsys):
    from twin.cli import main

    assert main(["igtl-serve", "--probes", "Probe1ToTracker,Probe1ToTracker", "--duration-s", "1"]) == 2
    assert "--probes: igtl_probes = 'Probe1ToTracker,Probe1ToTracker'" in capsys.readouterr().err
