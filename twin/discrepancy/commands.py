"""``twin discrepancy DATASET``: find, name, add and show the effect missing from the model."""

from __future__ import annotations

import argparse
import json
import sys

from twin.params import load_params, parse_override

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "discrepancy",
        help="name the physical effect missing from the model for a measured dataset",
        description="Predict every row of DATASET, test the residuals for structure beyond noise, fit each "
        "candidate effect (twin.effects) on a training split, rank them on held-out rows, and name the "
        "winner (greedy, until nothing beats noise).",
    )
    p.add_argument("dataset", metavar="DATASET", help="dataset folder, or the run folder of twin validate")
    p.add_argument("--params", metavar="FILE",
                   help="parameter file of the model to test (default: the one recorded with the dataset)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a parameter of that model (repeatable)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--report", metavar="DIR", help="write a Markdown report with figures into DIR")
    p.add_argument("--out-params", metavar="FILE", help="write the parameter set with the fitted effect(s) to FILE")
    p.add_argument("--seed", type=int, default=0, help="seed of the training/held-out split (default 0)")
    p.add_argument("--holdout", type=float, default=1 / 3, metavar="FRACTION",
                   help="share of configurations held out (default 1/3)")
    p.add_argument("--max-effects", type=int, default=3, metavar="N", help="name at most N effects (default 3)")
    p.set_defaults(func=run_discrepancy_command)


def run_discrepancy_command(args: argparse.Namespace) -> int:
    from twin.discrepancy.report import write_report
    from twin.discrepancy.workflow import run_discrepancy
    from twin.data.dataset import DatasetError, read_dataset

    try:
        dataset = read_dataset(args.dataset)
    except DatasetError as exc:
        print(f"twin discrepancy: {exc}", file=sys.stderr)
        return 2
    if args.params is not None:
        params = load_params(args.params, overrides=args.overrides)
    else:
        params = dataset.params
        if args.overrides:
            params = params.replace(dict(parse_override(o) for o in args.overrides))
    try:
        result = run_discrepancy(dataset, params, holdout_fraction=args.holdout, seed=args.seed,
                                 max_effects=args.max_effects, progress=True)
    except ValueError as exc:
        print(f"twin discrepancy: {exc}", file=sys.stderr)
        return 2
    if args.out_params:
        result.params_after.save(args.out_params)
    if args.report:
        write_report(result, args.report)
    if args.json:
        print(json.dumps(result.to_dict()))
        return 0
    print(result.residuals.statement)
    print(f"named: {', '.join(result.named) or 'none'}")
    for label, entry in result.parameters().items():
        print(f"  {label} = {entry['value']:.6g} ± {entry['std_error']:.2g}")
    print(f"held-out RMS error: {result.rms_before_m * 1e3:.3f} mm before, {result.rms_after_m * 1e3:.3f} mm after")
    for i, rnd in enumerate(result.rounds):
        ranking = ", ".join(f"{s.effect} {s.score:.1f}" for s in rnd.scores)
        print(f"round {i + 1} scores (lower is better): {ranking}")
    if args.out_params:
        print(f"parameters written to {args.out_params}")
    if args.report:
        print(f"report written to {args.report}/report.md")
    return 0
