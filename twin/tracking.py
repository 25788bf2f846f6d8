"""EM tracker fusion: two 5-DOF probes in the tip cap → one 6-DOF tip pose.

The rig's NDI tracker follows two 5-DOF needle probes mounted perpendicular in a cap on the
tip. A 5-DOF probe gives a position and the direction of its axis but no roll about that axis;
two probes together fix the full orientation. :func:`fuse` solves Wahba's problem by a
weighted SVD on three directions known in both frames (the two probe axes and the unit
probe-to-probe vector), then places the tip from that rotation and the two probe positions.

Bad frames are expected in a stream (a probe leaves the field, the cap slips, a metal tool
distorts the field), so :func:`fuse` never raises for them: it returns a
:class:`FusionResult` whose ``status`` says why the frame was rejected and whose ``pose`` is
``None`` then. Malformed arguments (wrong shapes) raise ``ValueError``.

Sources hand out :class:`ProbeFrame` objects: :class:`CallableSource` adapts the simulated twin;
the rig's OpenIGTLink (PLUS) client is :class:`twin.driver.igtl_source.OpenIGTLinkSource`.
"""

from __future__ import annotations

import dataclasses
import functools
import enum
import math
from typing import Callable

import numpy as np

from twin.checks import finite_vector
from twin.params import Params
from twin.pose import matrix_to_quat

__all__ = [
    "CapCalibration",
    "CallableSource",
    "compile_fusion",
    "FrameStatus",
    "FusionResult",
    "FusionSettings",
    "ProbeFrame",
    "ProbeReading",
    "TipPose",
    "fuse",
    "fuse_frame",
]


def _vector3(name: str, value) -> np.ndarray:
    v = np.asarray(value, dtype=float)
    if v.shape != (3,):
        raise ValueError(f"{name} = {value!r}: expected 3 numbers, got shape {v.shape}")
    return v


@dataclasses.dataclass(frozen=True, eq=False)
class ProbeReading:
    """One 5-DOF probe sample in the tracker (world) frame.

    Attributes:
        position_m: (3,) probe position (m).
        axis: (3,) direction of the probe's axis; normalised by :func:`fuse`.
        timestamp_s: time the tracker measured it (s, in the source's clock).
        valid: False when the source has no usable sample (probe never seen, out of field).
    """

    position_m: np.ndarray
    axis: np.ndarray
    timestamp_s: float
    valid: bool = True

    def __post_init__(self):
        object.__setattr__(self, "position_m", _vector3("position_m", self.position_m))
        object.__setattr__(self, "axis", _vector3("axis", self.axis))
        object.__setattr__(self, "timestamp_s", float(self.timestamp_s))

    @classmethod
    def missing(cls) -> "ProbeReading":
        """The reading of a probe the source has no sample of."""
        nan3 = np.full(3, np.nan)
        return cls(nan3, nan3, math.nan, valid=False)


@dataclasses.dataclass(frozen=True)
class ProbeFrame:
    """Both probes' latest readings and the source's current time ``now_s`` (s, same clock)."""

    probe_a: ProbeReading
    probe_b: ProbeReading
    now_s: float


@dataclasses.dataclass(frozen=True)
class CapCalibration:
    """Where the probes sit in the tip cap, in the tip frame.

    The tip frame is the backbone's body frame at the tip: z along the tangent, out of the tip
    face; x and y as the body x and y of :mod:`twin.rod` (tendon 1 at +x). Positions are the
    points the tracker reports for each probe (its sensor coil), relative to the tip centre.

    Defaults are an **assumption** (the thesis gives the cap only in a figure): probe A along
    +x, 3 mm off-centre towards −y, 2 mm above the tip face; probe B along +y, 3 mm towards −x,
    3 mm above the face. The two 0.8 mm needles lie in planes parallel to the tip face 1 mm
    apart, so they cross without touching inside the 12 mm cap. Measure the real cap (or fit
    these from a pivot calibration) and pass the values.

    Attributes:
        position_a_m, position_b_m: (3,) probe positions in the tip frame (m).
        axis_a, axis_b: (3,) unit probe axes in the tip frame.
    """

    position_a_m: tuple[float, float, float] = (0.0, -0.003, 0.002)
    axis_a: tuple[float, float, float] = (1.0, 0.0, 0.0)
    position_b_m: tuple[float, float, float] = (-0.003, 0.0, 0.003)
    axis_b: tuple[float, float, float] = (0.0, 1.0, 0.0)

    def __post_init__(self):
        for name in ("position_a_m", "axis_a", "position_b_m", "axis_b"):
            v = finite_vector(f"CapCalibration.{name}", getattr(self, name), 3)
            if name.startswith("axis"):
                if abs(np.linalg.norm(v) - 1.0) > 1e-6:
                    raise ValueError(f"CapCalibration.{name} = {v.tolist()}: must be a unit vector")
            object.__setattr__(self, name, tuple(float(x) for x in v))
        if np.linalg.norm(np.cross(self.axis_a, self.axis_b)) < 0.1:
            raise ValueError(
                f"CapCalibration axes {self.axis_a} and {self.axis_b}: nearly parallel, "
                "two probes then cannot fix the roll"
            )
        if self.probe_distance_m <= 0:
            raise ValueError(f"CapCalibration positions {self.position_a_m}: both probes at one point")

    @property
    def probe_distance_m(self) -> float:
        """Distance between the two probe positions (m)."""
        return float(np.linalg.norm(np.subtract(self.position_b_m, self.position_a_m)))

    @property
    def axis_angle_rad(self) -> float:
        """Angle between the two probe axes (rad); π/2 for the nominal cap."""
        from twin.tracking_kernels import angle_between_rad

        return angle_between_rad(np.asarray(self.axis_a, dtype=float), np.asarray(self.axis_b, dtype=float))


