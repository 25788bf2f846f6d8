"""``twin shadow``: drive a device through a standard motion with its twin in lockstep beside it and
print the divergences the shadow names (:mod:`twin.shadow`).

The standard motion is the dynamic experiments' excitation in length mode (:func:`standard_motion`:
the length steps, the pull-release cycles and the chirp of :func:`twin.dynamics.protocols.experiment_set`),
repeated for as long as asked; ``--motion FILE`` gives another (JSON lines ``{"t_s": 0.5,
"lengths_m": [...]}``, repeated likewise).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from twin.params import Params

# The default warm-up: periods of the motion, and at most this long (s). Two twins on the same
# commands part by their sensors' noise only after the first period or so (the standard motion's
# second cycle on the endoscope), and a minute of it holds the tails a clean half hour showed.
WARMUP_PERIODS = 4
MAX_WARMUP_S = 60.0

__all__ = ["MAX_WARMUP_S", "WARMUP_PERIODS", "Motion", "load_motion", "register", "run_motion", "standard_motion"]


class Motion:
    """Length setpoints (m, relative to the pretensioned straight pose) at times after the start,
    repeated every ``period_s``.

    Args:
        times_s: (C,) rising times within one period (s).
        lengths_m: (C, n) setpoints.
        period_s: the motion's period (s), at least the last time.
    """

    def __init__(self, times_s, lengths_m, period_s: float):
        self.times_s = np.asarray(times_s, dtype=float)
        self.lengths_m = np.asarray(lengths_m, dtype=float)
        self.period_s = float(period_s)

    def commands(self, start_s: float, end_s: float):
        """The (time, lengths) setpoints due in [start_s, end_s) of the repeated motion."""
        cycle = math.floor(start_s / self.period_s)
        while cycle * self.period_s < end_s:
            for t, lengths in zip(self.times_s, self.lengths_m):
                at = cycle * self.period_s + t
                if start_s <= at < end_s:
                    yield at, lengths
            cycle += 1


def standard_motion(params: Params) -> Motion:
    """The length-mode dynamic experiments back to back: steps, pull-release, chirp."""
    from twin.dynamics.protocols import experiment_set

    times: list[float] = []
    rows: list[tuple[float, ...]] = []
    offset = 0.0
    for experiment in experiment_set(params):
        if experiment.mode != "lengths":
            continue
        for command in experiment.commands:
            times.append(offset + command.time_s)
            rows.append(command.values)
        offset += experiment.duration_s
    return Motion(times, rows, offset)


def load_motion(path: str, params: Params) -> Motion:
    """A motion from JSON lines ``{"t_s": …, "lengths_m": [n numbers]}``; its period ends a
    quarter second after the last line.

    Raises:
        ValueError: unreadable, or a line not so (the line and value named).
    """
    n = params.tendons.count
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ValueError(f"cannot be read: {exc.strerror or exc}") from None
    times: list[float] = []
    rows: list[np.ndarray] = []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            entry = json.loads(line)
            t = float(entry["t_s"])
            lengths = np.asarray(entry["lengths_m"], dtype=float)
        except (json.JSONDecodeError, KeyError, TypeError, ValueError):
            raise ValueError(f"line {number}: {line.strip()[:80]!r}: expected {{\"t_s\": 0.5, \"lengths_m\": "
                             f"[{n} numbers]}}") from None
        if lengths.shape != (n,) or not np.isfinite(lengths).all() or not (math.isfinite(t) and t >= 0):
            raise ValueError(f"line {number}: {line.strip()[:80]!r}: t_s >= 0 and {n} finite lengths_m expected")
        if times and t < times[-1]:
            raise ValueError(f"line {number}: t_s = {t}: times must rise")
        times.append(t)
        rows.append(lengths)
    if not times:
        raise ValueError("no setpoints")
    return Motion(times, rows, times[-1] + 0.25)


def run_motion(device, params: Params, motion: Motion, duration_s: float, *, progress=None, stop=None) -> float:
    """Pretension ``device`` straight in the holder (lengths tared there), release it and play
    ``motion`` for ``duration_s`` of device time, or until ``stop()`` (called each frame) says so;
    returns the device time of the motion's start (s). The device is left disabled."""
    from twin.dynamics.protocols import RELEASE_REST_S
    from twin.experiments.protocols import pretension

    device.disable()
    pretension(device, params, mode="lengths", settle_s=0.3, tare_lengths=True)
    device.fixture.release_holder()
    device.wait(RELEASE_REST_S)
    start = device.time_s
    done_s = 0.0
    while done_s < duration_s:
        now_s = device.time_s - start
        for _, lengths in motion.commands(done_s, now_s + 1e-9):
            device.set_lengths(lengths)
        done_s = now_s + 1e-9
        device.wait_next(timeout_s=1.0)
        if progress is not None:
            progress(min(now_s, duration_s))
        if stop is not None and stop():
            break
    device.disable()
    return start


