"""``twin compensate`` and ``twin cocontraction``: the control studies from the shell (``twin tune`` is
:mod:`twin.tuning`'s, above the env)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from twin.cliargs import (UsageError, add_device_arg, add_param_args, add_twin_set_arg, count, new_run_folder, nonnegative,
                          open_device_arg, params_from_args, robot_name, twin_params)

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compensate", help="load compensation over the validation grid: PCC lengths vs "
                                          "model-compensated tensions (feed-forward, then tracker-corrected) "
                                          "under 5 g and 10 g (Markdown report)")
    add_device_arg(p)
    p.add_argument("--quick", action="store_true", help="6 configurations instead of the 60 bends of the grid")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="report folder (default a new runs/compensate-YYYYmmdd-HHMMSS)")
    p.add_argument("--floor", type=float, default=0.3, help="lowest tendon tension of the compensation (N)")
    p.add_argument("--ceiling", type=float, default=None,
                   help="highest tendon tension of the compensation (N); default what the tension loop can hold "
                        "at its duty clamp, with headroom (5.12 N for the tuned gains)")
    p.add_argument("--corrections", type=count, default=4,
                   help="most closed-loop corrections from the tracker per mass (0: feed-forward only)")
    add_twin_set_arg(p)
    p.add_argument("--unknown-load", action="store_true",
                   help="compensate the tip force estimated from the loaded tensions and tracked pose, not the known mass")
    p.add_argument("--side-force", type=nonnegative, default=0.0, metavar="N",
                   help="push the tip sideways with this force (N) with every mass, untold (default 0)")
    add_param_args(p)
    p.set_defaults(func=run_compensate)

    p = sub.add_parser("cocontraction", help="length vs tension control on an antagonistic pair: "
                                             "pair tensions while bending, under load and with a length mismatch")
    add_device_arg(p)
    p.add_argument("--out", default=None, metavar="DIR",
                   help="report folder (default a new runs/cocontraction-YYYYmmdd-HHMMSS)")
    p.add_argument("--pair", default=None, metavar="A,B",
                   help="the antagonistic pair, tendon numbers 1..N: A pulls, B opposes it (default the two "
                        "tendons furthest apart)")
    add_param_args(p)
    p.set_defaults(func=run_cocontraction)


def run_compensate(args: argparse.Namespace) -> int:
    """Exit 0 when the goal is met; 3 with one line per miss (faulted rows, a row compensated worse
    than uncompensated, a median reduction under the goal); 2 for a bad argument or a grid out of
    the compensation's reach; 4 when the device failed half-way (the rows so far are reported)."""
    from twin.control.compensation_trial import compensation_grid, run_compensation_trial, tension_ceiling_n
    from twin.control.gains import tension_gains_for
    from twin.driver.errors import DeviceError
    from twin.sim.plant import SimulationError

    params = params_from_args(args)
    twin = twin_params(args, params)
    gains = tension_gains_for(params)
    holds_n = tension_ceiling_n(params, gains, margin_n=0.0, headroom=1.0)
    if args.ceiling is not None and not args.floor < args.ceiling <= holds_n:
        raise UsageError(f"--ceiling {args.ceiling:g}: must be above --floor {args.floor:g} N and at most {holds_n:.2f} N "
                         f"(what the tension loop holds at its duty clamp {gains['output_limit']:.3f} under the "
                         f"{params.rig.tension_limit_n:g} N limit)")
    limit_n = tension_ceiling_n(params, gains) if args.ceiling is None else args.ceiling
    if not 0 <= args.floor < limit_n:
        raise UsageError(f"--floor {args.floor:g}: must be in [0, {limit_n:.2f}) N (the ceiling)")
    configs = compensation_grid(params, limit_n, quick=args.quick)
    start = time.perf_counter()
    with open_device_arg(args.device, params=twin, robot=robot_name(args)) as device:
        try:
            trial = run_compensation_trial(device, params, configs=configs, floor_n=args.floor, limit_n=limit_n,
                                           corrections=args.corrections, tension_gains=gains, progress=print,
                                           unknown_load=args.unknown_load, side_force_n=args.side_force)
        except ValueError as exc:  # nothing within reach: refused before anything ran
            raise UsageError(str(exc)) from None
        except (DeviceError, SimulationError) as exc:
            print(f"twin compensate: the device failed: {exc}", file=sys.stderr)
            return 4
    path = trial.write_report(Path(args.out or new_run_folder("runs", "compensate")), runtime_s=time.perf_counter() - start)
    print(json.dumps(trial.summary(), indent=1))
    for item in trial.left_out:
        print(f"left out: κ {item['kappa_per_m']:g} φ {item['phi_deg']:g}"
              + (f" {item['mass_g']:g} g" if "mass_g" in item else "") + f": {item['reason']}")
    print(f"report: {path}")
    met, problems = trial.verdict()
    for problem in problems:
        print(f"twin compensate: {problem}", file=sys.stderr)
    return 0 if met else 3


def run_cocontraction(args: argparse.Namespace) -> int:
    from twin.control.cocontraction import antagonistic_pair, run_cocontraction_study

    params = params_from_args(args)
    given: tuple[int, int] | None = None
    if args.pair is not None:
        try:
            numbers = [int(k) - 1 for k in args.pair.split(",")]
        except ValueError:
            numbers = []
        if len(numbers) != 2:
            raise UsageError(f"--pair {args.pair}: expected two tendon numbers, e.g. 1,3")
        given = (numbers[0], numbers[1])
    try:
        pair = antagonistic_pair(params, given)
    except ValueError as exc:
        raise UsageError(f"--pair {args.pair}: {exc}" if args.pair else str(exc)) from None
    with open_device_arg(args.device, params=params, robot=robot_name(args)) as device:
        study = run_cocontraction_study(device, params, pair=pair)
    path = study.write_report(Path(args.out or new_run_folder("runs", "cocontraction")))
    print(json.dumps(study.summary(), indent=1))
    print(f"report: {path}")
    return 0