@dataclasses.dataclass(frozen=True)
class FusionSettings:
    """Noise levels (they set the SVD weights) and rejection thresholds.

    Defaults: noise of the NDI Aurora 5-DOF probe as in ``models/endoscope/endoscope.toml``
    (``sensors.tracker_noise_m``, ``sensors.tracker_noise_rad``); thresholds several noise
    levels wide so a good frame is not rejected, yet tight enough to catch a slipped probe or
    field distortion of a millimetre or a few degrees; ages for the 40 Hz tracker.

    Attributes:
        position_noise_m: RMS probe position noise (m).
        axis_noise_rad: RMS probe axis direction noise (rad).
        max_distance_error_m: largest accepted change of the probe-to-probe distance (m).
        max_angle_error_rad: largest accepted change of the angle between the axes (rad).
        max_age_s: oldest accepted sample, ``now_s`` minus its timestamp (s).
        max_skew_s: largest accepted time between the two probes' samples (s).
    """

    position_noise_m: float = 0.0002
    axis_noise_rad: float = 0.002
    max_distance_error_m: float = 0.001
    max_angle_error_rad: float = math.radians(2.0)
    max_age_s: float = 0.1
    max_skew_s: float = 0.05

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"FusionSettings.{f.name} = {value!r}: must be finite and > 0")

    @classmethod
    def from_params(cls, params: Params, **overrides) -> "FusionSettings":
        """Noise from the parameter set's sensors; ages of four and two tracker periods."""
        period_s = 1.0 / params.rig.tracker_rate_hz
        # An ideal (noise-free) twin would make every SVD weight infinite; only the ratio of the
        # weights matters, so fall back to the default noise levels then.
        values = dict(
            position_noise_m=params.sensors.tracker_noise_m or cls.position_noise_m,
            axis_noise_rad=params.sensors.tracker_noise_rad or cls.axis_noise_rad,
            max_age_s=4 * period_s,
            max_skew_s=2 * period_s,
        )
        values.update(overrides)
        return cls(**values)


class FrameStatus(enum.Enum):
    """Outcome of fusing one frame; every value but ``OK`` is a rejection."""

    OK = "ok"
    INVALID = "invalid"  # the source has no sample of a probe
    NOT_FINITE = "not_finite"  # NaN/inf or a zero-length axis
    STALE = "stale"  # a sample older than max_age_s
    SKEW = "skew"  # the two samples further apart in time than max_skew_s
    DISTANCE = "distance"  # probe-to-probe distance drifted from the calibration
    ANGLE = "angle"  # inter-axis angle drifted from the calibration


@dataclasses.dataclass(frozen=True, eq=False)
class TipPose:
    """6-DOF tip pose in the tracker (world) frame.

    Attributes:
        position_m: (3,) tip centre (m).
        rotation: (3, 3) proper rotation, tip frame → world (columns are the tip axes).
        timestamp_s: mean of the two probe timestamps (s).
    """

    position_m: np.ndarray
    rotation: np.ndarray
    timestamp_s: float

    @property
    def quaternion(self) -> np.ndarray:
        """Orientation as a quaternion ``(w, x, y, z)``, w >= 0."""
        return matrix_to_quat(self.rotation)


@dataclasses.dataclass(frozen=True)
class FusionResult:
    """A fused frame: ``pose`` when ``ok``, else ``None`` and ``reason`` names the bad value.

    Attributes:
        status: :class:`FrameStatus`.
        reason: human-readable cause of a rejection ('' when ok).
        pose: the tip pose, or None when rejected.
        distance_error_m: measured minus calibrated probe distance (m); NaN if not reached.
        angle_error_rad: measured minus calibrated inter-axis angle (rad); NaN if not reached.
    """

    status: FrameStatus
    reason: str = ""
    pose: TipPose | None = None
    distance_error_m: float = math.nan
    angle_error_rad: float = math.nan

    @property
    def ok(self) -> bool:
        return self.status is FrameStatus.OK


