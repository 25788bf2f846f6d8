"""``twin discrepancy DATASET``: find, name, add and show the effect missing from the model."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from twin.cliargs import UsageError, add_device_arg, add_twin_set_arg, open_device_arg, twin_params
from twin.discrepancy.verdict import Verdict
from twin.params import ParameterError, load_params, parse_override

__all__ = ["EXIT_CODES", "register"]

# Exit code per verdict: a lab's script can branch on the answer without reading the JSON.
EXIT_CODES = {Verdict.EFFECT: 0, Verdict.NONE: 0, Verdict.AMBIGUOUS: 3, Verdict.UNEXPLAINED: 3}
# Exit code for a dataset, parameter file or option the command cannot use.
EXIT_BAD_INPUT = 2
# Exit code for a deciding experiment that the device, the protocol or a diverging twin stopped
# (as for twin validate), and for Ctrl-C (the shell's 128 + SIGINT).
EXIT_STOPPED = 4
EXIT_INTERRUPTED = 130

_EPILOG = """verdicts and exit codes:
  effect       0  the named effect(s) leave residuals consistent with noise, and a held-out
                  error within noise and model form
  none         0  no structured disagreement beyond noise, and a held-out error within noise
                  and model form
  ambiguous    3  two or more candidates explain the data equally (listed); none is named for it
  unexplained  3  structure remains that no candidate nor pair removes, or an error beyond noise
                  and model form that is no function of the configuration (where and how much shown)
  bad input    2  a dataset, parameter file or option that cannot be used (one line on stderr)
  stopped      4  a deciding experiment on --device stopped (the device, the protocol or a diverging
                  twin; one line on stderr); 130 on Ctrl-C. Either leaves the dataset with the
                  experiments completed before it, and no row of the one that stopped"""


# Geometry a discrepancy study does not fit: a parameter file off the recorded one by more than
# this is another robot (a re-measured length differs by well under 1%).
_GEOMETRY_TOLERANCE = 0.02


def _other_geometry(recorded, params) -> str:
    """How ``params``' geometry differs from the dataset's ``recorded`` one ('' when it does not):
    backbone length and radius, tendon radius and angles."""
    differences = []
    for section, key, unit, scale in (("backbone", "length_m", "m", 1.0), ("backbone", "radius_m", "mm", 1e3),
                                      ("tendons", "radius_m", "mm", 1e3)):
        a, b = getattr(getattr(recorded, section), key), getattr(getattr(params, section), key)
        if abs(b - a) > _GEOMETRY_TOLERANCE * abs(a):
            differences.append(f"{section}.{key.removesuffix('_m')} {b * scale:g} {unit}, recorded {a * scale:g} {unit}")
    angles_a, angles_b = np.asarray(recorded.tendons.angles_deg), np.asarray(params.tendons.angles_deg)
    if angles_a.shape == angles_b.shape and np.abs((angles_b - angles_a + 180.0) % 360.0 - 180.0).max() > 1.0:
        differences.append(f"tendons.angles {list(angles_b)} deg, recorded {list(angles_a)} deg")
    return "; ".join(differences)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "discrepancy",
        help="name the physical effect missing from the model for a measured dataset",
        description="Predict every row of DATASET, test the residuals for structure beyond noise, fit each "
        "candidate effect (twin.effects) on a training split, jointly with those already named, rank them on "
        "held-out rows, and name the best if it beats noise (greedy, until nothing does); then check what the "
        "fitted model leaves and give a verdict.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("dataset", metavar="DATASET", help="dataset folder, or the run folder of twin validate")
    p.add_argument("--params", metavar="FILE",
                   help="parameter file of the model to test (default: the one recorded with the dataset)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a parameter of that model (repeatable)")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (verdict, effects, candidates of a tie, parameters, "
                   "remaining_rms_m, ...)")
    p.add_argument("--report", metavar="DIR", help="write a Markdown report with figures into DIR")
    p.add_argument("--out-params", metavar="FILE", help="write the parameter set with the fitted effect(s) to FILE")
    p.add_argument("--seed", type=int, default=0, help="seed of the training/held-out split (default 0)")
    p.add_argument("--holdout", type=float, default=1 / 3, metavar="FRACTION",
                   help="share of configurations held out (default 1/3)")
    p.add_argument("--max-effects", type=int, default=3, metavar="N", help="name at most N effects (default 3)")
    p.add_argument("--model-form-mm", type=float, default=None, metavar="MM",
                   help="structured RMS (mm) the model's form may leave on a perfect rig's data, below which no "
                   "effect is sought (default 0.17, the predictor against the twin; a rig's is larger)")
    add_device_arg(p, default=None,
                   help="when the static data cannot decide (a tie, or structure the best candidates leave), run the "
                   "experiments that tell the contenders apart on this device (the rig the data were taken on, or "
                   "sim://), append them to DATASET and decide (twin.discrepancy.decide)")
    add_twin_set_arg(p, help="with --device sim://: the twin's hidden settings, the rig the dataset was taken on (as "
                     "given to twin validate --twin-set), repeatable")
    p.add_argument("--device-seed", type=int, default=None, metavar="SEED", help="sim:// noise seed of --device")
    p.set_defaults(func=run_discrepancy_command)


def run_discrepancy_command(args: argparse.Namespace) -> int:
    from twin.discrepancy.report import write_report
    from twin.discrepancy.workflow import run_discrepancy
    from twin.data.dataset import DatasetError, read_dataset
    from twin.driver.errors import DeviceError
    from twin.experiments.protocols import ProtocolError
    from twin.sim.plant import SimulationError

    def refuse(message: str) -> int:
        print(f"twin discrepancy: {message}", file=sys.stderr)
        return EXIT_BAD_INPUT

    try:
        dataset = read_dataset(args.dataset)
        if args.params is not None:
            params = load_params(args.params, overrides=args.overrides)
        else:
            params = dataset.params
            if args.overrides:
                params = params.replace(dict(parse_override(o) for o in args.overrides))
        dataset.check_robot(params, robot=Path(args.params).stem if args.params else dataset.robot)
        if args.params is not None:
            other = _other_geometry(dataset.params, params)
            if other:
                # Same tendon count, another robot: the fit would run and blame effects for geometry.
                print(f"twin discrepancy: warning: --params {args.params} is not the robot dataset {args.dataset} "
                      f"was recorded with ({other}); its gaps will include that difference", file=sys.stderr)
    except (DatasetError, ParameterError) as exc:
        return refuse(str(exc))
    except FileNotFoundError:
        return refuse(f"--params {args.params}: no such file")
    except OSError as exc:
        return refuse(f"--params {args.params}: cannot be read ({exc.strerror})")
    if args.model_form_mm is not None and not (np.isfinite(args.model_form_mm) and args.model_form_mm >= 0):
        return refuse(f"--model-form-mm {args.model_form_mm!r}: must be a finite length >= 0 (mm)")
    # Opened (not connected) before the long work, so a bad URL or --twin-set is refused at once.
    try:
        device = _open_device(args, dataset, params) if args.device or args.twin_overrides else None
    except (ValueError, UsageError) as exc:
        return refuse(str(exc))

    def workflow(data):
        form = {} if args.model_form_mm is None else {"model_form_m": args.model_form_mm * 1e-3}
        return run_discrepancy(data, params, holdout_fraction=args.holdout, seed=args.seed,
                               max_effects=args.max_effects, progress=True, **form)

    decision = None
    try:
        result = workflow(dataset)
        if device is not None:
            result, decision = _decide(args, device, result, dataset, params, workflow)
    except ValueError as exc:
        return refuse(str(exc))
    except (ProtocolError, DeviceError, SimulationError) as exc:
        print(f"twin discrepancy: --device {args.device}: a deciding experiment stopped ({type(exc).__name__}: {exc}); "
              f"{args.dataset} holds none of its rows; run the same command again to continue", file=sys.stderr)
        return EXIT_STOPPED
    except KeyboardInterrupt:
        print(f"twin discrepancy: interrupted; {args.dataset} holds no row of an experiment that did not complete; "
              "run the same command again to continue", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        if device is not None:
            device.close()
    if args.out_params:
        result.params_after.save(args.out_params)
    if args.report:
        write_report(result, args.report)
    code = EXIT_CODES[result.verdict]
    if args.json:
        out = result.to_dict()
        if args.device:
            out["decided_by"] = None if decision is None else {
                "contenders": list(decision.contenders), "experiments": list(decision.designs),
                "rows_added": decision.rows_added}
        print(json.dumps(out))
        return code
    if decision is not None:
        print(f"decided by experiment: {', '.join(decision.designs)} ({decision.rows_added} rows appended to "
              f"{args.dataset}) for {', '.join(decision.contenders)}")
    print(result.residuals.statement)
    print(f"verdict: {result.statement()}")
    print(f"named: {', '.join(result.named) or 'none'}")
    for label, entry in result.parameters().items():
        low, high = entry["ci95"]
        print(f"  {label} = {entry['value']:.6g}, 95 % interval {low:.6g} … {high:.6g} "
              f"(standard error {entry['std_error']:.2g}, split scatter {entry.get('split_scatter', 0.0):.2g}, "
              f"model form {entry.get('model_form', 0.0):.2g}, "
              f"model-form shift {entry.get('model_form_shift', 0.0):+.2g})")
    print(f"held-out RMS error: {result.rms_before_m * 1e3:.3f} mm before, {result.rms_after_m * 1e3:.3f} mm after "
          f"(noise {result.residuals.noise.rms_3d_m * 1e3:.3f} mm)")
    for i, rnd in enumerate(result.rounds):
        ranking = ", ".join(f"{s.effect} {s.score:.1f}" for s in rnd.scores)
        print(f"round {i + 1} scores (lower is better): {ranking}")
    if args.out_params:
        print(f"parameters written to {args.out_params}")
    if args.report:
        print(f"report written to {args.report}/report.md")
    return code


def _open_device(args, dataset, params):
    """``--device``, built with ``--twin-set`` on sim:// (the rig the dataset was taken on), not
    yet connected.

    Raises:
        UsageError: a bad URL, or a bad ``--twin-set`` or one without ``--device sim://``.
    """
    twin = twin_params(args, params)
    device = open_device_arg(args.device, params=twin, seed=args.device_seed, robot=dataset.robot)
    if not np.allclose(device.base_rotation, dataset.base_rotation, atol=1e-6):
        device.close()
        raise ValueError(f"--device {args.device}: runs in another base pose than {dataset.path} was recorded in "
                         "(give the same pose=… or base_quat=…)")
    return device


def _decide(args, device, result, dataset, params, workflow):
    """Run the deciding experiments of ``result`` on ``device`` (twin.discrepancy.decide) and
    the workflow again; returns (result, decision or None when nothing needed deciding)."""
    from twin.discrepancy.decide import contenders, decide
    from twin.experiments.protocols import apply_calibration

    if not contenders(result):
        print(f"twin discrepancy: --device {args.device}: the static data decide ({result.verdict}); nothing run",
              file=sys.stderr)
        return result, None
    device.connect()
    cal = dataset.metadata.get("calibration") or {}
    if cal.get("gain_counts_per_n"):
        apply_calibration(device, cal)
    decision = decide(result, device, dataset.path, params, run_workflow=workflow)
    if decision is None:
        return result, None
    return decision.result, decision
