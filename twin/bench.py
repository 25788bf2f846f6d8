"""``twin bench TARGET``: speed benchmarks that print figures (never timed tests).

Each target is a function in the package it measures, returning a dict of figures.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys

from twin.cliargs import UsageError, add_param_args, params_from_args
from twin.params import ParameterError

# target → (module, function, goals printed beside the figures as (comparison, value))
TARGETS = {
    "predictor": ("twin.rod.bench", "bench_predictor",
                  {"cold_s": ("<=", 10e-3), "warm_s": ("<=", 1e-3), "jacobian_s": ("<=", 3e-3),
                   "tip_error_m": ("<=", 1e-6)}),
    "device": ("twin.device.bench", "bench_device",
               {"telemetry_rate_hz": (">=", 39.0), "latency_p95_ms": ("<=", 30.0)}),
    # The default robot 100x real time on one core (20000 steps/s at the default 5 ms step); at 4x
    # the elements at least a quarter of that real-time factor (a cost growing no faster than linearly).
    "sim": ("twin.sim.bench", "bench_sim", {"realtime_factor": (">=", 100.0), "settle_wall_s": ("<=", 0.1),
                                            "scaling_realtime_ratio": (">=", 0.25)}),
    "env": ("envs.bench", "bench_env", {"steps_per_s": (">=", 1000.0)}),
    # A friction twin's validation sweep at most twice the CPU time of a frictionless one.
    "friction": ("twin.sim.bench", "bench_friction", {"cpu_ratio": ("<=", 2.0), "completed": ("==", True)}),
}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run a speed benchmark and print its figures (one core)",
                       description="Prints each figure beside its goal and exits 1 when a goal is not met; "
                                   "--json prints the figures only (exit 0), for scripts that judge them.")
    p.add_argument("target", choices=sorted(TARGETS), help="what to measure")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    p.add_argument("--elements", type=int, metavar="N",
                   help="sim only: time the twin cut into N elements instead of sim.elements, without the "
                        "runs at 2x and 4x the elements (compare two counts as two runs, alternating)")
    add_param_args(p)
    p.set_defaults(func=run_bench)


def run_bench(args: argparse.Namespace) -> int:
    # One core: keep numerical libraries from spreading work over threads.
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    module, function, goals = TARGETS[args.target]
    params, options = params_from_args(args), {}
    if args.elements is not None:
        if args.target != "sim":
            raise UsageError(f"--elements {args.elements}: only twin bench sim takes an element count")
        try:
            params = params.replace({"sim.elements": args.elements}, source="command line")
        except ParameterError as exc:
            raise UsageError(f"--elements {args.elements}: {exc}") from None
        options["scaling"] = False
    figures = getattr(importlib.import_module(module), function)(params, **options)
    if args.json:
        print(json.dumps(figures))
        return 0
    missed = []
    for key, value in figures.items():
        if key not in goals:
            if isinstance(value, list) and all(isinstance(item, dict) for item in value):
                # One line per run, e.g. each element count of the sim's scaling runs.
                for item in value:
                    print(f"{key:16s} " + "  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                                                    for k, v in item.items()))
            else:
                print(f"{key:16s} {value}")
            continue
        op, goal = goals[key]
        met = value <= goal if op == "<=" else value >= goal if op == ">=" else value == goal
        shown = f"{value:.4g}" if isinstance(value, float) else str(value)
        goal_text = goal if isinstance(goal, bool) else f"{goal:g}"
        print(f"{key:16s} {shown}   (goal {op} {goal_text}: {'met' if met else 'NOT met'})")
        if not met:
            missed.append(key)
    if missed:
        print(f"twin bench {args.target}: goal not met: {', '.join(missed)}", file=sys.stderr)
        return 1
    return 0
