"""``twin bench TARGET``: speed benchmarks that print figures (never timed tests).

Each target is a function in the package it measures, returning a dict of figures. Times are
CPU time (:class:`twin.stopwatch.Stopwatch`) and the goals are judged on them; the wall-clock
figure, where there is one, is printed beside (a key with ``_wall`` before its unit suffix). The
device's link figures are the exception: a telemetry rate and a latency are wall-clock by nature.
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
    # The kernel at most as costly per integration as a plain C++ RK4 of the same rod at the same
    # step count, which integrates the same shape (to well within the RK4 error).
    "peers": ("twin.rod.bench", "bench_peers", {"integration_ratio": ("<=", 1.0), "tip_difference_m": ("<=", 1e-6)}),
    "device": ("twin.device.bench", "bench_device",
               {"telemetry_rate_hz": (">=", 39.0), "latency_p95_ms": ("<=", 30.0)}),
    # The default robot 100x real time on one core (20000 steps/s at the default 5 ms step); at 4x
    # the elements the step growing no faster than the mass-matrix factorization MuJoCo's serial
    # chain imposes (twin/sim/bench.py says why a real-time ratio cannot be the goal).
    "sim": ("twin.sim.bench", "bench_sim", {"realtime_factor": (">=", 100.0), "settle_s": ("<=", 0.1),
                                            "scaling_over_chain": ("<=", 1.0)}),
    "env": ("twin.envs.bench", "bench_env", {"steps_per_s": (">=", 1000.0)}),
    # Not a speed: whether the board's loops settle (friction on with --set effects.tendon_friction_coeff=...).
    "hold": ("twin.control.settling", "hold_figures",
             {"tension_ptp_n": ("<=", 0.05), "tension_offset_n": ("<=", 0.02), "length_error_counts": ("<=", 1.0)}),
    # 40 Hz live estimates on one core; the accuracy goals of the tip force estimate (twin.force.bench).
    "force": ("twin.force.bench", "bench_force", {"estimate_s": ("<=", 5e-3), "worst_median_error_over_goal": ("<=", 1.0),
                                                  "coverage": (">=", 0.9), "converged_fraction": (">=", 1.0),
                                                  "warm_converged": ("==", True)}),
    # The same accuracy goals on the rig-like path: hidden loads on the sim:// twin, estimated from the device's telemetry.
    "force-rig": ("twin.dynamics.force_rig", "bench_force_rig", {"worst_median_error_over_goal": ("<=", 1.0),
                                                        "coverage": (">=", 0.9), "converged_fraction": (">=", 1.0)}),
    # Contact detection on the moving twin: no false alarm in a 10-minute clean run, every load flagged within 100 ms.
    "contact": ("twin.dynamics.force_rig", "bench_contact", {"false_alarms": ("==", 0), "detected": (">=", 1.0),
                                                    "latency_max_s": ("<=", 0.1)}),
    # The live shadow keeps up with the 40 Hz telemetry on one core: its twin's step and comparison per frame.
    "shadow": ("twin.dynamics.shadow_bench", "bench_shadow", {"realtime_load": ("<=", 1.0)}),
    # A friction twin's validation sweep at most twice the CPU time of a frictionless one.
    "friction": ("twin.experiments.bench", "bench_friction", {"cpu_ratio": ("<=", 2.0), "completed": ("==", True)}),
}


def _wall_key(key: str) -> str:
    """The wall-clock twin of a figure's key: ``cold_s`` → ``cold_wall_s``, ``steps_per_s`` →
    ``steps_per_s_wall``."""
    if key.endswith("_s") and not key.endswith("per_s"):
        return key[:-2] + "_wall_s"
    return key + "_wall"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run a speed benchmark (or hold: the control loops' settling) and print its "
                                      "figures (one core, CPU time)",
                       description="Prints each figure (CPU time; wall time beside it) beside its goal and exits 1 "
                                   "when a goal is not met; --json prints the figures only (exit 0), for scripts "
                                   "that judge them.")
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
    walls = {_wall_key(key) for key in figures} & figures.keys()
    for key, value in figures.items():
        if key in walls:
            continue
        wall = f"  (wall {figures[_wall_key(key)]:.4g})" if _wall_key(key) in figures else ""
        if key not in goals:
            if isinstance(value, list) and all(isinstance(item, dict) for item in value):
                # One line per run, e.g. each element count of the sim's scaling runs.
                for item in value:
                    print(f"{key:16s} " + "  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                                                    for k, v in item.items()))
            elif isinstance(value, float):
                print(f"{key:16s} {value:.4g}{wall}")
            else:
                print(f"{key:16s} {value}{wall}")
            continue
        op, goal = goals[key]
        met = value <= goal if op == "<=" else value >= goal if op == ">=" else value == goal
        shown = f"{value:.4g}" if isinstance(value, float) else str(value)
        goal_text = goal if isinstance(goal, bool) else f"{goal:g}"
        print(f"{key:16s} {shown}{wall}   (goal {op} {goal_text}: {'met' if met else 'NOT met'})")
        if not met:
            missed.append(key)
    if missed:
        print(f"twin bench {args.target}: goal not met: {', '.join(missed)}", file=sys.stderr)
        return 1
    return 0
