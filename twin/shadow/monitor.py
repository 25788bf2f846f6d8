"""Frame-by-frame comparison of a device with its twin: thresholds learned from the noise, divergence
found and named.

Each telemetry frame gives a residual ``r = device − twin`` per channel: tendon lengths (m), load-cell
tensions (N), motor duty (1) and tracked tip position (m). During a warm-up the monitor learns, per
channel, the residual's bias and noise as the two run side by side on the same commands: the load
cells' and tracker's noise, the twin's own sensor noise and what the calibrated twin still gets
wrong at this motion. Afterwards a channel diverges when the running median of its bias-free
residual stays out of the band the warm-up saw for :data:`MIN_PERSIST_FRAMES` frames (longer for
the length loop's own encoders and duties where their warm-up excursions lasted longer). The band
is :data:`ALARM_SIGMAS` robust spreads, or 1.5 times the warm-up's largest excursion, or the level
the warm-up's excursions reach once extrapolated to a run of :data:`WATCH_S` (peaks over a
threshold), whichever is widest. A tendon slack on either side, or below the tension at which the
board takes it as taut, has its encoder and duty left out (the loop parts from the twin's as the
slack is taken up), and its encoder is then compared from the gap that left, which tendon
friction may hold (:meth:`Monitor._from_take_up_gap`); an excursion that starts where the two sides disagree on a tendon's slack (a
take-up a tick apart) is held for as long as the warm-up's take-ups lasted
(:data:`TAKE_UP_FRAMES`). The frames after the first crossing
(:data:`NAMING_FRAMES`) are then named by what could cause them (:meth:`Monitor._name`), the twin
re-calibrated where the cause has a parameter, and the bias learned again over :data:`RESYNC_S`
before the monitor watches on, its bands widened by what the re-calibration left uncertain
(:meth:`Monitor.recalibrated`). An offset named on a held tension, which a gain would step
alike, is re-named the gain once the tension moves and a gain fits better
(:meth:`Monitor._refine`). A load cell's re-calibration that fits the frames after it no
better than the twin without it is taken back (:meth:`Monitor.take_retracted`), as is a tip load's
or a slip's.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Callable

import numpy as np

from twin.params import Params

__all__ = ["ALARM_SIGMAS", "FALSE_ALARM_RATE", "KINDS", "Divergence", "FrameValues", "Monitor", "NoiseModel"]

# The divergences the monitor names, and what each is.
KINDS = {
    "tip_load": "a force at the tip (a load or a contact)",
    "tendon_slip": "a tendon slipped on its spool (or went slack)",
    "loadcell_offset": "a load cell's offset drifted",
    "loadcell_gain": "a load cell's gain drifted",
    "friction": "the tendons' friction changed",
    "tracker_dropout": "the EM tracker sends no frames",
    "tracker_jump": "the tracked tip jumped with no change in the tendons",
    "latency": "the motors answer later than the twin's",
    "fault": "the board's state or faults differ from the twin's",
    "unexplained": "a divergence no cause of the library fits",
}
# Frames of the running median each channel is watched through (175 ms at 40 Hz): a change that
# lasts more than half of it moves the median, a transient of the motion (a step's overshoot on one
# side only) does not.
MEDIAN_FRAMES = 7
# Alarm band: this many robust spreads of the running median seen in the warm-up ...
ALARM_SIGMAS = 7.0
# ... and never less than the level the warm-up's excursions reach, extrapolated (peaks over a
# threshold, exponential tail) to at most :data:`FALSE_ALARM_RATE` over :data:`WATCH_S`: a motion's
# transients (a slack tendon snapping taut) part device and twin for a few frames at a time, by
# how the noise times them, and a warm-up sees a few of those, not their largest.
WATCH_S = 3600.0
FALSE_ALARM_RATE = 0.05
# ... and never less than this multiple of the largest running median the warm-up saw.
PEAK_MARGIN = 1.5
# Excursions start above this many robust spreads of the running median (the tail's threshold).
TAIL_SIGMAS = 3.0
# Fewest warm-up excursions a tail's scale is fitted from; fewer take the largest excursion's
# excess over the threshold as the scale.
TAIL_MIN_EXCURSIONS = 3
# Frames out of band in a row that start a divergence: one frame's crossing is the tail of the noise.
MIN_PERSIST_FRAMES = 2
# A tendon whose tension on the twin or the device is below this many load-cell noise levels is slack: where
# it goes slack or takes its slack up, the rig's length loop and the twin's part for a few frames
# by when in a tick the load came or went (the noise times it), so its encoder and duty are not
# compared while slack and for a running median's window after.
SLACK_NOISE = 5.0
# ... nor while it reads below this fraction of the tension cap on either side, and a window after:
# the board's guard lets a spool wind in faster only once its tendon reads taut above it (the
# firmware's kTautFraction, firmware/core/config.h), so that where each side's length loop speeds
# up turns on its load cell's noise (on helical a tendon wound in from slack parted the two
# encoders by up to 30 µm, twice what a minute's warm-up saw, until it read taut).
GUARD_TAUT_FRACTION = 0.1
# A tendon taken up (or gone slack) a tick apart on the two sides parts them, all channels, for
# as long as the spools then run speed-limited on their two paths (on helical a reversal a tick
# apart held every cell 0.1-0.3 N off for eight frames; on endoscope-soft-g a tendon that
# snapped taut on the device only held its cell 0.4-0.9 N off as long). The size is the noise's
# draw of the tick; the length is the loop's, which the warm-up's take-ups show: a channel's
# excursion (beyond :data:`TAIL_SIGMAS` spreads) that starts within this many frames of the two
# sides disagreeing on a tendon's slack or taut starts a divergence only once it outlasts the
# longest such excursion of the warm-up (:attr:`NoiseModel.take_up_persist`), out of band then;
# a lasting change is raised that much later, not missed. Two running medians' windows: an
# encoder or duty is left out for one after its tendon was loose, and a median moves within one
# of the change that moves it (on two-segment an encoder taken up 50 µm apart, compared again,
# crossed its band eleven frames after the two sides agreed on its tendon).
TAKE_UP_FRAMES = 2 * MEDIAN_FRAMES
# Frames averaged after the first crossing to name the divergence (75 ms at 40 Hz).
NAMING_FRAMES = 3
# Frames kept for the fits that name a divergence (400 ms at 40 Hz): the change, which the
# running median sees about half a window late, lies within them.
HISTORY_FRAMES = 16
# Frames a load cell's change that a gain fits better than an offset, not yet significantly, may
# wait for its tension to move enough to tell them (1 s at 40 Hz: the standard motion's steps and
# ramps come within it); undecided by then, it is named an offset, the commoner fault.
LOADCELL_WAIT_FRAMES = 40
# The χ² by which an offset's candidate gain must depart from a step over the frames since the
# change before the two are told apart, once: the two fits' χ² margin is then about −t for an
# offset and +t for a gain, with a spread of 2√t; at t = 16 a gain is named where the margin
# passes :data:`GAIN_CHI2`, which an offset's reaches 2.5 spreads out and a gain's 1.5 spreads in
# (the margin is looked at once, not at every frame, where its random walk would cross any level).
REFINE_SEPARATION = 16.0
# Frames the friction and latency fits take, the last of the history.
FIT_FRAMES = 8
# Time over which the bias is learned again after a divergence (s), alarms held meanwhile.
RESYNC_S = 1.0
# A twin given a change found (a tip force, a load cell's gain) is off by one draw of that
# estimate's error from then on, in the pattern the change made and varying with the pose: each
# channel group's band widens (in quadrature) by this many of the estimate's standard deviations,
# carried through the residual the change made at its naming (three: one draw held for the rest of
# the run stays inside 99.7 % of the time).
UNCERTAINTY_SIGMAS = 3.0
# A re-calibration is on trial for the resync and this many frames more (1 s at 40 Hz, the
# load-cell wait's length: the standard motion moves the tension within it): the twin with and
# without the change against the device, from the bias before it; a change that does not fit better
# by :data:`GAIN_CHI2` is taken back.
TRIAL_FRAMES = 40
# A load cell alone explains a tensions' change it leaves less than this fraction of unexplained
# (in units of the bands).
SINGLE_MISFIT = 0.35
# How much better (χ², the residuals in units of the cell's noise) a gain must fit a load cell's
# change than an offset to be named: two standard deviations.
GAIN_CHI2 = 4.0
# The tip's move is the tensions' doing when the rod model leaves less than this fraction of it.
EXPLAINED_FRACTION = 0.5
# How much better (χ², the tip's move in its spread at the motion's transients: its band over
# ALARM_SIGMAS) a force at the tip must explain the tip's move than a load cell's change or the
# tensions' own to be named a tip load with the tip still in its band: four standard deviations
# (where a cell's change left the tip still, its three axes' noise passes 14 in 0.3 % of draws).
TIP_LOAD_CHI2 = 16.0
# A friction change or a latency is named only where its model explains this fraction of the
# residuals of the last frames at least.
MIN_FIT = 0.3
# A force direction resolved worse than this is left out of a tip load's estimate (N).
MAX_FORCE_STD_N = 0.05
# A tracker whose frames stop for this many device-telemetry periods has dropped out.
DROPOUT_PERIODS = 4


@dataclasses.dataclass(frozen=True)
class FrameValues:
    """What one side reports at one telemetry frame.

    Attributes:
        time_s: device time of the frame (s).
        lengths_m: (n,) tendon lengths from the encoders (m).
        tensions_n: (n,) load-cell tensions (N).
        duty: (n,) motor duty (1).
        tip_m: (3,) tip position (m, world frame), NaN when not tracked.
        state: the board's state code; faults: its fault flags.
    """

    time_s: float
    lengths_m: np.ndarray
    tensions_n: np.ndarray
    duty: np.ndarray
    tip_m: np.ndarray
    state: int = 0
    faults: int = 0

    def vector(self) -> np.ndarray:
        return np.concatenate([self.lengths_m, self.tensions_n, self.duty, self.tip_m])


@dataclasses.dataclass(frozen=True)
class Divergence:
    """A named divergence.

    Attributes:
        t_s: device time it was raised (s).
        onset_s: device time of the first frame out of band (s).
        kind: one of :data:`KINDS`.
        key: the effect key or quantity it changes (e.g. ``effects.tension_offset_error_n[1]``).
        size: its estimated size, in ``unit``; ``std`` the size's standard deviation.
        where: the channels out of band, e.g. ``["tension[1]", "tip"]``.
        detail: further numbers (a force vector, a channel index).
    """

    t_s: float
    onset_s: float
    kind: str
    key: str
    size: float
    std: float
    unit: str
    where: tuple[str, ...]
    detail: dict = dataclasses.field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"t_s": round(self.t_s, 4), "onset_s": round(self.onset_s, 4), "kind": self.kind, "key": self.key,
                "size": _round(self.size), "std": _round(self.std), "unit": self.unit, "where": list(self.where),
                **{k: _round(v) for k, v in self.detail.items()}}

    def line(self) -> str:
        return (f"{self.t_s:8.3f} s  {self.kind:16s} {self.key} = {self.size:.4g} ± {self.std:.2g} {self.unit}"
                f"  ({', '.join(self.where)})")


def _round(value):
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_round(v) for v in np.asarray(value).tolist()]
    if isinstance(value, float):
        return float(f"{value:.6g}") if math.isfinite(value) else None
    return value


@dataclasses.dataclass
class NoiseModel:
    """Per-channel residual bias and spreads, learned in the warm-up.

    Attributes:
        bias: (C,) mean residual (device − twin).
        sigma: (C,) spread of one frame's watched residual about the bias.
        band: (C,) half-width of the alarm band of the running median.
        mix: (C, C) the map from a residual to what is watched: each load cell's residual less
            what the other cells' residuals predict of it (learned in the warm-up), the other
            channels as they are.
        stiffness_n_per_m: (n,) how much each tendon's tension falls per metre it is paid out on
            the twin in this motion (the backbone's compliance included): what sizes a slip.
        persist: (C,) frames in a row a channel's running median must stay out of band to start a
            divergence: :data:`MIN_PERSIST_FRAMES`, and for the length loop's own channels (the
            encoders and duties, which the loop drives back to the setpoints) one frame longer
            than their excursions beyond half the band lasted in the warm-up.
        ring_band_n: the tensions' frame-to-frame change (N, the norm over the cells, a median
            over :data:`FIT_FRAMES`) beyond which they ring: :data:`PEAK_MARGIN` times the
            largest the warm-up saw.
        excursion: (C,) the level beyond which a channel's running median makes an excursion:
            :data:`TAIL_SIGMAS` of its robust spreads in the warm-up.
        take_up_persist: (C,) frames a channel's excursion that starts at a take-up
            (:data:`TAKE_UP_FRAMES`) must outlast, out of band at its end, to start a
            divergence: the longest such excursion of the channel's group (the tendons'
            lengths, tensions, duties, the tip) in the warm-up, 0 where it had none.
    """

    bias: np.ndarray
    sigma: np.ndarray
    band: np.ndarray
    mix: np.ndarray
    stiffness_n_per_m: np.ndarray
    persist: np.ndarray
    ring_band_n: float = math.inf
    excursion: np.ndarray | None = None
    take_up_persist: np.ndarray | None = None


@dataclasses.dataclass
class _Trial:
    """A re-calibration on trial (:meth:`Monitor._judge`).

    Attributes:
        event: the divergence whose change the twin was given.
        uncertainty, bias: the bands' uncertainty and the residual's bias before it.
        channels: the watched channels the change shows in.
        pattern: what the change takes off those channels' watched residual, constant (a tip load,
            a slip: what the device's moved by at the naming); None for a load cell's, which
            follows the twin's tension.
        rows: (watched residual on the channels from the old bias, what the change took off it)
            per frame since.
    """

    event: Divergence
    uncertainty: np.ndarray
    bias: np.ndarray
    channels: np.ndarray
    pattern: np.ndarray | None
    rows: list = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class _Candidate:
    """A load cell's change named an offset that a gain might still explain better once its
    tension moves (:meth:`Monitor._refine`).

    Attributes:
        event: the offset's divergence.
        bias: the residual's bias before it (the watched residual of the cell is taken from it).
        given: the size the twin was given of the offset (0 until it is re-calibrated).
        rows: (the cell's watched residual from that bias without what the twin was given, the
            twin's tension without it) per frame since the change.
        frames: frames watched since the naming.
    """

    event: Divergence
    bias: np.ndarray
    given: float = 0.0
    rows: list = dataclasses.field(default_factory=list)
    frames: int = 0


class Monitor:
    """Compares device and twin frames, learns the noise, raises named divergences.

    Args:
        params: the robot's parameter set: the floors of the noise (load-cell and tracker noise,
            the encoder's count).
        warmup_s: device time of side-by-side running the noise is learned from (s); it should
            hold the motion the shadow watches.
        telemetry_period_s: the device's telemetry period (s).
        jacobian: a callable giving, for the twin's tensions (n,) N, the tip position's
            derivatives ``(d tip / d tension (3, n) m/N, d tip / d tip force (3, 3) m/N)``; None
            names without the rod model (a tip load then has no force estimate).
    """

    def __init__(self, params: Params, *, warmup_s: float = 10.0, telemetry_period_s: float = 0.025,
                 jacobian: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None,
                 noise: NoiseModel | None = None):
        n = params.tendons.count
        self.n = n
        self.warmup_s = float(warmup_s)
        self.period_s = float(telemetry_period_s)
        self._jacobian = jacobian
        # Floors of a frame's residual spread: what the sensors alone make it (both sides are noisy
        # where the twin simulates the sensor); the encoders' two counts, as each side's length loop
        # holds to within a count (the hold bench's goal).
        count_m = params.rig.tendon_m_per_count
        floor = np.concatenate([np.full(n, 2 * count_m), np.full(n, math.sqrt(2) * params.sensors.loadcell_noise_n),
                                np.full(n, 1e-3), np.full(3, params.sensors.tracker_noise_m)])
        self._floor = floor
        self._slack_n = SLACK_NOISE * params.sensors.loadcell_noise_n
        self._loose_n = max(self._slack_n, GUARD_TAUT_FRACTION * params.rig.tension_limit_n)
        self._since_slack = np.full(n, MEDIAN_FRAMES)
        # (n,) each encoder's residual where it was compared again after its tendon was loose (m).
        self._take_up_gap = np.zeros(n)
        # Frames since the two sides last disagreed on whether a tendon is slack or taut; each
        # channel's excursion so far (frames) and whether it started at a take-up.
        self._since_take_up = TAKE_UP_FRAMES + 1
        self._take_up_levels = np.array([self._slack_n, self._loose_n])
        self._take_up_began = False
        self._warm_take_up: list[int] = []
        self._excursion = np.zeros(3 * n + 3, dtype=int)
        self._excursion_take_up = np.zeros(3 * n + 3, dtype=bool)
        self.names = ([f"length[{i}]" for i in range(n)] + [f"tension[{i}]" for i in range(n)]
                      + [f"duty[{i}]" for i in range(n)] + ["tip.x", "tip.y", "tip.z"])
        self.noise: NoiseModel | None = None if noise is None else dataclasses.replace(noise, bias=noise.bias.copy())
        # The bands in use: the learned ones widened by what the twin's re-calibrations left uncertain.
        self._uncertainty = np.zeros(3 * n + 3)
        self._band = np.full(3 * n + 3, math.inf) if noise is None else noise.band.copy()
        self._named_watched = np.zeros(3 * n + 3)
        self._named_signed = np.zeros(3 * n + 3)
        self._start_s: float | None = None
        self._warm: list[np.ndarray] = []
        self._warm_twin: list[np.ndarray] = []
        self._window: list[np.ndarray] = []
        self._raw_window: list[np.ndarray] = []
        self._statistic = np.zeros(3 * n + 3)
        self._onset: tuple[float, list] | None = None  # (time, frames since)
        self._resync_until_s = -math.inf
        self._resync: list[np.ndarray] = []
        self._tip_time_s: float | None = None
        self._tip_seen_s = 0.0
        self._dropout = False
        self._fault_raised = False
        self._fault_frames = 0
        self._out_frames = np.zeros(3 * n + 3, dtype=int)
        self._history: list[tuple[FrameValues, FrameValues]] = []
        # (watched residual, the twin's tensions) of the last frames compared.
        self._watched: list[tuple[np.ndarray, np.ndarray]] = []
        # (channel, channels out of band) of a load cell's change waiting to be told gain or offset.
        self._pending: tuple[int, tuple[str, ...]] | None = None
        self._trial: _Trial | None = None
        self._candidate: _Candidate | None = None
        self._offset_rows: list[tuple[float, float]] = []
        self._offset_told = math.inf
        self._retracted: list[Divergence] = []
        self.frames = 0
        self.events: list[Divergence] = []

    def _model(self) -> NoiseModel:
        if self.noise is None:
            raise RuntimeError("the noise is not learned yet (the warm-up is not over)")
        return self.noise

    @property
    def ready(self) -> bool:
        """True once the warm-up is over and the noise learned."""
        return self.noise is not None

    def update(self, device: FrameValues, twin: FrameValues, *, tip_frame_time_s: float | None = None,
               settling: bool = False) -> list[Divergence]:
        """One frame of each side; returns the divergences raised at it.

        Args:
            device, twin: the two frames (same device time).
            tip_frame_time_s: the timestamp of the device's newest tracker frame (any clock), or
                None without a tracker: frames that stop coming are a dropout.
            settling: the frame follows a change of state both sides were given (enable, tare, a
                fixture action) by less than a frame or two: the two may differ by when in the
                frame it took effect, so it is not compared.
        """
        self.frames += 1
        raised: list[Divergence] = []
        if settling:
            return raised
        residual = device.vector() - twin.vector()
        # Slack on either side: a tendon one side has taken up and the other not yet parts the two
        # loops the same way.
        slack = np.minimum(twin.tensions_n, device.tensions_n) < self._loose_n
        self._since_slack = np.where(slack, 0, self._since_slack + 1)
        loose = np.flatnonzero(self._since_slack < MEDIAN_FRAMES)
        self._take_up(device.tensions_n, twin.tensions_n)
        residual[loose] = np.nan
        residual[2 * self.n + loose] = np.nan
        self._from_take_up_gap(residual)
        if self._start_s is None:
            self._start_s = device.time_s
        self._history.append((device, twin))
        if len(self._history) > HISTORY_FRAMES:
            del self._history[0]
        dropout = self._watch_tracker(device.time_s, tip_frame_time_s)
        if dropout is not None:
            raised.append(dropout)
        differ = device.state != twin.state or device.faults != twin.faults
        self._fault_frames = self._fault_frames + 1 if differ else 0
        if self._fault_frames >= NAMING_FRAMES and not self._fault_raised:
            self._fault_raised = True
            raised.append(Divergence(device.time_s, device.time_s, "fault", "board.state", float(device.faults), 0.0,
                                     "flags", ("state",), {"device_state": device.state, "twin_state": twin.state,
                                                            "device_faults": device.faults,
                                                            "twin_faults": twin.faults}))
        elif not differ:
            self._fault_raised = False
        if self.noise is None:
            self._warm.append(residual)
            self._warm_take_up.append(self._since_take_up)
            self._warm_twin.append(twin.vector())
            if device.time_s - self._start_s >= self.warmup_s:
                self._learn()
            self.events.extend(raised)
            return raised
        noise = self.noise
        if self._trial is not None:
            self._try(residual, twin.tensions_n, device.time_s)
        if self._candidate is not None:
            refined = self._refine(residual, twin.tensions_n, device.time_s)
            if refined is not None:
                raised.append(refined)
        if device.time_s < self._resync_until_s:
            self._resync.append(residual)
            self.events.extend(raised)
            return raised
        if self._resync:
            self._rebias()
        valid = np.isfinite(residual)
        deviation = np.where(valid, residual - noise.bias, 0.0)
        if self._dropout or not np.isfinite(device.tip_m).all():
            deviation[-3:] = 0.0
        self._raw_window.append(deviation)
        self._window.append(noise.mix @ deviation)
        self._watched.append((self._window[-1], twin.tensions_n))
        if len(self._watched) > HISTORY_FRAMES + LOADCELL_WAIT_FRAMES:
            del self._watched[0]
        if len(self._window) > MEDIAN_FRAMES:
            del self._window[0]
            del self._raw_window[0]
        if len(self._window) < MEDIAN_FRAMES:
            self.events.extend(raised)
            return raised
        self._statistic = np.median(np.array(self._window), axis=0)
        out = np.abs(self._statistic) > self._band
        # A channel out of band for longer than the warm-up's excursions lasted starts a divergence;
        # one whose excursion began at a take-up, once it outlasts the warm-up's take-ups too.
        self._out_frames = np.where(out, self._out_frames + 1, 0)
        due = self._out_frames >= noise.persist
        if noise.excursion is not None and noise.take_up_persist is not None:
            above = np.abs(self._statistic) > noise.excursion
            # A take-up that begins during an excursion starts its count afresh: the sides part
            # anew from there (a disagreement that goes on, as a change of the device's own may
            # make, does not).
            renewed = above & (self._since_take_up == 0) & self._take_up_began
            starting = above & (self._excursion == 0)
            self._excursion_take_up = above & np.where(starting, self._since_take_up <= TAKE_UP_FRAMES,
                                                       self._excursion_take_up | renewed)
            self._excursion = np.where(above, np.where(renewed, 0, self._excursion) + 1, 0)
            due &= ~self._excursion_take_up | (self._excursion > noise.take_up_persist)
        if self._onset is None and due.any():
            self._onset = (device.time_s, [])
        if self._onset is not None:
            onset_s, frames = self._onset
            frames.append((deviation, twin, device))
            if self._pending is not None:
                event = self._loadcell(device.time_s, onset_s, frames, *self._pending)
                if event is not None:
                    raised.append(event)
                    self._watch_candidate(event)
                    self._start_resync(device.time_s)
            elif len(frames) >= NAMING_FRAMES:
                self._onset = None
                # A crossing gone by the naming frames was the noise's tail, not a divergence.
                if out.any():
                    event = self._name(device.time_s, onset_s, frames)
                    if event is None:
                        self._onset = (onset_s, frames)
                    else:
                        raised.append(event)
                        self._watch_candidate(event)
                        self._start_resync(device.time_s)
        self.events.extend(raised)
        return raised

    # ------------------------------------------------------------------ learning
    def _learn(self) -> None:
        warm = np.array(self._warm)
        self._warm = []
        bias = _nanmedian(warm)
        n = self.n
        # The twin and the device part ways a little through the sensors' noise alone (the same
        # commands, another noise), mostly as all tendons' tensions shifting together; each cell is
        # watched for what the others do not explain.
        mix = np.eye(len(bias))
        tensions = np.nan_to_num(warm[:, n:2 * n] - bias[n:2 * n])
        if n > 1:
            for i in range(n):
                others = [j for j in range(n) if j != i]
                coeffs, *_ = np.linalg.lstsq(tensions[:, others], tensions[:, i], rcond=None)
                mix[n + i, [n + j for j in others]] = -coeffs
        centred = (np.nan_to_num(warm - bias) @ mix.T)
        centred[~np.isfinite(warm)] = np.nan
        # The spread from the median absolute deviation: a glitch in the warm-up does not widen it.
        sigma = np.fmax(1.4826 * _nanmedian(np.abs(centred)), self._floor)
        rows = np.nan_to_num(centred)
        # All windows at once: on a wall-clock device this runs between two of the board's
        # watchdog feeds.
        medians = np.median(np.lib.stride_tricks.sliding_window_view(rows, MEDIAN_FRAMES, axis=0), axis=-1)
        medians_abs = np.abs(medians)
        # Robust spread of the running median (its correlation in time included), and its peak: a
        # motion whose residual is not Gaussian widens the band by what the warm-up saw of it.
        median_sigma = 1.4826 * np.median(medians_abs, axis=0)
        # A median of k Gaussian frames spreads about 1.25/sqrt(k) of one frame.
        steady = sigma * 1.25 / math.sqrt(MEDIAN_FRAMES)
        spread = np.maximum(median_sigma, steady)
        warm_s = max(float(len(rows)) * self.period_s, self.period_s)
        groups = [slice(0, n), slice(n, 2 * n), slice(2 * n, 3 * n), slice(3 * n, 3 * n + 3)]
        band = np.maximum.reduce([ALARM_SIGMAS * spread, PEAK_MARGIN * medians_abs.max(axis=0),
                                  _tail_band(medians_abs, spread, warm_s, groups)])
        twin_rows = np.array(self._warm_twin)
        self._warm_twin = []
        persist = np.full(len(band), MIN_PERSIST_FRAMES, dtype=int)
        for group in groups[:3:2]:
            persist[group] = max(MIN_PERSIST_FRAMES, _longest_excursion(medians_abs[:, group], band[group] / 2) + 1)
        ring_band = PEAK_MARGIN * _ringing(np.nan_to_num(warm[:, n:2 * n] - bias[n:2 * n])).max(initial=0.0)
        # The running median of rows j..j+k-1 is seen at frame j+k-1.
        since_take_up = np.array(self._warm_take_up[MEDIAN_FRAMES - 1:])
        self._warm_take_up = []
        excursion = TAIL_SIGMAS * spread
        take_up_persist = np.zeros(len(band), dtype=int)
        for group in groups:
            take_up_persist[group] = _take_up_excursion(medians_abs[:, group], excursion[group], since_take_up)
        self.noise = NoiseModel(np.nan_to_num(bias), sigma, band, mix, _loop_stiffness(twin_rows, n), persist,
                                ring_band, excursion, take_up_persist)
        self._widen(self._uncertainty)
        self._window = []
        self._raw_window = []

    def _take_up(self, device_tensions_n: np.ndarray, twin_tensions_n: np.ndarray) -> None:
        """Count the frames since the two sides last disagreed on whether a tendon has taken up
        its slack (:data:`SLACK_NOISE`) or reads taut to the board (its spool then speeds up):
        one side below the level, the other above it and off by more than the slack level, which
        two sides sitting at the level on their noise are not (:data:`TAKE_UP_FRAMES`)."""
        low, high = np.minimum(device_tensions_n, twin_tensions_n), np.maximum(device_tensions_n, twin_tensions_n)
        levels = self._take_up_levels
        disagree = ((low[:, None] < levels) & (high[:, None] >= levels)).any(axis=1) & (high - low > self._slack_n)
        self._take_up_began = bool(disagree.any()) and self._since_take_up > 0
        self._since_take_up = 0 if disagree.any() else self._since_take_up + 1

    def _from_take_up_gap(self, residual: np.ndarray) -> None:
        """Take each tendon's encoder residual (in place) from the gap its last loose spell left:
        an encoder anywhere between the twin's and that gap (set at the first frame it is
        compared again) is in step, and only what goes beyond it is compared. A take-up a control
        tick apart on the two sides (where a tension crosses the taut level between two frames,
        which no frame shows) parts the two encoders while they are left out; tendon friction may
        then hold the gap for as long as the tendon stays taut (stiff-long at μ = 0.1: 7-9 counts
        from the step's take-up to the next slack, 0.5 s, against a band of 6.6 counts from a
        warm-up whose take-ups fell on the same ticks) or the loop close it at its own pace. The
        gap only shrinks (to where the encoder has come back to), so a gap that opens or grows
        while the tendon is taut is still seen. The warm-up learns the encoders' bands from what
        they did, gaps and all: on the endoscope at μ = 0.1 they part by 15 counts in a step
        whether or not the tendon was loose before, which a warm-up with its gaps taken off saw
        nowhere (a band of 6.6 counts against 23, an alarm at that step every cycle)."""
        if self.noise is None:
            return
        n = self.n
        lengths = residual[:n] - self.noise.bias[:n]
        finite = np.isfinite(lengths)
        resumed = (self._since_slack == MEDIAN_FRAMES) & finite
        self._take_up_gap[resumed] = lengths[resumed]
        gap = self._take_up_gap
        held = np.clip(np.where(finite, lengths, 0.0), np.minimum(gap, 0.0), np.maximum(gap, 0.0))
        self._take_up_gap = np.where(finite, held, gap)
        residual[:n] -= held

    def recalibrated(self, event: Divergence) -> None:
        """The twin was given ``event``'s change (its size): what remains between the two is a draw
        of the estimate's error, ``std`` in the pattern the change made at its naming. Each channel
        group the change took out of band widens by :data:`UNCERTAINTY_SIGMAS` of that (its largest
        channel in the frames before the naming, as the pattern moves between the tendons with the
        pose)."""
        if self.noise is None or not (math.isfinite(event.size) and math.isfinite(event.std) and event.size != 0):
            return
        n = self.n
        if self._trial is not None:
            self._judge(self._trial, math.nan)
        if self._candidate is not None and self._candidate.event is event:
            self._candidate.given = event.size
        if event.kind in ("loadcell_offset", "loadcell_gain"):
            self._trial = _Trial(event, self._uncertainty.copy(), self.noise.bias.copy(),
                                 np.array([n + int(event.detail["channel"])]), None)
        else:
            # A tip load or a slip moves the twin's tensions and tip by about what the device's moved
            # at the naming (the change was fitted to it); the length loop drives its encoders back.
            channels = np.concatenate([np.arange(n, 2 * n), np.arange(3 * n, 3 * n + 3)])
            channels = channels[np.abs(self._named_signed[channels]) > self._band[channels]]
            if len(channels):
                self._trial = _Trial(event, self._uncertainty.copy(), self.noise.bias.copy(), channels,
                                     self._named_signed[channels].copy())
        fraction = UNCERTAINTY_SIGMAS * abs(event.std / event.size)
        # The change's pattern: the channels it took out of their band (the others saw the noise).
        pattern = np.where(self._named_watched > self._band, self._named_watched, 0.0)
        uncertainty = self._uncertainty.copy()
        for group in (slice(0, n), slice(n, 2 * n), slice(2 * n, 3 * n), slice(3 * n, 3 * n + 3)):
            extra = fraction * float(np.max(pattern[group], initial=0.0))
            uncertainty[group] = np.hypot(uncertainty[group], extra)
        self._widen(uncertainty)

    def _widen(self, uncertainty: np.ndarray) -> None:
        """The bands in use: the learned ones widened, in quadrature, by ``uncertainty`` (C,), what the
        twin's re-calibrations left uncertain in each channel."""
        self._uncertainty = uncertainty
        self._band = np.hypot(self._model().band, uncertainty)

    def take_retracted(self) -> list[Divergence]:
        """The re-calibrations taken back since the last call (their events' ``detail`` says
        ``retracted``): the twin is to be given back what it had before each."""
        retracted, self._retracted = self._retracted, []
        return retracted

    def _try(self, residual: np.ndarray, twin_tensions_n: np.ndarray, now_s: float) -> None:
        """One frame of a re-calibration on trial: the watched residual of its channels from the
        bias before the change (the resync learns one with it), and what the change took off it."""
        trial = self._trial
        assert trial is not None
        event = trial.event
        watched = (self._model().mix[trial.channels] @ np.nan_to_num(residual - trial.bias))
        if trial.pattern is not None:
            change = trial.pattern
        else:
            # A load cell's change on the twin's reading: an offset shifts it, a gain scales the tension.
            tension = float(twin_tensions_n[int(event.detail["channel"])])
            change = np.array([event.size * (tension if event.kind == "loadcell_gain" else 1.0)])
        trial.rows.append((watched, change))
        if len(trial.rows) >= round(RESYNC_S / self.period_s) + TRIAL_FRAMES:
            self._judge(trial, now_s)

    def _judge(self, trial: "_Trial", now_s: float) -> None:
        """Keep a re-calibration that fits the frames since it better than the twin without it
        did, by :data:`GAIN_CHI2` (χ² in the channels' noise); else take it back: a step of the
        motion named a drift, a load or a slip (a tendon taking up its slack) leaves the twin off
        from then on wherever the pose goes, and sets off a divergence at every cycle."""
        self._trial = None
        if not trial.rows:
            return
        event = trial.event
        sigma = self._model().sigma[trial.channels]
        watched = np.array([r[0] for r in trial.rows]) / sigma
        without = watched + np.array([r[1] for r in trial.rows]) / sigma
        margin = float(np.sum(without ** 2) - np.sum(watched ** 2))
        event.detail["trial_chi2"] = margin
        if margin > GAIN_CHI2:
            return
        event.detail["retracted"] = True
        self._retracted.append(event)
        if self._candidate is not None and self._candidate.event is event:
            self._candidate = None
        self._widen(trial.uncertainty)
        if math.isfinite(now_s):
            self._start_resync(now_s)

    def _watch_candidate(self, event: Divergence) -> None:
        """A load cell's offset just named from frames that could not tell it from a gain (a held
        tension) is watched on as a candidate for a gain (from the frames since its change, which
        :meth:`_loadcell` fitted); any other divergence ends the watch."""
        self._candidate = None
        if event.kind == "loadcell_offset" and self._offset_told < GAIN_CHI2:
            self._candidate = _Candidate(event, self._model().bias.copy(), rows=list(self._offset_rows))
            event.detail["refinable_frames"] = round(RESYNC_S / self.period_s) + TRIAL_FRAMES

    def _refine(self, residual: np.ndarray, twin_tensions_n: np.ndarray, now_s: float) -> Divergence | None:
        """One frame of an offset's watch: a held tension scales to the same step under a gain as
        under an offset, and the offset, the commoner fault, is named at once; once the tension
        has moved enough to tell them (:data:`REFINE_SEPARATION`), a gain that fits the cell's
        residual since the change better by :data:`GAIN_CHI2` (χ² in the cell's noise) and is resolved (twice its
        standard deviation) replaces it: the gain is raised, the offset's re-calibration taken
        back, the bias learned again. The watch lasts as long as the offset's trial (the resync
        and :data:`TRIAL_FRAMES`)."""
        candidate = self._candidate
        assert candidate is not None
        event = candidate.event
        n = self.n
        i = int(event.detail["channel"])
        candidate.frames += 1
        if np.isfinite(residual[n + i]):
            # What the cell reads beyond the twin without the offset it was given.
            watched = float(self._model().mix[n + i] @ np.nan_to_num(residual - candidate.bias)) + candidate.given
            candidate.rows.append((watched, float(twin_tensions_n[i]) - candidate.given))
        if candidate.frames >= event.detail["refinable_frames"]:
            self._candidate = None
            return None
        rows = np.array(candidate.rows)
        if len(rows) < NAMING_FRAMES:
            return None
        d, tau = rows[:, 0], rows[:, 1]
        sigma = float(self._model().sigma[n + i])
        tt = max(float(tau @ tau), 1e-12)
        offset_sse = float(d @ d) - float(d.sum()) ** 2 / len(d)
        gain_sse = float(d @ d) - float(d @ tau) ** 2 / tt
        margin = (offset_sse - gain_sse) / sigma ** 2
        gain, gain_std = float(d @ tau) / tt, sigma / math.sqrt(tt)
        # How far a gain of the step's size at the tension held departs from the step by now.
        expected = float(d.mean()) / max(float(tau.mean()), 1e-12)
        moved = tau - tau.mean()
        if expected ** 2 * float(moved @ moved) / sigma ** 2 < REFINE_SEPARATION:
            return None
        self._candidate = None
        if margin <= GAIN_CHI2 or abs(gain) <= 2 * gain_std:
            return None
        if candidate.given != 0.0:
            if self._trial is not None and self._trial.event is event:
                self._widen(self._trial.uncertainty)
                self._trial = None
            event.detail["retracted"] = True
            self._retracted.append(event)
        event.detail["refined_by"] = "loadcell_gain"
        self._start_resync(now_s)
        return Divergence(now_s, event.onset_s, "loadcell_gain", f"effects.tension_gain_error[{i}]", gain, gain_std,
                          "1", event.where, {"channel": i, "offset_if_offset_n": float(d.mean()),
                                             "chi2_margin": margin, "refines_s": event.t_s})

    def _start_resync(self, now_s: float) -> None:
        self._onset = None
        self._pending = None
        self._resync_until_s = now_s + RESYNC_S
        self._resync = []
        self._watched = []
        self._window = []
        self._raw_window = []

    def _rebias(self) -> None:
        rows = np.array(self._resync)
        self._resync = []
        if len(rows):
            new = _nanmedian(rows)
            model = self._model()
            model.bias = np.where(np.isfinite(new), new, model.bias)

    def _watch_tracker(self, now_s: float, frame_time_s: float | None) -> Divergence | None:
        if frame_time_s is None:
            return None
        if frame_time_s != self._tip_time_s:
            self._tip_time_s, self._tip_seen_s = frame_time_s, now_s
            self._dropout = False
            return None
        age_s = now_s - self._tip_seen_s
        if not self._dropout and self.noise is not None and age_s >= DROPOUT_PERIODS * self.period_s - 1e-9:
            self._dropout = True
            return Divergence(now_s, self._tip_seen_s, "tracker_dropout", "tracker.frames", age_s, self.period_s, "s",
                              ("tip",), {"last_frame_s": self._tip_seen_s})
        return None

    # ------------------------------------------------------------------ naming
    def _name(self, now_s: float, onset_s: float, frames: list) -> Divergence | None:
        """Name the divergence from the pattern of the watched residuals (each channel in units of
        its alarm band): which groups left their band, whether one load cell alone explains the
        tensions' change, and whether the rod model explains the tip's move by the tensions'.
        None: one load cell's change, which waits for its tension to move (:meth:`_loadcell`)."""
        n = self.n
        noise = self._model()
        # The running medians at the naming: the frames since the change outnumber those before.
        watched = np.median(np.array(self._window), axis=0)
        deviation = np.median(np.array(self._raw_window), axis=0)
        level = watched / self._band
        # The change's pattern, channel by channel, at its largest over the frames kept (the length
        # loop drives its encoders back within them).
        self._named_watched = np.abs(np.array([w[0] for w in self._watched[-HISTORY_FRAMES:]])).max(axis=0)
        self._named_signed = watched
        out = [self.names[k] for k in np.flatnonzero(np.abs(level) > 1.0)]
        where = tuple(out) or ("none",)
        d_ten, d_tip = deviation[n:2 * n], deviation[3 * n:]
        l_len, l_ten, l_duty, l_tip = (np.abs(level[:n]), level[n:2 * n], np.abs(level[2 * n:3 * n]),
                                       np.abs(level[3 * n:]))
        tip_sig = bool(l_tip.max() > 1.0)
        ten_sig = bool(np.abs(l_ten).max() > 1.0)
        len_sig = bool(l_len.max() > 1.0 or l_duty.max() > 1.0)
        # One load cell: the watched tensions a change δ of cell i alone makes are column i of the
        # mix (the others' prediction of it is what they see of it).
        mix = noise.mix[n:2 * n, n:2 * n] / self._band[n:2 * n, None]
        target = l_ten
        fits = []
        for i in range(n):
            column = mix[:, i]
            delta = float(column @ target / max(column @ column, 1e-12))
            fits.append((float(np.linalg.norm(target - column * delta)) / max(float(np.linalg.norm(target)), 1e-12), i))
        single_misfit, channel = min(fits)
        twin_tensions = np.mean([f[1].tensions_n for f in frames], axis=0)
        tip_sigma = noise.band[3 * n:]
        debug = {"single_misfit": single_misfit, "level_max": float(np.abs(level).max())}

        if tip_sig and not ten_sig and not len_sig:
            return Divergence(now_s, onset_s, "tracker_jump", "tracker.position_m", float(np.linalg.norm(d_tip)),
                              float(np.linalg.norm(noise.sigma[3 * n:])), "m", where, {"jump_m": d_tip, **debug})
        explained = math.inf
        force: np.ndarray | None = None
        cov = np.zeros((3, 3))
        if ten_sig and self._jacobian is not None:
            # The rod model's tip for the measured tensions: what of the tip's move they do not
            # explain is a load at the tip (in length control the tip barely moves under one, while
            # the tensions that hold it change).
            wrt_tension, wrt_force = self._jacobian(np.maximum(twin_tensions, 0.0))
            unexplained = d_tip - wrt_tension @ d_ten
            explained = (float(np.linalg.norm(unexplained / tip_sigma))
                         / max(float(np.linalg.norm(d_tip / tip_sigma)), 1e-12))
            force, cov = _least_squares(wrt_force, unexplained, tip_sigma)
            debug["unexplained_tip_fraction"] = explained
            margin, tip_force, tip_cov = _tip_load_margin(d_tip, unexplained, wrt_force,
                                                          self._band[3 * n:] / ALARM_SIGMAS)
            debug["tip_chi2_margin"] = margin
            debug["tip_held_fraction"] = _held_fraction(wrt_tension @ d_ten, wrt_force @ tip_force)
        force_std = float(math.sqrt(max(np.trace(cov), 0.0)))
        load = None if force is None else Divergence(now_s, onset_s, "tip_load", "tip_force_n",
                                                      float(np.linalg.norm(force)), force_std, "N", where,
                                                      {"force_n": force, **debug})
        if (load is not None and debug["tip_chi2_margin"] > TIP_LOAD_CHI2
                and debug["tip_held_fraction"] <= EXPLAINED_FRACTION):
            # The tip moved where neither a load cell's change (the tip stays where the twin's is)
            # nor the tensions' own change (a slip, a late loop, friction: the tip goes where the
            # rod model puts it for the measured tensions) leaves it, and a force at the tip does:
            # a tip load, though the tip is still within its band (on a stiff, long robot a 10 g
            # mass moves the tip 7 mm against a band of 7.8 mm set by the motion's transients,
            # while the tensions holding it change by 2 N, which one cell's offset fits too), and
            # the tensions' change is the one that holds the tip back against that force (on long
            # a slip's tip went where no rod model's tensions put it, a millinewton's force
            # fitting it better; its tensions did not hold it back against that force). Its
            # force is the one fitted in the tip's spread there, which the band's width would
            # leave unresolved.
            return Divergence(now_s, onset_s, "tip_load", "tip_force_n", float(np.linalg.norm(tip_force)),
                              float(math.sqrt(max(np.trace(tip_cov), 0.0))), "N", where,
                              {"force_n": tip_force, **debug})
        if ten_sig and not tip_sig and single_misfit < SINGLE_MISFIT:
            # Friction shows most in the cell whose tendon slides under the most tension, much as
            # that cell's gain would; where it fits all the cells better (each reading what its
            # tendon's direction of sliding says), it is friction.
            sliding = self._friction(now_s, onset_s, frames, where)
            margin = self._friction_over_cell(channel)
            if margin > GAIN_CHI2 and _fits(sliding):
                return dataclasses.replace(sliding, detail={**sliding.detail, "chi2_over_cell": margin})
            # A cell's reading does not move the encoders; where they follow the motion late, as a
            # late loop's do, though still within their band, by more than the counts the two loops
            # hold to, the cell that crossed first is the loop's doing (on stiff-long a 5 ms
            # latency's encoders fitted the twin's rate to 0.97, its cell named a −0.19 N offset; a
            # three-tendon 0.2 N offset's encoders fitted a 0.3 ms lag, under a count).
            latency = self._latency(now_s, onset_s, where)
            if _fits(latency) and latency.detail["encoder_lag_m"] > float(self._floor[:n].max()):
                return latency
            self._pending = (channel, where)
            return self._loadcell(now_s, onset_s, frames, channel, where)
        if ten_sig or len_sig:
            # Tensions that swing from frame to frame more than they shift: the loop rings where
            # the twin's does not, as a loop whose motors answer late does (or one that friction
            # makes hunt: that is named friction where the friction model fits). The largest
            # swing over the frames kept, against the shift in the same frames: a ringing that
            # alternates frame by frame barely moves the running median, which crosses its band
            # later, as the loop settles off the twin's.
            recent = np.array([h[0].tensions_n - h[1].tensions_n for h in self._history]) - noise.bias[n:2 * n]
            swings = _ringing(recent) if len(recent) > FIT_FRAMES // 2 else np.zeros(1)
            k = int(np.argmax(swings))
            swing = float(swings[k])
            shift = float(np.linalg.norm(np.median(recent[k:k + FIT_FRAMES], axis=0)))
            debug["ringing_n"] = swing
            debug["shift_n"] = shift
            if swing > noise.ring_band_n and swing / 2 > shift:
                hunting = self._friction(now_s, onset_s, frames, where)
                if _fits(hunting):
                    return hunting
                latency = self._latency(now_s, onset_s, where)
                # Where the twin's own tensions swing as much (a stiff rod rings on both sides), a
                # step of the device's (a slip, a load) rings off the twin's too: the ringing is a
                # late loop's only where the cells follow the twin's swinging tensions late (the
                # lag fits them) or the encoders follow its motion late.
                twin_swing = float(_ringing(np.array([h[1].tensions_n for h in self._history]))[k])
                debug["twin_ringing_n"] = twin_swing
                if twin_swing <= swing or _fits(latency):
                    return dataclasses.replace(latency, detail={**latency.detail, **debug})
                following = self._tension_latency(now_s, onset_s, where)
                if _fits(following):
                    return dataclasses.replace(following, detail={**following.detail, **debug})
        slip = self._slip(now_s, onset_s, d_ten, where, debug) if ten_sig else None
        if ten_sig and tip_sig:
            if explained < EXPLAINED_FRACTION and slip is not None:
                # The tip moved as the measured tensions say: a tendon's own length changed under
                # the encoder.
                return slip
            if load is not None:
                return load
            return Divergence(now_s, onset_s, "tip_load", "tip_force_n", math.nan, math.nan, "N", where,
                              {"tip_change_m": d_tip, **debug})
        friction = self._friction(now_s, onset_s, frames, where) if ten_sig else None
        if friction is not None and _fits(friction):
            return friction
        if len_sig or ten_sig:
            latency = self._latency(now_s, onset_s, where)
            # A stiff rod's loop answers friction with its encoders, not its cells: a sliding
            # tendon's encoder lags its setpoint by what friction takes, in proportion to its
            # tension and with the sign of its sliding, where a late loop's lags in proportion to
            # the rate; whichever fits the encoders better names it (on stiff-long a 10 % friction's
            # encoders fitted a lag to 0.77, friction's pattern to 0.85).
            sliding = self._encoder_friction(now_s, onset_s, where)
            if _fits(sliding) and sliding.detail["fit"] > latency.detail["fit"]:
                return sliding
            if _fits(latency):
                return latency
        if load is not None and load.size > 3 * load.std and explained >= EXPLAINED_FRACTION:
            return load
        if slip is not None and float(d_ten[slip.detail["tendon"]]) < 0:
            # A tension fell with the encoders where the twin's are: the tendon is longer than its
            # count says (slipped on its spool, or gone slack), though the tip's move is too small
            # to tell.
            return slip
        return Divergence(now_s, onset_s, "unexplained", "", float(np.abs(level).max()), 0.0, "bands", where, debug)

    def _slip(self, now_s, onset_s, d_ten, where, debug) -> Divergence:
        """A slip of the tendon whose tension changed most, sized by how its tension falls per
        metre paid out on the twin."""
        noise = self._model()
        n = self.n
        i = int(np.argmax(np.abs(d_ten)))
        stiffness = float(noise.stiffness_n_per_m[i])
        size = -float(d_ten[i]) / stiffness if stiffness > 0 else math.nan
        std = float(noise.sigma[n + i]) / stiffness if stiffness > 0 else math.nan
        return Divergence(now_s, onset_s, "tendon_slip", f"tendon_slip_m[{i}]", size, std, "m", where,
                          {"tendon": i, "tension_change_n": float(d_ten[i]), **debug})

    def _loadcell(self, now_s, onset_s, frames, i, where) -> Divergence | None:
        """Cell ``i``'s offset δ or gain error g, whichever fits its residual since the change
        better (least squares with the change's frame free: a gain drift scales with the twin's
        tension, an offset does not), with the other's size in ``detail``; None while neither fits
        significantly better and the change may still wait (:data:`LOADCELL_WAIT_FRAMES`)."""
        n = self.n
        # The watched residual: what cell i reads beyond what the other cells' noise predicts, over
        # the history before the naming and the frames waited since.
        kept = self._watched[-(HISTORY_FRAMES + len(frames) - NAMING_FRAMES):]
        d = np.array([w[0][n + i] for w in kept])
        tau = np.array([w[1][i] for w in kept])
        sigma = float(self._model().sigma[n + i])
        # Each model takes its best change frame, at least the naming frames before the end (it
        # crossed the band since); sums over the frames from each start by cumulative sums.
        starts = np.arange(max(len(d) - NAMING_FRAMES, 1))
        zero = np.zeros(1)
        d2, dd, tt, dt = (np.concatenate([zero, np.cumsum(x)]) for x in (d * d, d, tau * tau, d * tau))
        count = len(d) - starts
        before = d2[starts]
        after_d2, after_d = d2[-1] - before, dd[-1] - dd[starts]
        after_tt, after_dt = tt[-1] - tt[starts], dt[-1] - dt[starts]
        offset_sse = before + after_d2 - after_d ** 2 / count
        gain_sse = before + after_d2 - after_dt ** 2 / np.maximum(after_tt, 1e-12)
        k_off, k_gain = int(np.argmin(offset_sse)), int(np.argmin(gain_sse))
        offset = (float(after_d[k_off] / count[k_off]), sigma / math.sqrt(count[k_off]))
        gain = (float(after_dt[k_gain] / max(after_tt[k_gain], 1e-12)), sigma / max(math.sqrt(after_tt[k_gain]), 1e-12))
        # A gain is named where it fits the frames significantly better than an offset (χ² by more
        # than GAIN_CHI2); an offset, the commoner fault, where it fits at least as well as a gain.
        margin = float(offset_sse[k_off] - gain_sse[k_gain]) / sigma ** 2
        # Whether the frames since the change could tell the two at all: what the gain's pattern
        # departs from a step there (χ², in the cell's noise). A held tension scales to the same
        # step either way: the offset is named at once, a candidate gain (:meth:`_refine`) until
        # the tension moves; where the frames could tell them, a gain that fits better, not yet
        # significantly, waits for the motion to move the tension further.
        held = tau[k_off:] - tau[k_off:].mean()
        self._offset_rows = [(float(a), float(b)) for a, b in zip(d[k_off:], tau[k_off:])]
        self._offset_told = gain[0] ** 2 * float(held @ held) / sigma ** 2
        if (0.0 < margin <= GAIN_CHI2 and self._offset_told >= GAIN_CHI2
                and len(frames) < NAMING_FRAMES + LOADCELL_WAIT_FRAMES):
            return None
        if margin > GAIN_CHI2:
            return Divergence(now_s, onset_s, "loadcell_gain", f"effects.tension_gain_error[{i}]", gain[0], gain[1],
                              "1", where, {"channel": i, "offset_if_offset_n": offset[0], "chi2_margin": margin})
        return Divergence(now_s, onset_s, "loadcell_offset", f"effects.tension_offset_error_n[{i}]", offset[0],
                          offset[1], "N", where, {"channel": i, "gain_if_gain": gain[0], "chi2_margin": margin})

    def _friction_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Over the last :data:`FIT_FRAMES` frames, (T, n) each: what friction would add to each
        cell's reading per unit of its coefficient (the twin's tension, + pulled in, − released,
        0 where the tendon moved less than the encoders resolve), the cells' residuals, the twin's
        tensions."""
        n = self.n
        hist = self._history[-FIT_FRAMES:]
        rows, xs, tensions = [], [], []
        for k in range(1, len(hist)):
            twin_now, twin_before = hist[k][1], hist[k - 1][1]
            rate = (twin_now.lengths_m - twin_before.lengths_m)
            moving = np.abs(rate) > self._floor[:n]
            device_now = hist[k][0]
            rows.append(device_now.tensions_n - twin_now.tensions_n - self._model().bias[n:2 * n])
            xs.append(-np.sign(rate) * moving * twin_now.tensions_n)
            tensions.append(twin_now.tensions_n)
        return np.array(xs).reshape(-1, n), np.array(rows).reshape(-1, n), np.array(tensions).reshape(-1, n)

    def _friction(self, now_s, onset_s, frames, where) -> Divergence:
        """Friction changes the tension a load cell reads against the tendon's sliding: pulled in
        (length falling) it reads more than the twin, released less; sized as the fraction of the
        tension lost per unit of that direction."""
        n = self.n
        xs, ys, _ = self._friction_rows()
        x, y = xs.ravel(), ys.ravel()
        fraction, std, fit = _slope(x, y, float(np.mean(self._model().sigma[n:2 * n])), floor=1e-12)
        return Divergence(now_s, onset_s, "friction", "effects.tendon_friction_coeff", fraction, std, "1 (tension fraction)",
                          where, {"fit": fit})

    def _encoder_friction(self, now_s, onset_s, where) -> Divergence:
        """Friction seen in the encoders: each moving tendon's encoder residual against its sliding
        direction times the twin's tension over the last :data:`FIT_FRAMES` frames (the length
        loop leaves a sliding tendon's encoder behind its motion by what friction takes); sized as the
        tension fraction that lag holds at the tendons' stiffness (what a metre paid out takes
        off the tension on the twin)."""
        n = self.n
        noise = self._model()
        hist = self._history[-FIT_FRAMES:]
        rows, xs = [], []
        for k in range(1, len(hist)):
            twin_now, twin_before = hist[k][1], hist[k - 1][1]
            rate = twin_now.lengths_m - twin_before.lengths_m
            moving = np.abs(rate) > self._floor[:n]
            rows.append(hist[k][0].lengths_m - twin_now.lengths_m - noise.bias[:n])
            xs.append(-np.sign(rate) * moving * np.maximum(twin_now.tensions_n, 0.0))
        x, y = np.concatenate(xs) if xs else np.zeros(0), np.concatenate(rows) if rows else np.zeros(0)
        lag, lag_std, fit = _slope(x, y, float(np.mean(noise.sigma[:n])))
        stiffness = float(np.nanmean(noise.stiffness_n_per_m)) if np.isfinite(noise.stiffness_n_per_m).any() else math.nan
        return Divergence(now_s, onset_s, "friction", "effects.tendon_friction_coeff", lag * stiffness,
                          lag_std * stiffness, "1 (tension fraction)", where,
                          {"fit": fit, "fitted_on": "encoders", "encoder_lag_m_per_n": lag})

    def _friction_over_cell(self, i: int) -> float:
        """How much better (χ², each cell's residual in its noise) friction fits the tensions of
        the last frames than cell ``i``'s offset or gain alone: a tendon pulled in reads more, its
        antagonist released reads less, where one cell's change leaves the others as they were."""
        n = self.n
        xs, ys, tensions = self._friction_rows()
        sigma = self._model().sigma[n:2 * n]
        x, y = (xs / sigma).ravel(), (ys / sigma).ravel()
        fraction = float(np.dot(x, y) / max(np.dot(x, x), 1e-12))
        friction_sse = float(np.sum((y - fraction * x) ** 2))
        cell, tau = ys[:, i] / sigma[i], tensions[:, i] / sigma[i]
        offset_sse = float(np.sum((cell - cell.mean()) ** 2))
        gain_sse = float(np.sum(cell ** 2) - np.dot(cell, tau) ** 2 / max(float(np.dot(tau, tau)), 1e-12))
        others = float(np.sum(y ** 2) - np.sum(cell ** 2))
        return others + min(offset_sse, gain_sse) - friction_sse

    def _latency(self, now_s, onset_s, where) -> Divergence:
        """Encoders lagging the twin's: the residual length against the twin's length rate, the lag
        the slope."""
        n = self.n
        hist = self._history[-FIT_FRAMES:]
        ys, xs = [], []
        for k in range(1, len(hist)):
            rate = (hist[k][1].lengths_m - hist[k - 1][1].lengths_m) / max(hist[k][1].time_s - hist[k - 1][1].time_s,
                                                                             1e-9)
            ys.append(hist[k][0].lengths_m - hist[k][1].lengths_m - self._model().bias[:n])
            xs.append(-rate)
        x, y = np.concatenate(xs), np.concatenate(ys)
        lag, std, fit = _slope(x, y, float(np.mean(self._model().sigma[:n])))
        # The most the lag moves an encoder in these frames (m): below the encoders' floor (two
        # counts) it is within what the two loops' holding to a count leaves.
        moved = abs(lag) * float(np.abs(x).max(initial=0.0))
        return Divergence(now_s, onset_s, "latency", "effects.actuation_latency_s", lag, std, "s", where,
                          {"fit": fit, "encoder_lag_m": moved})

    def _tension_latency(self, now_s, onset_s, where) -> Divergence:
        """Cells lagging the twin's: the cells' residual (less its mean over the frames kept, a
        step's shift not being a lag) against the twin's tension rate over the last
        :data:`FIT_FRAMES`, the lag the slope."""
        n = self.n
        hist = self._history
        rows = np.array([hist[k][0].tensions_n - hist[k][1].tensions_n for k in range(1, len(hist))])
        rates = np.array([(hist[k][1].tensions_n - hist[k - 1][1].tensions_n)
                          / max(hist[k][1].time_s - hist[k - 1][1].time_s, 1e-9) for k in range(1, len(hist))])
        y = (rows - rows.mean(axis=0))[-(FIT_FRAMES - 1):].ravel()
        x = -rates[-(FIT_FRAMES - 1):].ravel()
        lag, std, fit = _slope(x, y, float(np.mean(self._model().sigma[n:2 * n])))
        return Divergence(now_s, onset_s, "latency", "effects.actuation_latency_s", lag, std, "s", where,
                          {"fit": fit, "fitted_on": "tensions"})


def _fits(event: Divergence) -> bool:
    """A friction change or a latency fitted over the last frames is resolved (twice its standard
    deviation) and explains :data:`MIN_FIT` of their residuals at least."""
    return event.size > 2 * event.std and event.detail["fit"] >= MIN_FIT


def _slope(x: np.ndarray, y: np.ndarray, sigma: float, floor: float = 1e-18) -> tuple[float, float, float]:
    """The one-parameter fit y ≈ a·x through the origin (a friction's fraction, a latency's lag):
    ``a``, its standard deviation where each of ``y`` has noise ``sigma`` (``y``'s unit), and the
    share of ``y`` it explains. ``floor`` keeps ``x``'s norm off zero where nothing moved."""
    a = float(np.dot(x, y) / max(np.dot(x, x), floor))
    std = float(sigma / max(float(np.sqrt(np.dot(x, x))), floor))
    return a, std, _explained(x * a, y)


def _explained(model: np.ndarray, values: np.ndarray) -> float:
    """The fraction of ``values``' sum of squares the ``model`` explains (R², about 0)."""
    total = float(values @ values)
    return 1.0 - float((values - model) @ (values - model)) / total if total > 0 else 0.0


def _tip_load_margin(d_tip: np.ndarray, unexplained: np.ndarray, wrt_force: np.ndarray,
                     tip_noise: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """How much better (χ², the tip's move in ``tip_noise``, m) a force at the tip explains the
    tip's move than either a load cell's change (the tip where the twin's is: ``d_tip`` left)
    or the measured tensions' own change (``unexplained``, what the rod model leaves of it); and
    that force (N) and its covariance, fitted in that noise."""
    force, cov = _least_squares(wrt_force, unexplained, tip_noise)
    load = float(np.sum(((unexplained - wrt_force @ force) / tip_noise) ** 2))
    margin = min(float(np.sum((d_tip / tip_noise) ** 2)), float(np.sum((unexplained / tip_noise) ** 2))) - load
    return margin, force, cov


def _held_fraction(tensions_move_m: np.ndarray, force_move_m: np.ndarray) -> float:
    """How far (a fraction of it) the tip's move the measured tensions make on their own is from
    holding the tip back against a force at the tip: a part 0 < α ≤ 1 of the force's move, turned
    back (the length loop's tensions resist a tip load, taking up all of it where the tip is held
    fast); ``inf`` where no such part fits (the tensions pushing the tip along the force, or
    further back than it)."""
    norm2 = float(force_move_m @ force_move_m)
    alpha = -float(tensions_move_m @ force_move_m) / norm2 if norm2 > 0 else 0.0
    size = float(np.linalg.norm(tensions_move_m))
    if not 0.0 < alpha <= 1.0 or size == 0.0:
        return math.inf
    return float(np.linalg.norm(tensions_move_m + alpha * force_move_m)) / size


def _least_squares(matrix: np.ndarray, values: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x minimising ‖(A x − b)/σ‖ in the directions it resolves to :data:`MAX_FORCE_STD_N` (a
    push along a stiff direction, the backbone's axis, moves the tip too little to be seen), and
    its covariance there."""
    a = matrix / sigma[:, None]
    b = values / sigma
    u, singular, vt = np.linalg.svd(a, full_matrices=False)
    keep = singular > 1.0 / MAX_FORCE_STD_N
    inverse = np.where(keep, 1.0 / np.where(keep, singular, 1.0), 0.0)
    x = vt.T @ (inverse * (u.T @ b))
    cov = vt.T @ np.diag(inverse ** 2) @ vt
    return x, cov


def _loop_stiffness(twin_rows: np.ndarray, n: int) -> np.ndarray:
    """(n,) fall of each tendon's tension per metre it is paid out, from the twin's frames: the
    slope of tension on length over frame-to-frame changes."""
    if len(twin_rows) < 3:
        return np.full(n, math.nan)
    d = np.diff(twin_rows, axis=0)
    lengths, tensions = d[:, :n], d[:, n:2 * n]
    out = np.empty(n)
    for i in range(n):
        var = float(lengths[:, i] @ lengths[:, i])
        out[i] = -float(lengths[:, i] @ tensions[:, i]) / var if var > 0 else math.nan
    return out


def _tail_band(medians_abs: np.ndarray, spread: np.ndarray, warm_s: float, groups: list[slice]) -> np.ndarray:
    """(C,) the level each channel's running median exceeds at a rate of :data:`FALSE_ALARM_RATE`
    over :data:`WATCH_S`, from the warm-up's excursions above :data:`TAIL_SIGMAS` spreads (peaks
    over a threshold: the excursions' rate λ per channel and their peaks' mean excess s over the
    threshold u, an exponential tail, give u + s ln(λ T / α)). The channels of a group (the
    tendons' lengths, their tensions, their duties, the tip's axes) share their motors, loop and
    sensors, so their excursions, in units of each channel's spread, are pooled: a warm-up sees
    one tendon's transient where it may miss the same on another."""
    normal = medians_abs / spread
    out = TAIL_SIGMAS * spread.astype(float)
    for group in groups:
        peaks: list[float] = []
        for column in normal[:, group].T:
            # Excursions: runs of frames above the threshold, each one peak.
            peaks += [float(column[a:b].max()) for a, b in _runs(column > TAIL_SIGMAS)]
        if not peaks:
            continue
        excess = np.array(peaks) - TAIL_SIGMAS
        scale = float(excess.mean()) if len(peaks) >= TAIL_MIN_EXCURSIONS else float(excess.max())
        channels = len(range(*group.indices(normal.shape[1])))
        expected = len(peaks) / channels / warm_s * WATCH_S / FALSE_ALARM_RATE
        out[group] = spread[group] * (TAIL_SIGMAS + scale * math.log(max(expected, 1.0)))
    return out



def _longest_excursion(medians_abs: np.ndarray, level: np.ndarray) -> int:
    """The longest run of frames (rows) any column spent above its ``level``."""
    return max((int(last - first) for column, threshold in zip(medians_abs.T, level)
                for first, last in _runs(column > threshold)), default=0)


def _take_up_excursion(medians_abs: np.ndarray, level: np.ndarray, since_take_up: np.ndarray) -> int:
    """The longest any column's run above its ``level`` lasted after a take-up (0 if none): of
    the runs that start within :data:`TAKE_UP_FRAMES` of one or hold the start of one
    (``since_take_up``, per row, the frames since the two sides last disagreed on a tendon), the
    frames from the run's start or the last take-up begun in it, whichever is later, as
    :meth:`Monitor.update` counts them."""
    longest = 0
    now = np.flatnonzero((since_take_up == 0) & (np.concatenate([[1], since_take_up[:-1]]) > 0))
    for column, threshold in zip(medians_abs.T, level):
        for first, last in _runs(column > threshold):
            inside = now[(now >= first) & (now < last)]
            if since_take_up[first] <= TAKE_UP_FRAMES or len(inside):
                longest = max(longest, int(last - max(first, inside.max() if len(inside) else first)))
    return longest


def _runs(above: np.ndarray) -> list[tuple[int, int]]:
    """The runs of True in ``above`` (frames), each as (first, one past the last)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], above.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def _ringing(tensions_n: np.ndarray) -> np.ndarray:
    """The running median over :data:`FIT_FRAMES` of the tensions' frame-to-frame change (N, the
    norm over the cells), one value per window of rows (T, n)."""
    steps = np.linalg.norm(np.diff(tensions_n, axis=0), axis=1)
    if len(steps) == 0:
        return np.zeros(1)
    width = min(FIT_FRAMES - 1, len(steps))
    return np.median(np.lib.stride_tricks.sliding_window_view(steps, width), axis=-1)


def _nanmedian(rows: np.ndarray) -> np.ndarray:
    """Column medians of the finite values; NaN where a column has none (a tendon slack all along)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(rows, axis=0)
