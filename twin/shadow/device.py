"""A device with its twin in lockstep beside it: every command goes to both, every frame is compared.

:class:`ShadowDevice` stands in for a :class:`twin.driver.Device` (what it does not handle it
forwards), so code written for a device runs unchanged with a shadow (``?shadow=1`` on a device
URL, :func:`twin.driver.open_device`). The twin is a ``sim://`` device of the same parameters,
stepped in simulated time to each telemetry frame's device time: it hears the same commands and
fixture actions at the same device time, and each device frame (encoders, tensions, duty,
faults, and the tracked tip) is compared with the twin's frame of the same time by a
:class:`twin.shadow.monitor.Monitor`. A divergence it names goes to the console and a JSON-lines
log, and the twin is re-calibrated for the parameter found changed (:meth:`ShadowDevice._recalibrate`).

The comparison runs in the host's own calls (waits, commands, ``latest``, ``drain``), on the
frames that arrived since, so it costs the control loop its CPU time (:attr:`ShadowDevice.cpu_s`);
on a wall-clock device a shadow that falls more than :data:`BEHIND_FRAMES` frames behind says so.
"""

from __future__ import annotations

import collections
import json
import math
import sys
import time
from pathlib import Path
from typing import IO, Any, Callable

import numpy as np

from twin.params import Params
from twin.shadow.monitor import Divergence, FrameValues, Monitor
from twin.tracking import fuse_frame

__all__ = ["BEHIND_FRAMES", "DEFAULT_WARMUP_S", "IGTL_DEVICE", "ShadowDevice", "divergence_message"]

# OpenIGTLink device name of the divergences' STRING messages (Slicer: a text node of this name).
IGTL_DEVICE = "ShadowEvent"
# Device time the noise is learnt over by default (s): a minute of motion holds the tails that a
# clean half hour showed (twin shadow caps its own warm-up there for the same reason).
DEFAULT_WARMUP_S = 60.0

# Longest a wall-clock shadow works in one of the host's calls (s): a fifth of the board's 0.25 s watchdog.
SYNC_BUDGET_S = 0.05
# Frames waiting for comparison beyond which a wall-clock shadow reports it is behind (100 ms at 40 Hz).
BEHIND_FRAMES = 4
# Commands that only move setpoints: both sides take them at the same instant of the same frame.
SETPOINTS = ("set_lengths", "set_pairs", "set_tensions")
# Frames not compared after any other command or fixture action, which may take effect in
# another frame on each side (a tick's order of command and telemetry).
SETTLE_FRAMES = 2
# Largest difference of the two sides' setpoints (m in the length modes, N in tension mode) taken
# as the same setpoint: far below a count or a load cell's noise, above the float32 the board sends.
TARGET_TOLERANCE = 1e-6
# Device commands the twin hears too.
COMMANDS = ("enable", "disable", "tare", "set_mode", "set_gains", "set_calibration", "set_limits", "set_lengths",
            "set_pairs", "set_tensions")


def divergence_message(event: Divergence, *, timestamp_s: float, version: int = 1) -> bytes:
    """A divergence as an OpenIGTLink STRING message (device :data:`IGTL_DEVICE`): its console
    line, which Slicer shows as a text node; with header version 2 its fields as metadata too."""
    from twin.driver import igtl

    metadata = {k: json.dumps(v) if not isinstance(v, str) else v for k, v in event.to_dict().items()}
    return igtl.pack("STRING", IGTL_DEVICE, igtl.encode_string(event.line().strip()), timestamp_s=timestamp_s,
                     version=version, metadata=metadata if version == 2 else None)


class _FixturePair:
    """The device's fixture, its actions done on the twin too (at the same device time)."""

    def __init__(self, shadow: "ShadowDevice", device_fixture, twin_fixture):
        self._shadow, self._device, self._twin = shadow, device_fixture, twin_fixture

    def __getattr__(self, name: str):
        action = getattr(self._device, name)
        if not callable(action) or name.startswith("_") or not hasattr(self._twin, name):
            return action

        def both(*args, **kwargs):
            shadow = self._shadow
            shadow._sync(to_now=True)
            getattr(self._twin, name)(*args, **kwargs)
            shadow._settle()
            return action(*args, **kwargs)

        return both