def fuse(
    probe_a: ProbeReading,
    probe_b: ProbeReading,
    calibration: CapCalibration = CapCalibration(),
    settings: FusionSettings = FusionSettings(),
    *,
    now_s: float | None = None,
) -> FusionResult:
    """Fuse two 5-DOF probe readings into the 6-DOF tip pose, or reject the frame.

    The rotation solves Wahba's problem on three direction pairs, tip frame → world: axis A,
    axis B and the unit vector from probe A to probe B, weighted by the inverse variance of
    each direction (axis noise for the axes; √2·position noise over the probe distance for
    the baseline). The SVD solution is always a proper rotation (orthonormal, det +1) and is
    the least-squares best fit when the measured axes are not exactly perpendicular.

    The thesis built R = [r1 r2 r1×r2] from the two measured axes. That matrix is orthonormal
    only if r1 ⟂ r2 exactly: with the axes an angle θ ≠ 90° apart its columns are not
    orthogonal (r1·r2 = cos θ), its third column has length sin θ and det = sin²θ ≠ 1, so it
    is not a rotation and every mounting or noise error leaks into the position as shear.

    The tip position is the mean over both probes of p_i − R c_i (c_i the probe's position in
    the tip frame), the least-squares position given R.

    Checks, in this order, each rejecting the frame with its :class:`FrameStatus`: a probe not
    valid; NaN/inf or a zero axis; a sample older than ``settings.max_age_s`` before ``now_s``
    (only when ``now_s`` is given); probe timestamps more than ``settings.max_skew_s`` apart;
    probe distance or inter-axis angle off the calibration by more than the thresholds.

    Args:
        probe_a, probe_b: readings of the probes the calibration calls A and B (world frame).
        calibration: probe mounting in the tip frame.
        settings: noise levels and thresholds.
        now_s: current time in the readings' clock (s); None skips the age check.

    Returns:
        A :class:`FusionResult`; ``result.pose`` is set only when ``result.ok``.
    """
    for name, probe in (("A", probe_a), ("B", probe_b)):
        if not probe.valid:
            return FusionResult(FrameStatus.INVALID, f"probe {name}: no valid sample")
    for name, probe in (("A", probe_a), ("B", probe_b)):
        finite = np.isfinite(probe.position_m).all() and np.isfinite(probe.axis).all() and math.isfinite(probe.timestamp_s)
        if not finite or not probe.axis.any():
            return FusionResult(
                FrameStatus.NOT_FINITE,
                f"probe {name}: position_m = {probe.position_m.tolist()}, axis = "
                f"{probe.axis.tolist()}, timestamp_s = {probe.timestamp_s}: not finite or zero axis",
            )
    if now_s is not None:
        for name, probe in (("A", probe_a), ("B", probe_b)):
            age_s = now_s - probe.timestamp_s
            if age_s > settings.max_age_s:
                return FusionResult(
                    FrameStatus.STALE,
                    f"probe {name}: sample is {age_s:.3f} s old (max_age_s = {settings.max_age_s})",
                )
    skew_s = abs(probe_a.timestamp_s - probe_b.timestamp_s)
    if skew_s > settings.max_skew_s:
        return FusionResult(
            FrameStatus.SKEW,
            f"probe samples {skew_s:.3f} s apart (max_skew_s = {settings.max_skew_s})",
        )

    cap = _cap_geometry(calibration)
    baseline_noise_rad = math.sqrt(2.0) * settings.position_noise_m / cap.distance_m
    weights = np.array([settings.axis_noise_rad, settings.axis_noise_rad, baseline_noise_rad]) ** -2.0
    # Imported on the first fusion: a host that reads no tracker never loads Numba.
    from twin.tracking_kernels import fuse_geometry

    position_m, rotation, distance_m, angle_rad = fuse_geometry(
        probe_a.position_m, probe_b.position_m, probe_a.axis, probe_b.axis, cap.body, cap.probe_sum_m, weights)
    distance_error_m = distance_m - cap.distance_m
    angle_error_rad = angle_rad - cap.angle_rad
    if abs(distance_error_m) > settings.max_distance_error_m:
        return FusionResult(
            FrameStatus.DISTANCE,
            f"probe distance {distance_m * 1e3:.3f} mm, calibrated "
            f"{cap.distance_m * 1e3:.3f} mm (max_distance_error_m = "
            f"{settings.max_distance_error_m})",
            distance_error_m=distance_error_m,
            angle_error_rad=angle_error_rad,
        )
    if abs(angle_error_rad) > settings.max_angle_error_rad:
        return FusionResult(
            FrameStatus.ANGLE,
            f"inter-axis angle {math.degrees(angle_rad):.2f} deg, calibrated "
            f"{math.degrees(cap.angle_rad):.2f} deg (max_angle_error_rad = "
            f"{settings.max_angle_error_rad:.4f})",
            distance_error_m=distance_error_m,
            angle_error_rad=angle_error_rad,
        )

    pose = TipPose(position_m, rotation, 0.5 * (probe_a.timestamp_s + probe_b.timestamp_s))
    return FusionResult(
        FrameStatus.OK, pose=pose, distance_error_m=distance_error_m, angle_error_rad=angle_error_rad
    )


