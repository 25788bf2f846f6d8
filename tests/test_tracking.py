"""EM tracker fusion: known poses recovered, proper rotations, bad frames rejected, OpenIGTLink."""

import math
import signal
import socket
import time

import numpy as np
import pytest

from twin.params import load_params
from twin.pose import quat_to_matrix, rot_z
from twin.tracking import (
    CallableSource,
    CapCalibration,
    FrameStatus,
    FusionSettings,
    ProbeReading,
    fuse,
    fuse_frame,
)
from twin.tracking_kernels import _wahba
from twin.driver.igtl_source import OpenIGTLinkSource

CAL = CapCalibration()


def random_rotation(rng):
    return quat_to_matrix(rng.normal(size=4))


def rotation_error_rad(r_est, r_true):
    cos = (np.trace(r_est.T @ r_true) - 1.0) / 2.0
    return math.acos(min(1.0, max(-1.0, cos)))


def perturb_axis(rng, axis, noise_rad):
    """Axis tilted by noise_rad RMS: rotation vector σ = noise_rad/√2 per component, of which
    the two perpendicular to the axis tilt it; quaternion vector part is half the rotation vector."""
    q_sigma = noise_rad / (2 * math.sqrt(2))
    return quat_to_matrix(np.concatenate([[1.0], rng.normal(scale=q_sigma, size=3)])) @ axis


def probe_readings(rotation, position_m, cal=CAL, *, t_s=0.0, rng=None, noise_m=0.0, noise_rad=0.0):
    """World-frame readings of both probes for a tip at (rotation, position_m)."""
    out = []
    for c, axis in ((cal.position_a_m, cal.axis_a), (cal.position_b_m, cal.axis_b)):
        p = position_m + rotation @ np.asarray(c)
        a = rotation @ np.asarray(axis)
        if rng is not None:
            p = p + rng.normal(scale=noise_m, size=3)
            a = perturb_axis(rng, a, noise_rad)
        out.append(ProbeReading(p, a, t_s))
    return out


def assert_proper_rotation(r):
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-12)


def test_fuse_recovers_random_poses_exactly_without_noise():
    rng = np.random.default_rng(1)
    for _ in range(200):
        rotation, position = random_rotation(rng), rng.normal(scale=0.05, size=3)
        result = fuse(*probe_readings(rotation, position))
        assert result.ok, result.reason
        assert_proper_rotation(result.pose.rotation)
        np.testing.assert_allclose(result.pose.rotation, rotation, atol=1e-12)
        np.testing.assert_allclose(result.pose.position_m, position, atol=1e-14)
        np.testing.assert_allclose(quat_to_matrix(result.pose.quaternion), rotation, atol=1e-12)


def test_fuse_error_matches_the_sensor_noise():
    rng = np.random.default_rng(2)
    noise_m, noise_rad = 0.0002, 0.002
    pos_err, rot_err = [], []
    for _ in range(1000):
        rotation, position = random_rotation(rng), rng.normal(scale=0.05, size=3)
        result = fuse(*probe_readings(rotation, position, rng=rng, noise_m=noise_m, noise_rad=noise_rad))
        if result.ok:
            pos_err.append(np.linalg.norm(result.pose.position_m - position))
            rot_err.append(rotation_error_rad(result.pose.rotation, rotation))
    # Thresholds sit at ~3.5 sigma of the probe distance: almost every noisy frame passes.
    assert len(pos_err) >= 990
    # Position: mean of two probes, each σ per axis → RMS norm σ·sqrt(3/2); the rotation's
    # contribution (a few µm at 3 mm lever) is negligible.
    expected_pos_m = noise_m * math.sqrt(1.5)
    assert np.sqrt(np.mean(np.square(pos_err))) == pytest.approx(expected_pos_m, rel=0.15)
    # Rotation: each axis tilts σ/√2 about each perpendicular direction. The tilt about the tip's
    # y comes from axis A alone, about x from B alone, about z is averaged over both (σ²/4):
    # total variance 1.25 σ² (the baseline's weight is ~1000x smaller).
    rms_rot = np.sqrt(np.mean(np.square(rot_err)))
    assert rms_rot == pytest.approx(noise_rad * math.sqrt(1.25), rel=0.15)


