"""``twin compensate`` and ``twin cocontraction``: the control studies from the shell (``twin tune`` is
:mod:`twin.tuning`'s, above the env)."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from twin.cliargs import UsageError, add_param_args, count, new_run_folder, params_from_args, robot_name
from twin.device.commands import open_device_arg

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compensate", help="load compensation over the validation grid: PCC lengths vs "
                                          "model-compensated tensions (feed-forward, then tracker-corrected) "
                                          "under 5 g and 10 g (Markdown report)")
    p.add_argument("--device", default="sim://?seed=0", help="device URL (default the twin)")
    p.add_argument("--quick", action="store_true", help="6 configurations instead of the 60 bends of the grid")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="report folder (default a new runs/compensate-YYYYmmdd-HHMMSS)")
    p.add_argument("--floor", type=float, default=0.3, help="lowest tendon tension of the compensation (N)")
    p.add_argument("--ceiling", type=float, default=None,
                   help="highest tendon tension of the compensation (N); default what the tension loop can hold "
                        "at its duty clamp, with headroom (5.12 N for the tuned gains)")
    p.add_argument("--corrections", type=count, default=2,
                   help="most closed-loop corrections from the tracker per mass (0: feed-forward only)")
    add_param_args(p)
    p.set_defaults(func=run_compensate)

    p = sub.add_parser("cocontraction", help="length vs tension control on an antagonistic pair: "
                                             "pair tensions while bending, under load and with a length mismatch")
    p.add_argument("--device", default="sim://?seed=0", help="device URL (default the twin)")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="report folder (default a new runs/cocontraction-YYYYmmdd-HHMMSS)")
    p.add_argument("--pair", default=None, metavar="A,B",
                   help="the antagonistic pair, tendon numbers 1..N: A pulls, B opposes it (default the two "
                        "tendons furthest apart)")
    add_param_args(p)
    p.set_defaults(func=run_cocontraction)


def run_compensate(args: argparse.Namespace) -> int:
    from twin.control.compensation_trial import QUICK_CONFIGS, run_compensation_trial

    params = params_from_args(args)
    start = time.perf_counter()
    with open_device_arg(args.device, params=params, robot=robot_name(args)) as device:
        trial = run_compensation_trial(device, params, configs=QUICK_CONFIGS if args.quick else None,
                                       floor_n=args.floor, limit_n=args.ceiling, corrections=args.corrections,
                                       progress=print)
    path = trial.write_report(Path(args.out or new_run_folder("runs", "compensate")),
                              runtime_s=time.perf_counter() - start)
    print(json.dumps(trial.summary(), indent=1))
    print(f"report: {path}")
    return 0


def run_cocontraction(args: argparse.Namespace) -> int:
    from twin.control.cocontraction import antagonistic_pair, run_cocontraction_study

    params = params_from_args(args)
    pair = None
    if args.pair is not None:
        try:
            pair = tuple(int(k) - 1 for k in args.pair.split(","))
        except ValueError:
            pair = ()
        if len(pair) != 2:
            raise UsageError(f"--pair {args.pair}: expected two tendon numbers, e.g. 1,3")
    try:
        pair = antagonistic_pair(params, pair)
    except ValueError as exc:
        raise UsageError(f"--pair {args.pair}: {exc}" if args.pair else str(exc)) from None
    with open_device_arg(args.device, params=params, robot=robot_name(args)) as device:
        study = run_cocontraction_study(device, params, pair=pair)
    path = study.write_report(Path(args.out or new_run_folder("runs", "cocontraction")))
    print(json.dumps(study.summary(), indent=1))
    print(f"report: {path}")
    return 0
