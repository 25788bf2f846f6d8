"""The device interface: one protocol client for the rig and its twin.

Everything above the hardware (experiments, controllers, the Gymnasium env) talks to a
:class:`Device`; :func:`twin.driver.open_device` picks the backend from a URL. The client
speaks the binary protocol of ``firmware/PROTOCOL.md`` through a
:class:`twin.driver.transport.Transport`, and the two backends differ only in their clock
(:attr:`Device.clock`):

``"simulated"`` (``sim://``)
    The emulated board runs in this process. Time stands still between calls and advances only
    while the host waits — :meth:`Device.wait`, :meth:`Device.wait_next`, or a command awaiting
    its answer (answered at once, so no time passes) — as fast as the computer allows, 5 ms
    board tick by 5 ms tick. Durations and timeouts are simulated seconds; a run is repeated
    exactly for the same seed and calls.
``"wall"`` (``serial://``)
    The board runs on its own. Telemetry arrives in a background thread at 40 Hz whether or not
    the host waits; durations and timeouts are wall-clock seconds.

On both, the board's watchdog is fed by the host's control loop making progress: keepalive
PINGs go out only from the host's own calls (commands; waits, which send those that fall due
while they wait; :meth:`Device.latest`, :meth:`Device.drain` and :attr:`Device.time_s`, which
send one if due), never from a thread of their own. A host that stops calling for the
watchdog timeout (0.25 s by default) while enabled stops the rig, whether it hung or died.
Waiting for an operator on purpose is done in :meth:`Device.attended`.

A connection starts from a disabled board (connect sends DISABLE after the handshake), no
data the board sends can stop the host from hearing it (bad frames are counted and skipped,
:attr:`Device.stats`), and a host that cannot hear the board any more says so: the board is
sent DISABLE and every call raises :class:`DeviceDisconnected` naming the cause.

Example::

    with open_device("sim://?seed=3") as dev:   # or "serial:///dev/ttyACM0"
        dev.tare()
        dev.enable()
        dev.set_lengths([-0.002, 0.0, 0.002, 0.0])   # one length per tendon (the endoscope's four)
        dev.wait(1.0)
        lengths_m = dev.latest().tendon_lengths_m
"""

from __future__ import annotations

import dataclasses
import math
import threading
from typing import TYPE_CHECKING, Any, ContextManager, Iterable

import numpy as np
import numpy.typing as npt

from twin.checks import finite_vector
from twin.board_limits import GAIN_TOLERANCE, MAX_OFFSET_COUNTS, MAX_TENSION_LIMIT_N, RATED_GAIN_COUNTS_PER_N, motor_problems
from twin.driver import codec
from twin.driver.errors import (ChannelCountError, CommandRejected, DeviceDisconnected, DeviceError, DeviceTimeout,
                                ProtocolVersionError)
from twin.driver.inbox import Inbox, LinkStats
from twin.driver.telemetry import DeviceInfo, Telemetry
from twin.driver.transport import Clock, Transport
from twin.pose import HORIZONTAL

if TYPE_CHECKING:
    from twin.calibration import Calibration
    from twin.driver.fixture import Fixture
    from twin.driver.tracker import TipTracker

__all__ = ["GAIN_TOLERANCE", "MAX_LENGTH_SETPOINT_M", "MAX_OFFSET_COUNTS", "MAX_TENSION_LIMIT_N", "RATED_GAIN_COUNTS_PER_N",
           "MODE_NAMES", "Device"]

# Names of the control modes in this API → the protocol's modes.
MODE_NAMES = {"lengths": codec.Mode.LENGTHS, "pairs": codec.Mode.PAIRS, "tensions": codec.Mode.TENSION}


def _mode(mode: str | codec.Mode) -> codec.Mode:
    if isinstance(mode, codec.Mode):
        return mode
    if mode not in MODE_NAMES:
        raise ValueError(f"mode = {mode!r}: must be one of {', '.join(map(repr, MODE_NAMES))}")
    return MODE_NAMES[mode]


def _vector(name: str, values: npt.ArrayLike, count: int) -> tuple[float, ...]:
    return tuple(finite_vector(name, values, count).tolist())


# Length setpoints the firmware accepts (m): its kMaxLengthSetpointM, a value in mm sent as m
# must not unwind the spools.
MAX_LENGTH_SETPOINT_M = 0.05


