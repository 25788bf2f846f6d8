"""``twin predict``: solve the static shape with the Cosserat predictor."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from twin.cliargs import add_param_args, add_pose_args, params_from_args, vector


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "predict",
        help="predict the endoscope's static shape from tendon tensions and loads",
        description="Solve the coupled Cosserat rod-tendon statics (gravity from the parameter set, "
        "along world -z). Positions are in the world frame with the base at the origin.",
    )
    p.add_argument("--tensions", required=True, type=_tensions, metavar="T1,T2,...",
                   help="tendon tensions at the base (N), one per tendon")
    p.add_argument("--tip-force", type=vector(3), default=None, metavar="FX,FY,FZ", help="tip force (N), world frame")
    p.add_argument("--tip-moment", type=vector(3), default=None, metavar="MX,MY,MZ",
                   help="tip moment (N m), world frame")
    add_pose_args(p)
    add_param_args(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run_predict)


def _tensions(text: str) -> np.ndarray:
    try:
        values = np.array([float(x) for x in text.split(",")])
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected comma-separated tensions in N") from None
    if not np.all(np.isfinite(values)) or np.any(values < 0):
        raise argparse.ArgumentTypeError(f"{text!r}: tensions must be finite and >= 0 (tendons only pull)")
    return values


def run_predict(args: argparse.Namespace) -> int:
    # Imported here: the parser of every command is built without loading the compiled kernels.
    from twin.rod.model import RodModel
    from twin.rod.solver import ConvergenceError, solve

    params = params_from_args(args)
    model = RodModel.from_params(params)
    if args.tensions.size != model.tendon_count:
        print(f"twin predict: --tensions has {args.tensions.size} values; the robot has "
              f"{model.tendon_count} tendons", file=sys.stderr)
        return 2
    try:
        sol = solve(model, args.tensions, tip_force_n=args.tip_force, tip_moment_nm=args.tip_moment,
                    base_rotation=params.rig.base_rotation)
    except ConvergenceError as exc:
        if args.json:
            print(json.dumps({"converged": False, "status": exc.status.label, "residual": exc.residual_nm,
                              "iterations": exc.iterations, "error": str(exc)}))
        print(f"twin predict: {exc}", file=sys.stderr)
        return 3
    if args.json:
        print(json.dumps(sol.to_dict()))
        return 0
    tip = sol.tip_position_m * 1e3
    print(f"tip position     {tip[0]:9.3f} {tip[1]:9.3f} {tip[2]:9.3f} mm (world, base at origin)")
    print("tip rotation     " + "\n                 ".join(
        " ".join(f"{x:9.5f}" for x in row) for row in sol.tip_rotation))
    print("tendon lengths   " + " ".join(f"{x * 1e3:.4f}" for x in sol.tendon_lengths_m) + " mm")
    print(f"converged        {sol.converged} ({sol.status.label}) residual {sol.residual_nm:.2e} N m, "
          f"{sol.iterations} iterations, {sol.solve_time_s * 1e3:.2f} ms")
    return 0
