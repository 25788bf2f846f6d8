"""The live tip force: one estimate per telemetry sample, as a stream its users subscribe to.

:class:`ForceStream` turns what a device reports — a telemetry sample (load-cell tensions, the
encoders' ticks) and the tracker's fused tip pose — into a :class:`ForceSample`: the tip force
(world frame, the load applied at the tip), its covariance, which directions are observable, and
the contact detector's flag. Each estimate is warm (it starts from the last one: ~1-2 ms of CPU on
the default robot, well inside a 40 Hz sample period), and with tendon friction in the model each
tendon's sliding state is followed from the encoders' ticks, as the estimate needs it.

The stream does not read the device itself: whoever drives the device (a controller, the
Gymnasium env, a command's loop) hands it the samples and tracker frames it reads anyway, so
subscribing never steals a tracker frame or a telemetry sample from the driver. Sinks subscribe
with :meth:`ForceStream.subscribe` and get every sample; a controller reads :attr:`ForceStream.latest`.

Sinks of the repository: the env's ``info`` (``envs``), the live view's arrow and ellipsoid
(:mod:`twin.live`), OpenIGTLink messages 3D Slicer shows (:func:`force_messages`) and
``geometry_msgs/msg/WrenchStamped`` in a rosbag2 export (:mod:`twin.rosbag`).

Example:
    >>> stream = ForceStream.for_device(device, params)          # doctest: +SKIP
    >>> sample = device.wait_next(); fused = device.tracker.read()  # doctest: +SKIP
    >>> out = stream.update(sample, fused.pose.position_m, fused.pose.rotation)  # doctest: +SKIP
    >>> out.force_n, out.contact                                  # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
import threading
from typing import Callable

import numpy as np
from scipy.stats import chi2

from twin import effects
from twin.effects.tendon_friction import SlidingState
from twin.force.contact import ContactDetector
from twin.force.estimator import WrenchEstimate, estimate_tip_wrench
from twin.params import Params
from twin.rod import RodModel

__all__ = ["ForceSample", "ForceStream", "force_messages", "uncertainty_ellipsoid"]

# Millimetres of arrow per newton in the OpenIGTLink messages: 0.3 N (the contact range's top)
# draws 30 mm, half the default endoscope's length.
ARROW_MM_PER_N = 100.0


@dataclasses.dataclass(frozen=True)
class ForceSample:
    """One estimate of the live stream.

    Attributes:
        time_s: device time of the telemetry sample it was estimated from (s).
        force_n: (3,) tip force (N, world frame; the load applied at the tip); NaN on a world axis
            that is not observable.
        force_observable_n: (3,) the estimate's projection on its observable directions (N): what
            a display or a controller can use on every axis (nothing along an unobservable one).
        force_cov_n2: (3, 3) covariance of ``force_observable_n`` (N²; rank = observable dimensions).
        observable: (3,) per world axis, whether its component is observable.
        unobservable_directions: (k, 3) unit vectors along which the force is not seen.
        tip_position_m: (3,) the tracked tip position the estimate used (m, world, base at the origin).
        contact: whether the contact detector flags a load at the tip.
        contact_statistic: the detector's test statistic of this sample (see
            :class:`twin.force.contact.ContactDetector`).
        converged: the estimate converged (a sample that did not repeats the last good force).
        estimate_time_s: CPU time of the estimate (s).
    """

    time_s: float
    force_n: np.ndarray
    force_observable_n: np.ndarray
    force_cov_n2: np.ndarray
    observable: np.ndarray
    unobservable_directions: np.ndarray
    tip_position_m: np.ndarray
    contact: bool
    contact_statistic: float
    converged: bool
    estimate_time_s: float

    def to_dict(self) -> dict:
        """JSON-ready (NaN as null)."""
        def clean(a):
            return [[None if not np.isfinite(x) else float(x) for x in row] if np.ndim(row) else
                    (None if not np.isfinite(row) else float(row)) for row in np.asarray(a, dtype=float)]

        return {"time_s": float(self.time_s), "force_n": clean(self.force_n),
                "force_observable_n": clean(self.force_observable_n), "force_cov_n2": clean(self.force_cov_n2),
                "observable": [bool(b) for b in self.observable],
                "unobservable_directions": clean(self.unobservable_directions),
                "tip_position_m": clean(self.tip_position_m), "contact": bool(self.contact),
                "contact_statistic": float(self.contact_statistic), "converged": bool(self.converged),
                "estimate_time_s": float(self.estimate_time_s)}


class ForceStream:
    """Live tip force estimates from a device's telemetry and tracker frames.

    Args:
        params: the model's parameter set (the robot, its sensors' noise, its friction).
        tendon_m_per_count: tendon length per encoder count (m), the device handshake's
            (:attr:`twin.driver.DeviceInfo.tendon_m_per_count`): the sliding states follow the encoders.
        base_rotation: the clamp's orientation (3, 3), body to world (the device's ``base_rotation``).
        rate_hz: the telemetry rate (Hz) the detector's time constants are counted in; default the
            parameter set's ``rig.telemetry_rate_hz``.
        detector: the contact detector (default :class:`ContactDetector` at ``rate_hz``); None
            for none (``contact`` always False).
        estimate_options: passed on to :func:`twin.force.estimate_tip_wrench` (e.g.
            ``model_error_fraction``).
    """

    def __init__(self, params: Params, *, tendon_m_per_count: float, base_rotation=None, rate_hz: float | None = None,
                 detector: ContactDetector | None | bool = True, **estimate_options):
        self.params = params
        self.model = RodModel.from_params(params)
        self.base_rotation = np.asarray(params.rig.base_rotation if base_rotation is None else base_rotation, float)
        rate = float(rate_hz or params.rig.telemetry_rate_hz)
        self.detector = ContactDetector(rate_hz=rate) if detector is True else (detector or None)
        self._options = estimate_options
        self._sliding = SlidingState(tendon_m_per_count)
        self._sense = params.effects.tendon_friction_direction if params.effects.tendon_friction_coeff else 0.0
        self._previous: WrenchEstimate | None = None
        self._subscribers: list[Callable[[ForceSample], None]] = []
        self._lock = threading.Lock()
        self._latest: ForceSample | None = None
        self.estimates = 0
        self.failures = 0

    @classmethod
    def for_device(cls, device, params: Params, **options) -> "ForceStream":
        """A stream for ``device`` (its encoder scale, clamp orientation and telemetry rate)."""
        return cls(params, tendon_m_per_count=device.info.tendon_m_per_count, base_rotation=device.base_rotation,
                   **options)

    @property
    def latest(self) -> ForceSample | None:
        """The newest sample (thread-safe), None before the first."""
        with self._lock:
            return self._latest

    def subscribe(self, callback: Callable[[ForceSample], None]) -> Callable[[], None]:
        """Call ``callback(sample)`` with every sample from now on; returns the unsubscribe call."""
        self._subscribers.append(callback)
        return lambda: self._subscribers.remove(callback) if callback in self._subscribers else None

    def follow(self, samples) -> None:
        """Feed telemetry samples that carry no tracker frame (the encoders' ticks move the sliding
        states); :meth:`update` follows its own sample."""
        self._sliding.follow(samples)

    def reset(self) -> None:
        """Start afresh (a new episode, the device reconnected): no warm start, no detector
        baseline; the sliding states are kept (they follow the spools, which did not forget)."""
        self._previous = None
        if self.detector is not None:
            self.detector.reset()

    def update(self, sample, tip_position_m, tip_rotation=None, *, samples=None) -> ForceSample:
        """Estimate from one telemetry ``sample`` (its tensions) and the tracker's fused tip pose,
        notify the subscribers and return the sample.

        Args:
            sample: the newest telemetry sample.
            tip_position_m, tip_rotation: the tracker's fused tip pose (m; 3×3, or None).
            samples: every telemetry sample since the last update, oldest first, ``sample`` last
                (a :meth:`twin.driver.Device.drain`): their encoder ticks move the sliding states;
                default ``[sample]``.

        Raises:
            ValueError: a malformed pose (see :func:`twin.force.estimate_tip_wrench`).
        """
        sigma = self._sliding.follow([sample] if samples is None else samples)
        direction = None
        if self._sense and sigma is not None:
            direction = effects.friction_direction(np.zeros(self.model.tendon_count), self._sense, sigma)
        return self.estimate(float(sample.time_s), sample.tensions_n[:self.model.tendon_count], tip_position_m,
                             tip_rotation, friction_direction=direction)

    def estimate(self, time_s: float, tensions_n, tip_position_m, tip_rotation=None, *,
                 friction_direction=None) -> ForceSample:
        """Estimate from measured values (no telemetry sample: a plant's, a dataset row's), notify
        the subscribers and return the sample. ``friction_direction``: per tendon sliding state
        for the model's friction (see :class:`twin.rod.LoadCase`); default pulled."""
        est = estimate_tip_wrench(self.params, tensions_n, tip_position_m, tip_rotation,
                                  base_rotation=self.base_rotation, model=self.model, previous=self._previous,
                                  friction_direction=friction_direction, **self._options)
        self.estimates += 1
        if est.converged:
            self._previous = est
        else:
            self.failures += 1
            self._previous = None
        state = self.detector.update(est) if self.detector is not None else None
        last = self.latest
        if est.converged or last is None:
            force, observable_force = est.force_n.copy(), est.force_observable_n.copy()
            cov, observable = est.force_observable_cov_n2.copy(), est.force_observable.copy()
            unobservable = est.unobservable_force_directions.copy()
        else:  # a failed estimate repeats the last good force (flagged: converged False)
            force, observable_force, cov = last.force_n, last.force_observable_n, last.force_cov_n2
            observable, unobservable = last.observable, last.unobservable_directions
        out = ForceSample(
            time_s=time_s, force_n=force, force_observable_n=observable_force, force_cov_n2=cov,
            observable=observable, unobservable_directions=unobservable,
            tip_position_m=np.asarray(tip_position_m, dtype=float).copy(),
            contact=bool(state.contact) if state is not None else False,
            contact_statistic=float(state.statistic) if state is not None else float("nan"),
            converged=bool(est.converged), estimate_time_s=est.estimate_time_s)
        with self._lock:
            self._latest = out
        for callback in list(self._subscribers):
            callback(out)
        return out