# ---------------------------------------------------------------------------------------- command line
def register(subparsers) -> None:
    from twin.cliargs import add_device_arg, add_param_args
    from twin.live import add_live_argument

    p = subparsers.add_parser(
        "shadow",
        help="run a device with a calibrated twin in lockstep beside it through a standard motion and print "
             "the divergences it names (t_s, kind, effect key, size)")
    add_device_arg(p, help="device URL, e.g. sim://?events=hidden.jsonl (default sim://) or serial:///dev/ttyACM0")
    p.add_argument("--duration", type=float, default=60.0, metavar="S", help="device time of the motion (s, default 60)")
    p.add_argument("--motion", metavar="FILE", default=None,
                   help="JSON lines {\"t_s\": ..., \"lengths_m\": [...]} instead of the dynamic experiments' excitation")
    p.add_argument("--warmup", type=float, default=None, metavar="S",
                   help="device time the noise is learned over (s; default 4 periods of the motion, at most 60 s)")
    p.add_argument("--calibration", metavar="FILE", default=None, help="load-cell calibration (JSON) for the device")
    p.add_argument("--out", default="runs", help="parent of the run folder (shadow-<time>/events.jsonl)")
    p.add_argument("--json", action="store_true", help="print the divergences and figures as one JSON object")
    p.add_argument("--igtl", type=int, default=None, metavar="PORT",
                   help="also serve each divergence over OpenIGTLink on this port (0 picks one) as a STRING message "
                        "'ShadowEvent', which 3D Slicer's OpenIGTLinkIF shows as a text node")
    add_live_argument(p)
    add_param_args(p)
    p.set_defaults(func=run_shadow_command)