def _bounded(name: str, values: tuple[float, ...], low: float, high: float, unit: str, why: str) -> tuple[float, ...]:
    for i, value in enumerate(values):
        if not low <= value <= high:
            raise ValueError(f"{name}[{i}] = {value!r}: outside {low:g}..{high:g} {unit} ({why})")
    return values


def _tension_limit(name: str, value: float) -> float:
    if not (isinstance(value, (int, float, np.floating, np.integer)) and 0.0 < value <= MAX_TENSION_LIMIT_N):
        raise ValueError(f"{name} = {value!r}: must be in (0, {MAX_TENSION_LIMIT_N:g}] N")
    return float(value)


def _rated_gain(name: str, value: float) -> float:
    low, high = RATED_GAIN_COUNTS_PER_N
    if not (isinstance(value, (int, float, np.floating, np.integer)) and low <= value <= high):
        raise ValueError(f"{name} = {value!r}: must be in {low:g}..{high:.0f} counts/N (the HX711's 24-bit range "
                         f"holds the largest limit, {MAX_TENSION_LIMIT_N:g} N, and a count is at most 10 mN)")
    return float(value)


def _calibration(gains: tuple[float, ...], offsets: tuple[float, ...], rated: float) -> None:
    """Refuse, naming the value, a calibration outside the firmware's bounds for load cells of
    ``rated`` counts/N."""
    low, high = rated / GAIN_TOLERANCE, rated * GAIN_TOLERANCE
    for i, gain in enumerate(gains):
        if not low <= gain <= high:
            why = ("counts must rise with tension" if gain <= 0 else
                   f"more than 25 % off the load cells' rated {rated:g} counts/N, sensors.loadcell_gain_counts_per_n; "
                   "it would blind the tension limit")
            raise ValueError(f"gain_counts_per_n[{i}] = {gain!r}: outside {low:g}..{high:g} counts/N ({why})")
    for i, offset in enumerate(offsets):
        if not -MAX_OFFSET_COUNTS <= offset <= MAX_OFFSET_COUNTS:
            raise ValueError(f"offset_counts[{i}] = {offset!r}: outside ±{MAX_OFFSET_COUNTS:g} counts "
                             "(an eighth of the HX711's 24-bit range)")


def _mask(name: str, channels: bool | Iterable[int], count: int) -> int:
    """The bit mask of ``channels`` (True: all ``count``, False: none, else indices 0..count-1)."""
    if channels is True:
        return (1 << count) - 1
    if channels is False:
        return 0
    mask = 0
    for channel in channels:
        if not (isinstance(channel, (int, np.integer)) and 0 <= channel < count):
            raise ValueError(f"{name} = {channels!r}: channels are 0..{count - 1}")
        mask |= 1 << int(channel)
    return mask


