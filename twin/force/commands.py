"""``twin force``: the tip force from measured tensions and the tracked tip pose (one, or a dataset's rows)."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from twin.cliargs import UsageError, add_param_args, add_pose_args, nonnegative, params_from_args, positive, vector

EXIT_NOT_CONVERGED = 3


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "force",
        help="estimate the tip force from tendon tensions and the tracked tip pose",
        description="Intrinsic force sensing: the tip force (world frame, the load applied at the tip) that "
        "makes the predictor meet the measured tip pose, with its covariance from the sensors' noise "
        "(the robot's [sensors]) and a model-form term; directions the pose cannot see (the axial force of "
        "a straight robot) are reported unobservable (null), never 0. Exits 3 when an estimate did not converge.",
    )
    p.add_argument("dataset", nargs="?", default=None, metavar="DATASET",
                   help="a dataset folder: estimate every row (its tensions, tip pose, base pose, parameter set)")
    p.add_argument("--tensions", type=vector(None), metavar="T1,T2,...", help="load-cell tensions (N), one per tendon")
    p.add_argument("--tip-position", type=vector(3), metavar="X,Y,Z",
                   help="tracked tip position (m), base frame (origin at the base centre, world axes)")
    p.add_argument("--tip-rotation", type=vector(9), metavar="R11,...,R33",
                   help="tip rotation matrix (world), row by row; without it, the position alone is used")
    p.add_argument("--moment", action="store_true", help="estimate the tip moment too (default: a point contact)")
    p.add_argument("--model-error", type=nonnegative, default=0.02, metavar="FRACTION",
                   help="relative uncertainty of the force from the model's form (default 0.02)")
    p.add_argument("--max-std", type=positive, default=0.01, metavar="N",
                   help="a force direction seen with a larger standard deviation is unobservable (default 0.01 N)")
    add_pose_args(p)
    add_param_args(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run_force)


def _options(args) -> dict:
    return dict(estimate_moment=args.moment, model_error_fraction=args.model_error, max_std_n=args.max_std)


def run_force(args: argparse.Namespace) -> int:
    if args.dataset is not None:
        for name in ("tensions", "tip_position", "tip_rotation"):
            if getattr(args, name) is not None:
                raise UsageError(f"--{name.replace('_', '-')}: not with a DATASET (its rows give them)")
        return _run_dataset(args)
    for name in ("tensions", "tip_position"):
        if getattr(args, name) is None:
            raise UsageError(f"--{name.replace('_', '-')} is required (or a DATASET)")
    from twin.force.estimator import estimate_tip_wrench

    params = params_from_args(args)
    if args.tensions.size != params.tendons.count:
        raise UsageError(f"--tensions {','.join(f'{t:g}' for t in args.tensions)}: {args.tensions.size} values; "
                         f"the robot has {params.tendons.count} tendons")
    if (args.tensions < 0).any():
        raise UsageError(f"--tensions {','.join(f'{t:g}' for t in args.tensions)}: tendons only pull (>= 0 N)")
    rotation = None if args.tip_rotation is None else args.tip_rotation.reshape(3, 3)
    try:
        est = estimate_tip_wrench(params, args.tensions, args.tip_position, rotation, **_options(args))
    except ValueError as exc:
        raise UsageError(str(exc).replace("tip_rotation =", "--tip-rotation").replace(
            "tip_position_m =", "--tip-position")) from None
    if args.json:
        print(json.dumps(est.to_dict()))
    else:
        _print(est)
    if not est.converged:
        print("twin force: the estimate did not converge", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return 0


def _print(est) -> None:
    def fmt(v, scale=1.0):
        return " ".join("      n/a" if not np.isfinite(x) else f"{x * scale:9.2f}" for x in v)

    print(f"tip force        {fmt(est.force_n, 1e3)} mN (world; n/a: not observable)")
    std = np.sqrt(np.diag(est.force_cov_n2))
    print(f"force std        {fmt(std, 1e3)} mN")
    for d in est.unobservable_force_directions:
        print(f"unobservable     along {d[0]:+.3f} {d[1]:+.3f} {d[2]:+.3f}")
    if est.moment_nm is not None:
        print(f"tip moment       {fmt(est.moment_nm, 1e3)} mN m")
    if est.consistent is False:
        print("inconsistent     no tip force explains the pose to the sensors' noise (chi2 too large)")
    print(f"converged        {est.converged} ({est.iterations} iterations, chi2 {est.residual_chi2:.2f}, "
          f"{est.estimate_time_s * 1e3:.1f} ms CPU)")


def _run_dataset(args) -> int:
    from tqdm import tqdm

    from twin import effects
    from twin.data.dataset import read_dataset
    from twin.force.rows import dataset_estimates

    dataset = read_dataset(args.dataset)
    if args.robot is not None or args.params is not None:
        params = params_from_args(args)
    else:
        params = dataset.params
        if args.overrides:
            params = params.replace(dict(_override(o) for o in args.overrides), source="command line")
    dataset.check_robot(params, robot=args.robot or args.params)
    rows, failures = [], 0
    estimates = dataset_estimates(dataset, params, **_options(args))
    for i, est in enumerate(tqdm(estimates, total=len(dataset), desc="estimating", unit="row", leave=False,
                                 disable=args.json and not sys.stderr.isatty())):
        failures += not est.converged
        rows.append({"row": i, "config": int(dataset["config"][i]),
                     "known_force_n": effects.tip_force_n(params, float(dataset["tip_mass_kg"][i])).tolist(),
                     **est.to_dict()})
    if args.json:
        print(json.dumps({"rows": rows, "converged": failures == 0, "failures": failures}))
    else:
        for r in rows:
            f = ["  n/a" if x is None else f"{x * 1e3:7.2f}" for x in r["force_n"]]
            k = [f"{x * 1e3:7.2f}" for x in r["known_force_n"]]
            print(f"row {r['row']:4d} config {r['config']:4d}  force {' '.join(f)} mN   known {' '.join(k)} mN"
                  f"   {'converged' if r['converged'] else 'NOT converged'}")
    if failures:
        print(f"twin force: {failures} of {len(rows)} rows did not converge", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return 0


def _override(text: str):
    from twin.params import parse_override

    return parse_override(text)