def run_shadow_command(args: argparse.Namespace) -> int:
    from twin.cliargs import UsageError, new_run_folder, open_device_arg, params_from_args, robot_name
    from twin.device.sim_url import open_shadow_twin
    from twin.shadow import ShadowDevice

    params = params_from_args(args)
    if not (math.isfinite(args.duration) and args.duration > 0):
        raise UsageError(f"--duration {args.duration}: must be a time > 0 (s)")
    if args.warmup is not None and not (math.isfinite(args.warmup) and 0 < args.warmup < args.duration):
        raise UsageError(f"--warmup {args.warmup}: must be > 0 and shorter than --duration {args.duration}")
    try:
        motion = load_motion(args.motion, params) if args.motion else standard_motion(params)
    except ValueError as exc:
        raise UsageError(f"--motion {args.motion}: {exc}") from None
    if "shadow=" in args.device:
        raise UsageError(f"--device {args.device}: twin shadow runs the shadow itself; drop shadow= from the URL")
    calibration = None
    if args.calibration:
        from twin.calibration import load_calibration

        try:
            calibration = load_calibration(args.calibration)
        except (OSError, ValueError) as exc:
            raise UsageError(f"--calibration {args.calibration}: {exc}") from None
    warmup_s = args.warmup if args.warmup is not None else min(WARMUP_PERIODS * motion.period_s, MAX_WARMUP_S)
    if warmup_s >= args.duration:
        raise UsageError(f"--duration {args.duration}: must exceed the warm-up of {warmup_s:g} s (one period of the "
                         "motion; set --warmup)")
    folder = new_run_folder(args.out, "shadow")
    log_path = folder / "events.jsonl"
    device = open_device_arg(args.device, params=params, robot=robot_name(args))
    shadow = ShadowDevice(device, open_shadow_twin(params, device.base_rotation), params, warmup_s=warmup_s,
                          log_path=log_path, console=None if args.json else sys.stderr)
    shadow.warm_rod()
    with contextlib.ExitStack() as stack:
        _publish_divergences(args, shadow, stack)
        wall = time.monotonic()
        watched = stack.enter_context(shadow)
        if calibration is not None:
            watched.set_calibration(calibration)
        else:
            watched.tare(loadcells=True, lengths=False)
        start_s = run_motion(stack.enter_context(_live(args, watched, params)), params, motion, args.duration)
        wall = time.monotonic() - wall
    figures = summary(shadow, start_s, wall)
    result = {"device": args.device, "run": str(folder), "warmup_s": warmup_s, **figures,
              "events": [{**e.to_dict(), "t_s": round(e.t_s - start_s, 4)} for e in shadow.divergences]}
    (folder / "summary.json").write_text(json.dumps(result, indent=1))
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{len(shadow.divergences)} divergences named in {figures['compared_frames']} frames; log {log_path}")
        print(f"cost {figures['cpu_per_frame_ms']:.2f} ms CPU a frame ({figures['realtime_load']:.2f} of the 25 ms "
              f"period){'; fell behind ' + str(shadow.behind) + ' times' if shadow.behind else ''}")
    return 0


def _publish_divergences(args: argparse.Namespace, shadow, stack: contextlib.ExitStack) -> None:
    """``--igtl PORT``: an OpenIGTLink server sending each divergence as a STRING message."""
    if args.igtl is None:
        return
    from twin.cliargs import UsageError
    from twin.device.igtl_server import OpenIGTLinkServer
    from twin.shadow.device import divergence_message

    try:
        server = stack.enter_context(OpenIGTLinkServer(port=args.igtl))
    except OSError as exc:
        raise UsageError(f"--igtl {args.igtl}: cannot listen ({exc.strerror or exc})") from None
    print(f"twin shadow: divergences over OpenIGTLink on {server.host}:{server.port} (STRING 'ShadowEvent')",
          file=sys.stderr, flush=True)
    shadow.subscribe(lambda event: server.send([divergence_message(event, timestamp_s=time.time())]))


@contextlib.contextmanager
def _live(args: argparse.Namespace, shadow, params: Params):
    """``--live [PORT]``: the device as the live view shows it, the divergences listed there."""
    from twin.live import LiveDevice, live_view_from_args

    view = live_view_from_args(args, params, base_rotation=shadow.base_rotation, command="shadow")
    if view is None:
        yield shadow
        return
    with view:
        view.follow_shadow(shadow)
        yield LiveDevice(shadow, view)


def summary(shadow, start_s: float, wall_s: float) -> dict:
    """The shadow's figures: frames compared, CPU per frame, real-time load."""
    frames = max(shadow.compared, 1)
    per_frame_s = shadow.cpu_s / frames
    return {"compared_frames": shadow.compared, "unmatched_frames": shadow.unmatched,
            "cpu_per_frame_ms": round(per_frame_s * 1e3, 3), "realtime_load": round(per_frame_s / 0.025, 3),
            "behind": shadow.behind, "max_queue_frames": shadow.max_queue, "skipped_frames": shadow.skipped,
            "setpoint_mismatch_frames": shadow.target_mismatches, "wall_s": round(wall_s, 1)}