class Device:
    """A board behind the protocol: the rig's Teensy, or its emulation.

    Usually made by :func:`twin.driver.open_device`. Commands block until the board's ACK and
    raise :class:`CommandRejected` on a NACK; waits raise :class:`DeviceDisconnected` once the
    board is gone, while the samples received before stay readable (:meth:`latest`,
    :meth:`drain`).

    Args:
        transport: bytes and clock of the backend.
        fixture: operator and fixture actions (tip mass, holder, calibration masses).
        tracker: the EM tracker's fused tip poses, or None when no tracker is configured.
        twin: the simulated twin's ground truth and reset (``sim://``); None on a rig.
        command_timeout_s: longest wait for a command's answer (device clock, s).
        keepalive_s: longest silence before the host's next call sends a PING (device clock,
            s); keep it well under the watchdog timeout (0.25 s by default). None sends no
            keepalives, so the watchdog trips while the host only waits.
        queue_size: samples kept for :meth:`drain`.
        tension_limit_n: the configured per-channel tension limit (N, in (0, 50]), e.g. the
            parameter set's ``rig.tension_limit_n`` (:func:`twin.driver.open_device` passes it):
            every :meth:`enable` sends it first, so that the board never drives with another
            limit than the host's. None keeps the board's default (6 N) until :meth:`set_limits`.
        base_rotation: the clamp's orientation (3×3, body → world) the board's robot is mounted
            in (the twin is built in it): :attr:`base_rotation`. Default the thesis's horizontal clamp.
        tendons: the robot's tendon count (``tendons.count``): :meth:`connect` refuses a board
            with another channel count. None takes the board's count as it comes.
        robot: the robot's name, for that refusal's message (None: "the robot").
        loadcell_gain_counts_per_n: the load cells' rated sensitivity (counts/N), e.g. the
            parameter set's ``sensors.loadcell_gain_counts_per_n``: sent with the limits on
            :meth:`connect` and before every :meth:`enable`; the board then bounds calibrations
            by it (25 % either way) and reads tensions with it until one arrives. None keeps the
            board's default (45,000 counts/N, the thesis's 1 kg cells).
        tendon_m_per_count: the rig's tendon length per encoder count (m), e.g.
            ``rig.tendon_m_per_count``: :meth:`connect` refuses a board that counts otherwise
            (another spool, gearbox or encoder). None takes the board's as it comes.
        motors: the motors at the tendons (:class:`twin.driver.codec.SetMotors`: stall force,
            no-load speed, reflected rotor mass), e.g. from the parameter set's
            ``rig.motor_stall_force_n``, ``rig.motor_no_load_speed_m_per_s`` and
            ``rig.motor_reflected_mass_kg``: sent on :meth:`connect` and before every
            :meth:`enable`, so the board bounds the tension with these motors. None keeps the
            board's default (the thesis rig's).

    Attributes:
        fixture: the :class:`twin.driver.fixture.Fixture` (None if the backend has none).
        tracker: the :class:`twin.driver.tracker.TipTracker`, or None.
    """

    def __init__(
        self,
        transport: Transport,
        *,
        fixture: Fixture | None = None,
        tracker: TipTracker | None = None,
        twin: Any = None,
        command_timeout_s: float = 0.5,
        keepalive_s: float | None = 0.1,
        queue_size: int = 4096,
        tension_limit_n: float | None = None,
        base_rotation=HORIZONTAL,
        tendons: int | None = None,
        robot: str | None = None,
        loadcell_gain_counts_per_n: float | None = None,
        tendon_m_per_count: float | None = None,
        motors: codec.SetMotors | None = None,
    ):
        if motors is not None:
            problems = motor_problems(dataclasses.asdict(motors))
            if problems:
                raise ValueError(f"motors: {problems[0]}")
        self._motors = motors if motors is not None else codec.SetMotors()
        if tendons is not None and not (isinstance(tendons, (int, np.integer)) and tendons >= 1):
            raise ValueError(f"tendons = {tendons!r}: must be a whole number >= 1, or None")
        self._tendons = None if tendons is None else int(tendons)
        self._robot = robot
        if not (math.isfinite(command_timeout_s) and command_timeout_s > 0):
            raise ValueError(f"command_timeout_s = {command_timeout_s!r}: must be finite and > 0")
        if keepalive_s is not None and not (math.isfinite(keepalive_s) and keepalive_s > 0):
            raise ValueError(f"keepalive_s = {keepalive_s!r}: must be finite and > 0, or None")
        self._transport = transport
        self.fixture = fixture
        self.tracker = tracker
        self._twin = twin
        self._command_timeout_s = command_timeout_s
        self._keepalive_s = keepalive_s
        self._inbox = Inbox(transport.time_s, queue_size=queue_size, on_lost=self._disable_after_loss)
        self._send_lock = threading.Lock()
        self._seq = 0
        self._info: DeviceInfo | None = None
        # The limits this host last set, the configured ones (or the board's defaults) until
        # then: the bound on tension setpoints, and what every ENABLE is preceded by.
        defaults = codec.SetLimits()
        self._tension_limit_n = defaults.tension_limit_n
        if tension_limit_n is not None:
            self._tension_limit_n = _tension_limit("tension_limit_n", tension_limit_n)
        self._watchdog_timeout_ms = defaults.watchdog_timeout_ms
        self._rated_gain = defaults.loadcell_gain_counts_per_n
        if loadcell_gain_counts_per_n is not None:
            self._rated_gain = _rated_gain("loadcell_gain_counts_per_n", loadcell_gain_counts_per_n)
        if tendon_m_per_count is not None and not (math.isfinite(tendon_m_per_count) and tendon_m_per_count > 0):
            raise ValueError(f"tendon_m_per_count = {tendon_m_per_count!r}: must be finite and > 0, or None")
        self._tendon_m_per_count = tendon_m_per_count
        self._base_rotation = np.array(base_rotation, dtype=float)
        if self._base_rotation.shape != (3, 3):
            raise ValueError(f"base_rotation = {base_rotation!r}: must be a 3x3 rotation")

    # ------------------------------------------------------------------ identity
    @property
    def url(self) -> str:
        return self._transport.url

    @property
    def loadcell_gain_counts_per_n(self) -> float:
        """The load cells' rated sensitivity (counts/N) this host gives the board: the noise of
        a reading in N scales with its inverse (the HX711's noise is in counts)."""
        return self._rated_gain

    @property
    def base_rotation(self) -> np.ndarray:
        """The clamp's orientation (3×3, body → world): the pose datasets taken on this device
        record and predictions of its measurements use."""
        return self._base_rotation.copy()

    @property
    def transport(self) -> Transport:
        """The backend's transport (bytes and clock); the twin's state is :attr:`twin`'s."""
        return self._transport

    @property
    def twin(self) -> Any:
        """The twin behind a ``sim://`` device (the driver knows no twin: this is what the scheme
        gave, :class:`twin.device.sim_twin.SimTwin` on ``sim://``): its
        ground truth (tip pose, true tensions, simulated time) and a fast reset.

        Raises:
            DeviceError: the device is not a twin (``serial://``: a rig has no ground truth).
        """
        if self._twin is None:
            raise DeviceError(f"{self.url}: not a simulated twin; device.twin (ground truth, reset) is sim:// only")
        return self._twin

    @property
    def clock(self) -> Clock:
        """``"simulated"`` (``sim://``: time passes only in waits) or ``"wall"`` (``serial://``)."""
        return self._transport.clock

    @property
    def connected(self) -> bool:
        """True after :meth:`connect` until :meth:`close` or the board going away."""
        return self._info is not None and self._inbox.error is None

    @property
    def info(self) -> DeviceInfo:
        """What the handshake reported (versions, channels, rates, tendon m per count)."""
        if self._info is None:
            raise DeviceError(f"{self.url}: not connected (call connect())")
        return self._info

    @property
    def channels(self) -> int:
        """Motors and load cells of the board (its HELLO_REPLY's count; the robot's tendon
        count once connected): the length of every per-tendon argument and telemetry array.

        Raises:
            DeviceError: not connected.
        """
        return self.info.channels

    # ------------------------------------------------------------------ connection
    def connect(self, *, timeout_s: float = 2.0) -> DeviceInfo:
        """Open the link, check the protocol version (HELLO), disable the board and wait for
        the first sample after that.

        The board is disabled whatever state a previous host left it in (say one that died a
        moment ago with the rig enabled): this host starts from coasting motors.

        Args:
            timeout_s: how long the port may take to appear and the board to answer (s).

        Raises:
            DeviceError: the port cannot be opened.
            DeviceTimeout: no HELLO_REPLY, no answer to DISABLE or no telemetry in time.
            ProtocolVersionError: the board speaks another protocol version (it was sent
                DISABLE, and nothing else).
            ChannelCountError: the board drives another number of motors than the robot has
                tendons (it was sent DISABLE, and nothing else).
        """
        if self._info is not None:
            return self._info
        self._inbox.restart()
        self._transport.open(self._inbox, timeout_s=timeout_s)
        try:
            info = self._handshake(timeout_s)
        except BaseException:
            self._transport.close()
            raise
        self._info = info
        if self.tracker is not None and self.clock == Clock.WALL:
            # The first fusion in a process compiles (numba: 1 s to over a minute on a loaded
            # machine): done here, with the board disabled, not on a run's first tracker reading,
            # when the silent host let the watchdog stop the enabled board. In simulated time
            # nothing waits meanwhile.
            from twin.tracking import compile_fusion

            with self.attended():
                compile_fusion(self.tracker.calibration)
        return info

    def reconnect(self, *, timeout_s: float = 5.0) -> DeviceInfo:
        """Close the link and connect again, waiting up to ``timeout_s`` for the port to come
        back (a board unplugged and plugged in again).

        Reconnecting is never automatic: a board that comes back has restarted (disabled,
        tares and calibration lost), so the caller must decide how to go on. Samples queued
        before stay in :meth:`drain`.
        """
        self._shutdown()
        return self.connect(timeout_s=timeout_s)

    def close(self) -> None:
        """Disable the motors (if the board is still there), stop the threads, close the link."""
        if self.connected:
            try:
                self.disable()
            except DeviceError:
                # The board went away while closing; its watchdog stops the motors anyway.
                pass
        self._shutdown()
        if self.tracker is not None:
            self.tracker.close()
        close_fixture = getattr(self.fixture, "close", None)  # a RemoteFixture's connection
        if close_fixture is not None:
            close_fixture()

    def attended(self) -> ContextManager[None]:
        """A block in which the host waits on purpose for something other than the board, e.g.
        an operator's confirmation: the watchdog is fed meanwhile, as during :meth:`wait`.

        Example::

            with device.attended():
                input("Hang 10 g at the tip, then press Enter: ")
        """
        return self._transport.attended()

    def __enter__(self) -> "Device":
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ commands
    def ping(self) -> None:
        """A PING answered by an ACK: checks the link and feeds the watchdog."""
        self._command(codec.Ping())

    def enable(self) -> None:
        """Enter ENABLED (clearing latched faults); the rig holds its current lengths or
        tensions until setpoints arrive.

        The motors and the limits this host set last (or was configured with) go to the board
        just before, so that whatever a power cycle or another host did to them, the board
        drives with these.

        Raises:
            CommandRejected: the board refused the motors or the limits (then it was sent DISABLE) or ENABLE.
        """
        self._check_connected()
        sent = [self._motors, self._limits()]
        # Not awaited on their own: the board answers in order, so their answers are in when ENABLE's is.
        seqs = [self._send(message, expect_answer=True) for message in sent]
        try:
            self._await_answer(codec.Enable())
        finally:
            replies = [self._inbox.take_answer(seq) for seq in seqs]
        for message, seq, reply in zip(sent, seqs, replies):
            if isinstance(reply, codec.Nack):
                self._await_answer(codec.Disable())
                raise CommandRejected(self.url, message, seq, reply.error)

    def disable(self) -> None:
        """Enter DISABLED: each motor brakes until its spool stands still, then coasts. Latched
        fault flags stay readable."""
        self._command(codec.Disable())

    def tare(self, *, loadcells: bool | Iterable[int] = True, lengths: bool | Iterable[int] = True) -> None:
        """Zero load cells (tension reads 0 N now) and/or tendon lengths (length reads 0 m now).

        Args:
            loadcells: True for all, False for none, or channel indices 0..channels-1.
            lengths: likewise for the tendon length origins.

        Raises:
            CommandRejected: while enabled, or a load cell to tare is stale.
        """
        n = self.channels
        self._command(codec.Tare(_mask("loadcells", loadcells, n), _mask("lengths", lengths, n), n))

    def set_mode(self, mode: str | codec.Mode) -> None:
        """Switch control mode: ``"lengths"``, ``"pairs"`` or ``"tensions"``. The new mode
        starts from the current measurement (bumpless).

        Raises:
            ValueError: an unknown mode, or ``"pairs"`` on an odd count of tendons (pairs are
                tendon i and i + N/2).
        """
        mode = _mode(mode)
        if mode == codec.Mode.PAIRS:
            self._check_pairs("mode", "pairs")
        self._command(codec.SetMode(mode))

    def set_gains(
        self, mode: str | codec.Mode, *, kp: float, ki: float, kd: float, output_limit: float = 1.0
    ) -> None:
        """PID gains of one mode, for all motors.

        Args:
            mode: ``"lengths"``, ``"pairs"`` or ``"tensions"``.
            kp: duty per m (length modes) or per N (tensions), >= 0.
            ki: duty per (m·s) or (N·s), >= 0.
            kd: duty·s per m or per N, >= 0.
            output_limit: bound on |duty| and on the integral term, in (0, 1].

        Raises:
            ValueError: a gain not finite or negative, or ``output_limit`` outside (0, 1].
        """
        for name, value in (("kp", kp), ("ki", ki), ("kd", kd)):
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} = {value!r}: must be finite and >= 0")
        if not 0.0 < output_limit <= 1.0:
            raise ValueError(f"output_limit = {output_limit!r}: must be in (0, 1]")
        self._command(codec.SetGains(_mode(mode), float(kp), float(ki), float(kd), float(output_limit)))

    def set_calibration(
        self,
        calibration: Calibration | None = None,
        *,
        gain_counts_per_n: npt.ArrayLike | None = None,
        offset_counts: npt.ArrayLike | None = None,
    ) -> None:
        """Give the board the load-cell calibration ``raw = offset_counts + gain_counts_per_n · N``.

        Pass a :class:`twin.calibration.Calibration`, or both arrays. Needed before tension mode.

        Raises:
            ValueError: neither or both forms given, values not finite, or a gain or offset
                outside the bounds the firmware accepts (:data:`GAIN_TOLERANCE` of the rated
                sensitivity, :data:`MAX_OFFSET_COUNTS`; the argument, channel and value named).
            CommandRejected: while enabled.
        """
        if calibration is not None:
            if gain_counts_per_n is not None or offset_counts is not None:
                raise ValueError("set_calibration: pass a Calibration or the arrays, not both")
            gain_counts_per_n, offset_counts = calibration.gain_counts_per_n, calibration.offset_counts
        elif gain_counts_per_n is None or offset_counts is None:
            raise ValueError(
                f"gain_counts_per_n = {gain_counts_per_n!r}, offset_counts = {offset_counts!r}: "
                "pass a Calibration, or both arrays"
            )
        gains = _vector("gain_counts_per_n", gain_counts_per_n, self.channels)
        offsets = _vector("offset_counts", offset_counts, self.channels)
        _calibration(gains, offsets, self._rated_gain)
        self._command(codec.SetCalibration(tuple(1.0 / g for g in gains), offsets, self.channels))

    def set_limits(self, *, tension_limit_n: float | None = None, watchdog_timeout_s: float = 0.25) -> None:
        """Per-channel tension limit and watchdog timeout; every later :meth:`enable` sends them
        again.

        Args:
            tension_limit_n: N, in (0, 50]; None keeps the one configured or set last.
            watchdog_timeout_s: s, 0.02…10.

        Raises:
            ValueError: a value out of range (named).
        """
        limit = self._tension_limit_n if tension_limit_n is None else _tension_limit("tension_limit_n", tension_limit_n)
        if not 0.02 <= watchdog_timeout_s <= 10.0:
            raise ValueError(f"watchdog_timeout_s = {watchdog_timeout_s!r}: must be in 0.02..10")
        self._command(codec.SetLimits(limit, round(watchdog_timeout_s * 1e3), self._rated_gain))

    def set_lengths(self, lengths_m: npt.ArrayLike) -> None:
        """Setpoints of ``"lengths"`` mode: a relative length per tendon (m, positive = paid out,
        within ±:data:`MAX_LENGTH_SETPOINT_M`).

        Raises:
            ValueError: not :attr:`channels` finite numbers, or one beyond ±0.05 m (the value
                and its index named).
        """
        n = self.channels
        lengths = _vector("lengths_m", lengths_m, n)
        limit = MAX_LENGTH_SETPOINT_M
        self._command(codec.SetSetpoints.lengths(_bounded("lengths_m", lengths, -limit, limit, "m", "mm sent as m?"), n))

    def set_pairs(self, pairs_m: npt.ArrayLike) -> None:
        """Setpoints of ``"pairs"`` mode, one per antagonistic pair (tendon k and k + N/2 of N):
        d₁₃ and d₂₄ on four tendons (m, within ±:data:`MAX_LENGTH_SETPOINT_M`); tendon 1 goes to
        c₁₃ + d₁₃ and tendon 3 to c₁₃ − d₁₃, c the pair's mean length when the mode was entered.

        Raises:
            ValueError: an odd count of tendons (no pairs), not N/2 finite numbers, or one
                beyond ±0.05 m.
        """
        n = self.channels
        self._check_pairs("pairs_m", pairs_m)
        pairs = _vector("pairs_m", pairs_m, n // 2)
        limit = MAX_LENGTH_SETPOINT_M
        self._command(codec.SetSetpoints.pairs(_bounded("pairs_m", pairs, -limit, limit, "m", "mm sent as m?"), n))

    def set_tensions(self, tensions_n: npt.ArrayLike) -> None:
        """Setpoints of ``"tensions"`` mode: a tension per tendon (N, from 0 to the tension
        limit this host last set with :meth:`set_limits`, 6 N until then).

        Raises:
            ValueError: not :attr:`channels` finite numbers, or one outside 0..limit.
        """
        n = self.channels
        tensions = _vector("tensions_n", tensions_n, n)
        tensions = _bounded("tensions_n", tensions, 0.0, self._tension_limit_n, "N", "the tension limit; set_limits")
        self._command(codec.SetSetpoints.tensions(tensions, n))

    # ------------------------------------------------------------------ telemetry and time
    def latest(self) -> Telemetry:
        """The most recent sample (kept after the board went away); sends the keepalive PING
        if one is due, as every call of the control loop does."""
        self._transport.ping_if_due()
        if self._inbox.latest is None:
            raise DeviceError(f"{self.url}: no telemetry yet (call connect())")
        return self._inbox.latest

    def wait_next(self, timeout_s: float = 1.0) -> Telemetry:
        """Wait for the next sample after this call (40 Hz) and return it.

        Raises:
            DeviceTimeout: none within ``timeout_s`` (device clock).
            DeviceDisconnected: the board went away.
        """
        self._check_connected()
        count = self._inbox.sample_count
        if not self._wait_for(lambda: self._inbox.sample_count > count, timeout_s):
            raise DeviceTimeout(f"{self.url}: no telemetry within {timeout_s} s ({self.clock} clock)")
        latest = self._inbox.latest
        assert latest is not None, "a counted sample is kept"
        return latest

    def wait(self, duration_s: float) -> None:
        """Let ``duration_s`` pass: simulated seconds on ``sim://`` (the twin runs meanwhile),
        wall-clock seconds on ``serial://``.

        Raises:
            DeviceDisconnected: the board went away meanwhile.
        """
        if not (math.isfinite(duration_s) and duration_s >= 0):
            raise ValueError(f"duration_s = {duration_s!r}: must be finite and >= 0")
        self._check_connected()
        self._wait_for(lambda: False, duration_s)

    @property
    def time_s(self) -> float:
        """Device time now (s since the board started): exact on ``sim://``; on ``serial://``
        the latest sample's time plus the wall time since it arrived."""
        latest = self.latest()
        return latest.time_s + (self._transport.time_s() - latest.received_s)

    def drain(self) -> list[Telemetry]:
        """Every sample received since the last drain, oldest first (up to ``queue_size``);
        works after the board went away. Sends the keepalive PING if one is due."""
        self._transport.ping_if_due()
        return self._inbox.drain()

    def add_sample_listener(self, listener) -> None:
        """Have ``listener(sample)`` called with every telemetry sample as it arrives (in the
        transport's reader thread on ``serial://``, so it must be short), whoever drains them."""
        self._inbox.listeners.append(listener)

    @property
    def lost_samples(self) -> int:
        """Samples missing from the board's sequence (lost on the link)."""
        return self._inbox.lost_samples

    @property
    def dropped_samples(self) -> int:
        """Samples pushed out of the drain queue because nobody drained it."""
        return self._inbox.dropped_samples

    @property
    def stats(self) -> LinkStats:
        """What the host dropped or missed on the link, with the reason for the latest drop
        (:class:`twin.driver.inbox.LinkStats`)."""
        return self._inbox.stats()

    @property
    def bad_frames(self) -> int:
        """Frames this host dropped for framing or CRC errors (this connection)."""
        return self._inbox.decoder.bad_frames

    @property
    def bad_messages(self) -> int:
        """Intact frames this host could not use: unknown type or wrong length (this connection)."""
        return self._inbox.decoder.bad_messages

    # ------------------------------------------------------------------ internals
    def _handshake(self, timeout_s: float) -> DeviceInfo:
        # A leading delimiter ends whatever partial frame a previous host left on the line.
        self._transport.write(b"\x00")
        count = self._inbox.hello_count
        self._send(codec.Hello())
        if not self._wait_for(lambda: self._inbox.hello_count > count, timeout_s):
            raise DeviceTimeout(
                f"{self.url}: no HELLO_REPLY within {timeout_s} s; is the twin firmware running on it?"
            )
        reply = self._inbox.hello_reply
        assert reply is not None, "a counted HELLO_REPLY is kept"
        if reply.protocol_version != codec.PROTOCOL_VERSION:
            self._send(codec.Disable())
            raise ProtocolVersionError(self.url, reply.protocol_version)
        if self._tendons is not None and reply.channels != self._tendons:
            self._send(codec.Disable())
            raise ChannelCountError(self.url, reply.channels, self._tendons, self._robot)
        if self._tendon_m_per_count is not None and not math.isclose(
                reply.tendon_m_per_count, self._tendon_m_per_count, rel_tol=1e-5):
            self._send(codec.Disable())
            raise DeviceError(
                f"{self.url}: the board counts {reply.tendon_m_per_count:.6g} m of tendon per encoder count, the "
                f"robot's rig {self._tendon_m_per_count:.6g} m (rig.spool_radius_m, rig.gear_ratio, "
                "rig.encoder_counts_per_rev); flash firmware built for this rig (firmware/core/config.h) "
                "or correct the parameter file")
        self._transport.keep_alive(self._keepalive_s, self._ping)
        # Whatever a previous host left running stops before this one takes over; then the board
        # is given this host's limits and load cells, so that it reads tensions in this rig's
        # units from the first sample on.
        self._await_answer(codec.Disable())
        self._await_answer(self._motors)
        self._await_answer(self._limits())
        # Samples that came before may be stale (old bytes on the line, a state before the
        # DISABLE); wait for one after.
        inbox = self._inbox
        count = inbox.samples_before_answer
        if not self._wait_for(lambda: inbox.sample_count > count, timeout_s):
            raise DeviceTimeout(f"{self.url}: handshake done but no telemetry within {timeout_s} s")
        return DeviceInfo.from_reply(reply, url=self.url, clock=self.clock)

    def _limits(self) -> codec.SetLimits:
        """The limits this host set last (or was configured with), and its load cells."""
        return codec.SetLimits(self._tension_limit_n, self._watchdog_timeout_ms, self._rated_gain)

    def _check_pairs(self, name: str, value) -> None:
        """Refuse, naming ``name`` and its value, pairs on an odd count of tendons."""
        if not codec.pairs_possible(self.channels):
            raise ValueError(f"{name} = {value!r}: the board's {self.channels} tendons do not form antagonistic "
                             "pairs (tendon i and i + N/2 need an even count)")

    def _shutdown(self) -> None:
        self._transport.close()
        self._info = None

    def _check_connected(self) -> None:
        self._raise_if_lost()
        if self._info is None:
            raise DeviceError(f"{self.url}: not connected (call connect())")

    def _raise_if_lost(self) -> None:
        error = self._inbox.error
        if error is not None:
            raise DeviceDisconnected(str(error)) from error

    def _send(self, message: codec.Message, *, expect_answer: bool = False) -> int:
        # Nothing goes out once the link is lost (no PING keeps a board enabled for a host
        # that cannot hear it), except the DISABLE of _disable_after_loss.
        self._raise_if_lost()
        return self._write(message, expect_answer=expect_answer)

    def _write(self, message: codec.Message, *, expect_answer: bool = False) -> int:
        with self._send_lock:
            self._seq = (self._seq + 1) & 0xFFFF
            seq = self._seq
            self._inbox.sent(seq, message.TYPE)
            if expect_answer:
                self._inbox.expect(seq, message.TYPE)
            self._transport.write(codec.encode_frame(message, seq))
        return seq

    def _ping(self) -> None:
        self._send(codec.Ping())

    def _disable_after_loss(self, error: DeviceDisconnected) -> None:
        """The host stopped hearing the board while the board may still hear it: tell it to
        stop, best effort (its watchdog stops it anyway once nothing more arrives)."""
        try:
            self._write(codec.Disable())
        except DeviceError:
            pass

    def _command(self, message: codec.Message) -> None:
        self._check_connected()
        self._await_answer(message)
        if isinstance(message, codec.SetLimits):
            self._tension_limit_n = message.tension_limit_n
            self._watchdog_timeout_ms = message.watchdog_timeout_ms

    def _await_answer(self, message: codec.Message) -> None:
        seq = self._send(message, expect_answer=True)
        try:
            answered = self._wait_for(lambda: self._inbox.answered(seq), self._command_timeout_s)
        finally:
            reply = self._inbox.take_answer(seq)
        if not answered:
            name = codec.MsgType(message.TYPE).name
            raise DeviceTimeout(
                f"{self.url}: no answer to {name} (seq {seq}) within {self._command_timeout_s} s ({self.clock} clock)"
            )
        if isinstance(reply, codec.Nack):
            raise CommandRejected(self.url, message, seq, reply.error)

    def _wait_for(self, predicate, timeout_s: float) -> bool:
        inbox = self._inbox
        done = self._transport.wait_until(lambda: inbox.error is not None or predicate(), timeout_s)
        self._raise_if_lost()
        return done
