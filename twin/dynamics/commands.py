"""``twin dynamics record|replay|calibrate``: the twin's dynamics checked against time series."""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from twin.cliargs import (UsageError, add_device_arg, add_param_args, add_pose_args, add_twin_set_arg, count,
                          new_run_folder, open_device_arg, params_from_args, robot_name, twin_params)
from twin.params import parse_override

__all__ = ["register"]

# Exit code of a run the device or the protocol stopped (as twin validate's).
EXIT_STOPPED = 4
# The fitted parameter file calibrate writes into the run folder by default.
FITTED_PARAMS = "fitted_dynamics.toml"

_CALIBRATE_EPILOG = """verdicts and exit codes:
  effect       0  one effect of the library, or a pair, replays the held-out experiments to
                  the noise level (the noise the data show, within its 99 % bound)
  none         0  the replay gap is at the noise level
  ambiguous    3  two or more effects explain the held-out experiments equally (listed)
  unexplained  3  no effect nor pair replays the held-out experiments to the noise level;
                  what the best of each leaves is shown (a partial explanation is not named)
  bad input    2  a run folder, parameter file or option that cannot be used (one line on stderr)"""


def register(sub: argparse._SubParsersAction) -> None:
    d = sub.add_parser("dynamics", help="record dynamic experiments, replay them on the twin, calibrate its dynamics",
                       description="Time-series experiments (tension and length steps, slow pull-release cycles, a "
                       "chirp) on any device, their replay on the twin, and the dynamic effect the twin misses.")
    actions = d.add_subparsers(dest="action", required=True, metavar="ACTION")

    r = actions.add_parser("record", help="run the dynamic experiments on a device into a run folder",
                           description="Runs the dynamic experiment set (docs/dynamic-dataset.md) on --device and "
                           "writes its commands and telemetry into RUN/dynamics/ of a new run folder.")
    add_device_arg(r)
    r.add_argument("--out", default="runs", metavar="DIR", help="parent folder of the run folder (default runs)")
    r.add_argument("--quick", action="store_true",
                   help="the first tendon's steps, one pull-release cycle and a 2 s chirp (about 11 s of device time)")
    r.add_argument("--seed", type=count, default=None, help="sim:// noise seed (default 0)")
    r.add_argument("--calibration", metavar="FILE", help="load-cell calibration file (default: the parameter set's)")
    r.add_argument("--resume", metavar="RUN_DIR",
                   help="continue a stopped run in this folder: the experiments it holds are kept, the rest recorded")
    add_twin_set_arg(r)
    add_pose_args(r)
    add_param_args(r)
    r.set_defaults(func=run_record)

    p = actions.add_parser("replay", help="replay a recorded run on the twin and show the per-channel RMS gaps")
    p.add_argument("run", metavar="RUN_FOLDER", help="run folder of twin dynamics record (or its dynamics/ folder)")
    _model_args(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run_replay)

    c = actions.add_parser("calibrate", help="name and fit the dynamic effect the twin misses in a recorded run",
                           description="Replays the run on the twin, fits each dynamic effect of twin.effects on the "
                           "training experiments, names the one that explains the held-out experiments, writes the "
                           "fitted parameter file and shows the held-out gap before and after.",
                           epilog=_CALIBRATE_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    c.add_argument("run", metavar="RUN_FOLDER", help="run folder of twin dynamics record (or its dynamics/ folder)")
    _model_args(c)
    c.add_argument("--training", metavar="NAME,NAME", default=None,
                   help="experiments fitted on (default length_steps); the others are held out")
    c.add_argument("--out-params", metavar="FILE",
                   help=f"fitted parameter file (default RUN_FOLDER/{FITTED_PARAMS}); written when an effect is named")
    c.add_argument("--json", action="store_true", help="print one JSON object")
    c.set_defaults(func=run_calibrate)


def _model_args(p: argparse.ArgumentParser) -> None:
    group = p.add_mutually_exclusive_group()
    group.add_argument("--robot", metavar="NAME", default=None, help="the model under test: a robot of the zoo")
    group.add_argument("--params", metavar="FILE", help="the model under test: a parameter file (default: the run's)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a parameter of that model (repeatable)")


# ----------------------------------------------------------------------------------------- record
def run_record(args: argparse.Namespace) -> int:
    from twin.data.dataset import write_atomic
    from twin.driver.errors import DeviceError
    from twin.dynamics.protocols import experiment_set, run_experiment
    from twin.dynamics.series import DYNAMICS_FOLDER, SeriesWriter
    from twin.experiments.commands import RUN_RECORD, TWIN_TRUTH
    from twin.experiments.protocols import ProtocolError, apply_calibration, nominal_calibration
    from twin.sim.plant import SimulationError
    from tqdm import tqdm

    params = params_from_args(args)
    sim = args.device.startswith("sim://")
    if args.seed is not None and not sim:
        raise UsageError(f"--seed {args.seed}: applies to sim:// only, not --device {args.device}")
    twin = twin_params(args, params)
    experiments = experiment_set(params, quick=args.quick)
    if args.calibration:
        from twin.calibration import CalibrationFileError, load_calibration

        try:
            calibration_file = load_calibration(args.calibration)
        except (OSError, CalibrationFileError) as exc:
            raise UsageError(f"--calibration {args.calibration}: {exc}") from None
        from twin.experiments.commands import RunRefused, _check_channels

        try:
            _check_channels(args, calibration_file, params)
        except RunRefused as exc:  # before a run folder exists: a refused run leaves none
            raise UsageError(str(exc)) from None
    invocation = {"command": "dynamics record", "device": args.device, "seed": args.seed, "quick": args.quick,
                  "params": args.params, "robot": args.robot, "set": list(args.overrides),
                  "calibration": args.calibration}
    done: list[str] = []
    if args.resume:
        folder, done = _check_resume(args, invocation, params, [e.name for e in experiments])
        if len(done) == len(experiments):
            print(f"twin dynamics record: --resume {folder}: all {len(done)} experiments are recorded already; "
                  "nothing to do", file=sys.stderr)
            print(f"dynamic dataset: {folder / DYNAMICS_FOLDER}")
            return 0
    device = open_device_arg(args.device, params=twin, seed=args.seed, robot=robot_name(args))
    if not args.resume:
        folder = new_run_folder(args.out, "dynamics")
        write_atomic(folder / RUN_RECORD, json.dumps(invocation, indent=1))
        if args.twin_overrides:
            # The hidden truth stays out of the dataset folder, so a calibration sees only what a lab would.
            write_atomic(folder / TWIN_TRUTH, json.dumps({"twin_set": args.twin_overrides}, indent=1))
    todo = [e for e in experiments if e.name not in done]
    print(f"twin dynamics record: {len(todo)} experiments on {args.device}"
          + (f" ({len(done)} recorded before: {', '.join(done)})" if done else "") + f", run folder {folder}",
          file=sys.stderr)
    recorded = 0
    try:
        device.connect()
        if args.calibration:
            device.set_calibration(calibration_file)
            calibration = {**calibration_file.to_dict(), "file": str(args.calibration)}
        else:
            calibration = nominal_calibration(params)
            apply_calibration(device, calibration)
        if done:
            writer = SeriesWriter.resume(folder / DYNAMICS_FOLDER)
        else:
            writer = SeriesWriter(folder / DYNAMICS_FOLDER, params=params, device=args.device,
                                  base_rotation=device.base_rotation, calibration=calibration,
                                  seed=(args.seed or 0) if sim else None, robot=args.robot,
                                  planned=[e.name for e in experiments], quick=args.quick)
        for experiment in tqdm(todo, desc="dynamic experiments", unit="experiment"):
            writer.write(run_experiment(device, experiment, params))
            recorded += 1
    except (ProtocolError, DeviceError, SimulationError) as exc:
        if not recorded and not args.resume:
            # Nothing measured: no run folder that looks like a run.
            shutil.rmtree(folder, ignore_errors=True)
            print(f"twin dynamics record: stopped: {type(exc).__name__}: {exc}; nothing was recorded", file=sys.stderr)
        else:
            print(f"twin dynamics record: stopped: {type(exc).__name__}: {exc}; the experiments completed so far are "
                  f"in {folder / DYNAMICS_FOLDER}; continue with: twin dynamics record --resume {folder} "
                  "and the same options", file=sys.stderr)
        return EXIT_STOPPED
    except BaseException:
        if not recorded and not args.resume:
            shutil.rmtree(folder, ignore_errors=True)
        raise
    finally:
        device.close()
    print(f"dynamic dataset: {folder / DYNAMICS_FOLDER}")
    return 0


def _check_resume(args, invocation: dict, params, planned: list[str]) -> tuple[Path, list[str]]:
    """The run folder of ``--resume`` and the experiments it holds, once it is known to be a
    ``twin dynamics record`` run taken with these options, parameters and ``--twin-set``.

    Raises:
        UsageError: not such a run, or a setting that differs (each named).
    """
    from twin.dynamics.series import DYNAMICS_FOLDER, METADATA
    from twin.experiments.commands import RUN_RECORD, TWIN_TRUTH

    folder = Path(args.resume)
    where = f"--resume {folder}"
    try:
        record = json.loads((folder / RUN_RECORD).read_text())
        truth = json.loads((folder / TWIN_TRUTH).read_text())["twin_set"] if (folder / TWIN_TRUTH).exists() else []
        metadata_path = folder / DYNAMICS_FOLDER / METADATA
        metadata = json.loads(metadata_path.read_text()) if metadata_path.exists() else None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UsageError(f"{where}: not a readable run folder of twin dynamics record ({exc})") from None
    if not isinstance(record, dict) or record.get("command") != "dynamics record":
        raise UsageError(f"{where}: not a run folder of twin dynamics record")
    differences = [f"{key} {invocation[key]!r} here, {record.get(key)!r} in the run" for key in invocation
                   if key != "command" and invocation[key] != record.get(key)]
    if sorted(args.twin_overrides) != sorted(truth):
        differences.append(f"--twin-set {args.twin_overrides} here, {truth} in the run")
    done: list[str] = []
    if metadata is not None:
        ours = {(s, k): e["value"] for s, entries in params.to_dict().items() for k, e in entries.items()}
        theirs = {(s, k): e.get("value") for s, entries in metadata.get("params", {}).items()
                  for k, e in entries.items()}
        changed = sorted(f"{s}.{k}" for s, k in ours.keys() | theirs.keys() if ours.get((s, k)) != theirs.get((s, k)))
        if changed:
            differences.append(f"parameters {', '.join(changed[:6])}{' ...' if len(changed) > 6 else ''} differ")
        if metadata.get("planned") != planned:
            differences.append(f"experiments {planned} planned here, {metadata.get('planned')} in the run")
        done = [e["name"] for e in metadata.get("experiments", [])]
    if differences:
        raise UsageError(f"{where}: " + "; ".join(differences) + "; resume with the run's settings, or start a "
                         "new run: series taken under other conditions would be mixed in")
    return folder, done


# ----------------------------------------------------------------------------------------- replay
def _load(args: argparse.Namespace):
    """The run and the model under test (``--robot``/``--params``/``--set``, default the run's)."""
    from twin.data.dataset import DatasetError
    from twin.dynamics.series import read_run

    try:
        run = read_run(args.run)
    except DatasetError as exc:
        raise UsageError(f"RUN_FOLDER {args.run}: {exc}") from None
    if args.robot is None and args.params is None:
        params = run.params
        if args.overrides:
            params = params.replace(dict(parse_override(o) for o in args.overrides))
    else:
        params = params_from_args(args)
    if params.tendons.count != int(run.metadata["tendons"]):
        raise UsageError(f"RUN_FOLDER {args.run}: recorded with {run.metadata['tendons']} tendons; the model has "
                         f"{params.tendons.count}")
    return run, params


def run_replay(args: argparse.Namespace) -> int:
    from twin.dynamics.replay import GROUPS, UNITS, compare, replay

    run, params = _load(args)
    comparison = compare(run.series, replay(run.series, params, run.base_rotation))
    recorded = {s.experiment.name for s in run.series}
    missing = [name for name in run.metadata.get("planned", []) if name not in recorded]
    if missing:
        # A run stopped part-way: the gap below is of the experiments it holds, not of the set.
        print(f"twin dynamics replay: RUN_FOLDER {args.run}: {len(missing)} of the {len(run.metadata['planned'])} "
              f"planned experiments missing (the recording stopped before them): {', '.join(missing)}",
              file=sys.stderr)
    if args.json:
        print(json.dumps({"experiments": comparison.names, "missing": missing, **comparison.to_dict()}))
        return 0
    print(f"replay of {', '.join(comparison.names)} on the twin; per-channel RMS gap (measured - twin):")
    for group in GROUPS:
        values = ", ".join(f"{v:.4g}" for v in comparison.rms(group))
        print(f"  {group:8s} [{UNITS[group]}]  {values}")
    return 0


# -------------------------------------------------------------------------------------- calibrate
def run_calibrate(args: argparse.Namespace) -> int:
    from twin.discrepancy.commands import EXIT_CODES
    from twin.dynamics.calibrate import TRAINING, calibrate
    from twin.dynamics.replay import GROUPS, UNITS

    run, params = _load(args)
    training = TRAINING if args.training is None else tuple(n.strip() for n in args.training.split(",") if n.strip())
    names = [s.experiment.name for s in run.series]
    unknown = [n for n in training if n not in names]
    if unknown:
        raise UsageError(f"--training {args.training}: the run has no experiment {unknown[0]!r} (it has "
                         f"{', '.join(names)})")
    try:
        result = calibrate(run.series, params, run.base_rotation, training=training, progress=not args.json)
    except ValueError as exc:
        raise UsageError(f"--training {args.training or ','.join(TRAINING)}: {exc}") from None
    out = None
    if result.params_after is not None:
        out = Path(args.out_params) if args.out_params else _run_folder(run.folder) / FITTED_PARAMS
        result.params_after.save(out)
    code = EXIT_CODES[result.verdict]
    if args.json:
        print(json.dumps({**result.to_dict(), "fitted_params": None if out is None else str(out)}))
        return code
    print(f"training: {', '.join(result.training)}; held out: {', '.join(result.heldout)}")
    print(f"verdict: {result.statement()}")
    for fit in result.fits:
        note = "  (on its bound: not determined)" if fit.on_bound else ""
        note += "" if fit.converged else "  (the minimiser did not converge)"
        print(f"  {fit.effect:18s} {fit.parameter.key} = {fit.value:.4g}: training score {fit.training_score:.3g}, "
              f"held-out {fit.heldout_score:.3g} ({fit.evaluations} replays){note}")
    print(f"held-out per-channel RMS gap, before{' -> after' if result.after is not None else ''}:")
    for group in GROUPS:
        before = result.before.rms(group)
        after = result.after.rms(group) if result.after is not None else None
        cells = [f"{b:.4g}" + (f" -> {a:.4g}" if after is not None else "") for b, a in
                 zip(before, after if after is not None else before)]
        print(f"  {group:8s} [{UNITS[group]}]  {', '.join(cells)}")
    print(f"{result.wall_s:.1f} s wall")
    if out is not None:
        print(f"fitted parameter file: {out}")
    return code


def _run_folder(dataset_folder: Path) -> Path:
    """The run folder of a dynamic dataset folder (its parent when it is RUN/dynamics)."""
    from twin.dynamics.series import DYNAMICS_FOLDER

    return dataset_folder.parent if dataset_folder.name == DYNAMICS_FOLDER else dataset_folder
