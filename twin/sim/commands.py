"""``twin sim`` (settle the twin under tensions or tendon lengths) and ``twin crosscheck``."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from twin.cliargs import (UsageError, add_param_args, add_pose_args, count, new_run_folder, nonnegative, params_from_args,
                          pose_overrides, positive, sigterm_event, vector)
from twin.live import add_live_argument

__all__ = ["register"]


def register(subparsers) -> None:
    sim = subparsers.add_parser("sim", help="settle the MuJoCo twin under tensions or tendon lengths")
    drive = sim.add_mutually_exclusive_group(required=True)
    drive.add_argument("--tensions", type=vector(None), metavar="T1,T2,...", help="tendon tensions (N), one per tendon")
    drive.add_argument("--lengths", type=vector(None), metavar="D1,D2,...",
                       help="relative tendon lengths (m, positive = paid out), one per tendon")
    sim.add_argument("--tip-mass-kg", type=nonnegative, default=0.0, metavar="M", help="mass hung at the tip (kg)")
    sim.add_argument("--tip-force", type=vector(3), default=np.zeros(3), metavar="FX,FY,FZ",
                     help="force on the tip, world frame (N), beside a hung mass")
    sim.add_argument("--tip-moment", type=vector(3), default=np.zeros(3), metavar="MX,MY,MZ",
                     help="moment on the tip, world frame (N·m)")
    sim.add_argument("--timeout-s", type=positive, default=3.0, help="simulated time allowed to settle (s)")
    sim.add_argument("--seed", type=count, default=0, help="sensor-noise seed")
    sim.add_argument("--json", action="store_true", help="print one JSON object")
    add_live_argument(sim)
    add_pose_args(sim)
    add_param_args(sim)
    sim.set_defaults(func=run_sim)

    check = subparsers.add_parser("crosscheck", help="twin vs predictor over the thesis validation grid",
                                  description="Exits 1 when the goal (median <= 1%%, worst <= 3%% of L, every "
                                              "configuration compared) is missed.")
    check.add_argument("--out", default=None, metavar="DIR",
                       help="report directory (default a new runs/crosscheck-YYYYmmdd-HHMMSS; the checked-in "
                            "reports are regenerated with --out reports/crosscheck)")
    check.add_argument("--elements", type=int, default=None, help="twin elements (default sim.elements)")
    check.add_argument("--robot", default=None, metavar="NAME",
                       help="a robot of the zoo (models/NAME/; --set applies on top), or 'all' of them with a "
                            "table in zoo.md")
    check.add_argument("--quick", action="store_true", help="the reduced grid (QUICK_GRID), no cause studies")
    check.add_argument("--no-causes", action="store_true", help="skip the cause studies")
    check.add_argument("--workers", type=int, default=1, metavar="N",
                       help="with --robot all: cross-check N robots at a time in local processes")
    check.add_argument("--cluster", default=None, metavar="ADDRESS",
                       help="with --robot all: cross-check the robots on the Ray cluster whose head is at ADDRESS "
                            "(HOST:PORT, 'auto', or 'local' for a new one of --workers CPUs); needs "
                            "pip install 'twin[cluster]'")
    add_pose_args(check)
    add_param_args(check, robot=False)
    check.set_defaults(func=run_crosscheck_command)


def run_sim(args: argparse.Namespace) -> int:
    from twin.live import live_view_from_args
    from twin.sim.plant import Plant

    params = params_from_args(args)
    drive = args.tensions if args.tensions is not None else args.lengths
    if drive.size != params.tendons.count:
        option = "--tensions" if args.tensions is not None else "--lengths"
        raise UsageError(f"{option} has {drive.size} values; the robot has {params.tendons.count} tendons")
    plant = Plant(params, base_rotation=params.rig.base_rotation, seed=args.seed)
    if args.tensions is not None:
        plant.set_tensions(args.tensions)
    else:
        plant.set_tendon_lengths(args.lengths)
    plant.set_tip_mass_kg(args.tip_mass_kg)
    plant.set_tip_load(args.tip_force, args.tip_moment)
    result = plant.settle(timeout_s=args.timeout_s)
    view = live_view_from_args(args, params, base_rotation=params.rig.base_rotation, command="sim")
    position, rotation = plant.tip_pose()
    # What the load cells report, through the nominal calibration (gain and offset).
    s = params.sensors
    measured = (plant.loadcell_raw_counts() - np.asarray(s.loadcell_offset_counts)) / s.loadcell_gain_counts_per_n
    out = {
        "tip_position_m": position.tolist(),
        "tip_rotation": rotation.tolist(),
        "tendon_lengths_m": plant.tendon_path_lengths_m().tolist(),
        "tensions_n": measured.tolist(),
        "encoder_counts": plant.encoder_counts().tolist(),
        "settled": result.settled,
        "settle_time_s": result.sim_time_s,
        "wall_time_s": result.wall_time_s,
    }
    if args.json:
        print(json.dumps(out))
    else:
        for key, value in out.items():
            print(f"{key}: {value}")
    if not result.settled:
        print(f"twin sim: did not settle within {args.timeout_s} s of simulated time "
              f"(last 20 ms moved {result.last_change_m:.3g} m); the state above is not static",
              file=sys.stderr)
        code = 1
    else:
        code = 0
    if view is not None:
        _serve_settled(view, plant)
    return code


def _serve_settled(view, plant) -> None:
    """Show the settled twin (and the prediction for its tensions) until Ctrl-C or SIGTERM."""
    from twin.live import show_twin

    show_twin(view, plant, label="settled")
    print("twin sim: serving the settled state; Ctrl-C to stop", file=sys.stderr, flush=True)
    try:
        with sigterm_event() as stop:
            while not stop.wait(1.0):
                pass
    except KeyboardInterrupt:
        pass
    finally:
        view.close()


def run_crosscheck_command(args: argparse.Namespace) -> int:
    from twin.params import parse_override
    from twin.sim.crosscheck import QUICK_GRID, ROBOTS, robot_params, run_crosscheck, run_zoo

    configs = QUICK_GRID if args.quick else None
    overrides = {**dict(parse_override(o) for o in args.overrides), **pose_overrides(args)}
    if args.elements is not None:
        overrides["sim.elements"] = args.elements
    if args.robot not in (None, "all") and args.robot not in ROBOTS:
        print(f"twin crosscheck: --robot {args.robot}: expected all or one of {', '.join(ROBOTS)}", file=sys.stderr)
        return 2
    if (args.workers != 1 or args.cluster is not None) and args.robot != "all":
        print("twin crosscheck: --workers and --cluster spread the robots of --robot all", file=sys.stderr)
        return 2
    if args.robot is not None and args.params is not None:
        print("twin crosscheck: --robot and --params: give one (a robot is its parameter file)", file=sys.stderr)
        return 2
    # Every robot's parameter set and the cluster are checked before a report folder is made.
    robots = {name: robot_params(name, overrides)
              for name in (ROBOTS if args.robot == "all" else [args.robot] if args.robot else [])}
    params = params_from_args(args).replace(overrides) if args.robot is None else robots.get(args.robot)
    if args.cluster is not None:
        from twin.scaleout import connect

        connect(args.cluster, args.workers)
    out = args.out or new_run_folder("runs", "crosscheck")
    if args.robot == "all":
        table, summaries = run_zoo(out, configs=configs, overrides=overrides, workers=args.workers,
                                    cluster=args.cluster, with_causes=not args.no_causes)
        print(f"report: {table}")
        for name, summary in summaries.items():
            _print_summary(name, summary)
        missed = [name for name, summary in summaries.items() if not summary["meets_goal"]]
        if missed:
            print(f"twin crosscheck: goal missed for {', '.join(missed)}", file=sys.stderr)
        return 1 if missed else 0
    path, summary = run_crosscheck(params, out, configs=configs, robot=args.robot,
                                   with_causes=not (args.no_causes or args.quick or args.robot not in (None, ROBOTS[0])))
    print(f"report: {path}")
    _print_summary(args.robot or "twin", summary)
    if not summary["meets_goal"]:
        print("twin crosscheck: goal missed (median <= 1%, worst <= 3% of L, every configuration compared); "
              "the report says by what", file=sys.stderr)
        return 1
    return 0


def _print_summary(name: str, summary: dict) -> None:
    print(f"{name}: median {summary['median_mm']:.3f} mm ({summary['median_pct']:.2f}% of L), "
          f"worst {summary['worst_mm']:.3f} mm ({summary['worst_pct']:.2f}%) over {summary['compared']} of "
          f"{summary['configurations']}: {'goal met' if summary['meets_goal'] else 'GOAL MISSED'}")
