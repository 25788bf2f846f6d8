"""The dynamic experiments: schedules of timed commands, run on any device through its interface.

An :class:`Experiment` is a control mode and a list of :class:`Command` (device time after the
start, setpoints), sized from the robot's parameter set (its pretension, tension limit, tendon
radius and angles, backbone length) for any tendon count. :func:`run_experiment` pretensions
the endoscope straight in the reference holder (:func:`twin.experiments.protocols.pretension`),
releases it, then sends each command once the device's clock reaches its time, reading every
telemetry sample and the tracked tip until the schedule ends. The same function records on the
rig and replays on the twin (:mod:`twin.dynamics.replay`), so both see the commands at the same
device times, to the telemetry period (25 ms at the thesis's 40 Hz).

The set (:func:`experiment_set`), in the order it runs:

``length_steps``   lengths mode: the PCC lengths of curvature :data:`STEP_KAPPA_PER_M` in each
                   tendon's plane in turn, held, back to straight.
``pull_release``   lengths mode: slow triangles of curvature to :data:`CYCLE_KAPPA_PER_M` and back
                   in the first tendon's plane (hysteresis, backlash), a command per
                   :data:`CYCLE_COMMAND_S`.
``chirp``          lengths mode: curvature ``κ_a sin(2π ∫f dt)`` with f swept linearly from
                   :data:`CHIRP_HZ` low to high, a command per telemetry period.
``tension_steps``  tensions mode: each tendon in turn stepped from the pretension up by
                   :data:`TENSION_STEP_FRACTION` of the headroom to the tension limit, held,
                   stepped back.

``quick`` keeps the first tendon of the steps, one cycle and a shorter chirp.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from twin.driver.errors import CommandRejected
from twin.experiments.protocols import ProtocolError, pretension
from twin.params import Params
from twin.pcc import THESIS_LENGTH_M, tendon_length_changes_m

__all__ = ["CHIRP_HZ", "CYCLE_COMMAND_S", "CYCLE_KAPPA_PER_M", "COMMAND_KINDS", "Command", "Experiment",
           "Series", "STEP_HOLD_S", "STEP_KAPPA_PER_M", "TENSION_STEP_FRACTION", "experiment_set", "run_experiment"]

# Share of the headroom between pretension and tension limit a tension step takes: well inside
# the limit, large enough that a 5 mN load-cell noise is a hundredth of it.
TENSION_STEP_FRACTION = 0.3
# Curvature of a length step (1/m): half the thesis grid's largest 26.2 1/m.
STEP_KAPPA_PER_M = 13.0
# Peak curvature of a pull-release cycle (1/m): the grid's 17.5 1/m.
CYCLE_KAPPA_PER_M = 17.5
# Command spacing of the slow cycles (s): slow beside the 100 Hz control loop.
CYCLE_COMMAND_S = 0.05
# How long a step is held (s): the tip's step response (damping time 30 ms, loops of 10 ms)
# settles within a few tenths of a second.
STEP_HOLD_S = 0.6
# The chirp's frequency sweep (Hz): from quasi-static to where the length loop's phase lag is large.
CHIRP_HZ = (0.5, 4.0)
# The chirp's curvature amplitude (1/m).
CHIRP_KAPPA_PER_M = 8.0
# Device time the released endoscope rests before the schedule starts (s).
RELEASE_REST_S = 0.3

COMMAND_KINDS = ("tensions", "lengths")


@dataclasses.dataclass(frozen=True)
class Command:
    """One setpoint command.

    Attributes:
        time_s: device time after the experiment's start at which it is sent (s).
        values: per tendon: tensions (N) in tensions mode, lengths relative to the pretensioned
            straight pose (m, positive = paid out) in lengths mode.
    """

    time_s: float
    values: tuple[float, ...]


@dataclasses.dataclass(frozen=True)
class Experiment:
    """A dynamic experiment: its name, control mode, commands in time order and duration.

    Attributes:
        name: e.g. ``"tension_steps"``.
        mode: ``"tensions"`` or ``"lengths"`` (:data:`COMMAND_KINDS`).
        commands: the schedule.
        duration_s: device time recorded after the start (s), at least the last command's.
    """

    name: str
    mode: str
    commands: tuple[Command, ...]
    duration_s: float

    def __post_init__(self):
        if self.mode not in COMMAND_KINDS:
            raise ValueError(f"mode = {self.mode!r}: must be one of {', '.join(COMMAND_KINDS)}")
        times = [c.time_s for c in self.commands]
        if times != sorted(times) or (times and (times[0] < 0 or times[-1] > self.duration_s)):
            raise ValueError(f"experiment {self.name!r}: command times must rise within 0..{self.duration_s} s")


@dataclasses.dataclass
class Series:
    """What one run of an experiment recorded.

    Attributes:
        experiment: the :class:`Experiment` run.
        sent_s: (C,) device time after the start at which each command was sent (s).
        time_s: (T,) device time of each telemetry sample after the start (s).
        lengths_m: (T, n) encoder lengths relative to the pretensioned straight pose (m).
        tensions_n: (T, n) calibrated tensions (N).
        tip_m: (T, 3) tracked tip position, world frame (m); NaN where no frame was valid.
        tip_quat: (T, 4) its orientation (w, x, y, z); NaN likewise.
    """

    experiment: Experiment
    sent_s: np.ndarray
    time_s: np.ndarray
    lengths_m: np.ndarray
    tensions_n: np.ndarray
    tip_m: np.ndarray
    tip_quat: np.ndarray


def _steps(name: str, mode: str, rest: np.ndarray, targets: list[np.ndarray]) -> Experiment:
    commands, t = [], 0.0
    for target in targets:
        commands.append(Command(t, tuple(float(v) for v in target)))
        commands.append(Command(t + STEP_HOLD_S, tuple(float(v) for v in rest)))
        t += 2 * STEP_HOLD_S
    return Experiment(name, mode, tuple(commands), t)


def _kappa_schedule(name: str, params: Params, times_s: np.ndarray, kappa_per_m: np.ndarray, phi_deg: float,
                    duration_s: float) -> Experiment:
    commands = tuple(Command(float(t), tuple(float(v) for v in tendon_length_changes_m(float(k), phi_deg, params)))
                     for t, k in zip(times_s, kappa_per_m))
    return Experiment(name, "lengths", commands, duration_s)


def experiment_set(params: Params, *, quick: bool = False) -> list[Experiment]:
    """The dynamic experiments for the robot of ``params`` (any tendon count); ``quick``: the
    first tendon of the steps, one pull-release cycle and a 2 s chirp. The curvatures are the
    thesis's 60 mm robot's, scaled to bend this one by the same angles (as the validation grid,
    :func:`twin.pcc.validation_grid`)."""
    bend = THESIS_LENGTH_M / params.backbone.length_m
    n = params.tendons.count
    angles = list(params.tendons.angles_deg)
    tendons = range(1 if quick else n)
    pre = params.tendons.pretension_n
    step_n = TENSION_STEP_FRACTION * (params.rig.tension_limit_n - pre)
    rest = np.full(n, pre)
    tension_targets = [rest + step_n * (np.arange(n) == i) for i in tendons]
    length_targets = [tendon_length_changes_m(bend * STEP_KAPPA_PER_M, angles[i], params) for i in tendons]
    cycles = 1 if quick else 2
    period_s = 2.0
    cycle_t = np.arange(0.0, cycles * period_s + 1e-9, CYCLE_COMMAND_S)
    phase = np.mod(cycle_t, period_s) / period_s
    cycle_k = bend * CYCLE_KAPPA_PER_M * (1.0 - np.abs(2.0 * phase - 1.0))
    chirp_s = 2.0 if quick else 4.0
    chirp_t = np.arange(0.0, chirp_s + 1e-9, 0.025)
    f0, f1 = CHIRP_HZ
    chirp_k = bend * CHIRP_KAPPA_PER_M * np.sin(2 * math.pi * (f0 * chirp_t + 0.5 * (f1 - f0) / chirp_s * chirp_t ** 2))
    # The tension steps last: their loop carries load-cell noise into the motion, and what it
    # leaves (a spool stuck by friction where the noise left it) would carry into the others.
    return [
        _steps("length_steps", "lengths", np.zeros(n), length_targets),
        _kappa_schedule("pull_release", params, cycle_t, cycle_k, angles[0], cycles * period_s + STEP_HOLD_S),
        _kappa_schedule("chirp", params, chirp_t, chirp_k, angles[0], chirp_s + STEP_HOLD_S),
        _steps("tension_steps", "tensions", rest, tension_targets),
    ]


def run_experiment(device, experiment: Experiment, params: Params) -> Series:
    """Run ``experiment`` on a connected, calibrated ``device`` (with a fixture and a tracker) and
    return what it recorded; the device is left disabled.

    The endoscope is pretensioned straight in the holder with the lengths tared there
    (:func:`twin.experiments.protocols.pretension`), released and left :data:`RELEASE_REST_S`;
    then each command goes out at the first telemetry sample at or after its time.

    Raises:
        ProtocolError: no tracker, or the board faulted (a tension limit tripped) or refused a setpoint.
    """
    if device.tracker is None:
        raise ProtocolError("this device has no tracker (serial:// needs ?igtl=host:port)")
    device.disable()
    pretension(device, params, mode=experiment.mode, settle_s=0.3, tare_lengths=True)
    device.fixture.release_holder()
    device.wait(RELEASE_REST_S)
    device.drain()
    start = device.time_s
    sent, rows, tips, quats = [], [], [], []
    pending = list(experiment.commands)
    send = device.set_tensions if experiment.mode == "tensions" else device.set_lengths
    while True:
        now = device.time_s - start
        while pending and pending[0].time_s <= now + 1e-9:
            try:
                send(pending.pop(0).values)
            except CommandRejected as exc:
                device.disable()
                raise ProtocolError(f"experiment {experiment.name}: at {now:.3f} s the board refused a setpoint "
                                    f"(state {device.latest().state.name}, fault {device.latest().fault_flags!r}): {exc}") from None
            sent.append(device.time_s - start)
        if now >= experiment.duration_s - 1e-9:
            break
        sample = device.wait_next(timeout_s=1.0)
        if sample.fault_flags:
            device.disable()
            raise ProtocolError(f"experiment {experiment.name}: the board reports fault {sample.fault_flags!r} at "
                                f"{sample.time_s - start:.3f} s; clear the cause and re-enable")
        fused = device.tracker.read()
        rows.append((sample.time_s - start, sample.tendon_lengths_m, sample.tensions_n))
        if fused.ok:
            tips.append(fused.pose.position_m)
            quats.append(fused.pose.quaternion)
        else:
            tips.append(np.full(3, np.nan))
            quats.append(np.full(4, np.nan))
    device.disable()
    n = params.tendons.count
    return Series(experiment, np.array(sent), np.array([r[0] for r in rows]),
                  np.array([r[1][:n] for r in rows]).reshape(-1, n), np.array([r[2][:n] for r in rows]).reshape(-1, n),
                  np.array(tips).reshape(-1, 3), np.array(quats).reshape(-1, 4))