class ShadowDevice:
    """``device`` with ``twin`` in lockstep beside it.

    Args:
        device: the watched :class:`twin.driver.Device` (not yet connected).
        twin: a ``sim://`` device of the calibrated parameters whose fixture acts without settling
            (the device's fixture settles for both).
        params: the calibrated parameter set (noise floors, the rod model for naming).
        warmup_s: device time over which the noise is learned (s).
        log_path: JSON-lines file the divergences are appended to, or None.
        console: where each divergence is printed as a line (None: not printed).
        on_divergence: also called with each :class:`Divergence`.
        use_rod: name tip loads with the rod model's Jacobian (Numba; compiled once).
        recalibrate: re-calibrate the twin after a divergence with a parameter (else only learn the
            bias again).
        noise: a :class:`twin.shadow.monitor.NoiseModel` learned before on this device and motion
            (no warm-up then).
    """

    def __init__(self, device, twin, params: Params, *, warmup_s: float = DEFAULT_WARMUP_S, log_path: str | Path | None = None,
                 console: IO[str] | None = sys.stderr, on_divergence: Callable[[Divergence], None] | None = None,
                 use_rod: bool = True, recalibrate: bool = True, noise=None):
        self._device = device
        self._twin = twin
        self.params = params
        self._queue: collections.deque = collections.deque()
        device.add_sample_listener(self._queue.append)
        self.fixture = _FixturePair(self, device.fixture, twin.fixture)
        self.monitor = Monitor(params, warmup_s=warmup_s, jacobian=self._jacobian if use_rod else None, noise=noise)
        self._log_path = Path(log_path) if log_path is not None else None
        self._console = console
        self._listeners: list[Callable[[Divergence], None]] = [] if on_divergence is None else [on_divergence]
        self._recalibrate_on = recalibrate
        self._offset_s: float | None = None
        self._rod: Any = None  # the twin.rod.RodModel, built with the first Jacobian
        self._twin_force_n = np.zeros(3)
        # What gives the twin back what it had before each re-calibration, by the event's id.
        self._given: dict[int, Callable[[], None]] = {}
        self._settle_until_s = -math.inf
        self._in_sync = False
        self.cpu_s = 0.0
        self.compared = 0
        self.unmatched = 0
        self.behind = 0
        self.max_queue = 0
        self.twin_resyncs = 0
        self.skipped = 0
        self.target_mismatches = 0
        self.divergences: list[Divergence] = []

    # ------------------------------------------------------------------ forwarding
    def __getattr__(self, name: str) -> Any:
        attribute = getattr(self._device, name)
        if name in COMMANDS:
            def both(*args, **kwargs):
                self._sync(to_now=True)
                result = attribute(*args, **kwargs)
                self._sync(to_now=True)
                self._twin_command(name, *args, **kwargs)
                if name not in SETPOINTS:
                    self._settle()
                return result

            return both
        if name in ("wait", "wait_next", "latest", "drain"):
            def then_compare(*args, **kwargs):
                result = attribute(*args, **kwargs)
                self._sync()
                return result

            return then_compare
        return attribute

    def _twin_command(self, name: str, *args, **kwargs) -> None:
        """The device's command to the twin too. A twin that faulted where the device did not (a
        fault divergence is raised from the frames) is re-synchronised first: enabled again in the
        device's mode."""
        if name in SETPOINTS:
            device, twin = self._device.latest(), self._twin.latest()
            if device.enabled and not twin.enabled:
                self.twin_resyncs += 1
                self._twin.set_mode(device.mode)
                self._twin.enable()
        getattr(self._twin, name)(*args, **kwargs)

    def subscribe(self, listener: Callable[[Divergence], None]) -> None:
        """Call ``listener`` with each :class:`Divergence` raised from now on (a live view's
        :meth:`twin.live.LiveView.show_divergence`, an OpenIGTLink server's send)."""
        self._listeners.append(listener)

    @property
    def twin_device(self):
        """The twin beside the device (a ``sim://`` :class:`twin.driver.Device`)."""
        return self._twin

    @property
    def device(self):
        """The watched device."""
        return self._device

    @property
    def time_s(self) -> float:
        now = self._device.time_s
        self._sync()
        return now

    def connect(self, **kwargs):
        info = self._device.connect(**kwargs)
        self._twin.connect()
        self._align(info)
        return info

    def reconnect(self, **kwargs):
        info = self._device.reconnect(**kwargs)
        self._twin.reconnect()
        self._align(info)
        return info

    def _align(self, info) -> None:
        """Start the lockstep afresh after a (re)connect: no frame of before is compared, and the
        twin's clock is offset from the device's by whole telemetry periods, so that the two
        sides' frames fall at the same instants."""
        self._queue.clear()
        period = info.telemetry_period_s
        self._offset_s = round((self._device.time_s - self._twin.time_s) / period) * period

    def close(self) -> None:
        try:
            self._device.close()
        finally:
            self._twin.close()

    def __enter__(self) -> "ShadowDevice":
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ lockstep
    def _settle(self) -> None:
        """Skip the comparison of the next :data:`SETTLE_FRAMES` frames."""
        self._settle_until_s = self._device.latest().time_s + (SETTLE_FRAMES + 0.5) * 0.025

    def _sync(self, to_now: bool = False) -> None:
        """Compare the frames that arrived since the last call; with ``to_now`` also bring the
        twin to the device's time now (before a command or fixture action).

        On a wall-clock device the shadow must not starve the control loop: it feeds the board's
        watchdog between frames and spends at most :data:`SYNC_BUDGET_S` of wall time a call;
        frames left over are compared at the next call, or, where a command needs the twin at the
        device's time now, stepped over uncompared (counted in :attr:`skipped`)."""
        if self._in_sync or self._offset_s is None:
            return
        self._in_sync = True
        start = time.process_time()
        wall = self._device.clock == "wall"
        deadline = time.monotonic() + SYNC_BUDGET_S
        try:
            queue = self._queue
            self.max_queue = max(self.max_queue, len(queue))
            if len(queue) > BEHIND_FRAMES and wall:
                self.behind += 1
                if self._console is not None and self.behind in (1, 10, 100, 1000):
                    print(f"shadow: {len(queue)} frames behind the device (the twin and comparison cost more than "
                          "real time); comparing them late", file=self._console, flush=True)
            tip_frame = None
            if queue and self._device.tracker is not None:
                tip_frame = self._device_tip()
            while queue:
                if wall:
                    self._device.latest()  # sends the keepalive PING if one is due
                    if time.monotonic() > deadline:
                        break
                sample = queue.popleft()
                self._compare(sample, tip_frame if not queue else None)
            if to_now:
                self.skipped += len(queue)
                queue.clear()
                self._advance_twin(self._device.time_s - self._offset_s)
        finally:
            self._in_sync = False
            self.cpu_s += time.process_time() - start

    def _advance_twin(self, target_s: float) -> None:
        twin = self._twin
        ahead = target_s - twin.time_s
        if ahead > 1e-9:
            twin.wait(ahead)

    def _device_tip(self):
        """The device's tracked tip position (None when the frame is rejected) and its frame's
        timestamp (None when unreadable)."""
        tracker = self._device.tracker
        try:
            frame = tracker.read_frame()
            fused = fuse_frame(frame, tracker.calibration, tracker.settings)
        except Exception:  # noqa: BLE001 - a tracker that fails is seen as a dropout, not a crash of the host
            return None, None
        return (fused.pose.position_m if fused.ok and fused.pose is not None else None), frame.probe_a.timestamp_s

    def _compare(self, sample, tip_frame) -> None:
        target = sample.time_s - self._offset_s
        self._advance_twin(target)
        twin_sample = self._twin.latest()
        # The frame of an instant comes out of the tick that starts there.
        while twin_sample.time_s < target - 1e-6:
            twin_sample = self._twin.wait_next(timeout_s=0.1)
        if abs(twin_sample.time_s - target) > 1e-4:
            self.unmatched += 1
            return
        n = self.params.tendons.count
        nan3 = np.full(3, np.nan)
        device_tip, twin_tip, frame_time = nan3, nan3, None
        if tip_frame is not None:
            position, frame_time = tip_frame
            if position is not None:
                device_tip = np.asarray(position, dtype=float)
                twin_tip = self._twin.twin.tip_pose()[0]
        device = FrameValues(sample.time_s, sample.tendon_lengths_m[:n], sample.tensions_n[:n],
                             sample.motor_commands[:n], device_tip, int(sample.state), int(sample.fault_flags))
        twin = FrameValues(sample.time_s, twin_sample.tendon_lengths_m[:n], twin_sample.tensions_n[:n],
                           twin_sample.motor_commands[:n], twin_tip, int(twin_sample.state),
                           int(twin_sample.fault_flags))
        self.compared += 1
        if not np.allclose(sample.targets[:n], twin_sample.targets[:n], rtol=0.0, atol=TARGET_TOLERANCE):
            # A setpoint reached one side a tick or more before the other (a wall-clock link's
            # latency, which the host's clock does not see): the two loops run different commands
            # until both hold it, and part for the step's transient after.
            self.target_mismatches += 1
            self._settle_until_s = sample.time_s + (SETTLE_FRAMES + 0.5) * self.monitor.period_s
        settling = sample.time_s <= self._settle_until_s
        for event in self.monitor.update(device, twin, tip_frame_time_s=frame_time, settling=settling):
            self._raise(event)
        for event in self.monitor.take_retracted():
            self._retract(event)

    # ------------------------------------------------------------------ divergences
    def _raise(self, event: Divergence) -> None:
        self.divergences.append(event)
        if self._console is not None:
            print(f"shadow: {event.line()}", file=self._console, flush=True)
        if self._log_path is not None:
            with self._log_path.open("a") as log:
                log.write(json.dumps(event.to_dict()) + "\n")
        for listener in self._listeners:
            listener(event)
        if self._recalibrate_on:
            self._recalibrate(event)

    def _recalibrate(self, event: Divergence) -> None:
        """Give the twin the change found where the cause has a parameter it can take."""
        from twin.sim.events import HiddenEvent

        twin = self._twin.twin
        n = self.params.tendons.count
        # Only a change resolved (twice its uncertainty) is given to the twin; else the bias is
        # learned again and that is all.
        if not (math.isfinite(event.size) and math.isfinite(event.std) and abs(event.size) > 2 * event.std):
            return
        if event.kind in ("loadcell_offset", "loadcell_gain"):
            key = "effects.tension_offset_error_n" if event.kind == "loadcell_offset" else "effects.tension_gain_error"
            values = np.array(twin.params.get(key), dtype=float)
            before = HiddenEvent(0.0, "set", (key, values.tolist()))
            self._given[id(event)] = lambda: twin.change(before)
            values[event.detail["channel"]] += event.size
            twin.change(HiddenEvent(0.0, "set", (key, values.tolist())))
        elif event.kind == "tendon_slip":
            slip = np.zeros(n)
            slip[event.detail["tendon"]] = event.size
            self._given[id(event)] = lambda: twin.change(HiddenEvent(0.0, "tendon_slip_m", -slip))
            twin.change(HiddenEvent(0.0, "tendon_slip_m", slip))
        elif event.kind == "tip_load" and "force_n" in event.detail:
            # The load as the world sees it: the twin's own tip force plus the one found.
            force = np.asarray(event.detail["force_n"], dtype=float)
            self._given[id(event)] = lambda: self._give_tip_force(self._twin_force_n - force)
            self._give_tip_force(self._twin_force_n + force)
        else:
            return
        self.monitor.recalibrated(event)

    def _give_tip_force(self, force_n: np.ndarray) -> None:
        from twin.sim.events import HiddenEvent

        self._twin_force_n = force_n
        self._twin.twin.change(HiddenEvent(0.0, "tip_force_n", force_n))

    def _retract(self, event: Divergence) -> None:
        """Give the twin back what it had before ``event``'s re-calibration, which the monitor
        found fits the device no better than the twin without it."""
        undo = self._given.pop(id(event), None)
        if undo is not None:
            undo()
        if self._console is not None:
            print(f"shadow: retracted {event.line()}", file=self._console, flush=True)
        if self._log_path is not None:
            with self._log_path.open("a") as log:
                # The event again, its detail now saying ``retracted``: the log's lines keep one shape.
                log.write(json.dumps(event.to_dict()) + "\n")

    def _jacobian(self, tensions_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from twin.rod import RodModel, solve_with_jacobian

        if self._rod is None:
            self._rod = RodModel.from_params(self.params)
        _, jac = solve_with_jacobian(self._rod, tensions_n, base_rotation=self._device.base_rotation)
        return jac.position_wrt_tension, jac.position_wrt_force

    def warm_rod(self) -> None:
        """Compile and cache the rod model's kernels now (once per install), not at the first
        divergence."""
        self._jacobian(np.full(self.params.tendons.count, self.params.tendons.pretension_n))