@dataclasses.dataclass(frozen=True, eq=False)
class _CapGeometry:
    """What :func:`fuse` needs of a calibration, computed once per calibration.

    Attributes:
        body: (3, 3) rows axis A, axis B and the unit baseline A → B, in the tip frame.
        probe_sum_m: (3,) c_A + c_B (m).
        distance_m: the probes' distance (m).
        angle_rad: the angle between their axes (rad).
    """

    body: np.ndarray
    probe_sum_m: np.ndarray
    distance_m: float
    angle_rad: float


@functools.lru_cache(maxsize=16)
def _cap_geometry(calibration: CapCalibration) -> _CapGeometry:
    c_a, c_b = np.array(calibration.position_a_m), np.array(calibration.position_b_m)
    distance_m = calibration.probe_distance_m
    body = np.array([calibration.axis_a, calibration.axis_b, (c_b - c_a) / distance_m])
    return _CapGeometry(body, c_a + c_b, distance_m, calibration.axis_angle_rad)


def compile_fusion(calibration: CapCalibration = CapCalibration()) -> None:
    """Compile :func:`fuse`'s kernels (numba) now, by fusing the cap's own probes at the identity
    pose: the first fusion in a process otherwise takes about a second, which a real-time caller
    (a host feeding the board's watchdog) cannot spend on its first tracker reading."""
    fuse(ProbeReading(np.array(calibration.position_a_m), np.array(calibration.axis_a), 0.0),
         ProbeReading(np.array(calibration.position_b_m), np.array(calibration.axis_b), 0.0), calibration)


def fuse_frame(
    frame: ProbeFrame,
    calibration: CapCalibration = CapCalibration(),
    settings: FusionSettings = FusionSettings(),
) -> FusionResult:
    """:func:`fuse` on a source's frame, checking the samples' age against ``frame.now_s``."""
    return fuse(frame.probe_a, frame.probe_b, calibration, settings, now_s=frame.now_s)


class CallableSource:
    """Probe frames from a function, e.g. the simulated twin's sensor hook.

    Args:
        sample: called once per :meth:`read`; returns ``(time_s, positions_m, axes)`` with
            ``positions_m`` and ``axes`` of shape (2, 3), rows probe A then probe B, in the
            world frame. A row containing NaN marks that probe as out of the field (invalid).
            ``time_s`` is both the samples' timestamp and the frame's ``now_s``, so a
            simulated frame is never stale unless the caller makes it so.
    """

    def __init__(self, sample: Callable[[], tuple[float, np.ndarray, np.ndarray]]):
        self._sample = sample

    @classmethod
    def from_arrays(cls, times_s, positions_m, axes) -> "CallableSource":
        """Replay recorded or generated frames in order; reading past the end raises IndexError.

        Args:
            times_s: (n,) sample times (s).
            positions_m: (n, 2, 3) probe positions (m), probe A then B.
            axes: (n, 2, 3) probe axes.
        """
        times_s = np.asarray(times_s, dtype=float)
        positions_m = np.asarray(positions_m, dtype=float)
        axes = np.asarray(axes, dtype=float)
        n = times_s.shape[0] if times_s.ndim == 1 else -1
        for name, arr in (("positions_m", positions_m), ("axes", axes)):
            if arr.shape != (n, 2, 3):
                raise ValueError(f"{name}: shape {arr.shape}, expected ({n}, 2, 3) for {n} times")
        index = iter(range(n))

        def sample():
            i = next(index, None)
            if i is None:
                raise IndexError(f"CallableSource.from_arrays: all {n} frames have been read")
            return times_s[i], positions_m[i], axes[i]

        return cls(sample)

    def read(self) -> ProbeFrame:
        """The next frame from the sample function."""
        time_s, positions_m, axes = self._sample()
        readings = []
        for position_m, axis in zip(np.asarray(positions_m, float), np.asarray(axes, float), strict=True):
            if np.isfinite(position_m).all() and np.isfinite(axis).all():
                readings.append(ProbeReading(position_m, axis, time_s))
            else:
                readings.append(ProbeReading.missing())
        return ProbeFrame(readings[0], readings[1], float(time_s))