def test_non_perpendicular_probes_still_give_a_proper_rotation():
    # A cap whose probes are 80° apart: the thesis's [r1 r2 r1×r2] is then no rotation at all.
    axis_b = (math.cos(math.radians(80)), math.sin(math.radians(80)), 0.0)
    cal = CapCalibration(axis_b=axis_b)
    rng = np.random.default_rng(3)
    rotation, position = random_rotation(rng), np.array([0.01, -0.02, 0.06])
    a, b = probe_readings(rotation, position, cal)
    thesis = np.column_stack([a.axis, b.axis, np.cross(a.axis, b.axis)])
    assert np.linalg.det(thesis) == pytest.approx(math.sin(math.radians(80)) ** 2)
    result = fuse(a, b, cal)
    assert result.ok, result.reason
    assert_proper_rotation(result.pose.rotation)
    np.testing.assert_allclose(result.pose.rotation, rotation, atol=1e-12)
    np.testing.assert_allclose(result.pose.position_m, position, atol=1e-14)


def _wahba_by_svd(b):
    u, _, vt = np.linalg.svd(b)
    u[:, 2] *= np.sign(np.linalg.det(u) * np.linalg.det(vt))
    return u @ vt


@pytest.mark.parametrize("case", ["noisy", "reflection", "equal weights", "two directions", "parallel"])
def test_the_wahba_solution_is_the_svd_one(case):
    """The eigenvector form gives Markley's SVD solution: for noisy direction sets, a B whose
    polar factor is a reflection, a repeated singular value, a rank-2 B, and (the fallback)
    all directions parallel."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        rotation = random_rotation(rng)
        body = rng.normal(size=(3, 3))
        body /= np.linalg.norm(body, axis=1, keepdims=True)
        weights = rng.uniform(0.1, 10.0, 3)
        if case == "equal weights":
            body, weights = np.eye(3), np.full(3, 2.5e5)
        if case == "two directions":
            weights[2] = 0.0
        if case == "parallel":
            body[:] = body[0]
        world = body @ rotation.T + rng.normal(scale=0.05, size=(3, 3))
        if case == "reflection":
            world = -world
        b = (world.T * weights) @ body
        expected = _wahba_by_svd(b)
        if case in ("two directions", "parallel"):
            # R is not unique there: compare the cost, not the rotation.
            cost = lambda r: np.sum(weights * np.sum((world - body @ r.T) ** 2, axis=1))
            r = np.array(_wahba(b))
            assert_proper_rotation(r)
            assert cost(r) <= cost(expected) * (1 + 1e-9) + 1e-12
            continue
        r = np.array(_wahba(b))
        assert_proper_rotation(r)
        np.testing.assert_allclose(r, expected, atol=1e-11)


def test_axes_measured_off_perpendicular_give_the_best_fit_rotation():
    # Nominal cap, probe B's axis measured 1.5° off in the cap plane: within the angle threshold.
    rotation, position = rot_z(0.4), np.zeros(3)
    a, b = probe_readings(rotation, position)
    tilt = math.radians(1.5)
    b = ProbeReading(b.position_m, rotation @ rot_z(tilt) @ np.asarray(CAL.axis_b), 0.0)
    result = fuse(a, b)
    assert result.ok, result.reason
    assert_proper_rotation(result.pose.rotation)
    assert result.angle_error_rad == pytest.approx(tilt)  # y turned towards −x: wider angle
    # Equal axis weights split the disagreement: the rotation error is half the tilt about z
    # (the baseline, weighted ~1000x less, moves it by well under a percent of that).
    assert rotation_error_rad(result.pose.rotation, rotation) == pytest.approx(tilt / 2, rel=0.01)


def _good_pair(t_s=10.0):
    return probe_readings(rot_z(0.2), np.array([0.0, 0.0, 0.06]), t_s=t_s)


def _unit(v):
    return v / np.linalg.norm(v)


def _shift(reading, dp=(0, 0, 0), axis=None, t_s=None, valid=True):
    return ProbeReading(
        reading.position_m + np.asarray(dp),
        reading.axis if axis is None else axis,
        reading.timestamp_s if t_s is None else t_s,
        valid,
    )


@pytest.mark.parametrize(
    "make, now_s, status, words",
    [
        (lambda a, b: (a, _shift(b, valid=False)), None, FrameStatus.INVALID, "probe B"),
        (lambda a, b: (_shift(a, dp=(math.nan, 0, 0)), b), None, FrameStatus.NOT_FINITE, "probe A"),
        (lambda a, b: (a, _shift(b, axis=np.zeros(3))), None, FrameStatus.NOT_FINITE, "probe B"),
        (lambda a, b: (a, b), 10.5, FrameStatus.STALE, "0.500 s old"),
        (lambda a, b: (a, _shift(b, t_s=9.9)), None, FrameStatus.SKEW, "0.100 s apart"),
        (lambda a, b: (a, _shift(b, dp=0.002 * _unit(b.position_m - a.position_m))), None,
         FrameStatus.DISTANCE, "probe distance 6.359 mm"),
        (lambda a, b: (a, _shift(b, axis=rot_z(0.2) @ [-0.1, 1.0, 0.0])), None, FrameStatus.ANGLE,
         "inter-axis angle 95.71 deg"),
    ],
)
def test_bad_frames_are_rejected_with_their_reason(make, now_s, status, words):
    a, b = make(*_good_pair())
    result = fuse(a, b, now_s=now_s)
    assert result.status is status
    assert not result.ok and result.pose is None
    assert words in result.reason


def test_frames_just_inside_the_thresholds_pass():
    a, b = _good_pair()
    s = FusionSettings()
    b = _shift(b, dp=0.9 * s.max_distance_error_m * (b.position_m - a.position_m) / CAL.probe_distance_m,
               t_s=10.0 - 0.9 * s.max_skew_s)
    result = fuse(a, b, now_s=10.0 + 0.9 * s.max_age_s - 0.9 * s.max_skew_s)
    assert result.ok, result.reason
    assert result.distance_error_m == pytest.approx(0.9 * s.max_distance_error_m)


def test_settings_from_params_follow_the_tracker_rate_and_noise():
    p = load_params(overrides=["rig.tracker_rate_hz=20.0", "sensors.tracker_noise_m=0.0005"])
    s = FusionSettings.from_params(p)
    assert s.max_age_s == pytest.approx(0.2) and s.max_skew_s == pytest.approx(0.1)
    assert s.position_noise_m == 0.0005
    with pytest.raises(ValueError, match="max_age_s = -1"):
        FusionSettings(max_age_s=-1)


def test_calibration_refuses_parallel_axes_and_non_unit_axes():
    with pytest.raises(ValueError, match="parallel"):
        CapCalibration(axis_b=(1.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="axis_a"):
        CapCalibration(axis_a=(2.0, 0.0, 0.0))


def test_callable_source_replays_arrays_and_marks_missing_probes():
    rotation, position = rot_z(0.3), np.array([0.01, 0.0, 0.05])
    a, b = probe_readings(rotation, position)
    positions = np.array([[a.position_m, b.position_m]] * 2)
    axes = np.array([[a.axis, b.axis]] * 2)
    positions[1, 1] = np.nan  # probe B out of the field in the second frame
    source = CallableSource.from_arrays([0.0, 0.025], positions, axes)
    first = fuse_frame(source.read())
    assert first.ok and np.allclose(first.pose.position_m, position, atol=1e-15)
    second = fuse_frame(source.read())
    assert second.status is FrameStatus.INVALID and "probe B" in second.reason
    with pytest.raises(IndexError, match="all 2 frames"):
        source.read()
    with pytest.raises(ValueError, match="positions_m"):
        CallableSource.from_arrays([0.0], np.zeros((2, 2, 3)), np.zeros((1, 2, 3)))


# --- against a local OpenIGTLink server publishing synthetic poses ---------------------------

pyigtl = pytest.importorskip("pyigtl")


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def igtl():
    """(server, source) on a free local port; both closed afterwards, signal handlers restored."""
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    port = _free_port()
    server = pyigtl.OpenIGTLinkServer(port=port, local_server=True)
    source = OpenIGTLinkSource("127.0.0.1", port, device_a="ProbeA", device_b="ProbeB")
    try:
        yield server, source
    finally:
        # Client first: a client whose server vanished spins on its dead socket.
        source.close()
        server.stop()
        for sig, handler in handlers.items():
            signal.signal(sig, handler)


def _transform_mm(position_m, axis, roll_rad, axis_column=2):
    """4×4 transform of a 5-DOF probe: translation in mm, ``axis`` as column ``axis_column``,
    the other columns an arbitrary roll about it (as a 5-DOF sensor reports)."""
    axis = np.asarray(axis) / np.linalg.norm(axis)
    helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    u, v = math.cos(roll_rad) * u + math.sin(roll_rad) * v, -math.sin(roll_rad) * u + math.cos(roll_rad) * v
    cols = [u, v]
    cols.insert(axis_column, axis)
    m = np.eye(4)
    m[:3, :3] = np.column_stack(cols)
    m[:3, 3] = np.asarray(position_m) * 1e3
    return m


def _publish(server, device, reading, roll_rad, timestamp):
    m = _transform_mm(reading.position_m, reading.axis, roll_rad)
    server.send_message(pyigtl.TransformMessage(m, timestamp=timestamp, device_name=device), wait=False)


def _read_until(source, predicate, timeout_s=3.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        frame = source.read()
        if predicate(frame):
            return frame
        time.sleep(0.01)
    raise AssertionError(f"no matching frame from the OpenIGTLink server within {timeout_s} s")


def test_openigtlink_pose_recovered_to_the_noise_level(igtl):
    server, source = igtl
    rng = np.random.default_rng(4)
    rotation, position = random_rotation(rng), np.array([0.10, -0.05, 0.20])
    a, b = probe_readings(rotation, position, rng=rng, noise_m=0.0002, noise_rad=0.002)
    now = time.time()
    _publish(server, "ProbeA", a, 0.7, now)
    _publish(server, "ProbeB", b, -1.9, now)
    frame = _read_until(source, lambda f: f.probe_a.valid and f.probe_b.valid)
    assert frame.probe_a.timestamp_s == pytest.approx(now, abs=1e-6)
    # float32 transport loses ~1e-5 mm; the rest is the injected noise
    np.testing.assert_allclose(frame.probe_a.position_m, a.position_m, atol=1e-8)
    result = fuse_frame(frame)
    assert result.ok, result.reason
    assert np.linalg.norm(result.pose.position_m - position) < 5 * 0.0002
    assert rotation_error_rad(result.pose.rotation, rotation) < 5 * 0.002


def test_openigtlink_probe_never_seen_is_invalid_and_silent_probe_goes_stale(igtl):
    server, source = igtl
    a, b = probe_readings(rot_z(0.5), np.array([0.0, 0.0, 0.1]))
    settings = FusionSettings(max_age_s=0.1)
    _publish(server, "ProbeA", a, 0.0, time.time())
    frame = _read_until(source, lambda f: f.probe_a.valid)
    assert fuse_frame(frame, settings=settings).status is FrameStatus.INVALID

    _publish(server, "ProbeB", b, 0.0, time.time())
    frame = _read_until(source, lambda f: f.probe_b.valid)
    assert fuse_frame(frame, settings=settings).ok
    # Probe B leaves the field: PLUS stops sending it while A keeps streaming at 40 Hz.
    stop = time.monotonic() + 0.2
    while time.monotonic() < stop:
        _publish(server, "ProbeA", a, 0.0, time.time())
        time.sleep(0.025)
    result = fuse_frame(source.read(), settings=settings)
    assert result.status is FrameStatus.STALE
    assert "probe B" in result.reason
