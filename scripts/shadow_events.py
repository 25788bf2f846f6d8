"""The shadow's detection table: hidden events of every kind at three sizes, at random times, on zoo robots.

Per robot: the noise is learned in a clean warm-up of the standard motion, which then runs clean for
``--clean-minutes`` (false alarms); then ``--reps`` trials per kind and size, each a fresh sim://
device with one hidden event at a random time, watched for one period of the motion (a change the
motion does not load now shows when it next does; the figures within 2 s of the event, the earlier
watch, are printed beside them; twin.dynamics.shadow_bench); ``--set`` changes the parameters of
every device and twin alike. Prints one row per kind and size (detection rate, latency median and
95th percentile, right-name rate, the names given) and the goals' figures: events above the
smallest size detected, named right, false alarms.
Trials are appended to ``--out`` as JSON lines as they finish (nothing lost when it stops half-way).

    .venv/bin/python scripts/shadow_events.py --robots endoscope,three-tendon --reps 2 --clean-minutes 30
    .venv/bin/python scripts/shadow_events.py --robots stiff-long --reps 0 --set effects.tendon_friction_coeff=0.1
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time

import numpy as np

from twin.dynamics import shadow_bench as sb
from twin.params import ParameterError
from twin.robots import load_robot, robot_path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", default="endoscope", help="comma-separated zoo robots")
    parser.add_argument("--kinds", default=",".join(sb.EVENT_KINDS), help="comma-separated event kinds")
    parser.add_argument("--reps", type=int, default=2, help="trials per kind, size and robot")
    parser.add_argument("--warmup-s", type=float, default=60.0, help="device time the noise is learned over (s)")
    parser.add_argument("--clean-minutes", type=float, default=30.0, help="clean running after the warm-up (min)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="shadow-events.jsonl", help="JSON-lines file the trials are appended to")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="a parameter of the device and the twin alike, e.g. effects.tendon_friction_coeff=0.1 "
                             "(repeatable)")
    args = parser.parse_args(argv)
    kinds = args.kinds.split(",")
    unknown = [k for k in kinds if k not in sb.EVENT_KINDS]
    if unknown:
        parser.error(f"--kinds {args.kinds}: {', '.join(unknown)} unknown; kinds are {', '.join(sb.EVENT_KINDS)}")
    rng = np.random.default_rng(args.seed)
    folder = sb.temporary_folder()
    trials: list[sb.Trial] = []
    clean = {}
    for robot in args.robots.split(","):
        try:
            robot_path(robot)
        except ValueError as exc:
            parser.error(f"--robots {robot}: {exc}")
        try:
            params = load_robot(robot, args.overrides)
        except ParameterError as exc:
            parser.error(f"--set {' '.join(args.overrides)}: {exc}")
        started = time.monotonic()
        try:
            noise, alarms, frames, cpu_s = sb.learn_noise(params, warmup_s=args.warmup_s,
                                                          clean_s=args.clean_minutes * 60, seed=args.seed)
        except ValueError as exc:
            # learn_noise's message names the seed first ("seed N: why").
            parser.error(f"--seed {args.seed}: {str(exc).split(': ', 1)[-1]}")
        clean[robot] = {"clean_minutes": args.clean_minutes, "set": args.overrides, "false_alarms": len(alarms),
                        "frames": frames,
                        "cpu_per_frame_ms": 1e3 * cpu_s / max(frames, 1), "alarms": [a.line() for a in alarms]}
        print(f"{robot}: clean {args.clean_minutes:g} min after a {args.warmup_s:g} s warm-up: {len(alarms)} false "
              f"alarms; shadow {clean[robot]['cpu_per_frame_ms']:.2f} ms CPU a frame "
              f"({time.monotonic() - started:.0f} s)", file=sys.stderr, flush=True)
        for alarm in alarms:
            print(f"   {alarm.line()}", file=sys.stderr)
        with open(args.out, "a") as out:
            out.write(json.dumps({"robot": robot, "clean": clean[robot]}) + "\n")
        total = len(kinds) * 3 * args.reps
        done = 0
        for kind in kinds:
            for size in sb.EVENT_KINDS[kind][1]:
                for _ in range(args.reps):
                    trial = sb.run_trial(params, noise, kind, size, robot=robot, rng=rng, folder=folder)
                    trials.append(trial)
                    done += 1
                    print(f"[{robot} {done}/{total}] {kind} {size:g}: "
                          f"{'detected in %.0f ms as %s' % (trial.latency_s * 1e3, trial.first_named + ('' if trial.named == trial.first_named else ' -> ' + trial.named)) if trial.detected else 'missed'}"
                          f"{', %d false alarms before' % trial.false_alarms if trial.false_alarms else ''}",
                          file=sys.stderr, flush=True)
                    with open(args.out, "a") as out:
                        out.write(json.dumps({k: v for k, v in dataclasses.asdict(trial).items()}, default=str) + "\n")
    rows = sb.summarise(trials, kinds)
    print(f"{'kind':16s} {'size':>8s} {'unit':4s} {'n':>3s} {'detected':>8s} {'median ms':>9s} {'p95 ms':>7s} "
          f"{'named':>6s}  names")
    for row in rows:
        def ms(x):
            return f"{x * 1e3:.0f}" if math.isfinite(x) else "-"
        print(f"{row['kind']:16s} {row['size']:8g} {row['unit']:4s} {row['trials']:3d} {row['detected']:8.2f} "
              f"{ms(row['latency_median_s']):>9s} {ms(row['latency_p95_s']):>7s} {row['right_name']:6.2f}  "
              f"{','.join(row['names'])}")
    above = [t for t in trials if t.size != sb.EVENT_KINDS[t.kind][1][0]]
    detected = [t for t in trials if t.detected]
    latencies = [t.latency_s for t in detected]
    figures: dict = {
        "events": len(trials),
        "detected_above_smallest": sum(t.detected for t in above) / max(len(above), 1),
        "detected_all": len(detected) / max(len(trials), 1),
        "named_right": sum(t.right_name for t in trials) / max(len(trials), 1),
        # The first name alone, before an offset on a held tension is replaced by the gain it was.
        "first_named_right": sum(t.first_named == sb.EVENT_KINDS[t.kind][0] for t in trials) / max(len(trials), 1),
        "named_right_above_smallest": sum(t.right_name for t in above) / max(len(above), 1),
        "named_right_of_detected": sum(t.right_name for t in detected) / max(len(detected), 1),
        "latency_median_ms": float(np.median(latencies)) * 1e3 if latencies else math.nan,
        "latency_p95_ms": float(np.percentile(latencies, 95)) * 1e3 if latencies else math.nan,
        # The earlier watch's figures: detected within sb.DETECTION_WINDOW_S of the event, named by then.
        "detected_above_smallest_in_window": sum(t.detected_in_window for t in above) / max(len(above), 1),
        "named_right_in_window": sum(t.right_name_in_window for t in trials) / max(len(trials), 1),
        "false_alarms_before_events": sum(t.false_alarms for t in trials),
        "alarms_in_pretension": sum(t.pretension_alarms for t in trials),
        "clean": {robot: {k: v for k, v in c.items() if k != "alarms"} for robot, c in clean.items()},
    }
    robots = sb.summarise_robots(trials)
    figures["robots"] = robots
    print(json.dumps(figures, indent=1))
    print(f"{'robot':18s} {'events':>6s} {'detected above smallest':>23s} {'named right':>11s} "
          f"{'named above smallest':>20s} {'median ms':>9s} {'p95 ms':>7s} {'false alarms':>12s}  goals"
          f"   (within {sb.DETECTION_WINDOW_S:g} s: detected above smallest, named right)")
    for robot, row in robots.items():
        alarms = clean[robot]["false_alarms"] + row["false_alarms_before_events"]
        print(f"{robot:18s} {row['events']:6d} {row['detected_above_smallest']:23.0%} {row['named_right']:11.0%} "
              f"{row['named_right_above_smallest']:20.0%} {row['latency_median_ms']:9.0f} "
              f"{row['latency_p95_ms']:7.0f} {alarms:12d}  {'met' if row['goals_met'] and alarms == 0 else 'NOT met':7s}"
              f"   ({row['detected_above_smallest_in_window']:.0%}, {row['named_right_in_window']:.0%})")
    # Every robot is held to the goals on its own: a robot that meets them does not carry one that does not.
    goals_met = (figures["detected_above_smallest"] >= sb.GOAL_DETECTED and figures["named_right"] >= sb.GOAL_NAMED
                 and all(c["false_alarms"] == 0 for c in clean.values())
                 and all(row["goals_met"] for row in robots.values()))
    print(f"goals (>= {sb.GOAL_DETECTED:.0%} above the smallest size detected, >= {sb.GOAL_NAMED:.0%} named right, "
          f"latency median <= {sb.GOAL_LATENCY_MEDIAN_S * 1e3:.0f} ms, 0 false alarms clean, on every robot): "
          f"{'met' if goals_met else 'NOT met'}")
    return 0 if goals_met else 1


if __name__ == "__main__":
    sys.exit(main())