def uncertainty_ellipsoid(cov_n2, *, probability: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """The ``probability`` ellipsoid of a 3-D force covariance: semi-axes (3,) in N (0 along a
    direction without variance) and the rotation (3, 3) whose columns are their directions."""
    cov = np.asarray(cov_n2, dtype=float)
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    if np.linalg.det(vec) < 0:
        vec[:, 0] = -vec[:, 0]
    return np.sqrt(chi2.ppf(probability, 3) * np.clip(lam, 0.0, None)), vec


def force_messages(sample: ForceSample, *, timestamp_s: float, device: str = "TipForce",
                   mm_per_n: float = ARROW_MM_PER_N, version: int = 1) -> list[bytes]:
    """The force of ``sample`` as OpenIGTLink messages 3D Slicer shows (lengths in mm, world frame).

    ``TipForce`` (POLYDATA: Slicer makes it a model): an arrow from the tracked tip along the
    observable force, ``mm_per_n`` mm per N, its head two strokes; ``TipForceUncertainty``
    (POLYDATA): the 95 % ellipsoid of the force at the arrow's head, as its three principal
    ellipses; ``TipForcePoints`` (POINT: Slicer makes them markups): the tip and the arrow's head,
    named ``tip`` and ``force``. With header version 2 each message carries the force (N), its
    standard deviations (N) and the contact flag as metadata.
    """
    from twin.driver import igtl

    tip = np.asarray(sample.tip_position_m, dtype=float) * 1e3
    force = np.asarray(sample.force_observable_n, dtype=float)
    head = tip + force * mm_per_n
    length = float(np.linalg.norm(head - tip))
    points = [tip, head]
    lines = [[0, 1]]
    if length > 0:
        axis = (head - tip) / length
        side = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
        side /= np.linalg.norm(side)
        barb = 0.2 * length
        points += [head - barb * axis + 0.5 * barb * side, head - barb * axis - 0.5 * barb * side]
        lines += [[1, 2], [1, 3]]
    axes, rotation = uncertainty_ellipsoid(sample.force_cov_n2)
    ring: list[np.ndarray] = []
    ring_lines: list[list[int]] = []
    angles = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    for a, b in ((0, 1), (1, 2), (0, 2)):
        start = len(ring)
        for t in angles:
            ring.append(head + mm_per_n * (axes[a] * np.cos(t) * rotation[:, a] + axes[b] * np.sin(t) * rotation[:, b]))
        ring_lines.append([*range(start, start + len(angles)), start])
    std = np.sqrt(np.clip(np.diag(sample.force_cov_n2), 0.0, None))
    meta = {"force_n": " ".join(f"{x:.6g}" for x in force), "force_std_n": " ".join(f"{x:.6g}" for x in std),
            "contact": str(bool(sample.contact)).lower()} if version >= 2 else None
    return [
        igtl.pack("POLYDATA", device, igtl.encode_polydata(np.array(points), lines=lines), timestamp_s=timestamp_s,
                  version=version, metadata=meta),
        igtl.pack("POLYDATA", device + "Uncertainty", igtl.encode_polydata(np.array(ring), lines=ring_lines),
                  timestamp_s=timestamp_s, version=version, metadata=meta),
        igtl.pack("POINT", device + "Points", igtl.encode_point(np.array([tip, head]), names=["tip", "force"],
                                                                 group=device, rgba=(230, 159, 0, 255)),
                  timestamp_s=timestamp_s, version=version, metadata=meta),
    ]
